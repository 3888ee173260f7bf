"""The paper's experiment (docs/method.md#spec-5): Table 1, the Fig. 8 sweep, Table 2, and SPX+MGG vs CMA-ES.

Protocol, all on our ground truth (``defaults.GT_PARAMS``, simulated with a 4x finer step than the
fitter uses) and the ``lab18`` rig:

* capture: 30 shapes every 0.05 s after releasing one of four held corners, 18 cameras at 480 x 640,
  5 % of the boundary pixels of every silhouette flipped (seeded);
* training shapes t = 0.10 ... 1.50, test shapes t = 0.05 ... 1.45;
* Table 1: train with 1, 2, 4, 8, 16 cameras chosen by the spread rule (``camera.spread_order``);
  silhouette error = mean ``E_sil x 100`` over the test-shape images of the cameras NOT used in
  training; shape error = mean over test shapes of the mean vertex distance [mm] to the truth;
  beside them two floors on the same images: the truth's own silhouettes vs the noisy observations
  (noise only), and the true parameters run through the fitter's model (noise + discretisation);
* Fig. 8: the same with the first N training shapes, N = 3 ... 15;
* Table 2: train with 2, 4, 8 cameras on captures rendered at 60 x 80, 120 x 160, 240 x 320 (noise
  applied at that resolution), test against the unused cameras' 480 x 640 test images;
* optimisers: evaluations for SPX+MGG and CMA-ES to reach given mean training ``E_sil`` levels,
  over several seeds, on the 4-camera problem.
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Callable, Iterable, Sequence
from typing import Any

import numpy as np

from .. import defaults as D
from ..errors import ClothFitError
from ..fitting.evaluate import evaluate
from ..fitting.job import FitConfig, FitJob
from ..fitting.progress import run_shown
from ..observation.camera import select_training
from ..observation.capture import Capture, load_capture
from ..observation.raster import silhouette
from ..observation.synth import synth_capture
from ..physics.paper import identifiable, identifiable_errors

FULL = dict(evals=2500, fig8_cameras=[1, 16], opt_seeds=5, opt_evals=2000, opt_cameras=4)
QUICK = dict(evals=700, fig8_cameras=[4], opt_seeds=2, opt_evals=600, opt_cameras=4)
DEFAULT_OPTIMIZER = D.DEFAULT_OPTIMIZER
# optimiser variants compared: the paper's GA with the textbook sizes (population 20n, 10n children),
# the same GA with a smaller population (7n, 5n children), and CMA-ES with its default population
OPT_VARIANTS = [
    ("spx-mgg", {"optimizer": "spx-mgg", "population": D.GA_POPULATION_TEXTBOOK, "children": D.GA_CHILDREN_TEXTBOOK}),
    ("spx-mgg-small", {"optimizer": "spx-mgg", "population": 7 * D.N_FREE, "children": 5 * D.N_FREE}),
    ("cma-es", {"optimizer": "cma-es"}),
]


def noise_floor(capture: Capture, cams: Iterable[int], times: Iterable[float]) -> float:
    """Mean E_sil x 100 of the truth's own (noise-free) silhouettes against the observations."""
    fidx = [capture.frame_index(t) for t in times]
    tris = capture.scenario.grid.triangles
    e = []
    for c in cams:
        for f in fidx:
            obs = capture.load_silhouette(c, f)
            mod = silhouette(capture.cameras[c], capture.shapes[f], tris)
            e.append(np.count_nonzero(obs ^ mod) / obs.sum())
    return 100.0 * float(np.mean(e))


def _log(msg):
    print(msg, flush=True)


