"""Whether the first frames of a take make a smoother search objective than all of them, on the default fit's capture.

The default fit (``bench --default-fit``: a 21 x 21 cloth of Blender's model, 4 cameras x 15 frames at 480 x 640,
quality chosen, the manipulation's unknowns estimated) ends about 14x its held-out floor, its settings near the
truth's but bending 8x low. Four measurements:

* ``landscape``: the truth's training error in three windows of the training frames (0.1-0.5 s, 0.6-1.0 s,
  1.1-1.5 s) with one strong setting scaled by factors from 1 + 1e-6 to 0.1, the others at the truth. Where the
  error in a window does not grow as the setting moves away, that window's frames cannot lead a search to it.
* ``fits``: per seed, the default fit as ``bench --default-fit`` runs it (``clothfit fit CAPTURE --cameras n:4
  --times train --quality auto``: the quality chosen by the fit, one search) beside a fit in two steps of the same
  total budget: the first five training frames alone at the ladder's start quality (``--times 0.1,...,0.5
  --quality 5 --searches 1``, 1000 evaluations), then all training frames from its settings (``--init``, quality
  chosen, 1500 evaluations). Held-out ratio to the floor, the strong settings, wall and CPU time of each.
* ``cameras``: per seed, the default fit with more training cameras (``--cameras n:N``), the same budget: more
  views of the one take, against the same floor's ratio (held-out on the cameras it did not train on). With
  ``--n 4`` it is the default fit itself, and its record says what the user is told of how sure each setting is
  (every mode records each fit's intervals of the strong settings, whether they hold the truth, and their caveat).
* ``frames``: per seed, the fit on the first ``--k`` training frames alone (4 cameras, quality chosen, the default
  budget): the last frames left out, the weight the landscape suggests; scored on the held-out cameras at every
  training time beside the truth's own error there (``clothfit evaluate``).

    python lab/early_window.py landscape --json OUT
    python lab/early_window.py fits --seeds 0-3 --json OUT
    python lab/early_window.py cameras --n 8 --seeds 0-3 --json OUT
    python lab/early_window.py frames --k 10 --seeds 0-3 --json OUT
    python lab/early_window.py slice --points 48 --json OUT
    python lab/early_window.py around --from FITS.json --seeds 2-3 --json OUT
    python lab/early_window.py inside --seeds 0-1 --search ... --json OUT

* ``slice``: the truth's training error with bending at ``--points`` values across the search's range (the values
  a line of that many rows tries) and shear at 0.95, 1 and 1.05 of the truth's: how narrow the truth's bending
  valley is at this resolution beside the grid's cells.
* ``around``: for each seed of a recorded ``cameras`` run (``--from``), the line of 48 bendings through that fit's
  strong settings (the others at the truth's, the manipulation's unknowns at 0), at the fit's own tension and shear
  and with each moved by -0.01 and +0.01 of the search's cube, one at a time (the five passes ``fit --search
  staged_restart_grid_near=0.01`` tries): where the line's lowest cell lies once tension and shear move a step.
* ``inside``: per seed, the default fit with ``--search`` options that score the line at the first stage's end on
  the first frames (``staged_restart_grid_frames``), run to that line in this process; the line then scored on every
  frame too: whether the cells the first frames keep beat the stage's best point, and where every frame's best cell
  ranks on the first frames (the line in the search's own state, not at the truth's weak settings as in ``around``).
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from clothfit.core import defaults as D  # noqa: E402
from clothfit.core.fitting.job import FitConfig, FitJob  # noqa: E402
from clothfit.core.fitting.result import intervals_caveat  # noqa: E402
from clothfit.core.jsonio import read_json, write_json  # noqa: E402
from clothfit.core.observation.camera import select_training  # noqa: E402
from clothfit.core.observation.capture import load_capture  # noqa: E402
from generation_cost import workload  # noqa: E402

TRUTH = {  # the capture's settings (generation_cost.workload), Blender's defaults for the others, at mass 0.3
    "tension_stiffness": 15.0,
    "compression_stiffness": 15.0,
    "shear_stiffness": 5.0,
    "bending_stiffness": 0.5,
    "tension_damping": 5.0,
    "shear_damping": 5.0,
    "bending_damping": 0.5,
    "air_damping": 1.0,
}
MASS = 0.3  # Blender's default vertex mass: the search's settings are per unit mass
WINDOWS = {
    "0.1-0.5 s": [0.1, 0.2, 0.3, 0.4, 0.5],
    "0.6-1.0 s": [0.6, 0.7, 0.8, 0.9, 1.0],
    "1.1-1.5 s": [1.1, 1.2, 1.3, 1.4, 1.5],
}
FACTORS = [1.0, 1 + 1e-6, 1 + 1e-4, 1 + 1e-3, 1.01, 1.1, 1.5, 0.5, 0.2, 0.1]
STRONG = ("tension_stiffness", "shear_stiffness", "bending_stiffness", "air_damping")
EARLY = "0.1,0.2,0.3,0.4,0.5"


def _truth_job(cap, times: list[float]) -> FitJob:
    """A fit job on ``cap``'s 4 training cameras at ``times``, quality 5 (the capture's own): the truth's errors."""
    train, _ = select_training(cap.cameras, 4)
    return FitJob(cap, FitConfig(train_cameras=train, train_times=times, seed=0, quality=5))


