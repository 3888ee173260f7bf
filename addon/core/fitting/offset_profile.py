"""After a fit's search, where the manipulation has unknowns: the polish of its offsets and their profile.

:func:`profile_step` is one step of a :class:`~.job.FitJob` in its "profile" stage: a polish round
(:func:`polish_round`: the offsets stepped with the settings held, while a step lowers the error), or, once
the polish is over, the profile itself (the objective either side of each offset: its uncertainty, or that
the fit cannot separate it). Both read and write the job's state (its best point, evaluations, profile), so
a checkpoint taken between any two steps resumes exactly (docs/real_captures.md).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from .. import defaults as D
from .result import finite_or_none as _finite

if TYPE_CHECKING:
    from .job import FitJob


def polish_round(
    job: FitJob, f0: float, x0: np.ndarray, steps: np.ndarray, lo: np.ndarray, hi: np.ndarray
) -> tuple[bool, np.ndarray | None]:
    """One polish round before the profile: ``steps`` holds the best point with each offset moved either way
    by the profile's step (kept within the bounds here). Where some of them beat the best, the improving
    steps taken together (or the best single one, if better) become the best: returns (True, None), and
    the profile waits for the next round. Else (False, their errors), the errors given back for the
    profile when no step was cut at a bound (the same points), else None."""
    k = job.manip.n
    S = steps.copy()
    S[:, job.npar :] = np.clip(S[:, job.npar :], lo, hi)
    f = job.evaluate(S)
    job.state.exploded += int(np.sum(~np.isfinite(f)))
    job.state.done_evals += 2 * k
    job.state.polish_rounds += 1
    g = np.where(np.isfinite(f), f, np.inf)
    if not np.min(g) < f0:
        return False, (f if np.array_equal(S, steps) else None)
    xc = x0.copy()
    for i in range(k):
        if min(g[2 * i], g[2 * i + 1]) < f0:
            xc[job.npar + i] = S[2 * i if g[2 * i] < g[2 * i + 1] else 2 * i + 1, job.npar + i]
    fc = float(job.evaluate(xc[None])[0])
    job.state.done_evals += 1
    j = int(np.argmin(g))
    fb, xb = (fc, xc) if math.isfinite(fc) and fc < g[j] else (float(g[j]), S[j].copy())
    job.state.best_by_quality[job.chosen_quality()] = [float(fb), np.asarray(xb, dtype=np.float64).tolist()]
    job.state.history_prev.append([int(job.state.done_evals), float(fb)])
    return True, None


def profile_step(job: FitJob) -> None:
    """Polish rounds first (``polish_round``: up to ``PROFILE_POLISH_ROUNDS``, one per call; a step of the
    profile's size while one lowers the error, then halved down to ``PROFILE_POLISH_FINEST`` of it), then the
    objective either side of the best offsets: each one's uncertainty. The centre is the mean of
    ``PROFILE_JITTER`` evaluations at the best point moved by a part in 10^7 (every coordinate): on
    Blender's float32 cloth that already changes the trajectory, and the best point itself is the
    luckiest of thousands of such draws, so a curvature measured from it is too steep. The uncertainty
    is the offset at which the quadratic through the three points rises by ``PROFILE_RISE`` of the error
    or by ``PROFILE_JITTER_SIGMAS`` of the jitter's spread, whichever is more: a rise within the
    objective's own jitter tells nothing."""
    f0, x0 = job.best_point()
    names = job.manip.names
    lo = np.array([job.manip.bounds[n][0] for n in names])
    bounds = np.array([job.manip.bounds[n][1] for n in names])
    h = D.PROFILE_STEP * bounds
    k = len(names)
    J = D.PROFILE_JITTER
    X = np.repeat(x0[None], 2 * k + J, 0)
    for i in range(k):
        X[2 * i, job.npar + i] += h[i]
        X[2 * i + 1, job.npar + i] -= h[i]
    f_steps = None
    if job.state.polish_rounds < D.PROFILE_POLISH_ROUNDS:
        scale = job.state.polish_scale
        steps = X[: 2 * k] if scale == 1.0 else x0 + scale * (X[: 2 * k] - x0)
        moved, f_steps = polish_round(job, f0, x0, steps, lo, bounds)
        if moved:
            return
        if scale > D.PROFILE_POLISH_FINEST:  # no step of this size helps: a finer one next round
            job.state.polish_scale = scale / 2
            return
        f_steps = f_steps if scale == 1.0 else None  # the profile's own points only at the profile's step
    signs = np.random.default_rng(D.PROFILE_JITTER_SEED).choice([-1.0, 1.0], size=(J, len(x0)))
    tiny = np.concatenate([np.abs(x0[: job.npar]), bounds]) * D.PROFILE_JITTER_RELATIVE
    X[2 * k :] += signs * tiny
    todo = X if f_steps is None else X[2 * k :]  # the steps' errors, when the last polish round has them
    f = job.evaluate(todo)
    job.state.exploded += int(np.sum(~np.isfinite(f)))
    job.state.done_evals += len(todo)
    if f_steps is not None:
        f = np.concatenate([f_steps, f])
    fj = f[2 * k :][np.isfinite(f[2 * k :])]
    centre = float(np.mean(fj)) if len(fj) else f0
    spread = float(np.std(fj, ddof=1)) if len(fj) > 1 else 0.0
    rise = max(D.PROFILE_RISE * centre, D.PROFILE_JITTER_SIGMAS * spread)
    prof = {}
    for i, n in enumerate(names):
        fp, fm = float(f[2 * i]), float(f[2 * i + 1])
        a = (fp + fm - 2 * centre) / (2 * h[i] ** 2) if math.isfinite(fp) and math.isfinite(fm) else float("nan")
        unc = math.sqrt(rise / a) if a > 0 and rise > 0 else None
        prof[n] = {
            "step": float(h[i]),
            "E_plus": _finite(fp),
            "E_minus": _finite(fm),
            "E_best": _finite(f0),
            "E_centre": _finite(centre),
            "E_jitter_sd": _finite(spread),
            "rise": _finite(rise),
            "uncertainty": unc,
            "separated": unc is not None and unc < bounds[i],
        }
    job.state.profile = prof
    job.end_profile()
