"""The jitter floor of a take, measured at the fit itself: no truth needed.

A cloth that flaps, folds over or swings is chaotic: settings a part in 10^7 apart give visibly different
silhouettes a second later. On such a take even the cloth's own settings cannot score the images' noise floor
``F`` (``observation/floor.py``): their neighbours score ``F + J``, where ``J`` is how far two such neighbours'
silhouettes lie apart. ``J`` needs no truth: it is measured at the fit.

``jitter(fit, x, objective, silhouettes)`` simulates ``JITTER_SAMPLES`` points a part in ``JITTER_RELATIVE``
from the fit's settings ``x`` (``SearchSpace.neighbours``: every free setting moved, random signs; the
manipulation's unknowns as fitted) and
scores each against the fit's own clean silhouettes, image by image, in the units of ``E_sil`` (the XOR over the
observed silhouette's area): ``J`` per neighbour, in % per image. The result's floor block states ``F + J`` at
its 10th, 50th and 90th percentiles beside the noise floor, and a fit whose error is within ``F + J`` at
``JITTER_QUANTILE`` is at the floor its take allows (``diagnose.report``).

Checked on five captures with known truth (``lab/search_ab.py --jitter-check``, docs/search.md): at the truth,
``F + J`` reproduces the spread of the truth's own neighbours' errors within a few percent.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .. import defaults as D
from ..errors import ClothFitError
from .objective import SilhouetteObjective


def jitter(fit: Any, x: np.ndarray, objective: SilhouetteObjective, silhouettes: list | None) -> dict | None:
    """``{"samples", "relative", "pct": [J of each neighbour, % per image]}`` for a fit (``FitJob`` or
    ``TakeView``) at coordinates ``x`` on ``objective``'s cameras and frames, whose clean silhouettes there are
    ``silhouettes`` (``diagnose._model_silhouettes``); None where they are missing (a scene evaluator's fit, a
    candidate that explodes) or a silhouette of the fit is empty (the cloth out of view)."""
    if silhouettes is None or D.JITTER_SAMPLES < 2:
        return None
    try:
        own = SilhouetteObjective(
            objective.scenario,
            objective.cameras,
            silhouettes,
            backend=objective.backend,
            model=objective.model,
            ignore=objective.ignore,
        )
    except ClothFitError:  # a silhouette of the fit is empty: no area to measure a difference against
        return None
    X = fit.par.space.neighbours(x, D.JITTER_SAMPLES, D.JITTER_RELATIVE, D.JITTER_SEED)
    rows = fit.par.rows(X[:, : fit.npar])
    off = None if fit.manip is None else fit.manip.offsets(X[:, fit.npar :])
    per, exploded = own.per_image(rows, offsets=off)
    ok = ~exploded & np.all(np.isfinite(per), axis=(1, 2))
    if ok.sum() < 2:
        return None
    # E_sil's own normaliser: the observed silhouette's area, not the fit's
    j = (per[ok] * own.areas[None] / objective.areas[None]).mean(axis=(1, 2))
    return {"samples": int(ok.sum()), "relative": D.JITTER_RELATIVE, "pct": [float(v) for v in 100.0 * j]}


def floor_with_jitter(floor_pct: float, jit: dict | None) -> dict | None:
    """The floor a take allows, ``F + J``, at the 10th, 50th and 90th percentiles of ``jit``'s neighbours
    (``{"p10", "p50", "p90"}`` in % per image), or None without a measurement."""
    if jit is None or floor_pct is None:
        return None
    q = np.quantile(floor_pct + np.asarray(jit["pct"]), (0.1, 0.5, 0.9))
    return {"p10": float(q[0]), "p50": float(q[1]), "p90": float(q[2])}


def allowed(floor_pct: float, jit: dict | None) -> float | None:
    """The error (% per image) at and below which a fit is at the floor its take allows: ``F + J`` at
    ``JITTER_QUANTILE``, or None without a measurement."""
    if jit is None or floor_pct is None:
        return None
    return float(np.quantile(floor_pct + np.asarray(jit["pct"]), D.JITTER_QUANTILE))
