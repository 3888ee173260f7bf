"""Does a seed give the same fit on another machine? The same fit run natively and as on a CPU without AVX-512.

    python lab/same_fit.py [--json FILE] [--out DIR] [--evals 1500]

NumPy picks its kernels by the CPU it runs on; with AVX-512 its float64 ``exp`` and ``log`` (the fit's
log-scaled search space decodes with them) round some values to the other neighbouring float than
on a CPU without it. This tool makes a capture with Blender's cloth model (``synth --model blender``,
lab18 at 120 x 160, 5 % boundary noise), fits it twice with the same seed through the command line,
once as this machine runs it and once with ``NPY_DISABLE_CPU_FEATURES`` naming every AVX-512 feature
NumPy found here (NumPy then runs its AVX2 or baseline kernels, as on such a CPU), and compares: the
training error, the evaluations, the fitted settings (largest relative difference) and whether the
two results are the same. On a machine without AVX-512 there is nothing to switch off, and the JSON
says so (``avx512_here: false``).
"""

from __future__ import annotations

import argparse
import json
import os
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TOOLS = os.path.dirname(os.path.abspath(__file__))
if TOOLS not in sys.path:
    sys.path.insert(0, TOOLS)

from fit_goals import Runner  # noqa: E402  (the lab: the one runner of the CLI in a subprocess)

CAPTURE = ["--model", "blender", "--rig", "lab18", "--resolution", "120x160", "--noise", "0.05", "--seed", "3"]


def avx512_features() -> list:
    """The AVX-512 features NumPy found on this CPU (its dispatch names)."""
    from numpy.core._multiarray_umath import __cpu_features__

    return [k for k, v in __cpu_features__.items() if v and k.startswith("AVX512")]


def fit_once(run, capture, out, evals, seed, env):
    _, info = run(
        [
            "fit",
            capture,
            "--cameras",
            "n:4",
            "--max-evaluations",
            str(evals),
            "--seed",
            str(seed),
            "--out",
            out,
            "--force",
            "--quiet",
        ],
        env=env,
    )
    with open(out) as f:
        res = json.load(f)
    return {
        "train_E_sil_pct": res["best_E_sil_mean_pct"],
        "evaluations": res["evaluations"],
        "optimizer": res["optimizer"],
        "settings": {k: v for k, v in res["blender_cloth"].items() if isinstance(v, float)},
        "wall_s": info["wall_s"],
        "cpu_s": info["cpu_s"],
        "load": info["load"],
    }


def main(argv=None):
    ap = argparse.ArgumentParser(prog="lab/same_fit.py", description=__doc__.split("\n")[0])
    ap.add_argument("--out", default="out/same_fit", help="folder of the capture and the fits (default: %(default)s)")
    ap.add_argument("--evals", type=int, default=1500, help="each fit's budget (default: %(default)s)")
    ap.add_argument("--seed", type=int, default=0, help="the fits' seed (default: %(default)s)")
    ap.add_argument("--json", help="write the comparison here")
    a = ap.parse_args(argv)
    out = os.path.join(ROOT, a.out)
    run = Runner(os.path.join(out, "same_fit.log"))  # the CLI in a subprocess, logged and timed
    capture = os.path.join(out, "capture")
    if not os.path.isfile(os.path.join(capture, "capture.json")):
        run(["synth", "--out", capture, *CAPTURE])
    feats = avx512_features()
    runs = {"native": fit_once(run, capture, os.path.join(out, "native.json"), a.evals, a.seed, None)}
    if feats:
        env = dict(os.environ, NPY_DISABLE_CPU_FEATURES=" ".join(feats))
        runs["without_avx512"] = fit_once(run, capture, os.path.join(out, "without_avx512.json"), a.evals, a.seed, env)
    doc = {"avx512_here": bool(feats), "disabled": feats, "capture": CAPTURE, "evals": a.evals, "runs": runs}
    if feats:
        n, w = runs["native"], runs["without_avx512"]
        rel = max(abs(w["settings"][k] / n["settings"][k] - 1) for k in n["settings"] if n["settings"][k] != 0)
        doc["same_error"] = n["train_E_sil_pct"] == w["train_E_sil_pct"]
        doc["same_evaluations"] = n["evaluations"] == w["evaluations"]
        doc["settings_max_rel_diff"] = rel
        print(
            f"native {n['train_E_sil_pct']:.6f} %, without AVX-512 {w['train_E_sil_pct']:.6f} %; "
            f"settings differ by at most {rel:.1e} (relative)",
            file=sys.stderr,
        )
    else:
        print("no AVX-512 on this CPU: nothing to switch off", file=sys.stderr)
    if a.json:
        from clothfit.core.jsonio import write_json

        write_json(a.json, doc)
    print(json.dumps(doc))
    return 0


if __name__ == "__main__":
    sys.exit(main())
