"""The estimation pipeline: a recording (batch) or a stream (chunks) in, estimates out."""

from collections.abc import Mapping, Sequence

from ..recording import Recording
from .calibrate import Calibration
from .estimates import REFERENCE_ORDER, EstimateArrays, Estimates
from .session import Pipeline, PipelineConfig


def estimate_recording(recording: Recording, filter_name: str = "qcf",
                       gyr_bias_priors: Mapping[str, Sequence[float]] | None = None
                       ) -> tuple[Estimates, Calibration]:
    """Estimates of a whole recording, and the calibration they used (``gyr_bias_priors``:
    see ``Pipeline``)."""
    pipeline = run_recording(recording, filter_name, gyr_bias_priors)
    estimates = pipeline.finish()
    assert pipeline.calibration is not None
    return estimates, pipeline.calibration


def run_recording(recording: Recording, filter_name: str = "qcf",
                  gyr_bias_priors: Mapping[str, Sequence[float]] | None = None) -> Pipeline:
    """A pipeline fed a whole recording (samples, marks, wrist points), not yet finished:
    ``finish()`` gives its estimates; ``elbow_source`` and ``gamma`` say what the points
    did; ``learnt_biases()`` the gyroscope biases (``gyr_bias_priors``: see ``Pipeline``).
    The filters take the kit's gyroscope delay from the recording (``gyro_delay_s``)."""
    config = PipelineConfig(side=recording.side, lengths=recording.segment_lengths(),
                            sensors=tuple(recording.sensors), filter=filter_name,
                            gyro_delay_s=recording.gyro_delay_s)
    pipeline = Pipeline(config, poses=recording.calibration,
                        points_frame=recording.points_frame if recording.points else None,
                        gyr_bias_priors=gyr_bias_priors)
    for mark in recording.marks:
        pipeline.add_mark(mark)
    for name, stream in recording.sensors.items():
        pipeline.feed(name, stream.t, stream.acc, stream.gyr, stream.mag)
    if pipeline.gamma is not None:
        pipeline.gamma.flag_log = []
    for name, points in recording.points.items():
        pipeline.feed_points(name, points.t, points.p)
    return pipeline


__all__ = ["REFERENCE_ORDER", "Calibration", "EstimateArrays", "Estimates", "Pipeline",
           "PipelineConfig", "estimate_recording", "run_recording"]
