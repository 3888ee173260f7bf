"""A fit's verdict: one line a person reads, and its kind for a program, from the result alone.

``verdict(result)`` reads a result dict (a fit's, as written to its file: old files too) and says which of
these it is:

* ``at_floor``: training and held-out errors within ``FLOOR_FAR_ABOVE`` of the images' noise floor, or within the
  floor a chaotic take allows (the floor block's ``at_jitter_floor``: the noise floor plus the jitter of the
  fit's neighbours, ``jitter.py``; the line then says "at the jitter floor" with its figures), no free setting or
  offset at its bound and none the capture leaves undetermined;
* ``at_floor_undetermined``: at the floor, but the result's ``undetermined`` list (free settings whose
  interval is too wide to mean anything) is not empty: it names them and what would determine them;
* ``at_bound``: at the floor, but a free setting (or a manipulation offset) ended at its search bound: the
  cloth's value may lie beyond it;
* ``far_above``: far above the floor, with the cause the floor report tested (``diagnose.report``'s
  ``likely_cause``);
* ``takes_disagree``: a fit of several takes whose shared settings serve a take clearly worse than that take's
  own search does (``alone.py``): one set of settings does not serve every take; each such take's error beside
  what it reaches alone;
* ``start_better``: a fit that started from a user's settings (a scene's Cloth modifier, a warm start) predicts
  the cameras and frames it did not see no better than those settings do (``diagnose.report``'s ``start_note``):
  keep them (the result's ``start_settings``);
* ``noise_free``: the floor is 0 (noise-free or synthetic silhouettes at the fit's resolution): a ratio to
  it means nothing, so the line gives the errors beside a one-pixel shift of the outline instead;
* ``unfinished`` (cancelled, or stopped before its floor report) and ``failed`` (an error).

Every line but the last two ends by saying how many times the fit searched, where it searched again
(``searches``: ``again.py``), and how many of the search's independent starts (the result's ``looks``) ended in
the basin of its best one, where it made more than one.

``settings_at_bound(par, x)`` is the check behind ``at_bound`` for the free settings (the result's
``settings_at_bound``; the manipulation's offsets have their own, ``ManipulationParameters.at_bound``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .. import defaults as D

KINDS = (
    "at_floor",
    "at_floor_undetermined",
    "at_bound",
    "far_above",
    "takes_disagree",
    "start_better",
    "noise_free",
    "unfinished",
    "failed",
)

# what would determine a setting the capture leaves undetermined, by the part of its name that says what it is
DETERMINED_BY = (
    ("bending", "a higher resolution, or a camera that sees the folds edge-on"),
    ("damping", "a take with another handling (a faster motion, a longer fall)"),
    ("d_over_m", "a take with another handling (a faster motion, a longer fall)"),
    ("stiffness", "a take with another handling that stretches the cloth (a pull, a shake)"),
    ("k_over_m", "a take with another handling that stretches the cloth (a pull, a shake)"),
    ("time_offset", "a take with a sharper release (a clear event on the capture's clock)"),
    ("handle", "another camera that sees the handle"),
)
ANY_MORE_DATA = "another camera, a take with another handling, or a higher resolution"


def settings_at_bound(par: Any, x: Any) -> dict[str, dict]:
    """{name: {"side": "lower" or "upper", "bound": value}} of the free settings of a fit's parameters ``par``
    (``parameters.PaperParameters`` / ``BlenderParameters``) whose fitted coordinates ``x`` (the settings
    first, as ``FitJob.best_x``) end within ``SETTING_AT_BOUND_UNIT`` of the search range of a bound (or within
    ``SETTING_AT_BOUND_RELATIVE`` of its value, for a narrow range); the
    bound in the result's units (Blender's, at the fit's vertex mass, for the mass-scaled settings)."""
    space = par.space
    x = np.asarray(x, dtype=np.float64).reshape(-1)[: space.n]
    scaled = getattr(par, "scaled", set())
    out = {}
    for n, side in space.at_bound(x, D.SETTING_AT_BOUND_UNIT, D.SETTING_AT_BOUND_RELATIVE).items():
        b = space.bounds[n][0 if side == "lower" else 1]
        out[n] = {"side": side, "bound": float(b * par.m if n in scaled else b)}
    return out


def determined_by(name: str) -> str:
    """What would determine a setting (or offset) the capture leaves undetermined."""
    return next((what for key, what in DETERMINED_BY if key in name), ANY_MORE_DATA)


def _ratios(fl: dict) -> str:
    parts = [
        f"{label} {fl[k]:.1f}x"
        for label, k in (("training", "train_ratio"), ("held-out", "heldout_ratio"))
        if isinstance(fl.get(k), (int, float))
    ]
    return ", ".join(parts)


def _at_bound(result: dict) -> tuple[list, dict]:
    """(names at their bounds: settings and offsets, the settings' {name: {side, bound}})."""
    detail = result.get("settings_at_bound") or (result.get("floor") or {}).get("settings_at_bound") or {}
    return list(dict.fromkeys(list(detail) + list(result.get("at_bound") or []))), detail


def _bounds_text(result: dict) -> str:
    """The settings and offsets at their bounds, with the bound and what to do, or ''."""
    names, detail = _at_bound(result)
    if not names:
        return ""
    shown = [f"{n} at its {detail[n]['side']} bound {detail[n]['bound']:.4g}" if n in detail else n for n in names]
    todo = []
    if any(n in detail for n in names):
        todo.append("widen --bounds")
    if any(n not in detail for n in names):
        todo.append("widen --uncertain")
    return f"{', '.join(shown)}: the cloth's value may lie beyond it ({' / '.join(todo)})"


def _pct(v: Any) -> str:
    return f"{v:.2f} %" if isinstance(v, (int, float)) else "?"


