"""Benchmark: armtrack on RING (real IMUs on a moving 5-segment chain, optical truth), beside
VQF in the same run, scored as ``../shared/data/ring/README.md`` says. Run by hand (~1 min
on 2 cores; the tests in ``tests/test_real_data.py`` assert the bars):

    python bench/ring.py [--data DIR] [--out CSV] [--trials 1,2] [--no-vqf]

Every armtrack figure comes twice: **cold** (each recording alone, as today) and with **kit
memory** (``docs/gyro-bias-memory.md``): trial 2 started from the gyroscope biases trial 1
learnt, the same sensors in the same mounting (rigid → rigid, foam → foam, 9D → 9D, 6D →
6D; the RING README's chain: each of the ten IMUs' first-0.6 s mean gyroscope agrees
between the trials within 0.6 mrad/s an axis, and differs between IMUs by mrad/s). Only
biases stillness taught are remembered; never trial 2 → trial 1, never from the truth.
Trial 1 has no earlier session: its kit-memory figures are its cold ones.

Two parts:

* **arm recordings** (``arm/ring_trial{1,2}_{rigid,nonrigid}_{9axis,6axis}.csv``): the whole
  pipeline, ``estimate_recording`` (what ``armtrack estimate`` runs), each angle
  interpolated to the truth's times; RMSE per angle over t ≥ 5 s, truth NaN skipped,
  differences wrapped to ±180°.
* **per joint** (``chain/trial{1,2}/imu_{rigid,nonrigid}.csv`` and ``omc.csv``): one sensor
  at a time through the filter alone, as ``armtrack orient`` runs it
  (``make_filter("qcf").update_batch``, causal), and VQF (``vqf.VQF(Ts).updateBatch``,
  defaults, causal; 9D ``quat9D``, 6D ``quat6D``). Truth: the optical segment orientation
  times A⁻¹, A the IMU→segment rotation fitted from gyroscope vs optical rate (Wahba/SVD,
  first 40 % of the trial, |ω| > 0.3 rad/s). Relative orientation of each joint, error
  ``2 acos|w|`` of ``q_rel,est⁻¹ ⊗ q_rel,true`` at the optical times (the estimate slerped
  there), RMSE over t ≥ 5 s. 6D: the constant initial relative heading (circular mean of
  the heading part of the error over the first 5 s) is removed first, and the heading
  drift is the least-squares slope of the heading error over t ≥ 5 s [°/min]. The bar
  counts the three hinge pairs (seg2–3, seg3–4, seg4–5) of the rigid IMUs; the spherical
  seg1–2 pair and the foam-mounted IMUs are reported too.

Writes ``bench/results/ring.csv`` (one row per item, filter and mode) and prints tables.
"""

from __future__ import annotations

import argparse
import csv
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
DEFAULT_DATA = HERE.parent.parent / "shared" / "data" / "ring"
DEFAULT_OUT = HERE / "results" / "ring.csv"
ANGLES = ("elbow_flexion", "forearm_pronation", "wrist_flexion", "wrist_deviation")
HINGES = ((2, 3), (3, 4), (4, 5))
PAIRS = ((1, 2), *HINGES)
SCORED_FROM_S = 5.0


# --- quaternions (wxyz) -------------------------------------------------------------------

def qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack([aw * bw - ax * bx - ay * by - az * bz,
                     aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw], axis=-1)


def qinv(q: np.ndarray) -> np.ndarray:
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def qslerp(t: np.ndarray, q: np.ndarray, times: np.ndarray) -> np.ndarray:
    """``q`` (N, 4) at ``t`` slerped to ``times`` (held outside)."""
    from scipy.spatial.transform import Rotation, Slerp
    times = np.clip(times, t[0], t[-1])
    return Slerp(t, Rotation.from_quat(q, scalar_first=True))(times).as_quat(scalar_first=True)


