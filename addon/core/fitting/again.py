"""Searching again: a search that ended above the floor its own jitter allows runs again from another seed.

A search can end in a basin other than the cloth's: on the search captures (docs/search.md) a third of the fits of
one search do, and their error is then above what the truth's own neighbours score. A fit knows that when its
search ends, from the training images alone: ``diagnose.above_jitter_floor`` puts the search's best error beside
the images' noise floor plus the jitter of its neighbours (``jitter.py``). Where it is above both, the fit
searches again from another seed (``SEARCH_AGAIN_SEED`` apart), with the first search's budget added to the fit's,
up to ``searches`` in all (``FitConfig.searches``, default ``FIT_SEARCHES``), and keeps the best point of all
(``RunState.track``); the ladder, the profile and the intervals start from it. A search that ends in the basin of
an earlier one (its strong settings within ``LOOKS_AGREE_UNIT`` of their range, as the result's ``looks`` counts a
search's starts) ends the searching: another seed found the same basin, so the basin is not what keeps the fit above
its floor. A fit of less than
``SEARCH_AGAIN_MIN_BUDGET`` evaluations (a quick look), several takes, or a scene's own solver never searches again.

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
    searches again) for a fit of less than ``SEARCH_AGAIN_MIN_BUDGET`` evaluations, with a scene's own solver, or
    of several takes."""
    cfg = job.config
    n = D.FIT_SEARCHES if cfg.searches is None else int(cfg.searches)
    if cfg.max_evaluations < D.SEARCH_AGAIN_MIN_BUDGET or job.evaluator is not None or len(job.takes) > 1:
        return 1
    return n


def start_again(job: FitJob) -> bool:
    """At the end of a search: whether to search again (and ``job.state.again`` says why, or how the check
    ended). The caller builds the new search's optimiser (``FitJob.main_optimizer``: the seed moves with
    ``job.state.again``). A search that ends in the basin an earlier one ended in (``agreeing``) is not
    followed by another: two searches from different seeds found one basin, so what keeps the fit above its
    floor is not the basin (the manipulation's unknowns, the search's precision, the model), and a third
    search costs its budget for nothing."""
    s = job.state
    ag = s.again or {"searches": 0, "start": 0, "why": [], "ended": None, "ends": []}
    if ag["searches"] + 1 >= searches_allowed(job) or s.stage_quality not in s.best_by_quality:
        return False
    f, x = s.best_by_quality[s.stage_quality]
    why = above_jitter_floor(job, np.asarray(x, dtype=np.float64), f)
    ends = list(ag.get("ends") or []) + [ended_point(job)]
    if why is None:
        if ag["searches"]:  # a search again that reached the floor: said in the result
            s.again = dict(ag, ended="at the floor its jitter allows", ends=ends)
        return False
    same = agreeing(job, ends)
    if same is not None:
        s.again = dict(ag, ends=ends, ended=same)
        return False
    s.again = {"searches": ag["searches"] + 1, "start": s.done_evals, "why": ag["why"] + [why], "ended": None}
    s.again["ends"] = ends
    return True


def ended_point(job: FitJob) -> list:
    """The search that just ended: ``[names compared, its best point's coordinates in the unit cube]`` (the
    search's strong settings where it reports its starts' agreement, else every coordinate), or [] before any."""
    opt = job.opt
    if opt.best_x is None:
        return []
    looks = opt.looks()
    names = list(looks["settings"]) if looks else list(job.space.names)
    u = job.space.encode(np.asarray(opt.best_x, dtype=np.float64)[None])[0]
    return [names, [float(u[job.space.names.index(n)]) for n in names]]


def agreeing(job: FitJob, ends: list) -> str | None:
    """Where the last of the searches' ``ends`` lies in the basin of an earlier one (every compared setting
    within ``LOOKS_AGREE_UNIT`` of its search range, log-scaled, as the result's ``looks`` counts starts): how the
    check ended, for the result; else None."""
    if len(ends) < 2 or not ends[-1]:
        return None
    names, u = ends[-1]
    for k, e in enumerate(ends[:-1]):
        if e and e[0] == names and np.all(np.abs(np.array(e[1]) - np.array(u)) <= D.LOOKS_AGREE_UNIT):
            return (
                f"in the basin search {k + 1} ended in (each of {', '.join(names)} within {D.LOOKS_AGREE_UNIT:g} "
                f"of its search range): what keeps it above its floor is not the basin, so no search again"
            )
    return None


def extra_budget(job: FitJob) -> int:
    """The evaluations the searches again add to the fit's budget: the first search's share for each."""
    return (job.state.again or {}).get("searches", 0) * job.search_end


def searches_result(job: FitJob) -> dict:
    """The result's ``searches`` block: how many searches ran, why each again, their best training errors
    (E_sil per image, %); {} for a fit of one search."""
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
            "note": f"a search that ends above the floor its own jitter allows searches again from another seed "
            f"(up to {searches_allowed(job)} in all, fit --searches): the best point of all is kept",
        }
    }
