"""A fit's result: ``FitResult``, the JSON object a fit writes and every reader reads back.

A fit (``fitting.job.FitJob.result``, here ``job_result``) makes one; ``to_json`` gives the
object written to the result file (the same keys and values as the plain dict results always
were: old files load, recorded figures stay); ``FitResult.from_json`` reads a dict or a file back
and checks the keys its readers depend on (one-line ``ClothFitError`` naming the file and the
key). ``FitResult`` is a ``dict`` underneath, so readers that index it (``res["blender_cloth"]``,
``res.get("handles")``) and code that takes a plain result dict (``physics.scenario.fitted_scenario``,
``physics.models.model_and_row``) keep working; new code uses its properties and methods.

Keys (the reference: docs/api.md, "A fit: configuration and result"): ``format``/``version``; what was fitted (``capture``,
``capture_hash``, ``silhouettes_hash``, ``train_cameras``, ``train_times``, ``resolution``,
``model``); the search (``optimizer``, ``seed``, ``evaluations``, ``generations``, ``stop_reason``,
``stages``, ``looks``: the search's independent starts and how many ended in the best one's basin,
``history``...); the answer (paper: ``params``, ``identifiable``; Blender:
``blender_cloth``, ``blender_scene``: ``fps`` and ``fps_source``); ``settings_at_bound`` and ``at_bound``
(the free settings, then the offsets, that ended at their bounds); the errors (``best_E_sil_mean_pct``,
``floor``...) and the one-line ``verdict`` with its ``verdict_kind`` (``verdict.verdict``); the
fitted manipulation (``time_offset_s``, ``handles``, ``release_instants``: each released handle's
release on the capture's clock, ``manipulation_profile``, ``manipulation_note``, ``uncertainty_caveat``).
"""

from __future__ import annotations

import math
import os
from typing import TYPE_CHECKING, Any

from .. import defaults as D
from ..errors import ClothFitError
from ..jsonio import read_json, write_json
from ..physics.paper import Params, identifiable
from .verdict import settings_at_bound, verdict

if TYPE_CHECKING:
    import numpy as np

    from ..physics.models import BlenderModel, ClothModel
    from .job import FitJob

RESULT_FORMAT = "silhouette-cloth-fit/result"
RESULT_VERSION = 1


def finite_or_none(x: float) -> float | None:
    """A finite number as a float, else None (results are strict JSON)."""
    return float(x) if math.isfinite(x) else None


def _is_num(v):
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


