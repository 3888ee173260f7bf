"""A/B of search strategies on exact-model captures: held-out error against the noise floor.

Runs strategies x seeds in-process (one process, one fit at a time) on one or more synthetic
captures that record their true settings (``meta.true_blender_cloth``), and writes one JSON line
per fit::

    capture, strategy, seed, evals, train_pct, heldout_pct, floor_pct, jitter_floor_pct, ratio,
    stop_reason, cpu_s, wall_s, best_x

``train_pct`` is the fit's own objective (E_sil per training image, %: 4 spread cameras, the
training frames); ``heldout_pct`` scores its best settings on the 4 held-out cameras at the test
frames; ``floor_pct`` scores the TRUE settings the same way; ``jitter_floor_pct`` is the median
held-out error of the true settings perturbed by 1e-7 relative (Blender's float32 solver makes
the error jump that much: no search can be expected below it). ``ratio = heldout / floor``.

    .venv/bin/python lab/search_ab.py CAPTURE [CAPTURE ...] --strategies baseline,cma-polish \
        --seeds 0-9 --out docs/figures/search_ab.jsonl
    .venv/bin/python lab/search_ab.py --summary docs/figures/search_ab.jsonl

Strategies are presets of ``make_optimizer`` (STRATEGIES below); ``baseline`` is what
``FitJob`` builds today for the blender model (cma-es, popsize 4 + 3 ln n, IPOP restarts 4).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from clothfit.core import defaults as D  # noqa: E402
from clothfit.core.fitting.job import FitConfig, FitJob  # noqa: E402
from clothfit.core.fitting.optimise import make_optimizer  # noqa: E402
from clothfit.core.observation.camera import select_training  # noqa: E402
from clothfit.core.observation.capture import load_capture  # noqa: E402
from fit_goals import parse_seeds  # noqa: E402  (the lab: the one seed-list parser)

BUDGET = D.FIT_EVALUATIONS

# runs again within the first stage's own share (StagedCMA's first_restart_step, first_explore)
RS48 = {"restarts": 4, "first_restart_step": 0.005, "first_fraction": 0.48, "first_explore": 0.36}
# the same settled at 0.01 of the cube, with the warm tail: the default since docs/search.md, "Shorter runs
# again" ("staged-rs48-step01")
STEP01 = dict(RS48, first_restart_step=0.01, warm_tail=0.2)
# runs again in a larger first stage: runs until 56 % of the budget, the best going on to 72 % ("staged-runs")
RUNS72 = {"restarts": 4, "first_restart_step": 0.005, "first_fraction": 0.72, "first_explore": 0.56}
# name -> (optimiser, kwargs); popsize None = FitJob's 4 + 3 ln n; tolx/tolfun as FitJob sets them
STRATEGIES = {
    "baseline": ("cma-es", {"restarts": 4}),
    "active16": ("cma-es", {"popsize": 16, "active": True}),
    "pop32": ("cma-es", {"popsize": 32}),
    "pf4": ("cma-portfolio", {"runs": 4, "explore": 0.6, "polish_sigma": 0.02}),
    "pf2p16": ("cma-portfolio", {"runs": 2, "explore": 0.6, "popsize": 16, "polish_sigma": 0.02}),
    "pf8": ("cma-portfolio", {"runs": 8, "explore": 0.7, "polish_sigma": 0.02}),
    # one long active CMA-ES run with a large population (faster covariance learning per evaluation
    # in the narrow, curved valley of the damping settings), local active restarts from the best
    # point if it stops before the budget
    "active32": (
        "cma-portfolio",
        {"runs": 1, "explore": 0.0, "popsize": 32, "active": True, "polish": "cma", "polish_sigma": 0.05},
    ),
    # the settings the silhouettes see most first (docs/search.md, "Strong settings first"): the fit's
    # `--optimizer cma-staged` (StagedCMA, set up as FitJob sets it up) before its warm tail and runs again
    # ("staged-rs48-tail20")
    "staged": ("cma-staged", {"restarts": 4}),
    # the same with three first-stage runs raced, 250 evaluations each, the best going on (StagedCMA's
    # 'race'; tried and not kept: docs/search.md)
    "staged-race3": ("cma-staged", {"restarts": 4, "race": 3, "race_evals": 250, "scan_points": 0}),
    # the same with each strong setting scanned at 24 values across its range between the stages
    # (StagedCMA's 'scan_points'; tried and not kept: docs/search.md)
    "staged-scan": ("cma-staged", {"restarts": 4, "race": 1, "scan_points": 24}),
    # the same with compression following tension in the first stage instead of held at Blender's default
    # (StagedCMA's 'tie'; tried as the default and not kept)
    "staged-tie": ("cma-staged", {"restarts": 4}),
    # runs again (StagedCMA's 'first_restart_step'; tried and not kept: docs/search.md, "Runs again"): each
    # first-stage run that has converged is followed by another from the same start with a new random
    # stream, until 56 % of the budget; then the best run goes on to 72 %, the first stage's larger share
    "staged-runs": ("cma-staged", RUNS72),
    # the same, the runs going on to the end of the 72 % and the best not going on
    "staged-rs": ("cma-staged", dict(RUNS72, first_explore=1.0)),
    # runs again within the first stage's own share: runs until 36 % of the budget, the best going on to 48 %
    "staged-rs48": ("cma-staged", RS48),
    # one run with a larger first-stage population (24 instead of Hansen's 8 for the strong four): more of
    # each generation lands in the bending valley before the mean settles (tried, not kept)
    "staged-pop24": ("cma-staged", {"restarts": 4, "first_popsize": 24}),
    # both stages' populations filled to whole batches of the kernel's lanes on two cores (16: two batches of
    # simd.W = 8, one per core, so a generation costs the wall time of one batch): fewer, wider generations
    "staged-pop16": ("cma-staged", {"restarts": 4, "first_popsize": 16, "popsize": 16}),
    # the same at about the default's wall time on two cores: 3900 evaluations, its own budget (strategy_budget)
    "staged-pop16-3900": ("cma-staged", {"restarts": 4, "first_popsize": 16, "popsize": 16, "budget": 3900}),
    # the second stage keeps the steps the first stage's run converged at on the strong settings (its
    # covariance) and starts the held ones at the usual step (StagedCMA's 'second_warm'), instead of one
    # step of 0.05 for all, which throws the strong settings off their narrow valley
    "staged-warm": ("cma-staged", {"restarts": 4, "second_warm": True}),
    # the same after runs again in the first stage ("staged-runs" above)
    "staged-runs-warm": ("cma-staged", dict(RUNS72, second_warm=True)),
    # the default second stage, then the last 20 % of the budget a third run from the best point so far with
    # the steps of 'staged-warm' (StagedCMA's 'warm_tail')
    "staged-tail20": ("cma-staged", {"restarts": 4, "warm_tail": 0.2}),
    # the same tail, but only where the second stage has found nothing better than the first stage's best point by
    # then (StagedCMA's 'warm_tail_stuck'); from 68 % of the budget: 800 evaluations
    "staged-stuck32": ("cma-staged", {"restarts": 4, "warm_tail": 0.32, "warm_tail_stuck": True}),
    # the same from 80 % of the budget (500 evaluations), where the plain tail ('staged-tail20') helped the goal's
    # capture: the fit's default until "staged-rs48-tail20"
    "staged-stuck20": ("cma-staged", {"restarts": 4, "warm_tail": 0.2, "warm_tail_stuck": True}),
    # runs again in the first stage ("staged-runs") with that tail
    "staged-runs-tail20": ("cma-staged", dict(RUNS72, warm_tail=0.2)),
    # runs again within the first stage's own share ("staged-rs48") with the warm tail only where the second stage has
    # found nothing better by 80 % of the budget
    "staged-rs48-stuck20": ("cma-staged", dict(RS48, warm_tail=0.2, warm_tail_stuck=True)),
    # the same with the tail in every fit, wherever the second stage stands by 80 % of the budget (the default where
    # the fit searches no manipulation unknowns, until runs again settled at 0.01: "staged-rs48-step01")
    "staged-rs48-tail20": ("cma-staged", dict(RS48, warm_tail=0.2)),
    # "staged-rs48-tail20", the tail also starting as soon as the second stage has gained less than 1 % over 10 %
    # of the budget
    # (250 evaluations; StagedCMA's 'warm_tail_stall'): where the second stage is stuck the tail gets its share
    "staged-rs48-stall10": ("cma-staged", dict(RS48, warm_tail=0.2, warm_tail_stall=0.1)),
    # "staged-rs48-tail20" with runs again counting a first-stage run as settled at steps below 0.02 instead of
    # 0.005: shorter runs, so more of them within the 36 % (each a chance at the truth's basin), the best still going
    # on to 48 %
    "staged-rs48-step02": ("cma-staged", dict(RS48, first_restart_step=0.02, warm_tail=0.2)),
    # the same at 0.01 (the default since, where no quality ladder follows the main search: docs/search.md,
    # "Shorter runs again")
    "staged-rs48-step01": ("cma-staged", STEP01),
    # the same with each run after the first started at another bending (StagedCMA's 'first_restart_vary': 0.2, 0.8,
    # 0.35, 0.65, 0.5 of its range in turn), the other strong settings where the first began
    "staged-rs48-step01-bend": (
        "cma-staged",
        dict(STEP01, first_restart_vary="bending_stiffness"),
    ),
    # the same, but the second run from where the first began (as the default's), only the third and later at other
    # bendings (0.2, 0.8, 0.35, 0.65 of its range in turn): keep the default's second chance, add the others
    "staged-rs48-step01-bendc": (
        "cma-staged",
        dict(STEP01, first_restart_vary="bending_stiffness", first_restart_levels=(0.5, 0.2, 0.8, 0.35, 0.65)),
    ),
    # the "staged-rs48-step01" with the tail from 70 % of the budget instead of 80 %: more of the budget for the
    # points near the truth among which the fit keeps its luckiest
    "staged-rs48-step01-tail30": ("cma-staged", dict(STEP01, warm_tail=0.3)),
    # the same recipe by hand, as first tried with two `fit` commands: CMA-ES (IPOP restarts) over D.STAGED_STRONG
    # alone, every other setting at Blender's default, for STAGED_FIRST of the budget; then the
    # baseline over all eight from that point with a step of STAGED_SIGMA
    # runs again from the best cells of a bending x air-damping grid at the first run's end (tried: docs/search.md,
    # "Runs again from a grid")
    "staged-grid": ("cma-staged", dict(STEP01, first_restart_grid=["bending_stiffness", "air_damping"])),
    "staged-recipe": ("staged-recipe", {}),
}
STAGED_FIRST = D.STAGED_FIRST_FRACTION
STAGED_SIGMA = D.STAGED_SECOND_SIGMA


def strategy_budget(strategy, budget):
    """A fit's evaluations: the strategy's own where it names them (``staged-pop16-3900``), else ``budget``."""
    return int(STRATEGIES[strategy][1].get("budget", budget)) if strategy in STRATEGIES else budget


# captures the tool makes itself (``synth:NAME``, under out/search_ab/NAME): the blender model on the
# lab18 rig at 240 x 320 with 5 % boundary noise; "default" is Blender's default material (the
# tuning capture), "fresh" another material and noise seed, kept apart for judging, "damped" below
SYNTH = {
    "default": ["--seed", "0"],
    # every setting off Blender's defaults (compression apart from tension, the three dampings): a
    # strategy that holds settings at the defaults for a while is not handed their true values
    "damped": [
        "--seed",
        "5",
        "--params",
        json.dumps(
            {
                "tension_stiffness": 15,
                "compression_stiffness": 9,
                "shear_stiffness": 5,
                "bending_stiffness": 0.5,
                "air_damping": 1.0,
                "tension_damping": 12,
                "shear_damping": 2,
                "bending_damping": 1.5,
            }
        ),
    ],
    # the strong settings away from the middle of the search's cube, where every first-stage run starts
    # (the three above have bending within 0.03 of it): a soft cloth (bending 0.3 of the cube) and a stiff one (0.7)
    "soft": [
        "--seed",
        "11",
        "--params",
        json.dumps(
            {
                "tension_stiffness": 40,
                "compression_stiffness": 40,
                "shear_stiffness": 15,
                "bending_stiffness": 0.05,
                "air_damping": 0.3,
            }
        ),
    ],
    "stiff": [
        "--seed",
        "13",
        "--params",
        json.dumps(
            {
                "tension_stiffness": 80,
                "compression_stiffness": 80,
                "shear_stiffness": 30,
                "bending_stiffness": 10,
                "air_damping": 2.0,
            }
        ),
    ],
    "fresh": [
        "--seed",
        "7",
        "--params",
        json.dumps(
            {
                "tension_stiffness": 25,
                "compression_stiffness": 25,
                "shear_stiffness": 8,
                "bending_stiffness": 1,
                "air_damping": 1.5,
            }
        ),
    ],
}
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def capture_path(spec):
    """A capture folder, or ``synth:NAME``: made once under out/search_ab/NAME (SYNTH above)."""
    if not spec.startswith("synth:"):
        return spec
    name = spec.split(":", 1)[1]
    out = os.path.join(ROOT, "out", "search_ab", name)
    if not os.path.isfile(os.path.join(out, "capture.json")):
        import subprocess

        subprocess.run(
            [
                sys.executable,
                "-m",
                "clothfit",
                "synth",
                "--out",
                out,
                "--model",
                "blender",
                "--rig",
                "lab18",
                "--resolution",
                "240x320",
                "--noise",
                "0.05",
                "--force",
            ]
            + SYNTH[name],
            cwd=ROOT,
            check=True,
            stdout=subprocess.DEVNULL,
        )
    return out


def capture_key(spec):
    """A capture's name for --reuse: the folder's name, ``synth:NAME`` and out/search_ab/NAME alike."""
    spec = spec.split(":", 1)[1] if spec.startswith("synth:") else spec
    return os.path.basename(spec.rstrip("/"))


class Bench:
    """One capture: the training objective (as `fit --cameras n:4 --times train`), the held-out
    objective (held-out cameras, test frames), the truth's coordinates and floors."""

    def __init__(self, path, jitter_samples=4):
        self.path = path
        cap = load_capture(path)
        train, held = select_training(cap.cameras, 4)
        self.job = FitJob(cap, FitConfig(train_cameras=train, train_times=list(D.TRAIN_TIMES)))
        self.hjob = FitJob(cap, FitConfig(train_cameras=held, train_times=list(D.TEST_TIMES)))
        t = cap.meta["true_blender_cloth"]
        par = self.job.par
        self.truth = np.array([par._coord(n, t[n]) for n in par.free])
        self.floor = self.held(self.truth)
        self.train_floor = self.train(self.truth)
        self.jitter = float(np.median(self.held_many(self.near_truth(np.random.default_rng(12345), jitter_samples))))

    def near_truth(self, rng, samples, rel=1e-7):
        """``samples`` points round the truth: every setting off by +-``rel`` (relative), random signs."""
        return self.truth[None] * (1 + rel * rng.choice([-1.0, 1.0], size=(samples, self.truth.size)))

    def train_many(self, X):
        """The training error of each row of ``X`` (E_sil per image, %)."""
        o = self.job.objective
        return o(self.job.par.rows(np.asarray(X))) / o.n_images * 100

    def held_many(self, X):
        """The held-out error of each row of ``X`` (E_sil per image, %)."""
        o = self.hjob.objective
        return o(self.job.par.rows(np.asarray(X))) / o.n_images * 100

    def train(self, x):
        return float(self.train_many(np.asarray(x)[None])[0])

    def held(self, x):
        return float(self.held_many(np.asarray(x)[None])[0])

    def make(self, strategy, seed, **extra):
        name, kw = STRATEGIES[strategy]
        kw = dict(kw, **extra)
        n = self.job.space.n
        kw.setdefault("popsize", 4 + int(3 * math.log(n)))
        kw.setdefault("tolx", D.FIT_TOLX)
        kw.setdefault("tolfun", D.FIT_TOLFUN_PER_IMAGE * self.job.objective.n_images)
        if name == "cma-portfolio":
            kw.setdefault("budget", BUDGET)
        if name == "cma-staged":
            # the capture's stages (first, hold, ...) as FitJob sets them; a preset's own settings win
            kw = dict({k: v for k, v in self.job._staged_kw().items() if k != "budget"}, **kw)
            kw["budget"] = kw.get("budget", BUDGET)
            # each preset is the search its rows were recorded with: the warm tail and runs again (the default's
            # since docs/search.md, "A warm tail" and "Runs again and the tail") only where a preset names them
            kw.setdefault("warm_tail", 0.0)
            kw.setdefault("warm_tail_stuck", False)
            kw.setdefault("first_restart_step", 0.0)
            kw.setdefault("warm_tail_stall", 0.0)
            if "first_restart_grid" not in STRATEGIES[strategy][1]:
                kw["first_restart_grid"] = None  # runs again from a grid (the default's since) only where named
            if strategy == "staged-tie" and "compression_stiffness" in self.job.space.names:
                kw["tie"] = {"compression_stiffness": "tension_stiffness"}
        return make_optimizer(name, self.job.space, seed=seed, **kw)

    def _staged(self, seed, budget):
        """The ``staged-recipe`` strategy: (the second fit's optimiser, the first fit's evaluations)."""
        cap = self.job.capture
        free = list(self.job.par.free)
        strong = self.job._strong_free()
        job1 = FitJob(
            cap, FitConfig(train_cameras=self.job.train_cameras, train_times=list(D.TRAIN_TIMES), free=strong)
        )
        n1 = job1.space.n
        opt1 = make_optimizer(
            "cma-es",
            job1.space,
            seed=seed,
            restarts=4,
            popsize=4 + int(3 * math.log(n1)),
            tolx=D.FIT_TOLX,
            tolfun=D.FIT_TOLFUN_PER_IMAGE * job1.objective.n_images,
        )
        first = int(round(STAGED_FIRST * budget))
        while opt1.evaluations < first and not opt1.stopped:
            X = opt1.ask()
            opt1.tell(X, job1.objective(job1.par.rows(X)))
        row = job1.par.rows(np.asarray(opt1.best_x)[None])[0]
        from clothfit.core.physics import blender as B

        x0 = np.array([self.job.par._coord(n, row[B.FLOAT_SETTINGS.index(n)]) for n in free])
        kw = {"initial": [x0], "sigma0": STAGED_SIGMA}
        opt = self.make("baseline", seed, **kw)
        return opt, opt1.evaluations

    def fit(self, strategy, seed, budget=BUDGET, trace=False):
        spent = 0
        c0, t0 = time.process_time(), time.time()
        if strategy == "staged-recipe":
            opt, spent = self._staged(seed, budget)
        else:
            opt = self.make(strategy, seed)
        obj = self.job.objective
        tail_at = (1.0 - D.STAGED_WARM_TAIL) * budget  # where the default's tail starts (80 % of the budget)
        best_at_80 = None  # the best value then
        tail_started = None  # the evaluations when the warm tail started (its third stage), if it did
        while opt.evaluations + spent < budget and not opt.stopped:
            X = opt.ask()
            f = obj(self.job.par.rows(X))
            opt.tell(X, f)
            if best_at_80 is None and opt.evaluations + spent >= tail_at:
                best_at_80 = float(opt.best_f)
            if tail_started is None and getattr(opt, "stage", None) == 3:
                tail_started = int(opt.evaluations) + int(spent)
            if trace and opt.generation % 10 == 0:
                print(
                    f"  gen {opt.generation} evals {opt.evaluations} best {opt.best_f / obj.n_images * 100:.3f}"
                    f" {getattr(opt, 'phase_info', lambda: '')()}",
                    file=sys.stderr,
                    flush=True,
                )
        cpu, wall = time.process_time() - c0, time.time() - t0
        xb = opt.best_x
        h = self.held(xb)
        stop = opt.stop_reason if opt.stopped else "budget"
        return {
            "capture": self.path,
            "strategy": strategy,
            "seed": seed,
            "budget": int(budget),
            "evals": int(opt.evaluations) + int(spent),
            "train_pct": opt.best_f / obj.n_images * 100,
            "heldout_pct": h,
            "floor_pct": self.floor,
            "jitter_floor_pct": self.jitter,
            "train_floor_pct": self.train_floor,
            "ratio": h / self.floor,
            "stop_reason": stop,
            "cpu_s": cpu,
            "wall_s": wall,
            "best_x": [float(v) for v in xb],
            "truth_x": [float(v) for v in self.truth],
            "load": os.getloadavg()[0],
            "first_runs": getattr(opt, "first_runs", None),
            "looks": opt.looks() if hasattr(opt, "looks") else None,
            "first_best_pct": None
            if getattr(opt, "first_best_f", None) is None
            else opt.first_best_f / obj.n_images * 100,
            "best_at_80_pct": None if best_at_80 is None else best_at_80 / obj.n_images * 100,
            "stage": getattr(opt, "stage", None),
            "tail_started": tail_started,
        }


