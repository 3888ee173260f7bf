"""A phone rig, rendered: what users film with a few phones round a cloth, and how well we recover it.

Subcommands (recorded: docs/figures/phone_rig_calib_s101.json, phone_rig_e2e.json; docs/phone_rig.md)::

    python lab/phone_rig.py calibrate --out out/phone_rig/calib_s101 --seed 101 --scale 0.375 --poses 14 \
        --samples 4 --json out/phone_rig/calib_s101.json
    python lab/phone_rig.py e2e --out out/phone_rig/e2e_s7 --seed 7 --scale 0.3 --poses 10 --frames 15 \
        --samples 4 --evals 300 --uncertain-evals 600 --json out/phone_rig/e2e_s7.json

``e2e``: the phones in an arc before a cloth (0.30 x 0.24 m, 150 g/m2) hung by four clips from a rod, the
right one let go 1/5..4/5 of a frame after a frame; the board rendered first (flat, then held up), then
each phone's background plate and frames. The cloth is the core's Blender model (Blender's cloth) at
settings the pipeline is not told. Then, through the CLI as a user runs it on the images, the clicks
(true image points + 0.5 px), the size and the mass only: ``calibrate``, ``handles``, ``extract``,
``fit --model blender`` (3 free settings, ``--uncertain none``), ``export-blender-cloth``; and the same
fit on the same silhouettes given the true cameras and manipulation. Compared: the calibration, the clips
(mm; and what that error is made of: the clicks alone, the calibration alone, the floor 0.5 px clicks
leave with perfect cameras), the release frame and instant, each fit's settings replayed under the true
manipulation against the true cloth (mean vertex distance, mm) and their ratio (goal <= 2); with
``--uncertain-evals`` also the fit that estimates the capture's uncertain block (time offset, clip offsets)
and the release instant it implies (goal: within a third of a frame): the fit's ``release_instants``, where
its model's cloth starts to fall (Blender's cloth lets go at the last held frame) plus the fitted offset.

``calibrate``: four phone-like cameras stand round a table (portrait 1080 x 1920 scaled by
``--scale``, different focal lengths and lens distortion, principal points off centre), a printed
ChArUco board (on 5 mm foam board) lies flat on the textured table at the first moment, then is held
up in ``--poses`` poses round the middle, each turned towards a pair of neighbouring phones. Every
view where the board faces a phone is rendered by Blender's Cycles on the CPU (the approach of
``lab/render_footage.py``: a pinhole render on a grown canvas, warped with the camera's OpenCV
distortion, then sensor noise and a JPEG), in a child process: this driver never imports bpy. Then
``python -m clothfit calibrate`` runs on the images as a user would run it, and its cameras are
compared with the true ones, in the calibration's own world frame (the board at the first moment:
origin at the chessboard's centre, Z out of its face): focal length error [%], camera centre error
[mm], rotation error [deg], the reprojection RMS [px] and the gravity direction error [deg] (the
angle between each calibrated camera's world up and the scene's true up, seen from that camera), beside
the spread calibrate reports for each camera (``rotation_sd_deg``, ``tilt_sd_deg``: what its views leave).

Everything random comes from ``--seed``: a seed not run before is a rig, a lens set and a set of
board poses nobody has seen. The table is level, so the flat board's normal is the true up.
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
TOOLS = os.path.dirname(os.path.abspath(__file__))
if TOOLS not in sys.path:
    sys.path.insert(0, TOOLS)

from clothfit.core.footage import calibrate as CB  # noqa: E402
from clothfit.core.observation.camera import Camera, intrinsics, look_at  # noqa: E402

BOARD = "9,7,0.04,0.03,DICT_5X5_100"
PHONE_SIZE = (1080, 1920)  # portrait W x H of a phone's 1080p video
GOALS = {"focal_pct": 0.5, "centre_mm": 2.0, "rotation_deg": 0.1, "rms_px": 0.5, "gravity_deg": 0.2}
FLIP = np.diag([1.0, -1.0, -1.0])
BOARD_THICKNESS = 0.005  # foam board under the print [m]
TEXTURE_PX_PER_SQUARE = 96  # the print as Blender's texture


# ============================================================================ the rig


def _phone(rng, fx: float, W: int, H: int, R, t, name: str) -> Camera:
    """A phone's camera at pose ``R, t``: focal ``fx`` [px], its principal point up to 1 % off centre and its
    lens' radial and tangential distortion drawn from ``rng`` (in this order)."""
    K = intrinsics(
        fx,
        W,
        H,
        cx=(W - 1) / 2 + rng.uniform(-0.01, 0.01) * W,
        cy=(H - 1) / 2 + rng.uniform(-0.01, 0.01) * H,
    )
    dist = np.array(
        [
            rng.uniform(-0.10, 0.02),
            rng.uniform(-0.02, 0.08),
            rng.uniform(-1e-3, 1e-3),
            rng.uniform(-1e-3, 1e-3),
            0.0,
        ]
    )
    return Camera(K, R, t, W, H, name=name, dist=dist)


def phone_cameras(seed: int, scale: float, n: int = 4) -> list:
    """``n`` portrait phones round the table: azimuths spread with jitter, 0.55-0.75 m from the middle,
    28-42 degrees above the table top, aimed at the middle 15 cm up; focal lengths from a wide main camera
    to a mild tele (fx = 0.8 ... 1.3 x the image width), radial + tangential distortion, principal points
    up to 1 % off centre."""
    rng = np.random.default_rng([seed, 1])
    W, H = int(round(PHONE_SIZE[0] * scale)), int(round(PHONE_SIZE[1] * scale))
    focal = rng.permutation(np.linspace(0.8, 1.3, n)) * rng.uniform(0.97, 1.03, n)
    cams = []
    for i in range(n):
        az = 2 * math.pi * i / n + rng.uniform(-0.3, 0.3)
        el = math.radians(rng.uniform(28, 42))
        r = rng.uniform(0.55, 0.75)
        eye = np.array([r * math.cos(el) * math.cos(az), r * math.cos(el) * math.sin(az), r * math.sin(el)])
        target = np.array([rng.uniform(-0.04, 0.04), rng.uniform(-0.04, 0.04), 0.15])
        R, t = look_at(eye, target)
        cams.append(_phone(rng, focal[i] * W, W, H, R, t, f"phone{i}"))
    return cams


def _rot(axis, deg):
    import cv2

    a = np.asarray(axis, float)
    return cv2.Rodrigues(a / np.linalg.norm(a) * math.radians(deg))[0]


def board_poses(board: CB.Board, cams: list, n: int, seed: int, close: int = 0) -> list:
    """(R, t) board -> scene: flat on the table (z = 0 is the table top) at moment 0, then ``n`` poses
    held up, each turned towards a point between two neighbouring phones, tilted and rolled; then
    ``close`` poses before each phone (:func:`close_poses`)."""
    rng = np.random.default_rng([seed, 2])
    c = board.centre()
    R0 = _rot([0, 0, 1], rng.uniform(-30, 30)) @ FLIP  # printed face up
    # the print on the foam board on the table: its face BOARD_THICKNESS above the table top
    centre0 = np.array([rng.uniform(-0.05, 0.05), rng.uniform(-0.05, 0.05), BOARD_THICKNESS])
    poses = [(R0, centre0 - R0 @ c)]
    for k in range(n):
        i = k % len(cams)
        j = (i + 1) % len(cams)
        a = rng.uniform(0.15, 0.85)
        towards = a * cams[i].center + (1 - a) * cams[j].center
        centre = np.array([rng.uniform(-0.08, 0.08), rng.uniform(-0.08, 0.08), rng.uniform(0.14, 0.30)])
        Rc, _ = look_at(towards, centre)  # rows: a camera at ``towards`` looking at centre
        R = (
            Rc.T
            @ _rot([1, 0, 0], rng.uniform(-30, 30))
            @ _rot([0, 1, 0], rng.uniform(-20, 20))
            @ _rot([0, 0, 1], rng.uniform(-45, 45))
        )
        poses.append((R, centre - R @ c))
    return poses + close_poses(board, cams, close, seed)


def close_poses(board: CB.Board, cams: list, k: int, seed: int) -> list:
    """``k`` poses per phone after the others, as a calibration guide asks for each camera's lens: the
    board held before that phone, filling about 60-80 % of the image's width, tilted 15-35 degrees away
    from facing it (about a random axis) and moved round the image, so that its corners visit the
    image's edges, where the distortion and the principal point show. Never below the table top."""
    rng = np.random.default_rng([seed, 4])
    c = board.centre()
    out = []
    for cam in cams:
        fx = cam.K[0, 0]
        for _ in range(k):
            for _try in range(50):
                fill = rng.uniform(0.6, 0.8)
                d = board.size_m[0] * fx / (fill * cam.width)  # the board's width over fill of the image's
                # where its middle lands in the image: within the middle 40 % x 50 %
                u = cam.K[0, 2] + rng.uniform(-0.2, 0.2) * cam.width
                v = cam.K[1, 2] + rng.uniform(-0.25, 0.25) * cam.height
                ray = cam.R.T @ np.linalg.solve(cam.K, [u, v, 1.0])
                centre = cam.center + d * ray / np.linalg.norm(ray)
                Rc, _ = look_at(cam.center, centre)
                axis = np.array([math.cos(a := rng.uniform(0, 2 * math.pi)), math.sin(a), 0.0])
                R = Rc.T @ _rot(axis, rng.uniform(15, 35)) @ _rot([0, 0, 1], rng.uniform(-30, 30))
                t = centre - R @ c
                if (board.corners() @ R.T + t)[:, 2].min() > 0.02 and visible(cam, board, (R, t), min_inside=0.9):
                    out.append((R, t))
                    break
    return out