class FitResult(dict):
    """A fit's result (a ``dict`` of the result file's keys; see the module's docstring).
    ``source``: the file it was read from (or a description), named by its errors."""

    source = "fit result"

    # ------------------------------------------------------------------ JSON
    def to_json(self) -> dict:
        """The plain JSON object the result file holds (the keys and values of a fit's result)."""
        return dict(self)

    @classmethod
    def from_json(
        cls, data: str | os.PathLike | dict[str, Any], what: str = "fit result", need_parameters: bool = True
    ) -> FitResult:
        """A result from a dict or a JSON file, checked: an object; ``format`` (when given) a fit
        result's; ``blender_cloth`` or ``params`` an object (``need_parameters``: one of them must be
        there: a result that found nothing cannot be applied, exported or warm-started from);
        ``model``, ``blender_scene``, ``handles`` and ``time_offset_s`` of the right kinds. Errors: one
        ``ClothFitError`` line naming ``what``, the file and the key."""
        if isinstance(data, (str, os.PathLike)):
            src = f"{what} {os.fspath(data)}"
            d = read_json(data, what)
        else:
            src = what
            d = data
            if not isinstance(d, dict):
                raise ClothFitError(f"{src}: expected a JSON object, got {type(d).__name__}")
        res = cls(d)
        res.source = src
        res.check(need_parameters)
        return res

    def check(self, need_parameters: bool = True) -> FitResult:
        """The checks of ``from_json`` (see there)."""
        src = self.source

        def bad(key, why):
            return ClothFitError(f"{src}: '{key}' {why}")

        fmt = self.get("format")
        if fmt is not None and fmt != RESULT_FORMAT:
            raise bad(
                "format",
                f"is {fmt!r}, not a fit result's {RESULT_FORMAT!r}"
                + (" (a checkpoint: give the fit's --out file)" if "checkpoint" in str(fmt) else ""),
            )
        if fmt is not None and self.get("version", RESULT_VERSION) != RESULT_VERSION:
            raise bad("version", f"{self.get('version')!r} is not supported (this reader knows {RESULT_VERSION})")
        for key in ("blender_cloth", "params", "blender_scene"):
            if self.get(key) is not None and not isinstance(self[key], dict):
                raise bad(key, f"must be an object, got {type(self[key]).__name__}")
        if need_parameters and not (self.get("blender_cloth") or self.get("params")):
            raise ClothFitError(
                f"{src}: no 'blender_cloth' or 'params' in it (not a fit result, or a fit that found no parameters)"
            )
        m = self.get("model")
        if m is not None and not isinstance(m, (str, dict)):
            raise bad("model", f"must be a name or an object, got {type(m).__name__}")
        fps = (self.get("blender_scene") or {}).get("fps")
        if fps is not None and not (_is_num(fps) and fps > 0):
            raise bad("blender_scene.fps", f"must be a positive number, got {fps!r}")
        h = self.get("handles")
        if h is not None and not (isinstance(h, list) and all(isinstance(x, dict) for x in h)):
            raise bad("handles", "must be a list of objects")
        t = self.get("time_offset_s")
        if t is not None and not _is_num(t):
            raise bad("time_offset_s", f"must be a number, got {t!r}")
        ts = self.get("time_scale")
        if ts is not None and not (_is_num(ts) and ts > 0):
            raise bad("time_scale", f"must be a positive number, got {ts!r}")
        return self

    def save(self, path: str | os.PathLike) -> None:
        """Write the result file: strict JSON (no NaN), atomically (``jsonio.write_json``)."""
        write_json(path, self.to_json(), strict=True)

    # ------------------------------------------------------------ its parts
    @property
    def is_blender(self) -> bool:
        """A Blender-cloth fit (``blender_cloth`` settings), not the paper's sheet (m, k, l, d)."""
        return isinstance(self.get("blender_cloth"), dict)

    @property
    def blender_cloth(self) -> dict | None:
        return self.get("blender_cloth")

    @property
    def params(self) -> dict | None:
        return self.get("params")

    @property
    def paper_params(self) -> Params:
        """The paper model's fitted m, k, l, d (checked)."""
        if not isinstance(self.get("params"), dict):
            raise ClothFitError(
                f"{self.source}: no 'params' (m, k, l, d) in it" + (" (a Blender-cloth fit)" if self.is_blender else "")
            )
        return Params.from_dict(self["params"], self.source)

    @property
    def manipulation(self) -> dict:
        """The manipulation the fit estimated: ``time_offset_s``, ``handles`` and ``time_scale`` where given."""
        return {k: self[k] for k in ("time_offset_s", "handles", "time_scale") if self.get(k) is not None}

    def replay(self, default_model: str | dict[str, Any] | ClothModel | None = None) -> tuple[ClothModel, np.ndarray]:
        """(model, parameter row) that replays the fit (``physics.models.model_and_row``)."""
        from ..physics.models import model_and_row

        return model_and_row(self, default_model)

    def blender_settings(self) -> tuple[BlenderModel, dict[str, Any]]:
        """(BlenderModel, ClothSettings values) of a Blender-cloth fit; a paper-model fit is an error."""
        from ..physics.models import BlenderModel

        model, row = self.replay()
        if not isinstance(model, BlenderModel):
            raise ClothFitError(
                f"{self.source}: a {model.name}-model fit has no Blender cloth settings "
                "(fit with --model blender, or warm-start one from it with --init)"
            )
        return model, model.settings(row)

    def blender_export(self) -> dict:
        """What ``export-blender-cloth`` prints: ``blender_cloth`` (checked ClothSettings values),
        ``blender_scene`` (the frame rate they belong to) and, when the fit estimated it,
        ``manipulation`` (where the pins go, when the cloth is let go)."""
        model, s = self.blender_settings()
        out = {"blender_cloth": s, "blender_scene": {"fps": model.fps}}
        if self.manipulation:
            out["manipulation"] = self.manipulation
        if self.get("colliders"):
            out["colliders"] = self["colliders"]
            out["collision_settings"] = self.get("collision_settings") or {}
        if self.get("intervals"):  # how sure each setting is (fitting/intervals.py); undetermined ones keep values
            out["intervals"] = {n: v for n, v in self["intervals"].items() if n in s}
            out["undetermined"] = list(self.get("undetermined") or [])
            caveat = intervals_caveat(self)
            if caveat:
                out["intervals_caveat"] = caveat
        return out


def interval_comments(res: dict) -> list[str]:
    """``interval_lines`` as comment lines of a Python file (the export's script, a cloth preset)."""
    return [f"# {line}" for line in interval_lines(res)]


