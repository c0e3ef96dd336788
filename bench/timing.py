"""Benchmark: how the real data sets' gyroscopes are timed against their optical references,
and what that does to BROAD's inclination score. Run by hand (~2 min; not a test):

    python bench/timing.py [--broad DIR] [--ring DIR] [--no-vqf]

1. **Lag of the gyroscope behind the optical reference**, measured without any filter: the
   optical rate (finite differences of consecutive optical quaternions, at the midpoint of
   each interval, in the sensor frame) against the gyroscope interpolated at ``t + L``;
   the ``L`` (a grid of 0.05 samples over ±3 samples) with the least squared difference is
   the time by which a gyroscope sample lags the rate it measured. BROAD: over the movement
   phase; RING (``../shared/data/ring/chain``, sensor truth as ``bench/ring.py``): where
   |ω| > 0.3 rad/s. The accelerometer's lag likewise: |acc| against |p̈ + g| from the
   optical positions (BROAD's ``opt_pos``; RING: the segment's marker centre, every
   sample whose smoothing window was seen), so the gyroscope's delay behind its own
   accelerometer — a property of the sensor — is told apart from the data set's clocks.
2. **BROAD's 6D inclination with the estimate read later**: qcf's and VQF's 6D estimates
   slerped to ``t + s·dt`` and scored against the optical reference at ``t`` (BROAD's
   metric, ``bench/broad.py``), for s = 0 (the benchmark), ½, 1 and the trial's measured
   lag. An estimator that integrates a lagging gyroscope lags by as much; reading it
   later scores the tilt physics apart from the timing.
3. **VQF at qcf's convention** (with VQF): VQF integrates each interval with the
   interval's own (later) sample, qcf with the mean of its two ends (a sample is the rate
   at its stamp). VQF fed that mean, ``(ω[i−1] + ω[i]) / 2``, integrates as qcf does;
   fed it with qcf's ``tau_acc`` as well, only the two filters' tilt physics (the
   accelerometer correction, rest and bias handling) differ. The gap qcf − VQF (6D
   inclination, s = 0) splits per trial into convention (VQF at qcf's convention − VQF),
   time constant (… with qcf's ``tau_acc`` − … without) and the rest (qcf − both), summed
   by BROAD group.

Prints per-trial lags and the means. Writes nothing.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.io import loadmat

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import broad  # noqa: E402
import ring  # noqa: E402

SHIFTS = (0.0, 0.5, 1.0)  # [samples], besides each trial's measured lag


def optical_rate(q: np.ndarray, dt: float) -> np.ndarray:
    """Body rate [rad/s] (N−1, 3) between consecutive orientations ``q`` (N, 4) wxyz."""
    d = ring.qmul(ring.qinv(q[:-1]), q[1:])
    d *= np.sign(d[:, :1] + (d[:, :1] == 0))
    norm = np.linalg.norm(d[:, 1:], axis=1)
    angle = 2.0 * np.arctan2(norm, d[:, 0])
    return d[:, 1:] / np.maximum(norm, 1e-12)[:, None] * (angle / dt)[:, None]


def gyro_lag(t_gyr: np.ndarray, gyr: np.ndarray, t_opt: np.ndarray, q_opt: np.ndarray,
             use: np.ndarray) -> float:
    """Lag [s] of the gyroscope behind the optical rate (see the module docstring);
    ``use`` (len(t_opt) − 1,) selects the optical intervals scored."""
    dt_opt = float(t_opt[1] - t_opt[0])
    dt_gyr = float(t_gyr[1] - t_gyr[0])
    omega = optical_rate(q_opt, dt_opt)
    t_mid = t_opt[:-1] + 0.5 * dt_opt
    use = use & np.isfinite(omega).all(axis=1)
    best, best_lag = np.inf, 0.0
    for lag in np.arange(-3.0, 3.0001, 0.05) * dt_gyr:
        g = np.column_stack([np.interp(t_mid[use] + lag, t_gyr, gyr[:, k]) for k in range(3)])
        err = float(np.mean(np.sum((g - omega[use]) ** 2, axis=1)))
        if err < best:
            best, best_lag = err, float(lag)
    return best_lag


def acc_lag(t_acc: np.ndarray, acc: np.ndarray, t_opt: np.ndarray, pos: np.ndarray,
            use: np.ndarray, window: int) -> float:
    """Lag [s] of the accelerometer behind the optical positions: |acc| interpolated at
    ``t + L`` against |p̈ + g| (p̈ a cubic Savitzky–Golay second derivative over ``window``
    optical samples, symmetric: no delay of its own; the norm needs no frame), over the
    optical samples ``use`` whose window holds no lost sample. The grid as ``gyro_lag``'s."""
    from scipy.signal import savgol_filter
    dt_opt = float(t_opt[1] - t_opt[0])
    dt_acc = float(t_acc[1] - t_acc[0])
    ok = np.isfinite(pos).all(axis=1)
    p_dd = savgol_filter(np.where(ok[:, None], pos, 0.0), window, 3, deriv=2, delta=dt_opt,
                         axis=0)
    whole = np.convolve(ok, np.ones(window), "same") > window - 0.5
    use = use & ok & whole
    f = np.linalg.norm(p_dd[use] + [0.0, 0.0, 9.81], axis=1)
    a = np.linalg.norm(acc, axis=1)
    best, best_lag = np.inf, 0.0
    for lag in np.arange(-3.0, 3.0001, 0.05) * dt_acc:
        err = float(np.mean((np.interp(t_opt[use] + lag, t_acc, a) - f) ** 2))
        if err < best:
            best, best_lag = err, float(lag)
    return best_lag


