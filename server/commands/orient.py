"""``armtrack orient``: one sensor's orientation over time, sensor to earth (ENU)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from armtrack.estimator.errors import InvalidArgument

from .choices import DEFAULT_FILTER, FILTER_NAMES
from .output import open_output

if TYPE_CHECKING:
    import numpy as np

HELP = "one sensor's orientation (quaternion, sensor to earth ENU)"
DESCRIPTION = ("Runs an orientation filter on one IMU: input t,ax,ay,az,gx,gy,gz,mx,my,mz; "
               "output t,qw,qx,qy,qz (R_world_sensor, earth x east, y north, z up).")

COLUMNS = ["t", "ax", "ay", "az", "gx", "gy", "gz", "mx", "my", "mz"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("imu", type=Path, help="CSV with columns " + ",".join(COLUMNS) +
                        " (units as in recordings; mx,my,mz empty for a 6-axis sensor)")
    parser.add_argument("-o", "--output", type=Path, metavar="FILE",
                        help="where to write t,qw,qx,qy,qz (default: standard output)")
    parser.add_argument("--filter", choices=sorted(FILTER_NAMES), default=DEFAULT_FILTER)


def read_imu(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """``t, acc, gyr, mag`` of a one-sensor CSV, checked: the columns, finite numbers, all
    three magnetometer fields empty or none, t non-decreasing."""
    import numpy as np
    import pyarrow as pa
    import pyarrow.csv as pacsv

    with open(path, "rb") as file:
        header = file.readline().decode("utf-8", "replace").strip()
    if header.split(",") != COLUMNS:
        raise InvalidArgument(f"{path}: line 1: expected the columns {','.join(COLUMNS)}, "
                              f"got {header!r}")
    try:
        table = pacsv.read_csv(path, convert_options=pacsv.ConvertOptions(
            column_types=dict.fromkeys(COLUMNS, pa.float64()), null_values=[""],
            strings_can_be_null=False))
    except pa.ArrowInvalid as exc:
        raise InvalidArgument(f"{path}: {exc}") from None
    if table.num_rows == 0:
        raise InvalidArgument(f"{path}: no samples after the header")
    data = {c: table.column(c).to_numpy(zero_copy_only=False) for c in COLUMNS}
    base = np.column_stack([data[c] for c in COLUMNS[:7]])
    bad = ~np.isfinite(base).all(axis=1)
    if bad.any():
        row = int(np.flatnonzero(bad)[0])
        raise InvalidArgument(f"{path}: line {row + 2}: t, ax…gz must be finite numbers")
    mag = np.column_stack([data[c] for c in COLUMNS[7:]])
    present = np.isfinite(mag)
    row_present = present.all(axis=1)
    mixed = (present.any(axis=1) != row_present) | (row_present != row_present[0])
    if mixed.any():
        row = int(np.flatnonzero(mixed)[0])
        raise InvalidArgument(f"{path}: line {row + 2}: mx,my,mz must be all present or all "
                              f"empty, the same on every line")
    t = base[:, 0]
    back = np.flatnonzero(np.diff(t) < 0)
    if back.size:
        row = int(back[0]) + 1
        raise InvalidArgument(f"{path}: line {row + 2}: t goes backwards "
                              f"({t[row]} after {t[row - 1]})")
    return t, base[:, 1:4], base[:, 4:7], mag if row_present[0] else None


def run(args: argparse.Namespace) -> int:
    import numpy as np
    from armtrack.estimator.orientation import make_filter

    t, acc, gyr, mag = read_imu(args.imu)
    q = make_filter(args.filter).update_batch(t, acc, gyr, mag).q
    with open_output(args.output) as out:
        out.write("t,qw,qx,qy,qz\n")
        np.savetxt(out, np.column_stack([t, q]), delimiter=",", fmt=["%.6f"] + ["%.9f"] * 4)
    return 0
