"""How sensitive is the paper scenario's motion to the parameters? (the figures on chaos: docs/figures_sources.md, sensitivity.)

    python lab/sensitivity.py [--json FILE]

For several k and d/m it perturbs k by a relative 1e-7 and prints the largest vertex displacement
over the 30 frames (t = 0.05 ... 1.5 s). A smooth, damped motion moves by ~1e-9 m; a chaotic one
amplifies the perturbation to tenths of a millimetre or more. It also prints the displacement for
larger perturbations of the ground truth (continuity of the motion in k/m).
"""

import argparse
import json
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from clothfit.core import defaults as D
from clothfit.core.physics.models import simulate
from clothfit.core.physics.paper import Params
from clothfit.core.physics.scenario import paper_scenario


def max_move(sc, base, rel):
    a = simulate(sc, [base]).positions[0]
    b = simulate(sc, [Params(base.m, base.k * (1 + rel), base.l, base.d)]).positions[0]
    return float(np.abs(a - b).max())


DAMPINGS = (5, 6, 7, 8, 10)  # d/m [1/s]
STIFFNESSES = (9.0, 10.0, 11.0)  # k [N/m]
CHANGES = (1e-6, 1e-4, 1e-3, 1e-2)


def main(argv=None):
    ap = argparse.ArgumentParser(prog="lab/sensitivity.py", description=__doc__.split("\n")[0])
    ap.add_argument("--json", help="also write every figure to this file")
    a = ap.parse_args(argv)
    sc = paper_scenario()
    m, l = D.GT_PARAMS["m"], D.GT_PARAMS["l"]
    out = {
        "perturbation": 1e-7,
        "d_over_m": list(DAMPINGS),
        "k": list(STIFFNESSES),
        "max_move_m": {},
        "ground_truth_changes": [],
    }
    print("max vertex displacement [m] after perturbing k by a relative 1e-7")
    print("k [N/m] | " + " | ".join(f"d/m = {dm:g} /s" for dm in DAMPINGS))
    for k in STIFFNESSES:
        moves = [max_move(sc, Params(m, k, l, dm * m), 1e-7) for dm in DAMPINGS]
        out["max_move_m"][f"{k:g}"] = moves
        print(f"{k:7.1f} | " + " | ".join(f"{c:12.1e}" for c in moves))
    gt = Params(**D.GT_PARAMS)
    print("ground truth: relative change of k -> max vertex displacement [m]")
    for rel in CHANGES:
        mv = max_move(sc, gt, rel)
        out["ground_truth_changes"].append({"relative_change": rel, "max_move_m": mv})
        print(f"  {rel:g}: {mv:.2e}")
    if a.json:
        os.makedirs(os.path.dirname(os.path.abspath(a.json)), exist_ok=True)
        with open(a.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
