"""Check: a speed change changed no number. Run by hand:
``python bench/same_numbers.py [--base REV] [--tolerance X]``. Not a test.

The estimates of this checkout and of a base revision (default ``main``; a temporary
``git worktree``), each computed in its own fresh process (two versions of one package
cannot share one), on simulated recordings (6- and 9-axis; with and without a trunk, a
swaying trunk at 50 Hz with jitter, forearm and hand, forearm alone, packed samples with
equal stamps, a field disturbed from the start; ``long_session`` 7 minutes) and, when
``../shared/data/recordings`` is there, on some shared ones (``trunk_reach`` also without
its magnetometer). Each recording is estimated whole (batch) and streamed in 10- and
37-row chunks (``feed`` + ``poll``, ``finish``). Every estimate (time, angles, residuals,
positions, segment orientations) is compared; prints the largest difference per case and
exits 1 when one exceeds ``--tolerance`` (default 0: byte-identical, the signs of zeros
included) or a case's shape differs.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
SHARED = REPO.parent / "shared" / "data" / "recordings"

PROBE = r'''
import os, sys
for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[k] = "1"
from dataclasses import replace
from pathlib import Path
import numpy as np
import armtrack.estimator as est
from armtrack.estimator.pipeline import Pipeline, PipelineConfig, estimate_recording
from armtrack.estimator.recording import SensorStream, read_recording
from armtrack.estimator.simulation import SimulationConfig as C, simulate

out_path, shared = sys.argv[1], Path(sys.argv[2])
ARM4 = ("trunk", "upper_arm", "forearm", "hand")
CASES = {
    "elbow9": C(exercise="elbow_flexion", seed=3),
    "elbow6": C(exercise="elbow_flexion", seed=3, nine_axis=False),
    "long9": C(exercise="long_session", seed=1),
    "long6": C(exercise="long_session", seed=2, nine_axis=False),
    "trunk9": C(exercise="trunk_reach", seed=4, sensors=ARM4),
    "trunk6_sway": C(exercise="trunk_reach", seed=5, nine_axis=False, sensors=ARM4,
                     trunk_sway=(8.0, 0.15), rate_hz=50.0, jitter_s=0.002),
    "forearm_hand6": C(exercise="pronation", seed=6, nine_axis=False,
                       sensors=("forearm", "hand")),
    "forearm_only6": C(exercise="elbow_flexion", seed=7, nine_axis=False,
                       sensors=("forearm",)),
    "packed6": C(exercise="shoulder_flexion", seed=8, nine_axis=False, pack_size=4),
    "disturbed9": C(exercise="shoulder_abduction", seed=9, start_disturbance_s=(20.0, 30.0)),
}


def recordings():
    for name, config in CASES.items():
        yield name, simulate(config).recording
    for name in ("elbow_6axis", "trunk_reach", "left_reach_50hz", "pronation"):
        path = shared / f"{name}.csv"
        if not path.exists():
            continue
        recording = read_recording(path)
        yield "shared_" + name, recording
        if name == "trunk_reach":
            yield "shared_trunk_reach_6", replace(recording, sensors={
                n: SensorStream(s.t, s.acc, s.gyr, None) for n, s in recording.sensors.items()})


def flat(e):
    parts = [e.t, *(e.angles[k] for k in sorted(e.angles)),
             *(e.residuals[k] for k in sorted(e.residuals)),
             *(e.positions[k] for k in sorted(e.positions)),
             *(e.R_world_segment[k] for k in sorted(e.R_world_segment))]
    return np.concatenate([np.asarray(p, dtype=np.float64).ravel() for p in parts])


def streamed(rec, rows):
    config = PipelineConfig(side=rec.side, lengths=rec.segment_lengths(),
                            sensors=tuple(rec.sensors), gyro_delay_s=rec.gyro_delay_s)
    pipeline = Pipeline(config, poses=rec.calibration)
    for mark in rec.marks:
        pipeline.add_mark(mark)
    parts = []
    for a in range(0, max(len(s.t) for s in rec.sensors.values()), rows):
        for name, s in rec.sensors.items():
            if len(s.t[a:a + rows]):
                pipeline.feed(name, s.t[a:a + rows], s.acc[a:a + rows], s.gyr[a:a + rows],
                              None if s.mag is None else s.mag[a:a + rows])
        parts.append(pipeline.poll())
    parts.append(pipeline.finish())
    return np.concatenate([flat(e) for e in parts if len(e.t)])


out = {"module": np.array(est.__file__)}
for name, rec in recordings():
    out[name + "/batch"] = flat(estimate_recording(rec)[0])
    for rows in (10, 37):
        out[f"{name}/chunks{rows}"] = streamed(rec, rows)
np.savez(out_path, **out)
'''


def package_root(checkout: Path, into: Path) -> Path:
    """A folder holding ``armtrack/{estimator,server,web}`` linked to ``checkout``'s."""
    root = into / "pkg"
    (root / "armtrack").mkdir(parents=True)
    for part in ("estimator", "server", "web"):
        (root / "armtrack" / part).symlink_to(checkout / part)
    return root


def estimates(root: Path, out: Path) -> dict[str, np.ndarray]:
    env = {**os.environ, "PYTHONPATH": str(root), "NUMBA_CACHE_DIR": str(root / "numba")}
    done = subprocess.run([sys.executable, "-c", PROBE, str(out), str(SHARED)], env=env,
                          capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise SystemExit(f"the probe failed under {root}:\n{done.stderr[-3000:]}")
    result = dict(np.load(out))
    expected = str(root / "armtrack" / "estimator")
    if not str(result.pop("module")).startswith(expected):
        raise SystemExit(f"the probe did not import {expected}: the installed package "
                         "shadows the checkout")
    return result


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--base", default="main", help="base revision (main)")
    parser.add_argument("--tolerance", type=float, default=0.0,
                        help="largest difference allowed (default 0: identical)")
    args = parser.parse_args(argv)
    base_rev = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", args.base],
                              capture_output=True, text=True, check=True).stdout.strip()
    with tempfile.TemporaryDirectory(prefix="armtrack-same-") as tmp:
        tmp_path = Path(tmp)
        base_checkout = tmp_path / "base"
        subprocess.run(["git", "-C", str(REPO), "worktree", "add", "--detach", "-q",
                        str(base_checkout), args.base], check=True)
        try:
            base = estimates(package_root(base_checkout, tmp_path / "b"), tmp_path / "b.npz")
            new = estimates(package_root(REPO, tmp_path / "n"), tmp_path / "n.npz")
        finally:
            subprocess.run(["git", "-C", str(REPO), "worktree", "remove", "--force",
                            str(base_checkout)], check=False)
    print(f"base {base_rev} against this checkout (working tree), {len(new)} estimates")
    failed = False
    for key in sorted(set(base) | set(new)):
        b, n = base.get(key), new.get(key)
        if b is None or n is None or b.shape != n.shape:
            print(f"  {key:<32} only in one, or shapes differ")
            failed = True
            continue
        identical = np.array_equal(b, n, equal_nan=True) and np.array_equal(
            np.signbit(b), np.signbit(n))
        nan_alike = np.array_equal(np.isnan(b), np.isnan(n))
        worst = 0.0 if identical else (float(np.nanmax(np.abs(b - n))) if nan_alike
                                       else np.inf)
        failed |= not identical and (args.tolerance == 0.0 or not worst <= args.tolerance)
        print(f"  {key:<32} {'identical' if identical else f'largest difference {worst:.3g}'}")
    print("FAILED" if failed else "same numbers")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
