"""Each take alone: can one set of settings serve every take of a fit of several?

After the joint search (and the offsets' profile and the intervals, which may move its best point), each take
is searched on its own for
``D.TAKES_ALONE_EVALUATIONS`` evaluations: CMA-ES over the settings and that take's own unknowns, started at the
joint fit's best point (``takes.TakeView``), at the quality the fit chose. Its best training error is what the take
reaches alone near the joint settings (a local search: far-off settings that serve it better are not looked for).
The floor report (``diagnose.report_takes``) puts each take's joint error beside it: a take the joint settings
serve more than ``D.TAKES_ALONE_FACTOR`` times worse than it serves itself says that one set of settings does not
serve every take. The joint fit's best point is not changed by this stage.

One generation per ``alone_step``; the state (``job.state.alone``: the take running, the results so far, the running
CMA-ES's own state) is plain JSON in the checkpoint, so a resumed fit continues it exactly.
"""

from __future__ import annotations

import math
from typing import Any

from .. import defaults as D
from .optimise import make_optimizer, optimizer_from_state
from .parameters import joint_space
from .takes import TakeView


def alone_budget(job: Any) -> int:
    """The evaluations the stage takes: 0 for a fit of one take, or where the fit's budget is under
    ``D.TAKES_ALONE_BUDGET_SHARE`` times it (the joint search first)."""
    need = D.TAKES_ALONE_EVALUATIONS * len(job.takes)
    if len(job.takes) < 2 or job.config.max_evaluations < D.TAKES_ALONE_BUDGET_SHARE * need:
        return 0
    return need


def alone_note(job: Any) -> str | None:
    """Why a fit of several takes does not search each take alone (its budget), or None."""
    if len(job.takes) < 2 or alone_budget(job):
        return None
    need = D.TAKES_ALONE_BUDGET_SHARE * D.TAKES_ALONE_EVALUATIONS * len(job.takes)
    return (
        f"each take not searched alone: a budget of {job.config.max_evaluations} evaluations is under the {need} "
        f"that leave the joint search most of it (--max-evaluations {need} or more)"
    )


def _optimizer(job: Any, view: TakeView, state: dict | None) -> Any:
    if state is not None:
        return optimizer_from_state(state)
    space = joint_space(job.par.space, view.manip)
    return make_optimizer(
        "cma-es",
        space,
        job.config.seed,
        initial=[view.best_x],
        sigma0=D.WARM_START_SIGMA,
        restarts=0,
        popsize=4 + int(3 * math.log(space.n)),
    )


def alone_step(job: Any) -> bool:
    """One generation of the take running alone; True once every take has had its run."""
    st = job.state.alone
    if st is None:
        st = job.state.alone = {"take": 0, "results": [], "opt": None}
    k = st["take"]
    if k >= len(job.takes):
        return True
    view = TakeView(job, k)
    if job.alone_opt is None:
        job.alone_opt = _optimizer(job, view, st.get("opt"))
    opt = job.alone_opt
    X = opt.ask()
    f = view.evaluate(X)
    opt.tell(X, f)
    job.state.done_evals += len(X)
    job.state.exploded += int(sum(1 for v in f if not math.isfinite(v)))
    if opt.evaluations >= D.TAKES_ALONE_EVALUATIONS or opt.stopped:
        n = view.objective.n_images
        alone = float(opt.best_f) if opt.best_x is not None and math.isfinite(opt.best_f) else None
        joint = view.best_error
        st["results"].append(
            {
                "take": job.takes[k].name,
                "alone_E_sil_pct": None if alone is None else 100.0 * min(alone, joint) / n,
                "joint_E_sil_pct": 100.0 * joint / n if math.isfinite(joint) else None,
                "evaluations": int(opt.evaluations),
            }
        )
        st["take"], st["opt"], job.alone_opt = k + 1, None, None
    return st["take"] >= len(job.takes)


def disagreeing(results: list[dict]) -> list[dict]:
    """The takes the joint settings serve more than ``D.TAKES_ALONE_FACTOR`` times worse than they serve
    themselves (``alone_step``'s results)."""
    return [
        r
        for r in results
        if r.get("alone_E_sil_pct")
        and r.get("joint_E_sil_pct")
        and r["joint_E_sil_pct"] > D.TAKES_ALONE_FACTOR * r["alone_E_sil_pct"]
    ]


def disagreement_text(results: list[dict]) -> str | None:
    """One line: which takes one set of settings does not serve, each with its error here and alone; or None."""
    bad = disagreeing(results)
    if not bad:
        return None
    return "one set of settings does not serve every take: " + "; ".join(
        f"take {r['take']} {r['joint_E_sil_pct']:.2f} % with the shared settings against "
        f"{r['alone_E_sil_pct']:.2f} % fitted alone"
        for r in bad
    )
