"""numba, when it is there: one switch for every kernel of the core.

The numpy code of each model and of the rasteriser is the reference and runs everywhere (inside
Blender too, which does not ship numba). When numba is importable, the ``*_kernels`` modules
compute the same quantities with the same formulas (tests check the agreement) an order of
magnitude faster, and run the candidates of a population in parallel threads. Set
``CLOTHFIT_NO_NUMBA=1`` to disable them.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any

try:  # pragma: no cover - depends on the environment
    if os.environ.get("CLOTHFIT_NO_NUMBA"):
        raise ImportError("disabled by CLOTHFIT_NO_NUMBA")
    import numba
    from numba import njit, prange

    _HAVE = True
except ImportError:  # pragma: no cover
    numba = None
    _HAVE = False

    def njit(*args: Any, **kwargs: Any) -> Callable[..., Any]:  # the kernels are defined but never called without numba
        if args and callable(args[0]):
            return args[0]
        return lambda f: f

    prange = range

JIT = dict(cache=True, nogil=True, fastmath=False)  # options of every serial kernel
PARALLEL = dict(parallel=True, cache=True, nogil=True)  # options of the population loops


def available() -> bool:
    return _HAVE
