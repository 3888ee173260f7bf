"""Photoreal test footage: what a real lab would record, rendered with Blender (bpy module).

The scene: the paper's cloth (10 cm, 16 x 16, our model with the ground-truth parameters, released
corner falling) with a printed-fabric texture, hanging above a textured table in a room with
textured walls, lit by a spot light that casts its shadow on the table and a dim environment.
Rendered by every camera of a rig (default ``lab18``) at a reduced resolution, then, per camera:

* **lens distortion**: Blender renders a pinhole image over a slightly larger canvas (so that the
  distorted image is covered), which is warped with the camera's OpenCV distortion
  (``cv2.undistortPoints`` gives, for every pixel of the distorted image, where to sample the
  pinhole render; bilinear). Each camera gets its own ``k1, k2, p1, p2`` (barrel, like real lenses);
* **sensor noise**: Gaussian read noise plus signal-dependent shot noise, then 8-bit quantisation,
  drawn independently for every image (so two background plates differ by noise only);
* **background plates**: the same scene without the cloth, two plates per camera
  (``background.png``, ``background_2.png``);
* **true masks**: the cloth's triangles projected with the distorted camera and filled at pixel
  centres by the core rasteriser (``raster.silhouette``), and the true vertex positions.

Output (``--out``, the input ``python -m clothfit extract`` reads)::

    footage/footage.json          cameras file, frame times, scenario, cloth mass, render settings
    footage/calibration.yml       the distorted cameras (OpenCV FileStorage)
    footage/colmap/               the same cameras as a COLMAP text model
    footage/cam00/background.png, background_2.png, 000.png, 001.png ...
    footage/truth/masks/cam00/000.png ...   true silhouettes
    footage/truth/shapes.npz      true vertex positions (F, V, 3)

Commands::

    python lab/render_footage.py render --out out/footage            # ~ minutes on 2 cores
    python lab/render_footage.py score --footage out/footage --capture out/footage_capture
    python lab/render_footage.py fit --capture out/footage_capture --footage out/footage

``score`` runs the extraction (automatic threshold) and reports IoU per camera against the true
masks; ``fit`` fits the model on the extracted silhouettes of a few training cameras and reports
the silhouette error on the held-out cameras (against the extracted and the true silhouettes) and
the shape error against the true vertices.

Engine: Cycles on the CPU with few samples and the OpenImageDenoise denoiser (measured in
``docs/footage_measured.md``). Runs under ``python`` with the ``bpy`` module and under
``blender -b --factory-startup -P lab/render_footage.py -- render ...``.
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
from clothfit.core.footage import calib_io  # noqa: E402
from clothfit.core.observation.camera import Camera, load_rig  # noqa: E402
from clothfit.core.observation.raster import silhouette  # noqa: E402
from clothfit.core.physics.paper import Params  # noqa: E402
from clothfit.core.physics.scenario import paper_scenario

DEFAULT_TIMES = [0.1, 0.2, 0.3, 0.4, 0.6, 0.8]
DEFAULT_RES = (240, 320)  # H, W (half of the rig's 480 x 640)
TABLE_Z = -0.09  # table top under the cloth [m]


# ====================================================================== lens & sensor


def lens_distortion(index: int, rng: np.random.Generator) -> np.ndarray:
    """Plausible OpenCV distortion of a small machine-vision lens: barrel k1, small tangential terms."""
    k1 = -0.12 + 0.04 * rng.uniform(-1, 1)
    k2 = 0.05 + 0.02 * rng.uniform(-1, 1)
    p1, p2 = 0.0015 * rng.uniform(-1, 1, 2)
    return np.array([k1, k2, p1, p2, 0.0])


def distortion_maps(cam: Camera, margin: int):
    """For every pixel of the distorted image, where to sample a pinhole render whose canvas is
    the camera's image grown by ``margin`` px on every side (float32 maps for cv2.remap)."""
    import cv2

    H, W = cam.height, cam.width
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    pts = np.stack([xx.ravel(), yy.ravel()], -1).reshape(-1, 1, 2)
    und = cv2.undistortPoints(pts, cam.K, cam.dist, P=cam.K).reshape(H, W, 2)
    return (und[..., 0] + margin).astype(np.float32), (und[..., 1] + margin).astype(np.float32)