def visible(cam: Camera, board: CB.Board, pose, min_cos: float = 0.3, min_inside: float = 0.6) -> bool:
    """The printed face turned towards the phone and at least ``min_inside`` of its corners in the image."""
    R, t = pose
    centre = R @ board.centre() + t
    face = -R[:, 2]
    to_cam = cam.center - centre
    if face @ to_cam / np.linalg.norm(to_cam) < min_cos:
        return False
    uv = cam.project(board.corners() @ R.T + t)
    inside = (
        np.all(np.isfinite(uv), axis=1)
        & (uv[:, 0] >= 0)
        & (uv[:, 1] >= 0)
        & (uv[:, 0] <= cam.width - 1)
        & (uv[:, 1] <= cam.height - 1)
    )
    return bool(inside.mean() >= min_inside)


def cameras_in_world(cams, board: CB.Board, pose0) -> list:
    """The true cameras in the calibration's world frame (the board at ``pose0``)."""
    Rb, tb = pose0
    out = []
    for cam in cams:
        out.append(
            Camera(
                cam.K,
                cam.R @ Rb @ FLIP,
                cam.R @ (Rb @ board.centre() + tb) + cam.t,
                cam.width,
                cam.height,
                cam.name,
                cam.dist,
            )
        )
    return out


# ======================================================================= rendering (bpy)


def _board_object(board: CB.Board, texture_path: str, margin_m: float):
    """The printed board on foam board: the print on the face (-Z of the board frame), white edges and back."""
    import bpy

    W, H = board.size_m
    x0, y0, x1, y1 = -margin_m, -margin_m, W + margin_m, H + margin_m
    T = BOARD_THICKNESS
    verts = [(x0, y0, 0), (x1, y0, 0), (x1, y1, 0), (x0, y1, 0), (x0, y0, T), (x1, y0, T), (x1, y1, T), (x0, y1, T)]
    faces = [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)]
    mesh = bpy.data.meshes.new("Board")
    mesh.from_pydata(verts, [], faces)
    mesh.update()
    uv = mesh.uv_layers.new(name="UVMap")
    for poly in mesh.polygons:
        for li in poly.loop_indices:
            x, y, _ = verts[mesh.loops[li].vertex_index]
            uv.data[li].uv = ((x - x0) / (x1 - x0), 1.0 - (y - y0) / (y1 - y0))
    obj = bpy.data.objects.new("Board", mesh)
    bpy.context.scene.collection.objects.link(obj)
    paper = bpy.data.materials.new("Board Print")
    paper.use_nodes = True
    nodes, links = paper.node_tree.nodes, paper.node_tree.links
    bsdf = nodes["Principled BSDF"]
    bsdf.inputs["Roughness"].default_value = 0.7
    tex = nodes.new("ShaderNodeTexImage")
    tex.image = bpy.data.images.load(texture_path)
    tex.image.colorspace_settings.name = "sRGB"
    tex.interpolation = "Linear"
    # printed ink is not black and paper not white: 0.03 .. 0.8 reflectance
    ramp = nodes.new("ShaderNodeMapRange")
    ramp.inputs["To Min"].default_value = 0.03
    ramp.inputs["To Max"].default_value = 0.8
    links.new(tex.outputs["Color"], ramp.inputs["Value"])
    links.new(ramp.outputs["Result"], bsdf.inputs["Base Color"])
    foam = bpy.data.materials.new("Foam Board")
    foam.use_nodes = True
    foam.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (0.85, 0.85, 0.82, 1)
    mesh.materials.append(paper)
    mesh.materials.append(foam)
    for i, poly in enumerate(mesh.polygons):
        poly.material_index = 0 if i == 0 else 1
    return obj


def _room(engine: str, samples: int, denoise: bool):
    """The scene of render_footage.py without the cloth: a wooden table top at z = 0, walls, a key spot
    and a fill area light."""
    import bpy
    import render_footage as RF

    scene = RF.empty_scene("CYCLES", samples, denoise, world_name="Room")
    bpy.ops.mesh.primitive_plane_add(size=1.8, location=(0, 0, 0))
    bpy.context.object.name = "Table"
    bpy.context.object.data.materials.append(RF._table_material())
    bpy.ops.mesh.primitive_cylinder_add(
        vertices=48, radius=1.4, depth=2.6, location=(0, 0, 0.5), end_fill_type="NOTHING"
    )
    bpy.context.object.data.materials.append(RF._wall_material())
    spot = bpy.data.lights.new("Key", "SPOT")
    spot.energy = 60.0
    spot.spot_size = math.radians(80)
    spot.shadow_soft_size = 0.05
    key = bpy.data.objects.new("Key", spot)
    scene.collection.objects.link(key)
    key.location = (0.4, -0.3, 1.1)
    RF._aim(key, (0.0, 0.0, 0.1))
    fill = bpy.data.lights.new("Fill", "AREA")
    fill.energy = 40.0
    fill.size = 1.0
    fill_obj = bpy.data.objects.new("Fill", fill)
    scene.collection.objects.link(fill_obj)
    fill_obj.location = (-0.7, 0.6, 1.2)
    RF._aim(fill_obj, (0.0, 0.0, 0.1))
    return scene


def render_views(spec_path: str):
    """Child process (imports bpy): render every (camera, moment) the spec lists."""
    import bpy
    import cv2
    import render_footage as RF
    from mathutils import Matrix

    with open(spec_path) as f:
        spec = json.load(f)
    board = CB.parse_board(spec["board"])
    out = spec["images"]
    tex = os.path.join(os.path.dirname(spec_path), "board_texture.png")
    margin = spec["print_margin_m"]
    # the texture: whole pixels per square, the margin a whole number of pixels too
    px = TEXTURE_PX_PER_SQUARE
    mpx = int(round(margin / board.square_m * px))
    margin = mpx * board.square_m / px
    img = board.cv_board().generateImage(
        (board.squares_x * px + 2 * mpx, board.squares_y * px + 2 * mpx), marginSize=mpx, borderBits=1
    )
    cv2.imwrite(tex, img)
    scene = _room("CYCLES", spec["samples"], spec["denoise"])
    scene.cycles.seed = int(spec["seed"])
    bobj = _board_object(board, tex, margin)
    cam_data = bpy.data.cameras.new("Phone")
    cam_data.sensor_fit = "HORIZONTAL"
    cam_data.sensor_width = 36.0
    cam_obj = bpy.data.objects.new("Phone", cam_data)
    scene.collection.objects.link(cam_obj)
    tmp = os.path.join(os.path.dirname(spec_path), "_render")
    os.makedirs(tmp, exist_ok=True)
    rng = np.random.default_rng([int(spec["seed"]), 3])
    times = []
    for cd in spec["cameras"]:
        cam = Camera.from_dict(cd)
        margin_px = RF.needed_margin(cam)
        maps = RF.distortion_maps(cam, margin_px)
        os.makedirs(os.path.join(out, cam.name), exist_ok=True)
        for k in spec["views"][cam.name]:
            path = os.path.join(out, cam.name, f"m{k:03d}.jpg")
            if spec.get("keep") and os.path.isfile(path):
                continue  # rendered by a run before (--keep-renders)
            R, t = (np.asarray(a) for a in spec["poses"][k])
            M = np.eye(4)
            M[:3, :3], M[:3, 3] = R, t
            bobj.matrix_world = Matrix(M.tolist())
            t0 = time.time()
            pin = RF.render_pinhole(scene, cam_obj, cam, margin_px, os.path.join(tmp, "pin.png"))
            times.append(time.time() - t0)
            frame = RF.add_sensor_noise(RF.distort_image(pin, maps), rng, spec["read_noise"], spec["shot_noise"])
            cv2.imwrite(path, frame, [cv2.IMWRITE_JPEG_QUALITY, 95])
            print(f"[render] {cam.name} m{k:03d}: {times[-1]:.1f} s", flush=True)
    with open(os.path.join(os.path.dirname(spec_path), "render_times.json"), "w") as f:
        json.dump({"seconds": times}, f)


# ============================================================================ calibrate


def _load1():
    try:
        return os.getloadavg()[0]
    except OSError:
        return None


