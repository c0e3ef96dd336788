"""numba for armtrack's compiled kernels, in one place: optional, and cached where a later
install cannot trip over it.

Without numba each kernel keeps its pure-Python twin (the same numbers, slower). Kernels
are cached on disk (``cache=True``). numba puts the cache beside the source
(``__pycache__/*.nbi``, ``*.nbc``); for an installed copy (``pip install .``) that is inside
site-packages, and pip does not remove those files when it replaces the package: the
folders left behind then hide an editable install of the checkout (README's "Run it" then
"Test it" in one ``.venv``: every test failed to import). An installed copy therefore
caches under the user's cache folder (``$XDG_CACHE_HOME`` or ``~/.cache``,
``armtrack/numba``) unless ``NUMBA_CACHE_DIR`` says otherwise; a checkout keeps numba's
default."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

#: Folders whose name says the package was installed into them, not checked out there.
_INSTALLED_INTO = {"site-packages", "dist-packages"}


def installed_cache_dir() -> Path:
    """Where an installed armtrack's compiled kernels are cached (a folder)."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "armtrack" / "numba"


def compiler(**options) -> Callable | None:
    """``numba.njit(cache=True, **options)``, or None without numba (the caller then keeps
    its pure-Python function)."""
    try:
        import numba
    except ImportError:
        return None
    if (not numba.config.CACHE_DIR and not os.environ.get("NUMBA_CACHE_DIR")
            and _INSTALLED_INTO & set(Path(__file__).resolve().parts)):
        numba.config.CACHE_DIR = str(installed_cache_dir())
    return numba.njit(cache=True, **options)