def needed_margin(cam: Camera) -> int:
    mx, my = distortion_maps(cam, 0)
    over = max(
        float(-mx.min()), float(-my.min()), float(mx.max() - (cam.width - 1)), float(my.max() - (cam.height - 1)), 0.0
    )
    return int(math.ceil(over)) + 2


def add_sensor_noise(
    img: np.ndarray, rng: np.random.Generator, read_sigma: float = 2.0, shot: float = 0.04
) -> np.ndarray:
    """8-bit image with read noise (sigma ``read_sigma`` levels) and shot noise (variance
    ``shot * level``), quantised."""
    f = img.astype(np.float32)
    sigma = np.sqrt(read_sigma**2 + shot * np.maximum(f, 0))
    return np.clip(np.round(f + rng.normal(0, 1, f.shape).astype(np.float32) * sigma), 0, 255).astype(np.uint8)


# ============================================================================ scene


def _new_material(name):
    import bpy

    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    return mat, mat.node_tree.nodes, mat.node_tree.links


def _fabric_material():
    """A printed fabric: indigo and cream checks with fine noise, rough. The cream is close to the
    table's and the wall's colours on purpose: extraction must not rely on a saturated cloth."""
    mat, nodes, links = _new_material("Footage Fabric")
    bsdf = nodes["Principled BSDF"]
    bsdf.inputs["Roughness"].default_value = 0.8
    tc = nodes.new("ShaderNodeTexCoord")
    mapping = nodes.new("ShaderNodeMapping")
    mapping.inputs["Scale"].default_value = (1.0, 1.0, 1.0)
    links.new(tc.outputs["UV"], mapping.inputs["Vector"])
    chk = nodes.new("ShaderNodeTexChecker")
    chk.inputs["Scale"].default_value = 6.0
    chk.inputs["Color1"].default_value = (0.10, 0.16, 0.35, 1)  # muted indigo
    chk.inputs["Color2"].default_value = (0.70, 0.64, 0.50, 1)  # cream, close to the wall and table
    links.new(mapping.outputs["Vector"], chk.inputs["Vector"])
    noise = nodes.new("ShaderNodeTexNoise")
    noise.inputs["Scale"].default_value = 60.0
    links.new(mapping.outputs["Vector"], noise.inputs["Vector"])
    mix = nodes.new("ShaderNodeMix")
    mix.data_type = "RGBA"
    mix.blend_type = "MULTIPLY"
    mix.inputs["Factor"].default_value = 0.35
    links.new(chk.outputs["Color"], mix.inputs[6])
    links.new(noise.outputs["Color"], mix.inputs[7])
    links.new(mix.outputs[2], bsdf.inputs["Base Color"])
    return mat


def _table_material():
    """Light wood: stretched noise rings."""
    mat, nodes, links = _new_material("Footage Table")
    bsdf = nodes["Principled BSDF"]
    bsdf.inputs["Roughness"].default_value = 0.6
    tc = nodes.new("ShaderNodeTexCoord")
    mapping = nodes.new("ShaderNodeMapping")
    mapping.inputs["Scale"].default_value = (4.0, 40.0, 4.0)
    links.new(tc.outputs["Object"], mapping.inputs["Vector"])
    wave = nodes.new("ShaderNodeTexWave")
    wave.inputs["Scale"].default_value = 2.0
    wave.inputs["Distortion"].default_value = 6.0
    links.new(mapping.outputs["Vector"], wave.inputs["Vector"])
    ramp = nodes.new("ShaderNodeValToRGB")
    ramp.color_ramp.elements[0].color = (0.42, 0.30, 0.18, 1)
    ramp.color_ramp.elements[1].color = (0.62, 0.48, 0.32, 1)
    links.new(wave.outputs["Fac"], ramp.inputs["Fac"])
    links.new(ramp.outputs["Color"], bsdf.inputs["Base Color"])
    return mat


