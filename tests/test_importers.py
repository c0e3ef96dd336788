"""Vendor importers (estimator/importers): per format, files written in the vendor's layout
from a simulated session import to the same joint angles as the simulated recording
(within 0.1°); real public header lines and samples read with gravity where it must be;
damaged files refused naming file, line and problem; unit conversions in one place."""

from __future__ import annotations

import math
from functools import cache
from pathlib import Path

import numpy as np
import pytest
from armtrack.estimator.importers import (
    Assignment,
    ImportFailure,
    ReadOptions,
    SourceFile,
    import_recording,
    read_signals,
)
from armtrack.estimator.importers import units as U
from armtrack.estimator.importers.xsens_dot import parse_start_time
from armtrack.estimator.pipeline import estimate_recording
from armtrack.estimator.recording import parse_recording, write_recording
from armtrack.estimator.simulation import SimulationConfig, simulate
from importer_layouts import (
    GENERIC_MAP,
    SIM_FIELD_UT,
    apdm_h5,
    generic_csv,
    metamotion_csvs,
    sensor_logger_files,
    shimmer_csv,
    xsens_dot_csv,
)

FIXTURES = Path(__file__).parent / "fixtures" / "importers"
SENSORS = ("upper_arm", "forearm", "hand")
TOLERANCE_DEG = 0.1


@cache
def session(rate_hz: float = 60.0):
    """A short simulated elbow-flexion session with calibration poses (9-axis)."""
    return simulate(SimulationConfig(rate_hz=rate_hz, repetitions=2, seed=3))


@cache
def simulated_angles(rate_hz: float = 60.0):
    estimates, _ = estimate_recording(session(rate_hz).recording)
    return estimates.t, estimates.degrees()


def snapped(recording, per_second: int):
    """The recording with its sample times on a vendor's time grid (DOT: whole µs,
    ``per_second`` 10⁶), as the reader computes them (count / per_second): the samples
    are the simulation's, stamped at most half a count off. The estimates are not smooth
    in the times' last bits: a sample at 3.0 s or at 3.0000000000000004 s falls in or out
    of the N-pose window and moved angles by 0.1° (a finding for the estimator), so the
    reference holds exactly the times the vendor file can."""
    from dataclasses import replace

    from armtrack.estimator.recording import SensorStream

    return replace(recording, sensors={
        n: SensorStream(np.round(s.t * per_second) / per_second, s.acc, s.gyr, s.mag)
        for n, s in recording.sensors.items()})


def worst_difference(recording, rate_hz: float = 60.0, reference=None) -> tuple[float, str]:
    """The largest difference [deg] of any reported angle, imported vs simulated."""
    if reference is None:
        t_ref, ref = simulated_angles(rate_hz)
    else:
        est, _ = estimate_recording(reference)
        t_ref, ref = est.t, est.degrees()
    estimates, _ = estimate_recording(recording)
    assert np.allclose(estimates.t, t_ref, atol=1e-6)
    got = estimates.degrees()
    diffs = {k: float(np.max(np.abs(got[k] - ref[k]))) for k in ref}
    name = max(diffs, key=diffs.get)
    return diffs[name], name


def calibration_of(recording) -> str:
    return "; ".join(f"{p.name} {p.start:g} {p.end:g}" for p in recording.calibration)


# --- units, in one place --------------------------------------------------------------

def test_unit_conversions():
    assert U.g_to_ms2(1.0) == pytest.approx(9.80665)
    assert U.deg_to_rad(180.0) == pytest.approx(math.pi)
    assert U.tesla_to_ut(4.8e-5) == pytest.approx(48.0)
    assert U.gauss_to_ut(0.5) == pytest.approx(50.0)
    assert U.au_to_ut(1.0, 48.0) == pytest.approx(48.0)
    assert U.unit_factor("m/(s^2)", "acc") == 1.0
    assert U.unit_factor("m/s²", "acc") == 1.0
    assert U.unit_factor("g", "acc") == pytest.approx(9.80665)
    assert U.unit_factor("G", "mag") == 100.0  # gauss for a magnetometer
    assert U.unit_factor("(deg/s)", "gyr") == pytest.approx(math.pi / 180)
    assert U.unit_factor("µT", "mag") == 1.0
    assert U.unit_factor("T", "mag") == 1e6
    assert U.unit_factor("local_flux", "mag") == 100.0
    assert U.unit_factor("ms", "time") == 1e-3
    assert U.unit_factor("ns", "time") == 1e-9
    assert U.seconds(3000, 1e-3) == 3.0 and U.seconds(7, 1e-3) == 7 / 1000  # not 7 * 0.001
    assert U.unit_factor("deg/s", "acc") is None  # a unit of another quantity


