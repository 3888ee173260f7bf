"""The goal of the ``--backend blender`` fit: a cloth hung and released onto a collider (no core model emulates it), fitted with
Blender's own solver (``fit --backend blender``) in at most 600 evaluations, and Blender replaying
the result within 1 mm of the observed motion.

1. ``build`` (bpy, child process): ``addon/blender/collider_scene.py`` writes the .blend (a 9 x 9,
   10 cm cloth with Blender's *default* settings at the real-time time scale, hung by its corners,
   released at t = 0 onto a 6 cm box 3 cm below) and observes it with Blender at the true settings
   (``collider_scene.TRUTH``): a capture from the ``ring8`` rig (8 cameras), every other frame for
   0.5 s after the release, the true vertices in ``shapes.npz``.
2. ``fit`` (no bpy): ``python -m clothfit fit CAPTURE --backend blender --blend SCENE --frame-zero N``
   (Ray, ``--workers``), CMA-ES from the scene's values, ``--budget`` evaluations.
3. ``replay`` (bpy, child process): the result's ``blender_cloth`` on the scene's Cloth modifier,
   simulated by Blender at every capture time; distance to the true vertices [mm]; and the floor:
   the true settings with one setting 1 % off, replayed the same way.

    python lab/blender_scene_fit.py all --out out/scene_fit [--budget 600] [--workers 2]
        [--resolution 240x320] [--population 8] [--seed 0] [--init RESULT.json]

The warm start (``--release corner``: only one corner let go, so the cloth first swings free about
the other three, as in the paper, and strikes the box later; ``--drop 0.05`` puts the box's top
5 cm below the cloth, where the swinging corner reaches it):

4. ``warm`` (no bpy): the core's blender model (which has no colliders) fitted on the capture times
   before the cloth reaches the box, the contact time predicted by that model at the scene's
   starting settings (5 mm margin; the truth is not used); its result is ``--init`` for ``fit``.
   ``all --warm`` runs build, warm, fit from the warm start, replay.

    python lab/blender_scene_fit.py all --out out/scene_warm --release corner --drop 0.05 --after 0.75 --warm
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)


BOX = 0.06  # the box collider's side [m]; centred under the cloth
MARGIN = 0.005  # warm start: capture times while the predicted cloth stays this far above the box


def _paths(out):
    return {
        "blend": os.path.join(out, "drop.blend"),
        "capture": os.path.join(out, "capture"),
        "fit": os.path.join(out, "fit.json"),
        "replay": os.path.join(out, "replay.json"),
        "meta": os.path.join(out, "scene.json"),
        "warm": os.path.join(out, "warm.json"),
    }


def free_times(cap, drop, box, fps=24.0):
    """Capture times before the cloth comes within ``MARGIN`` of the box (top ``drop`` below the
    cloth, ``box`` wide, centred), as the core blender model predicts at Blender's default settings
    with the real-time time scale (the scene's starting settings; no collider in the core model)."""
    import numpy as np
    from clothfit.core.physics import blender as B
    from clothfit.core.physics.models import BlenderModel

    model = BlenderModel(fps)
    s = dict(B.DEFAULTS, time_scale=B.physical_time_scale(fps))
    sc = cap.scenario
    X = model.simulate(sc, B.settings_row(s)[None]).positions[0]  # (F, V, 3)
    top = sc.grid.height - drop
    inside = (np.abs(X[..., 0]) < box / 2 + MARGIN) & (np.abs(X[..., 1]) < box / 2 + MARGIN)
    near = (inside & (X[..., 2] < top + MARGIN)).any(axis=1)
    k = int(np.argmax(near)) if near.any() else len(near)
    return [float(t) for t in sc.frame_times[:k]]


def warm(a):
    from clothfit.core.observation.capture import load_capture

    P = _paths(a.out)
    with open(P["meta"]) as f:
        meta = json.load(f)
    cap = load_capture(P["capture"])
    times = free_times(cap, meta.get("drop", 0.03), meta.get("box", BOX))
    if len(times) < 2:
        raise SystemExit(
            f"warm start: only {len(times)} capture time(s) before the cloth reaches the box; "
            f"use --release corner and a deeper --drop"
        )
    cmd = [
        sys.executable,
        "-m",
        "clothfit",
        "fit",
        P["capture"],
        "--model",
        "blender",
        "--fps",
        "24",
        "--times",
        ",".join(f"{t:.9g}" for t in times),
        "--max-evaluations",
        str(a.warm_budget),
        "--seed",
        str(a.seed),
        "--out",
        P["warm"],
        "--force",
        "--quiet",
    ]
    t0 = time.time()
    subprocess.run(cmd, check=True, cwd=ROOT)
    with open(P["warm"]) as f:
        res = json.load(f)
    with open(os.path.join(a.out, "warm_summary.json"), "w") as f:
        json.dump(
            {
                "times": len(times),
                "t_last": times[-1],
                "evaluations": res.get("evaluations"),
                "train_E_sil_pct": res.get("best_E_sil_mean_pct"),
                "seconds": time.time() - t0,
                "blender_cloth": res.get("blender_cloth"),
            },
            f,
            indent=1,
        )
    print(
        f"warm start: the core blender model on the {len(times)} capture times before contact "
        f"(t <= {times[-1]:.3f} s), {res.get('evaluations')} evaluations in {time.time() - t0:.1f} s, "
        f"training E_sil {res.get('best_E_sil_mean_pct'):.3f} % -> {P['warm']}"
    )
    return P["warm"]


def build(a):
    from clothfit.blender import collider_scene as CS

    P = _paths(a.out)
    h, w = (int(x) for x in a.resolution.split("x"))
    sc = CS.collider_scenario(a.grid, settle=0.25, after=a.after, every=a.every, release=a.release)
    f0 = CS.build_scene(P["blend"], sc, drop=a.drop, box=BOX)
    CS.observe(P["blend"], sc, P["capture"], frame_zero=f0, resolution=(h, w))
    with open(P["meta"], "w") as f:
        json.dump(
            {"frame_zero": f0, "grid": a.grid, "resolution": [h, w], "release": a.release, "drop": a.drop, "box": BOX},
            f,
        )
    print(f"wrote {P['blend']} (t = 0 at frame {f0}) and {P['capture']}")


def replay(a):
    import numpy as np
    from clothfit.blender.scene_worker import BlendScene
    from clothfit.core.jsonio import read_json

    P = _paths(a.out)
    res = read_json(a.result or P["fit"], "fit result")
    meta = read_json(P["meta"], "scene meta")
    cap = read_json(os.path.join(P["capture"], "capture.json"), "capture")
    obs = np.load(os.path.join(P["capture"], "shapes.npz"))["positions"]
    bs = BlendScene(P["blend"])
    info = bs.info()
    frames = meta["frame_zero"] + np.asarray(cap["scenario"]["frame_times"]) * info["fps"]
    start = bs.simulate(info["settings"], frames)["positions"]
    fit = bs.simulate(res["blender_cloth"], frames)["positions"]
    d = np.linalg.norm(fit - obs, axis=-1) * 1000
    d0 = np.linalg.norm(start - obs, axis=-1) * 1000
    out = {
        "mean_mm": float(d.mean()),
        "max_mm": float(d.max()),
        "per_frame_max_mm": d.max(1).tolist(),
        "start_mean_mm": float(d0.mean()),
        "start_max_mm": float(d0.max()),
        "evaluations": res.get("evaluations"),
        "best_E_sil_mean_pct": res.get("best_E_sil_mean_pct"),
    }
    if os.path.isfile(P["warm"]) and a.result is None:  # the warm start on its own, replayed by Blender
        wres = read_json(P["warm"], "warm-start result")
        y = bs.simulate(
            dict(info["settings"], **{k: v for k, v in wres["blender_cloth"].items() if k in info["settings"]}), frames
        )["positions"]
        dw = np.linalg.norm(y - obs, axis=-1) * 1000
        out["warm_start_mean_mm"], out["warm_start_max_mm"] = float(dw.mean()), float(dw.max())
        print(f"the core model's warm start replayed by Blender: mean {dw.mean():.2f} mm, max {dw.max():.2f} mm")
    # the floor: the true settings with one of them 1 % off, replayed by Blender (contact is chaotic)
    truth = cap["meta"]["true_blender_cloth"]
    floor = {}
    for k in (
        "tension_stiffness",
        "compression_stiffness",
        "shear_stiffness",
        "bending_stiffness",
        "tension_damping",
        "air_damping",
    ):
        y = bs.simulate(dict(truth, **{k: truth[k] * 1.01}), frames)["positions"]
        dd = np.linalg.norm(y - obs, axis=-1) * 1000
        floor[k] = [float(dd.mean()), float(dd.max())]
    out["one_setting_1pct_off_mm"] = floor
    print(
        "the truth with one setting 1 % off: "
        + ", ".join(f"{k} {v[0]:.2f} / {v[1]:.2f} mm" for k, v in floor.items())
        + " (mean / max)"
    )
    with open(P["replay"], "w") as f:
        json.dump(out, f, indent=1)
    print(
        f"Blender replay of the fit vs the observed vertices: mean {out['mean_mm']:.4f} mm, max {out['max_mm']:.4f} mm "
        f"(the scene's starting settings: mean {out['start_mean_mm']:.2f} mm, max {out['start_max_mm']:.2f} mm)"
    )


def _child(cmd, a, extra=()):
    args = [sys.executable, os.path.abspath(__file__), cmd, "--out", a.out] + list(extra)
    subprocess.run(args, check=True, cwd=ROOT)


def main(argv=None):
    ap = argparse.ArgumentParser(prog="lab/blender_scene_fit.py")
    ap.add_argument("cmd", choices=["build", "warm", "fit", "replay", "all"])
    ap.add_argument("--out", default="out/scene_fit")
    ap.add_argument("--grid", type=int, default=9)
    ap.add_argument("--resolution", default="240x320")
    ap.add_argument("--budget", type=int, default=600)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--population", type=int, default=8)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--init", default=None)
    ap.add_argument("--result", default=None, help="replay: this result instead of OUT/fit.json")
    ap.add_argument("--release", default="all", choices=["all", "corner"], help="build: corners let go at t = 0")
    ap.add_argument("--drop", type=float, default=0.03, help="build: the box's top below the cloth [m]")
    ap.add_argument("--after", type=float, default=0.5, help="build: seconds observed after the release")
    ap.add_argument("--every", type=int, default=2, help="build: a capture time every N frames (24 fps)")
    ap.add_argument("--warm", action="store_true", help="all: fit from the core model's warm start")
    ap.add_argument("--warm-budget", type=int, default=1500, help="warm: core-model evaluations")
    a = ap.parse_args(argv)
    os.makedirs(a.out, exist_ok=True)
    if a.cmd == "build":
        return build(a)
    if a.cmd == "replay":
        return replay(a)
    if a.cmd == "warm":
        return warm(a)
    P = _paths(a.out)
    if a.cmd == "all":
        _child(
            "build",
            a,
            [
                "--grid",
                str(a.grid),
                "--resolution",
                a.resolution,
                "--release",
                a.release,
                "--drop",
                str(a.drop),
                "--after",
                str(a.after),
                "--every",
                str(a.every),
            ],
        )
        if a.warm:
            a.init = warm(a)
    with open(P["meta"]) as f:
        meta = json.load(f)
    cmd = [
        sys.executable,
        "-m",
        "clothfit",
        "fit",
        P["capture"],
        "--backend",
        "blender",
        "--blend",
        P["blend"],
        "--frame-zero",
        str(meta["frame_zero"]),
        "--workers",
        str(a.workers),
        "--max-evaluations",
        str(a.budget),
        "--population",
        str(a.population),
        "--seed",
        str(a.seed),
        "--out",
        P["fit"],
        "--quiet",
        "--force",
    ]
    if a.init:
        cmd += ["--init", a.init]
    t0 = time.time()
    subprocess.run(cmd, check=True, cwd=ROOT)
    wall = time.time() - t0
    print(f"fit: {wall:.1f} s wall (Ray start-up included)")
    if a.cmd == "all":
        _child("replay", a)
        with open(P["replay"]) as f:
            summary = {
                "fit_wall_s": wall,
                "workers": a.workers,
                "budget": a.budget,
                "population": a.population,
                "resolution": a.resolution,
                "grid": a.grid,
                "replay": json.load(f),
            }
        floor = summary["replay"]["one_setting_1pct_off_mm"].values()
        summary["one_setting_1pct_off_range_mm"] = {
            "mean": [min(v[0] for v in floor), max(v[0] for v in floor)],
            "max": [min(v[1] for v in floor), max(v[1] for v in floor)],
        }
        with open(P["fit"]) as f:
            summary["fit_blender_cloth"] = json.load(f)["blender_cloth"]
        with open(os.path.join(P["capture"], "capture.json")) as f:
            summary["true_blender_cloth"] = json.load(f)["meta"]["true_blender_cloth"]
        if a.init and a.warm:
            with open(os.path.join(a.out, "warm_summary.json")) as f:
                summary["warm"] = json.load(f)
        with open(os.path.join(a.out, "summary.json"), "w") as f:
            json.dump(summary, f, indent=1)


if __name__ == "__main__":
    sys.exit(main())
