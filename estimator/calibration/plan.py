"""Which calibration poses a session has, and when its calibration becomes final.

``docs/spec/kinematics.md`` ("Estimates"): calibration is final at the end of a T-pose; or 5 s
after the end of an N-pose when no T-pose has begun by then; or, with no pose at all,
60 s after the first sample (then the default mounting is used). A file's
``calibration`` header and a stream's ``npose``/``tpose`` marks are the same poses.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

from ..recording import Mark, Pose

#: Seconds after an N-pose's end by which a T-pose must have begun to be waited for.
NPOSE_GRACE_S = 5.0
#: Seconds after the first sample when a session with no pose calibrates by default.
NO_POSE_TIMEOUT_S = 60.0


@dataclass(frozen=True)
class CalibrationPlan:
    """The poses used: the first N-pose, and the first T-pose that began no later than
    ``NPOSE_GRACE_S`` after it ended (or any T-pose when there is no N-pose)."""

    npose: Pose | None
    tpose: Pose | None

    @classmethod
    def from_poses(cls, poses: Iterable[Pose]) -> CalibrationPlan:
        poses = list(poses)
        npose = next((p for p in poses if p.name == "npose"), None)
        tposes = [p for p in poses if p.name == "tpose"]
        if npose is not None:
            tposes = [p for p in tposes if p.start <= npose.end + NPOSE_GRACE_S]
        return cls(npose=npose, tpose=tposes[0] if tposes else None)

    def final_time(self, first_sample_s: float) -> float:
        """The stream time [s] at which calibration is final."""
        if self.tpose is not None:
            return self.tpose.end
        if self.npose is not None:
            return self.npose.end + NPOSE_GRACE_S
        return first_sample_s + NO_POSE_TIMEOUT_S

    @property
    def method(self) -> str:
        """``two-pose``, ``n-pose`` (tilt from the N-pose, the rest default) or ``default``."""
        if self.npose is not None and self.tpose is not None:
            return "two-pose"
        if self.npose is not None:
            return "n-pose"
        return "default"


def poses_from_marks(marks: Iterable[Mark]) -> list[Pose]:
    """The calibration poses that ``npose``/``end:npose`` and ``tpose``/``end:tpose`` marks
    delimit (an unended pose is left out: it is still being held)."""
    open_at: dict[str, float] = {}
    poses = []
    for mark in sorted(marks, key=lambda m: m.t):
        if mark.label in ("npose", "tpose"):
            open_at[mark.label] = mark.t
        elif mark.label in ("end:npose", "end:tpose"):
            name = mark.label[4:]
            if name in open_at and open_at[name] < mark.t:
                poses.append(Pose(name, open_at.pop(name), mark.t))
    return poses
