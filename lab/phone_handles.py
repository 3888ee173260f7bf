"""Phone footage of a cloth hung by clips, one released: `clothfit handles` measured against the truth.

The scene (Blender Cycles, the room of ``lab/render_footage.py``): a printed cloth ``0.30 x 0.24 m``
hung in a vertical plane by four clips on its top edge (its corners and the thirds) under a rod; the
top-right clip lets go at a time drawn at random within a frame period, and the corner falls and
swings, the clip with it. The cloth is the core's paper model (bending-free sheet, continuous-time
release), placed where the clips are. Four "phones" around it at 0.7-0.8 m, 1280 x 720, 70 degree field
of view, each with its own barrel distortion and sensor noise, filming at 30 fps from 0.2 s before the
release. The seed draws the release phase, the phones' positions, the lens distortions, the sensor
noise and the user's clicks.

Then ``clothfit handles`` runs as a user would: the clips marked once at frame 0 in every phone (the
true projection of the clip's point plus 0.5 px of click noise), the cloth's measured size, the
calibration file. ``measure`` compares what it wrote with the truth: each clip's triangulated position
(mm), the release frame (the first frame after the true release instant), the release instant (in
frames), the cloth's placement.

    python lab/phone_handles.py all --out out/phone_handles --seed 7 --json out/phone_handles/result.json
    python lab/phone_handles.py render --out DIR [--seed S] [--cameras 4] [--resolution 720x1280]
    python lab/phone_handles.py measure --footage DIR --json OUT.json

Goals (the phone rig's): handles within 1 mm; the release frame exact. The render (about 90 Cycles images) takes
minutes on 2 cores; ``measure`` seconds.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "lab"))

from clothfit.core.observation.camera import Camera, intrinsics, look_at  # noqa: E402
from clothfit.core.physics.rotation import rotation_vector  # noqa: E402
from clothfit.core.physics.scenario import ClothGrid, Handle, Scenario  # noqa: E402

WIDTH, HEIGHT = 0.30, 0.24  # the cloth [m]
NX, NY = 16, 13  # 2 cm cells: the clips at u = 0, 0.1, 0.2, 0.3 sit on vertices
TOP = 0.42  # the clips' height [m]
CLIPS = {"left": 0.0, "third": 0.10, "two-thirds": 0.20, "right": 0.30}  # u of each clip on the top edge
RELEASED = "right"
FPS = 30.0
FRAMES = 18
BEFORE = 0.2  # s filmed before the release
CLICK_SIGMA = 0.5  # px: a person's click on a zoomed frame
PARAMS = {"m": 5.2e-5, "k": 10.0, "l": 0.02, "d": 5.2e-4}  # 150 g/m2 cotton on 2 cm cells, d/m = 10 /s


def truth(seed: int):
    """The manipulation, the cloth's motion and the phones of one seed (no bpy)."""
    from clothfit.core.physics.models import simulate
    from clothfit.core.physics.paper import Params

    rng = np.random.default_rng(seed)
    phase = float(rng.uniform(0.02, 0.98))
    t0 = 0.0
    t_release = t0 + BEFORE + phase / FPS
    times = t0 + np.arange(FRAMES) / FPS
    # the cloth in the plane y = 0, columns along +x, rows downward: rotation x -> x, y -> -z
    R = np.stack([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]], 1)  # columns: local x, y, z in the world
    origin = np.array([0.0, 0.0, TOP - HEIGHT / 2.0])
    grid = ClothGrid(NX, NY, WIDTH, side_y=HEIGHT, origin=origin, rotation=rotation_vector(R))
    handles, verts = [], {}
    for name, u in CLIPS.items():
        v = int(round(u / (WIDTH / (NX - 1))))
        verts[name] = v
        handles.append(Handle(v, [0.0], grid.rest[v][None], t_release if name == RELEASED else None))
    scen = Scenario(grid, handles, times, settle_time=1.0)
    X = simulate(scen, [Params.from_dict(PARAMS)]).positions[0]
    cams = []
    for i, az in enumerate(np.linspace(-55, 55, 4) + rng.uniform(-6, 6, 4)):
        a = math.radians(az - 90.0)
        dist = float(rng.uniform(0.7, 0.8))
        eye = np.array([dist * math.cos(a), dist * math.sin(a), TOP + float(rng.uniform(-0.05, 0.15))])
        Rc, tc = look_at(eye, [0.0, 0.0, TOP - 0.12])
        w, h = 1280, 720
        fx = (w / 2) / math.tan(math.radians(35.0))
        k1 = -0.10 + 0.04 * float(rng.uniform(-1, 1))
        distc = np.array([k1, 0.04 + 0.02 * float(rng.uniform(-1, 1)), *(0.001 * rng.uniform(-1, 1, 2)), 0.0])
        cams.append(Camera(intrinsics(fx, w, h), Rc, tc, w, h, f"phone{i}", distc))
    return {
        "scenario": scen,
        "positions": X,
        "times": times,
        "release_time": t_release,
        "phase": phase,
        "vertices": verts,
        "cameras": cams,
        "rng": rng,
    }