def _wall_material():
    """Pale wallpaper with a blotchy pattern and a few posters' worth of colour."""
    mat, nodes, links = _new_material("Footage Wall")
    bsdf = nodes["Principled BSDF"]
    bsdf.inputs["Roughness"].default_value = 0.9
    tc = nodes.new("ShaderNodeTexCoord")
    noise = nodes.new("ShaderNodeTexNoise")
    noise.inputs["Scale"].default_value = 3.0
    noise.inputs["Detail"].default_value = 8.0
    links.new(tc.outputs["Object"], noise.inputs["Vector"])
    ramp = nodes.new("ShaderNodeValToRGB")
    ramp.color_ramp.elements[0].color = (0.45, 0.50, 0.55, 1)
    ramp.color_ramp.elements[1].color = (0.75, 0.72, 0.62, 1)
    links.new(noise.outputs["Fac"], ramp.inputs["Fac"])
    brick = nodes.new("ShaderNodeTexBrick")
    brick.inputs["Scale"].default_value = 4.0
    brick.inputs["Color1"].default_value = (1, 1, 1, 1)
    brick.inputs["Color2"].default_value = (0.85, 0.85, 0.85, 1)
    brick.inputs["Mortar"].default_value = (0.6, 0.6, 0.6, 1)
    links.new(tc.outputs["Object"], brick.inputs["Vector"])
    mix = nodes.new("ShaderNodeMix")
    mix.data_type = "RGBA"
    mix.blend_type = "MULTIPLY"
    mix.inputs["Factor"].default_value = 1.0
    links.new(ramp.outputs["Color"], mix.inputs[6])
    links.new(brick.outputs["Color"], mix.inputs[7])
    links.new(mix.outputs[2], bsdf.inputs["Base Color"])
    return mat


def empty_scene(engine="CYCLES", samples=8, denoise=True, world_name="Footage World"):
    """A factory-empty scene set to render as the footage is rendered (also lab/phone_rig.py's room): the
    engine (Cycles on the CPU, fixed samples, optional OpenImageDenoise; or Eevee), the Standard view
    transform without dither, 8-bit RGB PNG, a grey world."""
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    if engine == "CYCLES":
        scene.render.engine = "CYCLES"
        scene.cycles.device = "CPU"
        scene.cycles.samples = samples
        scene.cycles.use_adaptive_sampling = False
        scene.cycles.use_denoising = bool(denoise)
        if denoise:
            scene.cycles.denoiser = "OPENIMAGEDENOISE"
        scene.cycles.max_bounces = 3
        scene.cycles.diffuse_bounces = 2
        scene.cycles.glossy_bounces = 1
        scene.cycles.transmission_bounces = 0
        scene.cycles.transparent_max_bounces = 0
        scene.cycles.seed = 0
        scene.render.threads_mode = "AUTO"
    else:
        scene.render.engine = "BLENDER_EEVEE_NEXT"
        scene.eevee.taa_render_samples = samples
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.render.dither_intensity = 0.0
    scene.render.film_transparent = False
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_mode = "RGB"
    scene.render.image_settings.color_depth = "8"
    world = bpy.data.worlds.new(world_name)
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Color"].default_value = (0.30, 0.30, 0.32, 1)
    world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.6
    scene.world = world
    return scene


