"""Benchmark: our orientation filters on BROAD (real IMU data, optical ground truth), side
by side with VQF and imufusion. Run by hand (not a test; ~10 min on 2 cores, EKF most of it):

    python bench/broad.py [--trials N] [--filters qcf,ekf,euler-cf,vqf,imufusion]
                          [--ekf-every K] [--data DIR] [--out CSV] [--declare-gyro-delay]

Data: the BROAD subset in ``../shared/data/broad`` (30 of the 39 trials of Laidig et al.,
"BROAD — A Benchmark for Robust Inertial Orientation Estimation", Data 6(7), 2021,
CC BY 4.0): ``imu_gyr`` [rad/s], ``imu_acc`` [m/s²], ``imu_mag`` [µT] — already the units
of our filters, so nothing is converted for them — at a constant 285.7 Hz (no timestamps
in the files: ``t = i / sampling_rate``), and ``opt_quat``, the optical orientation
``R_ENU_sensor`` (wxyz), already aligned by BROAD to the IMU's axes and to an ENU frame
whose north is magnetic north.

Error metric: BROAD's own (its ``broad_utils.calculateRMSE``), re-implemented here:
``d = q_est ⊗ q_opt⁻¹`` (the error in the earth frame, both normalised), total error
``2 acos|d_w|``, heading ``2 atan|d_z / d_w|``, inclination ``2 acos √(d_w² + d_z²)``;
RMS over the samples of the ``movement`` mask (the rest phase before the movement, during
which every filter converges, is not scored) with ``nanmean`` (samples where the cameras
lost the marker are skipped); a group's figure is the mean of its trials' RMSE. There is no
alignment step: BROAD's data is already aligned, and its evaluation does not estimate the
IMU-to-marker rotation, a heading offset or any other constant; an ENU estimate is compared
as it is. 6-axis estimates have no magnetic heading: their benchmark figure is the
inclination RMSE only (their heading and total are written to the CSV for completeness;
every trial starts with the sensor flat, its x axis within 5° of east, so a 6-axis filter
that starts with x along world x is heading-aligned by construction, and its "total" error
is mostly heading drift).

Where this deviates from BROAD: 30 of its 39 trials (the 9 longest are not in shared), so
averages are over 30 trials, not BROAD's 39, and its group means (e.g. "undisturbed") miss
the absent trials; every filter runs with one fixed parameter set (its defaults), not
BROAD's TAGP (the grid-searched parameters that minimise the 39-trial mean). The check of
the evaluation: VQF 9D with defaults must give the shared README's 2.43 / 2.27 / 0.72°
(total / heading / inclination) on the 30 trials; the bench prints whether it does.

Filters, all fresh per trial and per mode (9D with the magnetometer, 6D without):

* ``qcf``, ``ekf``, ``euler-cf``: ``armtrack.estimator.orientation.make_filter(name)``,
  ``update_batch(t, acc, gyr, mag)`` (``mag=None`` for 6D). ``ekf`` is a pure-Python loop
  (~0.2 ms/sample, ~9 min for the 30 trials in both modes): ``--ekf-every K`` runs it on
  every K-th trial only, and the averages are then also printed on that subset.
* ``vqf``: ``vqf.VQF(Ts).updateBatch`` (the C++ core), defaults; 9D ``quat9D``, 6D
  ``quat6D`` of a run without magnetometer. ``vqf-offline`` (``vqf.offlineVQF``, non-causal,
  not default) is a reference only; the shared README gives 2.15 / 2.05 / 0.53 for it.
* ``imufusion``: x-io's Fusion AHRS called sample by sample as its examples do (gyroscope
  in °/s, accelerometer in g; ``update`` / ``update_no_magnetometer``), after its gyroscope
  ``Bias`` module; the settings its documentation recommends: gain 0.5, acceleration and
  magnetic rejection 10°, rejection timeout 5 s, gyroscope range 2000 °/s (never reached:
  BROAD peaks at 1446 °/s); ENU. Note: in imufusion 1.3.3 ``AhrsSettings(convention=...)``
  silently keeps NWU; the convention is set as an attribute here and checked. These
  settings give 9.29° (9D total) on the 30 trials, not the shared README's 5.42° for
  "imufusion with its bias module", whose settings it does not give (a 20 s or 60 s
  rejection timeout gives ~5.2-5.5°); imufusion 1.2.11 with the same settings gives the
  same 9.29°.

``--declare-gyro-delay`` adds ``qcf-delay``: ``qcf`` told BROAD's kit's gyroscope delay
behind its accelerometer (``gyro_delay_s``, ``docs/extensions/gyro-delay.md``), measured
as a kit maker would, against the optical reference (``bench/timing.py``'s
``gyro_behind_acc``), and *held out*: each trial is run with the median of the other 29
trials' measurements (leave one out), never its own and never anything fitted to a score.
On the 30 trials every held-out median is 0.65 samples (2.275 ms).

Times: wall time of each filter's run (the numba kernel of ``qcf`` is compiled before the
first trial and its compile time printed apart). CSV: one row per trial, filter and mode.
Optional dependencies: ``vqf``, ``imufusion`` (their rows are skipped when missing);
``scipy`` (required by armtrack) reads the ``.mat`` files.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.io
from armtrack.estimator.orientation import make_filter

HERE = Path(__file__).resolve().parent
DEFAULT_DATA = HERE.parent.parent / "shared" / "data" / "broad"
DEFAULT_OUT = HERE / "results" / "broad.csv"
OURS = ("qcf", "ekf", "euler-cf")
DEFAULT_FILTERS = (*OURS, "vqf", "imufusion")
KNOWN_FILTERS = (*DEFAULT_FILTERS, "vqf-offline", "qcf-delay")
#: The shared README's figures on these 30 trials (total, heading, inclination) [°].
REFERENCE = {"vqf": (2.43, 2.27, 0.72), "vqf-offline": (2.15, 2.05, 0.53)}
REFERENCE_TOLERANCE = 0.03  # [°], the README rounds to hundredths
STANDARD_GRAVITY = 9.80665  # imufusion wants g
MODES = ("9D", "6D")


@dataclass(frozen=True)
class Trial:
    name: str
    rate: float
    t: np.ndarray
    gyr: np.ndarray
    acc: np.ndarray
    mag: np.ndarray
    opt_quat: np.ndarray
    movement: np.ndarray
    groups: tuple[str, ...]

    @property
    def n(self) -> int:
        return self.t.shape[0]


def load_trial(path: Path, groups: tuple[str, ...]) -> Trial:
    mat = scipy.io.loadmat(str(path))
    rate = float(np.asarray(mat["sampling_rate"]).squeeze())
    gyr = np.ascontiguousarray(mat["imu_gyr"], dtype=np.float64)
    n = gyr.shape[0]
    movement = np.asarray(mat["movement"]).reshape(-1).astype(bool)
    if movement.shape != (n,):
        raise ValueError(f"{path.name}: movement has {movement.shape[0]} samples, not {n}")
    return Trial(name=path.stem, rate=rate, t=np.arange(n) / rate, gyr=gyr,
                 acc=np.ascontiguousarray(mat["imu_acc"], dtype=np.float64),
                 mag=np.ascontiguousarray(mat["imu_mag"], dtype=np.float64),
                 opt_quat=np.asarray(mat["opt_quat"], dtype=np.float64),
                 movement=movement, groups=groups)


# --- BROAD's error metric ------------------------------------------------------------------

def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    aw, ax, ay, az = a.T
    bw, bx, by, bz = b.T
    return np.stack([aw * bw - ax * bx - ay * by - az * bz,
                     aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw], axis=1)


def broad_errors(q_est: np.ndarray, q_opt: np.ndarray, movement: np.ndarray
                 ) -> tuple[float, float, float]:
    """Total, heading and inclination RMSE [°] over the movement samples, as BROAD's
    ``calculateRMSE``: NaN samples of the reference skipped."""
    q_est = q_est / np.linalg.norm(q_est, axis=1)[:, None]
    q_opt = q_opt / np.linalg.norm(q_opt, axis=1)[:, None]
    d = quat_multiply(q_est, q_opt * np.array([1.0, -1.0, -1.0, -1.0]))
    d = d / np.linalg.norm(d, axis=1)[:, None]
    w, z = d[movement, 0], d[movement, 3]
    total = 2.0 * np.arccos(np.clip(np.abs(w), 0.0, 1.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        heading = 2.0 * np.arctan(np.abs(z / w))
    inclination = 2.0 * np.arccos(np.clip(np.sqrt(w ** 2 + z ** 2), 0.0, 1.0))

    def rmse_deg(e: np.ndarray) -> float:
        return float(np.rad2deg(np.sqrt(np.nanmean(e ** 2))))

    return rmse_deg(total), rmse_deg(heading), rmse_deg(inclination)


# --- the filters -----------------------------------------------------------------------------

Runner = Callable[[Trial, bool], np.ndarray]  # (trial, use_mag) -> q (N, 4) wxyz ENU


def ours(name: str) -> Runner:
    def run(trial: Trial, use_mag: bool) -> np.ndarray:
        flt = make_filter(name)
        return flt.update_batch(trial.t, trial.acc, trial.gyr, trial.mag if use_mag else None).q
    return run


def declared_delay_runner(delays: dict[str, float]) -> Runner:
    """``qcf`` told the kit's gyroscope delay [s] held out for each trial (``delays``)."""
    def run(trial: Trial, use_mag: bool) -> np.ndarray:
        flt = make_filter("qcf", gyro_delay_s=delays[trial.name])
        return flt.update_batch(trial.t, trial.acc, trial.gyr, trial.mag if use_mag else None).q
    return run