GROUPS = {
    "all": None,
    "tension_shear": ("tension_stiffness", "shear_stiffness"),
    "compression_bending": ("compression_stiffness", "bending_stiffness"),
    "dampings_air": ("tension_damping", "shear_damping", "bending_damping", "air_damping"),
}
RELATIVE = (1e-7, 1e-3, 1e-2, 1e-1, 3e-1)


def landscape(b, samples=4, seed=1):
    """The training and held-out error of the truth perturbed by +-rel (random signs, relative to each
    setting) in a group of settings: how close to the truth a search must come."""
    rng = np.random.default_rng(seed)
    free = list(b.job.par.free)
    out = []
    for group, names in GROUPS.items():
        idx = list(range(len(free))) if names is None else [free.index(n) for n in names if n in free]
        for rel in RELATIVE:
            X = np.repeat(b.truth[None], samples, axis=0)
            X[:, idx] *= 1 + rel * rng.choice([-1.0, 1.0], size=(samples, len(idx)))
            tr, he = b.train_many(X), b.held_many(X)
            out.append(
                {
                    "group": group,
                    "relative": rel,
                    "train_pct": [float(v) for v in tr],
                    "heldout_pct": [float(v) for v in he],
                    "median_ratio": float(np.median(he) / b.floor),
                    "min_ratio": float(np.min(he) / b.floor),
                    "max_ratio": float(np.max(he) / b.floor),
                }
            )
    return {
        "capture": b.path,
        "floor_pct": b.floor,
        "train_floor_pct": b.train_floor,
        "jitter_floor_pct": b.jitter,
        "rows": out,
    }