def landscape(root: str) -> dict:
    cap = load_capture(root)
    jobs = {w: _truth_job(cap, t) for w, t in WINDOWS.items()}
    names = next(iter(jobs.values())).space.names
    x0 = np.array([TRUTH.get(n, 0.0) / MASS for n in names])  # the manipulation's unknowns at 0
    rows = []
    for s in STRONG:
        X = np.repeat(x0[None], len(FACTORS), 0)
        X[:, names.index(s)] *= np.array(FACTORS)
        for w, j in jobs.items():
            e = 100.0 * j.evaluate(X) / j.objective.n_images
            rows.append({"setting": s, "window": w, "factors": FACTORS, "E_sil_pct": [float(v) for v in e]})
            print(f"{s:18s} {w}: " + " ".join(f"{v:.3f}" for v in e), flush=True)
    return {"factors": FACTORS, "windows": WINDOWS, "rows": rows}


def bending_slice(root: str, points: int, shear_factors: list[float]) -> dict:
    """The truth's training error (4 cameras, the training frames, quality 5) with bending at ``points`` values across
    the fit's search range (the centres of equal cells of its log scale: the values a line of that many rows tries)
    and shear scaled by each of ``shear_factors``, the others at the truth: how wide the truth's bending valley is
    beside the search's range."""
    job = _truth_job(load_capture(root), D.TRAIN_TIMES)
    names, space = job.space.names, job.space
    x0 = np.array([TRUTH.get(n, 0.0) / MASS for n in names])
    ib, ish = names.index("bending_stiffness"), names.index("shear_stiffness")
    U = np.repeat(space.encode(x0[None]), points, 0)
    U[:, ib] = (np.arange(points) + 0.5) / points
    bend = space.decode(U)[:, ib] * MASS
    rows = []
    for k in shear_factors:
        X = space.decode(U)
        X[:, ish] *= k
        e = 100.0 * job.evaluate(X) / job.objective.n_images
        # the valley: the cells within twice the lowest (the plateau beside it scores several times more)
        valley = [float(b) for b, v in zip(bend, e) if v < 2.0 * e.min()]
        rows.append(
            {
                "shear_factor": k,
                "E_sil_pct": [float(v) for v in e],
                "lowest_pct": float(e.min()),
                "lowest_bending": float(bend[int(np.argmin(e))]),
                "valley_bendings": valley,
                "valley_points": len(valley),
                "plateau_pct": float(np.median(e[bend < 0.1])),  # the low bendings the wrong basin sits on
            }
        )
        print(f"shear x{k}: lowest {e.min():.3f} % at bending {bend[int(np.argmin(e))]:.3g}", flush=True)
    truth_pct = float(100.0 * job.evaluate(x0[None])[0] / job.objective.n_images)
    return {
        "points": points,
        "bending": [float(b) for b in bend],
        "truth_pct": truth_pct,
        "rows": rows,
        "range": [float(space.lo[ib] * MASS), float(space.hi[ib] * MASS)],
    }