def fit_and_score(
    train_cap: Capture,
    test_cap: Capture,
    n_cams: int,
    train_times: Sequence[float],
    optimizer: str,
    evals: int,
    seed: int,
    resolution: Sequence[int] | None = None,
    sizes: dict[str, int] | None = None,
    progress: Callable[[str], Any] | None = None,
) -> tuple[dict[str, Any], list[int]]:
    train, held = select_training(train_cap.cameras, n_cams)
    t0 = time.time()
    job = FitJob(
        train_cap,
        FitConfig(
            train_cameras=train,
            train_times=train_times,
            optimizer=optimizer,
            seed=seed,
            max_evaluations=evals,
            **(sizes or {}),
        ),
    )
    res = run_shown(job, progress, f"cameras {n_cams}, shapes {len(train_times)}, seed {seed}")
    ev = evaluate(test_cap, res["params"], cameras=held, times=D.TEST_TIMES)
    gt = test_cap.meta["true_params"]
    row = {
        "cameras": n_cams,
        "train_shapes": len(train_times),
        "silhouette_error_pct": ev["silhouette_error_pct"],
        "shape_error_mm": ev["shape_error_mm"],
        "train_E_sil_pct": res["best_E_sil_mean_pct"],
        "params": res["params"],
        "identifiable": identifiable(res["params"]),
        "identifiable_error_pct": identifiable_errors(res["params"], gt),
        "evaluations": res["evaluations"],
        "fit_seconds": time.time() - t0,
        "train_cameras": [train_cap.cameras[c].name for c in train],
        "heldout_cameras": [test_cap.cameras[c].name for c in held],
    }
    if resolution:
        row["train_resolution"] = list(resolution)
    return row, held


def _check_options(max_evaluations, population, children, truth_dt_safety):
    """``run_paper``'s numbers, checked: one error naming the option at fault."""
    for name, v, lo in (
        ("max_evaluations", max_evaluations, 1),
        ("population", population, 2),
        ("children", children, 1),
    ):
        if v is not None and (isinstance(v, bool) or not isinstance(v, int) or v < lo):
            raise ClothFitError(f"paper: {name} must be an integer >= {lo}, got {v!r}")
    if truth_dt_safety is not None and not (
        isinstance(truth_dt_safety, (int, float)) and math.isfinite(truth_dt_safety) and 0 < truth_dt_safety <= 1
    ):
        raise ClothFitError(f"paper: --truth-dt-safety must be a number in (0, 1], got {truth_dt_safety!r}")