def rotation_matrix(q: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation
    return Rotation.from_quat(q, scalar_first=True).as_matrix()


# --- the chain ----------------------------------------------------------------------------

@dataclass(frozen=True)
class Imu:
    t: np.ndarray
    acc: np.ndarray
    gyr: np.ndarray
    mag: np.ndarray  # a.u. as in the file (×49 ≈ µT)


@dataclass(frozen=True)
class ChainTrial:
    name: str
    imus: dict[int, Imu]
    t_omc: np.ndarray
    q_omc: dict[int, np.ndarray]  # segment → world, NaN rows where lost


def _read(path: Path) -> tuple[float, dict[str, np.ndarray]]:
    with open(path) as file:
        rate = float(file.readline().split(":")[1])
        file.readline()
        columns = file.readline().strip().split(",")
    data = np.genfromtxt(path, delimiter=",", skip_header=3, ndmin=2)
    return rate, {c: data[:, k] for k, c in enumerate(columns)}


def load_chain(data: Path, trial: int, mounting: str) -> ChainTrial:
    rate, imu = _read(data / "chain" / f"trial{trial}" / f"imu_{mounting}.csv")
    rate_omc, omc = _read(data / "chain" / f"trial{trial}" / "omc.csv")
    n = len(imu["seg1_acc_x"])
    t = np.arange(n) / rate
    imus = {}
    def cols(s: int, kind: str) -> np.ndarray:
        return np.ascontiguousarray(np.column_stack([imu[f"seg{s}_{kind}_{a}"] for a in "xyz"]))

    for s in range(1, 6):
        imus[s] = Imu(t, cols(s, "acc"), cols(s, "gyr"), cols(s, "mag"))
    m = len(omc["seg1_quat_w"])
    q_omc = {s: np.column_stack([omc[f"seg{s}_quat_{c}"] for c in "wxyz"]) for s in range(1, 6)}
    return ChainTrial(f"trial{trial} {mounting}", imus, np.arange(m) / rate_omc, q_omc)


def imu_to_segment(imu: Imu, t_omc: np.ndarray, q_omc: np.ndarray) -> np.ndarray:
    """A (3, 3), ``gyr ≈ A ω_optical`` (ω in the segment frame), fitted over the first 40 %
    of the trial where |ω| > 0.3 rad/s (Wahba/SVD)."""
    ok = np.isfinite(q_omc).all(axis=1)
    dt = np.diff(t_omc)
    q0, q1 = q_omc[:-1], q_omc[1:]
    d = qmul(qinv(q0), q1)
    d *= np.sign(d[:, :1] + (d[:, :1] == 0))
    angle = 2.0 * np.arctan2(np.linalg.norm(d[:, 1:], axis=1), d[:, 0])
    axis = d[:, 1:] / np.maximum(np.linalg.norm(d[:, 1:], axis=1), 1e-12)[:, None]
    omega = axis * (angle / dt)[:, None]
    t_mid = 0.5 * (t_omc[:-1] + t_omc[1:])
    valid = ok[:-1] & ok[1:] & (t_mid < 0.4 * t_omc[-1])
    gyr = np.column_stack([np.interp(t_mid, imu.t, imu.gyr[:, k]) for k in range(3)])
    use = valid & (np.linalg.norm(omega, axis=1) > 0.3)
    B = gyr[use].T @ omega[use]
    U, _, Vt = np.linalg.svd(B)
    D = np.diag([1.0, 1.0, np.linalg.det(U @ Vt)])
    return U @ D @ Vt


def truth_sensor(trial: ChainTrial, segment: int) -> np.ndarray:
    """q_world_sensor at the optical times: q_world_segment ⊗ A⁻¹ (NaN where lost)."""
    from scipy.spatial.transform import Rotation
    A = imu_to_segment(trial.imus[segment], trial.t_omc, trial.q_omc[segment])
    # gyr_sensor = A ω_segment: A maps segment → sensor coordinates, so R_segment_sensor = Aᵀ
    qa = Rotation.from_matrix(A.T).as_quat(scalar_first=True)
    return qmul(trial.q_omc[segment], qa)


def pair_errors(t: np.ndarray, q_parent: np.ndarray, q_child: np.ndarray,
                true_parent: np.ndarray, true_child: np.ndarray, six_axis: bool
                ) -> tuple[float, float, float]:
    """(RMSE [°], heading drift [°/min] or NaN, inclination RMSE [°]) of one joint's
    relative orientation at times ``t`` (all rows NaN-free)."""
    rel_true = qmul(qinv(true_parent), true_child)
    E = qmul(qmul(q_child, qinv(rel_true)), qinv(q_parent))
    heading = 2.0 * np.arctan2(E[:, 3], E[:, 0])
    drift = float("nan")
    if six_axis:
        first = t < SCORED_FROM_S
        h0 = np.arctan2(np.mean(np.sin(heading[first])), np.mean(np.cos(heading[first])))
        turn = np.column_stack([np.full_like(t, np.cos(-h0 / 2)), 0 * t, 0 * t,
                                np.full_like(t, np.sin(-h0 / 2))])
        q_child = qmul(turn, q_child)
        E = qmul(qmul(q_child, qinv(rel_true)), qinv(q_parent))
        heading = np.unwrap(2.0 * np.arctan2(E[:, 3], E[:, 0]))
    scored = t >= SCORED_FROM_S
    rel_est = qmul(qinv(q_parent), q_child)
    e = qmul(qinv(rel_est), rel_true)
    err = 2.0 * np.arccos(np.clip(np.abs(e[:, 0]), 0.0, 1.0))
    incl = 2.0 * np.arccos(np.clip(np.sqrt(E[:, 0] ** 2 + E[:, 3] ** 2), 0.0, 1.0))
    if six_axis:
        slope = np.polyfit(t[scored] / 60.0, np.rad2deg(heading[scored]), 1)[0]
        drift = float(slope)
    return (float(np.rad2deg(np.sqrt(np.mean(err[scored] ** 2)))), drift,
            float(np.rad2deg(np.sqrt(np.mean(incl[scored] ** 2)))))


def orient_armtrack(imu: Imu, nine: bool, prior=None, learnt: list | None = None
                    ) -> np.ndarray:
    """``armtrack orient``'s estimate (µT for the magnetometer), its filter started from
    ``prior`` [rad/s] (None: zero); the filter's ``LearntGyroBias`` appended to ``learnt``."""
    from armtrack.estimator.orientation import make_filter
    flt = make_filter("qcf", gyr_bias_prior=prior)
    q = flt.update_batch(imu.t, imu.acc, imu.gyr, imu.mag * 49.0 if nine else None).q
    if learnt is not None:
        learnt.append(flt.learnt_bias())
    return q


def orient_vqf(imu: Imu, nine: bool) -> np.ndarray:
    from vqf import VQF
    v = VQF(float(imu.t[1] - imu.t[0]))
    if nine:
        return v.updateBatch(imu.gyr, imu.acc, np.ascontiguousarray(imu.mag * 49.0))["quat9D"]
    return v.updateBatch(imu.gyr, imu.acc)["quat6D"]


FILTERS = {"armtrack": orient_armtrack, "vqf": orient_vqf}


def score_chain(trial: ChainTrial, filters: dict, memory: dict | None = None,
                learnt: dict | None = None) -> list[dict]:
    """Rows: filter, mode, pair, rmse, drift, inclination. ``memory``: (mode, segment) →
    the bias armtrack's filter starts from (kit memory, the filter ``armtrack+memory``);
    ``learnt``, if given, receives (mode, segment) → armtrack's cold ``LearntGyroBias``."""
    truth = {s: truth_sensor(trial, s) for s in range(1, 6)}
    rows = []
    runs = [(name, orient, None) for name, orient in filters.items()]
    if memory is not None:
        runs.insert(1, ("armtrack+memory", orient_armtrack, memory))
    for name, orient, priors in runs:
        for mode in ("9D", "6D"):
            est = {}
            for s in range(1, 6):
                if name == "armtrack":
                    out: list = []
                    q = orient(trial.imus[s], mode == "9D", learnt=out)
                    if learnt is not None:
                        learnt[(mode, s)] = out[0]
                elif priors is not None:
                    q = orient(trial.imus[s], mode == "9D", prior=priors.get((mode, s)))
                else:
                    q = orient(trial.imus[s], mode == "9D")
                est[s] = qslerp(trial.imus[s].t, q, trial.t_omc)
            for parent, child in PAIRS:
                ok = np.isfinite(truth[parent]).all(axis=1) & np.isfinite(truth[child]).all(axis=1)
                rmse, drift, incl = pair_errors(trial.t_omc[ok], est[parent][ok], est[child][ok],
                                                truth[parent][ok], truth[child][ok], mode == "6D")
                rows.append(dict(part="pair", item=f"{trial.name} seg{parent}-seg{child}",
                                 hinge=(parent, child) in HINGES, filter=name, mode=mode,
                                 rmse=rmse, drift=drift, inclination=incl))
    return rows


def _circular_mean(angle: np.ndarray) -> float:
    return float(np.arctan2(np.mean(np.sin(angle)), np.mean(np.cos(angle))))


def _wrap(angle: np.ndarray) -> np.ndarray:
    return (angle + np.pi) % (2.0 * np.pi) - np.pi


def sensor_headings(trial: ChainTrial) -> list[dict]:
    """Per sensor, 9D, t ≥ 5 s: where its field points and how each filter's heading errs.

    The field read with the optical truth orientation (sensor → optical world, µT): its
    heading relative to the chain's north (the circular mean of the five sensors' field
    headings), its dip and norm; each filter's heading error (the turn about the vertical
    of ``q_est ⊗ q_true⁻¹``) about that filter's own north (the circular mean of its five
    sensors' errors, so the optical world's arbitrary north drops out): mean and RMS [°];
    the fraction of samples each filter took the field as disturbed, and the time [s]
    VQF first accepted a reference field (NaN: never)."""
    from armtrack.estimator.orientation import make_filter
    from scipy.spatial.transform import Rotation
    from vqf import VQF
    truth = {s: truth_sensor(trial, s) for s in range(1, 6)}
    field, errors, flags, accepted = {}, {"armtrack": {}, "vqf": {}}, {}, {}
    for s in range(1, 6):
        imu = trial.imus[s]
        q_true = np.column_stack([np.interp(imu.t, trial.t_omc, truth[s][:, k])
                                  for k in range(4)])
        ok = np.isfinite(q_true).all(axis=1) & (imu.t >= SCORED_FROM_S)
        q_true = q_true[ok] / np.linalg.norm(q_true[ok], axis=1)[:, None]
        mag = imu.mag * 49.0
        m_world = Rotation.from_quat(q_true, scalar_first=True).apply(mag[ok])
        field[s] = m_world
        out = make_filter("qcf").update_batch(imu.t, imu.acc, imu.gyr, mag)
        v = VQF(float(imu.t[1] - imu.t[0])).updateBatch(imu.gyr, imu.acc,
                                                         np.ascontiguousarray(mag))
        dist = np.asarray(v["magDistDetected"], dtype=bool)
        flags[s] = (float(np.mean(out.mag_disturbed[ok])), float(np.mean(dist[ok])))
        clean = np.flatnonzero(~dist)
        accepted[s] = float(imu.t[clean[0]]) if clean.size else float("nan")
        for name, q in (("armtrack", out.q), ("vqf", v["quat9D"])):
            E = qmul(q[ok], qinv(q_true))
            errors[name][s] = 2.0 * np.arctan2(E[:, 3], E[:, 0])
    north = _circular_mean(np.concatenate(
        [np.arctan2(m[:, 0], m[:, 1]) for m in field.values()]))
    offsets = {name: _circular_mean(np.concatenate(list(e.values())))
               for name, e in errors.items()}
    rows = []
    for s in range(1, 6):
        m = field[s]
        heading = _wrap(np.arctan2(m[:, 0], m[:, 1]) - north)
        dip = np.arctan2(-m[:, 2], np.hypot(m[:, 0], m[:, 1]))
        row = dict(part="sensor", item=f"{trial.name} seg{s}", mode="9D",
                   field_heading=np.rad2deg(_circular_mean(heading)),
                   field_dip=np.rad2deg(np.mean(dip)),
                   field_norm=float(np.mean(np.linalg.norm(m, axis=1))),
                   armtrack_disturbed=flags[s][0], vqf_disturbed=flags[s][1],
                   vqf_accepted_s=accepted[s])
        for name, e in errors.items():
            about = np.rad2deg(_wrap(e[s] - offsets[name]))
            row[f"{name}_mean"] = float(np.mean(about))
            row[f"{name}_rms"] = float(np.sqrt(np.mean(about ** 2)))
        rows.append(row)
    return rows


# --- the arm recordings -------------------------------------------------------------------

def arm_recordings(data: Path, trials=(1, 2)) -> list[tuple[str, Path, Path]]:
    out = []
    for trial in trials:
        for mounting in ("rigid", "nonrigid"):
            for axes in ("9axis", "6axis"):
                name = f"ring_trial{trial}_{mounting}_{axes}"
                out.append((name, data / "arm" / f"{name}.csv",
                            data / "arm" / f"ring_trial{trial}_{mounting}.truth.csv"))
    return out


def score_arm(recording: Path, truth: Path) -> tuple[dict[str, float], list[str]]:
    """RMSE [°] per angle of ``estimate_recording`` against the truth, and the warnings."""
    scores, warnings, _ = run_arm(recording, truth)
    return scores, warnings


def run_arm(recording: Path, truth: Path, memory: dict | None = None
            ) -> tuple[dict[str, float], list[str], dict]:
    """``score_arm`` of the pipeline started from the kit's ``memory`` (sensor name →
    ``RememberedBias``; None: cold), and the kit's memory after it (``remember``)."""
    from armtrack.estimator.pipeline import run_recording
    from armtrack.estimator.pipeline.bias_memory import priors, remember
    from armtrack.estimator.recording import read_recording
    pipeline = run_recording(read_recording(recording),
                             gyr_bias_priors=priors(memory) if memory else None)
    estimates, calibration = pipeline.finish(), pipeline.calibration
    assert calibration is not None
    kept = remember(memory or {}, pipeline.learnt_biases())
    table = np.genfromtxt(truth, delimiter=",", names=True)
    scored = table["t"] >= SCORED_FROM_S
    out = {}
    for angle in ANGLES:
        est = np.interp(table["t"], estimates.t, np.unwrap(estimates.angles[angle]))
        diff = np.rad2deg(est) - table[angle]
        diff = (diff + 180.0) % 360.0 - 180.0
        use = scored & np.isfinite(diff)
        out[angle] = float(np.sqrt(np.mean(diff[use] ** 2)))
    return out, [w.message for w in calibration.warnings], kept


def arm_with_memory(data: Path, trials=(1, 2)) -> dict[str, dict]:
    """Every arm recording cold and with kit memory: name → {"cold": scores, "memory":
    scores, "warnings": …, "learnt": the kit's memory after the cold run}. Trial 2 starts
    from trial 1's memory of the same mounting and axes; trial 1 has none (memory = cold)."""
    out: dict[str, dict] = {}
    for name, rec, truth in arm_recordings(data, trials):
        cold, warnings, learnt = run_arm(rec, truth)
        out[name] = dict(cold=cold, memory=cold, warnings=warnings, learnt=learnt)
        earlier = name.replace("trial2", "trial1")
        if name.startswith("ring_trial2") and earlier in out:
            out[name]["memory"] = run_arm(rec, truth, out[earlier]["learnt"])[0]
    return out


def remembered_chain(learnt: dict) -> dict:
    """(mode, segment) → the bias kept for the next session: only one stillness taught."""
    return {key: value.bias for key, value in learnt.items() if value.remembered}


# --- the run ------------------------------------------------------------------------------

def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    parser.add_argument("--trials", default="1,2")
    parser.add_argument("--no-vqf", action="store_true")
    parser.add_argument("--skip", choices=("arm", "pairs", "sensors"), action="append",
                        default=[])
    args = parser.parse_args(argv)
    if not (args.data / "arm").is_dir():
        print(f"no RING data at {args.data}", file=sys.stderr)
        return 2
    trials = tuple(int(x) for x in args.trials.split(","))
    rows = []
    start = time.perf_counter()
    if "arm" not in args.skip:
        print("arm recording, RMSE ° cold / with kit memory (trial 2 from trial 1's learnt "
              "biases; trial 1 has no earlier session)")
        print(f"{'':<30}" + "".join(f"{a:>20}" for a in ANGLES))
        for name, result in arm_with_memory(args.data, trials).items():
            cold, memory = result["cold"], result["memory"]
            print(f"{name:<30}" + "".join(f"{cold[a]:11.2f} / {memory[a]:5.2f}" for a in ANGLES),
                  flush=True)
            for a in ANGLES:
                rows.append(dict(part="arm", item=name, hinge="", filter="armtrack", mode="",
                                 rmse=cold[a], drift="", inclination="", angle=a))
                rows.append(dict(part="arm", item=name, hinge="", filter="armtrack+memory",
                                 mode="", rmse=memory[a], drift="", inclination="", angle=a))
    if "pairs" not in args.skip:
        filters = dict(FILTERS)
        if args.no_vqf:
            del filters["vqf"]
        names = ["armtrack", "armtrack+memory", *[f for f in filters if f != "armtrack"]]
        print("\nper joint: RMSE ° (6D: drift °/min) — armtrack cold, with kit memory (trial 2 "
              "only), " + ", ".join(names[2:]))
        print(f"{'pair':<30}{'mode':>5}" + "".join(f"{n:>22}" for n in names))
        learnt: dict[str, dict] = {}
        for trial in trials:
            for mounting in ("rigid", "nonrigid"):
                chain = load_chain(args.data, trial, mounting)
                memory = None
                if trial == 2:
                    if mounting not in learnt:  # trial 1 not run here: learn it silently
                        learnt[mounting] = {}
                        score_chain(load_chain(args.data, 1, mounting),
                                    {"armtrack": orient_armtrack}, learnt=learnt[mounting])
                    memory = remembered_chain(learnt[mounting])
                found = score_chain(chain, filters, memory,
                                    learnt=learnt.setdefault(mounting, {}) if trial == 1 else None)
                rows.extend(found)
                by = {(r["item"], r["mode"], r["filter"]): r for r in found}
                for item, mode in dict.fromkeys((r["item"], r["mode"]) for r in found):
                    cells = []
                    for n in names:
                        r = by.get((item, mode, n))
                        if r is None:
                            cells.append(f"{'(= cold)':>22}")
                        elif mode == "6D":
                            cells.append(f"{r['rmse']:13.2f} ({r['drift']:5.1f})")
                        else:
                            cells.append(f"{r['rmse']:22.2f}")
                    print(f"{item:<30}{mode:>5}" + "".join(cells), flush=True)
        # trial 1 has no earlier session: with kit memory it is its cold self
        rows.extend([{**r, "filter": "armtrack+memory"} for r in list(rows)
                     if r["part"] == "pair" and r["filter"] == "armtrack"
                     and r["item"].startswith("trial1 ")])
        for part, sel in (("rigid hinge pairs (the bar's six)",
                           lambda r: r["hinge"] and "nonrigid" not in r["item"]),
                          ("foam hinge pairs", lambda r: r["hinge"] and "nonrigid" in r["item"])):
            for label, prefix in [*((f"trial {t}", f"trial{t} ") for t in trials),
                                  ("both trials", "trial")]:
                print(f"\nmean over the {label} {part}")
                for f in names:
                    for mode in ("9D", "6D"):
                        chosen = [r for r in rows if r["part"] == "pair" and sel(r)
                                  and r["filter"] == f and r["mode"] == mode
                                  and r["item"].startswith(prefix)]
                        if not chosen:
                            continue
                        drift = (np.mean([abs(r["drift"]) for r in chosen]) if mode == "6D"
                                 else float("nan"))
                        print(f"  {f:<16}{mode}  RMSE {np.mean([r['rmse'] for r in chosen]):6.2f}"
                              f"  drift {drift:5.1f}  incl "
                              f"{np.mean([r['inclination'] for r in chosen]):5.2f}")
    if "sensors" not in args.skip and not args.no_vqf:
        print("\nper sensor, 9D, rigid, t ≥ 5 s: the field in the optical world (heading about "
              "the chain's north, dip, norm) and each filter's heading error about its own "
              "north, mean / RMS [°]; the share of samples taken as disturbed; VQF's first "
              "accepted field [s]")
        print(f"{'sensor':<22}{'field head':>11}{'dip':>6}{'µT':>6}{'armtrack':>16}"
              f"{'vqf':>16}{'disturbed a/v':>15}{'vqf ref':>9}")
        for trial in trials:
            for r in sensor_headings(load_chain(args.data, trial, "rigid")):
                rows.append(r)
                print(f"{r['item']:<22}{r['field_heading']:11.1f}{r['field_dip']:6.1f}"
                      f"{r['field_norm']:6.1f}{r['armtrack_mean']:8.1f} /{r['armtrack_rms']:5.1f}"
                      f"{r['vqf_mean']:8.1f} /{r['vqf_rms']:5.1f}"
                      f"{r['armtrack_disturbed']:8.2f} /{r['vqf_disturbed']:5.2f}"
                      f"{r['vqf_accepted_s']:9.1f}", flush=True)
    print(f"\n{time.perf_counter() - start:.0f} s")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    keys = ["part", "item", "hinge", "filter", "mode", "angle", "rmse", "drift", "inclination",
            "field_heading", "field_dip", "field_norm", "armtrack_mean", "armtrack_rms",
            "vqf_mean", "vqf_rms", "armtrack_disturbed", "vqf_disturbed", "vqf_accepted_s"]
    with open(args.out, "w", newline="") as file:
        writer = csv.DictWriter(file, keys)
        writer.writeheader()
        for row in rows:
            writer.writerow({k: row.get(k, "") for k in keys})
    return 0


if __name__ == "__main__":
    sys.exit(main())
