"""Scores of a parameter set on a capture: silhouette error per image, shape error where known.

A fit's result scores any take of the cloth (``for_take``): a take the fit saw with the manipulation it fitted
there (its time offset, its handles' offsets); a take it never saw with that take's own declared handles and
release, the fitted settings, and the take's own frame rate (Blender's cloth: its real-time Speed Multiplier,
the same cloth in physical time)."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import ClothFitError
from ..observation.frame_rate import frame_rate_from_times
from ..observation.metrics import shape_error_mm
from ..physics.models import model_and_row
from ..physics.scenario import fitted_scenario
from .checkpoint import capture_hash
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
    params, manipulation = for_take(capture, params)
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
        "manipulation": manipulation,
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


UNSEEN = (
    "declared: a take the fit never saw (its own handles and release, the fitted settings; its unknowns not fitted)"
)
MANIPULATION_KEYS = ("time_offset_s", "handles")


def capture_rate(capture: Capture) -> float | None:
    """A capture's frame rate: its model's, else read from its frame times (None when they do not say)."""
    m = getattr(capture, "model", None)
    if isinstance(m, dict) and m.get("fps"):
        return float(m["fps"])
    return frame_rate_from_times(capture.frame_times)[0]


def for_take(capture: Capture, params: Any) -> tuple[Any, str]:
    """(the parameters that replay ``params`` on ``capture``, how its manipulation is read). A fit's result (of
    one take or several) replays a take it fitted with the manipulation it fitted there, at that take's frame
    rate; any other take with the take's own declared manipulation, at the take's own frame rate (Blender's
    cloth: the Speed Multiplier scaled with it, the same cloth in physical time). Anything else (bare settings,
    paper m, k, l, d) is replayed as it is."""
    if not isinstance(params, dict) or "capture_hash" not in params:
        return params, "declared"
    h = capture_hash(capture)
    base = {k: v for k, v in params.items() if k not in MANIPULATION_KEYS and k != "takes"}
    for e in params.get("takes") or []:
        if isinstance(e, dict) and e.get("capture_hash") == h:
            base.update({k: e[k] for k in MANIPULATION_KEYS if k in e})
            return at_rate(base, e.get("fps")), f"fitted: take {e.get('take')} of the fit"
    if not params.get("takes") and params["capture_hash"] == h:
        return params, "fitted" if any(k in params for k in MANIPULATION_KEYS) else "declared"
    return at_rate(base, capture_rate(capture)), UNSEEN


def at_rate(params: dict, fps: float | None) -> dict:
    """A Blender-cloth result moved to a scene at ``fps`` (its Speed Multiplier times its own rate over ``fps``:
    the same cloth in physical time); as it is for another model, no rate, or its own rate."""
    bc, scene = params.get("blender_cloth"), params.get("blender_scene") or {}
    own = scene.get("fps")
    if not isinstance(bc, dict) or not fps or not own or abs(float(own) - fps) <= 1e-9 * fps:
        return params
    out = dict(params, blender_scene=dict(scene, fps=float(fps)))
    if "time_scale" in bc:
        out["blender_cloth"] = dict(bc, time_scale=float(bc["time_scale"]) * float(own) / fps)
    if isinstance(params.get("model"), dict):
        out["model"] = dict(params["model"], fps=float(fps))
    return out