def gyro_behind_acc(file: Path) -> float:
    """How far a BROAD trial's gyroscope lags its own accelerometer [samples]: each one's
    lag behind the optical reference (``gyro_lag``, ``acc_lag``; movement phase), the
    difference. A bench measurement of the kit's timing, as ``docs/kit-builder.md`` tells
    a kit maker to make it; no filter runs."""
    trial = broad.load_trial(file, ())
    movement = trial.movement[:-1] & trial.movement[1:]
    gyro = gyro_lag(trial.t, trial.gyr, trial.t, trial.opt_quat, movement)
    pos = np.asarray(loadmat(file)["opt_pos"], dtype=float)
    acc = acc_lag(trial.t, trial.acc, trial.t, pos, trial.movement, 31)
    return (gyro - acc) * trial.rate


def held_out_delays(files: list[Path]) -> dict[str, float]:
    """Trial name → the gyroscope delay [s] BROAD's kit would declare, measured on the
    *other* trials (leave one out: the median of their ``gyro_behind_acc``), so no trial
    is scored with a figure measured on itself and nothing is fitted to a score."""
    lags = {f.stem: gyro_behind_acc(f) for f in files}
    rate = trials_rate(files)
    return {name: float(np.median([v for k, v in lags.items() if k != name])) / rate
            for name in lags}


def broad_part(path: Path, with_vqf: bool) -> None:
    from armtrack.estimator.orientation import make_filter
    from armtrack.estimator.orientation.qcf import QcfParams
    tau_qcf = QcfParams().tau_acc
    files = sorted(path.glob("*.mat"))
    if not files:
        print(f"no BROAD trials at {path}", file=sys.stderr)
        return
    names = ["qcf"] + (["vqf"] if with_vqf else [])
    scores = {n: [] for n in names}
    same = []  # per trial: VQF at qcf's convention, the same with qcf's tau_acc [°]
    lags, acc_lags = [], []
    print(f"{'BROAD trial':<46}{'lag':>7}{'acc':>7}   6D inclination [°] at s = 0, ½, 1, lag")
    for file in files:
        trial = broad.load_trial(file, ())
        movement = trial.movement[:-1] & trial.movement[1:]
        lag = gyro_lag(trial.t, trial.gyr, trial.t, trial.opt_quat, movement) * trial.rate
        lags.append(lag)
        pos = np.asarray(loadmat(file)["opt_pos"], dtype=float)
        acc_lags.append(acc_lag(trial.t, trial.acc, trial.t, pos, trial.movement, 31)
                        * trial.rate)
        line = f"{trial.name:<46}{lag:+7.2f}{acc_lags[-1]:+7.2f}"
        for name in names:
            if name == "qcf":
                q = make_filter("qcf").update_batch(trial.t, trial.acc, trial.gyr, None).q
            else:
                from vqf import VQF
                q = VQF(1.0 / trial.rate).updateBatch(trial.gyr, trial.acc)["quat6D"]
            row = []
            for s in (*SHIFTS, lag):
                shifted = ring.qslerp(trial.t, q, trial.t + s / trial.rate)
                row.append(broad.broad_errors(shifted, trial.opt_quat, trial.movement)[2])
            scores[name].append(row)
            line += f"   {name} " + " ".join(f"{x:.2f}" for x in row)
        if with_vqf:
            same.append([vqf_at_qcf_convention(trial, tau_acc) for tau_acc in (None, tau_qcf)])
            line += "   same convention " + " ".join(f"{x:.2f}" for x in same[-1])
        print(line, flush=True)
    print(f"\nBROAD: the gyroscope lags the optical reference by {np.mean(lags):.2f} samples "
          f"({np.mean(lags) / trials_rate(files) * 1000:.1f} ms) on average "
          f"(trials {min(lags):.2f}…{max(lags):.2f}); its accelerometer by "
          f"{np.median(acc_lags):.2f} (median; trials {min(acc_lags):.2f}…"
          f"{max(acc_lags):.2f}, the tapping ones' impacts the outliers): the gyroscope lags "
          f"its own accelerometer by {np.median(np.subtract(lags, acc_lags)):.2f} samples "
          f"(median of the trials)")
    for name in names:
        mean = np.mean(scores[name], axis=0)
        print(f"  {name} 6D inclination, estimate read s samples later: "
              + ", ".join(f"s={s:g}: {m:.3f}°" for s, m in zip(SHIFTS, mean[:3], strict=True))
              + f", s=lag: {mean[3]:.3f}°")
    if with_vqf:
        print_decomposition([f.stem for f in files], np.array(scores["qcf"])[:, 0],
                            np.array(scores["vqf"])[:, 0], np.array(same))


