"""Searching again: a search that ended above the floor its own jitter allows runs again from another seed.

A search can end in a basin other than the cloth's: on the search captures (docs/search.md) a third of the fits of
one search do, and their error is then above what the truth's own neighbours score. A fit knows that when its
search ends, from the training images alone: ``diagnose.above_jitter_floor`` puts the search's best error beside
the images' noise floor plus the jitter of its neighbours (``jitter.py``). Where it is above both, the fit
searches again from another seed (``SEARCH_AGAIN_SEED`` apart), with the first search's budget added to the fit's,
up to ``searches`` in all (``FitConfig.searches``, default ``FIT_SEARCHES``), and keeps the best point of all
(``RunState.track``); the ladder, the profile and the intervals start from it. A fit of less than
``SEARCH_AGAIN_MIN_BUDGET`` evaluations (a quick look), several takes, a scene's own solver, or a quality still to be
chosen never searches again.

``start_again(job)`` makes that decision when a search ends (``FitJob._next_stage``) and records it in
``job.state.again``: ``searches`` started again, the evaluation ``start`` of the running one, ``why`` each began,
how the last check ``ended``, and where each search ended (``ends``). ``searches_result(job)`` is the result's ``searches`` block.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .. import defaults as D
from .diagnose import above_jitter_floor

if TYPE_CHECKING:
    from .job import FitJob


def searches_allowed(job: FitJob) -> int:
    """How many searches this fit may run in all: ``FitConfig.searches`` (default ``FIT_SEARCHES``), or 1 (it never
    searches again) for a fit of less than ``SEARCH_AGAIN_MIN_BUDGET`` evaluations, with a scene's own solver, of
    several takes, or whose quality is still to be chosen: there the search runs at the ladder's start quality,
    whose error also holds what that quality cannot follow, so its end beside the jitter floor cannot tell a wrong
    basin from a wrong quality (docs/search.md: Warp's cotton searched three times at its start quality, the three
    within a few per cent of each other, before the ladder halved the error)."""
    cfg = job.config
    n = D.FIT_SEARCHES if cfg.searches is None else int(cfg.searches)
    if (
        cfg.max_evaluations < D.SEARCH_AGAIN_MIN_BUDGET
        or job.evaluator is not None
        or len(job.takes) > 1
        or job.ladder is not None
    ):
        return 1
    return n


def start_again(job: FitJob) -> bool:
    """At the end of a search: whether to search again (and ``job.state.again`` says why, how the check ended,
    and where each search ended: ``ends``, [best error, best point] each). The caller builds the new search's
    optimiser (``FitJob.main_optimizer``: the seed moves with ``job.state.again``)."""
    s = job.state
    ag = s.again or {"searches": 0, "start": 0, "why": [], "ended": None, "ends": []}
    opt = job.opt
    ends = list(ag.get("ends") or []) + [
        [] if opt.best_x is None else [float(opt.best_f), [float(v) for v in opt.best_x]]
    ]
    if ag["searches"] + 1 >= searches_allowed(job) or s.stage_quality not in s.best_by_quality:
        if ag["searches"]:  # the last search allowed: where it ended, for the result
            s.again = dict(ag, ends=ends)
        return False
    f, x = s.best_by_quality[s.stage_quality]
    why = above_jitter_floor(job, np.asarray(x, dtype=np.float64), f)
    if why is None:
        if ag["searches"]:  # a search again that reached the floor: said in the result
            s.again = dict(ag, ended="at the floor its jitter allows", ends=ends)
        return False
    s.again = {"searches": ag["searches"] + 1, "start": s.done_evals, "why": ag["why"] + [why], "ended": None}
    s.again["ends"] = ends
    return True


def extra_budget(job: FitJob) -> int:
    """The evaluations the searches again add to the fit's budget: the first search's share for each."""
    return (job.state.again or {}).get("searches", 0) * job.search_end


def _settings(job: FitJob, x: list) -> dict:
    """A point's free settings in the result's units (``blender_cloth``'s, or the paper's m, k, l, d)."""
    return dict(job.par.reported(name, x[k]) for k, name in enumerate(list(job.space.names)[: job.npar]))


def searches_result(job: FitJob) -> dict:
    """The result's ``searches`` block: how many searches ran, why each again, their best training errors
    (E_sil per image, %) and where each ended (``ended_at``: each search's best settings in the result's units, so
    a user sees whether the searches found one basin); {} for a fit of one search."""
    ag = job.state.again
    if not ag or not ag["searches"]:
        return {}
    n = job.objective.n_images
    ends = [r.get("best_f") for r in job.state.records if r["stage"] == "search"]
    return {
        "searches": {
            "count": ag["searches"] + 1,
            "why": ag["why"],
            "ended": ag["ended"],
            "best_E_sil_pct": [None if f is None else 100.0 * float(f) / n for f in ends],
            "ended_at": [_settings(job, e[1]) if e else None for e in ag.get("ends") or []],
            "note": f"a search that ends above the floor its own jitter allows searches again from another seed "
            f"(up to {searches_allowed(job)} in all, fit --searches): the best point of all is kept",
        }
    }
