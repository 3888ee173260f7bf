"""A fit's errors beside the noise floor of its own images, and when far above it, why.

``report(job)`` (called once when a ``FitJob`` finishes) scores the best candidate on the training
images and on held-out ones (the capture's cameras and frames the fit did not see: other cameras at
other frames where both exist), and puts each beside the floor estimated from those images alone
(``observation/floor.py``: no truth needed), and beside the floor the take's own chaos allows (``jitter.py``:
the noise floor plus the jitter of the fit's neighbours a part in 10^7 away, also no truth needed). A fit more
than ``FLOOR_FAR_ABOVE`` times its noise floor and above that jitter floor says so, with the likely cause among
those it can test by a few evaluations of the best settings:

* **quality**: the ladder's error still fell at its highest rung; or the rungs chose a quality that fits
  far better (``QUALITY_BASIN_GAIN``) than the start, where the search ran and from whose settings every
  rung began (a search at the chosen quality from the start may find another basin); or (quality fixed)
  twice the quality fits clearly better;
* **time scale**: Blender's default Speed Multiplier 1 (a user scene not set to real time) fits
  clearly better than the physical one;
* **manipulation**: reading the capture half a frame earlier or later fits clearly better (the
  release or the clock is off: declare ``uncertain``);
* **bounds** (said before the probes): a free setting ended at its search bound (``verdict.settings_at_bound``),
  so the bounds may exclude the cloth's values;
* **search**: it stopped on its budget with its error still falling over its last fifth;
* none of these: the search stopped in a local minimum, the cloth does not move like this
  simulator, or the observation has an error the floor estimate cannot see (a segmenter's bias):
  the result says which were tested and that it cannot tell these apart.

A floor of (nearly) 0 (``FLOOR_ZERO_OF_RIM``: noise-free or synthetic silhouettes at the fit's resolution) gets no
ratio: the warning says so and gives a one-pixel shift of the outline (``train_rim_pct``) to compare with instead.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .. import defaults as D
from ..errors import ClothFitError
from ..observation.floor import capture_floor
from ..physics import blender as B
from .alone import alone_note, disagreement_text
from .jitter import allowed, floor_with_jitter, jitter
from .objective import SilhouetteObjective
from .takes import TakeView
from .verdict import jitter_text, settings_at_bound

if TYPE_CHECKING:
    from .job import FitJob

CLEARLY = D.QUALITY_CLEARLY_BETTER  # a probe "fits clearly better" below (1 - CLEARLY) x the best error


def _heldout(job):
    """(camera indices, frame indices) the fit did not see, or None."""
    cap = job.capture
    cams = [c for c in range(len(cap.cameras)) if c not in job.train_cameras]
    frames = [f for f in range(cap.n_frames) if f not in job.train_frames]
    if not cams and not frames:
        return None
    return (cams or list(job.train_cameras)), (frames or list(job.train_frames))


def _objective(job, cams, fidx):
    from .job import load_observed

    cap = job.capture
    times = [float(cap.frame_times[i]) for i in fidx]
    sc = (
        job.evaluator.scenario(times, cap.scenario.crop)
        if job.evaluator is not None
        else cap.scenario.with_frames(times)
    )
    cameras, observed, ignore = load_observed(cap, cams, fidx, job.config.resolution)
    return SilhouetteObjective(
        sc, cameras, observed, backend=job.config.backend, model=job.objective.model, ignore=ignore
    )


def _model_silhouettes(job, x, obj):
    """The best candidate's clean silhouettes as ``obj`` rasterises them (the floor's baseline:
    ``capture_floor``'s ``model``), or None for a scene evaluator's fit or a candidate that explodes there."""
    if job.evaluator is not None:
        return None
    X = np.atleast_2d(np.asarray(x, dtype=np.float64))
    off = None if job.manip is None else job.manip.offsets(X[:, job.npar :])
    return obj.silhouettes(job.par.rows(X[:, : job.npar])[0], offsets=off)


def _jitter_floor(job, x, obj, sils, floor_pct, side) -> dict:
    """The floor the take's own chaos allows on one side (``side``: "train" or "heldout"; ``jitter.py``):
    ``{side}_jitter_floor_pct`` (the images' noise floor plus the jitter of the fit's neighbours: 10th, 50th and
    90th percentiles) and ``{side}_allowed_ratio`` (that floor at ``JITTER_QUANTILE``, over the noise floor), or
    nothing where it cannot be measured."""
    jit = jitter(job, x, obj, sils)
    q, lim = floor_with_jitter(floor_pct, jit), allowed(floor_pct, jit)
    if q is None or lim is None or not floor_pct:
        return {}
    return {
        f"{side}_jitter_floor_pct": q,
        f"{side}_allowed_ratio": lim / floor_pct,
        "jitter_samples": jit["samples"],
        "jitter_relative": jit["relative"],
    }


def _train_floor(job, x) -> dict:
    """The training side's floor at ``x`` on the running objective: ``{"mt": the clean silhouettes, "tf": the
    images' noise floor}``, and ``"jitter"`` once measured (``_jitter_floor``'s block). Kept in ``job.floor_cache``
    for the last point asked, so that the report at the end does not measure again what the check for searching
    again measured at the same point and quality (the measurement is deterministic)."""
    key = (np.asarray(x, dtype=np.float64).tobytes(), job.state.stage_quality)
    cache = getattr(job, "floor_cache", None)  # a take's view of a fit of several takes keeps none
    hit = None if cache is None else cache.get(key)
    if hit is None:
        mt = _model_silhouettes(job, x, job.objective)
        tf = capture_floor(job.capture, job.train_cameras, job.train_frames, job.config.resolution, model=mt)
        hit = {"mt": mt, "tf": tf}
        if cache is not None:
            job.floor_cache = {key: hit}
    return hit


def _train_jitter(job, x, floor_pct) -> dict:
    """``_jitter_floor`` on the training side at ``x``, measured once per point (``_train_floor``)."""
    hit = _train_floor(job, x)
    if "jitter" not in hit:
        hit["jitter"] = _jitter_floor(job, x, job.objective, hit["mt"], floor_pct, "train")
    return hit["jitter"]


def above_jitter_floor(job: FitJob, x: np.ndarray, f: float) -> str | None:
    """Why a search that ended at ``x`` with training error ``f`` (``E_all``, at the running quality) should search
    again: its error is above the floor its own jitter allows on the training images (``_jitter_floor``: what a fit
    knows when its search ends, no held-out image used) by more than ``SEARCH_AGAIN_MARGIN``, or above both that floor
    and ``FLOOR_FAR_ABOVE`` times the noise floor; None when it is within, or neither can be measured (a scene
    evaluator's fit, a floor of 0)."""
    obj = job.objective
    tr = _train_floor(job, x)
    if tr["mt"] is None:
        return None
    tf = tr["tf"]
    if _is_zero(tf):
        return None
    e, floor = 100.0 * float(f) / obj.n_images, 100.0 * tf.floor
    raw = _train_jitter(job, x, floor).get("train_allowed_ratio")
    # the verdict's rule (2x or the jitter floor), and SEARCH_AGAIN_MARGIN times the jitter floor where that is lower:
    # a search between the two may be in another basin, and searching again costs time, not a wrong answer
    allow = max(D.FLOOR_FAR_ABOVE, raw or 0.0)
    if raw:
        allow = min(allow, D.SEARCH_AGAIN_MARGIN * raw)
    if e <= allow * floor:
        return None
    return (
        f"the search ended at {e / floor:.1f}x the training images' noise floor, above the {allow:.1f}x its own "
        f"jitter allows"
    )


def _probes(job, x, f0):
    """[(cause, what, error ratio to the best)] of the tests that apply to this fit."""
    out = []
    lad = job.ladder
    if lad is not None and lad.tried and not lad.probe_only:
        top = max(lad.tried)
        if job.chosen_quality() == top and lad.next() is None and top < max(lad.rungs):
            up = lad.above(top)
            out.append(
                (
                    "quality",
                    f"the error still fell at the highest quality tried ({top}): refit with --quality {up}",
                    0.0,
                )
            )
        c, s = job.chosen_quality(), lad.start
        if c != s and s in lad.tried and c in lad.tried and lad.tried[c] < (1.0 - D.QUALITY_BASIN_GAIN) * lad.tried[s]:
            out.append(
                (
                    "quality",
                    f"the rungs fitted {100 * (1 - lad.tried[c] / lad.tried[s]):.0f} % better at quality {c} than "
                    f"the search at {s}, each starting from that search's settings, which may make up for the "
                    f"coarser solver: refit with --quality {c}, a search at that quality from the start",
                    0.0,
                )
            )
    if lad is None and job.evaluator is None and getattr(job.par.model, "name", "") == "blender":
        q = job.par.model.quality
        f = float(job.evaluate(x[None], objective=job.objective_at(min(80, 2 * q)))[0])
        out.append(("quality", f"quality {min(80, 2 * q)} instead of {q}", f / f0))
    if job.evaluator is None and getattr(job.par.model, "name", "") == "blender":
        X = np.atleast_2d(x)
        rows = job.par.rows(X[:, : job.npar])
        k = B.FLOAT_SETTINGS.index("time_scale")
        if abs(rows[0, k] - 1.0) > 1e-3:
            rows[:, k] = 1.0
            if job.manip is None:
                f = float(job.objective(rows)[0])
            else:
                f = float(job.objective(rows, offsets=job.manip.offsets(X[:, job.npar :]))[0])
            out.append(("time scale", "Blender's default Speed Multiplier 1 instead of the real-time one", f / f0))
    if job.manip is None or "time_offset_s" not in job.manip.names:
        ft = np.asarray(job.capture.frame_times, dtype=np.float64)
        dt = float(np.median(np.diff(ft))) if ft.size > 1 else 1.0 / 24
        from ..physics.scenario import Offsets

        P = job.par.rows(np.atleast_2d(x)[:, : job.npar])
        H = len(getattr(job.scenario, "handles", []))
        if H and job.evaluator is None:
            base = np.zeros((2, H, 3))
            if job.manip is not None:
                base[:] = job.manip.offsets(np.atleast_2d(x)[:, job.npar :]).handles[0]
            off = Offsets(np.array([0.5 * dt, -0.5 * dt]), base)
            f = job.objective(np.repeat(P, 2, 0), offsets=off)
            out.append(
                (
                    "manipulation",
                    f"the capture read half a frame ({1000 * 0.5 * dt:.0f} ms) earlier or later",
                    float(np.min(f)) / f0,
                )
            )
    return out


def _still_improving(job):
    """A description when the main search stopped on its budget while its best still fell by more
    than ``CLEARLY`` over its last fifth, else None."""
    rec = [r for r in job.state.records if r["stage"] == "search"]
    if not rec or rec[-1]["stop"] != "budget":
        return None
    n = rec[-1]["evaluations"]  # the last search (a fit that searched again: the one that ran last)
    start = (job.state.again or {}).get("start", 0)
    hist = [(e - start, f) for e, f in job.state.history_prev if start <= e <= start + n and f is not None]
    if len(hist) < 2:
        return None
    before = [f for e, f in hist if e <= 0.8 * n]
    if not before:
        return None
    if hist[-1][1] < (1.0 - CLEARLY) * before[-1]:
        return (
            f"the search stopped on its budget ({n} evaluations) with its error still falling "
            f"({100 * (1 - hist[-1][1] / before[-1]):.0f} % over its last fifth): a larger --max-evaluations"
        )
    return None


def _rim(cf) -> float:
    """The ``E_sil`` of a one-pixel shift of the whole outline, averaged over a capture floor's images."""
    return float(np.mean([[e.rim for e in row] for row in cf.images]))


def _is_zero(cf) -> bool:
    """A capture floor of (nearly) 0: below ``FLOOR_ZERO_OF_RIM`` of a one-pixel shift of the outline."""
    return cf.floor <= D.FLOOR_ZERO_OF_RIM * _rim(cf)


def _start_beside(job, x, obj, e) -> dict:
    """The settings the fit started from (a scene's Cloth modifier, a warm start) beside the fit's, on the
    cameras and frames it did not see: ``start_train_E_sil_pct``, ``start_heldout_E_sil_pct`` and, when the start
    predicts them as well or better, ``start_note`` (the fit is then no better than what it was given, whatever
    its training error says). {} for a fit without a start, or one that ended on it."""
    x0 = getattr(job, "start_x", None)  # a take of several (takes.TakeView) has none of its own
    f0 = None if x0 is None else job.state.start_f
    if x0 is None or f0 is None or not np.isfinite(f0) or np.array_equal(np.asarray(x0), np.asarray(x)):
        return {}
    e0 = float(job.evaluate(np.asarray(x0, dtype=np.float64)[None], objective=obj)[0]) / obj.n_images
    out = {"start_train_E_sil_pct": 100.0 * float(f0) / job.objective.n_images}
    out["start_heldout_E_sil_pct"] = 100.0 * e0 if np.isfinite(e0) else None
    if np.isfinite(e0) and np.isfinite(e) and e0 <= e * (1.0 + D.START_HELDOUT_MARGIN):
        out["start_note"] = (
            f"the settings the fit started from predict the cameras and frames it did not see as well or better "
            f"(held-out {100.0 * e0:.2f} % against the fit's {100.0 * e:.2f} %; training {out['start_train_E_sil_pct']:.2f} % "
            f"against {100.0 * float(job.best_error) / job.objective.n_images:.2f} %): the fit is no better than "
            f"what it was given; keep those settings (the result's start_settings)"
        )
    return out


def report(job: FitJob) -> dict:
    """The result's ``floor`` block (see the module's text)."""
    x = job.best_x
    if x is None:
        raise ClothFitError("no candidate to report on")
    cap, res = job.capture, job.config.resolution
    n = job.objective.n_images
    f0 = float(job.best_error)
    tf = _train_floor(job, x)["tf"]
    d = {
        "train_E_sil_pct": 100.0 * f0 / n,
        "train_floor_pct": 100.0 * tf.floor,
        "train_rim_pct": 100.0 * _rim(tf),
        "threshold": D.FLOOR_FAR_ABOVE,
        "floor_basis": tf.basis,
        "floor_limits": tf.limits,
    }
    # a floor of (nearly) 0: noise-free silhouettes at the fit's resolution, where a ratio to it means nothing
    d["floor_zero"] = _is_zero(tf)
    d["train_ratio"] = d["train_E_sil_pct"] / d["train_floor_pct"] if not d["floor_zero"] else None
    if not d["floor_zero"]:
        d.update(_train_jitter(job, x, d["train_floor_pct"]))
    ho = _heldout(job)
    if ho is not None:
        cams, fidx = ho
        try:
            obj = _objective(job, cams, fidx)
            e = float(job.evaluate(x[None], objective=obj)[0]) / obj.n_images
            mh = _model_silhouettes(job, x, obj)
            hf = capture_floor(cap, cams, fidx, res, model=mh)
            d.update(
                heldout_cameras=[cap.cameras[c].name for c in cams],
                heldout_n_frames=len(fidx),
                heldout_E_sil_pct=100.0 * e if np.isfinite(e) else None,
                heldout_floor_pct=100.0 * hf.floor,
                heldout_rim_pct=100.0 * _rim(hf),
                heldout_floor_basis=hf.basis,
            )
            d["heldout_ratio"] = (
                d["heldout_E_sil_pct"] / d["heldout_floor_pct"]
                if not _is_zero(hf) and d["heldout_E_sil_pct"] is not None
                else None
            )
            if d["heldout_ratio"] is not None:
                d.update(_jitter_floor(job, x, obj, mh, d["heldout_floor_pct"], "heldout"))
            d.update(_start_beside(job, x, obj, e))
        except ClothFitError as err:
            d["heldout_error"] = str(err)
    ratios = [r for r in (d.get("train_ratio"), d.get("heldout_ratio")) if r is not None]
    # far above: above 2x the noise floor and above the floor the take's own jitter allows, on either side
    d["far_above"] = any(
        d[f"{k}_ratio"] > max(D.FLOOR_FAR_ABOVE, d.get(f"{k}_allowed_ratio") or 0.0)
        for k in ("train", "heldout")
        if d.get(f"{k}_ratio") is not None
    )
    d["at_jitter_floor"] = bool(ratios) and not d["far_above"] and max(ratios) > D.FLOOR_FAR_ABOVE
    d["likely_cause"] = None
    d["warning"] = None
    d["settings_at_bound"] = bound = settings_at_bound(job.par, x)
    if d["floor_zero"]:
        d["warning"] = (
            f"the floor is 0 (noise-free or synthetic silhouettes): the ratio is not meaningful; compare training "
            f"{d['train_E_sil_pct']:.2f} % with a one-pixel shift of the whole outline ({d['train_rim_pct']:.2f} %) "
            f"or with the true settings' error (evaluate --params)"
        )
    if d["far_above"]:
        probes = _probes(job, x, f0) if np.isfinite(f0) and f0 > 0 else []
        d["probes"] = [{"cause": c, "tried": w, "error_ratio": r} for c, w, r in probes]
        hits = sorted((r, c, w) for c, w, r in probes if r < 1.0 - CLEARLY)
        still = _still_improving(job)
        if not hits and still:
            hits = [(0.0, "search", still)]
        if bound:  # the search ended against its bounds: they may exclude the cloth, whatever the probes say
            d["likely_cause"] = (
                "bounds ("
                + ", ".join(f"{k} at its {v['side']} bound {v['bound']:.4g}" for k, v in bound.items())
                + ": the cloth's values may lie outside the search range: widen --bounds)"
            )
        elif hits:
            d["likely_cause"] = (
                f"{hits[0][1]} ({hits[0][2]}: error x{hits[0][0]:.2f})"
                if hits[0][0] > 0
                else f"{hits[0][1]} ({hits[0][2]})"
            )
        else:
            d["likely_cause"] = (
                "none of those tested ("
                + ", ".join(sorted({c for c, _, _ in probes} | {"search"}))
                + "): the search may have stopped in a local minimum (another --seed, a larger "
                "--max-evaluations), the cloth may not move like this simulator, or the silhouettes "
                "carry an error the floor cannot see (a segmenter's bias)"
            )
        worst = max(ratios)
        d["warning"] = (
            f"the fit ends {worst:.1f}x above its images' noise floor (training {d['train_E_sil_pct']:.2f} % "
            f"against {d['train_floor_pct']:.2f} %"
            + (
                f"; held-out {d['heldout_E_sil_pct']:.2f} % against {d['heldout_floor_pct']:.2f} %"
                if d.get("heldout_E_sil_pct") is not None
                else ""
            )
            + f"): likely cause: {d['likely_cause']}"
            + (f"; {jitter_text(d)}" if jitter_text(d) else "")
        )
    return d


def _weighted(blocks, key, weight) -> float | None:
    """The mean of the take blocks' ``key`` weighted by ``weight(block)`` (None when a block lacks it)."""
    vals = [(b.get(key), weight(b)) for b in blocks]
    if not vals or any(not isinstance(v, (int, float)) for v, _ in vals):
        return None
    w = sum(n for _, n in vals)
    return sum(v * n for v, n in vals) / w if w else None


def report_takes(job: FitJob) -> tuple[dict, list[dict]]:
    """A fit of several takes: (the fit's ``floor`` block over every take, each take's own ``report``).
    Training and held-out errors and floors over all takes are their images' weighted means; the fit is far
    above its floor when any take is, with that take's likely cause."""
    per = []
    for k in range(len(job.takes)):
        try:
            per.append(report(TakeView(job, k)))
        except ClothFitError as e:  # never a reason to lose the result
            per.append({"error": str(e)})
    ok = [b for b in per if "error" not in b]
    n_train = [len(t.train_cameras) * len(t.train_frames) for t, b in zip(job.takes, per) if "error" not in b]
    train_w = dict(zip(map(id, ok), n_train))
    d = {
        "train_E_sil_pct": 100.0 * float(job.best_error) / job.objective.n_images,
        "train_floor_pct": _weighted(ok, "train_floor_pct", lambda b: train_w[id(b)]),
        "train_rim_pct": _weighted(ok, "train_rim_pct", lambda b: train_w[id(b)]),
        "threshold": D.FLOOR_FAR_ABOVE,
        "floor_basis": "each take's images (weighted by their number)",
        "floor_limits": (ok[0] if ok else {}).get("floor_limits"),
        "floor_zero": bool(ok) and all(b.get("floor_zero") for b in ok),
    }
    d["train_ratio"] = (
        d["train_E_sil_pct"] / d["train_floor_pct"] if d["train_floor_pct"] and not d["floor_zero"] else None
    )
    held = [b for b in ok if b.get("heldout_E_sil_pct") is not None]
    if held and len(held) == len(ok):

        def n_held(b):
            return len(b["heldout_cameras"]) * b["heldout_n_frames"]

        d.update(
            heldout_E_sil_pct=_weighted(held, "heldout_E_sil_pct", n_held),
            heldout_floor_pct=_weighted(held, "heldout_floor_pct", n_held),
            heldout_rim_pct=_weighted(held, "heldout_rim_pct", n_held),
        )
        d["heldout_ratio"] = (
            d["heldout_E_sil_pct"] / d["heldout_floor_pct"]
            if d["heldout_floor_pct"] and not all(b.get("floor_zero") for b in held)
            else None
        )
    d["settings_at_bound"] = settings_at_bound(job.par, job.best_x)
    alone = (job.state.alone or {}).get("results") or []
    for t, b in zip(job.takes, per):  # what each take reaches searched alone (alone.py), beside its joint error
        r = next((r for r in alone if r["take"] == t.name), None)
        if r is not None and "error" not in b:
            b["alone_E_sil_pct"] = r["alone_E_sil_pct"]
    d["takes_note"] = disagreement_text(alone)
    d["takes_alone_note"] = alone_note(job)
    far = [
        (max(r for r in (b.get("train_ratio"), b.get("heldout_ratio")) if r is not None), t.name, b)
        for t, b in zip(job.takes, per)
        if b.get("far_above")
    ]
    d["far_above"] = bool(far) or len(ok) < len(per)
    d["at_jitter_floor"] = not d["far_above"] and any(b.get("at_jitter_floor") for b in ok)
    d["likely_cause"] = None
    d["warning"] = None
    if far and d["takes_note"]:  # the takes disagree: that is the cause a search of all of them cannot remove
        d["likely_cause"] = d["takes_note"]
        d["warning"] = f"the fit ends far above its floor on {', '.join(n for _, n, _ in far)}: {d['takes_note']}"
    elif far:
        _, name, worst = max(far, key=lambda w: w[0])
        d["likely_cause"] = f"take {name}: {worst.get('likely_cause')}"
        d["warning"] = f"take {name}: {worst.get('warning')}"
    elif len(ok) < len(per):
        name, err = next((t.name, b["error"]) for t, b in zip(job.takes, per) if "error" in b)
        d["likely_cause"] = d["warning"] = f"take {name} has no floor report: {err}"
    elif d["floor_zero"]:
        d["warning"] = next(b["warning"] for b in ok if b.get("warning"))
    return d, per