def vqf_runner() -> Runner:
    from vqf import VQF

    def run(trial: Trial, use_mag: bool) -> np.ndarray:
        if use_mag:
            return VQF(1.0 / trial.rate).updateBatch(trial.gyr, trial.acc, trial.mag)["quat9D"]
        return VQF(1.0 / trial.rate).updateBatch(trial.gyr, trial.acc)["quat6D"]
    return run


def vqf_offline_runner() -> Runner:
    from vqf import offlineVQF

    def run(trial: Trial, use_mag: bool) -> np.ndarray:
        if use_mag:
            return offlineVQF(trial.gyr, trial.acc, trial.mag, 1.0 / trial.rate)["quat9D"]
        return offlineVQF(trial.gyr, trial.acc, None, 1.0 / trial.rate)["quat6D"]
    return run


def imufusion_runner() -> Runner:
    import imufusion

    def run(trial: Trial, use_mag: bool) -> np.ndarray:
        settings = imufusion.AhrsSettings(sample_rate=trial.rate, gain=0.5,
                                          gyroscope_range=2000.0, acceleration_rejection=10.0,
                                          magnetic_rejection=10.0, rejection_timeout=5.0)
        settings.convention = imufusion.CONVENTION_ENU  # the constructor ignores it (1.3.3)
        if settings.convention != imufusion.CONVENTION_ENU:
            raise RuntimeError("imufusion did not take the ENU convention")
        ahrs = imufusion.Ahrs()
        ahrs.set_settings(settings)
        bias = imufusion.Bias()
        bias.set_settings(imufusion.BiasSettings(sample_rate=trial.rate))
        gyr = np.rad2deg(trial.gyr)
        acc = trial.acc / STANDARD_GRAVITY
        mag = trial.mag
        q = np.empty((trial.n, 4))
        for i in range(trial.n):
            g = bias.update(gyr[i])
            if use_mag:
                ahrs.update(g, acc[i], mag[i])
            else:
                ahrs.update_no_magnetometer(g, acc[i])
            q[i] = ahrs.get_quaternion()
        return q
    return run