def run_calibrate(a) -> dict:
    board = CB.parse_board(BOARD)
    cams = phone_cameras(a.seed, a.scale)
    poses = board_poses(board, cams, a.poses, a.seed, a.close)
    views = {c.name: [k for k, p in enumerate(poses) if visible(c, board, p)] for c in cams}
    missing = [c for c, v in views.items() if 0 not in v]
    if missing:
        print(f"note: the flat board is not in view of {', '.join(missing)}", file=sys.stderr)
    os.makedirs(a.out, exist_ok=True)
    images = os.path.join(a.out, "images")
    spec = {
        "board": BOARD,
        "seed": a.seed,
        "samples": a.samples,
        "denoise": not a.no_denoise,
        "read_noise": a.read_noise,
        "shot_noise": a.shot_noise,
        "print_margin_m": 0.01,
        "images": images,
        "cameras": [c.to_dict() for c in cams],
        "views": views,
        "poses": [[R.tolist(), t.tolist()] for R, t in poses],
        "keep": bool(a.keep_renders),
    }
    spec_path = os.path.join(a.out, "spec.json")
    with open(spec_path, "w") as f:
        json.dump(spec, f, indent=1)
    load0 = _load1()
    t0 = time.time()
    cpu0 = os.times()
    if not a.skip_render:
        if os.path.isdir(images) and not a.keep_renders:
            import shutil

            shutil.rmtree(images)
        subprocess.run(
            [sys.executable, os.path.abspath(__file__), "_render", "--spec", spec_path], check=True, cwd=ROOT
        )
    render_s = time.time() - t0
    cpu1 = os.times()
    with open(os.path.join(a.out, "render_times.json")) as f:
        per_render = json.load(f)["seconds"]
    cams_json = os.path.join(a.out, "cameras.json")
    t1 = time.time()
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "clothfit",
            "calibrate",
            images,
            "--board",
            BOARD,
            "--out",
            cams_json,
            "--force",
            "--debug",
            os.path.join(a.out, "debug"),
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
    )
    calib_s = time.time() - t1
    sys.stderr.write(r.stderr)
    if r.returncode != 0:
        raise SystemExit(f"calibrate failed ({r.returncode}): {r.stderr.strip().splitlines()[-1]}")
    report = json.loads(r.stdout)
    est = {c.name: c for c in CB_load(cams_json)}
    truth = cameras_in_world(cams, board, poses[0])
    rows = []
    for t in truth:
        e = est[t.name]
        rep = next(c for c in report["cameras"] if c["name"] == t.name)
        # the scene's up, seen from the true camera; the calibrated world's up seen from the calibrated one
        true_scene = next(c for c in cams if c.name == t.name)
        up_true = true_scene.R @ np.array([0.0, 0.0, 1.0])
        up_est = e.R @ np.array([0.0, 0.0, 1.0])
        rows.append(
            {
                "camera": t.name,
                "width": t.width,
                "height": t.height,
                "fx_true": float(t.K[0, 0]),
                "fx": float(e.K[0, 0]),
                "focal_pct": float(100 * abs(e.K[0, 0] / t.K[0, 0] - 1)),
                "principal_point_px": float(np.linalg.norm(e.K[:2, 2] - t.K[:2, 2])),
                "centre_mm": float(1000 * np.linalg.norm(e.center - t.center)),
                "rotation_deg": CB.rotation_angle_deg(e.R @ t.R.T),
                "gravity_deg": math.degrees(math.acos(max(-1.0, min(1.0, float(up_true @ up_est))))),
                "rms_px": rep["rms_px"],
                # the spread calibrate reports (its views' first-order covariance): the error to expect
                "rotation_sd_deg": rep.get("rotation_sd_deg"),
                "tilt_sd_deg": rep.get("tilt_sd_deg"),
                "principal_point_sd_px": rep.get("principal_point_sd_px"),
                "views_used": rep["views_used"],
                "views_rendered": len(views[t.name]),
                "dist_true": t.dist.tolist(),
                "dist": e.dist.tolist(),
            }
        )
    worst = {k: max(r_[k] for r_ in rows) for k in GOALS}
    out = {
        "seed": a.seed,
        "board": BOARD,
        "resolution": [cams[0].width, cams[0].height],
        "scale": a.scale,
        "poses": a.poses,
        "samples": a.samples,
        "denoise": not a.no_denoise,
        "renders": sum(len(v) for v in views.values()),
        "cameras": rows,
        "worst": worst,
        "goals": GOALS,
        "meets_goals": {k: bool(worst[k] <= GOALS[k]) for k in GOALS},
        "calibration_rms_px": report["rms_px"],
        "rejected_corners": report["rejected_corners"],
        "dropped_views": len(report["dropped_views"]),
        "render_seconds": render_s,
        "render_cpu_seconds": (cpu1.children_user + cpu1.children_system) - (cpu0.children_user + cpu0.children_system),
        "seconds_per_render": float(np.mean(per_render)),
        "calibrate_seconds": calib_s,
        "load_1min_start": load0,
        "load_1min_end": _load1(),
    }
    print(format_table(out), file=sys.stderr)
    if a.json:
        from clothfit.core.jsonio import write_json

        write_json(a.json, out)
    return out


def CB_load(path):
    from clothfit.core.observation.camera import load_cameras

    return load_cameras(path)