# --- Movella DOT ------------------------------------------------------------------------

def dot_files(rec, **kw) -> dict[str, SourceFile]:
    return {s: SourceFile(f"{s}_D4CA6EF1{i:04X}.csv",
                          xsens_dot_csv(rec.sensors[s], f"dot{i}", **kw))
            for i, s in enumerate(SENSORS)}


def test_xsens_dot_round_trip_same_angles(tmp_path):
    rec = snapped(session().recording, 10**6)  # SampleTimeFine counts whole µs
    files = dot_files(rec)  # SampleTimeFine starts 80 s before its 32-bit wrap
    result = import_recording([Assignment(s, [f]) for s, f in files.items()], side=rec.side,
                              height_m=rec.height_m, calibration=calibration_of(rec),
                              options=ReadOptions(field_ut=SIM_FIELD_UT))
    for s in SENSORS:
        got = result.recording.sensors[s]
        np.testing.assert_allclose(got.t, rec.sensors[s].t, atol=1e-6)
        np.testing.assert_allclose(got.acc, rec.sensors[s].acc, rtol=1e-9, atol=1e-9)
    worst, name = worst_difference(result.recording, reference=rec)
    print(f"xsens-dot: largest angle difference {worst:.2e} deg ({name})")
    assert worst < TOLERANCE_DEG
    out = tmp_path / "dot.csv"
    write_recording(result.recording, out)
    assert parse_recording(out.read_bytes()).sensors.keys() == rec.sensors.keys()


def test_xsens_dot_unsynced_sensors_placed_by_start_time():
    rec = session().recording
    files = {s: SourceFile(f"{s}.csv", xsens_dot_csv(
        rec.sensors[s], s, synced=False, stf0_us=1000 * (i + 1),
        start_time=f"2024-03-01 09:30:0{2 * i}.250 +0100")) for i, s in enumerate(SENSORS)}
    result = import_recording([Assignment(s, [f]) for s, f in files.items()], side="right",
                              height_m=1.75)
    starts = [float(result.recording.sensors[s].t[0]) for s in SENSORS]
    assert starts == pytest.approx([0.0, 2.0, 4.0])
    assert result.recording.metadata["start_utc"] == "2024-03-01T08:30:00.250Z"


def test_xsens_dot_start_time_forms():
    assert parse_start_time("2021-08-30_17:05:05_000 GMT+8") == pytest.approx(1630314305.0)
    assert parse_start_time("2024-03-01 09:30:00.250 +0100") == pytest.approx(1709281800.25)


def test_xsens_dot_real_export_gravity_up():
    """A public DOT export (Euler + Acc + Gyr, sensor upside down): the reader's
    specific force, turned to the earth frame by the file's own Euler angles (Xsens:
    R = Rz(yaw) Ry(pitch) Rx(roll)), points up with ~9.81 m/s²."""
    source = SourceFile("dot.csv", (FIXTURES / "xsens_dot_rest_euler_acc_gyr.csv").read_bytes())
    (signal,) = read_signals([source])
    assert signal.label == "bei"
    assert len(signal) == 12  # the all-zero first packet dropped
    assert signal.clock == "unix"  # old export: no SyncStatus line
    text = (FIXTURES / "xsens_dot_rest_euler_acc_gyr.csv").read_text().splitlines()[9:]
    euler = np.array([[float(v) for v in line.split(",")[2:5]] for line in text])
    from scipy.spatial.transform import Rotation

    world = Rotation.from_euler("ZYX", euler[:, ::-1], degrees=True).apply(signal.acc)
    print("DOT real rows, specific force in the earth frame:", world.mean(axis=0))
    assert np.all(world[:, 2] > 9.5) and np.all(np.abs(world[:, :2]) < 0.2)
    assert np.allclose(signal.t - signal.t[0], np.arange(12) * 0.008333, atol=1e-6)