def make_runners(names: list[str], delays: dict[str, float] | None = None
                 ) -> dict[str, Runner]:
    runners: dict[str, Runner] = {}
    for name in names:
        try:
            if name in OURS:
                runners[name] = ours(name)
            elif name == "qcf-delay" and delays is not None:
                runners[name] = declared_delay_runner(delays)
            elif name == "vqf":
                runners[name] = vqf_runner()
            elif name == "vqf-offline":
                runners[name] = vqf_offline_runner()
            elif name == "imufusion":
                runners[name] = imufusion_runner()
        except ImportError as exc:
            print(f"{name}: skipped ({exc.name} is not installed: pip install {exc.name})")
    return runners


def warm_up() -> float:
    """Compile qcf's numba kernel (cached on disk after the first run) outside the timings."""
    start = time.perf_counter()
    rng = np.random.default_rng(0)
    t = np.arange(50) / 100.0
    acc = np.tile([0.0, 0.0, 9.81], (50, 1)) + rng.normal(0, 0.01, (50, 3))
    gyr = rng.normal(0, 0.01, (50, 3))
    mag = np.tile([0.0, 20.0, -40.0], (50, 1))
    make_filter("qcf").update_batch(t, acc, gyr, mag)
    make_filter("qcf").update_batch(t, acc, gyr, None)
    return time.perf_counter() - start