def run_paper(
    json_path: str | os.PathLike,
    quick: bool = False,
    out_dir: str | os.PathLike = "out/paper",
    seed: int = 0,
    optimizer: str | None = None,
    max_evaluations: int | None = None,
    only: str | None = None,
    truth_dt_safety: float | None = None,
    population: int | None = None,
    children: int | None = None,
    rig: str | None = None,
    progress: Callable[[str], Any] | None = None,
) -> dict[str, Any]:
    """``progress``: a maker of each fit's progress display (``fitting.progress.FitProgress``), or None."""
    S = dict(QUICK if quick else FULL)
    _check_options(max_evaluations, population, children, truth_dt_safety)
    if max_evaluations is not None:
        S["evals"] = max_evaluations
    optimizer = optimizer or DEFAULT_OPTIMIZER
    parts = set((only or "table1,fig8,table2,optimizers").split(","))
    sizes = {k: v for k, v in (("population", population), ("children", children)) if v is not None}
    kw = {"sizes": sizes, "progress": progress}
    t_start = time.time()
    os.makedirs(out_dir, exist_ok=True)
    cap_path = os.path.join(out_dir, "capture_480x640")
    _log(f"synthesising the ground-truth capture -> {cap_path}")
    tds = D.TRUTH_DT_SAFETY if truth_dt_safety is None else truth_dt_safety
    rig = rig or D.DEFAULT_RIG
    synth_capture(cap_path, seed=seed, truth_dt_safety=tds, rig=rig)
    cap = load_capture(cap_path)
    gt = cap.meta["true_params"]
    out = {
        "protocol": "SPEC 5 (see addon/core/studies/experiment.py)",
        "quick": quick,
        "seed": seed,
        "optimizer": optimizer,
        "optimizer_sizes": sizes,
        "evaluations_per_fit": S["evals"],
        "true_params": gt,
        "truth_dt_safety": tds,
        "model_dt_safety": D.DT_SAFETY,
        "true_identifiable": identifiable(gt),
        "rig": rig,
        "noise_fraction": D.NOISE_FRACTION,
    }

    if "table1" in parts:
        rows = []
        for n in D.TABLE1_CAMERAS:
            row, held = fit_and_score(cap, cap, n, D.TRAIN_TIMES, optimizer, S["evals"], seed, **kw)
            row["floor_noise_only_pct"] = noise_floor(cap, held, D.TEST_TIMES)
            fl = evaluate(cap, gt, cameras=held, times=D.TEST_TIMES)
            row["floor_true_params_pct"] = fl["silhouette_error_pct"]
            row["floor_true_params_shape_mm"] = fl["shape_error_mm"]
            rows.append(row)
            _log(
                f"table1 cameras={n:2d}: silhouette {row['silhouette_error_pct']:.3f} % (floors: noise "
                f"{row['floor_noise_only_pct']:.3f} %, true params {row['floor_true_params_pct']:.3f} %), shape "
                f"{row['shape_error_mm']:.3f} mm, recovery {_fmt_id(row['identifiable_error_pct'])} "
                f"[{row['fit_seconds']:.0f} s]"
            )
        out["table1"] = rows
        best = rows[-1]
        out["identifiable"] = {
            "estimated": best["identifiable"],
            "true": identifiable(gt),
            "error_pct": best["identifiable_error_pct"],
            "cameras": best["cameras"],
        }
        _dump(json_path, out)

    if "fig8" in parts:
        rows = []
        for n in S["fig8_cameras"]:
            for N in D.FIG8_SHAPES:
                row, _ = fit_and_score(cap, cap, n, D.TRAIN_TIMES[:N], optimizer, S["evals"], seed, **kw)
                rows.append(row)
                _log(
                    f"fig8 cameras={n:2d} shapes={N:2d}: silhouette {row['silhouette_error_pct']:.3f} %, shape "
                    f"{row['shape_error_mm']:.3f} mm [{row['fit_seconds']:.0f} s]"
                )
        out["fig8"] = rows
        _dump(json_path, out)

    if "table2" in parts:
        rows = []
        for res in D.TABLE2_RESOLUTIONS:
            lp = os.path.join(out_dir, f"capture_{res[0]}x{res[1]}")
            synth_capture(lp, seed=seed, resolution=res, truth_dt_safety=tds, rig=rig)
            low = load_capture(lp)
            for n in D.TABLE2_CAMERAS:
                row, held = fit_and_score(low, cap, n, D.TRAIN_TIMES, optimizer, S["evals"], seed, resolution=res, **kw)
                row["floor_noise_only_pct"] = noise_floor(cap, held, D.TEST_TIMES)
                rows.append(row)
                _log(
                    f"table2 {res[0]}x{res[1]} cameras={n}: silhouette {row['silhouette_error_pct']:.3f} %, shape "
                    f"{row['shape_error_mm']:.3f} mm [{row['fit_seconds']:.0f} s]"
                )
        out["table2"] = rows
        _dump(json_path, out)

    if "optimizers" in parts:
        out["optimizers"] = compare_optimizers(cap, S["opt_cameras"], S["opt_seeds"], S["opt_evals"], progress=progress)
        _dump(json_path, out)

    out["total_seconds"] = time.time() - t_start
    _dump(json_path, out)
    print(format_tables(out))
    return out


def compare_optimizers(
    cap: Capture,
    n_cams: int,
    seeds: int,
    evals: int,
    levels: Sequence[float] = (2.0, 1.0, 0.5),
    progress: Callable[[str], Any] | None = None,
) -> dict[str, Any]:
    """Evaluations each optimiser needs to bring the mean training E_sil below ``levels`` [%]."""
    train, _ = select_training(cap.cameras, n_cams)
    out = {
        "cameras": n_cams,
        "seeds": seeds,
        "budget": evals,
        "levels_pct": list(levels),
        "runs": [],
        "variants": {k: v for k, v in OPT_VARIANTS},
    }
    for label, kw in OPT_VARIANTS:
        opt = label
        for s in range(seeds):
            job = FitJob(
                cap,
                FitConfig(train_cameras=train, train_times=D.TRAIN_TIMES, seed=100 + s, max_evaluations=evals, **kw),
            )
            run_shown(job, progress, f"{label}, seed {100 + s}")
            n_img = job.objective.n_images
            hist = [(e, 100 * f / n_img) for e, f in job.opt.history]
            reach = {}
            for lv in levels:
                hit = [e for e, f in hist if f <= lv]
                reach[str(lv)] = int(hit[0]) if hit else None
            out["runs"].append(
                {
                    "optimizer": opt,
                    "seed": 100 + s,
                    "final_E_sil_pct": hist[-1][1],
                    "evaluations_to_reach": reach,
                    "evaluations": job.evaluations,
                }
            )
            _log(f"optimizers {opt} seed {100 + s}: final {hist[-1][1]:.3f} %, reach {reach}")
    summ = {}
    for opt, _ in OPT_VARIANTS:
        runs = [r for r in out["runs"] if r["optimizer"] == opt]
        summ[opt] = {"final_E_sil_pct_median": float(np.median([r["final_E_sil_pct"] for r in runs]))}
        for lv in levels:
            hits = [r["evaluations_to_reach"][str(lv)] for r in runs]
            ok = [h for h in hits if h is not None]
            summ[opt][f"reached_{lv}"] = f"{len(ok)}/{len(runs)}"
            summ[opt][f"median_evals_to_{lv}"] = float(np.median(ok)) if ok else None
    out["summary"] = summ
    return out