# ============================================================================ render (bpy)


def _clip_material():
    import bpy

    mat = bpy.data.materials.new("Clip")
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    bsdf = nodes["Principled BSDF"]
    bsdf.inputs["Roughness"].default_value = 0.35
    chk = nodes.new("ShaderNodeTexChecker")
    chk.inputs["Scale"].default_value = 3.0
    chk.inputs["Color1"].default_value = (0.02, 0.02, 0.025, 1)  # black plastic ...
    chk.inputs["Color2"].default_value = (0.75, 0.72, 0.2, 1)  # ... with yellow stripes
    tc = nodes.new("ShaderNodeTexCoord")
    links.new(tc.outputs["Generated"], chk.inputs["Vector"])
    links.new(chk.outputs["Color"], bsdf.inputs["Base Color"])
    return mat


def render(out, seed=0, samples=8, resolution=None):
    import bpy
    import cv2
    from clothfit.core.footage import calib_io
    from render_footage import (
        add_sensor_noise,
        build_scene,
        distort_image,
        distortion_maps,
        needed_margin,
        render_pinhole,
        set_cloth_shape,
    )

    tr = truth(seed)
    scen, X, cams, rng = tr["scenario"], tr["positions"], tr["cameras"], tr["rng"]
    if resolution:
        cams = [Camera(c.resized(*resolution).K, c.R, c.t, resolution[1], resolution[0], c.name, c.dist) for c in cams]
    grid = scen.grid
    os.makedirs(out, exist_ok=True)
    scene, cloth = build_scene(grid, "CYCLES", samples, True)
    # texture coordinates from the flat sheet (the room builder takes them from a horizontal rest shape)
    me = cloth.data
    uv = me.uv_layers["UVMap"]
    loc = grid.local
    u = (loc[:, 0] + WIDTH / 2) / WIDTH
    v = (loc[:, 1] + HEIGHT / 2) / HEIGHT
    loop_uv = np.stack([u, v], -1)[np.array([lp.vertex_index for lp in me.loops])]
    uv.data.foreach_set("uv", loop_uv.astype(np.float32).ravel())
    mat = _clip_material()
    clips = {}
    for name, vtx in tr["vertices"].items():
        bpy.ops.mesh.primitive_cube_add(size=1.0)
        ob = bpy.context.object
        ob.name = f"Clip {name}"
        ob.scale = (0.016, 0.010, 0.022)  # jaws 1.6 cm wide, 2.2 cm tall, over the cloth's edge
        ob.data.materials.append(mat)
        clips[name] = (ob, vtx)
    bpy.ops.mesh.primitive_cylinder_add(
        radius=0.004, depth=0.5, location=(0.0, 0.0, TOP + 0.03), rotation=(0.0, math.pi / 2, 0.0)
    )
    bpy.context.object.name = "Rod"
    cam_data = bpy.data.cameras.new("Phone")
    cam_data.sensor_fit = "HORIZONTAL"
    cam_data.sensor_width = 36.0
    cam_obj = bpy.data.objects.new("Phone", cam_data)
    scene.collection.objects.link(cam_obj)
    tmp = os.path.join(out, "_render")
    os.makedirs(tmp, exist_ok=True)
    calib_io.export_cameras(cams, os.path.join(out, "calibration.yml"), "opencv")
    secs = []
    for cam in cams:
        d = os.path.join(out, cam.name)
        os.makedirs(d, exist_ok=True)
        margin = needed_margin(cam)
        maps = distortion_maps(cam, margin)
        for f in range(len(tr["times"])):
            set_cloth_shape(cloth, X[f])
            for ob, vtx in clips.values():
                ob.location = tuple(float(x) for x in X[f, vtx] + [0.0, 0.0, 0.004])
            t0 = time.time()
            img = distort_image(render_pinhole(scene, cam_obj, cam, margin, os.path.join(tmp, "f.png")), maps)
            secs.append(time.time() - t0)
            cv2.imwrite(os.path.join(d, f"{f:03d}.png"), add_sensor_noise(img, rng))
        print(
            f"[render] {cam.name}: {len(tr['times'])} frames, {np.mean(secs[-len(tr['times']) :]):.1f} s each",
            flush=True,
        )
    marks = {"frame": 0, "handles": []}
    for name, vtx in tr["vertices"].items():
        h = {
            "name": name,
            "at": [CLIPS[name], 0.0],
            "marks": {c.name: (c.project(X[0, vtx]) + rng.normal(0, CLICK_SIGMA, 2)).tolist() for c in cams},
        }
        if name == RELEASED:
            h["released"] = True
        marks["handles"].append(h)
    with open(os.path.join(out, "marks.json"), "w") as f:
        json.dump(marks, f, indent=1)
    t = tr["times"]
    info = {
        "cameras": "calibration.yml",
        "frame_times": t.tolist(),
        "meta": {
            "generator": "lab/phone_handles.py",
            "seed": seed,
            "samples": samples,
            "seconds_per_render": float(np.mean(secs)),
            "truth": {
                "release_time": tr["release_time"],
                "phase": tr["phase"],
                "release_frame": int(np.searchsorted(t, tr["release_time"], side="right")),
                "vertices": tr["vertices"],
                "clip_positions": {n: X[:, v].tolist() for n, v in tr["vertices"].items()},
                "scenario": scen.to_dict(),
                "click_sigma_px": CLICK_SIGMA,
            },
        },
    }
    with open(os.path.join(out, "footage.json"), "w") as f:
        json.dump(info, f, indent=1)
    try:
        os.remove(os.path.join(tmp, "f.png"))
        os.rmdir(tmp)
    except OSError:
        pass
    return info