def build_scene(grid, engine="CYCLES", samples=8, denoise=True):
    """A factory-empty scene with the room, the lights and the cloth mesh (rest shape). Returns
    (scene, cloth object)."""
    import bpy

    scene = empty_scene(engine, samples, denoise)

    # table top and a room around the rig (walls 1.1 m away, floor below the table)
    bpy.ops.mesh.primitive_plane_add(size=1.6, location=(0, 0, TABLE_Z))
    table = bpy.context.object
    table.name = "Table"
    table.data.materials.append(_table_material())
    bpy.ops.mesh.primitive_cylinder_add(
        vertices=48, radius=1.1, depth=2.4, location=(0, 0, 0.3), end_fill_type="NOTHING"
    )
    wall = bpy.context.object
    wall.name = "Walls"
    wall.data.materials.append(_wall_material())
    bpy.ops.mesh.primitive_plane_add(size=2.4, location=(0, 0, 1.5))
    ceiling = bpy.context.object
    ceiling.name = "Ceiling"
    ceiling.data.materials.append(_wall_material())

    # key light: a spot from above and to the side, shadows on the table; a soft fill area light
    spot = bpy.data.lights.new("Key", "SPOT")
    spot.energy = 25.0
    spot.spot_size = math.radians(70)
    spot.shadow_soft_size = 0.03
    spot_obj = bpy.data.objects.new("Key", spot)
    scene.collection.objects.link(spot_obj)
    spot_obj.location = (0.35, -0.25, 0.75)
    _aim(spot_obj, (0.0, 0.0, 0.0))
    fill = bpy.data.lights.new("Fill", "AREA")
    fill.energy = 15.0
    fill.size = 0.8
    fill_obj = bpy.data.objects.new("Fill", fill)
    scene.collection.objects.link(fill_obj)
    fill_obj.location = (-0.6, 0.5, 0.9)
    _aim(fill_obj, (0.0, 0.0, 0.0))

    mesh = bpy.data.meshes.new("Cloth")
    mesh.from_pydata(grid.rest.tolist(), [], grid.triangles.tolist())
    mesh.update()
    uv = mesh.uv_layers.new(name="UVMap")
    u = (grid.rest[:, 0] - grid.rest[:, 0].min()) / grid.side
    v = (grid.rest[:, 1] - grid.rest[:, 1].min()) / grid.side_y
    loop_uv = np.stack([u, v], -1)[np.array([lp.vertex_index for lp in mesh.loops])]
    uv.data.foreach_set("uv", loop_uv.astype(np.float32).ravel())
    for p in mesh.polygons:
        p.use_smooth = True
    cloth = bpy.data.objects.new("Cloth", mesh)
    scene.collection.objects.link(cloth)
    cloth.data.materials.append(_fabric_material())
    return scene, cloth


def _aim(obj, target):
    from mathutils import Vector

    d = Vector(target) - obj.location
    obj.rotation_euler = d.to_track_quat("-Z", "Y").to_euler()


def set_cloth_shape(cloth, positions):
    cloth.data.vertices.foreach_set("co", np.asarray(positions, np.float32).ravel())
    cloth.data.update()


def render_pinhole(scene, cam_obj, cam: Camera, margin: int, path: str) -> np.ndarray:
    """Render ``cam`` (no distortion) on a canvas grown by ``margin`` px; returns uint8 BGR."""
    import cv2
    from clothfit.blender.scene import camera_to_blender

    K = cam.K.copy()
    K[0, 2] += margin
    K[1, 2] += margin
    big = Camera(K, cam.R, cam.t, cam.width + 2 * margin, cam.height + 2 * margin, cam.name)
    camera_to_blender(big, cam_obj, scene)
    scene.camera = cam_obj
    scene.render.filepath = path
    import bpy

    bpy.ops.render.render(write_still=True)
    img = cv2.imread(path, cv2.IMREAD_COLOR)
    if img is None:
        raise ClothFitError(f"Blender did not write the render {path}")
    return img


