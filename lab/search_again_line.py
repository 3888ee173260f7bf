"""Whether two searches of one fit ended in one basin: the training error along the line between their best points.

A fit searches again where a search ends above the floor its jitter allows (``addon/core/fitting/again.py``); a
third search costs a third more time, so a rule that stops once two searches end in one basin was tried: the
points a quarter, half and three quarters of the way between their best points (unit cube) all within
``BARRIER`` times the worse end. This measures that line on fits whose first search is known to have ended in
another basin than the truth's (the exact goal's capture, seeds 9 and 12: bending far off, 2.1-2.3x the truth's
held-out error, their second search at the floor): a rule that tells basins apart must see a ridge there.

    python lab/search_again_line.py CAPTURE --seeds 9,12 --json OUT     (runs fit CAPTURE --cameras n:4 --times train)
    python lab/search_again_line.py CAPTURE --checkpoints CK [CK ...]  (finished fits' OUT.checkpoint.json)

The fit's checkpoint keeps where each search ended (``again.ends``).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

from clothfit.core.fitting.job import FitJob  # noqa: E402
from clothfit.core.observation.capture import load_capture  # noqa: E402

LINE = np.linspace(0.0, 1.0, 11)
RULE = (0.25, 0.5, 0.75)  # the rule tried: these points ...
BARRIER = 1.25  # ... within this times the worse end = one basin


def line_profile(capture: str, checkpoint: str) -> dict:
    cap = load_capture(capture)
    job = FitJob.resume(checkpoint, capture=cap)
    ag = job.state.again or {}
    ends = [e for e in ag.get("ends") or [] if e]
    out = {"checkpoint": checkpoint, "searches": len(ends), "pairs": []}
    sp = job.space
    job.activate(job.chosen_quality())
    for i in range(len(ends)):
        for j in range(i + 1, len(ends)):
            (fa, xa), (fb, xb) = ends[i], ends[j]
            ua, ub = sp.encode(np.asarray([xa, xb], dtype=np.float64))
            X = sp.decode(ua[None] + LINE[:, None] * (ub - ua)[None])
            f = job.evaluate(X)
            worse = max(fa, fb)
            inner = f[1:-1]
            quarter = [float(job.evaluate(sp.decode(ua[None] + t * (ub - ua)[None]))[0]) for t in RULE]
            out["pairs"].append(
                {
                    "searches": [i + 1, j + 1],
                    "ends_E_all": [fa, fb],
                    "line_t": LINE.tolist(),
                    "line_E_all": [float(v) for v in f],
                    "ridge_ratio": float(np.max(inner)) / worse,
                    "rule_ridge_ratio": max(quarter) / worse,
                    "one_basin_by_rule": max(quarter) / worse <= BARRIER,
                    "settings": {n: [float(xa[k]), float(xb[k])] for k, n in enumerate(sp.names) if k < job.npar},
                }
            )
    return out


def run_fits(capture: str, seeds: list[int], tmp: str) -> list[str]:
    """The default fit of ``capture`` on 4 cameras and the training times, one per seed, two at a time: their
    checkpoints."""
    procs, cks = [], []
    for s in seeds:
        out = os.path.join(tmp, f"seed{s}.json")
        argv = [sys.executable, "-m", "clothfit", "fit", capture, "--cameras", "n:4", "--times", "train"]
        argv += ["--seed", str(s), "--out", out, "--force", "--quiet"]
        procs.append(subprocess.Popen(argv, stdout=subprocess.DEVNULL))
        cks.append(out + ".checkpoint.json")
        if len(procs) == 2:
            [p.wait() for p in procs]
            procs = []
    [p.wait() for p in procs]
    return cks


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("capture")
    ap.add_argument("--seeds", help="fit these seeds first (e.g. 9,12)")
    ap.add_argument("--checkpoints", nargs="*", default=[])
    ap.add_argument("--json")
    a = ap.parse_args(argv)
    cks = list(a.checkpoints)
    if a.seeds:
        cks += run_fits(a.capture, [int(v) for v in a.seeds.split(",")], tempfile.mkdtemp(prefix="line_"))
    rows = [line_profile(a.capture, ck) for ck in cks]
    for r in rows:
        for p in r["pairs"]:
            print(
                f"{r['checkpoint']}: searches {p['searches']}, ends {p['ends_E_all'][0]:.4g} / {p['ends_E_all'][1]:.4g}, "
                f"ridge {p['ridge_ratio']:.2f}x the worse end (rule's three points: {p['rule_ridge_ratio']:.2f}x, "
                f"one basin: {p['one_basin_by_rule']})"
            )
            print("   line:", " ".join(f"{v:.4g}" for v in p["line_E_all"]))
    if a.json:
        with open(a.json, "w", encoding="utf-8") as fh:
            json.dump({"barrier": BARRIER, "rule_points": list(RULE), "fits": rows}, fh, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