def around(
    root: str, fits_json: str, seeds: list[int], step: float = 0.01, points: int = 48, k: int | None = None
) -> dict:
    """The line of ``points`` bendings through each seed's fitted strong settings (``fits_json``: a ``cameras``
    run's record or its data), at the fit's own tension and shear and with each moved by -``step`` and +``step`` of
    the search's cube, one at a time; scored on the training frames, or on the first ``k`` of them (a cheaper line:
    the simulation stops there)."""
    rec = read_json(fits_json, "fits")
    fits_by_seed = {f["seed"]: f["fit"] for f in rec.get("data", rec)["fits"]}
    times = D.TRAIN_TIMES if k is None else [round(0.1 * (i + 1), 2) for i in range(k)]
    job = _truth_job(load_capture(root), times)
    names, space = job.space.names, job.space
    ib = names.index("bending_stiffness")
    truth_row = None
    rows = []
    for seed in seeds:
        fit = fits_by_seed[seed]
        x0 = np.array([fit["settings"].get(n, TRUTH.get(n, 0.0)) / MASS for n in names])
        U = np.repeat(space.encode(x0[None]), points, 0)
        U[:, ib] = (np.arange(points) + 0.5) / points
        bend = space.decode(U)[:, ib] * MASS
        truth_row = int(np.argmin(np.abs(np.log(bend / TRUTH["bending_stiffness"]))))
        passes = []
        for moved, d in [(None, 0.0)] + [
            (n, d) for n in ("tension_stiffness", "shear_stiffness") for d in (-step, step)
        ]:
            V = U.copy()
            if moved is not None:
                V[:, names.index(moved)] += d
            e = 100.0 * job.evaluate(space.decode(V)) / job.objective.n_images
            k = int(np.argmin(e))
            passes.append(
                {
                    "moved": moved,
                    "by": d,
                    "value": None if moved is None else float(space.decode(V[:1])[0, names.index(moved)] * MASS),
                    "lowest_pct": float(e[k]),
                    "lowest_bending": float(bend[k]),
                    "truth_row_pct": float(e[truth_row]),
                    "plateau_pct": float(np.median(e[bend < 0.1])),
                }
            )
            print(f"seed {seed}, {moved or 'own'} {d:+.2f}: lowest {e[k]:.3f} % at bending {bend[k]:.3g}", flush=True)
        best = min(passes, key=lambda p: p["lowest_pct"])
        rows.append(
            {
                "seed": seed,
                "settings": fit["settings"],
                "passes": passes,
                "own_lowest_bending": passes[0]["lowest_bending"],
                "best_pass": best,
            }
        )
    return {
        "step": step,
        "points": points,
        "times": list(times),
        "truth_row_bending": float(bend[truth_row]),
        "seeds": rows,
    }


def _fit(argv: list[str]) -> tuple[float, float]:
    """Run ``clothfit fit`` as a user would: its wall and CPU time."""
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(
        [sys.executable, "-m", "clothfit", "fit", *argv, "--force", "--quiet"], check=True, stdout=subprocess.DEVNULL
    )
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.perf_counter() - t0, (r1.ru_utime + r1.ru_stime) - (r0.ru_utime + r0.ru_stime)


def _summary(path: str, wall: float, cpu: float) -> dict:
    r = read_json(path, "fit result")
    fl = r.get("floor") or {}
    bc = r["blender_cloth"]
    return {
        "wall_s": wall,
        "cpu_s": cpu,
        "evaluations": r["evaluations"],
        "train_E_sil_pct": r["best_E_sil_mean_pct"],
        "heldout_ratio": fl.get("heldout_ratio"),
        "train_ratio": fl.get("train_ratio"),
        "quality": bc.get("quality"),
        "settings": {k: bc[k] for k in STRONG},
        "bending_over_truth": bc["bending_stiffness"] / TRUTH["bending_stiffness"],
        # what the user is told of how sure each setting is: the intervals, and what they cannot say
        "intervals": {k: r["intervals"][k] for k in STRONG} if r.get("intervals") else None,
        "truth_inside": {k: r["intervals"][k][0] <= TRUTH[k] <= r["intervals"][k][1] for k in STRONG}
        if r.get("intervals")
        else None,
        "undetermined": r.get("undetermined"),
        "effective_points": (r.get("interval_method") or {}).get("effective_points"),
        "intervals_caveat": intervals_caveat(r),
        # how many independent starts the search made (1: its first run never settled, so no run again, no grid)
        "looks": r.get("looks"),
    }