def interval_lines(res: dict) -> list[str]:
    """A result's intervals for people, one line per free setting: value, 90 % interval, and UNDETERMINED where
    the capture cannot tell it (the command line, the overlay's legend and the add-on's panel show these);
    the note instead where the fit has none."""
    iv = res.get("intervals")
    if not iv:
        return [f"no intervals: {res['intervals_note']}"] if res.get("intervals_note") else []
    values = dict(res.get("params") or {}, **(res.get("blender_cloth") or {}))
    und = set(res.get("undetermined") or [])
    out = ["90 % intervals (from the error's own noise)"]
    caveat = intervals_caveat(res)
    if caveat:
        out.append(f"CAUTION: {caveat}")
    for n, (lo, hi) in iv.items():
        if n in values:
            out.append(f"{n} {values[n]:.4g} [{lo:.4g}, {hi:.4g}]" + ("  UNDETERMINED" if n in und else ""))
    return out


def _fit_ratio(fl: dict) -> float | None:
    """A floor block's ratio of the fit's error to its floor: held-out where the fit has held-out images."""
    return fl.get("heldout_ratio") if fl.get("heldout_ratio") is not None else fl.get("train_ratio")


def intervals_caveat(res: dict) -> str | None:
    """What a result's intervals cannot say, where it ends far above its floor: they describe the neighbourhood
    of the fit, and a fit far above its floor may sit in another basin than the cloth's (the intervals stage
    cannot see that: ``intervals.py``), so the cloth's settings may lie outside them. None otherwise (an
    export's own ``intervals_caveat``, which carries it without the floor, is returned as it is)."""
    if res.get("intervals_caveat"):
        return res["intervals_caveat"]
    fl = res.get("floor") or {}
    if not fl.get("far_above"):
        return None
    ratio = _fit_ratio(fl)
    at = f"{ratio:.1f}x" if isinstance(ratio, (int, float)) else "far"
    return (
        f"the fit ends {at} above its floor, perhaps in another basin than the cloth's: these intervals describe "
        "that basin, and the cloth's settings may lie outside them"
    )


def uncertainty_caveat(res: dict) -> str | None:
    """What the offsets' stated uncertainties are, where a fit states any: the curvature of the error along each
    offset alone at the fitted point, the settings held, so an offset that trades against the settings may lie
    further off (how far, on the offsets goal's fits (lab/fit_goals.py offsets): docs/fit_goals.md, figure source fit_goals_offsets_coverage);
    where the fit ends far above its floor, that it may sit in a wrong basin, where the curvature says even less.
    None where none is stated."""
    fl = res.get("floor") or {}
    stated = res.get("time_offset_uncertainty_s") is not None or any(
        u is not None
        for h in (res.get("handles") or [])
        if isinstance(h, dict)
        for u in (h.get("offset_uncertainty_m") or [])
    )
    if not stated:
        return None
    ratio = _fit_ratio(fl)
    if fl.get("far_above") and ratio is not None:
        return (
            f"the offsets' uncertainties are the error's curvature at the fitted point, and the fit ends {ratio:.1f}x "
            f"above its floor: the true offsets may lie further off than they say"
        )
    return (
        "the offsets' uncertainties are the error's curvature along each offset alone, the settings held at the "
        "fitted point: an offset that trades against the settings (a released corner's height) may lie further off "
        "than it says"
    )


def search_looks(looks: dict, n_images: int) -> dict:
    """The result's ``looks``: the main search's independent starts (``StagedCMA.looks``), each start's best
    training error as a mean E_sil in %, and how many ended in the basin of the best one."""
    return {
        "starts": looks["starts"],
        "agreeing": looks["agreeing"],
        "ended_E_sil_pct": [100.0 * float(f) / n_images for f in looks["ended"]],
        "settings": looks["settings"],
        "rule": (
            f"a start agrees when each of {', '.join(looks['settings'])} ends within {D.LOOKS_AGREE_UNIT:g} of its "
            f"search range (log-scaled) of the best start's"
        ),
    }


