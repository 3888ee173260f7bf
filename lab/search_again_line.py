"""Whether two searches of one fit ended in one basin: the training error along the line between their best points.

Searching again (``addon/core/fitting/again.py``) stops where a search ends in the basin an earlier one ended in,
judged by the points a quarter, half and three quarters of the way between their best points (unit cube) scoring
within ``SEARCH_AGAIN_BARRIER`` times the worse end. This measures that line finely on finished fits whose
checkpoint keeps where each search ended (``again.ends``), so the rule can be checked where the answer is known:
a fit whose first search ended in another basin than the truth's (exact goal, seeds 9 and 12) must show a ridge;
searches that ended in one basin (settings alike, errors alike) must not.

    python lab/search_again_line.py CAPTURE CHECKPOINT [CHECKPOINT ...] [--json OUT]

The checkpoint is the one ``fit`` leaves beside its result (``OUT.checkpoint.json``).
"""

from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

from clothfit.core import defaults as D  # noqa: E402
from clothfit.core.fitting.job import FitJob  # noqa: E402
from clothfit.core.observation.capture import load_capture  # noqa: E402

LINE = np.linspace(0.0, 1.0, 11)


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
            quarter = [float(job.evaluate(sp.decode(ua[None] + t * (ub - ua)[None]))[0]) for t in D.SEARCH_AGAIN_LINE]
            out["pairs"].append(
                {
                    "searches": [i + 1, j + 1],
                    "ends_E_all": [fa, fb],
                    "line_t": LINE.tolist(),
                    "line_E_all": [float(v) for v in f],
                    "ridge_ratio": float(np.max(inner)) / worse,
                    "rule_ridge_ratio": max(quarter) / worse,
                    "one_basin_by_rule": max(quarter) / worse <= D.SEARCH_AGAIN_BARRIER,
                    "settings": {n: [float(xa[k]), float(xb[k])] for k, n in enumerate(sp.names) if k < job.npar},
                }
            )
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("capture")
    ap.add_argument("checkpoints", nargs="+")
    ap.add_argument("--json")
    a = ap.parse_args(argv)
    rows = [line_profile(a.capture, ck) for ck in a.checkpoints]
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
            json.dump({"barrier": D.SEARCH_AGAIN_BARRIER, "fits": rows}, fh, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
