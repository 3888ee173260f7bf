"""When does a fit stop by itself? CMA-ES and SPX + MGG on a small capture with a budget they never reach.

    python lab/stopping.py [--json FILE] [--budget 100000]

The capture of ``tests/test_trust.py`` (its fast version of this measurement): 6 cameras of lab18
at 60 x 80, frames at 0.1, 0.2, 0.3, 0.4, 0.6, 0.8 s, 5 % boundary noise, synthesis seed 3; fitted
on 3 training cameras (spread rule) and all 6 frames with CMA-ES (seeds 0-4) and SPX + MGG
(seeds 0-2). Prints, per run, the evaluations spent, why it stopped, the best training E_sil and the
recovery error of k/m, d/m and l.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)

from clothfit.core.fitting.job import FitConfig, FitJob
from clothfit.core.observation import camera as C
from clothfit.core.observation import synth
from clothfit.core.physics.scenario import paper_scenario

TIMES = [0.1, 0.2, 0.3, 0.4, 0.6, 0.8]
RUNS = [("cma-es", s) for s in range(5)] + [("spx-mgg", s) for s in range(3)]


def main(argv=None):
    ap = argparse.ArgumentParser(prog="lab/stopping.py", description=__doc__.split("\n")[0])
    ap.add_argument("--json", help="also write every figure to this file")
    ap.add_argument("--budget", type=int, default=100_000)
    a = ap.parse_args(argv)
    cams = [c.resized(60, 80) for c in C.load_rig("lab18")[:6]]
    train, _ = C.select_training(cams, 3)
    out = {
        "cameras": len(cams),
        "resolution": [60, 80],
        "train_cameras": train,
        "times": TIMES,
        "budget": a.budget,
        "runs": [],
    }
    with tempfile.TemporaryDirectory() as td:
        cap = synth.synth_capture(
            os.path.join(td, "cap"), cameras=cams, scenario=paper_scenario(frame_times=TIMES), seed=3
        )
        for opt, seed in RUNS:
            t0 = time.perf_counter()
            r = FitJob(
                cap,
                FitConfig(train_cameras=train, train_times=TIMES, optimizer=opt, seed=seed, max_evaluations=a.budget),
            ).run()
            run = {
                "optimizer": opt,
                "seed": seed,
                "evaluations": r["evaluations"],
                "stop_reason": r["stop_reason"],
                "converged_by": r.get("converged_by"),
                "best_E_sil_pct": r["best_E_sil_mean_pct"],
                "identifiable_error_pct": r["identifiable_error_pct"],
                "seconds": time.perf_counter() - t0,
            }
            out["runs"].append(run)
            e = run["identifiable_error_pct"]
            print(
                f"{opt:8s} seed {seed}: {run['evaluations']:6d} evaluations, {run['stop_reason']} "
                f"({', '.join(run['converged_by'] or [])}), best E_sil {run['best_E_sil_pct']:.4f} %, "
                f"k/m {e['k_over_m']:.3f} %, d/m {e['d_over_m']:.3f} %, l {e['l']:.3f} %",
                flush=True,
            )
    if a.json:
        with open(a.json, "w") as f:
            json.dump(out, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
