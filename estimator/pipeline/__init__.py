"""The estimation pipeline: a recording (batch) or a stream (chunks) in, estimates out."""

from ..recording import Recording
from .calibrate import Calibration
from .estimates import REFERENCE_ORDER, EstimateArrays, Estimates
from .session import Pipeline, PipelineConfig


def estimate_recording(recording: Recording, filter_name: str = "qcf"
                       ) -> tuple[Estimates, Calibration]:
    """Estimates of a whole recording, and the calibration they used."""
    config = PipelineConfig(side=recording.side, lengths=recording.segment_lengths(),
                            sensors=tuple(recording.sensors), filter=filter_name)
    pipeline = Pipeline(config, poses=recording.calibration)
    for mark in recording.marks:
        pipeline.add_mark(mark)
    for name, stream in recording.sensors.items():
        pipeline.feed(name, stream.t, stream.acc, stream.gyr, stream.mag)
    estimates = pipeline.finish()
    assert pipeline.calibration is not None
    return estimates, pipeline.calibration


__all__ = ["REFERENCE_ORDER", "Calibration", "EstimateArrays", "Estimates", "Pipeline",
           "PipelineConfig", "estimate_recording"]
