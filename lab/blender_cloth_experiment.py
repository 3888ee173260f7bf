"""A cloth the model did not make: observations from Blender's own cloth simulator, fitted by ours.

Blender's cloth solver (implicit integration; structural, shear and angular bending springs on a
quad mesh; its own damping model) simulates the paper's manipulation, Blender renders the
silhouettes, and our mass-spring model is fitted to them with 4, 8 and 16 training cameras. The
score is what a real cloth would give: held-out silhouette error (cameras not used in training,
at the test times) and the shape error against Blender's true vertex positions.

The set-up, step by step:

1. **Mesh**: the 10 cm, 16 x 16 grid of ``ClothGrid`` (same vertex order and positions, z = 0.1 m)
   as 225 quads (Blender's cloth builds structural springs on the edges, shear springs on the
   quads' diagonals and angular bending springs across edges).
2. **Pins and release**: vertex group ``pin`` = the four corners (weight 1); group ``release`` =
   the released corner. A *Vertex Weight Mix* modifier before the cloth modifier subtracts
   ``release`` from ``pin`` with an animated global influence that jumps from 0 to 1 between the
   last settling frame and t = 0. Blender's cloth re-reads the pin weights every frame ("dynamic
   vertex groups"), so the corner is held during settling and free from t = 0 on (checked: the
   three other corners stay put to 1e-6 m, the released one falls).
3. **Time**: Blender's cloth integrates in its own time unit, one frame, with gravity scaled by
   1/1000 (measured here: a free-falling sheet accelerates 9.81e-3 m/frame^2 at any scene frame
   rate), i.e. one solver time unit is ``TAU = sqrt(0.001) s = 31.6 ms`` of physical time.
   ``time_scale`` is set so that one frame is ``FRAME_DT = 0.01 s`` (``time_scale = FRAME_DT /
   TAU``); the capture times 0.05 ... 1.50 s are then whole frames after the release frame.
   Stiffness and damping are given here in physical units and converted (``k/m`` scales with
   ``TAU^2``, ``d/m`` with ``TAU``).
4. **Settling**: ``SETTLE`` s with the four corners held and strong air damping (the damping is
   keyframed down to the experiment's value at the release frame).
5. **Bake**: the frames are stepped in order (Blender's point cache holds the simulation), the
   evaluated vertex positions at the capture times go to ``shapes.npz``.
6. **Silhouettes**: Workbench, flat, anti-aliasing off (``clothfit.blender.render.render_masks``)
   through the ``lab18`` rig at the paper's 30 capture times: a capture in our format.
7. **Fit**: ``FitJob`` with the paper's training times (0.10 ... 1.50) and the first 4, 8, 16
   cameras of the spread order; scored on the held-out cameras at the test times (0.05 ... 1.45)
   with ``evaluate``; overlays of the held-out cameras.

Commands::

    python lab/blender_cloth_experiment.py observe --out out/blendercloth/capture
    python lab/blender_cloth_experiment.py fit --capture out/blendercloth/capture --cameras 4,8,16 \\
        --json out/blendercloth/fit.json --overlays out/blendercloth/overlays

Runs under ``python`` with the ``bpy`` module, or ``blender -b --factory-startup -P <this> -- ...``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)

from clothfit.blender.pipeline import script_argv  # noqa: E402  (no bpy import)
from clothfit.core import defaults as D  # noqa: E402
from clothfit.core.errors import ClothFitError  # noqa: E402
from clothfit.core.physics.scenario import ClothGrid, paper_scenario  # noqa: E402

TAU = math.sqrt(0.001)  # s of physical time per Blender cloth time unit (gravity is scaled by 1/1000)
FRAME_DT = 0.01  # s per frame
SETTLE = 1.0  # s of settling with the four corners held
SETTLE_AIR = 60.0  # Blender air damping while settling

# The Blender cloth, in physical units (per vertex mass, spring stiffness per unit mass, damping
# per unit mass). Chosen to be a soft, light fabric of the same scale as the paper's synthetic
# cloth; converted into Blender's settings by ``blender_settings``.
CLOTH = {
    "mass": 0.3,  # kg per vertex in Blender (only ratios matter: k/m, d/m)
    "tension_k_over_m": 1.0e6,  # 1/s^2: structural springs (tension = compression)
    "shear_k_over_m": 0.3e6,  # 1/s^2: shear springs (quad diagonals)
    "bending": 0.005,  # Blender's angular bending stiffness (its own units)
    "air_d_over_m": 4.0,  # 1/s: air drag per unit mass (viscous)
    "spring_damping": 0.5,  # Blender's tension/shear/bending damping
    "quality": 10,  # solver steps per frame
}


def blender_settings(grid: ClothGrid, cloth=None) -> dict:
    """Blender ClothSettings values for ``cloth`` (physical units) on ``grid``."""
    c = dict(CLOTH, **(cloth or {}))
    m = c["mass"]
    L = grid.spacing  # Blender divides the stiffness by the average spring length
    # Blender: spring k = stiffness / avg_spring_len in (N per frame-time-unit^2); k/m in 1/TAU^2
    tension = c["tension_k_over_m"] * TAU**2 * m * L
    shear = c["shear_k_over_m"] * TAU**2 * m * L
    # Blender's air drag force per vertex is 0.01 * air_damping * v (in its time unit)
    air = c["air_d_over_m"] * TAU * m / 0.01
    return {
        "mass": m,
        "tension_stiffness": tension,
        "compression_stiffness": tension,
        "shear_stiffness": shear,
        "bending_stiffness": c["bending"],
        "air_damping": air,
        "tension_damping": c["spring_damping"],
        "compression_damping": c["spring_damping"],
        "shear_damping": c["spring_damping"],
        "bending_damping": c["spring_damping"],
        "quality": int(c["quality"]),
        "time_scale": FRAME_DT / TAU,
    }


def frame_numbers(times):
    """(frame of t = 0, frame of each capture time): frame 1 starts the settling."""
    release_frame = 1 + int(round(SETTLE / FRAME_DT))
    frames = [release_frame + int(round(t / FRAME_DT)) for t in times]
    if any(abs((f - release_frame) * FRAME_DT - t) > 1e-9 for f, t in zip(frames, times)):
        raise ClothFitError(f"capture times {list(times)} are not multiples of {FRAME_DT} s")
    return release_frame, frames


def build(grid: ClothGrid, times, cloth=None, released_corner=D.RELEASED_CORNER):
    """A factory-empty scene with the pinned cloth; returns (scene, object, frame of each time)."""
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    n, ny = grid.nx, grid.ny
    quads = [
        [i * n + j, i * n + j + 1, (i + 1) * n + j + 1, (i + 1) * n + j] for i in range(ny - 1) for j in range(n - 1)
    ]
    me = bpy.data.meshes.new("Blender Cloth")
    me.from_pydata(grid.rest.tolist(), [], quads)
    me.update()
    ob = bpy.data.objects.new("Blender Cloth", me)
    scene.collection.objects.link(ob)
    corners = grid.corners()
    pin = ob.vertex_groups.new(name="pin")
    pin.add(corners, 1.0, "REPLACE")
    rel = ob.vertex_groups.new(name="release")
    rel.add([corners[released_corner]], 1.0, "REPLACE")
    release_frame, frames = frame_numbers(times)
    scene.render.fps, scene.render.fps_base = int(round(1 / FRAME_DT)), 1.0
    scene.frame_start, scene.frame_end = 1, frames[-1]
    mix = ob.modifiers.new("release corner", "VERTEX_WEIGHT_MIX")
    mix.vertex_group_a, mix.vertex_group_b = "pin", "release"
    mix.mix_mode, mix.mix_set = "SUB", "ALL"
    mix.mask_constant = 0.0
    mix.keyframe_insert("mask_constant", frame=release_frame - 1)
    mix.mask_constant = 1.0
    mix.keyframe_insert("mask_constant", frame=release_frame)
    _constant_keys(ob)
    cl = ob.modifiers.new("cloth", "CLOTH")
    s = cl.settings
    bs = blender_settings(grid, cloth)
    for k, v in bs.items():
        setattr(s, k, v)
    s.vertex_group_mass = "pin"
    s.pin_stiffness = 1.0
    s.use_pressure = False
    s.use_internal_springs = False
    s.bending_model = "ANGULAR"
    s.effector_weights.gravity = 1.0
    cl.collision_settings.use_collision = False
    cl.collision_settings.use_self_collision = False
    # strong damping while settling, the experiment's from t = 0 on
    s.air_damping = SETTLE_AIR
    s.keyframe_insert("air_damping", frame=release_frame - 1)
    s.air_damping = bs["air_damping"]
    s.keyframe_insert("air_damping", frame=release_frame)
    _constant_keys(ob)
    cl.point_cache.frame_start, cl.point_cache.frame_end = 1, frames[-1]
    return scene, ob, frames, release_frame


def _constant_keys(ob):
    ad = ob.animation_data
    if ad is None or ad.action is None:
        return
    act = ad.action
    fcs = list(getattr(act, "fcurves", []) or [])
    if not fcs:
        for layer in getattr(act, "layers", []):
            for strip in layer.strips:
                for cb in getattr(strip, "channelbags", []):
                    fcs.extend(cb.fcurves)
    for fc in fcs:
        for kp in fc.keyframe_points:
            kp.interpolation = "CONSTANT"


def evaluated_positions(ob):
    import bpy

    dg = bpy.context.evaluated_depsgraph_get()
    ev = ob.evaluated_get(dg)
    m = ev.to_mesh()
    try:
        co = np.empty(len(m.vertices) * 3, np.float32)
        m.vertices.foreach_get("co", co)
    finally:
        ev.to_mesh_clear()
    M = np.array(ob.matrix_world)
    return co.reshape(-1, 3).astype(np.float64) @ M[:3, :3].T + M[:3, 3]


def simulate_blender(grid: ClothGrid, times, cloth=None):
    """Step Blender's cloth through settling and the capture times. Returns (scene, object,
    positions (F, V, 3) at ``times``, positions at t = 0, seconds)."""
    import bpy

    scene, ob, frames, release_frame = build(grid, times, cloth)
    want = {f: i for i, f in enumerate(frames)}
    out = np.zeros((len(frames), grid.n_vertices, 3))
    t0 = time.time()
    X0 = None
    for f in range(1, frames[-1] + 1):
        scene.frame_set(f)
        if f == release_frame:
            X0 = evaluated_positions(ob)
        if f in want:
            out[want[f]] = evaluated_positions(ob)
    secs = time.time() - t0
    if not np.all(np.isfinite(out)):
        raise ClothFitError("Blender's cloth simulation produced non-finite positions")
    bpy.context.view_layer.update()
    return scene, ob, out, X0, secs


def observe(out_dir, rig=D.DEFAULT_RIG, times=None, cloth=None, resolution=None):
    """Simulate with Blender's cloth, render the rig's silhouettes with Workbench, write a capture."""
    import bpy
    from clothfit.blender.render import render_masks
    from clothfit.blender.scene import build_rig
    from clothfit.core.observation.camera import load_rig
    from clothfit.core.observation.capture import write_capture

    times = list(D.FRAME_TIMES if times is None else times)
    grid = ClothGrid()
    scen = paper_scenario(grid, frame_times=times)
    scene, ob, X, X0, sim_secs = simulate_blender(grid, times, cloth)
    corners = grid.corners()
    held = [c for k, c in enumerate(corners) if k != D.RELEASED_CORNER]
    drift = float(np.abs(X[:, held] - grid.rest[held]).max())
    fall = float(np.linalg.norm(X[-1, corners[D.RELEASED_CORNER]] - grid.rest[corners[D.RELEASED_CORNER]]))
    if drift > 1e-4 or fall < 0.01:
        raise ClothFitError(
            f"Blender cloth: pinning failed (held corners drift {drift:.2e} m, released corner moved {fall:.3f} m)"
        )
    cams = load_rig(rig)
    if resolution:
        cams = [c.resized(int(resolution[0]), int(resolution[1])) for c in cams]
    cam_objs = build_rig(scene, cams)
    t0 = time.time()
    sils = [[None] * len(times) for _ in cams]
    _, frames = frame_numbers(times)
    for fi, f in enumerate(frames):
        scene.frame_set(f)
        masks = render_masks(scene, ob, cam_objs)
        for ci, m in enumerate(masks):
            if not m.any():
                raise ClothFitError(f"camera '{cams[ci].name}' does not see Blender's cloth at t = {times[fi]:.2f} s")
            sils[ci][fi] = m
    render_secs = time.time() - t0
    bs = blender_settings(grid, cloth)
    meta = {
        "generator": "lab/blender_cloth_experiment.py (Blender cloth solver, Workbench silhouettes)",
        "blender": bpy.app.version_string,
        "cloth_physical": dict(CLOTH, **(cloth or {})),
        "blender_settings": bs,
        "tau_s": TAU,
        "frame_dt_s": FRAME_DT,
        "settle_s": SETTLE,
        "held_corner_drift_m": drift,
        "sim_seconds": sim_secs,
        "render_seconds": render_secs,
        "rest_shape_t0": X0.tolist() if X0 is not None else None,
        "rig": rig,
    }
    cap = write_capture(out_dir, cams, scen, sils, shapes=X, cloth_mass=None, meta=meta)
    print(
        f"[observe] Blender cloth: {sim_secs:.1f} s simulation, {render_secs:.1f} s for {len(cams) * len(times)} "
        f"Workbench silhouettes; held corners drift {drift:.1e} m; wrote {out_dir}",
        flush=True,
    )
    return cap


def check_units(frames=10):
    """Measure Blender's cloth time unit: a free (unpinned) sheet falls under our settings; returns
    the acceleration in m/s^2 with one frame = FRAME_DT (9.81 when the conversion is right)."""
    import bpy

    grid = ClothGrid()
    scene, ob, _, _ = build(grid, [FRAME_DT * frames])
    ob.vertex_groups.remove(ob.vertex_groups["pin"])
    ob.vertex_groups.new(name="pin")  # nothing pinned
    cl = ob.modifiers["cloth"].settings
    ob.animation_data_clear()  # the keyed air damping and pin release
    cl.air_damping = 0.0
    zs = []
    for f in range(1, frames + 2):
        scene.frame_set(f)
        zs.append(evaluated_positions(ob)[:, 2].mean())
    c = np.polyfit(np.arange(len(zs)) * FRAME_DT, np.array(zs), 2)
    bpy.context.view_layer.update()
    return -2.0 * c[0]


# =============================================================================== fit


def shape_oracle(cap, times=None, evals=600, seed=0):
    """The best our model can do against the true shapes: CMA-ES on the mean vertex distance at
    ``times`` (default: the test times) over k/m, d/m, l (log scale). A reference for the shape
    error a silhouette fit could reach at best, not a method (it needs the 3D truth)."""
    import cma
    from clothfit.core.observation.metrics import shape_error_mm
    from clothfit.core.physics.models import simulate

    times = list(D.TEST_TIMES if times is None else times)
    fidx = [cap.frame_index(t) for t in times]
    sc = cap.scenario.with_frames([float(cap.frame_times[i]) for i in fidx])
    true = cap.shapes[fidx]
    m = D.GT_PARAMS["m"]
    L = cap.scenario.grid.spacing
    x0 = np.log([5e5, 5.0, 0.95])

    def params(x):
        km, dm, lr = np.exp(x)
        return [m, km * m, lr * L, dm * m]

    es = cma.CMAEvolutionStrategy(x0, 0.5, {"seed": seed + 1, "maxfevals": evals, "verbose": -9})
    while not es.stop():
        X = es.ask()
        sim = simulate(sc, [params(x) for x in X])
        f = [
            float(np.mean(shape_error_mm(sim.positions[i], true))) if not sim.exploded[i] else 1e9
            for i in range(len(X))
        ]
        es.tell(X, f)
    best = params(es.result.xbest)
    return {
        "shape_error_mm": float(es.result.fbest),
        "params": dict(zip(("m", "k", "l", "d"), best)),
        "evaluations": int(es.result.evaluations),
    }


def fit(
    capture_dir, n_cams=(4, 8, 16), evals=D.FIT_EVALUATIONS, seed=0, optimizer="spx-mgg", overlays=None, resolution=None
):
    from clothfit.core.fitting.evaluate import evaluate
    from clothfit.core.fitting.job import FitConfig, FitJob
    from clothfit.core.observation.camera import select_training
    from clothfit.core.observation.capture import load_capture
    from clothfit.core.observation.overlay import capture_overlays
    from clothfit.core.physics.paper import identifiable

    cap = load_capture(capture_dir)
    rows = []
    for n in n_cams:
        train, held = select_training(cap.cameras, n)
        t0 = time.time()
        job = FitJob(
            cap,
            FitConfig(
                train_cameras=train,
                train_times=D.TRAIN_TIMES,
                optimizer=optimizer,
                seed=seed,
                max_evaluations=evals,
                resolution=resolution,
            ),
        )
        res = job.run()
        ev = evaluate(cap, res["params"], cameras=held, times=D.TEST_TIMES)
        ev_train = evaluate(cap, res["params"], cameras=train, times=D.TEST_TIMES)
        row = {
            "cameras": n,
            "heldout_sil_err_pct": ev["silhouette_error_pct"],
            "shape_error_mm": ev["shape_error_mm"],
            "shape_error_mm_per_time": ev["shape_error_mm_per_time"],
            "train_cams_test_times_sil_err_pct": ev_train["silhouette_error_pct"],
            "train_E_sil_pct": res["best_E_sil_mean_pct"],
            "params": res["params"],
            "identifiable": identifiable(res["params"]),
            "mass_source": res["mass_source"],
            "evaluations": res["evaluations"],
            "seconds": time.time() - t0,
            "train": [cap.cameras[c].name for c in train],
            "heldout": [cap.cameras[c].name for c in held],
            "heldout_sil_err_pct_per_time": ev["silhouette_error_pct_per_time"],
        }
        rows.append(row)
        print(
            f"[fit] {n:2d} cameras: held-out E_sil {row['heldout_sil_err_pct']:.2f} %, shape error "
            f"{row['shape_error_mm']:.2f} mm, train E_sil {row['train_E_sil_pct']:.2f} %, "
            f"k/m {row['identifiable']['k_over_m']:.3g} 1/s^2, d/m {row['identifiable']['d_over_m']:.3g} 1/s, "
            f"l {1000 * row['identifiable']['l']:.3f} mm ({row['seconds']:.0f} s)",
            flush=True,
        )
        if overlays:
            capture_overlays(
                cap, res["params"], os.path.join(overlays, f"{n:02d}cams"), cameras=held[:6], times=D.TEST_TIMES[::3]
            )
    return rows


def format_rows(rows):
    lines = [
        "| training cameras | held-out silhouette error [%] | shape error [mm] | train E_sil [%] | "
        "k/m [1/s^2] | d/m [1/s] | l [mm] |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        i = r["identifiable"]
        lines.append(
            f"| {r['cameras']} | {r['heldout_sil_err_pct']:.2f} | {r['shape_error_mm']:.2f} | "
            f"{r['train_E_sil_pct']:.2f} | {i['k_over_m']:.3g} | {i['d_over_m']:.3g} | {1000 * i['l']:.3f} |"
        )
    return "\n".join(lines)


# ============================================================================== main


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    o = sub.add_parser("observe", help="simulate with Blender's cloth and render silhouettes (a capture)")
    o.add_argument("--out", required=True)
    o.add_argument("--rig", default=D.DEFAULT_RIG)
    o.add_argument("--resolution", help="HxW (default: the rig's)")
    c = sub.add_parser("check-units", help="measure gravity in Blender's cloth with our time conversion")
    c.add_argument("--json", help="also write the measured acceleration to this file")
    f = sub.add_parser("fit", help="fit our model, score held-out cameras at the test times")
    f.add_argument("--capture", required=True)
    f.add_argument("--cameras", default="4,8,16")
    f.add_argument("--evals", type=int, default=D.FIT_EVALUATIONS)
    f.add_argument("--seed", type=int, default=0)
    f.add_argument("--optimizer", default="spx-mgg")
    f.add_argument("--resolution", help="HxW to fit at (default: the capture's)")
    f.add_argument("--json")
    f.add_argument("--overlays", help="folder for overlays of the held-out cameras")
    f.add_argument(
        "--oracle",
        action="store_true",
        help="also report the best shape error our model can reach (fitted on the 3D truth)",
    )
    a = ap.parse_args(script_argv(argv))
    try:
        if a.cmd == "check-units":
            g = check_units()
            print(f"free fall in Blender's cloth with one frame = {FRAME_DT} s: {g:.3f} m/s^2 (expected 9.81)")
            if a.json:
                os.makedirs(os.path.dirname(os.path.abspath(a.json)), exist_ok=True)
                with open(a.json, "w") as fh:
                    json.dump({"frame_dt_s": FRAME_DT, "free_fall_m_s2": g}, fh, indent=1)
        elif a.cmd == "observe":
            res = [int(v) for v in a.resolution.lower().split("x")] if a.resolution else None
            observe(a.out, a.rig, resolution=res)
        else:
            res = [int(v) for v in a.resolution.lower().split("x")] if a.resolution else None
            rows = fit(a.capture, [int(v) for v in a.cameras.split(",")], a.evals, a.seed, a.optimizer, a.overlays, res)
            print(format_rows(rows))
            if a.oracle:
                from clothfit.core.fitting.evaluate import evaluate
                from clothfit.core.observation.capture import load_capture

                orc = shape_oracle(load_capture(a.capture))
                ev = evaluate(load_capture(a.capture), orc["params"], times=D.TEST_TIMES)
                orc["all_cameras_sil_err_pct"] = ev["silhouette_error_pct"]
                print(
                    f"oracle (our model fitted to the true 3D shapes at the test times): shape error "
                    f"{orc['shape_error_mm']:.2f} mm, silhouette error on all cameras {ev['silhouette_error_pct']:.2f} %"
                )
                rows.append({"oracle": orc})
            if a.json:
                os.makedirs(os.path.dirname(os.path.abspath(a.json)), exist_ok=True)
                with open(a.json, "w") as fh:
                    json.dump(rows, fh, indent=1)
    except ClothFitError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
