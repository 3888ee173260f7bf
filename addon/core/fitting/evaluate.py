"""Scores of a parameter set on a capture: silhouette error per image, shape error where known.

A fit's result scores any take of the cloth (``for_take``): a take the fit saw with the manipulation it fitted
there (its time offset, its handles' offsets); a take it never saw with that take's own declared handles and
release, the fitted settings, and the take's own frame rate (Blender's cloth: its real-time Speed Multiplier,
the same cloth in physical time)."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from .. import defaults as D
from ..errors import ClothFitError
from ..observation.metrics import points_to_cloth_m, shape_error_mm
from ..observation.points import capture_points, points_scatter_mm
from ..physics.blender_settings import rate_factor
from ..physics.models import model_and_row
from ..physics.scenario import fitted_scenario
from .checkpoint import capture_hash
from .job import load_observed
from .objective import SilhouetteObjective
from .optimise import make_optimizer
from .parameters import ManipulationParameters, capture_frame_rate
from .space import SearchSpace

if TYPE_CHECKING:
    from ..observation.capture import Capture


def evaluate(
    capture: Capture,
    params: dict[str, Any],
    cameras: Iterable[int] | None = None,
    times: Iterable[float] | None = None,
    resolution: Sequence[int] | None = None,
    backend: str = "auto",
    fit_unknowns: int = 0,
    unknowns_on: tuple[Iterable[int] | None, Iterable[float] | None] | None = None,
) -> dict:
    """Mean ``E_sil x 100`` over the images of ``cameras`` (indices) at ``times`` and, if the capture
    has ground-truth shapes, the mean vertex distance [mm] per shape and overall. ``params``: a fit
    result (its model is used), paper m, k, l, d, or ClothSettings values (the capture's model).
    Pixels the capture marks as unknown (ignore masks / ignore labels) are left out of the error
    (``objective``). ``fit_unknowns``: a take the result never saw has the unknowns its capture declares
    (``uncertain``) fitted on these same images with the settings held, in that many evaluations
    (``held_unknowns``; 0: its declared manipulation as it is). ``unknowns_on``: (cameras, times) to fit them on
    instead (None in either: the scored ones), so that the images scored are not those they were fitted on."""
    params, manipulation = for_take(capture, params)
    model, row = model_and_row(params, getattr(capture, "model", None))
    cams = list(range(len(capture.cameras))) if cameras is None else [int(c) for c in cameras]
    if not cams:
        raise ClothFitError("evaluate: no camera selected")
    times = list(capture.frame_times) if times is None else list(times)
    fidx = [capture.frame_index(t) for t in times]
    tt = [float(capture.frame_times[i]) for i in fidx]
    camobjs, observed, ignore = load_observed(capture, cams, fidx, resolution)
    if fit_unknowns and manipulation == UNSEEN:
        on = (camobjs, observed, ignore, tt)
        if unknowns_on is not None:
            uc = cams if unknowns_on[0] is None else [int(c) for c in unknowns_on[0]]
            uf = fidx if unknowns_on[1] is None else [capture.frame_index(t) for t in unknowns_on[1]]
            if not uc:
                raise ClothFitError("evaluate: no camera to fit the unknowns on")
            on = (*load_observed(capture, uc, uf, resolution), [float(capture.frame_times[i]) for i in uf])
        unknowns = held_unknowns(capture, model, row, *on, backend, fit_unknowns)
        if unknowns is not None:
            params = dict(params, **unknowns)
            manipulation = FITTED_HERE if unknowns_on is None else FITTED_ON_OTHERS
    sc = fitted_scenario(capture.scenario.with_frames(tt), params)  # a result's estimated manipulation
    obj = SilhouetteObjective(sc, camobjs, observed, backend=backend, model=model, ignore=ignore)
    esil, exploded = obj.per_image(row[None])
    out = {
        "model": model.to_dict(),
        "cameras": [capture.cameras[c].name for c in cams],
        "times": tt,
        "manipulation": manipulation,
        "time_offset_s": params.get("time_offset_s") if isinstance(params, dict) else None,
        **({k: params[k] for k in ("time_scale", "handles") if isinstance(params, dict) and params.get(k)}),
        "exploded": bool(exploded[0]),
        "silhouette_error_pct": float(100 * esil[0].mean()),
        "silhouette_error_pct_per_camera": (100 * esil[0].mean(1)).tolist(),
        "silhouette_error_pct_per_time": (100 * esil[0].mean(0)).tolist(),
    }
    points = capture_points(capture, fidx)
    if capture.shapes is not None or points is not None:
        sim = model.simulate(sc, row[None], backend=backend)
        X = None if sim.exploded[0] else sim.positions[0]
    if capture.shapes is not None:
        se = np.full(len(fidx), np.inf) if X is None else shape_error_mm(X, capture.shapes[fidx])
        out["shape_error_mm"] = float(se.mean())
        out["shape_error_mm_per_time"] = se.tolist()
    if points is not None:  # the real points the capture was made from: each one's distance to the cloth
        tri = capture.scenario.grid.triangles
        pm = [
            np.inf if X is None or not len(P) else 1000.0 * float(points_to_cloth_m(P, X[k], tri).mean())
            for k, P in enumerate(points)
        ]
        out["points_mm"] = float(np.mean(pm))
        out["points_mm_per_time"] = pm
        # what a perfect cloth would still score: the points' own scatter about a smooth surface
        out["points_scatter_mm"] = points_scatter_mm(capture, fidx, points)
    return out


UNSEEN = (
    "declared: a take the fit never saw (its own handles and release, the fitted settings; its unknowns not fitted)"
)
FITTED_HERE = (
    "fitted here: a take the fit never saw, its declared unknowns fitted on these same images with the settings "
    "held (an optimistic score: score other cameras or frames for a fair one)"
)
FITTED_ON_OTHERS = (
    "fitted on other images: a take the fit never saw, its declared unknowns fitted with the settings held on the "
    "images given (--unknowns-cameras, --unknowns-times), then these scored"
)
MANIPULATION_KEYS = ("time_offset_s", "handles", "time_scale")


def held_unknowns(
    capture: Capture,
    model: Any,
    row: np.ndarray,
    cameras: Sequence[Any],
    observed: Sequence[Sequence[np.ndarray]],
    ignore: Sequence[Sequence[np.ndarray | None]],
    times: Sequence[float],
    backend: str,
    budget: int,
    seed: int = 0,
) -> dict | None:
    """The manipulation's unknowns ``capture`` declares (``uncertain``: time offset, handle offsets), fitted
    on the given images with the parameter ``row`` held (CMA-ES over the unknowns alone, ``budget``
    evaluations): ``{"time_offset_s", "handles"}`` as a result holds them, or None when it declares none."""
    if capture.uncertain is None or not capture.uncertain.active:
        return None
    sc = capture.scenario.with_frames(list(times))
    manip = ManipulationParameters(capture.uncertain, sc)
    obj = SilhouetteObjective(sc, cameras, observed, backend=backend, model=model, ignore=ignore)
    space = SearchSpace(manip.names, manip.bounds, {n: False for n in manip.names})

    def score(M):
        return obj(np.repeat(np.asarray(row)[None], len(M), 0), offsets=manip.offsets(M))

    best_m, best_f = np.zeros(manip.n), float(score(np.zeros((1, manip.n)))[0])  # as declared: never worse
    opt = make_optimizer("cma-es", space, seed, initial=[best_m], sigma0=D.HELD_UNKNOWNS_SIGMA, restarts=0)
    while opt.evaluations + 1 < budget and not opt.stopped:
        M = opt.ask()
        opt.tell(M, score(M))
    if opt.best_x is not None and opt.best_f < best_f:
        best_m = np.asarray(opt.best_x, dtype=np.float64)
    d = manip.describe(best_m, capture.scenario)
    return {k: d[k] for k in MANIPULATION_KEYS if k in d}


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
    return at_rate(base, capture_frame_rate(capture)[0]), UNSEEN


def at_rate(params: dict, fps: float | None) -> dict:
    """A Blender-cloth result moved to a scene at ``fps`` (its Speed Multiplier times its own rate over ``fps``:
    the same cloth in physical time); as it is for another model, no rate, or its own rate."""
    bc, scene = params.get("blender_cloth"), params.get("blender_scene") or {}
    own = scene.get("fps")
    if not isinstance(bc, dict) or not fps or not own or rate_factor(own, fps) == 1.0:
        return params
    out = dict(params, blender_scene=dict(scene, fps=float(fps)))
    if "time_scale" in bc:
        out["blender_cloth"] = dict(bc, time_scale=float(bc["time_scale"]) * rate_factor(own, fps))
    if isinstance(params.get("model"), dict):
        out["model"] = dict(params["model"], fps=float(fps))
    return out