def vqf_at_qcf_convention(trial, tau_acc: float | None) -> float:
    """BROAD 6D inclination [°] of VQF fed the mean of each interval's two gyroscope
    samples (qcf's trapezoid), with VQF's own ``tauAcc`` or ``tau_acc`` [s]."""
    from vqf import VQF
    gyr = np.array(trial.gyr, dtype=float)
    gyr[1:] = 0.5 * (trial.gyr[1:] + trial.gyr[:-1])
    kwargs = {} if tau_acc is None else {"tauAcc": float(tau_acc)}
    q = VQF(1.0 / trial.rate, **kwargs).updateBatch(
        np.ascontiguousarray(gyr), np.ascontiguousarray(trial.acc, dtype=float))["quat6D"]
    return broad.broad_errors(q, trial.opt_quat, trial.movement)[2]


def print_decomposition(names: list[str], qcf: np.ndarray, vqf: np.ndarray,
                        same: np.ndarray) -> None:
    """The gap qcf − VQF (6D inclination [°], per trial) split into the integration
    convention, the accelerometer time constant and the rest, by BROAD group."""
    convention, tau, rest = same[:, 0] - vqf, same[:, 1] - same[:, 0], qcf - same[:, 1]
    gap = qcf - vqf
    print(f"\nBROAD 6D inclination, mean of {len(names)}: qcf {qcf.mean():.3f}°, VQF "
          f"{vqf.mean():.3f}°, VQF at qcf's convention {same[:, 0].mean():.3f}°, the same "
          f"with qcf's tau_acc {same[:, 1].mean():.3f}°")
    print(f"gap qcf − VQF {gap.mean():+.3f}° = convention {convention.mean():+.3f} + tau_acc "
          f"{tau.mean():+.3f} + the rest {rest.mean():+.3f}")
    groups: dict[str, list[int]] = {}
    for i, name in enumerate(names):
        parts = name.split("_")[1:]
        if parts[-1] in "ABCD" or parts[-1].endswith("cm"):
            parts = parts[:-1]
        groups.setdefault("_".join(parts), []).append(i)
    print(f"{'group':<42}{'n':>3}{'qcf':>7}{'VQF':>7}{'share':>7}"
          f"{'conv.':>8}{'tau':>8}{'rest':>8}   (means of the group's trials [°])")
    for group, index in groups.items():
        ix = np.array(index)
        print(f"{group:<42}{len(ix):>3}{qcf[ix].mean():7.2f}{vqf[ix].mean():7.2f}"
              f"{gap[ix].sum() / gap.sum() * 100:6.0f}%{convention[ix].mean():+8.3f}"
              f"{tau[ix].mean():+8.3f}{rest[ix].mean():+8.3f}")


def trials_rate(files: list[Path]) -> float:
    return broad.load_trial(files[0], ()).rate


def ring_part(path: Path) -> None:
    if not (path / "chain").is_dir():
        print(f"no RING data at {path}", file=sys.stderr)
        return
    print("\nRING: lag of each sensor's gyroscope (and accelerometer, against its segment's "
          "marker centre) behind the optical truth [40 Hz samples]")
    for trial in (1, 2):
        _, omc = ring._read(path / "chain" / f"trial{trial}" / "omc.csv")
        for mounting in ("rigid", "nonrigid"):
            chain = ring.load_chain(path, trial, mounting)
            lags, accs = [], []
            for s in range(1, 6):
                truth = ring.truth_sensor(chain, s)
                imu = chain.imus[s]
                dt_opt = float(chain.t_omc[1] - chain.t_omc[0])
                fast = np.linalg.norm(np.nan_to_num(optical_rate(truth, dt_opt)), axis=1) > 0.3
                lags.append(gyro_lag(imu.t, imu.gyr, chain.t_omc, truth, fast)
                            / float(imu.t[1] - imu.t[0]))
                pos = np.mean([np.column_stack([omc[f"seg{s}_marker{k}_{a}"] for a in "xyz"])
                               for k in range(1, 5)], axis=0)
                accs.append(acc_lag(imu.t, imu.acc, chain.t_omc, pos,
                                    np.ones(len(pos), dtype=bool), 9)
                            / float(imu.t[1] - imu.t[0]))
            print(f"  trial {trial} {mounting:<9}" + " ".join(f"{x:+.2f}" for x in lags)
                  + f"   (median {np.median(lags):+.2f} = {np.median(lags) * 25:+.1f} ms)"
                  + "   accelerometer " + " ".join(f"{x:+.2f}" for x in accs)
                  + f"   (median {np.median(accs):+.2f})")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--broad", type=Path, default=broad.DEFAULT_DATA)
    parser.add_argument("--ring", type=Path, default=ring.DEFAULT_DATA)
    parser.add_argument("--no-vqf", action="store_true")
    args = parser.parse_args(argv)
    with_vqf = not args.no_vqf
    if with_vqf:
        try:
            import vqf  # noqa: F401
        except ImportError:
            with_vqf = False
    broad_part(args.broad, with_vqf)
    ring_part(args.ring)
    return 0


if __name__ == "__main__":
    sys.exit(main())