def distort_image(pinhole: np.ndarray, maps) -> np.ndarray:
    import cv2

    return cv2.remap(pinhole, maps[0], maps[1], interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


# ============================================================================ render


def render_footage(
    out,
    rig=D.DEFAULT_RIG,
    times=None,
    resolution=DEFAULT_RES,
    engine="CYCLES",
    samples=8,
    denoise=True,
    seed=0,
    cameras=None,
    read_sigma=2.0,
    shot=0.04,
    plates=2,
    keep_pinhole=False,
):
    import bpy
    import cv2
    from clothfit.core.observation.silhouette_files import save_silhouette
    from clothfit.core.physics.models import simulate

    times = list(DEFAULT_TIMES if times is None else times)
    rng = np.random.default_rng(seed)
    cams = load_rig(rig)
    cams = [c.resized(int(resolution[0]), int(resolution[1])) for c in cams]
    if cameras:
        cams = [c for c in cams if c.name in set(cameras)]
    cams = [Camera(c.K, c.R, c.t, c.width, c.height, c.name, lens_distortion(i, rng)) for i, c in enumerate(cams)]
    scen = paper_scenario(frame_times=times)
    p = Params.from_dict(D.GT_PARAMS)
    sim = simulate(scen, [p])
    X = sim.positions[0]
    os.makedirs(out, exist_ok=True)
    calib_io.export_cameras(cams, os.path.join(out, "calibration.yml"), "opencv")
    calib_io.export_cameras(cams, os.path.join(out, "colmap"), "colmap")
    scene, cloth = build_scene(scen.grid, engine, samples, denoise)
    cam_data = bpy.data.cameras.new("FootageCam")
    cam_data.sensor_fit = "HORIZONTAL"
    cam_data.sensor_width = 36.0
    cam_obj = bpy.data.objects.new("FootageCam", cam_data)
    scene.collection.objects.link(cam_obj)
    tmp = os.path.join(out, "_render")
    os.makedirs(tmp, exist_ok=True)
    timing = []
    for _ci, cam in enumerate(cams):
        d = os.path.join(out, cam.name)
        os.makedirs(d, exist_ok=True)
        margin = needed_margin(cam)
        maps = distortion_maps(cam, margin)
        cloth.hide_render = True
        t0 = time.time()
        bg = distort_image(render_pinhole(scene, cam_obj, cam, margin, os.path.join(tmp, "bg.png")), maps)
        timing.append(time.time() - t0)
        for k in range(plates):
            name = "background.png" if k == 0 else f"background_{k + 1}.png"
            cv2.imwrite(os.path.join(d, name), add_sensor_noise(bg, rng, read_sigma, shot))
        cloth.hide_render = False
        for fi, _t in enumerate(times):
            set_cloth_shape(cloth, X[fi])
            t0 = time.time()
            pin = render_pinhole(scene, cam_obj, cam, margin, os.path.join(tmp, f"{cam.name}_{fi:03d}.png"))
            timing.append(time.time() - t0)
            img = distort_image(pin, maps)
            cv2.imwrite(os.path.join(d, f"{fi:03d}.png"), add_sensor_noise(img, rng, read_sigma, shot))
            mask = silhouette(cam, X[fi], scen.grid.triangles)
            save_silhouette(os.path.join(out, "truth", "masks", cam.name, f"{fi:03d}.png"), mask)
            if not keep_pinhole:
                os.remove(os.path.join(tmp, f"{cam.name}_{fi:03d}.png"))
        print(
            f"[render] {cam.name}: {1 + len(times)} renders, mean {np.mean(timing[-(1 + len(times)) :]):.2f} s",
            flush=True,
        )
    set_cloth_shape(cloth, scen.grid.rest)
    np.savez_compressed(os.path.join(out, "truth", "shapes.npz"), positions=X, frame_times=np.array(times))
    try:
        os.remove(os.path.join(tmp, "bg.png"))
        if not keep_pinhole:
            os.rmdir(tmp)
    except OSError:
        pass
    info = {
        "cameras": "calibration.yml",
        "frame_times": times,
        "scenario": scen.to_dict(),
        "cloth_mass": p.m * scen.grid.n_vertices,
        "meta": {
            "generator": "lab/render_footage.py",
            "true_params": p.as_dict(),
            "rig": rig,
            "resolution": list(resolution),
            "engine": engine,
            "samples": samples,
            "denoise": denoise,
            "sensor_noise": {"read_sigma": read_sigma, "shot": shot},
            "seed": seed,
            "background_plates": plates,
            "seconds_per_render": float(np.mean(timing)),
            "truth": {"masks": "truth/masks/{camera}/{frame:03d}.png", "shapes": "truth/shapes.npz"},
        },
    }
    with open(os.path.join(out, "footage.json"), "w") as f:
        json.dump(info, f, indent=1)
    return info


# ============================================================================= score


def single_plate_view(footage, tmp):
    """A view of ``footage`` (symlinks) with only the first background plate per camera."""
    os.makedirs(tmp, exist_ok=True)
    for entry in os.listdir(footage):
        src = os.path.join(footage, entry)
        dst = os.path.join(tmp, entry)
        if os.path.lexists(dst):
            continue
        if os.path.isdir(src) and entry.startswith("cam"):
            os.makedirs(dst, exist_ok=True)
            for f in os.listdir(src):
                if not f.startswith("background_"):
                    os.symlink(os.path.abspath(os.path.join(src, f)), os.path.join(dst, f))
        else:
            os.symlink(os.path.abspath(src), dst)
    return tmp


def score(footage, capture_dir, single_plate=False, **extract_kw):
    """Extract ``footage`` into ``capture_dir`` and compare with the true masks: IoU per camera."""
    import tempfile

    from clothfit.core.footage.extract import extract_capture
    from clothfit.core.observation.capture import load_capture
    from clothfit.core.observation.silhouette_files import read_silhouette

    t0 = time.time()
    src = single_plate_view(footage, tempfile.mkdtemp(prefix="footage_1plate_")) if single_plate else footage
    rep = extract_capture(src, capture_dir, **extract_kw)
    secs = time.time() - t0
    cap = load_capture(capture_dir)
    rows = []
    for ci, cam in enumerate(cap.cameras):
        inter = union = xor = area = 0
        for fi in range(cap.n_frames):
            m = cap.load_silhouette(ci, fi, allow_empty=True)
            t = read_silhouette(os.path.join(footage, "truth", "masks", cam.name, f"{fi:03d}.png"))
            inter += int((m & t).sum())
            union += int((m | t).sum())
            xor += int((m ^ t).sum())
            area += int(t.sum())
        r = rep["cameras"][cam.name]
        rows.append(
            {
                "camera": cam.name,
                "iou": inter / max(union, 1),
                "e_sil_pct": 100.0 * xor / max(area, 1),
                "threshold": r["threshold"],
                "otsu": r["otsu"],
                "noise": r["noise"],
            }
        )
    out = {
        "rows": rows,
        "mean_iou": float(np.mean([r["iou"] for r in rows])),
        "min_iou": float(np.min([r["iou"] for r in rows])),
        "mean_e_sil_pct": float(np.mean([r["e_sil_pct"] for r in rows])),
        "extract_seconds": secs,
        "warnings": rep["warnings"],
        "options": rep["options"],
    }
    return out


def format_score(s):
    lines = ["| camera | IoU | E_sil vs truth [%] | threshold | Otsu | noise |", "|---|---|---|---|---|---|"]
    for r in s["rows"]:
        lines.append(
            f"| {r['camera']} | {r['iou']:.4f} | {r['e_sil_pct']:.2f} | {r['threshold']:.2f} | "
            f"{r['otsu']:.2f} | {r['noise']:.2f} |"
        )
    lines.append(f"| **mean** | **{s['mean_iou']:.4f}** | **{s['mean_e_sil_pct']:.2f}** | | | |")
    return "\n".join(lines)


# =============================================================================== fit


def fit_footage(capture_dir, footage, n_train=(4,), evals=1500, seed=0, optimizer="spx-mgg", train_times=None):
    """Fit on ``n`` training cameras' extracted silhouettes; score on the held-out cameras."""
    from clothfit.core.fitting.evaluate import evaluate
    from clothfit.core.fitting.job import FitConfig, FitJob
    from clothfit.core.observation.camera import select_training
    from clothfit.core.observation.capture import load_capture, read_shapes, write_capture
    from clothfit.core.observation.silhouette_files import read_silhouette
    from clothfit.core.physics.paper import identifiable, identifiable_errors

    cap = load_capture(capture_dir)
    truth_dir = os.path.join(os.path.dirname(os.path.abspath(capture_dir)), os.path.basename(capture_dir) + "_truth")
    shapes = read_shapes(os.path.join(footage, "truth", "shapes.npz"), cap.frame_times, cap.scenario.grid.n_vertices)
    masks = [
        [read_silhouette(os.path.join(footage, "truth", "masks", c.name, f"{f:03d}.png")) for f in range(cap.n_frames)]
        for c in cap.cameras
    ]
    truth = write_capture(
        truth_dir,
        cap.cameras,
        cap.scenario,
        masks,
        shapes=shapes,
        cloth_mass=cap.cloth_mass,
        meta={"generator": "true masks of " + os.path.abspath(footage)},
    )
    with open(os.path.join(footage, "footage.json")) as f:
        gt = json.load(f)["meta"]["true_params"]
    times = list(cap.frame_times) if train_times is None else train_times
    rows = []
    for n in n_train:
        train, held = select_training(cap.cameras, n)
        t0 = time.time()
        job = FitJob(
            cap,
            FitConfig(train_cameras=train, train_times=times, optimizer=optimizer, seed=seed, max_evaluations=evals),
        )
        res = job.run()
        ev_obs = evaluate(cap, res["params"], cameras=held)
        ev_true = evaluate(truth, res["params"], cameras=held)
        ev_gt = evaluate(cap, gt, cameras=held)
        rows.append(
            {
                "cameras": n,
                "heldout_sil_err_vs_extracted_pct": ev_obs["silhouette_error_pct"],
                "heldout_sil_err_vs_true_pct": ev_true["silhouette_error_pct"],
                "shape_error_mm": ev_true["shape_error_mm"],
                "gt_params_heldout_sil_err_vs_extracted_pct": ev_gt["silhouette_error_pct"],
                "params": res["params"],
                "identifiable": identifiable(res["params"]),
                "identifiable_error_pct": identifiable_errors(res["params"], gt),
                "evaluations": res["evaluations"],
                "seconds": time.time() - t0,
                "train": [cap.cameras[c].name for c in train],
            }
        )
        print(json.dumps(rows[-1], indent=1), flush=True)
    return rows


# ============================================================================== main


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("render", help="render photoreal footage")
    r.add_argument("--out", required=True)
    r.add_argument("--rig", default=D.DEFAULT_RIG)
    r.add_argument("--times", default=",".join(str(t) for t in DEFAULT_TIMES))
    r.add_argument("--resolution", default=f"{DEFAULT_RES[0]}x{DEFAULT_RES[1]}", help="HxW")
    r.add_argument("--engine", default="CYCLES", choices=["CYCLES", "EEVEE"])
    r.add_argument("--samples", type=int, default=8)
    r.add_argument("--no-denoise", action="store_true")
    r.add_argument("--camera", action="append", help="render only this camera (repeatable)")
    r.add_argument("--seed", type=int, default=0)
    r.add_argument("--read-noise", type=float, default=2.0)
    r.add_argument("--shot-noise", type=float, default=0.04)
    s = sub.add_parser("score", help="extract and compare with the true masks")
    s.add_argument("--footage", required=True)
    s.add_argument("--capture", required=True)
    s.add_argument("--threshold", default="auto")
    s.add_argument("--luma-weight", type=float)
    s.add_argument("--shadow-min", type=float)
    s.add_argument("--blur", type=float)
    s.add_argument("--refine", type=int, help="boundary refinement radius (0 = off)")
    s.add_argument("--shadow-window", type=int)
    s.add_argument("--single-plate", action="store_true", help="use only the first background plate")
    s.add_argument("--json", help="write the scores here")
    f = sub.add_parser("fit", help="fit on extracted silhouettes, score held-out cameras")
    f.add_argument("--capture", required=True)
    f.add_argument("--footage", required=True)
    f.add_argument("--cameras", default="4", help="numbers of training cameras, comma separated")
    f.add_argument("--evals", type=int, default=1500)
    f.add_argument("--seed", type=int, default=0)
    f.add_argument("--json", help="write the rows here")
    a = ap.parse_args(script_argv(argv))
    try:
        if a.cmd == "render":
            h, w = (int(v) for v in a.resolution.lower().split("x"))
            t0 = time.time()
            info = render_footage(
                a.out,
                a.rig,
                [float(t) for t in a.times.split(",")],
                (h, w),
                "CYCLES" if a.engine == "CYCLES" else "EEVEE",
                a.samples,
                not a.no_denoise,
                a.seed,
                a.camera,
                a.read_noise,
                a.shot_noise,
            )
            print(
                f"rendered {a.out} in {time.time() - t0:.0f} s ({info['meta']['seconds_per_render']:.2f} s per render)"
            )
        elif a.cmd == "score":
            kw = {
                k: v
                for k, v in (
                    ("threshold", a.threshold),
                    ("luma_weight", a.luma_weight),
                    ("shadow_min", a.shadow_min),
                    ("blur", a.blur),
                    ("refine_radius", a.refine),
                    ("shadow_window", a.shadow_window),
                )
                if v is not None
            }
            sc = score(a.footage, a.capture, a.single_plate, **kw)
            print(format_score(sc))
            for wmsg in sc["warnings"]:
                print("warning:", wmsg)
            if a.json:
                with open(a.json, "w") as fh:
                    json.dump(sc, fh, indent=1)
        else:
            rows = fit_footage(a.capture, a.footage, [int(v) for v in a.cameras.split(",")], a.evals, a.seed)
            if a.json:
                with open(a.json, "w") as fh:
                    json.dump(rows, fh, indent=1)
    except ClothFitError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