def jitter_text(fl: dict) -> str:
    """What the take's chaos allows (a floor block's ``*_jitter_floor_pct``, ``jitter.py``), held-out where it was
    measured there, else training: the noise floor plus the jitter of the fit's neighbours over the noise floor,
    or ''."""
    for side, label in (("heldout", "held-out"), ("train", "training")):
        q, f = fl.get(f"{side}_jitter_floor_pct"), fl.get(f"{side}_floor_pct")
        if isinstance(q, dict) and isinstance(f, (int, float)) and f > 0:
            return (
                f"settings a part in 10^7 from the fit's score {q['p10'] / f:.1f}-{q['p90'] / f:.1f}x the noise "
                f"floor ({label}, median {q['p50'] / f:.1f}x): the floor this take's chaos allows"
            )
    return ""


def looks_text(result: dict) -> str:
    """How many of the search's independent starts ended in the basin of its best one (the result's ``looks``), or
    '' for a search of one start."""
    lk = result.get("looks")
    if not isinstance(lk, dict) or not isinstance(lk.get("starts"), int) or lk["starts"] < 2:
        return ""
    n, k = lk["starts"], lk.get("agreeing")
    if k == n:
        return (
            f"all {n} starts of the search ended in this basin (no proof that it is the cloth's: the floor says that)"
        )
    rest = "the other in a worse one" if n - k == 1 else "the others in worse ones"
    return f"{k} of {n} starts of the search ended in this basin, {rest}: a basin no start reached may fit better"


def searches_text(result: dict) -> str:
    """How many times the fit searched (the result's ``searches``, ``again.py``), or '' for one search."""
    sr = result.get("searches")
    if not isinstance(sr, dict) or not isinstance(sr.get("count"), int) or sr["count"] < 2:
        return ""
    why = sr.get("why") or ["?"]
    end = f"; the last ended {sr['ended']}" if sr.get("ended") else ""
    return f"searched {sr['count']} times from different seeds, the best point of all kept (first: {why[0]}){end}"


def verdict(result: dict) -> tuple[str, str]:
    """(kind, line) of a fit's result dict (see the module's text; ``kind`` is one of ``KINDS``), with how many
    times it searched (``searches_text``) and how many of the search's starts ended in its basin (``looks_text``)."""
    kind, line = _verdict(result)
    if kind not in ("failed", "unfinished"):
        line = "; ".join([line] + [t for t in (searches_text(result), looks_text(result)) if t])
    return kind, line


def _verdict(result: dict) -> tuple[str, str]:
    if result.get("error"):
        return "failed", f"failed: {result['error']}"
    fl = result.get("floor") or {}
    ev = result.get("evaluations")
    if not fl or fl.get("train_floor_pct") is None:
        why = "cancelled" if result.get("cancelled") else "unfinished"
        return "unfinished", (
            f"{why} after {ev if ev is not None else '?'} evaluations: no verdict (the errors are put beside the "
            f"images' noise floor when a fit finishes; resume it with --resume)"
        )
    bounds = _bounds_text(result)
    # a setting at its bound is said so once, as at its bound
    undetermined = [
        n for n in (result.get("undetermined") or []) if isinstance(n, str) and n not in _at_bound(result)[0]
    ]
    undet = (
        "the capture cannot determine " + "; ".join(f"{n} ({determined_by(n)})" for n in undetermined)
        if undetermined
        else ""
    )
    tail = "".join(f"; {t}" for t in (bounds, undet) if t)
    if fl.get("floor_zero"):
        shown = []
        for label, e, rim in (
            ("training", "train_E_sil_pct", "train_rim_pct"),
            ("held-out", "heldout_E_sil_pct", "heldout_rim_pct"),
        ):
            if isinstance(fl.get(e), (int, float)):
                r = fl.get(rim)
                shown.append(
                    f"{label} {_pct(fl[e])}"
                    + (
                        f" ({fl[e] / r:.1f}x a one-pixel shift of the outline, {_pct(r)})"
                        if isinstance(r, (int, float)) and r > 0
                        else ""
                    )
                )
        return "noise_free", (
            "the floor is 0 (noise-free or synthetic silhouettes): the ratio is not meaningful; "
            + ", ".join(shown)
            + "; compare with the true settings' error (evaluate --params)"
            + tail
        )
    ratios = _ratios(fl)
    if fl.get("start_note"):
        where = "far above the floor" if fl.get("far_above") else "at the floor"
        return "start_better", f"{where} ({ratios}), but {fl['start_note']}" + tail
    if fl.get("takes_note"):  # a fit of several takes that one set of settings does not serve
        where = "far above the floor" if fl.get("far_above") else "at the floor"
        return "takes_disagree", f"{where} ({ratios}), but {fl['takes_note']}" + tail
    if fl.get("far_above"):
        cause = fl.get("likely_cause") or "not tested"
        extra = f"; {bounds}" if bounds and "bound" not in cause else ""
        chaos = f"; {jitter_text(fl)}" if jitter_text(fl) else ""
        return "far_above", f"far above the floor ({ratios}{chaos}): likely cause: {cause}{extra}" + (
            f"; {undet}" if undet else ""
        )
    at = f"at the floor ({ratios})" if ratios else "at the floor"
    if fl.get("at_jitter_floor"):
        why = jitter_text(fl) or "each take within the floor its own chaos allows (the result's takes)"
        at = f"at the jitter floor ({ratios} the noise floor; {why})"
    if bounds:
        return "at_bound", f"{at}, but {bounds}" + (f"; {undet}" if undet else "")
    if undet:
        return "at_floor_undetermined", f"{at}, but {undet}"
    if "intervals" in result:
        return "at_floor", f"{at}, every free setting determined"
    return "at_floor", f"{at}"
