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


def apdm_h5(path, sensors: dict[str, tuple[str, SensorStream]], *,
            t0_us: int = 1_709_281_800_000_000, version: int = 5) -> None:
    """An APDM file (format version 5): /Sensors/<id>/{Accelerometer [m/s²], Gyroscope
    [rad/s], Magnetometer [µT], Time [µs since 1970, uint64]}, the label in the
    Configuration group's ``Label 0`` attribute (bytes)."""
    import h5py

    with h5py.File(path, "w") as f:
        f.attrs["FileFormatVersion"] = np.int32(version)
        group = f.create_group("Sensors")
        for sid, (label, s) in sensors.items():
            g = group.create_group(sid)
            g.create_dataset("Time", data=(t0_us + np.round(s.t * 1e6)).astype(np.uint64))
            g.create_dataset("Accelerometer", data=s.acc.astype(np.float64))
            g.create_dataset("Gyroscope", data=s.gyr.astype(np.float64))
            if s.mag is not None:
                g.create_dataset("Magnetometer", data=s.mag.astype(np.float64))
            config = g.create_group("Configuration")
            config.attrs["Label 0"] = np.bytes_(label.encode())


def metamotion_csvs(stream: SensorStream, mac: str = "C8CF7A2F32A7", *,
                    t0_ms: float = 1_709_281_800_000.0, every: dict[str, int] | None = None,
                    epoch_name: str = "epoc (ms)") -> dict[str, bytes]:
    """MetaBase files per signal: ``epoc (ms),timestamp (+01:00),elapsed (s),x-axis (g)…``;
    accelerometer in g, gyroscope in deg/s, magnetometer in T. ``every`` keeps every k-th
    sample of a signal (signals at different rates)."""
    every = every or {}
    parts = {"Accelerometer": ("g", stream.acc / STANDARD_GRAVITY),
             "Gyroscope": ("deg/s", stream.gyr * RAD2DEG)}
    if stream.mag is not None:
        parts["Magnetometer"] = ("T", stream.mag * 1e-6)
    out = {}
    for name, (unit, values) in parts.items():
        k = every.get(name, 1)
        t = stream.t[::k]
        ms = t0_ms + t * 1000.0
        rows = [f"{m:.0f},2024-03-01T09.30.{int(s) % 60:02d}.000,{s:.3f}," +
                ",".join(f"{v:.10g}" for v in row)
                for m, s, row in zip(ms, t, values[::k], strict=True)]
        head = (f"{epoch_name},timestamp (+01:00),elapsed (s),x-axis ({unit}),"
                f"y-axis ({unit}),z-axis ({unit})")
        rate = 1.0 / float(np.median(np.diff(t)))
        fname = f"MetaWear_2024-03-01T09.30.00.000_{mac}_{name}_{rate:.3f}Hz_1.7.3.csv"
        out[fname] = ("\n".join([head, *rows]) + "\n").encode()
    return out


def sensor_logger_files(stream: SensorStream, R_world_sensor: np.ndarray, *,
                        platform: str = "android", t0_ns: int = 1_709_281_800_000_000_000,
                        gravity_every: int = 1) -> dict[str, bytes]:
    """A Sensor Logger export: Accelerometer.csv without gravity and Gravity.csv (the
    gravity part of the specific force, from the true orientation), Gyroscope.csv [rad/s],
    Magnetometer.csv [µT], time in ns, columns z,y,x; iOS negates all accelerations."""
    gravity = np.einsum("nji,j->ni", R_world_sensor, np.array([0.0, 0.0, 9.81]))
    linear = stream.acc - gravity
    sign = -1.0 if platform == "ios" else 1.0
    files = {"Accelerometer.csv": (stream.t, sign * linear),
             "Gravity.csv": (stream.t[::gravity_every], sign * gravity[::gravity_every]),
             "Gyroscope.csv": (stream.t, stream.gyr)}
    if stream.mag is not None:
        files["Magnetometer.csv"] = (stream.t, stream.mag)
    out = {}
    for name, (t, v) in files.items():
        ns = t0_ns + np.round(t * 1e9).astype(np.int64)
        rows = [f"{n},{s:.9f},{z:.12g},{y:.12g},{x:.12g}"
                for n, s, (x, y, z) in zip(ns, t, v, strict=True)]
        out[name] = ("\n".join(["time,seconds_elapsed,z,y,x", *rows]) + "\n").encode()
    out["Metadata.csv"] = (
        "version,device name,recording time,platform,appVersion,device id,sensors,"
        "sampleRateMs\n"
        f"3,Pixel 7,2024-03-01_08-30-00,{platform},1.30,abc,Accelerometer|Gravity|"
        "Gyroscope|Magnetometer,10|10|10|10\n").encode()
    return out


def generic_csv(stream: SensorStream, *, label: str | None = None) -> bytes:
    """A device of our own invention: ``;``-separated, time in ms from its start,
    acceleration in g, rate in deg/s, field in nT, and its y and z axes opposite to the
    sensor frame (turned 180° about x, still right-handed)."""
    flip = np.array([1.0, -1.0, -1.0])
    cols = ["Time [ms]", "Acc X", "Acc Y", "Acc Z", "Gyr X", "Gyr Y", "Gyr Z"]
    values = [stream.t * 1000.0, *(stream.acc * flip / STANDARD_GRAVITY).T,
              *(stream.gyr * flip * RAD2DEG).T]
    if stream.mag is not None:
        cols += ["Mag X", "Mag Y", "Mag Z"]
        values += list((stream.mag * flip * 1000.0).T)
    lines = ["# exported by a device of our own", ";".join(cols)]
    lines += [";".join(f"{v:.12g}" for v in row) for row in np.column_stack(values)]
    return ("\n".join(lines) + "\n").encode()


GENERIC_MAP = ("t='Time [ms]':ms ax='Acc X':g ay=-'Acc Y':g az=-'Acc Z':g gx='Gyr X':deg/s "
               "gy=-'Gyr Y':deg/s gz=-'Gyr Z':deg/s mx='Mag X':nT my=-'Mag Y':nT mz=-'Mag Z':nT")