def format_table(out: dict) -> str:
    lines = [
        f"seed {out['seed']}, {out['resolution'][0]} x {out['resolution'][1]} px, {out['renders']} renders",
        "| camera | fx | focal err % | centre err mm | rotation err deg | gravity err deg | RMS px | views |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in out["cameras"]:
        lines.append(
            f"| {r['camera']} | {r['fx_true']:.1f} | {r['focal_pct']:.3f} | {r['centre_mm']:.2f} | "
            f"{r['rotation_deg']:.3f} | {r['gravity_deg']:.3f} | {r['rms_px']:.3f} | {r['views_used']} |"
        )
    w = out["worst"]
    lines.append(
        f"| worst | | {w['focal_pct']:.3f} | {w['centre_mm']:.2f} | {w['rotation_deg']:.3f} | "
        f"{w['gravity_deg']:.3f} | {w['rms_px']:.3f} | |"
    )
    lines.append(
        "goals: " + ", ".join(f"{k} <= {v} {'met' if out['meets_goals'][k] else 'MISSED'}" for k, v in GOALS.items())
    )
    return "\n".join(lines)


# ========================================================================== end to end

CLOTH_W, CLOTH_H = 0.30, 0.24  # the user's cloth, measured [m]
CLOTH_NX, CLOTH_NY = 16, 13  # 2 cm cells: the clips at u = 0, 0.1, 0.2, 0.3 sit on vertices
CLOTH_GSM = 0.150  # cotton, 150 g/m2: the cloth's weighed mass = GSM * area
TOP = 0.40  # the clips' height above the table [m]
CLIPS = {"left": 0.0, "third": 0.10, "two-thirds": 0.20, "right": 0.30}  # u of each clip on the top edge
RELEASED = "right"
# clips on a rod are never in one line: their offsets across the cloth [m] (a flat sheet hung by clips in one
# line cannot buckle: its corner would only sag in its plane)
CLIP_Y = {"third": 0.010, "two-thirds": -0.010}
FPS = 30.0
# the clips were put on long before the filming starts: the truth settles a full second (the clips come from
# the flat cloth to the rod in its first half), so nothing moves before the release
TRUTH_SETTLE = 1.0
TRUTH_FPS = 150.0  # the truth's Blender frame rate (quality 1)
BEFORE = 0.1  # s filmed before the release
CLICK_SIGMA = 0.5  # px: a person's click on a zoomed frame
FREE = ("tension_stiffness", "bending_stiffness", "air_damping")
# the truth: Blender's defaults (a new Cloth modifier) with the free settings changed, all at Blender's
# default vertex mass of 0.3 kg, then moved to the cloth's own vertex mass (the motion is unchanged)
TRUE_AT_DEFAULT_MASS = {"tension_stiffness": 30.0, "bending_stiffness": 0.2, "air_damping": 1.5}
E2E_GOALS = {"shape_ratio": 2.0, "release_frame_exact": True, "release_time_frames": 1.0 / 3.0}


def front_cameras(seed: int, scale: float, n: int = 4) -> list:
    """``n`` portrait phones in an arc in front of the hanging cloth (azimuths -60 .. +60 degrees round the
    cloth's normal, jittered), 0.55-0.70 m away, their lenses 0.30-0.45 m above the table, aimed at the
    cloth's middle: every phone sees the cloth's face, the clips and the table where the board lies; focal
    lengths 1.0 ... 1.3 x the image width (a main camera zoomed a little), distortion, principal points
    up to 1 % off centre."""
    rng = np.random.default_rng([seed, 11])
    W, H = int(round(PHONE_SIZE[0] * scale)), int(round(PHONE_SIZE[1] * scale))
    focal = rng.permutation(np.linspace(1.0, 1.3, n)) * rng.uniform(0.97, 1.03, n)
    cams = []
    for i, az in enumerate(np.linspace(-60, 60, n) + rng.uniform(-8, 8, n)):
        a = math.radians(az - 90.0)
        r = rng.uniform(0.55, 0.70)
        eye = np.array([r * math.cos(a), r * math.sin(a), rng.uniform(0.30, 0.45)])
        R, t = look_at(eye, [rng.uniform(-0.02, 0.02), 0.0, 0.22])
        cams.append(_phone(rng, focal[i] * W, W, H, R, t, f"phone{i}"))
    return cams


def true_settings(vertex_mass: float) -> dict:
    from clothfit.core.fitting.parameters import _rescale
    from clothfit.core.physics import blender as B

    s = dict(B.DEFAULTS, **TRUE_AT_DEFAULT_MASS, time_scale=B.physical_time_scale(FPS))
    return B.check_settings(_rescale(s, vertex_mass, s["bending_model"]), "true settings")


def cloth_truth(seed: int, frames: int):
    """The manipulation (4 clips on the top edge, the right one let go at a random phase within a frame),
    the cloth's motion by the core's Blender model (Blender's cloth, bit-exact) at the true settings."""
    from clothfit.core.physics import blender as B
    from clothfit.core.physics.models import BlenderModel
    from clothfit.core.physics.rotation import rotation_vector
    from clothfit.core.physics.scenario import ClothGrid, Handle, Scenario

    rng = np.random.default_rng([seed, 12])
    # the truth runs Blender's cloth at TRUTH_FPS (quality 1: the time step of 30 fps at quality 5, the motion
    # the same within 0.01 mm), whose pins let go on its frames: the release falls 1/5, 2/5, 3/5 or 4/5 of a
    # footage frame after a frame, exactly the instant the cloth starts to fall (never on a footage frame,
    # where the "first free frame" would be undefined)
    phase = int(rng.integers(1, TRUTH_FPS // FPS)) / (TRUTH_FPS / FPS)
    t_release = BEFORE + phase / FPS
    times = np.arange(frames) / FPS
    R = np.stack([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]], 1)  # the cloth in the plane y = 0
    grid = ClothGrid(
        CLOTH_NX,
        CLOTH_NY,
        CLOTH_W,
        side_y=CLOTH_H,
        origin=np.array([0.0, 0.0, TOP - CLOTH_H / 2]),
        rotation=rotation_vector(R),
    )
    handles, verts = [], {}
    for name, u in CLIPS.items():
        v = int(round(u / (CLOTH_W / (CLOTH_NX - 1))))
        verts[name] = v
        pos = grid.rest[v] + [0.0, CLIP_Y.get(name, 0.0), 0.0]
        handles.append(Handle(v, [0.0], pos[None], t_release if name == RELEASED else None))
    scen = Scenario(grid, handles, times, TRUTH_SETTLE)
    mass = CLOTH_GSM * CLOTH_W * CLOTH_H
    settings = true_settings(mass / grid.n_vertices)
    fine = dict(settings, quality=1, time_scale=B.physical_time_scale(TRUTH_FPS))
    sim = BlenderModel(TRUTH_FPS, 1).simulate(scen, B.settings_row(fine)[None])
    if sim.exploded[0]:
        raise SystemExit(f"the true cloth exploded: {sim.reason[0]}")
    return {
        "scenario": scen,
        "positions": sim.positions[0],
        "times": times,
        "release_time": t_release,
        "phase": phase,
        "vertices": verts,
        "settings": settings,
        "cloth_mass": mass,
    }


def world_from_scene(board: CB.Board, pose0, X):
    """Scene points in the calibration's world frame (the board flat at ``pose0``)."""
    Rb, tb = pose0
    return (np.asarray(X) - (Rb @ board.centre() + tb)) @ Rb @ FLIP


def render_e2e(spec_path: str):
    """Child process (imports bpy): the board views, then each phone's background plate and frames."""
    import bpy
    import cv2
    import render_footage as RF
    from mathutils import Matrix

    with open(spec_path) as f:
        spec = json.load(f)
    board = CB.parse_board(spec["board"])
    work = os.path.dirname(spec_path)
    X = np.load(os.path.join(work, "truth_positions.npy"))
    from clothfit.core.physics.scenario import Scenario

    scen = Scenario.from_dict(spec["scenario"])
    tex = os.path.join(work, "board_texture.png")
    px = TEXTURE_PX_PER_SQUARE
    mpx = int(round(spec["print_margin_m"] / board.square_m * px))
    margin = mpx * board.square_m / px
    img = board.cv_board().generateImage(
        (board.squares_x * px + 2 * mpx, board.squares_y * px + 2 * mpx), marginSize=mpx, borderBits=1
    )
    cv2.imwrite(tex, img)
    scene, cloth = RF.build_scene(scen.grid, "CYCLES", spec["samples"], spec["denoise"])
    scene.cycles.seed = int(spec["seed"])
    bpy.data.objects["Table"].location.z = 0.0  # the table top is z = 0 here
    bobj = _board_object(board, tex, margin)
    # the printed cloth's texture from the flat sheet (as lab/phone_handles.py)
    me = cloth.data
    loc = scen.grid.local
    u = (loc[:, 0] + CLOTH_W / 2) / CLOTH_W
    v = (loc[:, 1] + CLOTH_H / 2) / CLOTH_H
    loop_uv = np.stack([u, v], -1)[np.array([lp.vertex_index for lp in me.loops])]
    me.uv_layers["UVMap"].data.foreach_set("uv", loop_uv.astype(np.float32).ravel())
    import phone_handles as PH

    mat = PH._clip_material()
    clips = []
    for name, vtx in spec["vertices"].items():
        bpy.ops.mesh.primitive_cube_add(size=1.0)
        ob = bpy.context.object
        ob.name = f"Clip {name}"
        ob.scale = (0.016, 0.010, 0.022)
        ob.data.materials.append(mat)
        clips.append((ob, vtx))
    bpy.ops.mesh.primitive_cylinder_add(
        radius=0.004, depth=0.5, location=(0.0, 0.0, TOP + 0.03), rotation=(0.0, math.pi / 2, 0.0)
    )
    cam_data = bpy.data.cameras.new("Phone")
    cam_data.sensor_fit = "HORIZONTAL"
    cam_data.sensor_width = 36.0
    cam_obj = bpy.data.objects.new("Phone", cam_data)
    scene.collection.objects.link(cam_obj)
    tmp = os.path.join(work, "_render")
    os.makedirs(tmp, exist_ok=True)
    rng = np.random.default_rng([int(spec["seed"]), 13])
    times = {"board": [], "footage": []}

    def show(obj, on):
        obj.hide_render = not on

    def shot(cam, maps, margin_px, path, kind, jpeg=False):
        if spec.get("keep") and os.path.exists(path):
            return
        t0 = time.time()
        pin = RF.render_pinhole(scene, cam_obj, cam, margin_px, os.path.join(tmp, "pin.png"))
        times[kind].append(time.time() - t0)
        frame = RF.add_sensor_noise(RF.distort_image(pin, maps), rng, spec["read_noise"], spec["shot_noise"])
        cv2.imwrite(path, frame, [cv2.IMWRITE_JPEG_QUALITY, 95] if jpeg else [])
        print(f"[render] {os.path.relpath(path, work)}: {times[kind][-1]:.1f} s", flush=True)

    for cd in spec["cameras"]:
        cam = Camera.from_dict(cd)
        margin_px = RF.needed_margin(cam)
        maps = RF.distortion_maps(cam, margin_px)
        # 1. the board, before the cloth is hung: the phones already where they will film
        show(cloth, False)
        for ob, _ in clips:
            show(ob, False)
        show(bobj, True)
        d = os.path.join(work, "calib_images", cam.name)
        os.makedirs(d, exist_ok=True)
        for k in spec["views"][cam.name]:
            R, t = (np.asarray(a) for a in spec["poses"][k])
            M = np.eye(4)
            M[:3, :3], M[:3, 3] = R, t
            bobj.matrix_world = Matrix(M.tolist())
            shot(cam, maps, margin_px, os.path.join(d, f"m{k:03d}.jpg"), "board", jpeg=True)
        # 2. the background plate (board away, no cloth), then the cloth's frames
        show(bobj, False)
        d = os.path.join(work, "footage", cam.name)
        os.makedirs(d, exist_ok=True)
        shot(cam, maps, margin_px, os.path.join(d, "background.png"), "footage")
        show(cloth, True)
        for ob, _ in clips:
            show(ob, True)
        for f in range(X.shape[0]):
            RF.set_cloth_shape(cloth, X[f])
            for ob, vtx in clips:
                ob.location = tuple(float(x) for x in X[f, vtx] + [0.0, 0.0, 0.004])
            shot(cam, maps, margin_px, os.path.join(d, f"{f:03d}.png"), "footage")
    with open(os.path.join(work, "render_times.json"), "w") as f:
        json.dump(times, f)


def _cli(args, log, what):
    """``python -m clothfit ARGS`` as a user runs it: its JSON (stdout), its messages (stderr) into ``log``."""
    t0 = time.time()
    r = subprocess.run([sys.executable, "-m", "clothfit", *args], cwd=ROOT, capture_output=True, text=True)
    secs = time.time() - t0
    with open(log, "a") as f:
        f.write(f"$ clothfit {' '.join(args)}\n{r.stderr}\n[{secs:.1f} s, exit {r.returncode}]\n\n")
    if r.returncode != 0:
        lines = r.stderr.strip().splitlines()
        raise SystemExit(f"{what} failed ({r.returncode}): {lines[-1] if lines else ''}")
    return json.loads(r.stdout), secs


def _fit_args(capture, out, a, uncertain=False, evals=None):
    """Both fits alike: Blender's cloth at the footage's 30 fps and quality 5 (the truth's: the fits differ in
    what they were given, not in the solver), the same free settings, budget and seed. ``uncertain``: the
    capture's ``uncertain`` block (written by handles) is estimated with the cloth; else ``--uncertain none``."""
    args = [
        "fit",
        capture,
        "--out",
        out,
        "--model",
        "blender",
        "--fps",
        f"{FPS:g}",
        "--quality",
        "5",
        "--free",
        ",".join(FREE),
        "--max-evaluations",
        str(evals or a.evals),
        "--seed",
        str(a.fit_seed),
        "--quiet",
        "--force",
    ]
    if a.resolution:
        args += ["--resolution", a.resolution]
    if not uncertain:
        args += ["--uncertain", "none"]
    return args


def replay_error_mm(settings: dict, tr: dict, scenario=None, truth=None) -> dict:
    """Settings replayed under the TRUE manipulation (the core's Blender model), or under ``scenario``:
    mean vertex distance to the true cloth (``truth``: its positions in the scenario's frame) [mm], over
    all frames, before and after the release, the worst and the last frame."""
    from clothfit.core.observation.metrics import shape_error_mm
    from clothfit.core.physics import blender as B
    from clothfit.core.physics.models import BlenderModel

    s = B.check_settings({k: v for k, v in settings.items() if k in B.DEFAULTS}, "replay")
    model = BlenderModel(FPS, s["quality"], s["bending_model"])
    sim = model.simulate(tr["scenario"] if scenario is None else scenario, B.settings_row(s)[None])
    se = shape_error_mm(sim.positions[0], tr["positions"] if truth is None else truth)
    after = tr["times"] > tr["release_time"]
    return {
        "mean_mm": float(se.mean()),
        "before_release_mm": float(se[~after].mean()),
        "after_release_mm": float(se[after].mean()),
        "max_frame_mm": float(se.max()),
        "end_mm": float(se[-1]),
        "per_frame_mm": se.tolist(),
    }


def handle_error_sources(cams, est_cams, marks: dict, truth_w, vertices: dict, seed: int, draws: int = 400) -> dict:
    """What the clips' 3-D error is made of (``cams``: the true cameras in the calibration's world frame,
    ``est_cams``: the calibrated ones, by name; ``truth_w``: the true points in that frame): per clip the
    triangulation of the clicks by the true cameras (the click noise alone), of the true image points by
    the calibrated cameras (the calibration alone) and of the clicks by the calibrated cameras (both, without
    tracking); and the click noise's floor: over ``draws`` draws of CLICK_SIGMA px clicks on the true image
    points, triangulated by the true cameras, the median of the worst clip and how often it is within the
    1 mm goal."""
    from clothfit.core.footage.handle_triangulate import triangulate

    names = [c.name for c in cams]
    est = [est_cams[n] for n in names]
    out = {"clicks_true_cameras_mm": {}, "true_points_calibrated_mm": {}, "clicks_calibrated_mm": {}}
    for h in marks["handles"]:
        Xt = truth_w[vertices[h["name"]]]
        clicks = [np.asarray(h["marks"][n], float) for n in names]
        true_px = [c.project(Xt) for c in cams]
        for key, cs, pts in (
            ("clicks_true_cameras_mm", cams, clicks),
            ("true_points_calibrated_mm", est, true_px),
            ("clicks_calibrated_mm", est, clicks),
        ):
            out[key][h["name"]] = 1000.0 * float(np.linalg.norm(triangulate(cs, pts).X - Xt))
    for key in ("clicks_true_cameras_mm", "true_points_calibrated_mm", "clicks_calibrated_mm"):
        out[key.replace("_mm", "_worst_mm")] = max(out[key].values())
    rng = np.random.default_rng([seed, 15])
    worst = []
    for _ in range(draws):
        e = []
        for v in vertices.values():
            Xt = truth_w[v]
            pts = [c.project(Xt) + rng.normal(0, CLICK_SIGMA, 2) for c in cams]
            e.append(1000.0 * float(np.linalg.norm(triangulate(cams, pts).X - Xt)))
        worst.append(max(e))
    out["click_floor"] = {
        "draws": draws,
        "click_sigma_px": CLICK_SIGMA,
        "worst_clip_median_mm": float(np.median(worst)),
        "worst_clip_within_1mm_fraction": float(np.mean(np.asarray(worst) <= 1.0)),
    }
    return out


def run_e2e(a) -> dict:
    from clothfit.core.observation.camera import save_cameras
    from clothfit.core.physics.scenario import Scenario

    board = CB.parse_board(BOARD)
    cams = front_cameras(a.seed, a.scale, a.cameras)
    poses = board_poses(board, cams, a.poses, a.seed, a.close)
    views = {c.name: [k for k, p in enumerate(poses) if visible(c, board, p)] for c in cams}
    tr = cloth_truth(a.seed, a.frames)
    os.makedirs(a.out, exist_ok=True)
    spec = {
        "board": BOARD,
        "seed": a.seed,
        "samples": a.samples,
        "denoise": not a.no_denoise,
        "read_noise": a.read_noise,
        "shot_noise": a.shot_noise,
        "print_margin_m": 0.01,
        "cameras": [c.to_dict() for c in cams],
        "views": views,
        "poses": [[R.tolist(), t.tolist()] for R, t in poses],
        "scenario": tr["scenario"].to_dict(),
        "vertices": tr["vertices"],
        "keep": bool(a.keep_renders),
    }
    spec_path = os.path.join(a.out, "spec.json")
    with open(spec_path, "w") as f:
        json.dump(spec, f, indent=1)
    np.save(os.path.join(a.out, "truth_positions.npy"), tr["positions"])
    load0 = _load1()
    t0 = time.time()
    if not a.skip_render:
        import shutil

        for d in ("calib_images", "footage"):
            if os.path.isdir(os.path.join(a.out, d)) and not a.keep_renders:
                shutil.rmtree(os.path.join(a.out, d))
        subprocess.run(
            [sys.executable, os.path.abspath(__file__), "_render_e2e", "--spec", spec_path],
            check=True,
            cwd=ROOT,
            stdout=None if a.verbose else subprocess.DEVNULL,
        )
    render_s = time.time() - t0
    with open(os.path.join(a.out, "render_times.json")) as f:
        rt = json.load(f)
    footage = os.path.join(a.out, "footage")
    # what the user has: the frames' times (the phones' frame rate, synced), the cloth's weighed mass and
    # measured size, and clicks on the clips in frame 0 (here: their true image points + click noise)
    rng = np.random.default_rng([a.seed, 14])
    with open(os.path.join(footage, "footage.json"), "w") as f:
        json.dump({"frame_times": tr["times"].tolist(), "cloth_mass": tr["cloth_mass"]}, f, indent=1)
    X = tr["positions"]
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
    marks_path = os.path.join(a.out, "marks.json")
    with open(marks_path, "w") as f:
        json.dump(marks, f, indent=1)
    log = os.path.join(a.out, "commands.log")
    if os.path.exists(log):
        os.remove(log)
    P = {
        k: os.path.join(a.out, v)
        for k, v in {
            "cams": "cameras.json",
            "scen": "scenario.json",
            "cap": "capture",
            "fit": "fit.json",
            "cloth": "blender_cloth.json",
            "true_cams": "true_cameras.json",
            "true_scen": "true_scenario.json",
            "true_cap": "capture_true",
            "true_fit": "fit_true.json",
        }.items()
    }
    secs = {}
    # ---- the user's pipeline: nothing true in it but the images, the clicks, the size and the mass
    calib, secs["calibrate"] = _cli(
        [
            "calibrate",
            os.path.join(a.out, "calib_images"),
            "--board",
            BOARD,
            "--out",
            P["cams"],
            "--force",
            "--debug",
            os.path.join(a.out, "calib_debug"),
        ],
        log,
        "calibrate",
    )
    hand, secs["handles"] = _cli(
        [
            "handles",
            footage,
            "--marks",
            marks_path,
            "--size",
            f"{CLOTH_W}x{CLOTH_H}",
            "--cameras",
            P["cams"],
            "-o",
            P["scen"],
            "--force",
        ],
        log,
        "handles",
    )
    _, secs["extract"] = _cli(
        ["extract", footage, "-o", P["cap"], "--cameras", P["cams"], "--scenario", P["scen"], "--force"], log, "extract"
    )
    # the fit as the phone rig's goal compares it: the manipulation handles measured taken as it is (the same search as
    # the fit given the truth: 3 settings, the same budget); then, with --uncertain-evals, the fit that also
    # estimates the capture's uncertain block (time offset, clip offsets: 16 unknowns, a larger budget)
    fit, secs["fit"] = _cli(_fit_args(P["cap"], P["fit"], a), log, "fit")
    cloth, secs["export"] = _cli(["export-blender-cloth", P["fit"]], log, "export-blender-cloth")
    with open(P["cloth"], "w") as f:
        json.dump(cloth, f, indent=1)
    uncertain = a.uncertain_evals > 0
    if uncertain:
        P["fit_u"] = os.path.join(a.out, "fit_uncertain.json")
        fit_u, secs["fit_uncertain"] = _cli(
            _fit_args(P["cap"], P["fit_u"], a, True, a.uncertain_evals), log, "fit --uncertain"
        )
        cloth_u, _ = _cli(["export-blender-cloth", P["fit_u"]], log, "export-blender-cloth")
        with open(os.path.join(a.out, "blender_cloth_uncertain.json"), "w") as f:
            json.dump(cloth_u, f, indent=1)
    # ---- the same fit given the truth: true cameras, the true manipulation, the same silhouettes
    save_cameras(P["true_cams"], cams)
    with open(P["true_scen"], "w") as f:
        json.dump({"scenario": tr["scenario"].to_dict()}, f, indent=1)
    _, secs["extract_true"] = _cli(
        ["extract", footage, "-o", P["true_cap"], "--cameras", P["true_cams"], "--scenario", P["true_scen"], "--force"],
        log,
        "extract (true)",
    )
    fit_true, secs["fit_true"] = _cli(_fit_args(P["true_cap"], P["true_fit"], a), log, "fit (true)")
    # ---- compare
    with open(P["fit"]) as f:
        res = json.load(f)
    with open(P["true_fit"]) as f:
        res_true = json.load(f)
    e2e = replay_error_mm(cloth["blender_cloth"], tr)
    oracle = replay_error_mm(res_true["blender_cloth"], tr)
    with open(P["scen"]) as f:
        sdoc = json.load(f)
    sc = Scenario.from_dict(sdoc["scenario"])
    times = tr["times"]
    period = 1.0 / FPS
    rel_h = next(h for h, r in zip(sc.handles, sdoc["report"]["handles"]) if r["name"] == RELEASED)
    rel_rep = next(r for r in sdoc["report"]["handles"] if r["name"] == RELEASED)
    true_frame = int(np.searchsorted(times, tr["release_time"], side="right"))
    truth_w = world_from_scene(board, poses[0], X[0])
    handle_mm = {}
    for h, r in zip(sc.handles, sdoc["report"]["handles"]):
        handle_mm[r["name"]] = 1000 * float(np.linalg.norm(h.positions[0] - truth_w[tr["vertices"][r["name"]]]))
    truth_cams = {c.name: c for c in cameras_in_world(cams, board, poses[0])}
    from clothfit.core.observation.camera import load_cameras

    cal = []
    for e in load_cameras(P["cams"]):
        t = truth_cams[e.name]
        rep = next((c for c in calib["cameras"] if c["name"] == e.name), {})
        cal.append(
            {
                "camera": e.name,
                "focal_pct": float(100 * abs(e.K[0, 0] / t.K[0, 0] - 1)),
                "centre_mm": float(1000 * np.linalg.norm(e.center - t.center)),
                "rotation_deg": CB.rotation_angle_deg(e.R @ t.R.T),
                "rotation_sd_deg": rep.get("rotation_sd_deg"),
            }
        )
    out = {
        "seed": a.seed,
        "resolution": [cams[0].width, cams[0].height],
        "cameras": len(cams),
        "frames": a.frames,
        "samples": a.samples,
        "board_renders": sum(len(v) for v in views.values()),
        "footage_renders": len(cams) * (a.frames + 1),
        "evaluations": a.evals,
        "free": list(FREE),
        "true_settings": {k: tr["settings"][k] for k in FREE},
        "release_phase": tr["phase"],
        "calibration": {
            "rms_px": calib["rms_px"],
            "cameras": cal,
            "worst": {k: max(c[k] for c in cal) for k in ("focal_pct", "centre_mm", "rotation_deg")},
        },
        "handles_mm": handle_mm,
        "handles_max_mm": max(handle_mm.values()),
        "handles_error_sources": handle_error_sources(
            list(truth_cams.values()),
            {e.name: e for e in load_cameras(P["cams"])},
            marks,
            truth_w,
            tr["vertices"],
            a.seed,
        ),
        "release_frame": rel_rep["release_frame"],
        "true_release_frame": true_frame,
        "release_frame_exact": rel_rep["release_frame"] == true_frame,
        "release_time_error_frames_handles": (rel_h.release_time - tr["release_time"]) / period,
        "fit": {
            "e2e": {
                "settings": {k: res["blender_cloth"][k] for k in FREE},
                "E_sil_pct": fit.get("best_E_sil_mean_pct"),
                "replay": e2e,
            },
            "truth_given": {
                "settings": {k: res_true["blender_cloth"][k] for k in FREE},
                "E_sil_pct": fit_true.get("best_E_sil_mean_pct"),
                "replay": oracle,
            },
        },
        "shape_ratio": e2e["mean_mm"] / oracle["mean_mm"],
        "uncertain_fit": bool(uncertain),
        "seconds": dict(secs, render=render_s),
        "seconds_per_render": {k: float(np.mean(v)) for k, v in rt.items() if v},
        "load_1min_start": load0,
        "load_1min_end": _load1(),
    }
    if uncertain:
        with open(P["fit_u"]) as f:
            res_u = json.load(f)
        rep_u = replay_error_mm(cloth_u["blender_cloth"], tr)
        t_off = res_u.get("time_offset_s")
        out["fit"]["uncertain"] = {
            "settings": {k: res_u["blender_cloth"][k] for k in FREE},
            "E_sil_pct": fit_u.get("best_E_sil_mean_pct"),
            "replay": rep_u,
            "evaluations": a.uncertain_evals,
            "time_offset_s": t_off,
            "time_offset_uncertainty_s": res_u.get("time_offset_uncertainty_s"),
            "uncertain_block": sdoc.get("uncertain"),
        }
        out["shape_ratio_uncertain"] = rep_u["mean_mm"] / oracle["mean_mm"]
        # the fit's release on the capture's clock (fitting.parameters.release_instants): the instant its model's
        # cloth starts to fall (Blender's cloth lets go at the last held frame, up to a frame before the declared
        # time) plus the fitted offset (true time = capture time - t_off)
        inst = next((r for r in res_u.get("release_instants") or [] if r["vertex"] == rel_h.vertex), None)
        if inst is not None:
            out["fit"]["uncertain"]["release_instant"] = inst
            out["release_time_error_frames_fit"] = (inst["capture_s"] - tr["release_time"]) / period
    out["goals"] = {
        "shape_ratio_le_2": out["shape_ratio"] <= E2E_GOALS["shape_ratio"],
        "release_frame_exact": out["release_frame_exact"],
    }
    if "release_time_error_frames_fit" in out:
        out["goals"]["release_time_within_third_frame"] = abs(out["release_time_error_frames_fit"]) <= 1 / 3
    print(format_e2e(out), file=sys.stderr)
    out["pictures"] = make_pictures(a.out, os.path.join(a.out, "pictures"))
    if a.json:
        from clothfit.core.jsonio import write_json

        write_json(a.json, out)
    return out


def _small_png(path, img):
    """A PNG of few colours (pictures for the docs: tens of kB, not hundreds)."""
    from PIL import Image

    Image.fromarray(img[:, :, ::-1]).quantize(96, dither=Image.Dither.NONE).save(path, optimize=True)


def make_pictures(out: str, dest: str, cams=("phone0", "phone2"), frames=(0, -1), width=200) -> list:
    """Small PNGs of a run for the tutorial (docs/img): the board's detected corners (flat, held up), and two
    phones' frames with the clicks (frame 0) and the extracted silhouette's outline."""
    import cv2

    os.makedirs(dest, exist_ok=True)
    written = []

    def small(img):
        h, w = img.shape[:2]
        return cv2.resize(img, (width, int(round(h * width / w))), interpolation=cv2.INTER_AREA)

    dbg = os.path.join(out, "calib_debug", cams[0])
    shots = sorted(os.listdir(dbg))
    tiles = [small(cv2.imread(os.path.join(dbg, f))) for f in (shots[0], shots[len(shots) // 2])]
    path = os.path.join(dest, "phone_rig_board.png")
    _small_png(path, np.concatenate(tiles, 1))
    written.append(path)
    with open(os.path.join(out, "marks.json")) as f:
        marks = json.load(f)
    tiles = []
    for cam in cams:
        names = sorted(n for n in os.listdir(os.path.join(out, "footage", cam)) if not n.startswith("background"))
        for k in frames:
            name = names[k]
            img = cv2.imread(os.path.join(out, "footage", cam, name))
            sil = cv2.imread(os.path.join(out, "capture", "sil", cam, name), cv2.IMREAD_GRAYSCALE)
            if sil is not None:
                cs, _ = cv2.findContours((sil > 127).astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
                cv2.drawContours(img, cs, -1, (60, 220, 60), 1)
            if k == 0:
                for h in marks["handles"]:
                    u, v = h["marks"][cam]
                    cv2.circle(
                        img, (int(round(u)), int(round(v))), 6, (0, 0, 255) if h.get("released") else (255, 160, 0), 2
                    )
            tiles.append(small(img))
    path = os.path.join(dest, "phone_rig_footage.png")
    _small_png(path, np.concatenate(tiles, 1))
    written.append(path)
    return written


def format_e2e(o: dict) -> str:
    c = o["calibration"]["worst"]
    f = o["fit"]
    return "\n".join(
        [
            f"seed {o['seed']}, {o['resolution'][0]} x {o['resolution'][1]} px, {o['board_renders']} board + "
            f"{o['footage_renders']} footage renders",
            f"calibration: RMS {o['calibration']['rms_px']:.3f} px; worst focal {c['focal_pct']:.3f} %, centre "
            f"{c['centre_mm']:.2f} mm, rotation {c['rotation_deg']:.3f} deg",
            f"handles: worst {o['handles_max_mm']:.2f} mm; release frame {o['release_frame']} (true "
            f"{o['true_release_frame']}), release time off by {o['release_time_error_frames_handles']:+.3f} frame",
            "handles, what the error is made of (worst clip): the clicks by the true cameras "
            f"{max(o['handles_error_sources']['clicks_true_cameras_mm'].values()):.2f} mm, the true points by the "
            f"calibrated cameras {max(o['handles_error_sources']['true_points_calibrated_mm'].values()):.2f} mm; "
            f"{CLICK_SIGMA:g} px clicks alone: worst clip median "
            f"{o['handles_error_sources']['click_floor']['worst_clip_median_mm']:.2f} mm, within 1 mm in "
            f"{100 * o['handles_error_sources']['click_floor']['worst_clip_within_1mm_fraction']:.0f} % of draws",
            f"fit (end to end):  {f['e2e']['settings']}  replay {f['e2e']['replay']['mean_mm']:.3f} mm",
            f"fit (truth given): {f['truth_given']['settings']}  replay {f['truth_given']['replay']['mean_mm']:.3f} mm",
            f"shape error ratio {o['shape_ratio']:.2f} (goal <= 2)",
        ]
        + (
            [
                f"fit --uncertain ({f['uncertain']['evaluations']} evaluations): {f['uncertain']['settings']}  replay "
                f"{f['uncertain']['replay']['mean_mm']:.3f} mm, ratio {o['shape_ratio_uncertain']:.2f}; time offset "
                f"{f['uncertain']['time_offset_s']}; release time off by {o.get('release_time_error_frames_fit', float('nan')):+.3f} "
                f"frame (goal: within 1/3)"
            ]
            if "uncertain" in f
            else []
        )
    )


def run_sensitivity(a) -> dict:
    """How much the clips' positions alone move the cloth: the TRUE settings (at the fits' frame rate and
    quality) replayed under (1) the true manipulation, (2) the clips as an e2e run measured them (``--e2e``:
    its scenario.json, in the calibration's world frame) and (3) ``--draws`` draws of clips moved by
    ``--sigma-mm`` per axis round the true ones; each against the true cloth (mean vertex distance [mm])."""
    from clothfit.core.physics.scenario import Handle, Scenario

    tr = cloth_truth(a.seed, a.frames)
    scen = tr["scenario"]
    s = dict(true_settings(CLOTH_GSM * CLOTH_W * CLOTH_H / scen.grid.n_vertices), quality=a.quality)

    def replay(sc, truth):
        r = replay_error_mm(s, tr, sc, truth)
        return {k: r[k] for k in ("mean_mm", "before_release_mm", "end_mm")}

    def moved(sc, d):
        hs = [
            Handle(h.vertex, list(h.times), np.asarray(h.positions) + dk, h.release_time)
            for h, dk in zip(sc.handles, d)
        ]
        return Scenario(sc.grid, hs, sc.frame_times, sc.settle_time)

    out = {
        "seed": a.seed,
        "frames": a.frames,
        "quality": a.quality,
        "true_manipulation": replay(scen, tr["positions"]),
        "sigma_mm": a.sigma_mm,
    }
    rng = np.random.default_rng([a.seed, 21])
    draws = []
    for _ in range(a.draws):
        d = rng.normal(0.0, a.sigma_mm / 1000.0, (len(scen.handles), 3))
        r = replay(moved(scen, d), tr["positions"])
        r["clip_error_mm"] = (1000 * np.linalg.norm(d, axis=1)).tolist()
        draws.append(r)
    out["clips_moved"] = draws
    out["clips_moved_mean_mm"] = float(np.mean([r["mean_mm"] for r in draws]))
    if a.e2e:
        with open(os.path.join(a.e2e, "spec.json")) as f:
            spec = json.load(f)
        with open(os.path.join(a.e2e, "scenario.json")) as f:
            meas = Scenario.from_dict(json.load(f)["scenario"])
        board = CB.parse_board(spec["board"])
        pose0 = tuple(np.asarray(v, dtype=np.float64) for v in spec["poses"][0])
        truth_w = np.stack([world_from_scene(board, pose0, x) for x in tr["positions"]])
        clips = [world_from_scene(board, pose0, np.asarray(h.positions[0])[None])[0] for h in scen.handles]
        out["measured_clips"] = replay(meas, truth_w)
        out["measured_clip_error_mm"] = [
            1000 * float(np.linalg.norm(np.asarray(h.positions[0]) - c)) for h, c in zip(meas.handles, clips)
        ]
        true_at = [Handle(h.vertex, [0.0], c[None], h.release_time) for h, c in zip(meas.handles, clips)]
        out["measured_placement_true_clips"] = replay(
            Scenario(meas.grid, true_at, meas.frame_times, meas.settle_time), truth_w
        )
    if a.json:
        with open(a.json, "w") as f:
            json.dump(out, f, indent=1)
    t = out["true_manipulation"]
    print(f"true settings, true clips: {t['mean_mm']:.2f} mm (the model's own floor at quality {a.quality})")
    if a.e2e:
        m = out["measured_clips"]
        print(
            f"true settings, the clips as measured ({', '.join(f'{e:.2f}' for e in out['measured_clip_error_mm'])} mm "
            f"off): {m['mean_mm']:.2f} mm (before the release {m['before_release_mm']:.2f}, last frame {m['end_mm']:.2f})"
        )
        print(
            f"true settings, the measured placement with the true clips: {out['measured_placement_true_clips']['mean_mm']:.2f} mm"
        )
    each = ", ".join(f"{r['mean_mm']:.2f}" for r in draws)
    print(
        f"true settings, clips moved by {a.sigma_mm:g} mm per axis ({a.draws} draws): mean "
        f"{out['clips_moved_mean_mm']:.2f} mm ({each})"
    )
    return out


def _true_clips_capture(e2e: str, truth_w, dest: str) -> str:
    """A copy of an e2e run's capture (the calibrated cameras, the measured placement and release) whose
    clips are put at the true points (``truth_w``: the true cloth at frame 0 in the calibration's frame)."""
    import shutil

    if os.path.isdir(dest):
        shutil.rmtree(dest)
    shutil.copytree(os.path.join(e2e, "capture"), dest)
    path = os.path.join(dest, "capture.json")
    with open(path) as f:
        doc = json.load(f)
    for h in doc["scenario"]["handles"]:
        h["positions"] = [truth_w[h["vertex"]].tolist() for _ in h["positions"]]
    with open(path, "w") as f:
        json.dump(doc, f, indent=1)
    return dest


def run_spread(a) -> dict:
    """The shape goal over fit seeds, on an e2e run's folder (its renders, capture and capture_true; nothing is
    rendered): for each ``--fit-seeds`` seed the three fits of ``e2e`` (told the clips are exact; with the
    capture's uncertain block; given the truth), each replayed under the true manipulation, and the ratios of
    the same seed; which fit the best training error of the seeds would keep. Then where the end-to-end
    fit's error comes from: the TRUE settings scored on the end-to-end capture (the clips as measured), on
    the same capture with the clips put at their true points, and on the capture given the truth."""
    from clothfit.core.physics.scenario import Scenario
    from fit_goals import parse_seeds

    e2e = a.e2e
    asked = a.kinds.split(",")
    if "truth_given" not in asked or not set(asked) <= {"e2e", "uncertain", "truth_given"}:
        raise SystemExit(f"--kinds {a.kinds!r}: a comma list of e2e, uncertain, truth_given, with truth_given")
    for need in ("spec.json", "capture", "capture_true", "fit.json", "scenario.json"):
        if not os.path.exists(os.path.join(e2e, need)):
            raise SystemExit(f"{e2e}: no {need}; run `lab/phone_rig.py e2e --out {e2e}` first")
    with open(os.path.join(e2e, "spec.json")) as f:
        spec = json.load(f)
    seed = int(spec["seed"])
    frames = len(Scenario.from_dict(spec["scenario"]).frame_times)
    tr = cloth_truth(seed, frames)
    board = CB.parse_board(spec["board"])
    pose0 = tuple(np.asarray(v, dtype=np.float64) for v in spec["poses"][0])
    truth_w = world_from_scene(board, pose0, tr["positions"][0])
    work = os.path.join(e2e, "spread" + (f"_{a.optimizer}" if a.optimizer else ""))  # another search: its own files
    os.makedirs(work, exist_ok=True)
    log = os.path.join(work, "commands.log")
    if os.path.exists(log):
        os.remove(log)
    with open(os.path.join(e2e, "scenario.json")) as f:
        meas = Scenario.from_dict(json.load(f)["scenario"])
    clip_mm = [1000 * float(np.linalg.norm(np.asarray(h.positions[0]) - truth_w[h.vertex])) for h in meas.handles]
    # the true settings in a result file the CLI scores (the first fit's, its free settings set to the truth)
    with open(os.path.join(e2e, "fit.json")) as f:
        doc = json.load(f)
    doc["blender_cloth"].update({k: tr["settings"][k] for k in FREE})
    true_params = os.path.join(work, "true_settings.json")
    with open(true_params, "w") as f:
        json.dump(doc, f, indent=1)
    true_clips = _true_clips_capture(e2e, truth_w, os.path.join(work, "capture_true_clips"))
    scored = {}
    for key, cap in (
        ("measured_clips", os.path.join(e2e, "capture")),
        ("true_clips", true_clips),
        ("truth_given", os.path.join(e2e, "capture_true")),
    ):
        r, _ = _cli(["evaluate", cap, "--params", true_params], log, f"evaluate ({key})")
        scored[key] = r["silhouette_error_pct"]
    kinds = [
        k
        for k in (("e2e", "capture", False), ("uncertain", "capture", True), ("truth_given", "capture_true", False))
        if k[0] in asked
    ]
    runs = []
    for fs in parse_seeds(a.fit_seeds):
        fa = argparse.Namespace(evals=a.evals, fit_seed=fs, resolution=None)
        row = {"fit_seed": fs}
        for kind, cap, unc in kinds:
            res = os.path.join(work, f"{kind}_{fs}.json")
            args = _fit_args(os.path.join(e2e, cap), res, fa, unc)
            if unc and a.uncertain:  # the uncertain block's bounds overridden (fit --uncertain)
                args += ["--uncertain", a.uncertain]
            if unc and a.optimizer:  # the uncertain fit's search (fit --optimizer)
                args += ["--optimizer", a.optimizer]
            fit, secs = _cli(args, log, f"fit {kind} (seed {fs})")
            cloth, _ = _cli(["export-blender-cloth", res], log, "export-blender-cloth")
            row[kind] = {
                "E_sil_pct": fit.get("best_E_sil_mean_pct"),
                "settings": {k: cloth["blender_cloth"][k] for k in FREE},
                "replay_mm": replay_error_mm(cloth["blender_cloth"], tr)["mean_mm"],
                "seconds": secs,
            }
        fitted = [k for k, _, _ in kinds if k != "truth_given"]
        for kind in fitted:
            row[f"ratio_{kind}"] = row[kind]["replay_mm"] / row["truth_given"]["replay_mm"]
        runs.append(row)
        print(
            f"seed {fs}: "
            + ", ".join(f"{k} {row[k]['replay_mm']:.2f} mm (ratio {row[f'ratio_{k}']:.2f})" for k in fitted)
            + f", given the truth {row['truth_given']['replay_mm']:.2f} mm",
            flush=True,
        )
    summary = {}
    given = min(runs, key=lambda r: r["truth_given"]["E_sil_pct"])  # the truth-given fit the same rule keeps
    for kind in fitted:
        ratios = [r[f"ratio_{kind}"] for r in runs]
        kept = min(runs, key=lambda r: r[kind]["E_sil_pct"])  # what the best training error of the seeds keeps
        summary[kind] = {
            "ratios": ratios,
            "median_ratio": float(np.median(ratios)),
            "within_2": int(sum(x <= 2.0 for x in ratios)),
            "best_by_training_seed": kept["fit_seed"],
            "best_by_training_ratio": kept[kind]["replay_mm"] / given["truth_given"]["replay_mm"],
        }
    out = {
        "seed": seed,
        "e2e": e2e,
        "evaluations": a.evals,
        "uncertain": a.uncertain,
        "optimizer": a.optimizer,
        "fit_seeds": [r["fit_seed"] for r in runs],
        "clip_error_mm": clip_mm,
        "true_settings_E_sil_pct": scored,
        "runs": runs,
        "summary": summary,
    }
    if a.json:
        with open(a.json, "w") as f:
            json.dump(out, f, indent=1)
    print(
        f"true settings scored: clips as measured ({', '.join(f'{e:.2f}' for e in clip_mm)} mm off) "
        f"{scored['measured_clips']:.2f} %, the same capture with the true clips {scored['true_clips']:.2f} %, "
        f"given the truth {scored['truth_given']:.2f} %"
    )
    for kind, s in summary.items():
        print(
            f"{kind}: ratios {', '.join(f'{x:.2f}' for x in s['ratios'])} (median {s['median_ratio']:.2f}, "
            f"{s['within_2']} of {len(runs)} within 2); the best training error keeps seed "
            f"{s['best_by_training_seed']}: {s['best_by_training_ratio']:.2f}"
        )
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("calibrate", help="render a ChArUco board in front of 4 phones, calibrate, compare")
    c.add_argument("--out", default="out/phone_rig/calib", help="working folder (default: %(default)s)")
    c.add_argument("--seed", type=int, default=0, help="the rig, the lenses, the board poses (default: %(default)s)")
    c.add_argument(
        "--scale",
        type=float,
        default=0.5,
        help="image size as a fraction of a phone's 1080 x 1920 (default: %(default)s)",
    )
    c.add_argument(
        "--poses", type=int, default=24, help="board poses held up after the flat one (default: %(default)s)"
    )
    c.add_argument(
        "--close",
        type=int,
        default=4,
        help="board poses held close before each phone, for its lens (default: %(default)s)",
    )
    c.add_argument("--samples", type=int, default=16, help="Cycles samples per pixel (default: %(default)s)")
    c.add_argument("--no-denoise", action="store_true", help="no OpenImageDenoise pass")
    c.add_argument(
        "--read-noise", type=float, default=2.0, help="sensor read noise [grey levels] (default: %(default)s)"
    )
    c.add_argument(
        "--shot-noise", type=float, default=0.04, help="shot noise variance per grey level (default: %(default)s)"
    )
    c.add_argument("--skip-render", action="store_true", help="reuse the images of a previous run with the same seed")
    c.add_argument(
        "--keep-renders",
        action="store_true",
        help="render only the images a previous run with the same seed did not write",
    )
    c.add_argument("--json", help="write the comparison here")
    e = sub.add_parser(
        "e2e",
        help="render a board, then a cloth hung by clips with one let go; run calibrate, "
        "handles, extract, fit, export-blender-cloth as a user; compare with the same fit "
        "given the truth",
    )
    e.add_argument("--out", default="out/phone_rig/e2e", help="working folder (default: %(default)s)")
    e.add_argument(
        "--seed", type=int, default=0, help="the rig, lenses, board poses, release phase, clicks (default: %(default)s)"
    )
    e.add_argument(
        "--scale",
        type=float,
        default=0.35,
        help="image size as a fraction of a phone's 1080 x 1920 (default: %(default)s)",
    )
    e.add_argument("--cameras", type=int, default=4, help="phones (default: %(default)s)")
    e.add_argument(
        "--poses", type=int, default=12, help="board poses held up after the flat one (default: %(default)s)"
    )
    e.add_argument(
        "--close",
        type=int,
        default=0,
        help="board poses held close before each phone, for its lens (default: %(default)s)",
    )
    e.add_argument("--frames", type=int, default=18, help="frames filmed at 30 fps (default: %(default)s)")
    e.add_argument("--samples", type=int, default=4, help="Cycles samples per pixel (default: %(default)s)")
    e.add_argument("--no-denoise", action="store_true", help="no OpenImageDenoise pass")
    e.add_argument(
        "--read-noise", type=float, default=2.0, help="sensor read noise [grey levels] (default: %(default)s)"
    )
    e.add_argument(
        "--shot-noise", type=float, default=0.04, help="shot noise variance per grey level (default: %(default)s)"
    )
    e.add_argument("--evals", type=int, default=300, help="fit budget, both fits (default: %(default)s)")
    e.add_argument("--fit-seed", type=int, default=0, help="the optimiser's seed, both fits (default: %(default)s)")
    e.add_argument("--resolution", help="fit at HxW [px] (default: the capture's)")
    e.add_argument(
        "--uncertain-evals",
        type=int,
        default=0,
        help="also fit with the capture's uncertain block (time offset and clip offsets estimated with the "
        "cloth) at this budget; 0 = not (default: %(default)s)",
    )
    e.add_argument("--skip-render", action="store_true", help="reuse the images of a previous run with the same seed")
    e.add_argument(
        "--keep-renders",
        action="store_true",
        help="render only the images a previous run with the same seed did not write (an interrupted run)",
    )
    e.add_argument("--verbose", action="store_true", help="show Blender's output")
    e.add_argument("--json", help="write the comparison here")
    sv = sub.add_parser(
        "sensitivity",
        help="the true settings replayed under the clips as measured and under clips moved by a small error: "
        "how far the clips alone move the cloth",
    )
    sv.add_argument("--seed", type=int, default=0, help="the rig's seed (the truth, as e2e) (default: %(default)s)")
    sv.add_argument("--frames", type=int, default=18, help="frames filmed at 30 fps (default: %(default)s)")
    sv.add_argument("--quality", type=int, default=5, help="the fits' Blender quality (default: %(default)s)")
    sv.add_argument("--sigma-mm", type=float, default=1.0, help="clip error per axis [mm] (default: %(default)s)")
    sv.add_argument("--draws", type=int, default=8, help="draws of clip errors (default: %(default)s)")
    sv.add_argument("--e2e", help="an e2e run's folder (same seed): also the clips it measured")
    sv.add_argument("--json", help="write the figures here")
    sp = sub.add_parser(
        "spread",
        help="on an e2e run's folder (nothing rendered): the three fits over several seeds, and the true settings "
        "scored with the clips as measured and at their true points",
    )
    sp.add_argument("--e2e", required=True, help="the e2e run's folder")
    sp.add_argument("--fit-seeds", default="0-4", help="the fits' seeds, e.g. 0-4 or 0,2 (default: %(default)s)")
    sp.add_argument("--evals", type=int, default=2500, help="each fit's budget (default: %(default)s)")
    sp.add_argument(
        "--kinds",
        default="e2e,uncertain,truth_given",
        help="the fits to run, truth_given among them (default: %(default)s)",
    )
    sp.add_argument("--uncertain", help="the uncertain fits' bounds instead of the capture's: fit --uncertain TEXT")
    sp.add_argument("--optimizer", help="the uncertain fits' search: fit --optimizer NAME (default: the fit's)")
    sp.add_argument("--json", help="write the figures here")
    r = sub.add_parser("_render", help="(internal) the child process that renders with bpy")
    r2 = sub.add_parser("_render_e2e", help="(internal) the child process that renders the end-to-end rig")
    r2.add_argument("--spec", required=True)
    r.add_argument("--spec", required=True)
    a = ap.parse_args(argv)
    if a.cmd == "_render":
        render_views(a.spec)
        return 0
    if a.cmd == "_render_e2e":
        render_e2e(a.spec)
        return 0
    if a.cmd == "e2e":
        run_e2e(a)
        return 0
    if a.cmd == "spread":
        run_spread(a)
        return 0
    if a.cmd == "sensitivity":
        run_sensitivity(a)
        return 0
    if a.cmd == "calibrate":
        run_calibrate(a)
        return 0  # the goals met or missed are in the JSON; an error exits non-zero
    return 2


if __name__ == "__main__":
    sys.exit(main())
