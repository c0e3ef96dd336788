"""Benchmark: reading and writing a 30-minute recording, side by side with the libraries a
user would pick instead. Run by hand: ``python bench/recording_read.py``. Not a test.

The file: 3 sensors (upper_arm, forearm, hand), 9-axis, 100 Hz, 30 min = 540,000 rows,
written by our writer with values at the shared recordings' resolution (t 0.01 s,
acc 1e-4 m/s², gyr 1e-5 rad/s, mag 1e-3 µT). Ours checks every rule of
spec/recording.md; the others only parse. The "exact" column says whether all 5.4 million
numbers equal ours bit for bit (ours equal Python's float() of the text). pandas is an
optional bench dependency (``pip install pandas``); without it those rows are skipped.
Times are medians of a few runs in one process; the machine's load shows in them.
"""

from __future__ import annotations

import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from armtrack.estimator.recording import Recording, SensorStream, read_recording, write_recording

SENSORS = ("upper_arm", "forearm", "hand")
NUMERIC = ("t", "ax", "ay", "az", "gx", "gy", "gz", "mx", "my", "mz")
RATE_HZ = 100.0
MINUTES = 30
GENFROMTXT_SUBSET = 10  # genfromtxt reads 1/10 of the rows; its time is scaled up


def make_recording(seed: int = 0) -> Recording:
    rng = np.random.default_rng(seed)
    n = int(MINUTES * 60 * RATE_HZ)
    sensors = {}
    for k, name in enumerate(SENSORS):
        t = np.round(np.arange(n) / RATE_HZ + k * 0.001, 4)
        acc = np.round(rng.normal([0, 9.81, 0], 1.5, (n, 3)), 4)
        gyr = np.round(rng.normal(0, 0.8, (n, 3)), 5)
        mag = np.round(rng.normal([20, -40, 10], 3, (n, 3)), 3)
        sensors[name] = SensorStream(t, acc, gyr, mag)
    return Recording("right", sensors, height_m=1.80, rate_hz=RATE_HZ,
                     metadata={"scenario": "bench"})


def timed(fn, repeat: int) -> tuple[float, object]:
    """Median wall time [s] over ``repeat`` runs, and the last result."""
    times, result = [], None
    for _ in range(repeat):
        start = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times), result


def exact(ours: Recording, sensor: np.ndarray, columns) -> str:
    """'yes' if every number equals ours bit for bit, else how many differ."""
    differ = 0
    for name, s in ours.sensors.items():
        rows = sensor == name
        mine = np.column_stack([s.t, s.acc, s.gyr, s.mag])
        for j, column in enumerate(NUMERIC):
            theirs = np.asarray(columns[column], dtype=np.float64)[rows]
            differ += int(np.count_nonzero(theirs.view(np.int64) != mine[:, j].view(np.int64)))
    return "yes" if differ == 0 else f"{differ:,} differ"


def main() -> int:
    rec = make_recording()
    rows = sum(len(s) for s in rec.sensors.values())
    results: list[tuple[str, str, float, str, str]] = []  # task, tool, seconds, exact, note
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "thirty_minutes.csv"
        write_s, _ = timed(lambda: write_recording(rec, path), 3)
        text = path.read_bytes()
        header_lines = text[: text.index(b"t,sensor")].count(b"\n")
        print(f"file: {rows:,} rows, {len(text) / 1e6:.1f} MB, {header_lines} header lines; "
              f"python {sys.version.split()[0]}, numpy {np.__version__}")

        ours_s, ours = timed(lambda: read_recording(path), 5)
        results.append(("read", "armtrack read_recording (all rules checked)", ours_s, "yes", ""))

        dtype = [("t", "f8"), ("sensor", "U9")] + [(c, "f8") for c in NUMERIC[1:]]
        skip = header_lines + 1
        s, arr = timed(lambda: np.loadtxt(path, delimiter=",", skiprows=skip, dtype=dtype), 1)
        results.append(("read", "numpy.loadtxt (structured dtype)", s,
                        exact(ours, arr["sensor"], arr), ""))
        subset = rows // GENFROMTXT_SUBSET
        s, _ = timed(lambda: np.genfromtxt(path, delimiter=",", skip_header=skip,
                                           max_rows=subset, dtype=dtype), 1)
        results.append(("read", "numpy.genfromtxt", s * GENFROMTXT_SUBSET, "",
                        f"timed on {subset:,} rows, x{GENFROMTXT_SUBSET}"))

        try:
            import pandas as pd
        except ImportError:
            pd = None
            print("pandas not installed: pip install pandas (optional bench dependency)")
        if pd is not None:
            types = {"sensor": "category"} | {c: "float64" for c in NUMERIC}
            variants = [("c", None), ("pyarrow", None)]
            for engine, precision in variants:
                options = {"engine": engine, "dtype": types, "skiprows": header_lines}
                if precision:
                    options["float_precision"] = precision
                s, df = timed(lambda o=options: pd.read_csv(path, **o), 3)
                label = f"pandas.read_csv(engine={engine!r}" + (
                    f", float_precision={precision!r})" if precision else ")")
                results.append(("read", label, s,
                                exact(ours, df["sensor"].to_numpy(dtype=str), df), ""))

        results.append(("write", "armtrack write_recording (checked, atomic)", write_s, "", ""))
        if pd is not None:
            out = Path(tmp) / "pandas.csv"
            s, _ = timed(lambda: df.to_csv(out, index=False), 3)
            results.append(("write", "pandas DataFrame.to_csv", s, "", ""))

    print()
    print(f"{'task':<6} {'tool':<58} {'seconds':>8} {'vs ours':>8} {'rows/s':>11}  "
          f"{'exact':<12} note")
    for task, tool, seconds, same, note in results:
        base = ours_s if task == "read" else write_s
        print(f"{task:<6} {tool:<58} {seconds:8.3f} {seconds / base:7.2f}x "
              f"{rows / seconds:11,.0f}  {same:<12} {note}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
