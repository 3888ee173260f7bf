"""Black-box minimisers of the silhouette error: SPX + MGG (the paper's GA) and CMA-ES.

Both optimisers share one *steppable* ask/tell interface, so that the CLI can loop, and a
Blender modal operator can do one generation per timer event and checkpoint in between::

    opt = make_optimizer("spx-mgg", space, seed=1)
    while opt.evaluations < budget:
        X = opt.ask()            # (B, n) candidates, REAL parameter values (decoded)
        f = objective(X)         # (B,) values to MINIMISE; inf / nan allowed
        opt.tell(X, f)
    opt.best_x, opt.best_f       # or simply opt.run(objective, budget)

The optimisers, one per module, each with ``ask`` / ``tell`` / ``stopped`` and an exact-resume
``state_dict`` / ``from_state``:

* :mod:`.space`: :class:`SearchSpace` (bounds, log scale, the unit-cube encoding) and the shared validators;
* :mod:`.steppable`: :class:`Optimizer`, the common ask/tell machinery (best so far, history, checkpoints);
* :mod:`.ga`: :class:`SPXMGG` ("spx-mgg"), the paper's GA;
* :mod:`.evolution_strategy`: :class:`CMAES` ("cma-es"), with active CMA and IPOP restarts;
* :mod:`.portfolio`: :class:`CMAPortfolio` ("cma-portfolio");
* :mod:`.polish`: :class:`CoordinatePolish` ("coord-polish");
* :mod:`.staged`: :class:`StagedCMA` ("cma-staged"), the strong settings first.

This module only names them: :data:`OPTIMIZERS`, :data:`FIT_OPTIMIZERS`, :func:`make_optimizer`,
:func:`optimizer_from_state`.
"""

from __future__ import annotations

from typing import Any

from ..errors import ClothFitError
from .evolution_strategy import CMAES
from .ga import SPXMGG
from .polish import CoordinatePolish
from .portfolio import CMAPortfolio
from .space import SearchSpace
from .staged import StagedCMA
from .steppable import Optimizer

OPTIMIZERS = {
    "spx-mgg": SPXMGG,
    "cma-es": CMAES,
    "cma-portfolio": CMAPortfolio,
    "coord-polish": CoordinatePolish,
    "cma-staged": StagedCMA,
}
# the searches a fit may run (coord-polish is a polish)
FIT_OPTIMIZERS = ("cma-es", "spx-mgg", "cma-portfolio", "cma-staged")
ALIASES = {
    "spx-mgg": "spx-mgg",
    "spx_mgg": "spx-mgg",
    "ga": "spx-mgg",
    "spxmgg": "spx-mgg",
    "cma-es": "cma-es",
    "cma": "cma-es",
    "cma_es": "cma-es",
    "cmaes": "cma-es",
    "cma-portfolio": "cma-portfolio",
    "cma_portfolio": "cma-portfolio",
    "portfolio": "cma-portfolio",
    "coord-polish": "coord-polish",
    "coord_polish": "coord-polish",
    "cma-staged": "cma-staged",
    "cma_staged": "cma-staged",
    "staged": "cma-staged",
}


def canonical_name(name: str) -> str:
    key = str(name).strip().lower()
    if key not in ALIASES:
        raise ClothFitError(
            f"unknown optimiser '{name}': choose one of {', '.join(sorted(ALIASES))} (i.e. {' or '.join(OPTIMIZERS)})"
        )
    return ALIASES[key]


def make_optimizer(name: str, space: SearchSpace, seed: int | None = None, **kw: Any) -> Optimizer:
    """Build an optimiser by name: "spx-mgg" ("ga", "spx_mgg") or "cma-es" ("cma")."""
    return OPTIMIZERS[canonical_name(name)](space, seed=seed, **kw)


def optimizer_from_state(d: dict) -> Optimizer:
    """Resume any optimiser from its ``state_dict()``."""
    if not isinstance(d, dict) or "algorithm" not in d:
        raise ClothFitError("checkpoint: not an optimiser state (no 'algorithm' key)")
    return OPTIMIZERS[canonical_name(d["algorithm"])].from_state(d)
