"""Unit conversions of vendor exports into the recording's units, in one place.

The recording (``docs``: recording format) holds specific force in m/s², angular rate in
rad/s, magnetic field in µT and time in s. Vendors write g, deg/s, tesla, gauss, an
"arbitrary unit" normalised to the local field, and ms/µs/ns. Every reader converts
through the functions and the unit table here, so a factor exists once.
"""

from __future__ import annotations

import math

import numpy as np

#: Standard gravity [m/s²] (CGPM 1901), the "g" of every vendor that states one
#: (Sensor Logger and MbientLab say 9.80665 explicitly).
STANDARD_GRAVITY = 9.80665

#: Assumed field strength [µT] behind one "arbitrary unit" of a magnetometer normalised to
#: the local field at its calibration (Movella DOT's ``Mag_*`` a.u.). Mid-latitude earth
#: field; only the field's direction matters to the orientation filters, whose magnetic
#: reference is learned from the recording itself.
DEFAULT_FIELD_UT = 50.0

#: Unit → (quantity, factor to the recording's unit). Keys are matched after
#: :func:`normalise_unit` (lower case, no spaces, ``²``→``^2``, ``µ``→``u``).
UNITS: dict[str, tuple[str, float]] = {
    # specific force
    "m/s^2": ("acc", 1.0), "m/(s^2)": ("acc", 1.0), "m/s2": ("acc", 1.0), "ms^-2": ("acc", 1.0),
    "mps2": ("acc", 1.0), "g": ("acc", STANDARD_GRAVITY), "mg": ("acc", STANDARD_GRAVITY / 1000),
    # angular rate
    "rad/s": ("gyr", 1.0), "deg/s": ("gyr", math.pi / 180.0), "dps": ("gyr", math.pi / 180.0),
    "°/s": ("gyr", math.pi / 180.0), "degrees/s": ("gyr", math.pi / 180.0),
    # magnetic field
    "ut": ("mag", 1.0), "microtesla": ("mag", 1.0), "t": ("mag", 1e6), "nt": ("mag", 1e-3),
    "g_mag": ("mag", 100.0), "gauss": ("mag", 100.0), "ga": ("mag", 100.0),
    "mgauss": ("mag", 0.1), "mga": ("mag", 0.1),
    # Shimmer's calibrated magnetometer unit: gauss with Shimmer's default calibration
    # (LSM303 sensitivities in LSB/gauss); see docs/importing.md for what is unclear.
    "local_flux": ("mag", 100.0), "local_flux*": ("mag", 100.0),
    # time
    "s": ("time", 1.0), "ms": ("time", 1e-3), "us": ("time", 1e-6), "ns": ("time", 1e-9),
}


def normalise_unit(text: str) -> str:
    """A unit as written by a vendor, in the form :data:`UNITS` is keyed by."""
    unit = text.strip()
    if unit[:1] in "([" and unit[-1:] in ")]":
        unit = unit[1:-1]  # "(deg/s)", "[g]"
    unit = unit.strip().lower().replace(" ", "")
    return unit.replace("²", "^2").replace("µ", "u").replace("μ", "u").replace("°/s", "deg/s")


def unit_factor(text: str, quantity: str) -> float | None:
    """The factor from ``text`` to the recording's unit of ``quantity`` (``acc``, ``gyr``,
    ``mag``, ``time``), or None when ``text`` is no unit of that quantity."""
    unit = normalise_unit(text)
    if quantity == "mag" and unit == "g":
        unit = "g_mag"  # "G" for a magnetometer is gauss, not standard gravity
    found = UNITS.get(unit)
    if found is None or found[0] != quantity:
        return None
    return found[1]


def seconds(counts, factor: float):
    """Time stamps in a unit of ``factor`` s (ms: 1e-3) → s, by dividing by the whole number
    of counts per second where there is one (``k / 1000`` is the float nearest k ms;
    ``k * 0.001`` can be one bit off, and estimates feel a time's last bit at window edges)."""
    per_second = 1.0 / factor
    if factor < 1.0 and abs(per_second - round(per_second)) < 1e-9 * per_second:
        return np.asarray(counts, dtype=np.float64) / round(per_second)
    return np.asarray(counts, dtype=np.float64) * factor


def g_to_ms2(values) -> np.ndarray:
    """Specific force in g → m/s²."""
    return np.asarray(values, dtype=np.float64) * STANDARD_GRAVITY


def deg_to_rad(values) -> np.ndarray:
    """Angular rate in deg/s → rad/s."""
    return np.asarray(values, dtype=np.float64) * (math.pi / 180.0)


def tesla_to_ut(values) -> np.ndarray:
    """Magnetic field in T → µT."""
    return np.asarray(values, dtype=np.float64) * 1e6


def gauss_to_ut(values) -> np.ndarray:
    """Magnetic field in gauss → µT (1 G = 100 µT)."""
    return np.asarray(values, dtype=np.float64) * 100.0


def au_to_ut(values, field_ut: float = DEFAULT_FIELD_UT) -> np.ndarray:
    """A field normalised to the local field (1 a.u. = that field) → µT, assuming the
    local field was ``field_ut``."""
    return np.asarray(values, dtype=np.float64) * float(field_ut)