def fits(root: str, seeds: list[int], tmp: str) -> list[dict]:
    rows = []
    base = [root, "--cameras", "n:4"]
    for s in seeds:
        load = os.getloadavg()[0]
        out = os.path.join(tmp, f"default{s}.json")
        w, c = _fit([*base, "--times", "train", "--quality", "auto", "--seed", str(s), "--out", out])
        default = _summary(out, w, c)
        early = os.path.join(tmp, f"early{s}.json")
        w1, c1 = _fit(
            [*base, "--times", EARLY, "--quality", "5", "--searches", "1", "--max-evaluations", "1000"]
            + ["--seed", str(s), "--out", early]
        )
        full = os.path.join(tmp, f"then_all{s}.json")
        w2, c2 = _fit(
            [*base, "--times", "train", "--quality", "auto", "--init", early, "--max-evaluations", "1500"]
            + ["--seed", str(s), "--out", full]
        )
        two = _summary(full, w1 + w2, c1 + c2)
        two["early_step"] = _summary(early, w1, c1)
        rows.append({"seed": s, "load_1min_at_start": load, "default": default, "early_then_all": two})
        print(
            f"seed {s}: default {default['heldout_ratio']:.2f}x held-out floor, bending {default['bending_over_truth']:.3g}x "
            f"the truth's, {default['wall_s']:.0f} s; early then all {two['heldout_ratio']:.2f}x, bending "
            f"{two['bending_over_truth']:.3g}x, {two['wall_s']:.0f} s (load {load:.2f})",
            flush=True,
        )
    return rows


def cameras(root: str, seeds: list[int], n: int, tmp: str, search: list[str] | None = None) -> list[dict]:
    rows = []
    for s in seeds:
        load = os.getloadavg()[0]
        out = os.path.join(tmp, f"cameras{n}_{s}.json")
        w, c = _fit(
            [root, "--cameras", f"n:{n}", "--times", "train", "--quality", "auto", "--seed", str(s), "--out", out]
            + [x for v in search or [] for x in ("--search", v)]
        )
        r = _summary(out, w, c)
        rows.append({"seed": s, "cameras": n, "load_1min_at_start": load, "fit": r})
        print(
            f"seed {s}, {n} cameras: {r['heldout_ratio']:.2f}x held-out floor, bending {r['bending_over_truth']:.3g}x "
            f"the truth's, {r['wall_s']:.0f} s (load {load:.2f})",
            flush=True,
        )
    return rows