def job_result(job: FitJob, paper: bool, searches: dict | None = None) -> FitResult:
    """The result of ``job`` (a ``fitting.job.FitJob``) so far: what a fit writes. ``paper``: a fit of
    the paper's sheet (``params``), else of Blender's cloth (``blender_cloth``); ``searches``: the searches
    again (``again.searches_result``)."""
    bp = job.best_params
    n_img = job.objective.n_images
    history = job.state.history_prev + (
        [[a + job.state.done_evals, b] for a, b in job.opt_history()] if job.state.stage in ("search", "rung") else []
    )
    res = {
        "format": RESULT_FORMAT,
        "version": RESULT_VERSION,
        "capture": os.path.abspath(job.capture.root),
        "capture_hash": job.capture_hash,
        "silhouettes_hash": job.silhouettes_hash,
        "optimizer": job.optimizer_name,
        "seed": job.config.seed,
        "train_cameras": [job.capture.cameras[c].name for c in job.train_cameras],
        "train_camera_indices": job.train_cameras,
        "train_times": job.train_times,
        "resolution": job.config.resolution,
        "evaluations": job.evaluations,
        "generations": job.generation,
        "max_evaluations": job.config.max_evaluations,
        "stop_reason": job.state.stop_reason,
        "converged_by": list(
            getattr(job.opt, "run_stops", None)
            or ([job.opt.stop_reason] if getattr(job.opt, "stop_reason", None) else [])
        ),
        "exploded_candidates": job.state.exploded,
        "best_E_all": finite_or_none(job.best_error),
        "best_E_sil_mean_pct": finite_or_none(100.0 * job.best_error / n_img),
        "n_train_images": n_img,
        "model": job.model_at(job.chosen_quality()).to_dict(),
        "params": bp if paper else None,
        "identifiable": identifiable(bp) if bp and paper else None,
        "mass_source": job.m_source,
        "note": job.par.note,
        "finished": job.state.finished,
        "cancelled": job.state.cancelled,
        "error": job.state.error,
        "elapsed_s": job.state.elapsed,
        "backend": job.objective.backend,
        "stages": job.state.records,
        "start_E_sil_mean_pct": None
        if job.state.start_f is None
        else finite_or_none(100.0 * job.state.start_f / n_img),
        "history": history,
    }
    if bp and not paper:
        with job.at_quality(job.chosen_quality()):
            res.update(job.par.describe(job.best_x[: job.npar]))
            if job.start_x is not None:  # what the fit was given (verdict ``start_better``: keep them)
                res["start_settings"] = job.par.describe(job.start_x[: job.npar]).get("blender_cloth")
    # the starts of the search that found the best point (a fit that searched again: the lowest of its searches)
    searched = [r for r in job.state.records if r["stage"] == "search" and "looks" in r]
    looks = (
        min(searched, key=lambda r: math.inf if r.get("best_f") is None else r["best_f"])["looks"] if searched else None
    )
    if looks is not None:
        res["looks"] = search_looks(looks, n_img)
    if job.ladder is not None and job.ladder.tried:
        res["quality_choice"] = job.ladder.describe(n_img)
        if isinstance(res.get("blender_cloth"), dict):
            res["blender_cloth"]["quality"] = job.chosen_quality()
    res.update(job.manipulation())
    cols = job.capture.scenario.colliders
    if cols is not None:  # what the cloth lands on: the export and Apply build it in Blender
        res["colliders"] = [c.to_dict() for c in cols.colliders]
        res["collision_settings"] = cols.settings_dict()
    if len(job.takes) > 1:
        res["takes"] = job.take_entries()
    st = job.state.intervals
    if st is not None and st.get("result"):
        res.update(st["result"])
    else:
        res["intervals"] = None
        res["undetermined"] = None
        res["intervals_note"] = job.intervals_note or "intervals not estimated: the fit stopped before them"
    if bp:  # the free settings at their search bounds, then the offsets at theirs (manipulation's at_bound)
        res["settings_at_bound"] = settings_at_bound(job.par, job.best_x)
        res["at_bound"] = list(res["settings_at_bound"]) + list(res.get("at_bound") or [])
    if job.state.final is not None:
        res["floor"] = job.state.final
        caveat = uncertainty_caveat(res)
        if caveat:
            res["uncertainty_caveat"] = caveat
            res["manipulation_note"] = "; ".join(x for x in (res.get("manipulation_note"), caveat) if x)
    if job.evaluator is not None:
        res["raster_backend"] = res["backend"]
        res.update(job.evaluator.describe())
        res["seconds"] = job.state.elapsed
    gt = (job.capture.meta or {}).get("true_params")
    if gt and bp and paper:
        # the capture's own record of its truth: free-form metadata, never a reason to lose the result
        try:
            truth = Params.from_dict(gt, "capture meta.true_params").as_dict()
        except ClothFitError as e:
            res["true_params_ignored"] = str(e)
        else:
            res["true_params"] = truth
            res["true_identifiable"] = identifiable(truth)
            est, tru = identifiable(bp), identifiable(truth)
            res["identifiable_error_pct"] = {
                k: (100.0 * abs(est[k] - tru[k]) / abs(tru[k]) if tru[k] else None) for k in est
            }
    res.update(searches or {})
    res["verdict_kind"], res["verdict"] = verdict(res)
    return FitResult(res)