def test_xsens_dot_orientation_only_and_delta_modes_refused():
    euler = b"sep=,\nDeviceTag:,a\n\nPacketCounter,SampleTimeFine,Euler_X,Euler_Y,Euler_Z," \
            b"FreeAcc_X,FreeAcc_Y,FreeAcc_Z\n0,1,0,0,0,0,0,0\n"
    with pytest.raises(ImportFailure, match=r"e\.csv, line 4: an orientation-only export.*"
                       r"Rate quantities"):
        read_signals([SourceFile("e.csv", euler)])
    delta = b"sep=,\n\nPacketCounter,SampleTimeFine,dq_W,dq_X,dq_Y,dq_Z,dv[1],dv[2],dv[3]\n"
    with pytest.raises(ImportFailure, match=r"line 3: a delta-quantities export \(dq/dv\)"):
        read_signals([SourceFile("d.csv", delta)])


# --- Shimmer ----------------------------------------------------------------------------

def test_shimmer_round_trip_same_angles():
    rec = snapped(session(50.0).recording, 1000)  # Consensys stamps whole ms
    data = shimmer_csv({"Shimmer_8A1F": rec.sensors["upper_arm"],
                        "Shimmer_40AC": rec.sensors["forearm"],
                        "Shimmer_5E77": rec.sensors["hand"]})
    source = SourceFile("consensys.csv", data)
    result = import_recording([Assignment("upper_arm", [source], "Shimmer_8A1F"),
                               Assignment("forearm", [source], "40AC"),
                               Assignment("hand", [source], "5E77")],
                              side=rec.side, height_m=rec.height_m,
                              calibration=calibration_of(rec))
    worst, name = worst_difference(result.recording, reference=rec)
    print(f"shimmer: largest angle difference {worst:.2e} deg ({name})")
    assert worst < TOLERANCE_DEG
    assert result.recording.metadata["start_utc"] == "2024-03-01T08:30:00.000Z"


def test_shimmer_real_export_gravity_and_units():
    """A public Consensys export (devicely's test data, ';'-separated, no formats row):
    at rest |a| ≈ 9.81 with +Y up, gyroscope deg/s → rad/s, local_flux → µT."""
    source = SourceFile("s.csv", (FIXTURES / "shimmer_rest_semicolon.csv").read_bytes())
    (signal,) = read_signals([source])
    assert signal.label == "Shimmer_40AC"
    norms = np.linalg.norm(signal.acc, axis=1)
    print("Shimmer real rows |a|:", norms.mean(), "mean a:", signal.acc.mean(axis=0))
    assert np.all(np.abs(norms - 9.81) < 0.5) and np.all(signal.acc[:, 1] > 9.5)
    assert signal.gyr[0, 1] == pytest.approx(1.8778625954198473 * math.pi / 180)
    assert signal.mag[0, 1] == pytest.approx(-91.60419790104948)
    assert signal.epoch + signal.t[0] == pytest.approx(1595933810.034)
    assert list(signal.lines[:2]) == [4, 5]


# --- APDM Opal .h5 -----------------------------------------------------------------------

def test_apdm_round_trip_same_angles(tmp_path):
    pytest.importorskip("h5py")
    rec = snapped(session(128.0).recording, 10**6)  # Opals: 128 Hz, Time in whole µs
    path = tmp_path / "20240301-093000_Walk.h5"
    apdm_h5(path, {"1234": ("Right Upper Arm", rec.sensors["upper_arm"]),
                   "2345": ("Right Forearm", rec.sensors["forearm"]),
                   "3456": ("Right Hand", rec.sensors["hand"])})
    source = SourceFile(str(path), path.read_bytes())
    result = import_recording([Assignment("upper_arm", [source], "Right Upper Arm"),
                               Assignment("forearm", [source], "2345"),
                               Assignment("hand", [source], "Hand")],
                              side=rec.side, height_m=rec.height_m,
                              calibration=calibration_of(rec))
    worst, name = worst_difference(result.recording, reference=rec)
    print(f"apdm: largest angle difference {worst:.2e} deg ({name})")
    assert worst < TOLERANCE_DEG


