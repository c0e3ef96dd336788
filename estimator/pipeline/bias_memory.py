"""A kit's memory of its sensors' gyroscope biases (``docs/gyro-bias-memory.md``).

A kit is used day after day with the same sensors, and a MEMS gyroscope's bias may change
little between sessions (0.6 mrad/s between RING's trials, minutes apart; between days and
with temperature it can move by more), while a session that never rests (a sensor on foam or
skin wobbling from its first sample, a swaying trunk) cannot learn the bias about the
vertical at all. So each session starts its filters from the bias each sensor last
learnt (a prior: the first stillness replaces it, the corrections in motion refine it),
and after it the kit remembers the biases that stillness taught — never one that was not
learnt (``LearntGyroBias.remembered``): a sensor that learnt nothing keeps its older
memory.

The JSON form, version 1::

    {"format": "armtrack-gyro-bias/1",
     "sensors": {"forearm": {"bias_rad_s": [0.0098, 0.0051, -0.0019],
                             "learnt": "still start", "still_s": 0.62, "age_s": 65.6}}}
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from ..body import SENSOR_NAMES
from ..errors import InvalidArgument
from ..orientation import LearntGyroBias, QcfParams
from ..orientation.qcf import LEARNT_REST, LEARNT_STILL_START

FORMAT = "armtrack-gyro-bias/1"
#: The largest remembered bias accepted per axis [rad/s] (the filter's ``bias_max``).
BIAS_MAX = QcfParams().bias_max


@dataclass(frozen=True)
class RememberedBias:
    """One sensor's remembered gyroscope bias: ``bias`` [rad/s] (sensor frame), how it was
    learnt (``"rest"`` or ``"still start"``), from ``still_s`` seconds of stillness, and
    ``age_s``: from its learning to the end of the session that learnt it [s]."""

    bias: tuple[float, float, float]
    learnt: str
    still_s: float
    age_s: float


def remember(previous: Mapping[str, RememberedBias],
             learnt: Mapping[str, LearntGyroBias]) -> dict[str, RememberedBias]:
    """The kit's memory after a session: each sensor's newly learnt bias where stillness
    taught one, else its previous memory (if any)."""
    memory = dict(previous)
    for name, value in learnt.items():
        if value.remembered:
            memory[name] = RememberedBias(value.bias, value.learnt, value.still_s,
                                          value.age_s)
    return memory


def priors(memory: Mapping[str, RememberedBias]) -> dict[str, tuple[float, float, float]]:
    """Sensor name → the bias its filter starts from (``Pipeline``'s ``gyr_bias_priors``)."""
    return {name: value.bias for name, value in memory.items()}


def memory_to_json(memory: Mapping[str, RememberedBias]) -> dict:
    """The JSON object of version 1 (sensors in name order)."""
    return {"format": FORMAT, "sensors": {
        name: {"bias_rad_s": list(value.bias), "learnt": value.learnt,
               "still_s": round(value.still_s, 3), "age_s": round(value.age_s, 3)}
        for name, value in sorted(memory.items())}}


def memory_from_json(document: object, source: str = "the bias memory"
                     ) -> dict[str, RememberedBias]:
    """Version 1's JSON object as a memory, or InvalidArgument naming ``source`` and what is
    wrong (nothing is taken from a document with any error)."""
    if not isinstance(document, dict) or document.get("format") != FORMAT:
        found = document.get("format") if isinstance(document, dict) else type(document).__name__
        raise InvalidArgument(f"{source}: 'format' must be {FORMAT!r}, got {found!r}")
    sensors = document.get("sensors")
    if not isinstance(sensors, dict):
        raise InvalidArgument(f"{source}: 'sensors' must be an object of sensor name → bias")
    memory = {}
    for name, entry in sensors.items():
        where = f"{source}: sensors.{name}"
        if name not in SENSOR_NAMES:
            raise InvalidArgument(f"{where}: unknown sensor; one of {', '.join(SENSOR_NAMES)}")
        if not isinstance(entry, dict):
            raise InvalidArgument(f"{where} must be an object")
        bias = entry.get("bias_rad_s")
        if (not isinstance(bias, list) or len(bias) != 3
                or not all(_is_number(v) and math.isfinite(v) for v in bias)):
            raise InvalidArgument(f"{where}.bias_rad_s must be 3 finite numbers [rad/s], "
                                  f"got {bias!r}")
        if max(abs(v) for v in bias) > BIAS_MAX:
            raise InvalidArgument(f"{where}.bias_rad_s must be within ±{BIAS_MAX} rad/s per "
                                  f"axis, got {bias!r}")
        how = entry.get("learnt")
        if how not in (LEARNT_REST, LEARNT_STILL_START):
            raise InvalidArgument(f"{where}.learnt must be {LEARNT_REST!r} or "
                                  f"{LEARNT_STILL_START!r} (a bias never learnt is not "
                                  f"remembered), got {how!r}")
        numbers = {}
        for key in ("still_s", "age_s"):
            value = entry.get(key)
            if not (_is_number(value) and math.isfinite(value) and value >= 0):
                raise InvalidArgument(f"{where}.{key} must be a number ≥ 0 [s], got {value!r}")
            numbers[key] = float(value)
        memory[name] = RememberedBias((float(bias[0]), float(bias[1]), float(bias[2])), how,
                                      numbers["still_s"], numbers["age_s"])
    return memory


def read_bias_memory(path: Path) -> dict[str, RememberedBias]:
    """A memory file (``memory_from_json``); InvalidArgument naming the file if unreadable."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InvalidArgument(f"{path}: cannot read the bias memory ({exc})") from None
    try:
        document = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InvalidArgument(f"{path}: not JSON ({exc})") from None
    except (RecursionError, ValueError) as exc:  # nested too deep, an int of > 4300 digits
        raise InvalidArgument(f"{path}: not a bias memory ({type(exc).__name__}: "
                              f"{str(exc)[:80]})") from None
    return memory_from_json(document, str(path))


def _is_number(value: object) -> bool:
    """A JSON number a float holds (an int too large for one is not: math.isfinite of it
    raises OverflowError)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    try:
        float(value)
    except OverflowError:
        return False
    return True
