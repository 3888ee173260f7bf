"""Cloth that Blender's solver made, fitted by the paper's sheet and by the core's blender model.

The set-up that first showed the paper's sheet cannot move like Blender's cloth: a 10 cm sheet, 21 x 21
vertices, hung from its four corners for ``SETTLE`` s, one corner released, ``AFTER`` s of motion at 24 fps;
three materials; a 12-camera rig that is not ours (two rings and a top pair, 480 x 640, fx 700, 0.45 m);
fitted on 1, 2, 4 and 8 cameras (spread rule) and the even frames, scored on the held-out cameras and the
odd frames.

1. ``observe`` (needs the bpy module): Blender's own Cloth modifier simulates each material
   (``clothfit.blender.cloth.replay``); the true vertices go to ``shapes.npz``; silhouettes are the
   core rasteriser's (which agrees with Workbench to < 1 % XOR, ``lab/raster_agreement.py``)
   with the usual boundary noise: one capture per material.
2. ``fit`` (no bpy): for every material, model and training-camera count a ``FitJob``; scores:
   held-out silhouette error (held-out cameras x odd frames), shape error [mm] at the odd frames
   against Blender's true vertices, and the noise floor (the true shapes' own held-out error).
3. ``replay`` (needs bpy): every blender-model result's ``blender_cloth`` is put on a Cloth
   modifier of the same mesh and pins, simulated by Blender, and compared with the truth.
4. ``all``: the three in order; ``observe`` and ``replay`` run in child processes, so the
   fitting process never imports bpy.

    python lab/cross_simulator.py all --out out/cross [--cameras 1,2,4,8] [--budget 3000] [--quick]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)

from clothfit.core.physics import blender as B  # noqa: E402
from clothfit.core.physics.scenario import ClothGrid, Scenario, paper_scenario  # noqa: E402

FPS = 24.0
SETTLE = 1.0
AFTER = 1.5
GRID = 21
MATERIALS = {  # Blender ClothSettings; time_scale: real time at 24 fps
    "cotton (Blender's defaults)": {},
    "silk (soft, little bending)": B.PRESETS["silk"],
    "denim (stiff, quality 12)": B.PRESETS["denim"],
}


def slug(name):
    return name.split(" ")[0]


def scenario() -> Scenario:
    times = np.arange(1, int(round(AFTER * FPS)) + 1) / FPS
    sc = paper_scenario(ClothGrid(GRID, GRID, 0.10), frame_times=times)
    return Scenario(sc.grid, sc.handles, sc.frame_times, SETTLE, sc.gravity)


def rig():
    from clothfit.core.observation.camera import ring_rig

    return ring_rig(
        n_per_ring=(6, 4, 2),
        elevations_deg=(10.0, 40.0, 75.0),
        distance=0.45,
        target=(0.0, 0.0, 0.06),
        width=640,
        height=480,
        fx=700.0,
        azimuth_offsets_deg=(15.0, 60.0, 30.0),
    )


def material_settings(name):
    return B.check_settings(dict(MATERIALS[name], time_scale=B.physical_time_scale(FPS)))


# ------------------------------------------------------------------------- observe (bpy)


def observe(out):
    import bpy
    from clothfit.blender import cloth as BC
    from clothfit.core import defaults as D
    from clothfit.core.observation.capture import write_capture
    from clothfit.core.observation.metrics import add_boundary_noise
    from clothfit.core.observation.raster import silhouette
    from clothfit.core.observation.synth import noise_rng

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    sc = scenario()
    cams = rig()
    for name in MATERIALS:
        s = material_settings(name)
        t0 = time.perf_counter()
        X = BC.replay(scene, sc, s, FPS)
        sils = []
        for ci, cam in enumerate(cams):
            row = []
            for fi in range(X.shape[0]):
                m = silhouette(cam, X[fi], sc.grid.triangles)
                row.append(add_boundary_noise(m, D.NOISE_FRACTION, noise_rng(0, ci, fi)))
            sils.append(row)
        meta = {
            "generator": f"Blender {bpy.app.version_string} Cloth modifier (lab/cross_simulator.py), core rasteriser",
            "true_blender_cloth": s,
            "true_model": {"name": "blender", "fps": FPS},
            "material": name,
            "noise_fraction": D.NOISE_FRACTION,
        }
        root = os.path.join(out, "captures", slug(name))
        write_capture(root, cams, sc, sils, shapes=X, cloth_mass=s["mass"] * sc.grid.n_vertices, meta=meta)
        print(f"observed {name}: {X.shape[0]} frames in {time.perf_counter() - t0:.1f} s -> {root}", flush=True)


# ------------------------------------------------------------------------------ fit (no bpy)


def fit(out, cameras, budget, paper_cameras, materials=None):
    from clothfit.core.fitting.evaluate import evaluate
    from clothfit.core.fitting.job import FitConfig, FitJob
    from clothfit.core.observation.camera import select_training
    from clothfit.core.observation.capture import load_capture

    path_json = os.path.join(out, "cross_simulator.json")
    rows = []
    if materials and os.path.isfile(path_json):  # a partial rerun keeps the other materials' rows
        with open(path_json) as f:
            rows = [r for r in json.load(f) if slug(r["material"]) not in materials]
    for name in MATERIALS:
        if materials and slug(name) not in materials:
            continue
        cap = load_capture(os.path.join(out, "captures", slug(name)))
        times = cap.frame_times
        even, odd = list(times[1::2]), list(times[0::2])  # frames 2, 4, ... train; 1, 3, ... test
        truth = {
            "model": {"name": "blender", "fps": FPS},
            "blender_cloth": cap.meta["true_blender_cloth"],
            "blender_scene": {"fps": FPS},
        }
        quality = cap.meta["true_blender_cloth"]["quality"]  # the scene's quality is the user's choice
        if quality != B.DEFAULTS["quality"]:
            q5 = evaluate(
                cap, dict(truth, blender_cloth=dict(truth["blender_cloth"], quality=B.DEFAULTS["quality"])), times=odd
            )
            print(
                f"{name}: the true settings at quality {B.DEFAULTS['quality']} instead of {quality}: E_sil "
                f"{q5['silhouette_error_pct']:.2f} %, shape {q5['shape_error_mm']:.3f} mm (so the fit uses "
                f"--quality {quality})",
                flush=True,
            )
        runs = [("blender", n) for n in cameras] + [("paper", n) for n in paper_cameras]
        for model, n in runs:
            train, held = select_training(cap.cameras, n)
            cfg = FitConfig(
                train_cameras=train,
                train_times=even,
                model=model,
                max_evaluations=budget,
                seed=0,
                quality=quality if model == "blender" else None,
            )
            t0 = time.perf_counter()
            job = FitJob(cap, cfg)
            job.run()
            wall = time.perf_counter() - t0
            res = job.result()
            path = os.path.join(out, "fits", f"{slug(name)}_{model}_{n}cams.json")
            job.save_result(path)
            ev = evaluate(cap, res, cameras=held, times=odd)
            floor = evaluate(cap, truth, cameras=held, times=odd)
            r = {
                "material": name,
                "model": model,
                "train_cameras": n,
                "evaluations": job.evaluations,
                "wall_s": wall,
                "train_E_sil_pct": res["best_E_sil_mean_pct"],
                "heldout_E_sil_pct": ev["silhouette_error_pct"],
                "shape_error_mm": ev["shape_error_mm"],
                "floor_heldout_E_sil_pct": floor["silhouette_error_pct"],
                "result": path,
            }
            rows.append(r)
            print(
                f"{name:30s} {model:7s} {n:2d} cams: held-out E_sil {r['heldout_E_sil_pct']:6.2f} % "
                f"(floor {r['floor_heldout_E_sil_pct']:.2f} %), shape {r['shape_error_mm']:7.3f} mm, "
                f"{job.evaluations} evals, {wall:.0f} s",
                flush=True,
            )
            with open(path_json, "w") as f:
                json.dump(rows, f, indent=1)
    return rows


# --------------------------------------------------------------------------- replay (bpy)


def replay(out):
    import bpy
    from clothfit.blender import cloth as BC
    from clothfit.core.observation.capture import load_capture
    from clothfit.core.observation.metrics import shape_error_mm
    from clothfit.core.physics.models import model_and_row

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    path = os.path.join(out, "cross_simulator.json")
    with open(path) as f:
        rows = json.load(f)
    for r in rows:
        if r["model"] != "blender":
            continue
        with open(r["result"]) as f:
            res = json.load(f)
        model, row = model_and_row(res)
        cap = load_capture(os.path.join(out, "captures", slug(r["material"])))
        X = BC.replay(scene, cap.scenario, model.settings(row), model.fps)
        core = model.simulate(cap.scenario, row[None]).positions[0]
        odd = np.arange(0, cap.frame_times.size, 2)
        r["blender_replay_shape_error_mm"] = float(shape_error_mm(X[odd], cap.shapes[odd]).mean())
        r["blender_replay_vs_core_max_mm"] = float(np.linalg.norm(X - core, axis=-1).max() * 1000)
        print(
            f"{r['material']:30s} {r['train_cameras']:2d} cams: Blender's replay of the exported settings: "
            f"shape error {r['blender_replay_shape_error_mm']:.3f} mm (core {r['shape_error_mm']:.3f} mm; "
            f"Blender vs core max {r['blender_replay_vs_core_max_mm']:.4f} mm)",
            flush=True,
        )
    with open(path, "w") as f:
        json.dump(rows, f, indent=1)


def format_table(rows) -> str:
    """The Markdown table of the rows of cross_simulator.json (docs/results.md, its cross-simulator section)."""
    out = [
        "| material | model | train cams | held-out E_sil % (floor) | shape error mm | Blender replay mm | evals | s |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        rep = r.get("blender_replay_shape_error_mm")
        out.append(
            f"| {r['material']} | {r['model']} | {r['train_cameras']} | {r['heldout_E_sil_pct']:.2f} "
            f"({r['floor_heldout_E_sil_pct']:.2f}) | {r['shape_error_mm']:.3f} | "
            f"{'-' if rep is None else f'{rep:.3f}'} | {r['evaluations']} | {r['wall_s']:.0f} |"
        )
    return "\n".join(out)


def table(out):
    with open(os.path.join(out, "cross_simulator.json")) as f:
        print(format_table(json.load(f)))


def _mats(spec):
    return [x.strip() for x in spec.split(",") if x.strip()] if spec else None


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("step", choices=["observe", "fit", "replay", "table", "all"])
    ap.add_argument("--out", default="out/cross")
    ap.add_argument("--cameras", default="1,2,4,8", help="training-camera counts of the blender model")
    ap.add_argument("--paper-cameras", default="4", help="training-camera counts of the paper model")
    ap.add_argument("--budget", type=int, default=3000, help="evaluations per fit")
    ap.add_argument("--materials", default=None, help="fit only these (cotton,silk,denim); other rows are kept")
    a = ap.parse_args(argv)
    cams = [int(x) for x in a.cameras.split(",") if x]
    pcams = [int(x) for x in a.paper_cameras.split(",") if x]
    me = os.path.abspath(__file__)
    if a.step == "observe":
        observe(a.out)
    elif a.step == "fit":
        fit(a.out, cams, a.budget, pcams, _mats(a.materials))
    elif a.step == "replay":
        replay(a.out)
    elif a.step == "table":
        table(a.out)
    else:  # bpy only in the children
        for step in ("observe",):
            subprocess.run([sys.executable, me, step, "--out", a.out], check=True)
        fit(a.out, cams, a.budget, pcams, _mats(a.materials))
        subprocess.run([sys.executable, me, "replay", "--out", a.out], check=True)
        table(a.out)


if __name__ == "__main__":
    main()