# ============================================================================ measure


def measure(footage, clip_size=0.02):
    """Run ``clothfit handles`` on the rendered footage; its errors against the truth."""
    from clothfit.cli import main as cli
    from clothfit.core.physics.scenario import Scenario

    with open(os.path.join(footage, "footage.json")) as f:
        info = json.load(f)
    tru = info["meta"]["truth"]
    out = os.path.join(footage, "scenario.json")
    t0 = time.time()
    code = cli(
        [
            "handles",
            footage,
            "--marks",
            os.path.join(footage, "marks.json"),
            "--size",
            f"{WIDTH}x{HEIGHT}",
            "--clip-size",
            str(clip_size),
            "-o",
            out,
            "--force",
        ]
    )
    secs = time.time() - t0
    if code != 0:
        raise SystemExit(f"clothfit handles failed (exit {code})")
    with open(out) as f:
        doc = json.load(f)
    sc = Scenario.from_dict(doc["scenario"])
    rep = doc["report"]
    times = np.asarray(info["frame_times"])
    period = float(np.median(np.diff(times)))
    rows = []
    for h, r in zip(sc.handles, rep["handles"]):
        true0 = np.asarray(tru["clip_positions"][r["name"]][0])
        row = {
            "name": r["name"],
            "error_mm": 1000.0 * float(np.linalg.norm(h.positions[0] - true0)),
            "residual_rms_px": r["residual_rms_px"],
            "residual_rms_mm": r["residual_rms_mm"],
            "sd_mm": r["sd_mm"],
            "bound_mm": r["uncertain_mm"],  # the triangulation's 3 sigma (the fit's box: fit_box_mm)
            "fit_box_mm": r.get("fit_box_mm"),
            "vertex": r["vertex"],
            "true_vertex": tru["vertices"][r["name"]],
            "track_frames": min(r["track_frames"].values()),
        }
        if r.get("released"):
            row.update(
                release_frame=r["release_frame"],
                true_release_frame=tru["release_frame"],
                release_time_error_frames=(r["release_time"] - tru["release_time"]) / period,
                departure_frame=r["departure_frame"],
            )
        rows.append(row)
    rel = [r for r in rows if "release_frame" in r][0]
    res = {
        "seed": info["meta"]["seed"],
        "handles": rows,
        "max_error_mm": max(r["error_mm"] for r in rows),
        "release_frame": rel["release_frame"],
        "true_release_frame": rel["true_release_frame"],
        "release_frame_exact": rel["release_frame"] == rel["true_release_frame"],
        "release_time_error_frames": rel["release_time_error_frames"],
        "release_phase": tru["phase"],
        "vertices_right": all(r["vertex"] == r["true_vertex"] for r in rows),
        "placement_rms_mm": rep["cloth"]["placement_rms_mm"],
        "uncertain": doc["uncertain"],
        "warnings": rep["warnings"],
        "handles_seconds": secs,
        "seconds_per_render": info["meta"]["seconds_per_render"],
    }
    res["goals"] = {"handles_within_1mm": res["max_error_mm"] <= 1.0, "release_frame_exact": res["release_frame_exact"]}
    return res


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    for name in ("render", "all"):
        s = sub.add_parser(name, help="render the footage" + (" and measure it" if name == "all" else ""))
        s.add_argument("--out", required=True, help="footage folder to write")
        s.add_argument("--seed", type=int, default=0, help="draws the release phase, phones, noise and clicks")
        s.add_argument("--samples", type=int, default=8, help="Cycles samples per pixel (denoised)")
        s.add_argument("--resolution", help="HxW of the phones' frames (default 720x1280)")
        if name == "all":
            s.add_argument("--json", required=True, help="write the measurement here")
    s = sub.add_parser("measure", help="run clothfit handles on rendered footage and compare with the truth")
    s.add_argument("--footage", required=True, help="a folder written by render")
    s.add_argument("--json", required=True, help="write the measurement here")
    a = ap.parse_args(argv)
    res = None
    if a.cmd in ("render", "all"):
        resolution = tuple(int(v) for v in a.resolution.lower().split("x")) if a.resolution else None
        if a.cmd == "all":  # bpy in a child process: the measurement runs without it
            cmd = [
                sys.executable,
                os.path.abspath(__file__),
                "render",
                "--out",
                a.out,
                "--seed",
                str(a.seed),
                "--samples",
                str(a.samples),
            ] + (["--resolution", a.resolution] if a.resolution else [])
            if subprocess.call(cmd) != 0:
                raise SystemExit("render failed")
        else:
            render(a.out, a.seed, a.samples, resolution)
            return 0
    res = measure(a.out if a.cmd == "all" else a.footage)
    print(json.dumps(res, indent=1))
    os.makedirs(os.path.dirname(os.path.abspath(a.json)), exist_ok=True)
    with open(a.json, "w") as f:
        json.dump(res, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