def _fmt_id(e):
    return "k/m {k_over_m:.2f} %, d/m {d_over_m:.2f} %, l {l:.2f} %".format(**e)


def _dump(path, obj):
    from ..jsonio import write_json

    write_json(path, obj)


def format_tables(out: dict[str, Any]) -> str:
    L = []
    if "table1" in out:
        L.append("Table 1 (held-out cameras, test shapes)           ours                paper")
        L.append(
            "cameras | silhouette % | floor noise / true-params % | shape mm | silhouette % | shape mm | k/m, d/m, l error %"
        )
        for r in out["table1"]:
            ps, pm = D.PAPER_TABLE1[r["cameras"]]
            e = r["identifiable_error_pct"]
            L.append(
                f"{r['cameras']:7d} | {r['silhouette_error_pct']:12.3f} | {r['floor_noise_only_pct']:10.3f} / "
                f"{r['floor_true_params_pct']:6.3f}     | {r['shape_error_mm']:8.4f} | {ps:12.3f} | {pm:8.3f} | "
                f"{e['k_over_m']:.2f}, {e['d_over_m']:.2f}, {e['l']:.2f}"
            )
    if "fig8" in out:
        L.append("")
        L.append("Fig. 8 (first N training shapes): cameras | N | silhouette % | shape mm")
        for r in out["fig8"]:
            L.append(
                f"  {r['cameras']:3d} | {r['train_shapes']:2d} | {r['silhouette_error_pct']:7.3f} | {r['shape_error_mm']:7.4f}"
            )
    if "table2" in out:
        L.append("")
        L.append("Table 2 (silhouette % at 480x640, held-out cameras): ours (paper)")
        L.append("resolution | " + " | ".join(f"{n} cams" for n in D.TABLE2_CAMERAS))
        for res in D.TABLE2_RESOLUTIONS:
            cells = []
            for n in D.TABLE2_CAMERAS:
                r = [x for x in out["table2"] if x["cameras"] == n and tuple(x["train_resolution"]) == tuple(res)]
                fl = f" [floor {r[0]['floor_noise_only_pct']:.3f}]" if r and "floor_noise_only_pct" in r[0] else ""
                cells.append(
                    f"{r[0]['silhouette_error_pct']:.3f}{fl} ({D.PAPER_TABLE2[tuple(res)][n]:.3f})" if r else "-"
                )
            L.append(f"{res[0]}x{res[1]} | " + " | ".join(cells))
    if "optimizers" in out:
        o = out["optimizers"]
        L.append("")
        L.append(
            f"Optimisers ({o['cameras']} cameras, {o['seeds']} seeds, budget {o['budget']}): "
            f"median evaluations to reach mean training E_sil"
        )
        for opt, s in o["summary"].items():
            L.append(
                f"  {opt:13s}: "
                + ", ".join(f"{lv} %: {s[f'median_evals_to_{lv}']} ({s[f'reached_{lv}']})" for lv in o["levels_pct"])
                + f"; median final {s['final_E_sil_pct_median']:.3f} %"
            )
    if "identifiable" in out:
        i = out["identifiable"]
        L.append("")
        L.append(
            f"Identifiable quantities ({i['cameras']} cameras): estimated {json.dumps({k: round(v, 6) for k, v in i['estimated'].items()})}, "
            f"true {json.dumps({k: round(v, 6) for k, v in i['true'].items()})}, error % {json.dumps({k: round(v, 3) for k, v in i['error_pct'].items()})}"
        )
    return "\n".join(L)