# --- the run ---------------------------------------------------------------------------------

@dataclass
class Result:
    trial: str
    filter: str
    mode: str
    total: float
    heading: float
    inclination: float
    seconds: float
    samples: int
    scored: int
    scored_nan: int

    @property
    def us_per_sample(self) -> float:
        return 1e6 * self.seconds / self.samples


def fmt(value: float, width: int = 7, digits: int = 2) -> str:
    return f"{value:{width}.{digits}f}" if math.isfinite(value) else f"{'-':>{width}}"


def print_trial(results: list[Result], names: list[str]) -> None:
    by = {(r.filter, r.mode): r for r in results}
    print(f"    {'filter':<12} {'9D total':>8} {'heading':>7} {'incl':>7} {'6D incl':>8} "
          f"{'µs/sample 9D':>12} {'6D':>7}")
    for name in names:
        r9, r6 = by.get((name, "9D")), by.get((name, "6D"))
        if r9 is None and r6 is None:
            continue
        nan = float("nan")
        print(f"    {name:<12} {fmt(r9.total if r9 else nan, 8)} "
              f"{fmt(r9.heading if r9 else nan)} {fmt(r9.inclination if r9 else nan)} "
              f"{fmt(r6.inclination if r6 else nan, 8)} "
              f"{fmt(r9.us_per_sample if r9 else nan, 12, 1)} "
              f"{fmt(r6.us_per_sample if r6 else nan, 7, 1)}")


def mean_of(results: list[Result], name: str, mode: str, attr: str,
            trials: set[str] | None = None) -> tuple[float, int]:
    values = [getattr(r, attr) for r in results if r.filter == name and r.mode == mode
              and (trials is None or r.trial in trials)]
    return (float(np.mean(values)), len(values)) if values else (float("nan"), 0)


def print_averages(results: list[Result], names: list[str], trials: set[str] | None,
                   title: str) -> None:
    print(f"\n{title}")
    print(f"  {'filter':<12} {'trials':>6} {'9D total':>8} {'heading':>7} {'incl':>7} "
          f"{'6D incl':>8} {'µs/sample 9D':>12} {'6D':>7}")
    for name in names:
        total, n = mean_of(results, name, "9D", "total", trials)
        if n == 0:
            continue
        heading, _ = mean_of(results, name, "9D", "heading", trials)
        incl, _ = mean_of(results, name, "9D", "inclination", trials)
        incl6, _ = mean_of(results, name, "6D", "inclination", trials)
        us9, _ = mean_of(results, name, "9D", "us_per_sample", trials)
        us6, _ = mean_of(results, name, "6D", "us_per_sample", trials)
        print(f"  {name:<12} {n:>6} {fmt(total, 8)} {fmt(heading)} {fmt(incl)} "
              f"{fmt(incl6, 8)} {fmt(us9, 12, 1)} {fmt(us6, 7, 1)}")


