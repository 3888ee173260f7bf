"""How sure each setting is: marginal intervals from the training error around the fit.

After the search (and the quality ladder and the manipulation's profile, where those run) a fit's
"intervals" stage measures the training error around its best point, in the search's unit cube (log
scale for every scale setting), one batch of evaluations per step, in three phases:

1. **jitter**: ``INTERVAL_JITTER`` evaluations at the best point moved by a part in 10^7 (random signs). No
   setting can tell those points apart, yet on Blender's float32 cloth a chaotic motion already changes
   there: their standard deviation ``sigma`` is the objective's own noise, and their mean the error the
   best point's neighbourhood really has (the best point is the luckiest of thousands of draws).
2. **axes**: every coordinate moved either way, the step grown while the error stays within the threshold
   below and shrunk while it rises by more than six (``INTERVAL_AXIS_ROUNDS`` rounds): the scale of each coordinate with the others held.
   A coordinate that does not rise even at the widest step is flat: no other setting can make its
   marginal narrower than that.
3. **sample** (adaptive importance sampling, population Monte Carlo): ``INTERVAL_ROUNDS`` rounds of
   ``interval_batch(n)`` points drawn from a Gaussian around the best point, the first at the axes'
   scales, each later one fitted to the weighted points so far (its covariance widened by
   ``INTERVAL_WIDEN``: valleys that run across the axes are followed). Every point is weighted by
   ``exp(-(E - E_ref) / T)`` over the density it was drawn from (all rounds' proposals as one
   mixture); points outside the search's bounds weigh nothing. Each coordinate's interval is the 5 % and
   95 % weighted quantiles of the points: **marginal** (every other setting and offset free), not the
   error's curvature with everything else held. The weights of a chaotic take's errors often rest on a few
   points (the result's ``effective_points``), and a quantile of two points says little: every interval is
   therefore at least as wide as the axes phase's own rise allows (``axis_reach``: the 90 % interval of a
   quadratic error along that coordinate alone; a marginal is never narrower than a conditional).
   Where a point of the stage scored lower than the search's end, it becomes the fit's best (the result's
   ``improved_best``): the values reported are its, and each interval holds it with the same reach around it.

The temperature comes from the capture's own noise, not from a choice: two evaluations that differ by
jitter alone differ by more than ``INTERVAL_Z * sqrt(2) * sigma`` one time in twenty, so a rise of that
much (the threshold) is where a setting starts to be excluded; for a locally quadratic error the 90 %
marginal region is the rise of ``chi2_1(0.90) / 2 = 1.353`` temperatures, so ``T = threshold / 1.353``.
The threshold never falls below what the images' pixel noise alone could make (``pixel_threshold``,
from their noise floor and outline length). An interval that reaches the search's bound, or spans more
than a factor ``INTERVAL_UNDETERMINED_FACTOR`` (a setting on a linear scale: more than
``INTERVAL_UNDETERMINED_SHARE`` of its search range), marks its setting **undetermined**: the capture cannot
tell it (another camera, a take with another handling or a higher resolution may).

What it cannot see: a search that ended in the wrong basin gets an interval around the wrong basin.
The intervals describe the neighbourhood of the answer; the result's verdict and floor say whether
the answer's basin is the one the images ask for.

The stage's whole state is plain numbers (``job.state.intervals``), written to the checkpoint between any two
steps, so a resumed fit reports the same intervals.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from .. import defaults as D
from ..errors import ClothFitError
from ..observation.floor import capture_floor
from .result import finite_or_none as _finite

if TYPE_CHECKING:
    from .job import FitJob


def interval_batch(n: int) -> int:
    """Points per sampling round for ``n`` coordinates."""
    return max(D.INTERVAL_BATCH_MIN, D.INTERVAL_BATCH_PER_DIM * n)


def intervals_plan(job: FitJob) -> str | None:
    """None when the fit can end with its intervals stage, else the reason it cannot (said in the result)."""
    cfg = job.config
    if not cfg.intervals:
        return "intervals not asked for (--no-intervals)"
    if job.objective.n_images < D.INTERVAL_MIN_IMAGES:
        return (
            f"intervals not estimated: {job.objective.n_images} training image(s) cannot tell the settings' "
            f"noise from their effect (need {D.INTERVAL_MIN_IMAGES}: more cameras or frames)"
        )
    need = interval_budget(job.space.n)
    if cfg.max_evaluations < D.INTERVAL_BUDGET_FACTOR * need:
        return (
            f"intervals not estimated: a budget of {cfg.max_evaluations} evaluations is under "
            f"{D.INTERVAL_BUDGET_FACTOR}x the {need} they need for {job.space.n} unknowns "
            f"(--max-evaluations {D.INTERVAL_BUDGET_FACTOR * need} or more)"
        )
    return None


def interval_budget(n: int) -> int:
    """Evaluations the intervals stage may use for ``n`` coordinates (every phase at its most)."""
    return D.INTERVAL_JITTER + 2 * n * D.INTERVAL_AXIS_ROUNDS + D.INTERVAL_ROUNDS * interval_batch(n)


def pixel_threshold(floors: list, boundaries: list) -> float:
    """The smallest rise of the summed training error that pixel noise alone cannot make (one-sided 95 %).

    With an image's boundary pixels flipped at rate ``p`` (its floor is ``p * boundary / area``), a model
    that differs from the best on ``D`` outline pixels raises its ``E_sil`` by ``D / area`` on average and by
    a random ``2 sqrt(p D) / area`` either way. Summed over the training images, a rise ``R`` stands out of
    that noise (z standard deviations) once ``R > 4 z^2 p / area = 4 z^2 floor / boundary`` (the mean over the
    images: the sum's variance grows with ``R`` itself, not with the number of images)."""
    vals = [f / b for f, b in zip(floors, boundaries) if f > 0 and b > 0]
    if not vals:
        return 0.0
    z = D.INTERVAL_Z
    return 4.0 * z * z * float(np.mean(vals))


def _pixel_part(job) -> float:
    """``pixel_threshold`` of the job's training images (their noise floor at the fit resolution); 0 for a job
    without images (an objective given as a function)."""
    if getattr(job, "capture", None) is None:
        return 0.0
    takes = getattr(job, "takes", None) or [job]  # several takes: every take's training images
    ims = []
    for t in takes:
        try:
            cf = capture_floor(t.capture, t.train_cameras, t.train_frames, job.config.resolution)
        except ClothFitError:
            return 0.0
        ims += [e for row in cf.images for e in row]
    # the pixel-noise part only: a splatting error (points made into silhouettes) is not a random flip per pixel
    return pixel_threshold([e.noise + e.resampling for e in ims], [e.rim * e.fit_area for e in ims])


def start(job: FitJob) -> dict:
    """The stage's initial state at the job's best point."""
    f0, x0 = job.best_error, job.best_x
    u0 = np.clip(job.space.encode(x0), 0.0, 1.0)
    return {
        "pixel_threshold": _pixel_part(job),
        "phase": "jitter",
        "round": 0,
        "u0": u0.tolist(),
        "f0": _finite(f0),
        "U": [],
        "F": [],
        "sigma": None,
        "centre": None,
        "threshold": None,
        "h": [D.INTERVAL_AXIS_STEP] * job.space.n,
        "settled": [False] * job.space.n,
        "flat": [False] * job.space.n,
        "active": None,
        "temperature": None,
        "sample_start": None,
        "props": [],
        "result": None,
    }


def _evaluate(job, st, U):
    """Evaluate unit-cube points; record them in the state; errors (inf for a failed candidate)."""
    U = np.clip(np.atleast_2d(U), 0.0, 1.0)
    f = np.asarray(job.evaluate(job.space.decode(U)), dtype=np.float64)
    f = np.where(np.isfinite(f), f, np.inf)
    job.state.exploded += int(np.sum(~np.isfinite(f)))
    job.state.done_evals += len(U)
    st["U"] += U.tolist()
    st["F"] += [_finite(v) for v in f]
    return f


def _phase_jitter(job, st):
    u0 = np.array(st["u0"])
    x0 = job.space.decode(u0)
    X = job.space.neighbours(x0, D.INTERVAL_JITTER, D.PROFILE_JITTER_RELATIVE, D.INTERVAL_SEED)
    U = job.space.encode(X)
    f = _evaluate(job, st, U)
    fj = f[np.isfinite(f)]
    st["centre"] = float(np.mean(fj)) if len(fj) else st["f0"]
    st["sigma"] = float(np.std(fj, ddof=1)) if len(fj) > 1 else 0.0
    pix = st["pixel_threshold"]
    # a part in 10^6 of the error itself: the float32 simulation's rounding, below which nothing is measured
    st["threshold"] = max(D.INTERVAL_Z * math.sqrt(2.0) * st["sigma"], pix, 1e-6 * max(st["centre"] or 0.0, 1e-12))
    st["temperature"] = D.INTERVAL_CALIBRATION * st["threshold"] / D.INTERVAL_CHI2_HALF
    st["phase"] = "axes"


def _phase_axes(job, st):
    n = job.space.n
    u0 = np.array(st["u0"])
    h = np.array(st["h"])
    todo = [i for i in range(n) if not st["settled"][i]]
    U = np.repeat(u0[None], 2 * len(todo), 0)
    for k, i in enumerate(todo):
        U[2 * k, i] += h[i]
        U[2 * k + 1, i] -= h[i]
    f = _evaluate(job, st, U)
    thr, c = st["threshold"], st["centre"]
    settled, flat = list(st["settled"]), list(st["flat"])
    rises = st.setdefault("rise", [None] * n)  # per coordinate: [step, rise at -step, rise at +step], the last
    for k, i in enumerate(todo):
        sides = f[2 * k : 2 * k + 2]
        rises[i] = [float(h[i])] + [_finite(v - c) for v in sides[::-1]]
        rise = float(np.max(np.where(np.isfinite(sides), sides - c, np.inf)))
        flat[i] = False
        if rise < thr and h[i] < D.INTERVAL_AXIS_MAX:  # within the noise: not yet a rise
            h[i] = min(h[i] * 3.0, D.INTERVAL_AXIS_MAX)
        elif rise > 6 * thr and h[i] > D.INTERVAL_AXIS_MIN:
            h[i] = max(h[i] / 3.0, D.INTERVAL_AXIS_MIN)
        else:
            settled[i] = True
            # flat across the widest step either way: no other setting can make its marginal narrower
            flat[i] = h[i] >= D.INTERVAL_AXIS_MAX and rise < thr
    st["h"], st["settled"], st["flat"] = h.tolist(), settled, flat
    st["round"] += 1
    if all(settled) or st["round"] >= D.INTERVAL_AXIS_ROUNDS:
        st["active"] = [i for i in range(n) if not flat[i]]
        st["phase"], st["round"] = "sample", 0


def round_temperature(st: dict, r: int) -> float:
    """The temperature round ``r`` aims at: ``INTERVAL_ANNEAL`` times hotter per round before the last ones
    (a wide first look that narrows onto the error's own temperature, so that no round's points all miss)."""
    return st["temperature"] * D.INTERVAL_ANNEAL ** max(0, D.INTERVAL_HOT_ROUNDS - r)


def _proposal(st):
    """The Gaussian of the next sampling round (mean, covariance) in the active coordinates (unit cube)."""
    act = st["active"]
    u0, h = np.array(st["u0"])[act], np.array(st["h"])[act]
    if not st["props"]:
        return u0, np.diag(h**2)
    U, w = _weighted(st, round_temperature(st, len(st["props"])))
    if not np.sum(w) > 0:  # every point so far outside the bounds or failed: the last proposal again
        mean, cov = st["props"][-1]
        return np.array(mean), np.array(cov)
    Ua = U[:, act]
    mean = w @ Ua
    d = Ua - mean
    cov = (d * w[:, None]).T @ d
    cov = D.INTERVAL_WIDEN * cov + np.diag((0.25 * h) ** 2)  # widened, and never thinner than a quarter step
    return mean, cov


def _log_q(st, Ua):
    """Log density of the points under the mixture of every proposal so far (active coordinates)."""
    out = []
    for mean, cov in st["props"]:
        mean, cov = np.array(mean), np.array(cov)
        L = np.linalg.cholesky(cov)
        z = np.linalg.solve(L, (Ua - mean).T)
        out.append(-0.5 * np.sum(z * z, 0) - np.sum(np.log(np.diag(L))))
    A = np.array(out)
    m = A.max(0)
    return m + np.log(np.mean(np.exp(A - m), 0))


def _weighted(st, temperature=None):
    """The sampled points (unit cube) and their normalised importance weights at ``temperature`` (default:
    the error's own)."""
    temperature = st["temperature"] if temperature is None else temperature
    k0 = st["sample_start"]
    U = np.array(st["U"][k0:], dtype=np.float64)
    F = np.array([np.inf if v is None else v for v in st["F"][k0:]], dtype=np.float64)
    act = st["active"]
    inside = np.all((U >= 0.0) & (U <= 1.0), 1) & np.isfinite(F)
    logw = np.full(len(U), -np.inf)
    if inside.any():
        logw[inside] = -(F[inside] - st["centre"]) / temperature - _log_q(st, U[inside][:, act])
    m = np.max(logw)
    w = np.exp(logw - m) if np.isfinite(m) else np.zeros(len(U))
    return U, w / max(np.sum(w), 1e-300)


def _phase_sample(job, st):
    act = st["active"]
    n = len(st["u0"])
    k = interval_batch(n)
    if not act:  # every coordinate flat: nothing to sample
        st["phase"], st["result"] = "done", summarise(job, st)
        return
    if st["sample_start"] is None:
        st["sample_start"] = len(st["U"])
    mean, cov = _proposal(st)
    st["props"].append([mean.tolist(), cov.tolist()])
    rng = np.random.default_rng([D.INTERVAL_SEED, len(st["props"])])
    Z = rng.multivariate_normal(mean, cov, size=k, method="cholesky")
    U = np.repeat(np.array(st["u0"])[None], k, 0)
    U[:, act] = Z
    inside = np.all((U >= 0.0) & (U <= 1.0), 1)
    F = np.full(k, np.inf)
    if inside.any():  # outside the bounds: no evaluation (its weight is nothing)
        F[inside] = np.asarray(job.evaluate(job.space.decode(U[inside])), dtype=np.float64)
        job.state.done_evals += int(np.sum(inside))
    F = np.where(np.isfinite(F), F, np.inf)
    job.state.exploded += int(np.sum(inside & ~np.isfinite(F)))
    st["U"] += U.tolist()
    st["F"] += [_finite(v) for v in F]
    st["round"] += 1
    if st["round"] >= D.INTERVAL_ROUNDS:
        st["result"] = summarise(job, st)
        st["phase"] = "done"


def axis_reach(st: dict, i: int) -> tuple[float, float] | None:
    """The ends (unit cube) the error's rise along coordinate ``i`` alone allows, every other coordinate held:
    on each side, the 90 % end of a quadratic error that rises by what the axes phase measured at its last step
    (a rise within the noise counts as the threshold: the error is at least that flat). A marginal is never
    narrower than this conditional interval; where the sample's weights rest on few points, their quantiles
    can be. None where the axes phase did not measure the coordinate."""
    rise = (st.get("rise") or [None] * (i + 1))[i]
    if rise is None:
        return None
    step, below, above = rise
    u0 = st["u0"][i]
    ends = []
    for r in (below, above):
        r = math.inf if r is None else max(r, st["threshold"])
        ends.append(D.INTERVAL_Z * step * math.sqrt(st["temperature"] / (2.0 * r)))
    return u0 - ends[0], u0 + ends[1]


def _quantile(x, w, q):
    o = np.argsort(x)
    c = np.cumsum(w[o])
    return float(x[o][min(len(x) - 1, int(np.searchsorted(c, q * c[-1])))])


def summarise(job: FitJob, st: dict) -> dict:
    """The result's intervals (in the model's own units), what is undetermined, and how they were made."""
    space = job.space
    u0 = np.array(st["u0"])
    act = st["active"] or []
    low = lowest_point(st)  # where the result's values end: the stage's lowest point where it beat the fit's
    u_low = u0 if low is None else np.array(low[1])
    x_best = space.decode(u_low)
    U, w = _weighted(st) if act and st["sample_start"] is not None else (np.zeros((0, len(u0))), np.zeros(0))
    ess = float(1.0 / np.sum(w**2)) if np.sum(w) > 0 else 0.0
    tail = (1.0 - D.INTERVAL_LEVEL) / 2
    edge = D.INTERVAL_BOUND_EDGE
    intervals, undetermined, details = {}, [], {}
    for i, name in enumerate(space.names):
        if i in act and ess > 1.0:
            lo_u, hi_u = _quantile(U[:, i], w, tail), _quantile(U[:, i], w, 1.0 - tail)
        else:  # flat along its own axis across the widest step: its marginal is at least as wide
            lo_u, hi_u = 0.0, 1.0
        reach = axis_reach(st, i) if i in act else None
        widened = False
        for c in {u0[i], u_low[i]}:  # every interval holds the fit's end and the value reported, with their reach
            ends = (c, c) if reach is None else (c - (u0[i] - reach[0]), c + (reach[1] - u0[i]))
            widened = widened or (reach is not None and (ends[0] < lo_u or ends[1] > hi_u))
            lo_u, hi_u = min(lo_u, ends[0]), max(hi_u, ends[1])
        lo_u, hi_u = max(0.0, lo_u), min(1.0, hi_u)
        at_lo, at_hi = lo_u <= edge, hi_u >= 1.0 - edge
        pair = []
        for v in (lo_u, hi_u):
            u = u0.copy()
            u[i] = v
            pair.append(float(space.decode(u)[i]))
        setting = i < job.npar
        if setting:
            rname, lo = job.par.reported(name, pair[0])
            hi = job.par.reported(name, pair[1])[1]
            best = job.par.reported(name, float(x_best[i]))[1]
        else:
            rname, lo, hi, best = name, pair[0], pair[1], float(x_best[i])
        lo, hi = min(lo, hi), max(lo, hi)
        factor = hi / lo if space.log[i] and lo > 0 else None
        share = hi_u - lo_u  # of the search's range (log scale for a scale setting)
        wide = factor > D.INTERVAL_UNDETERMINED_FACTOR if factor is not None else share > D.INTERVAL_UNDETERMINED_SHARE
        bound = [s for s, hit in (("low", at_lo), ("high", at_hi)) if hit]
        intervals[rname] = [lo, hi]
        details[rname] = {
            "value": best,
            "at_bound": bound,
            "factor": factor,
            "share": share,
            "flat": i not in act,
            "axis_widened": widened,
        }
        if setting and (bound or wide):
            undetermined.append(rname)
    return {
        "intervals": intervals,
        "undetermined": undetermined,
        "interval_method": {
            "level": D.INTERVAL_LEVEL,
            "kind": "marginal: weighted quantiles of points sampled around the fit (every setting and offset "
            "free), weighted by exp(-(E - E_ref) / T), never narrower than the rise along the setting's own axis "
            "allows",
            "jitter_sd": st["sigma"],
            "threshold": st["threshold"],
            "temperature": st["temperature"],
            "threshold_source": "the training error's jitter at the best point (a part in 10^7 moved), or the "
            "images' pixel noise where that is more",
            "effective_points": ess,
            "evaluations": int(sum(v is not None for v in st["F"])),
            "undetermined_factor": D.INTERVAL_UNDETERMINED_FACTOR,
            "details": details,
        },
    }


PHASES = {"jitter": _phase_jitter, "axes": _phase_axes, "sample": _phase_sample}


def lowest_point(st: dict) -> tuple[float, list] | None:
    """The stage's lowest point (its error, its unit-cube point) where it scored lower than the fit's best, else
    None."""
    F = np.array([np.inf if v is None else v for v in st["F"]])
    k = int(np.argmin(F)) if len(F) else -1
    f0 = math.inf if st["f0"] is None else st["f0"]
    return (float(F[k]), st["U"][k]) if k >= 0 and F[k] < f0 else None


def _keep_lowest(job, st):
    """A point of the stage that scored lower than the fit's best becomes the fit's best (the search had not
    quite settled there; ``summarise`` already reports its values, each interval around it too); the result
    says so."""
    low = lowest_point(st)
    if low is None:
        return
    f, u = low
    x = job.space.decode(np.array(u))
    job.state.best_by_quality[job.chosen_quality()] = [f, x.tolist()]
    job.state.history_prev.append([int(job.state.done_evals), f])
    st["result"]["interval_method"]["improved_best"] = {"from": st["f0"], "to": f}


def interval_step(job: FitJob) -> bool:
    """One batch of the intervals stage (``job.state.intervals`` holds its state); True once it is done."""
    if job.state.intervals is None:
        job.state.intervals = start(job)
    st = job.state.intervals
    if st["phase"] != "done":
        PHASES[st["phase"]](job, st)
        if st["phase"] == "done":
            _keep_lowest(job, st)
    return st["phase"] == "done"
