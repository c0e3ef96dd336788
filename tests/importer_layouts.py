"""Writers of vendor layouts from a simulated recording, for the importer tests: each
converts the recording's units (m/s², rad/s, µT, s) to the vendor's, in the vendor's
column order, header lines and time base, as the vendors' public documentation and
example files show (tests/fixtures/importers/README.md)."""

from __future__ import annotations

import io
import math

import numpy as np
from armtrack.estimator.importers.units import STANDARD_GRAVITY
from armtrack.estimator.recording import SensorStream

RAD2DEG = 180.0 / math.pi
#: the simulator's earth field [µT] (EARTH_FIELD_UT is 48 µT): one DOT a.u.
SIM_FIELD_UT = 48.0


def _fmt(values: np.ndarray) -> list[str]:
    return [",".join(f"{v:.10g}" for v in row) for row in values]


def xsens_dot_csv(stream: SensorStream, tag: str, *, synced: bool = True,
                  stf0_us: int = 4_290_000_000, start_time: str = "2024-03-01 09:30:00.000 +0100",
                  rate_hz: int = 60, mag: bool = True) -> bytes:
    """A DOT export in 'Rate quantities (with mag)' mode: SampleTimeFine [µs, wrapping at
    2³²] from ``stf0_us``, Acc [m/s²], Gyr [deg/s], Mag [a.u. of SIM_FIELD_UT]."""
    stf = (stf0_us + np.round(stream.t * 1e6).astype(np.int64)) % (2**32)
    cols = [np.arange(len(stream)), stf, *stream.acc.T, *(stream.gyr * RAD2DEG).T]
    names = "PacketCounter,SampleTimeFine,Acc_X,Acc_Y,Acc_Z,Gyr_X,Gyr_Y,Gyr_Z"
    if mag and stream.mag is not None:
        cols += list((stream.mag / SIM_FIELD_UT).T)
        names += ",Mag_X,Mag_Y,Mag_Z"
    pad = ",,,,,,,,,,,,,,,,,"
    head = ["sep=,", f"DeviceTag:,{tag}{pad}", f"FirmwareVersion:,2.6.0{pad}",
            f"AppVersion:,2023.6.0{pad}", f"SyncStatus:,{'Synced' if synced else 'Un-synced'}{pad}",
            f"OutputRate:,{rate_hz}Hz{pad}", f"FilterProfile:,General{pad}",
            f"Measurement Mode:,Rate quantities (with mag){pad}", f"StartTime:,{start_time}{pad}",
            f"Movella Technologies B. V. 2005-2024,,{pad}", "", names]
    body = [f"{int(c)},{int(s)}," + ",".join(f"{v:.10g}" for v in rest)
            for c, s, *rest in zip(*cols, strict=True)]
    return ("\n".join(head + body) + "\n").encode()


def shimmer_csv(devices: dict[str, SensorStream], *, t0_ms: float = 1_709_281_800_000.0,
                delimiter: str = "\t", acc_unit: str = "m/(s^2)",
                acc_factor: float = 1.0) -> bytes:
    """A Consensys export of several devices on one time base: ``"sep=\\t"``, names,
    formats row (CAL), units row, then rows; Accel_LN [m/(s^2)], Gyro [deg/s],
    Mag [local_flux = gauss]. ``acc_unit``/``acc_factor`` make a units row that lies."""
    names, formats, units, columns = [], [], [], []
    first = next(iter(devices.values()))
    for dev, s in devices.items():
        if len(s) != len(first) or not np.array_equal(s.t, first.t):
            raise ValueError("one Consensys file: devices on one time base")
        parts = [("Timestamp_Unix", "ms", [t0_ms + s.t * 1000.0])]
        parts += [(f"Accel_LN_{a}", acc_unit, [s.acc[:, i] * acc_factor]) for i, a in
                  enumerate("XYZ")]
        parts += [(f"Gyro_{a}", "deg/s", [s.gyr[:, i] * RAD2DEG]) for i, a in enumerate("XYZ")]
        if s.mag is not None:
            parts += [(f"Mag_{a}", "local_flux", [s.mag[:, i] / 100.0])
                      for i, a in enumerate("XYZ")]
        for sig, unit, (values,) in parts:
            names.append(f"{dev}_{sig}_CAL")
            formats.append("CAL")
            units.append(unit)
            columns.append(values)
    d = delimiter
    out = io.StringIO()
    out.write(f'"sep={d}"\n{d.join(names)}{d}\n{d.join(formats)}{d}\n{d.join(units)}{d}\n')
    for row in np.column_stack(columns):
        out.write(d.join(f"{v:.16g}" for v in row) + d + "\n")
    return out.getvalue().encode()


__all__ = ["SIM_FIELD_UT", "STANDARD_GRAVITY", "shimmer_csv", "xsens_dot_csv"]