SLICE_AXES = ("bending_stiffness", "air_damping")  # the grid's rows and columns
SLICE_AT = ("tension_stiffness", "shear_stiffness")  # held at the truth, or moved by --slice-shift


def slice_grid(b, n=16, shifts=(0.0, 0.01)):
    """The first stage's slice as cma-staged searches it (the weak settings held where it holds them):
    the training error over an n x n grid of bending x air damping across their whole (log) ranges,
    with tension and shear at the truth, then both moved by each of ``shifts`` (unit cube). Where the
    truth's basin is, how wide, and whether it survives a small error in the strong settings."""
    sp = b.job.space
    opt = b.make("staged", 0)
    names = list(sp.names)
    ib, ia = (names.index(x) for x in SLICE_AXES)
    it, ish = (names.index(x) for x in SLICE_AT)
    ut = sp.encode(b.truth)
    g = (np.arange(n) + 0.5) / n
    out = []
    for d in shifts:
        U = np.repeat(opt.hold_u[None], n * n, 0)
        U[:, it], U[:, ish] = ut[it] + d, ut[ish] + d
        B, A = np.meshgrid(g, g, indexing="ij")
        U[:, ib], U[:, ia] = B.ravel(), A.ravel()
        F = b.train_many(sp.decode(U)).reshape(n, n)
        i, j = np.unravel_index(int(np.argmin(F)), F.shape)
        moved = sp.decode(np.where(np.isin(np.arange(sp.n), [it, ish]), ut + d, ut))
        out.append(
            {
                "shift_u": d,
                "tension_rel": float(moved[it] / b.truth[it] - 1),
                "shear_rel": float(moved[ish] / b.truth[ish] - 1),
                "train_pct": F.round(4).tolist(),
                "min_pct": float(F[i, j]),
                "min_at_u": [float(g[i]), float(g[j])],
                "plateau_pct": float(np.median(F[: n // 2, : n // 2])),
                "row_at_truth_bending_pct": F[int(np.argmin(np.abs(g - ut[ib])))].round(4).tolist(),
                "col_at_truth_air_pct": F[:, int(np.argmin(np.abs(g - ut[ia])))].round(4).tolist(),
            }
        )
    u = opt.hold_u.copy()
    u[opt._idx] = ut[opt._idx]
    return {
        "capture": b.path,
        "axes": list(SLICE_AXES),
        "grid_u": g.tolist(),
        "truth_u": [float(ut[ib]), float(ut[ia])],
        "held_u": {nm: float(opt.hold_u[k]) for k, nm in enumerate(names) if nm not in opt.first},
        "truth_strong_held_weak_train_pct": b.train(sp.decode(u)),
        "train_floor_pct": b.train_floor,
        "slices": out,
    }


def local_start(b, rel=0.05, sigma=0.02, budget=1000, seed=0):
    """A CMA-ES run (active, popsize 10) started in the truth's own basin: every setting off by
    +-rel, step ``sigma``: does the search converge to the truth once it is close?"""
    from clothfit.core.fitting.evolution_strategy import CMAES

    rng = np.random.default_rng(seed)
    x0 = b.truth * (1 + rel * rng.choice([-1.0, 1.0], size=len(b.truth)))
    obj, sp = b.job.objective, b.job.space
    o = CMAES(
        sp,
        seed=seed,
        initial=[x0],
        sigma0=sigma,
        popsize=10,
        active=True,
        tolx=D.FIT_TOLX,
        tolfun=D.FIT_TOLFUN_PER_IMAGE * obj.n_images,
    )
    trace = [
        {
            "evals": 0,
            "train_pct": b.train(x0),
            "ratio": b.held(x0) / b.floor,
            "max_abs_du": float(np.abs(sp.encode(x0) - sp.encode(b.truth)).max()),
        }
    ]
    while o.evaluations < budget and not o.stopped:
        X = o.ask()
        o.tell(X, obj(b.job.par.rows(X)))
        if o.generation % 20 == 0 or o.evaluations >= budget or o.stopped:
            du = sp.encode(o.best_x) - sp.encode(b.truth)
            trace.append(
                {
                    "evals": int(o.evaluations),
                    "train_pct": o.best_f / obj.n_images * 100,
                    "ratio": b.held(o.best_x) / b.floor,
                    "max_abs_du": float(np.abs(du).max()),
                    "du": {n: float(v) for n, v in zip(b.job.par.free, du)},
                }
            )
    return {"relative": rel, "sigma0": sigma, "budget": budget, "trace": trace}


PROFILE_AXIS = "bending_stiffness"  # the profile's axis: the strong setting whose valley first stages miss
PROFILE_INNER = ("tension_stiffness", "shear_stiffness", "air_damping")  # searched at each of its values


def _sub_run(b, u_full, idx, sigma, evals, seed):
    """CMA-ES over the coordinates ``idx`` of the whole unit-cube point ``u_full`` (the others held),
    ``evals`` evaluations from it with step ``sigma``: (the best whole point, its training error %)."""
    from clothfit.core.fitting.evolution_strategy import CMAES

    sp, obj = b.job.space, b.job.objective
    sub = sp.subspace([sp.names[i] for i in idx])
    o = CMAES(
        sub, seed=seed, initial=[sub.decode(u_full[idx])], sigma0=sigma, popsize=8, restarts=0, tolx=1e-11, tolfun=1e-11
    )
    while o.evaluations < evals:
        X = o.ask()
        U = np.repeat(u_full[None], len(X), 0)
        U[:, idx] = sub.encode(X)
        o.tell(X, obj(b.job.par.rows(sp.decode(U))))
    u = u_full.copy()
    u[idx] = sub.encode(o.best_x)
    return u, float(o.best_f / obj.n_images * 100)


def profile_start(b, seed=0, points=16, per=64, top=2, refine=300, final=400):
    """A first stage by profile (tried, not kept: docs/search.md): bending held at ``points`` values
    evenly across its (log) range, stiff to soft, and at each the other strong settings (tension,
    shear, air damping) searched for ``per`` evaluations from the previous value's best (the weak
    settings held where cma-staged holds them); the ``top`` lowest values searched again for
    ``refine`` evaluations in all at their bending; then the four from the best with a step of 0.03
    for ``final``. Does the profile's lowest point sit in the truth's bending valley?"""
    sp = b.job.space
    names = list(sp.names)
    u0 = b.make("staged", 0).hold_u.copy()
    ib = names.index(PROFILE_AXIS)
    inner = [names.index(n) for n in PROFILE_INNER]
    strong = sorted(inner + [ib])
    ut = sp.encode(b.truth)
    c0 = time.process_time()
    cur, prof = u0.copy(), []
    for g in ((np.arange(points) + 0.5) / points)[::-1]:
        cur = cur.copy()
        cur[ib] = g
        cur, f = _sub_run(b, cur, inner, 0.1, per, seed)
        prof.append({"bending_u": float(g), "train_pct": f, "inner_u": cur[inner].round(4).tolist()})
    order = sorted(range(points), key=lambda i: prof[i]["train_pct"])[:top]
    best = None
    for i in order:
        u = u0.copy()
        u[ib] = prof[i]["bending_u"]
        u[inner] = prof[i]["inner_u"]
        u, f = _sub_run(b, u, inner, 0.05, refine // top, seed)
        prof[i]["refined_pct"] = f
        if best is None or f < best[0]:
            best = (f, u)
    u, f = _sub_run(b, best[1], strong, 0.03, final, seed)
    return {
        "capture": b.path,
        "seed": seed,
        "points": points,
        "per_point": per,
        "evaluations": points * per + (refine // top) * top + final,
        "truth_u": {names[i]: float(ut[i]) for i in strong},
        "profile": prof,
        "end_u": {names[i]: float(u[i]) for i in strong},
        "train_pct": f,
        "train_floor_pct": b.train_floor,
        "ratio": b.held(sp.decode(u)) / b.floor,
        "cpu_s": time.process_time() - c0,
    }


def oracle(b, samples=128, seed=5, relative=(1e-7, 1e-5, 1e-3), best_of=(1, 4, 16, 64)):
    """What even a search that knew the truth could reach: ``samples`` points round the truth (every
    setting off by +-rel, random signs), their held-out ratios, how often they are within 1.2x and
    1.5x, the correlation of their training and held-out errors (the trajectory's jitter is the same
    motion seen by every camera, so the training error sees it), and the held-out ratio of the best
    of ``n`` of them by *training* error (disjoint groups; median and share <= 1.2x): a search must
    come that close and then keep its luckiest point."""
    rng = np.random.default_rng(seed)
    out = []
    for rel in relative:
        X = b.near_truth(rng, samples, rel)
        tr, ratio = b.train_many(X), b.held_many(X) / b.floor
        sel = []
        for n in best_of:
            picked = np.array([ratio[i : i + n][np.argmin(tr[i : i + n])] for i in range(0, samples - n + 1, n)])
            sel.append(
                {
                    "n": n,
                    "groups": int(picked.size),
                    "median_ratio": float(np.median(picked)),
                    "within_1_2": float(np.mean(picked <= 1.2)),
                }
            )
        out.append(
            {
                "relative": rel,
                "samples": samples,
                "median_ratio": float(np.median(ratio)),
                "within_1_2": float(np.mean(ratio <= 1.2)),
                "within_1_5": float(np.mean(ratio <= 1.5)),
                "train_heldout_corr": float(np.corrcoef(tr, ratio)[0, 1]),
                "best_of": sel,
            }
        )
    return {"capture": b.path, "floor_pct": b.floor, "train_floor_pct": b.train_floor, "rows": out}


def jitter_spread(b, samples=40, seed=7):
    """The jitter floor's spread: the held-out ratio of ``samples`` points a part in 10^7 from the truth
    (every setting, random signs). One median hides how far that jitter alone throws a fit: where the
    trajectory is chaotic the truth's own neighbours land anywhere from 1.6x to 3x the floor, and fits
    there are judged against this spread (within its 90th percentile: as close as the truth's neighbours)."""
    r = np.sort(b.held_many(b.near_truth(np.random.default_rng(seed), samples)) / b.floor)
    return {
        "capture": capture_key(b.path),
        "floor_pct": b.floor,
        "samples": samples,
        "ratios": [float(v) for v in r],
        "p10": float(np.quantile(r, 0.1)),
        "p50": float(np.quantile(r, 0.5)),
        "p90": float(np.quantile(r, 0.9)),
        "max": float(r[-1]),
    }


def jitter_check(b, fits, p90, quantiles=(0.5, 0.75, 0.9)):
    """The jitter floor the product measures at a fit (``fitting/jitter.py``: the noise floor plus the
    silhouettes' difference between the fit and its neighbours a part in 10^7 away), checked where the truth is
    known. At the truth: its 10th / 50th / 90th percentiles beside those of the truth's own neighbours' errors
    (``jitter_spread``). At each fit of ``fits`` (rows of this tool): the held-out and training ratios beside
    the floor allowed at each of ``quantiles`` (never below ``FLOOR_FAR_ABOVE``), and whether the fit is within
    the truth's own spread (its held-out ratio at most ``p90``, the spread's 90th percentile): a rule that calls
    a fit outside that spread "at the floor" hides a wrong basin."""
    from clothfit.core.fitting.jitter import jitter

    def floors(job, x):
        o = job.objective
        j = jitter(job, x, o, o.silhouettes(job.par.rows(np.asarray(x)[None])[0]))
        return np.asarray(j["pct"])

    spread = jitter_spread(b)
    jh, jt = floors(b.hjob, b.truth), floors(b.job, b.truth)
    out = {
        "capture": capture_key(b.path),
        "truth_neighbours_ratio": [spread["p10"], spread["p50"], spread["p90"]],
        "truth_jitter_floor_ratio": [float(v) for v in np.quantile((b.floor + jh) / b.floor, (0.1, 0.5, 0.9))],
        "truth_jitter_floor_train_ratio": [
            float(v) for v in np.quantile((b.train_floor + jt) / b.train_floor, (0.1, 0.5, 0.9))
        ],
        "spread_p90": p90,
        "fits": [],
    }
    for r in fits:
        x = np.asarray(r["best_x"])
        h, t = b.held(x) / b.floor, b.train(x) / b.train_floor
        jh, jt = floors(b.hjob, x), floors(b.job, x)
        allow = {
            f"q{round(100 * q)}": [
                max(D.FLOOR_FAR_ABOVE, float(np.quantile(b.floor + jh, q)) / b.floor),
                max(D.FLOOR_FAR_ABOVE, float(np.quantile(b.train_floor + jt, q)) / b.train_floor),
            ]
            for q in quantiles
        }
        raw = {  # the jitter floor alone, over the floor (before the 2x): what searching again compares with
            f"q{round(100 * q)}": [
                float(np.quantile(b.floor + jh, q)) / b.floor,
                float(np.quantile(b.train_floor + jt, q)) / b.train_floor,
            ]
            for q in quantiles
        }
        out["fits"].append(
            {
                "allowed_raw": raw,
                "seed": r["seed"],
                "strategy": r["strategy"],
                "heldout_ratio": h,
                "train_ratio": t,
                "within_truth_spread": bool(h <= p90),
                "allowed": allow,
                "at_floor": {q: bool(h <= a[0] and t <= a[1]) for q, a in allow.items()},
                "at_floor_2x": bool(max(h, t) <= D.FLOOR_FAR_ABOVE),
            }
        )
    return out


def jitter_check_table(caps):
    """Per rule (the 2x rule, then each quantile: q75 = the 75th percentile): fits at the floor within the truth's spread (TP), outside it
    (FP: a wrong basin called fine), and the fits within it called far (FN), outside it called far (TN)."""
    fits = [f for c in caps for f in c["fits"]]
    rules = {"2x": lambda f: f["at_floor_2x"]}
    rules.update({q: (lambda f, q=q: f["at_floor"][q]) for q in fits[0]["at_floor"]} if fits else {})
    table = {}
    for name, rule in rules.items():
        c = {"TP": 0, "FP": 0, "FN": 0, "TN": 0}
        for f in fits:
            c[("T" if rule(f) == f["within_truth_spread"] else "F") + ("P" if rule(f) else "N")] += 1
        table[name] = c
    return table


def looks_check(caps, quantile="q75", margin=None):
    """What looking again would give, from a --jitter-check's fits alone (no new fit): a fit whose training error
    is above the floor its own jitter allows (``quantile``, the product's rule on the training side, which a
    fit knows when its search ends) is searched again with another seed, and the look with the lower training
    error is kept. Another seed's search is any other seed's fit of the same capture, so the expected outcome is
    the mean over the nine others (and, for a third look where the better of two is still above its floor,
    over the eight left). Per capture and in total: the fits within the truth's own spread with one look, with a
    second look where the first is above its floor, with up to three, and with two looks always; and how many
    fits look again. With ``margin``: a fit also looks again above ``margin`` times its jitter floor alone where
    that is below the 2x (a fit between its own jitter floor and 2x may be in another basin)."""
    out, total = [], {"one": 0.0, "second": 0.0, "third": 0.0, "always_two": 0.0, "looked_again": 0, "fits": 0}
    for c in caps:
        fits = c["fits"]
        p90 = c["spread_p90"]

        def inside(f, p90=p90):
            return f["heldout_ratio"] <= p90

        def above(f):
            limit = f["allowed"][quantile][1]
            if margin is not None:  # also above ``margin`` times the jitter floor alone, where that is lower
                limit = min(limit, margin * f["allowed_raw"][quantile][1])
            return f["train_ratio"] > limit

        def better(f, g):
            return f if f["train_ratio"] <= g["train_ratio"] else g

        row = {"capture": c["capture"], "one": 0.0, "second": 0.0, "third": 0.0, "always_two": 0.0, "looked_again": 0}
        for f in fits:
            others = [g for g in fits if g is not f]
            row["one"] += inside(f)
            row["always_two"] += float(np.mean([inside(better(f, g)) for g in others]))
            if not above(f):
                row["second"] += inside(f)
                row["third"] += inside(f)
                continue
            row["looked_again"] += 1
            row["second"] += float(np.mean([inside(better(f, g)) for g in others]))
            third = []
            for g in others:
                b = better(f, g)
                if not above(b):
                    third.append(inside(b))
                else:
                    third.append(float(np.mean([inside(better(b, h)) for h in others if h is not g])))
            row["third"] += float(np.mean(third))
        row["fits"] = len(fits)
        for k in total:
            total[k] += row[k]
        out.append(row)
    return {"quantile": quantile, "captures": out, "total": total}


def summary(rows, spread=None):
    """Per (capture, strategy): seeds, median / best / worst ratio, seeds <= 1.2x, mean CPU; with ``spread``
    (capture name -> jitter_spread's result) also the seeds within the jitter spread's 90th percentile."""
    groups = {}
    for r in rows:
        groups.setdefault((r["capture"], r["strategy"]), []).append(r)
    out = []
    for (cap, strat), rs in sorted(groups.items()):
        ratios = np.array([r["ratio"] for r in rs])
        js = (spread or {}).get(capture_key(cap))
        extra = (
            {} if js is None else {"jitter_p90_ratio": js["p90"], "within_jitter_p90": int(np.sum(ratios <= js["p90"]))}
        )
        out.append(
            {
                **extra,
                "capture": cap,
                "strategy": strat,
                "seeds": len(rs),
                "median_ratio": float(np.median(ratios)),
                "best_ratio": float(ratios.min()),
                "worst_ratio": float(ratios.max()),
                "within_1_2": int(np.sum(ratios <= 1.2)),
                "within_1_4": int(np.sum(ratios <= 1.4)),
                "within_1_5": int(np.sum(ratios <= 1.5)),
                "median_heldout_pct": float(np.median([r["heldout_pct"] for r in rs])),
                "floor_pct": rs[0]["floor_pct"],
                "jitter_floor_pct": rs[0]["jitter_floor_pct"],
                "median_train_pct": float(np.median([r["train_pct"] for r in rs])),
                "mean_evals": float(np.mean([r["evals"] for r in rs])),
                "mean_cpu_s": float(np.mean([r["cpu_s"] for r in rs])),
                "mean_wall_s": float(np.mean([r["wall_s"] for r in rs])),
                "mean_load": float(np.mean([r.get("load", float("nan")) for r in rs])),
            }
        )
    return out


def print_table(summ, file=sys.stderr):
    print(
        "| capture | strategy | seeds | median ratio | best | worst | <= 1.2x | <= 1.5x | median held-out % "
        "| floor % | jitter floor % | mean CPU s |",
        file=file,
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|", file=file)
    for s in summ:
        print(
            f"| {os.path.basename(s['capture'].rstrip('/'))} | {s['strategy']} | {s['seeds']} | "
            f"{s['median_ratio']:.2f} | {s['best_ratio']:.2f} | {s['worst_ratio']:.2f} | {s['within_1_2']} | "
            f"{s['within_1_5']} | {s['median_heldout_pct']:.3f} | {s['floor_pct']:.3f} | "
            f"{s['jitter_floor_pct']:.3f} | {s['mean_cpu_s']:.0f} |",
            file=file,
        )


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("captures", nargs="*", help="capture folders made by `synth --model blender`")
    ap.add_argument("--strategies", default="baseline", help=f"comma list of {', '.join(STRATEGIES)}")
    ap.add_argument("--seeds", default="0-4", help="seeds, e.g. 0-9 or 0,3,5")
    ap.add_argument("--budget", type=int, default=BUDGET, help="evaluations per fit")
    ap.add_argument("--out", help="JSONL file to append rows to")
    ap.add_argument("--summary", nargs="*", help="only summarise these JSONL files")
    ap.add_argument("--json-summary", help="write the summary (and rows) as one JSON document here")
    ap.add_argument("--trace", action="store_true", help="progress of each fit on stderr")
    ap.add_argument(
        "--only-reused",
        action="store_true",
        help="with --reuse: take the fits found there and run none (a seed missing there is left out)",
    )
    ap.add_argument(
        "--landscape",
        help="instead of fits: the errors of the truth perturbed group by group "
        "(settings x relative size), written as JSON here",
    )
    ap.add_argument(
        "--local",
        type=float,
        help="with --landscape: also a CMA-ES run started this far (relative) from the truth, 1000 evaluations",
    )
    ap.add_argument(
        "--reuse",
        nargs="*",
        default=[],
        help="JSONL files of earlier runs of this tool: a fit with the same capture name, strategy, "
        "seed and budget is taken from them instead of run again (the fits are deterministic)",
    )
    ap.add_argument(
        "--oracle",
        help="instead of fits: points round the truth and the best of n by training error "
        "(what a search that came that close could keep), written as JSON here",
    )
    ap.add_argument("--samples", type=int, default=128, help="with --oracle: points per distance")
    ap.add_argument(
        "--jitter-spread",
        help="instead of fits: the held-out ratios of 40 points a part in 10^7 from the truth per capture "
        "(their 10th, 50th, 90th percentiles and maximum), written as JSON here",
    )
    ap.add_argument(
        "--jitter-check",
        help="instead of fits: the jitter floor measured at the truth and at the fits of --reuse (--strategies, "
        "--seeds), beside the truth's own spread (--spread) and the rules that call a fit at the floor, as JSON here",
    )
    ap.add_argument(
        "--looks-check",
        nargs=2,
        metavar=("JITTER_CHECK", "OUT"),
        help="instead of fits: from a --jitter-check JSON (or its recording), what a second or third look would give "
        "where a fit ends above its own jitter floor (no new fit), as JSON here",
    )
    ap.add_argument(
        "--spread",
        help="a --jitter-spread JSON: the summary counts the seeds within each capture's 90th percentile",
    )
    ap.add_argument(
        "--slice",
        help="instead of fits: the first stage's slice (bending x air damping over their ranges, tension and "
        "shear at the truth and moved by 0.01 of the unit cube), written as JSON here",
    )
    ap.add_argument(
        "--profile",
        help="instead of fits: a first stage by profile over bending (tried, not kept), per capture and "
        "seed, written as JSON here",
    )
    ap.add_argument(
        "--profile-evals", default="64", help="with --profile: evaluations per bending value (a list: each)"
    )
    a = ap.parse_args(argv)
    if a.profile:
        from clothfit.core.jsonio import write_json

        out = []
        for c in a.captures:
            b = Bench(capture_path(c))
            for per in [int(v) for v in a.profile_evals.split(",")]:
                for seed in parse_seeds(a.seeds):
                    r = profile_start(b, seed=seed, per=per)
                    print(
                        f"{c} per {per} seed {seed}: train {r['train_pct']:.3f} % held-out {r['ratio']:.2f}x",
                        file=sys.stderr,
                        flush=True,
                    )
                    out.append(r)
        write_json(a.profile, {"runs": out})
        return
    if a.oracle:
        from clothfit.core.jsonio import write_json

        write_json(a.oracle, {"captures": [oracle(Bench(capture_path(c)), a.samples) for c in a.captures]})
        return
    if a.slice:
        from clothfit.core.jsonio import write_json

        write_json(a.slice, {"captures": [slice_grid(Bench(capture_path(c))) for c in a.captures]})
        return
    if a.landscape:
        from clothfit.core.jsonio import write_json

        out = []
        for c in a.captures:
            b = Bench(capture_path(c))
            d = landscape(b)
            if a.local:
                d["local_start"] = local_start(b, rel=a.local)
            out.append(d)
        write_json(a.landscape, {"captures": out})
        return
    if a.jitter_spread:
        from clothfit.core.jsonio import write_json

        out = []
        for c in a.captures:
            out.append(jitter_spread(Bench(capture_path(c))))
            print(json.dumps({k: v for k, v in out[-1].items() if k != "ratios"}), file=sys.stderr, flush=True)
        write_json(a.jitter_spread, {"captures": out})
        return
    if a.looks_check:
        from clothfit.core.jsonio import read_json, write_json

        d = read_json(a.looks_check[0])
        caps = d.get("data", d)["captures"]
        r = looks_check(caps)
        if all("allowed_raw" in f for c in caps for f in c["fits"]):
            r["margin"] = looks_check(caps, margin=D.SEARCH_AGAIN_MARGIN)
            r["margin"]["margin"] = D.SEARCH_AGAIN_MARGIN
            print(json.dumps(r["margin"]["total"]), file=sys.stderr)
        print(json.dumps(r["total"]), file=sys.stderr)
        write_json(a.looks_check[1], r)
        return
    if a.jitter_check:
        from clothfit.core.jsonio import read_json, write_json

        d = read_json(a.spread)
        p90 = {c["capture"]: c["p90"] for c in d.get("data", d)["captures"]}
        rows = [json.loads(line) for p in a.reuse for line in open(p) if line.strip()]
        strategies, seeds = a.strategies.split(","), parse_seeds(a.seeds)
        out = []
        for c in a.captures:
            key = capture_key(c.split(":", 1)[1] if c.startswith("synth:") else c)
            fits = [
                r
                for r in rows
                if capture_key(r["capture"]) == key and r["strategy"] in strategies and r["seed"] in seeds
            ]
            out.append(jitter_check(Bench(capture_path(c)), fits, p90[key]))
            print(json.dumps({k: v for k, v in out[-1].items() if k != "fits"}), file=sys.stderr, flush=True)
        table = jitter_check_table(out)
        print(json.dumps(table), file=sys.stderr)
        write_json(a.jitter_check, {"captures": out, "rules": table})
        return
    if a.summary:
        rows = [json.loads(line) for p in a.summary for line in open(p) if line.strip()]
    else:
        rows = []
        old = {}
        for p in a.reuse:
            for line in open(p):
                if line.strip():
                    r = json.loads(line)
                    old[(capture_key(r["capture"]), r["strategy"], r["seed"], r.get("budget", BUDGET))] = r
        for spec in a.captures:
            if a.only_reused:
                cap = spec.split(":", 1)[1] if spec.startswith("synth:") else spec
                for strat in a.strategies.split(","):
                    for seed in parse_seeds(a.seeds):
                        key = (capture_key(cap), strat, seed, strategy_budget(strat, a.budget))
                        if key in old:
                            rows.append(dict(old[key], capture=spec, reused=True))
                continue
            cap = capture_path(spec)
            b = Bench(cap)
            print(
                f"{cap}: floor {b.floor:.3f} %, jitter floor {b.jitter:.3f} %, train floor {b.train_floor:.3f} %",
                file=sys.stderr,
                flush=True,
            )
            for strat in a.strategies.split(","):
                for seed in parse_seeds(a.seeds):
                    budget = strategy_budget(strat, a.budget)
                    key = (capture_key(cap), strat, seed, budget)
                    if key in old:
                        r = dict(old[key], capture=spec, reused=True)
                    else:
                        r = dict(b.fit(strat, seed, budget, a.trace), capture=spec)
                    rows.append(r)
                    print(
                        json.dumps({k: v for k, v in r.items() if k not in ("best_x", "truth_x")}),
                        file=sys.stderr,
                        flush=True,
                    )
                    if a.out:
                        with open(a.out, "a") as fh:
                            fh.write(json.dumps(r) + "\n")
    spread = None
    if a.spread:
        from clothfit.core.jsonio import read_json

        d = read_json(a.spread)
        d = d.get("data", d)  # a recorded figure (tools/figures.py) or the tool's own JSON
        spread = {c["capture"]: c for c in d["captures"]}
    summ = summary(rows, spread)
    print_table(summ)
    if a.json_summary:
        from clothfit.core.jsonio import write_json

        write_json(a.json_summary, {"summary": summ, "rows": rows})
    print(json.dumps({"summary": summ}))


if __name__ == "__main__":
    main()