def print_groups(results: list[Result], names: list[str], trials: list[Trial],
                 group_names: list[str]) -> None:
    present = [n for n in names if any(r.filter == n and r.mode == "9D" for r in results)]
    print("\n9D total RMSE [°] by BROAD group (mean over the group's trials run here)")
    print(f"  {'group':<20} {'trials':>6} " + " ".join(f"{n:>11}" for n in present))
    for group in group_names:
        members = {t.name for t in trials if group in t.groups}
        if not members:
            continue
        cells = []
        for name in present:
            value, n = mean_of(results, name, "9D", "total", members)
            note = "" if n in (0, len(members)) else f" ({n})"  # ran on n of the group
            cells.append(f"{fmt(value, 0) + note:>11}")
        print(f"  {group:<20} {len(members):>6} " + " ".join(cells))


def print_gap(results: list[Result], reference: str = "vqf", subject: str = "qcf") -> None:
    names = {r.filter for r in results}
    if subject not in names or reference not in names:
        return
    common = ({r.trial for r in results if r.filter == subject}
              & {r.trial for r in results if r.filter == reference})
    q9, n = mean_of(results, subject, "9D", "total", common)
    v9, _ = mean_of(results, reference, "9D", "total", common)
    q6, _ = mean_of(results, subject, "6D", "inclination", common)
    v6, _ = mean_of(results, reference, "6D", "inclination", common)
    qh, _ = mean_of(results, subject, "9D", "heading", common)
    vh, _ = mean_of(results, reference, "9D", "heading", common)
    qi, _ = mean_of(results, subject, "9D", "inclination", common)
    vi, _ = mean_of(results, reference, "9D", "inclination", common)
    wins = sum(
        1 for t in common
        if mean_of(results, subject, "9D", "total", {t})[0]
        < mean_of(results, reference, "9D", "total", {t})[0])
    print(f"\n{subject} vs {reference} on {n} trials: 9D total {q9:.2f}° vs {v9:.2f}° "
          f"({q9 - v9:+.2f}°, x{q9 / v9:.2f}); 9D heading {qh - vh:+.2f}°, "
          f"9D inclination {qi - vi:+.2f}°; 6D inclination {q6:.2f}° vs {v6:.2f}° "
          f"({q6 - v6:+.2f}°); {subject} better on {wins} of {n} trials")


def check_reference(results: list[Result], n_available: int) -> None:
    for name, expected in REFERENCE.items():
        figures = [mean_of(results, name, "9D", a)
                   for a in ("total", "heading", "inclination")]
        if not figures[0][1]:
            continue
        got = tuple(f for f, _ in figures)
        if figures[0][1] != n_available:
            print(f"check: {name} ran on {figures[0][1]} of {n_available} trials; "
                  f"the README's {expected} are for all of them")
            continue
        ok = all(abs(g - e) <= REFERENCE_TOLERANCE for g, e in zip(got, expected, strict=True))
        print(f"check: {name} 9D {got[0]:.3f} / {got[1]:.3f} / {got[2]:.3f}° vs the README's "
              f"{expected[0]} / {expected[1]} / {expected[2]}°: "
              + ("reproduced" if ok else "NOT REPRODUCED: the evaluation differs"))


