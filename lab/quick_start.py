"""The README's Quick start as a new user runs it, over several seeds of the fit's search.

Runs the Quick start's first two commands in a scratch folder (``synth --model blender --resolution 120x160``,
then ``fit CAP --model blender --cameras n:4 [--seed S]``) in subprocesses (this driver never imports bpy) and
scores each fit against the capture's own truth (``meta.true_blender_cloth``): every free setting's ratio to the
truth, whether its 90 % interval holds the truth and whether the fit calls it undetermined, the held-out ratio to
the floor the fit states, the verdict's kind, the search's starts and how many agreed, wall and CPU seconds; and
the floors the fit states beside the truth's own errors on the same images (``evaluate`` with the capture's truth,
the fit's training cameras and times, then its held-out ones): the goal "a floor that is the floor".

    python lab/quick_start.py --seeds 0-4 --json out/quick_start.json
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import resource
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "lab"))

from fit_goals import parse_seeds  # noqa: E402  (the lab: the one seed-list parser)


def _clothfit(*args, cwd) -> str:
    """Run ``clothfit ARGS`` in ``cwd``; its stdout (one JSON document), or exit naming the command."""
    r = subprocess.run([sys.executable, "-m", "clothfit", *map(str, args)], cwd=cwd, capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"clothfit {' '.join(map(str, args))}: exit {r.returncode}: {r.stderr.strip()[-400:]}")
    return r.stdout


@functools.cache
def _truth_pct(work: str, cameras: tuple, times: tuple) -> float:
    """The capture's true settings' mean E_sil (%) on ``cameras`` at ``times`` (``evaluate``'s default params); the
    same for every seed's fit on the same images, so evaluated once."""
    out = _clothfit(
        "evaluate", "capture", "--cameras", ",".join(cameras), "--times", ",".join(f"{t:g}" for t in times), cwd=work
    )
    return float(json.loads(out)["silhouette_error_pct"])


def _floor_beside_truth(work: str, fit: dict) -> dict:
    """The fit's stated floors beside the truth's errors on the same training and held-out images."""
    fl = fit["floor"]
    times = tuple(fit["train_times"])
    if fl.get("heldout_n_frames") != len(times):
        raise SystemExit(f"the held-out floor covers {fl.get('heldout_n_frames')} frames, the training {len(times)}")
    train = _truth_pct(work, tuple(fit["train_cameras"]), times)
    held = _truth_pct(work, tuple(fl["heldout_cameras"]), times)  # the held-out side scores the same frames here
    return {
        "truth_train_pct": train,
        "truth_heldout_pct": held,
        "train_floor_pct": fl["train_floor_pct"],
        "heldout_floor_pct": fl["heldout_floor_pct"],
        "train_floor_over_truth": fl["train_floor_pct"] / train,
        "heldout_floor_over_truth": fl["heldout_floor_pct"] / held,
    }


def one(work: str, seed: int, search: list[str] | None = None) -> dict:
    """One fit of the Quick start's capture with ``--seed seed`` (0: no --seed, as the README has it) and the
    fit's ``--search`` options, if any (a variant of the search)."""
    res = os.path.join(work, f"fit_s{seed}.json")
    c0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.monotonic()
    _clothfit(
        "fit", "capture", "--model", "blender", "--cameras", "n:4", "--out", res, *(["--seed", seed] if seed else []),
        *[x for v in search or [] for x in ("--search", v)], cwd=work,
    )  # fmt: skip
    wall = time.monotonic() - t0
    c1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    with open(res) as fh:
        fit = json.load(fh)
    with open(os.path.join(work, "capture", "capture.json")) as fh:
        truth = json.load(fh)["meta"]["true_blender_cloth"]
    settings = {}
    for name, (lo, hi) in fit["intervals"].items():
        if name not in truth or name not in fit["blender_cloth"]:
            continue  # a manipulation offset (none in this capture)
        t = float(truth[name])
        settings[name] = {
            "truth": t,
            "fitted": float(fit["blender_cloth"][name]),
            "ratio": float(fit["blender_cloth"][name]) / t,
            "interval": [lo, hi],
            "holds_truth": bool(lo <= t <= hi),
            "undetermined": name in fit.get("undetermined", []),
        }
    floor = fit["floor"]
    return {
        "seed": seed,
        "settings": settings,
        "bending_ratio": settings["bending_stiffness"]["ratio"],
        "heldout_ratio": floor["heldout_ratio"],
        "train_ratio": floor.get("train_ratio"),
        "verdict_kind": fit["verdict_kind"],
        "looks": fit.get("looks"),
        "floor_vs_truth": _floor_beside_truth(work, fit),
        "intervals_holding": sum(s["holds_truth"] for s in settings.values()),
        "intervals": len(settings),
        "wall_s": wall,
        "cpu_s": (c1.ru_utime + c1.ru_stime) - (c0.ru_utime + c0.ru_stime),
        "load": os.getloadavg()[0],
    }


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0-4", help="the fit's seeds, e.g. 0-4 (0: the README's command as written)")
    ap.add_argument("--json", required=True, help="write the rows and their summary here")
    ap.add_argument(
        "--search", action="append", default=[], metavar="NAME=VALUE", help="the fit's --search (repeatable)"
    )
    a = ap.parse_args(argv)
    seeds = parse_seeds(a.seeds)
    rows = []
    with tempfile.TemporaryDirectory(prefix="quick_start_") as work:
        _clothfit("synth", "--model", "blender", "--out", "capture", "--resolution", "120x160", cwd=work)
        for s in seeds:
            rows.append(one(work, s, a.search))
            r = rows[-1]
            print(
                f"seed {s}: bending {r['bending_ratio']:.3f} of the truth, held-out {r['heldout_ratio']:.2f}x its floor, "
                f"{r['verdict_kind']}, intervals holding the truth {r['intervals_holding']}/{r['intervals']}, "
                f"{r['wall_s']:.0f} s",
                file=sys.stderr,
                flush=True,
            )
    summary = {
        "seeds": len(rows),
        "bending_within_10pct": sum(abs(r["bending_ratio"] - 1) <= 0.1 for r in rows),
        "bending_within_2x": sum(0.5 <= r["bending_ratio"] <= 2 for r in rows),
        "worst_bending_ratio": min(min(r["bending_ratio"], 1 / r["bending_ratio"]) for r in rows),
        "median_heldout_ratio": sorted(r["heldout_ratio"] for r in rows)[len(rows) // 2],
        "worst_heldout_ratio": max(r["heldout_ratio"] for r in rows),
        "intervals_holding": sum(r["intervals_holding"] for r in rows),
        "intervals": sum(r["intervals"] for r in rows),
        "tension_shear_determined_within_10pct": sum(
            all(not s["undetermined"] and abs(s["ratio"] - 1) <= 0.1 for n, s in r["settings"].items()
                if n in ("tension_stiffness", "shear_stiffness"))
            for r in rows
        ),  # fmt: skip
        "holding_or_undetermined": sum(
            all(s["holds_truth"] or s["undetermined"] for s in r["settings"].values()) for r in rows
        ),
        "train_floor_over_truth": [min(r["floor_vs_truth"]["train_floor_over_truth"] for r in rows),
                                   max(r["floor_vs_truth"]["train_floor_over_truth"] for r in rows)],
        "heldout_floor_over_truth": [min(r["floor_vs_truth"]["heldout_floor_over_truth"] for r in rows),
                                     max(r["floor_vs_truth"]["heldout_floor_over_truth"] for r in rows)],
    }  # fmt: skip
    sys.path.insert(0, ROOT)
    from clothfit.core.jsonio import write_json

    write_json(a.json, {"search": a.search, "summary": summary, "rows": rows})
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
