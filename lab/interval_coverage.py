"""How often a fit's 90 % intervals hold the truth: synthetic captures of Blender's cloth with known settings,
each fitted as a user fits it (default options, 4 training cameras), every free setting's interval checked.

    python lab/interval_coverage.py --captures 6 --json out/interval_coverage.json [--workdir out/coverage]

The captures: a 11 x 11 cloth (the paper's scenario: three corners held, one released), the lab18 rig at
120 x 160 with 5 % boundary noise, 10 frames; tension, shear, bending and air damping drawn log-uniformly
within a factor 3 of Blender's defaults (compression follows tension), the dampings Blender's defaults. Each
capture is fitted once (seed 0); the truth's own training error is evaluated too, so that a fit whose search
ended in another basin (the truth scores lower by more than the fit's threshold) is told apart: coverage is
reported over every setting-and-capture and over the fits that ended in the truth's basin.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from clothfit.core.fitting.job import FitConfig, FitJob  # noqa: E402
from clothfit.core.jsonio import write_json  # noqa: E402
from clothfit.core.observation.camera import select_training  # noqa: E402
from clothfit.core.observation.capture import load_capture  # noqa: E402
from clothfit.core.observation.synth import synth_capture  # noqa: E402
from clothfit.core.physics import blender as B  # noqa: E402
from clothfit.core.physics.scenario import ClothGrid, paper_scenario  # noqa: E402

TIMES = [0.15, 0.3, 0.45, 0.6, 0.75, 0.9, 1.05, 1.2, 1.35, 1.5]
VARIED = ("tension_stiffness", "shear_stiffness", "bending_stiffness", "air_damping")


def truth_of(i: int) -> dict:
    rng = np.random.default_rng([7, i])
    t = {n: float(B.DEFAULTS[n] * 3.0 ** rng.uniform(-1, 1)) for n in VARIED}
    t["compression_stiffness"] = t["tension_stiffness"]
    return t


def make(root: str, i: int) -> None:
    if os.path.exists(os.path.join(root, "capture.json")):
        return
    sc = paper_scenario(ClothGrid(11, 11, 0.1), frame_times=TIMES)
    synth_capture(
        root,
        truth_of(i),
        model={"name": "blender", "fps": 24},
        rig="lab18",
        resolution=(120, 160),
        scenario=sc,
        noise=0.05,
        seed=i,
    )


def one(root: str, seed: int) -> dict:
    cap = load_capture(root)
    train, _ = select_training(cap.cameras, 4)
    t0 = time.process_time()
    job = FitJob(cap, FitConfig(train_cameras=train, seed=seed, quality=5))
    res = job.run()
    cpu = time.process_time() - t0
    truth = cap.meta["true_blender_cloth"]
    x_t = np.array([job.par.coordinate(n, truth[n]) for n in job.par.free])
    e_truth = float(job.evaluate(x_t[None])[0])
    im = res.get("interval_method") or {}
    thr = im.get("threshold") or 0.0
    rows = []
    for n in job.par.free:
        lo, hi = res["intervals"][n] if res["intervals"] else (None, None)
        rows.append(
            {
                "setting": n,
                "truth": truth[n],
                "fit": res["blender_cloth"][n],
                "interval": [lo, hi],
                "holds": lo is not None and lo * (1 - 1e-9) <= truth[n] <= hi * (1 + 1e-9),
                "undetermined": n in (res["undetermined"] or []),
                "axis_widened": bool(im.get("details", {}).get(n, {}).get("axis_widened")),
            }
        )
    return {
        "capture": os.path.basename(root),
        "seed": seed,
        "cpu_s": cpu,
        "train_E_all": res["best_E_all"],
        "truth_E_all": e_truth,
        "threshold": thr,
        "effective_points": im.get("effective_points"),
        "truth_basin": bool(e_truth >= res["best_E_all"] - 2 * thr),
        "rows": rows,
    }


def summary(fits: list) -> dict:
    def share(rows):
        return {
            "pairs": len(rows),
            "hold": sum(r["holds"] for r in rows),
            "coverage": (sum(r["holds"] for r in rows) / len(rows)) if rows else None,
        }

    every = [r for f in fits for r in f["rows"]]
    basin = [r for f in fits if f["truth_basin"] for r in f["rows"]]
    det = [r for r in every if not r["undetermined"]]
    return {
        "all": share(every),
        "truth_basin_fits": share(basin),
        "determined": share(det),
        "fits": len(fits),
        "fits_in_truth_basin": sum(f["truth_basin"] for f in fits),
        "undetermined_pairs": sum(r["undetermined"] for r in every),
        "axis_widened_pairs": sum(bool(r.get("axis_widened")) for r in every),
    }


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--captures", type=int, default=6)
    ap.add_argument("--first", type=int, default=0)
    ap.add_argument("--workdir", default=os.path.join(ROOT, "out", "interval_coverage"))
    ap.add_argument("--json", required=True)
    a = ap.parse_args(argv)
    fits = []
    for i in range(a.first, a.first + a.captures):
        root = os.path.join(a.workdir, f"cap{i:02d}")
        make(root, i)
        f = one(root, 0)
        fits.append(f)
        held = sum(r["holds"] for r in f["rows"])
        print(
            f"{f['capture']}: {held}/{len(f['rows'])} hold, truth basin {f['truth_basin']} (fit {f['train_E_all']:.3f} "
            f"truth {f['truth_E_all']:.3f}), {f['cpu_s']:.0f} s CPU",
            file=sys.stderr,
            flush=True,
        )
        write_json(a.json, {"fits": fits, "summary": summary(fits)}, strict=True)
    print(json.dumps(summary(fits)))


if __name__ == "__main__":
    main()