def write_csv(results: list[Result], path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    with tmp.open("w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(["trial", "filter", "mode", "total_rmse_deg", "heading_rmse_deg",
                         "inclination_rmse_deg", "seconds", "us_per_sample", "samples",
                         "scored_samples", "scored_nan_samples"])
        for r in results:
            writer.writerow([r.trial, r.filter, r.mode, f"{r.total:.4f}", f"{r.heading:.4f}",
                             f"{r.inclination:.4f}", f"{r.seconds:.3f}",
                             f"{r.us_per_sample:.2f}", r.samples, r.scored, r.scored_nan])
    tmp.replace(path)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--trials", type=int, default=None,
                        help="run the first N trials only (default: all)")
    parser.add_argument("--filters", default=",".join(DEFAULT_FILTERS),
                        help=f"comma-separated, of {', '.join(KNOWN_FILTERS)} "
                             f"(default: {','.join(DEFAULT_FILTERS)})")
    parser.add_argument("--ekf-every", type=int, default=1, metavar="K",
                        help="run ekf on every K-th trial only (it is slow; default 1: all)")
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA,
                        help=f"BROAD folder (default: {DEFAULT_DATA})")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT,
                        help=f"CSV of results (default: {DEFAULT_OUT})")
    parser.add_argument("--declare-gyro-delay", action="store_true",
                        help="also run qcf-delay: qcf told the kit's gyroscope delay, measured "
                             "on the other trials (leave one out, bench/timing.py)")
    args = parser.parse_args(argv)

    names = [n.strip() for n in args.filters.split(",") if n.strip()]
    unknown = sorted(set(names) - set(KNOWN_FILTERS))
    if unknown:
        parser.error(f"unknown filter(s) {', '.join(unknown)}; one of {', '.join(KNOWN_FILTERS)}")
    if args.ekf_every < 1:
        parser.error("--ekf-every must be at least 1")
    info_path = args.data / "trials.json"
    if not info_path.is_file():
        print(f"no BROAD data at {args.data} (trials.json missing); pass --data", file=sys.stderr)
        return 2
    info = json.loads(info_path.read_text())
    paths = sorted(args.data.glob("*.mat"))
    n_available = len(paths)
    if args.trials is not None:
        paths = paths[: args.trials]
    delays = None
    if args.declare_gyro_delay or "qcf-delay" in names:
        import timing  # (bench/timing.py; it imports this module)
        delays = timing.held_out_delays(paths)
        if "qcf-delay" not in names:
            names.insert(names.index("qcf") + 1 if "qcf" in names else 0, "qcf-delay")
        print("gyroscope delay declared to qcf-delay, held out (median of the other trials' "
              "lag behind the accelerometer): "
              f"{min(delays.values()) * 1e3:.3f}–{max(delays.values()) * 1e3:.3f} ms")
    runners = make_runners(names, delays)
    names = [n for n in names if n in runners]

    started = time.perf_counter()
    if "qcf" in runners:
        print(f"qcf: numba kernel ready in {warm_up():.1f} s (compile or cache load, not timed)")
    print(f"{len(paths)} of {n_available} trials from {args.data}; filters: {', '.join(names)}"
          + (f" (ekf on every {args.ekf_every}th trial)" if args.ekf_every > 1 else ""))

    results: list[Result] = []
    trials: list[Trial] = []
    ekf_trials: set[str] = set()
    for index, path in enumerate(paths):
        groups = tuple(info["trials"].get(path.stem, {}).get("groups", ()))
        trial = load_trial(path, groups)
        trials.append(trial)
        scored = int(trial.movement.sum())
        scored_nan = int(np.isnan(trial.opt_quat[trial.movement, 0]).sum())
        print(f"\n[{index + 1:2d}/{len(paths)}] {trial.name}: {trial.n} samples "
              f"({trial.n / trial.rate:.0f} s at {trial.rate:.1f} Hz), {scored} scored "
              f"({100 * scored / trial.n:.0f} %), {scored_nan} of them without reference",
              flush=True)
        trial_results = []
        for name, run in runners.items():
            if name == "ekf":
                if index % args.ekf_every:
                    continue
                ekf_trials.add(trial.name)
            for mode in MODES:
                start = time.perf_counter()
                q = run(trial, mode == "9D")
                seconds = time.perf_counter() - start
                total, heading, incl = broad_errors(q, trial.opt_quat, trial.movement)
                trial_results.append(Result(trial.name, name, mode, total, heading, incl,
                                            seconds, trial.n, scored, scored_nan))
        print_trial(trial_results, names)
        results.extend(trial_results)
        write_csv(results, args.out)  # after every trial, so an interrupted run keeps its rows

    print_averages(results, names, None,
                   "Averages over the trials each filter ran on (RMSE [°]; 6D: inclination "
                   "only; BROAD's metric, movement phase, mean of per-trial RMSE)")
    if "ekf" in runners and 0 < len(ekf_trials) < len(trials):
        print_averages(results, names, ekf_trials,
                       f"The same on ekf's {len(ekf_trials)} trials only")
    print_groups(results, names, trials, [g["name"] for g in info["groups"]])
    print_gap(results)
    if "qcf-delay" in runners:
        print_gap(results, subject="qcf-delay")
    print()
    check_reference(results, n_available)
    print(f"\nwrote {len(results)} rows to {args.out}; "
          f"total time {time.perf_counter() - started:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