def _heldout_all(root: str, params: str | None, tmp: str) -> float:
    """E_sil [%] on the cameras a 4-camera fit does not train on, at every training time (the truth's without
    ``params``)."""
    out = os.path.join(tmp, "evaluate.json")
    argv = ["evaluate", root, "--cameras", "heldout:4", "--times", "train", "--json", out, "--force"]
    subprocess.run(
        [sys.executable, "-m", "clothfit", *argv, *(["--params", params] if params else [])],
        check=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    return float(read_json(out, "evaluate output")["silhouette_error_pct"])


def frames(root: str, seeds: list[int], k: int, tmp: str) -> dict:
    times = ",".join(f"{0.1 * (i + 1):.1f}" for i in range(k))
    truth = _heldout_all(root, None, tmp)
    rows = []
    for s in seeds:
        load = os.getloadavg()[0]
        out = os.path.join(tmp, f"frames{k}_{s}.json")
        w, c = _fit([root, "--cameras", "n:4", "--times", times, "--quality", "auto", "--seed", str(s), "--out", out])
        r = _summary(out, w, c)
        r["heldout_all_times_pct"] = _heldout_all(root, out, tmp)
        r["heldout_all_times_over_truth"] = r["heldout_all_times_pct"] / truth
        rows.append({"seed": s, "frames": k, "load_1min_at_start": load, "fit": r})
        print(
            f"seed {s}, first {k} frames: held-out at every training time {r['heldout_all_times_over_truth']:.2f}x the "
            f"truth's, bending {r['bending_over_truth']:.3g}x the truth's, {r['wall_s']:.0f} s (load {load:.2f})",
            flush=True,
        )
    return {"times": times, "truth_heldout_all_times_pct": truth, "fits": rows}


def inside(root: str, seeds: list[int], search: list[str]) -> list[dict]:
    """Per seed, the default fit (4 cameras, quality chosen) with ``search`` (its --search, the line at the first
    stage's end on the first frames among them) run in this process to that line; the line's cells then scored
    on every training frame too: whether the first frames' best cells (the ones scored again) beat the stage's best
    point, and where every frame's best cell ranks on the first frames."""
    from clothfit.cli import build_parser
    from clothfit.cli.fitting import fit_config
    from clothfit.core.fitting.takes import window_objective

    cap = load_capture(root)
    rows = []
    for s in seeds:
        argv = ["fit", root, "--cameras", "n:4", "--times", "train", "--quality", "auto", "--seed", str(s)]
        a = build_parser().parse_args([*argv, "--out", "unused.json", *[x for v in search for x in ("--search", v)]])
        job = FitJob(cap, fit_config(a, cap).checked())
        while not (job.state.stage == "search" and job.opt.window is not None):
            if not job.step():
                raise SystemExit(
                    f"seed {s}: the fit ended before its line (is the line on the first frames asked for?)"
                )
        X = job.opt.ask()
        ib = list(job.space.names).index("bending_stiffness")
        bend = X[:, ib] * MASS / TRUTH["bending_stiffness"]
        win = window_objective(job, job.opt.window)
        fw = 100.0 * job.evaluate(X, win) / win.n_images
        ff = 100.0 * job.evaluate(X) / job.objective.n_images
        stage = 100.0 * job.opt.best_f / job.objective.n_images
        order, best = np.argsort(fw, kind="stable"), int(np.argmin(ff))
        kept = order[: D.STAGED_FIRST_RESTART_GRID_RESCORE]
        rows.append(
            {
                "seed": s,
                "line_cells": len(X),
                "stage_best_pct": float(stage),
                "stage_best_bending": float(job.opt.best_x[ib] * MASS / TRUTH["bending_stiffness"]),
                "kept_bending": [float(bend[i]) for i in kept],
                "kept_best_pct": float(ff[kept].min()),
                "kept_beat_stage": bool(ff[kept].min() < stage),
                "all_best_pct": float(ff[best]),
                "all_best_bending": float(bend[best]),
                "all_best_rank_on_first_frames": int(np.flatnonzero(order == best)[0]),
                "all_best_beat_stage": bool(ff[best] < stage),
                "first_frames_spread_below_bending_2": float(np.ptp(fw[bend < 2.0])),
                "every_frame_spread_below_bending_2": float(np.ptp(ff[bend < 2.0])),
            }
        )
        r = rows[-1]
        print(
            f"seed {s}: stage best {stage:.3f} % (bending {r['stage_best_bending']:.3g}x); the first frames' best "
            f"{len(kept)} cells {r['kept_best_pct']:.3f} % on every frame; every frame's best cell {ff[best]:.3f} % "
            f"(bending {bend[best]:.3g}x), rank {r['all_best_rank_on_first_frames']} of {len(X)} on the first frames",
            flush=True,
        )
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("what", choices=("landscape", "fits", "cameras", "frames", "slice", "around", "inside"))
    ap.add_argument("--points", type=int, default=48, help="slice: bendings across the search's range")
    ap.add_argument("--k", type=int, default=10, help="frames (and around with --first): the first K training frames")
    ap.add_argument("--first", action="store_true", help="around: score the line on the first K frames only")
    ap.add_argument("--n", type=int, default=8, help="cameras: training cameras")
    ap.add_argument("--seeds", default="0-3", help="fits, cameras, frames: seeds A-B")
    ap.add_argument("--json")
    ap.add_argument("--from", dest="fits_json", help="around: a recorded cameras run (its JSON)")
    ap.add_argument(
        "--search", action="append", default=[], metavar="NAME=VALUE", help="cameras: the fit's --search (repeatable)"
    )
    a = ap.parse_args(argv)
    tmp = tempfile.mkdtemp(prefix="early_window_")
    workload(tmp)  # the default fit's capture
    root = os.path.join(tmp, "default21")
    if a.what == "landscape":
        out = landscape(root)
    elif a.what == "slice":
        out = bending_slice(root, a.points, [0.95, 1.0, 1.05])
    else:
        lo, _, hi = a.seeds.partition("-")
        seeds = list(range(int(lo), int(hi or lo) + 1))
        if a.what == "fits":
            out = {"seeds": seeds, "fits": fits(root, seeds, tmp)}
        elif a.what == "around":
            out = around(root, a.fits_json, seeds, k=a.k if a.first else None)
        elif a.what == "inside":
            out = {"seeds": seeds, "search": a.search, "lines": inside(root, seeds, a.search)}
        elif a.what == "frames":
            out = {"seeds": seeds, "frames": a.k, **frames(root, seeds, a.k, tmp)}
        else:
            out = {"seeds": seeds, "cameras": a.n, "search": a.search, "fits": cameras(root, seeds, a.n, tmp, a.search)}
    if a.json:
        write_json(a.json, out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
