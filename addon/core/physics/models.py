"""The cloth models of the core and the one entry point that simulates them.

``simulate`` runs a population of candidates of a model on a scenario with the fastest backend
available: the numba kernels (``*_kernels``) or the numpy reference code they are tested against.
"""
from __future__ import annotations

from .. import defaults as D
from ..errors import ClothFitError
from . import jit, paper_kernels
from .paper import SimResult, _as_params, simulate_numpy
from .scenario import Scenario


def simulate(scenario: Scenario, params, backend: str = "auto", safety: float = D.DT_SAFETY) -> SimResult:
    """Simulate a population; ``params`` is one or many (m, k, l, d). See the module doc.
    ``safety`` scales the time step (``dt <= safety * sqrt(m/k)``); synthetic ground truth uses a
    finer step than the fitter (``defaults.TRUTH_DT_SAFETY``)."""
    P = _as_params(params)
    if backend == "auto":
        backend = "numba" if jit.available() else "numpy"
    if backend == "numba":
        return paper_kernels.simulate(scenario, P, safety)
    if backend != "numpy":
        raise ClothFitError(f"unknown simulation backend {backend!r} (numpy, numba, auto)")
    return simulate_numpy(scenario, P, safety)
