"""Our CMA-ES (plain or active) against the `cma` package on a Blender-model fit of the
cross-simulator's cotton capture (4 training cameras, even frames, default free set, seed N):
the best training E_sil after a fixed number of evaluations. Needs `lab/cross_simulator.py
observe --out out/cross2` first (or --capture DIR).

    python lab/optimiser_ab.py {own,own-active,cma} SEED [--evaluations 1000] [--capture DIR]
    python lab/optimiser_ab.py all 0-5 --json out/optimiser_ab.json    # the three on seeds 0..5
"""

from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)

from clothfit.core import defaults as D  # noqa: E402
from clothfit.core.fitting.job import FitConfig, FitJob  # noqa: E402
from clothfit.core.fitting.optimise import make_optimizer  # noqa: E402
from clothfit.core.observation.camera import select_training  # noqa: E402
from clothfit.core.observation.capture import load_capture  # noqa: E402

WHICH = ("own", "own-active", "cma")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("which", choices=WHICH + ("all",))
    ap.add_argument("seed", help="a seed, or a range A-B (inclusive)")
    ap.add_argument("--evaluations", type=int, default=1000)
    ap.add_argument("--capture", default=os.path.join("out", "cross2", "captures", "cotton"))
    ap.add_argument("--json", help="write {which: {seed: best training E_sil %}} and medians here")
    a = ap.parse_args(argv)
    lo, _, hi = a.seed.partition("-")
    seeds = range(int(lo), int(hi or lo) + 1)
    which = WHICH if a.which == "all" else (a.which,)
    out = {w: {} for w in which}
    for s in seeds:
        for w in which:
            out[w][str(s)] = run_one(w, s, a.evaluations, a.capture)
    if a.json:
        med = {w: float(np.median(list(v.values()))) for w, v in out.items()}
        with open(a.json, "w") as f:
            json.dump(
                {"capture": a.capture, "evaluations": a.evaluations, "best_train_E_sil_pct": out, "median_pct": med},
                f,
                indent=1,
            )


def run_one(which, seed, evaluations, capture):
    """Best training E_sil [%] of one run."""
    a = argparse.Namespace(which=which, seed=seed, evaluations=evaluations, capture=capture)
    cap = load_capture(a.capture)
    train, _ = select_training(cap.cameras, 4)
    job = FitJob(
        cap,
        FitConfig(
            train_cameras=train,
            train_times=list(cap.frame_times[1::2]),
            model="blender",
            max_evaluations=a.evaluations,
            seed=a.seed,
            restarts=0,
        ),
    )
    n_img = job.objective.n_images
    if a.which == "cma":  # the `cma` package, active CMA (its default), same cube, sigma and population
        import cma

        es = cma.CMAEvolutionStrategy(
            np.full(job.space.n, 0.5), 0.3, {"bounds": [0, 1], "seed": a.seed + 1, "popsize": 10, "verbose": -9}
        )
        ev, best = 0, np.inf
        while ev < a.evaluations:
            U = np.array(es.ask())
            f = job.objective(job.to_params(job.space.decode(U)))
            ev += len(U)
            f = np.where(np.isfinite(f), f, 1e9)
            es.tell(list(U), f.tolist())
            best = min(best, float(f.min()))
        print(f"cma seed {a.seed}: {ev} evaluations, best training E_sil {100 * best / n_img:.3f} %", flush=True)
        return 100 * best / n_img
    if a.which == "own-active":
        job.opt = make_optimizer(
            "cma-es",
            job.space,
            seed=a.seed,
            tolx=D.FIT_TOLX,
            tolfun=D.FIT_TOLFUN_PER_IMAGE * n_img,
            restarts=0,
            popsize=job.opt.popsize,
            active=True,
        )
    job.run()
    print(
        f"{a.which} seed {a.seed}: {job.evaluations} evaluations, best training E_sil "
        f"{100 * job.best_error / n_img:.3f} %",
        flush=True,
    )
    return 100 * job.best_error / n_img


if __name__ == "__main__":
    main()
