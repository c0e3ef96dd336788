"""The ``armtrack`` command as a user runs it: the installed console script, a real process."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from armtrack.estimator.arm import POINTS, forward_kinematics
from armtrack.estimator.body import SegmentLengths

ARMTRACK = shutil.which("armtrack", path=str(Path(sys.executable).parent)) or "armtrack"


def run(*args, check=True):
    result = subprocess.run([ARMTRACK, *map(str, args)], capture_output=True, text=True,
                            timeout=60)
    if check:
        assert result.returncode == 0, result.stderr
    return result


def test_help_lists_the_commands():
    out = run("--help").stdout
    assert "pose" in out and "check" in out


def test_pose_json_matches_forward_kinematics():
    out = json.loads(run("pose", "--side", "left", "--height", "1.62", "shoulder_flexion=70",
                         "elbow_flexion=30", "--json").stdout)
    pose = forward_kinematics({"shoulder_flexion": np.deg2rad(70), "elbow_flexion": np.deg2rad(30)},
                              "left", SegmentLengths.from_height(1.62))
    for point in POINTS:
        np.testing.assert_allclose(out["positions_m"][point], pose.p_thorax[point], atol=1e-12)
    assert out["shoulder_elevation_deg"] == pytest.approx(70.0)


def test_pose_table_is_readable():
    out = run("pose", "shoulder_abduction=90").stdout
    assert "positions in the thorax frame" in out and "hand" in out


@pytest.mark.parametrize(
    "args, message",
    [
        (["pose", "shoulder_abdction=90"], "unknown joint angle 'shoulder_abdction'"),
        (["pose", "elbow_flexion=abc"], "elbow_flexion: 'abc' is not a number"),
        (["pose", "--height", "17", "elbow_flexion=10"], "body height"),
        (["pose", "--lengths", "0.2,0.3", "elbow_flexion=10"], "--lengths takes four numbers"),
        (["check", "no-such-file.csv"], "no-such-file.csv"),
    ],
)
def test_bad_input_exits_2_with_a_clear_message(args, message):
    result = run(*args, check=False)
    assert result.returncode == 2
    assert message in result.stderr
    assert "Traceback" not in result.stderr


def test_pose_from_truth_angles_csv_reproduces_truth_positions(recordings_dir, tmp_path):
    truth_csv = recordings_dir / "left_reach_50hz.truth.csv"
    out = tmp_path / "positions.csv"
    run("pose", "--angles-csv", truth_csv, "--side", "left", "--height", "1.70", "-o", out)
    got = np.genfromtxt(out, delimiter=",", names=True)
    truth = np.genfromtxt(truth_csv, delimiter=",", names=True)
    worst = max(np.abs(got[c] - truth[c]).max() for c in got.dtype.names)
    print(f"armtrack pose --angles-csv vs truth positions: {worst * 1e3:.4f} mm")
    assert worst < 1e-5


def test_check_summarises_a_shared_recording(recordings_dir):
    out = json.loads(run("check", recordings_dir / "elbow_6axis.csv",
                         "--json").stdout)
    assert out["side"] == "right" and out["height_m"] == 1.8
    assert set(out["sensors"]) == {"upper_arm", "forearm", "hand"}
    assert all(s["axes"] == 6 and s["rate_hz"] == pytest.approx(100.0)
               for s in out["sensors"].values())
    assert [c["pose"] for c in out["calibration"]] == ["npose", "tpose"]


def test_check_refuses_a_broken_file_naming_line_and_rule(tmp_path):
    broken = tmp_path / "broken.csv"
    broken.write_text(
        "# armtrack-recording: 1\n# side: right\n# height_m: 1.80\n"
        "t,sensor,ax,ay,az,gx,gy,gz,mx,my,mz\n"
        "0.00,forearm,0,9.81,0,0,0,0,,,\n"
        "0.01,elbow,0,9.81,0,0,0,0,,,\n")
    result = run("check", broken, check=False)
    assert result.returncode == 2
    assert "line 6" in result.stderr and "elbow" in result.stderr


def test_simulate_writes_a_recording_and_its_truth(tmp_path):
    out = tmp_path / "left.csv"
    printed = run("simulate", "--exercise", "reach", "--side", "left", "--rate", "50",
                  "--six-axis", "--lost", "0.02", "--jitter-ms", "1", "-o", out).stdout
    assert "wrote" in printed
    summary = json.loads(run("check", out, "--json").stdout)
    assert summary["side"] == "left"
    assert all(s["axes"] == 6 and 1.0 < s["lost_percent"] < 3.5 and
               s["rate_hz"] == pytest.approx(50, abs=1) for s in summary["sensors"].values())
    truth = np.genfromtxt(tmp_path / "left.truth.csv", delimiter=",", names=True)
    assert truth["shoulder_flexion"].max() == pytest.approx(80.0, abs=0.1)


def test_simulate_refuses_unknown_sensors(tmp_path):
    result = run("simulate", "--sensors", "upper_arm,elbow", "-o", tmp_path / "x.csv",
                 check=False)
    assert result.returncode == 2 and "unknown sensor(s) ['elbow']" in result.stderr


def test_estimate_writes_angles_and_prints_the_range_of_motion(tmp_path):
    rec = tmp_path / "elbow.csv"
    run("simulate", "--exercise", "elbow_flexion", "--amplitude", "110", "-o", rec)
    out = tmp_path / "angles.csv"
    printed = run("estimate", rec, "-o", out).stdout
    assert "calibration two-pose" in printed and "elbow_flexion" in printed
    table = np.genfromtxt(out, delimiter=",", names=True)
    assert table.dtype.names[:2] == ("t", "clavicle_protraction")
    assert {"shoulder_elevation", "hand_z"} <= set(table.dtype.names)
    truth = np.genfromtxt(tmp_path / "elbow.truth.csv", delimiter=",", names=True)
    elbow = np.interp(truth["t"], table["t"], table["elbow_flexion"])
    rmse = float(np.sqrt(np.mean((elbow - truth["elbow_flexion"])[truth["t"] > 10.5] ** 2)))
    print(f"armtrack estimate: elbow flexion RMSE {rmse:.2f}° against the simulator's truth")
    assert rmse < 1.0
    rom_line = next(line for line in printed.splitlines() if "elbow_flexion" in line)
    assert float(rom_line.split()[3]) == pytest.approx(110, abs=2)  # the range column


def test_orient_matches_the_filter_and_refuses_bad_files(tmp_path):
    from armtrack.estimator.orientation import make_filter
    from armtrack.estimator.simulation import SimulationConfig, simulate

    stream = simulate(SimulationConfig(exercise="reach", seed=3)).recording.sensors["forearm"]
    imu = tmp_path / "imu.csv"
    rows = np.column_stack([stream.t, stream.acc, stream.gyr, stream.mag])
    imu.write_text("t,ax,ay,az,gx,gy,gz,mx,my,mz\n"
                   + "\n".join(",".join(repr(float(v)) for v in row) for row in rows) + "\n")
    out = tmp_path / "q.csv"
    run("orient", imu, "-o", out)
    q = np.loadtxt(out, delimiter=",", skiprows=1)
    expected = make_filter().update_batch(stream.t, stream.acc, stream.gyr, stream.mag).q
    np.testing.assert_allclose(q[:, 1:], expected, atol=1e-8)
    broken = tmp_path / "broken.csv"
    broken.write_text("t,ax,ay,az,gx,gy,gz,mx,my,mz\n0,0,0,9.8,0,0,0,,,\n0.01,0,0,9.8,0,0,0,1,2,\n")
    result = run("orient", broken, check=False)
    assert result.returncode == 2 and "line 3" in result.stderr and "mx,my,mz" in result.stderr