def test_apdm_old_version_and_missing_dataset_refused(tmp_path):
    h5py = pytest.importorskip("h5py")
    old = tmp_path / "old.h5"
    with h5py.File(old, "w") as f:
        f.attrs["FileFormatVersion"] = 3
        f.create_group("XI-000123").create_group("Calibrated")
    with pytest.raises(ImportFailure, match=r"old\.h5: no /Sensors group \(file format version "
                       r"3\); armtrack reads APDM file format version\(s\) 5"):
        read_signals([SourceFile(str(old), old.read_bytes())])
    rec = session(128.0).recording
    broken = tmp_path / "broken.h5"
    apdm_h5(broken, {"1234": ("Right Forearm", rec.sensors["forearm"])})
    with h5py.File(broken, "a") as f:
        del f["Sensors/1234/Gyroscope"]
    with pytest.raises(ImportFailure, match=r"broken\.h5:/Sensors/1234: dataset Gyroscope is "
                       "missing"):
        read_signals([SourceFile(str(broken), broken.read_bytes())])
    data = broken.read_bytes()
    with pytest.raises(ImportFailure, match=r"cut\.h5: not a readable HDF5 file, truncated"):
        read_signals([SourceFile("cut.h5", data[: len(data) // 3])])


# --- MetaMotion ----------------------------------------------------------------------------

def test_metamotion_round_trip_same_angles():
    rec = session(100.0).recording
    sources = {s: [SourceFile(n, d) for n, d in metamotion_csvs(
        rec.sensors[s], mac=f"C8CF7A2F32A{i}", epoch_name=("epoc (ms)", "epoch (ms)")[i % 2]
    ).items()] for i, s in enumerate(SENSORS)}
    result = import_recording([Assignment(s, f) for s, f in sources.items()], side=rec.side,
                              height_m=rec.height_m, calibration=calibration_of(rec))
    assert not any(sig.resampled for sig in result.signals.values())
    worst, name = worst_difference(result.recording, 100.0)
    print(f"metamotion: largest angle difference {worst:.2e} deg ({name})")
    assert worst < TOLERANCE_DEG


def test_metamotion_mixed_rates_resampled_scored_against_truth():
    """Gyroscope 200 Hz, accelerometer 100 Hz, magnetometer 25 Hz (MetaBase's usual mix):
    merged onto the gyroscope's times; the angles' error against the simulation's truth
    stays that of the simulated recording."""
    from armtrack.estimator.simulation import SCORED_FROM_S

    sim = simulate(SimulationConfig(rate_hz=200.0, repetitions=2, seed=3))
    rec, truth = sim.recording, sim.truth
    sources = {s: [SourceFile(n, d) for n, d in metamotion_csvs(
        rec.sensors[s], mac=f"C8CF7A2F32A{i}",
        every={"Accelerometer": 2, "Magnetometer": 8}).items()] for i, s in enumerate(SENSORS)}
    result = import_recording([Assignment(s, f) for s, f in sources.items()], side=rec.side,
                              height_m=rec.height_m, calibration=calibration_of(rec))
    assert all(sig.resampled for sig in result.signals.values())

    def error(recording):
        est, _ = estimate_recording(recording)
        got = est.degrees()
        scored = est.t >= SCORED_FROM_S
        worst = 0.0
        for k in ("elbow_flexion", "shoulder_abduction", "forearm_pronation"):
            ref = np.rad2deg(np.interp(est.t, truth.t, truth.angles[k]))
            worst = max(worst, float(np.sqrt(np.mean((got[k] - ref)[scored] ** 2))))
        return worst

    original, imported = error(rec), error(result.recording)
    print(f"metamotion mixed rates: RMS error vs truth {imported:.3f} deg "
          f"(the simulated recording: {original:.3f} deg)")
    assert imported < original + 0.5


# --- Sensor Logger ---------------------------------------------------------------------------

@pytest.mark.parametrize("platform", ["android", "ios"])
def test_sensor_logger_round_trip_same_angles(tmp_path, platform):
    """A phone on the forearm: Accelerometer.csv without gravity plus Gravity.csv, iOS
    signs negated; imported from a zip to the same angles."""
    import zipfile

    sim = simulate(SimulationConfig(rate_hz=100.0, repetitions=2, seed=3, sensors=("forearm",)))
    rec = sim.recording
    files = sensor_logger_files(rec.sensors["forearm"], sim.truth.R_world_sensor["forearm"],
                                platform=platform)
    archive = tmp_path / "2024-03-01_08-30-00.zip"
    with zipfile.ZipFile(archive, "w") as z:
        for name, data in files.items():
            z.writestr(f"2024-03-01_08-30-00/{name}", data)
        z.writestr("2024-03-01_08-30-00/Location.csv", "time,seconds_elapsed,latitude\n")
    from armtrack.estimator.importers.sources import expand

    result = import_recording([Assignment("forearm", expand(archive))], side=rec.side,
                              height_m=rec.height_m, calibration=calibration_of(rec))
    est_ref, _ = estimate_recording(rec)
    est, _ = estimate_recording(result.recording)
    worst = max(float(np.max(np.abs(est.degrees()[k] - est_ref.degrees()[k])))
                for k in est_ref.angles)
    print(f"sensor-logger {platform}: largest angle difference {worst:.2e} deg")
    assert worst < TOLERANCE_DEG


def test_sensor_logger_real_ios_gravity():
    """Public iOS lines (Metadata.csv 'ios', Gravity.csv): after the iOS negation the
    gravity part of the specific force has |g| ≈ 9.81 and the phone lying screen up
    (iOS gravity −z, per Sensor Logger's coordinates page) reads +z."""
    meta = (FIXTURES / "sensor_logger_ios_Metadata.csv").read_bytes()
    grav = (FIXTURES / "sensor_logger_ios_Gravity.csv").read_bytes()
    from armtrack.estimator.importers import sensor_logger

    assert sensor_logger._metadata(SourceFile("Metadata.csv", meta))["platform"] == "ios"
    _, g, _ = sensor_logger._vectors(SourceFile("Gravity.csv", grav))
    force = -g  # the reader's iOS convention
    norms = np.linalg.norm(force, axis=1)
    print("Sensor Logger real iOS gravity, negated:", force.mean(axis=0), norms.mean())
    assert np.all(np.abs(norms - 9.81) < 0.3) and np.all(force[:, 2] > 7.0)


def test_sensor_logger_without_gravity_refused():
    sim = simulate(SimulationConfig(rate_hz=100.0, repetitions=1, seed=3, sensors=("forearm",)))
    files = sensor_logger_files(sim.recording.sensors["forearm"],
                                sim.truth.R_world_sensor["forearm"])
    del files["Gravity.csv"]
    with pytest.raises(ImportFailure, match=r"Accelerometer\.csv, line \d+: sensor Pixel 7: \|a\| "
                       r"at rest is 0\.\d+ m/s², not near 9\.81 \(the accelerometer excludes "
                       r"gravity\)"):
        import_recording([Assignment("forearm", [SourceFile(n, d) for n, d in files.items()])],
                         "right", 1.75)


# --- generic CSV with a column map -------------------------------------------------------------

def test_generic_round_trip_same_angles():
    rec = session(100.0).recording
    files = {s: SourceFile(f"{s}.txt", generic_csv(rec.sensors[s])) for s in SENSORS}
    # one file each: each on its own clock, so one sensor per recording here; the three
    # together come from one file with a sensor column below
    rows = []
    for s in SENSORS:
        text = generic_csv(rec.sensors[s]).decode().splitlines()
        rows += [f"{line};{s}" for line in text[2:]]
    header = generic_csv(rec.sensors["hand"]).decode().splitlines()[1] + ";Device"
    together = SourceFile("all.csv", ("\n".join([header, *rows]) + "\n").encode())
    options = ReadOptions(columns=GENERIC_MAP + " sensor=Device")
    result = import_recording([Assignment(s, [together], s, "generic") for s in SENSORS],
                              side=rec.side, height_m=rec.height_m,
                              calibration=calibration_of(rec), options=options)
    worst, name = worst_difference(result.recording, 100.0)
    print(f"generic: largest angle difference {worst:.2e} deg ({name})")
    assert worst < TOLERANCE_DEG
    with pytest.raises(ImportFailure, match="different clocks"):
        import_recording([Assignment(s, [f], None, "generic") for s, f in files.items()],
                         "right", 1.75, options=ReadOptions(columns=GENERIC_MAP))
    with pytest.raises(ImportFailure, match=r"hand\.txt, line 2: column 'Gyro Z' \(gz\) is "
                       "missing"):
        read_signals([files["hand"]], "generic",
                     ReadOptions(columns=GENERIC_MAP.replace("'Gyr Z'", "'Gyro Z'")))


# --- damaged files: refused naming file, line and problem; nothing written -------------

def test_damaged_missing_column(tmp_path):
    rec = session().recording
    text = xsens_dot_csv(rec.sensors["forearm"], "f").decode()
    text = text.replace("Gyr_X,Gyr_Y,Gyr_Z", "Gyr_X,Gyr_Y,Gyr_Q")
    with pytest.raises(ImportFailure, match=r"f\.csv, line 12: column Gyr_Z is missing"):
        read_signals([SourceFile("f.csv", text.encode())])


def test_damaged_unit_row_that_lies():
    rec = session().recording
    data = shimmer_csv({"Shimmer_40AC": rec.sensors["forearm"]},
                       acc_factor=1 / 9.80665)  # values in g, units row says m/(s^2)
    with pytest.raises(ImportFailure, match=r"s\.csv, line \d+: sensor Shimmer_40AC: \|a\| at "
                       r"rest is 1 m/s², not near 9\.81 \(values look like g, not m/s²\)"):
        import_recording([Assignment("forearm", [SourceFile("s.csv", data)])], "right", 1.75)


def test_damaged_truncated_file():
    rec = session().recording
    data = xsens_dot_csv(rec.sensors["forearm"], "f")
    cut = data[: len(data) - 40]
    lines = cut.decode().count("\n") + 1
    with pytest.raises(ImportFailure, match=rf"f\.csv, line {lines}: \d+ cells where the header "
                       r"has 11: the last line is cut short: the file is truncated"):
        read_signals([SourceFile("f.csv", cut)])


def test_damaged_mixed_rates():
    rec = session().recording
    s = rec.sensors["forearm"]
    from armtrack.estimator.recording import SensorStream

    # the second half at twice the rate: a file that joins two exports
    half = len(s) // 2
    t = np.concatenate([s.t[:half], s.t[half - 1] + np.arange(1, len(s) - half + 1) / 120.0])
    mixed = SensorStream(t, s.acc, s.gyr, s.mag)
    data = xsens_dot_csv(mixed, "f")
    with pytest.raises(ImportFailure, match=r"f\.csv, line \d+: the sample rate changes from "
                       r"60 Hz to 120 Hz"):
        import_recording([Assignment("forearm", [SourceFile("f.csv", data)])], "right", 1.75)


def test_damaged_metamotion_header_that_lies_and_zip_bomb():
    """A MetaMotion accelerometer whose header says g over values in m/s² reads |a| ≈ 96
    at rest and is refused; a zip that unpacks past the limit is refused unopened."""
    import io
    import zipfile

    from armtrack.estimator.importers.sources import expand_upload

    rec = session(100.0).recording
    files = metamotion_csvs(rec.sensors["forearm"])
    name = next(n for n in files if "_Accelerometer_" in n)
    lines = files[name].decode().splitlines()
    lied = [lines[0]] + [",".join(c.split(",")[:3] + [f"{float(v) * 9.80665:.10g}"
                                                         for v in c.split(",")[3:]])
                         for c in lines[1:]]
    files[name] = ("\n".join(lied) + "\n").encode()
    with pytest.raises(ImportFailure, match=r"_Accelerometer_.*, line \d+: sensor C8CF7A2F32A7: "
                       r"\|a\| at rest is 96\.\d m/s², not near 9\.81 \(the unit is wrong\)"):
        import_recording([Assignment("forearm", [SourceFile(n, d) for n, d in files.items()])],
                         "right", 1.75)
    packed = io.BytesIO()
    with zipfile.ZipFile(packed, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("Gyroscope.csv", b"0" * 5_000_000)
    with pytest.raises(ImportFailure, match=r"bomb\.zip: unpacks to 5000000 bytes, more than "
                       "1000000"):
        expand_upload("bomb.zip", packed.getvalue(), limit=1_000_000)


def test_refused_import_writes_nothing(tmp_path, capsys):
    from armtrack.server.cli import main

    rec = session().recording
    good = tmp_path / "ua.csv"
    good.write_bytes(xsens_dot_csv(rec.sensors["upper_arm"], "ua"))
    bad = tmp_path / "fa.csv"
    bad.write_bytes(xsens_dot_csv(rec.sensors["forearm"], "fa")[:-30])
    out = tmp_path / "rec.csv"
    code = main(["import", f"upper_arm={good}", f"forearm={bad}", "--side", "right",
                 "--height", "1.75", "-o", str(out)])
    assert code == 2
    assert "fa.csv, line" in capsys.readouterr().err
    assert sorted(tmp_path.iterdir()) == sorted([good, bad])  # no output, no temporary file


# --- calibration proposal and the command line --------------------------------------------

def test_cli_import_proposes_calibration_then_check_passes(tmp_path, capsys):
    from armtrack.server.cli import main

    rec = session().recording
    paths = []
    for i, s in enumerate(SENSORS):
        p = tmp_path / f"{s}.csv"
        p.write_bytes(xsens_dot_csv(rec.sensors[s], f"dot{i}"))
        paths.append(f"{s}={p}")
    out = tmp_path / "rec.csv"
    assert main(["import", *paths, "--side", "right", "--height", "1.75", "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    print(printed)
    proposal = printed.split('--calibration "')[1].split('"')[0]
    poses = dict((p.split()[0], (float(p.split()[1]), float(p.split()[2])))
                 for p in proposal.split("; "))
    # inside the simulated poses' still periods (N-pose 0–3 s, T-pose ~5–8.5 s)
    assert 0.0 <= poses["npose"][0] < poses["npose"][1] <= 3.1
    assert 4.9 <= poses["tpose"][0] < poses["tpose"][1] <= 8.6
    assert main(["import", *paths, "--side", "right", "--height", "1.75", "--calibration",
                 proposal, "-o", str(out)]) == 0
    capsys.readouterr()
    assert main(["check", str(out)]) == 0
    checked = capsys.readouterr().out
    assert "a valid recording" in checked and "npose" in checked


def test_cli_one_file_several_sensors_by_label(tmp_path, capsys):
    """APDM: --inspect lists the labels; SENSOR=FILE:LABEL picks them; --calibration auto
    takes the proposal; armtrack check passes on the output."""
    pytest.importorskip("h5py")
    from armtrack.server.cli import main

    rec = session(128.0).recording
    path = tmp_path / "walk.h5"
    apdm_h5(path, {"1234": ("Right Upper Arm", rec.sensors["upper_arm"]),
                   "2345": ("Right Forearm", rec.sensors["forearm"]),
                   "3456": ("Right Hand", rec.sensors["hand"])})
    assert main(["import", "--inspect", str(path)]) == 0
    listed = capsys.readouterr().out
    print(listed)
    assert "Right Upper Arm (1234) (apdm), 9 axes, 128 Hz" in listed
    out = tmp_path / "rec.csv"
    assert main(["import", f"upper_arm={path}:Right Upper Arm", f"forearm={path}:2345",
                 f"hand={path}:Hand", "--side", "right", "--height", "1.75",
                 "--calibration", "auto", "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "calibration: npose" in printed
    assert main(["check", str(out)]) == 0
    assert main(["import", f"upper_arm={path}", "--side", "right", "--height", "1.75",
                 "-o", str(out)]) == 2
    assert "holds 3 sensors (Right Upper Arm (1234), Right Forearm (2345), Right Hand " \
        "(3456)); name one with FILE:LABEL" in capsys.readouterr().err


def test_declared_rate_that_lies_refused():
    rec = session().recording
    data = xsens_dot_csv(rec.sensors["forearm"], "f", rate_hz=120)  # stamps are 60 Hz apart
    with pytest.raises(ImportFailure, match=r"f\.csv: the file declares 120 Hz but its time "
                       r"stamps are 60 Hz apart"):
        import_recording([Assignment("forearm", [SourceFile("f.csv", data)])], "right", 1.75)


def test_body_mismatch_said_once_for_every_caller():
    from armtrack.estimator.recording.mismatch import body_mismatch

    assert body_mismatch("right", 1.75, "right", 1.755) == []  # within 1.5 cm
    assert body_mismatch("right", 1.75, None, None) == []  # vendor files say nothing
    assert body_mismatch("left", 1.75, "right", 1.80) == [
        "the file records the right arm; left is the patient's treated arm on record",
        "the file's body height is 1.80 m; the patient's record says 1.75 m (segment "
        "lengths follow the height)"]
    assert body_mismatch("left", 1.75, "left", 1.80, has_lengths=True) == []


@pytest.mark.parametrize("exercise,seed", [("elbow_flexion", 11), ("reach", 5)])
def test_proposed_calibration_scores_like_the_true_windows(exercise, seed):
    """The still periods proposed as poses give joint angles as close to the simulation's
    truth as the simulator's own pose windows do."""
    from dataclasses import replace

    from armtrack.estimator.importers.poses import propose_calibration
    from armtrack.estimator.recording.header import parse_calibration
    from armtrack.estimator.simulation import SCORED_FROM_S

    sim = simulate(SimulationConfig(rate_hz=60.0, seed=seed, exercise=exercise, repetitions=2))

    def rms(recording):
        est, _ = estimate_recording(recording)
        got, scored = est.degrees(), est.t >= SCORED_FROM_S
        return max(float(np.sqrt(np.mean((got[k] - np.rad2deg(np.interp(
            est.t, sim.truth.t, sim.truth.angles[k])))[scored] ** 2)))
            for k in ("elbow_flexion", "shoulder_flexion", "shoulder_abduction",
                      "forearm_pronation"))

    proposal = propose_calibration(sim.recording.sensors)
    proposed = rms(replace(sim.recording, calibration=parse_calibration(proposal)))
    true_windows = rms(sim.recording)
    print(f"{exercise}: proposal {proposal!r}: RMS vs truth {proposed:.3f} deg "
          f"(the simulator's windows: {true_windows:.3f} deg)")
    assert proposed <= true_windows + 0.05


def test_apdm_reader_that_does_not_finish_is_stopped_and_named(tmp_path, monkeypatch):
    """Each .h5 is read in a process of its own (a crafted file can crash libhdf5); one
    that does not finish in its time (a file made to loop the library, a machine too busy)
    is stopped and the file refused by name — it must not hold a server's worker, nor
    leave its process behind. The limit is cut to 0 s here: no reader answers the moment
    it is started (a warm machine reads this file in ~30 ms, so any positive limit races)."""
    import multiprocessing

    from armtrack.estimator.importers import apdm

    pytest.importorskip("h5py")
    rec = session(128.0).recording
    path = tmp_path / "slow.h5"
    apdm_h5(path, {"1234": ("Right Forearm", rec.sensors["forearm"])})
    monkeypatch.setattr(apdm, "READ_TIME_LIMIT_S", 0.0)
    with pytest.raises(ImportFailure, match=r"slow\.h5: reading it took longer than 0 s"):
        read_signals([SourceFile(str(path), path.read_bytes())])
    assert not multiprocessing.active_children()


def test_apdm_readers_at_once_are_bounded(tmp_path):
    """Each .h5 reader is a process of its own (~100 MB with numpy and h5py): many uploads
    at once must not start as many processes (a server's 40 workers would be 40 of
    them); at most ``READERS_AT_ONCE`` run, the others wait their turn and still read."""
    import multiprocessing
    import threading
    import time

    from armtrack.estimator.importers import apdm

    pytest.importorskip("h5py")
    rec = session(128.0).recording
    path = tmp_path / "one.h5"
    apdm_h5(path, {"1234": ("Right Forearm", rec.sensors["forearm"])})
    data = path.read_bytes()
    results, most = [], 0
    threads = [threading.Thread(target=lambda: results.append(
        read_signals([SourceFile("one.h5", data)]))) for _ in range(5)]
    for thread in threads:
        thread.start()
    while any(thread.is_alive() for thread in threads):
        most = max(most, sum(p.name == "armtrack-h5-reader"
                             for p in multiprocessing.active_children()))
        time.sleep(0.01)
    print(f"5 reads at once: at most {most} reader processes, {len(results)} read")
    assert len(results) == 5
    assert 1 <= most <= apdm.READERS_AT_ONCE
