"""Scores of a parameter set on a capture: silhouette error per image, shape error where known."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import ClothFitError
from ..observation.metrics import shape_error_mm
from ..physics.models import model_and_row
from ..physics.scenario import fitted_scenario
from .job import load_observed
from .objective import SilhouetteObjective

if TYPE_CHECKING:
    from ..observation.capture import Capture


def evaluate(
    capture: Capture,
    params: dict[str, Any],
    cameras: Iterable[int] | None = None,
    times: Iterable[float] | None = None,
    resolution: Sequence[int] | None = None,
    backend: str = "auto",
) -> dict:
    """Mean ``E_sil x 100`` over the images of ``cameras`` (indices) at ``times`` and, if the capture
    has ground-truth shapes, the mean vertex distance [mm] per shape and overall. ``params``: a fit
    result (its model is used), paper m, k, l, d, or ClothSettings values (the capture's model).
    Pixels the capture marks as unknown (ignore masks / ignore labels) are left out of the error
    (``objective``)."""
    model, row = model_and_row(params, getattr(capture, "model", None))
    cams = list(range(len(capture.cameras))) if cameras is None else [int(c) for c in cameras]
    if not cams:
        raise ClothFitError("evaluate: no camera selected")
    times = list(capture.frame_times) if times is None else list(times)
    fidx = [capture.frame_index(t) for t in times]
    tt = [float(capture.frame_times[i]) for i in fidx]
    sc = fitted_scenario(capture.scenario.with_frames(tt), params)  # a result's estimated manipulation
    camobjs, observed, ignore = load_observed(capture, cams, fidx, resolution)
    obj = SilhouetteObjective(sc, camobjs, observed, backend=backend, model=model, ignore=ignore)
    esil, exploded = obj.per_image(row[None])
    out = {
        "model": model.to_dict(),
        "cameras": [capture.cameras[c].name for c in cams],
        "times": tt,
        "exploded": bool(exploded[0]),
        "silhouette_error_pct": float(100 * esil[0].mean()),
        "silhouette_error_pct_per_camera": (100 * esil[0].mean(1)).tolist(),
        "silhouette_error_pct_per_time": (100 * esil[0].mean(0)).tolist(),
    }
    if capture.shapes is not None:
        sim = model.simulate(sc, row[None], backend=backend)
        true = capture.shapes[fidx]
        if sim.exploded[0]:
            se = np.full(len(fidx), np.inf)
        else:
            se = shape_error_mm(sim.positions[0], true)
        out["shape_error_mm"] = float(se.mean())
        out["shape_error_mm_per_time"] = se.tolist()
    return out
