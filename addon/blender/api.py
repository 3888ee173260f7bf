# SPDX-License-Identifier: GPL-3.0-or-later
"""Scripting facade of the Blender layer: what the operators call, usable from any script.

Every function takes the scene (its ``scene.clothfit`` properties hold the settings) and raises
``ClothFitError`` on bad input; the operators turn that into a report. Typical pipeline::

    from addon.blender import api            # or bl_ext.<repo>.silhouette_cloth_fit.addon.blender
    api.build_rig(scene); api.build_cloth(scene); api.simulate(scene)
    cap = api.render_silhouettes(scene, "out/capture")
    result = api.run_fit(scene); api.apply_fit(scene); api.make_overlays(scene)
"""
from __future__ import annotations

import contextlib
import json
import math
import os
import time

import bpy
import numpy as np

from ..core import defaults as D
from ..core.errors import ClothFitError
from ..core.observation.camera import load_rig, ring_rig, select_training
from ..core.physics.paper import Params
from ..core.physics.scenario import ClothGrid, Handle, Scenario, paper_scenario
from . import render as R
from . import scene as S

RESULT_JSON = "fit_result.json"
RESULT_JSON_BLENDER = "fit_result_blender.json"   # a Blender-cloth fit keeps the paper fit's result
OVERLAY_DIR = "overlays"


def props(scene):
    p = getattr(scene, "clothfit", None)
    if p is None:
        raise ClothFitError("Cloth Fit is not registered (scene.clothfit is missing)")
    return p


# ==================================================================== helpers

def parse_times(spec: str):
    """``"start:stop:step"`` (stop included) or ``"t1, t2, ..."`` -> sorted list of seconds."""
    s = (spec or "").strip()
    if not s:
        raise ClothFitError("frame times are empty: give start:stop:step or a comma list")
    try:
        if ":" in s:
            parts = [float(x) for x in s.split(":")]
            if len(parts) != 3:
                raise ValueError("need start:stop:step")
            a, b, st = parts
            if st <= 0 or b < a:
                raise ValueError("step must be > 0 and stop >= start")
            n = int(math.floor((b - a) / st + 1e-6)) + 1
            if n > 100000:
                raise ValueError("too many frames")
            t = [round(a + i * st, 9) for i in range(n)]
        else:
            t = [float(x) for x in s.replace(";", ",").split(",") if x.strip()]
    except ValueError as e:
        raise ClothFitError(f"frame times {spec!r}: {e}") from None
    t = sorted(set(t))
    if not t or t[0] < 0 or not all(math.isfinite(x) for x in t):
        raise ClothFitError(f"frame times {spec!r} must be finite and >= 0")
    return t


def abspath(path: str, what: str) -> str:
    if not path:
        raise ClothFitError(f"no {what} given")
    if path.startswith("//") and not bpy.data.filepath:
        raise ClothFitError(f"{what} {path!r} is relative to the .blend file, which is not saved yet: "
                            f"save the file or give an absolute path")
    return os.path.normpath(bpy.path.abspath(path))


def capture_dir(scene) -> str:
    return abspath(props(scene).capture_dir, "capture directory")


def params_from_scene(scene) -> Params:
    p = props(scene)
    par = Params(p.m, p.k, p.l, p.d)
    par.check("scene parameters")
    return par


def params_to_scene(scene, params):
    p = props(scene)
    d = params.as_dict() if hasattr(params, "as_dict") else dict(params)
    p.m, p.k, p.l, p.d = d["m"], d["k"], d["l"], d["d"]


# ======================================================================== rig

def rig_from_props(scene):
    p = props(scene)
    if p.rig_source == "PRESET":
        return load_rig(bpy.path.abspath(p.rig_preset) if p.rig_preset.startswith("//") else p.rig_preset)
    return ring_rig(n_per_ring=(p.ring_cameras,), elevations_deg=(p.ring_elevation,), distance=p.ring_distance,
                    target=(0.0, 0.0, p.ring_target_z), width=p.ring_width, height=p.ring_height, fx=p.ring_fx,
                    azimuth_offsets_deg=(0.0,))


def build_rig(scene, cameras=None):
    """Cameras (core ``Camera`` list, default: the rig the properties describe) into the scene."""
    return set_rig(scene, cameras if cameras is not None else rig_from_props(scene))[0]


def rig_cameras(scene):
    return S.rig_cameras(scene)


# ------------------------------------------------------- exact (imported) cameras

PAR_APPROX_LIMIT = 0.01      # fx/fy ratios of one rig may differ this much (relative) and still be shown
EXACT_MATCH_TOL = {"K": 1e-3, "R": 1e-5, "C": 1e-5}   # px, -, m: a Blender camera still shows its exact one


def cameras_to_json(cameras) -> str:
    """Exact JSON of cameras (float64 repr); all-zero distortion is left out."""
    out = []
    for c in cameras:
        d = c.to_dict()
        if not np.any(c.dist != 0):
            d.pop("dist", None)
        out.append(d)
    return json.dumps(out)


def cameras_from_json(text, where="scene.clothfit.rig_cameras_json"):
    from ..core.observation.camera import Camera
    try:
        data = json.loads(text)
    except ValueError as e:
        raise ClothFitError(f"{where}: not valid JSON ({e})") from None
    if not isinstance(data, list):
        raise ClothFitError(f"{where}: expected a list of cameras")
    return [Camera.from_dict(d, where) for d in data]


def blender_view_cameras(cameras):
    """The cameras as one Blender scene can show them, and notes.

    One image size per scene: cameras of different sizes are an error naming the camera. One
    pixel aspect per scene: real calibrations have slightly different fx/fy per camera; up to
    ``PAR_APPROX_LIMIT`` apart the Blender cameras use the median fx/fy (fx kept, fy adjusted;
    a note says by how much), beyond it an error names the camera. Lens distortion cannot be
    shown by a Blender camera (a note; the exact cameras are kept in ``rig_cameras_json``)."""
    from ..core.observation.camera import Camera
    cameras = list(cameras)
    if not cameras:
        raise ClothFitError("the rig has no camera")
    notes = []
    pars = np.array([c.K[0, 0] / c.K[1, 1] for c in cameras])
    if pars.max() / pars.min() - 1.0 > 1e-9:
        par = float(np.median(pars))
        worst = int(np.argmax(np.abs(pars / par - 1.0)))
        off = abs(pars[worst] / par - 1.0)
        if off > PAR_APPROX_LIMIT:
            raise ClothFitError(
                f"camera '{cameras[worst].name}' has fx/fy = {pars[worst]:.6g}, {100 * off:.2f} % "
                f"away from the rig's median {par:.6g}: Blender has one pixel aspect per scene, so the cameras of a "
                f"rig must share fx/fy (within {100 * PAR_APPROX_LIMIT:g} % they are shown approximately)")
        shown, off = [], 0.0
        for c in cameras:
            K = c.K.copy()
            K[1, 1] = K[0, 0] / par
            off = max(off, abs(K[1, 1] - c.K[1, 1]))
            shown.append(Camera(K, c.R, c.t, c.width, c.height, c.name))
        notes.append(f"the cameras' fx/fy differ ({pars.min():.6g} to {pars.max():.6g}) but Blender has one pixel "
                     f"aspect per scene: the Blender cameras use fx/fy = {par:.6g} (fy off by up to {off:.3g} px); "
                     f"export keeps the exact cameras")
    else:
        shown = [Camera(c.K, c.R, c.t, c.width, c.height, c.name) for c in cameras]
    distorted = [c.name for c in cameras if c.dist.size and np.any(c.dist != 0)]
    if distorted:
        notes.append(f"{len(distorted)} camera(s) have lens distortion ({', '.join(distorted[:4])}"
                     f"{', ...' if len(distorted) > 4 else ''}): Blender shows the undistorted pinhole view; "
                     f"the exact cameras (with distortion) are kept for export and fitting")
    S.check_rig(shown)
    return shown, notes


def set_rig(scene, cameras):
    """Build the rig from ``cameras`` and keep them exactly in ``rig_cameras_json``.
    Returns (camera objects, notes)."""
    cameras = list(cameras)
    shown, notes = blender_view_cameras(cameras)
    objs = S.build_rig(scene, shown)
    props(scene).rig_cameras_json = cameras_to_json(cameras)
    return objs, notes


def _same_view(a, b):
    tol = EXACT_MATCH_TOL
    return ((a.width, a.height) == (b.width, b.height) and np.abs(a.K - b.K).max() <= tol["K"]
            and np.abs(a.R - b.R).max() <= tol["R"] and np.abs(a.center - b.center).max() <= tol["C"])


def exact_rig_cameras(scene):
    """Per rig camera (rig order): ``(blender, exact, shown)``.

    ``blender``: the camera as Blender renders it now (float32 settings); ``exact``: the imported
    or loaded camera (float64, lens distortion) when the Blender camera still shows it (not moved,
    not re-aimed: within ``EXACT_MATCH_TOL``), else None; ``shown``: float64 pinhole that Blender
    shows for it (``exact`` without distortion, fy adjusted to the scene's pixel aspect), or None."""
    p = props(scene)
    objs = S.rig_objects(scene)
    dg = bpy.context.evaluated_depsgraph_get()
    now = [S.camera_from_blender(o, scene, depsgraph=dg) for o in objs]
    stored = []
    if p.rig_cameras_json.strip():
        try:
            stored = cameras_from_json(p.rig_cameras_json)
            shown, _ = blender_view_cameras(stored)
        except ClothFitError:
            stored, shown = [], []
    byname = {c.name: (c, v) for c, v in zip(stored, shown)}
    out = []
    for o, b in zip(objs, now):
        ex, sh = byname.get(o.name, (None, None))
        if ex is not None and _same_view(b, sh):
            out.append((b, ex, sh))
        else:
            out.append((b, None, None))
    return out


def import_cameras(scene, path=None):
    """Calibrated cameras (OpenCV FileStorage YAML/JSON/XML file or folder, COLMAP text model,
    our cameras JSON) -> the rig. Returns (cameras, notes)."""
    from ..core.footage import calib_io
    p = props(scene)
    src = abspath(path if path else p.cameras_file, "camera file")
    cams = calib_io.import_cameras(src)
    _, notes = set_rig(scene, cams)
    if path:
        p.cameras_file = path
    return cams, notes


EXPORT_FORMATS = {"OPENCV": "opencv", "OPENCV_DIR": "opencv-dir", "COLMAP": "colmap", "JSON": "json"}


def _refuse_capture_files(dst, fmt):
    """A camera export must not replace a capture's own cameras.json / capture.json (the capture's
    silhouettes belong to those cameras)."""
    from ..core.observation.capture import CAMERAS_JSON, CAPTURE_JSON
    if fmt in ("OPENCV", "JSON"):
        folder, names = os.path.dirname(dst), [os.path.basename(dst)]
    else:
        folder, names = dst, []
    if not os.path.isfile(os.path.join(folder, CAPTURE_JSON)):
        return
    cap_files = {CAMERAS_JSON, CAPTURE_JSON}
    try:
        with open(os.path.join(folder, CAPTURE_JSON)) as f:
            ref = json.load(f).get("cameras")
        if isinstance(ref, str):
            cap_files.add(os.path.basename(ref))
    except (OSError, ValueError, AttributeError):
        pass
    hit = [n for n in names if n in cap_files]
    if hit:
        raise ClothFitError(f"camera export path {dst} is the camera file of the capture in {folder}: exporting "
                            f"there would replace the cameras its silhouettes were taken with; choose another path")


def export_cameras(scene, path=None, fmt=None):
    """The rig's cameras -> an OpenCV file/folder, a COLMAP model or our JSON. Cameras that
    still show their imported/loaded camera are written exactly (float64, distortion); moved
    ones as Blender shows them. Returns (path, cameras, names of cameras written from Blender)."""
    from ..core.footage import calib_io
    p = props(scene)
    fmt = fmt or p.cameras_export_format
    if fmt not in EXPORT_FORMATS:
        raise ClothFitError(f"camera export format {fmt!r} unknown ({', '.join(EXPORT_FORMATS)})")
    dst = abspath(path if path else p.cameras_export_path, "camera export path")
    if fmt in ("OPENCV", "JSON"):
        ext = os.path.splitext(dst)[1].lower()
        if os.path.isdir(dst) or not ext:
            dst = os.path.join(dst, "cameras.json" if fmt == "JSON" else "calibration.yml")
        elif fmt == "JSON" and ext != ".json":
            raise ClothFitError(f"camera export path {dst}: a Cloth Fit cameras JSON must end with .json")
    elif os.path.isfile(dst):
        raise ClothFitError(f"camera export path {dst} is a file: the {fmt} format writes a folder")
    _refuse_capture_files(dst, fmt)
    rows = exact_rig_cameras(scene)
    cams = [ex if ex is not None else b for b, ex, _ in rows]
    from_blender = [b.name for b, ex, _ in rows if ex is None]
    os.makedirs(os.path.dirname(dst) if fmt in ("OPENCV", "JSON") else dst, exist_ok=True)
    calib_io.export_cameras(cams, dst, EXPORT_FORMATS[fmt])
    if path:
        p.cameras_export_path = path
    return dst, cams, from_blender


# ====================================================================== cloth

def grid_from_props(scene) -> ClothGrid:
    p = props(scene)
    return ClothGrid(p.cloth_nx, side=p.cloth_side, height=p.cloth_height)


def capture_scenario(scene):
    """The loaded capture's scenario (handles, settling), for scenario source CAPTURE."""
    from ..core.observation.capture import load_capture as core_load
    return core_load(capture_dir(scene)).scenario


def scenario_for(scene, grid: ClothGrid, times=None):
    """The manipulation to simulate: the paper's (panel settings), the loaded capture's, or the
    linked empties' (``scenario_source`` SETTINGS / CAPTURE / EMPTIES)."""
    p = props(scene)
    times = times if times is not None else parse_times(p.frame_times)
    if p.scenario_source == "CAPTURE":
        sc = capture_scenario(scene)
        g = sc.grid
        if (g.nx, g.ny) != (grid.nx, grid.ny):
            raise ClothFitError(f"the capture's cloth is a {g.nx}x{g.ny} grid but the scene's cloth is "
                                f"{grid.nx}x{grid.ny}: rebuild the cloth")
        return sc.with_frames(times)
    if p.scenario_source == "EMPTIES":
        return empties_scenario(scene, grid, times)
    if not 0 <= p.released_corner <= 3:
        raise ClothFitError(f"released corner {p.released_corner} must be 0..3")
    sc = paper_scenario(grid, frame_times=times, released_corner=p.released_corner)
    sc.settle_time = float(p.settle_time)
    return sc


def build_cloth(scene):
    p = props(scene)
    grid = capture_scenario(scene).grid if p.scenario_source == "CAPTURE" else grid_from_props(scene)
    if p.scenario_source == "EMPTIES":  # vertex groups only: no need to sample (or validate) the empties yet
        handles = [Handle(v, [0.0], grid.rest[v][None], link.release_time if link.use_release else None)
                   for link, v in ((lk, lk.row * grid.nx + lk.column) for lk in p.handles)
                   if link.row < grid.ny and link.column < grid.nx]
    else:
        handles = scenario_for(scene, grid).handles
    obj = S.build_cloth(scene, grid, handles)
    p.cloth_object = obj
    return obj


def cloth_object(scene):
    """The cloth object, checked against the grid it was built from (missing / edited = error)."""
    p = props(scene)
    obj = p.cloth_object
    if obj is None or obj.name not in bpy.data.objects or obj.users == 0:
        obj = bpy.data.objects.get(S.CLOTH_NAME)
    if obj is None:
        raise ClothFitError("the cloth object is missing: build the cloth first")
    S.check_cloth(obj)
    return obj


def scene_scenario(scene, times=None):
    obj = cloth_object(scene)
    return scenario_for(scene, S.grid_from_object(obj), times), obj


# ============================================================ handles from empties

HANDLE_COLLECTION = "ClothFit Handles"


def scene_grid(scene) -> ClothGrid:
    """The grid of the built cloth, else the one the cloth settings describe."""
    try:
        return S.grid_from_object(cloth_object(scene))
    except ClothFitError:
        return grid_from_props(scene)


def handle_links(scene, grid: ClothGrid):
    """The Empties manipulation's links, checked: [(link, vertex index)]. Errors name the link."""
    p = props(scene)
    if not len(p.handles):
        raise ClothFitError("the manipulation source is Empties but no handle is linked: add a handle empty "
                            "(or link an empty to a grid vertex)")
    out, seen = [], {}
    for i, link in enumerate(p.handles):
        obj = link.empty
        name = f"handle #{i + 1}"
        if obj is None:
            raise ClothFitError(f"{name} (row {link.row}, column {link.column}) has no empty: pick one or remove the "
                                f"handle")
        name += f" ('{obj.name}')"
        if obj.name not in scene.objects:
            raise ClothFitError(f"{name}: the empty is not in the scene (deleted?): link another one or remove "
                                f"the handle")
        if obj.type != "EMPTY":
            raise ClothFitError(f"{name}: '{obj.name}' is a {obj.type}, not an empty")
        if not (0 <= link.row < grid.ny and 0 <= link.column < grid.nx):
            raise ClothFitError(f"{name}: vertex row {link.row}, column {link.column} is outside the {grid.nx}x"
                                f"{grid.ny} cloth grid (rows 0..{grid.ny - 1}, columns 0..{grid.nx - 1})")
        v = link.row * grid.nx + link.column
        if v in seen:
            raise ClothFitError(f"{name}: vertex row {link.row}, column {link.column} is already linked by "
                                f"{seen[v]}: one handle per vertex")
        seen[v] = name
        if link.use_release and not math.isfinite(link.release_time):
            raise ClothFitError(f"{name}: release time {link.release_time} is not finite")
        out.append((link, v))
    return out


def empties_scenario(scene, grid: ClothGrid, times, notes=None):
    """The Empties manipulation: one ``Handle`` per link whose trajectory is its empty's evaluated
    world position at every scene frame from the start of settling (t = -settle) to the last
    capture time (frames -> seconds with the scene's frame rate, frame_start = t = 0, as the bake
    keys it; keys that linear interpolation reproduces within 0.1 um are dropped). First the frame
    rate is set as the bake will set it (every capture time a whole frame), so the empties'
    keyframes are read at the rate the timeline then plays; ``notes`` gets a line if it changed."""
    p = props(scene)
    times = sorted(float(t) for t in times)
    links = handle_links(scene, grid)
    settle = float(p.settle_time)
    old = S.ensure_fps(scene, sorted(set([0.0] + times)))
    if old is not None and notes is not None:
        notes.append(f"frame rate changed from {old:g} to {scene.render.fps} fps so that every capture time is a "
                     f"whole frame: the empties' keyframes are read at {scene.render.fps} fps")
    rate = scene.render.fps / scene.render.fps_base
    f0 = scene.frame_start - int(math.ceil(settle * rate - 1e-6))   # settle is float32
    f1 = S.frame_of_time(scene, times[-1])
    frames = np.arange(f0, f1 + 1)
    pos = S.sample_world_positions(scene, [link.empty for link, _ in links], frames)
    ts = S.time_of_frame(scene, frames)
    handles = []
    for (link, v), P in zip(links, pos):
        kt, kp = S.simplify_track(ts, P)
        handles.append(Handle(v, kt, kp, float(link.release_time) if link.use_release else None))
    return Scenario(grid, handles, times, settle_time=settle)


def add_handle_empty(scene, row=None, column=None):
    """A new empty at grid vertex (row, column)'s rest position, linked to it; the manipulation
    source becomes Empties. Returns the link."""
    p = props(scene)
    row = p.new_handle_row if row is None or row < 0 else int(row)
    column = p.new_handle_column if column is None or column < 0 else int(column)
    grid = scene_grid(scene)
    if not (0 <= row < grid.ny and 0 <= column < grid.nx):
        raise ClothFitError(f"vertex row {row}, column {column} is outside the {grid.nx}x{grid.ny} cloth grid "
                            f"(rows 0..{grid.ny - 1}, columns 0..{grid.nx - 1})")
    v = row * grid.nx + column
    for i, link in enumerate(p.handles):
        if (link.row, link.column) == (row, column):
            raise ClothFitError(f"vertex row {row}, column {column} is already linked by handle #{i + 1}")
    coll = S.ensure_collection(scene, HANDLE_COLLECTION)
    obj = bpy.data.objects.new(f"ClothFit Handle r{row} c{column}", None)
    obj.empty_display_type = "SPHERE"
    obj.empty_display_size = max(grid.spacing, 1e-3)
    obj.location = [float(x) for x in grid.rest[v]]
    coll.objects.link(obj)
    link = p.handles.add()
    link.empty, link.row, link.column = obj, row, column
    p.handles_index = len(p.handles) - 1
    p.scenario_source = "EMPTIES"
    return link


def remove_handle(scene, index=None, delete_empty=False):
    """Remove handle link ``index`` (default: the active one); optionally delete its empty."""
    p = props(scene)
    i = p.handles_index if index is None or index < 0 else int(index)
    if not 0 <= i < len(p.handles):
        raise ClothFitError(f"no handle #{i + 1} to remove ({len(p.handles)} handles)")
    obj = p.handles[i].empty
    p.handles.remove(i)
    p.handles_index = max(0, min(p.handles_index, len(p.handles) - 1))
    if delete_empty and obj is not None:
        bpy.data.objects.remove(obj, do_unlink=True)


# ================================================================= simulation

def simulate(scene):
    """Simulate the scene's parameters and bake: one shape key per capture time plus t = 0."""
    from ..core.physics.models import simulate as core_simulate
    times = parse_times(props(scene).frame_times)
    bake_times = sorted(set([0.0] + times))
    notes = []
    obj = cloth_object(scene)
    grid = S.grid_from_object(obj)
    if props(scene).scenario_source == "EMPTIES":
        sc = empties_scenario(scene, grid, bake_times, notes)
    else:
        sc = scenario_for(scene, grid, bake_times)
    par = params_from_scene(scene)
    t0 = time.time()
    res = core_simulate(sc, [par])
    if res.exploded[0]:
        raise ClothFitError(f"the simulation with m={par.m:g}, k={par.k:g}, l={par.l:g}, d={par.d:g} is unstable: "
                            f"{res.reason[0]}")
    frames = S.bake_shape_keys(scene, obj, bake_times, res.positions[0])
    scene.frame_set(frames[0])
    return {"frames": frames, "times": bake_times, "seconds": time.time() - t0, "notes": notes, "scenario": sc}


# ============================================================ observations

def render_silhouettes(scene, out_dir=None, noise=None, seed=None, progress=None, engine=None):
    """Blender renders the cloth's silhouette from every rig camera at every capture time and
    writes a capture directory (core format). Returns the ``Capture``. ``engine``: WORKBENCH or
    EEVEE (default: the scene's setting). Objects of the collection ``Occluders`` hide the cloth
    (holdouts) and are written as the capture's ignore masks."""
    from ..core.observation.capture import finalize_capture, save_silhouette, write_capture
    from ..core.observation.metrics import add_boundary_noise
    from ..core.observation.synth import noise_rng
    p = props(scene)
    root = abspath(out_dir, "capture directory") if out_dir else capture_dir(scene)
    noise = p.noise if noise is None else float(noise)
    seed = p.noise_seed if seed is None else int(seed)
    objs = S.rig_objects(scene)
    times = parse_times(p.frame_times)
    sc, cloth = scene_scenario(scene, times)
    missing = [t for t in times if f"t={t:.3f}" not in {kb.name for kb in
                                                       (cloth.data.shape_keys.key_blocks if cloth.data.shape_keys else [])}]
    if missing:
        raise ClothFitError(f"the cloth is not baked at t = {missing[0]:.3f} s ({len(missing)} capture times "
                            f"missing): simulate first")
    _refuse_foreign_capture(root)
    shapes = S.baked_positions(cloth, times)
    check_bake_follows_handles(sc, shapes)
    # the cameras as Blender renders them: the exact (float64) imported camera while the Blender
    # camera still shows it, minus lens distortion (Blender renders a pinhole image)
    rows = exact_rig_cameras(scene)
    cams = [sh if sh is not None else b for b, _, sh in rows]
    dropped = [b.name for b, ex, _ in rows if ex is not None and ex.dist.size and np.any(ex.dist != 0)]
    par = params_from_scene(scene)
    engine = getattr(p, "render_engine", "WORKBENCH") if engine is None else engine
    occluders = R.occluder_objects(scene)
    meta = {"generator": f"{GENERATOR_PREFIX}{bpy.app.version_string} {engine.title()} (addon/blender/render.py)",
            "true_params": par.as_dict(), "noise_fraction": noise, "seed": seed}
    if occluders:
        meta["occluders"] = [o.name for o in occluders]
    if dropped:
        meta["distortion_dropped"] = dropped
    # two steps: everything but capture.json now, capture.json only once every PNG is written, so a
    # render that fails midway never leaves a capture that looks complete
    pending = write_capture(root, cams, sc, None, shapes=shapes, cloth_mass=par.m * sc.grid.n_vertices, meta=meta,
                            finalize=False, ignore=True if occluders else None)
    frame0 = scene.frame_current
    tmp = os.path.join(root, ".render_tmp")
    os.makedirs(tmp, exist_ok=True)
    try:
        for fi, t in enumerate(times):
            scene.frame_set(S.frame_of_time(scene, t))
            masks = R.render_masks(scene, cloth, objs, tmpdir=tmp, engine=engine,
                                   occluders=occluders if occluders else None)
            for ci, m in enumerate(masks):
                ign = None
                if occluders:
                    m, ign = m
                if not m.any():
                    raise ClothFitError(f"camera '{cams[ci].name}' does not see the cloth at t = {t:.3f} s "
                                        f"(empty silhouette{', occluders included' if occluders else ''})")
                if noise > 0:
                    m = add_boundary_noise(m, noise, noise_rng(seed, ci, fi))
                    if ign is not None:
                        m &= ~ign      # boundary noise at an occluder's edge is not cloth seen
                save_silhouette(pending.silhouette_path(ci, fi), m)
                if ign is not None:
                    save_silhouette(pending.ignore_path(ci, fi), ign)
            if progress:
                progress((fi + 1) / len(times))
        cap = finalize_capture(pending)
    finally:
        for f in os.listdir(tmp):
            os.remove(os.path.join(tmp, f))
        os.rmdir(tmp)
        scene.frame_set(frame0)
    p.capture_dir = root
    return cap


GENERATOR_PREFIX = "Blender "
BAKE_TOL = 1e-5   # m: a held handle vertex of the bake vs the manipulation's position for it


def check_bake_follows_handles(scenario, shapes):
    """Raise unless the baked shapes hold every handle where the scenario puts it (the bake is of
    this manipulation: e.g. no empty moved, no corner changed since Simulate)."""
    times = scenario.frame_times
    for h in scenario.handles:
        held = h.held(times)
        if not held.any():
            continue
        want = h.position(times[held])
        got = shapes[held][:, h.vertex]
        err = np.linalg.norm(got - want, axis=-1)
        k = int(np.argmax(err))
        if err[k] > BAKE_TOL:
            raise ClothFitError(f"the baked cloth does not follow the current manipulation: the handle on vertex "
                                f"{h.vertex} is {1000 * err[k]:.3f} mm away from its position at t = "
                                f"{times[held][k]:.3f} s (handles, empties or settings changed since Simulate): "
                                f"simulate again")


def _refuse_foreign_capture(root, own_prefix=GENERATOR_PREFIX, who="Render Silhouettes", what="renders"):
    """Never overwrite a capture that this writer did not write (real footage, synthetic...)."""
    path = os.path.join(root, "capture.json")
    if not os.path.isfile(path):
        return
    try:
        with open(path) as f:
            gen = str((json.load(f).get("meta") or {}).get("generator", ""))
    except (OSError, ValueError, AttributeError):
        gen = "?"
    if not gen.startswith(own_prefix):
        raise ClothFitError(f"{root} already holds a capture written by {gen or 'another tool'!r}; {who} "
                            f"only overwrites its own {what}: choose another capture directory")


# ================================================================= extraction

EXTRACT_GENERATOR = "addon.core.extract"
THRESHOLD_MODES = {"AUTO": "auto", "OTSU": "otsu", "NOISE": "noise"}


def parse_camera_thresholds(spec: str, camera_names=None) -> dict:
    """``"cam03=9.5, cam07=12"`` -> {"cam03": 9.5, "cam07": 12.0}; names checked against the cameras."""
    out = {}
    for item in (spec or "").replace(";", ",").split(","):
        item = item.strip()
        if not item:
            continue
        if "=" not in item:
            raise ClothFitError(f"per-camera threshold {item!r}: expected CAMERA=VALUE (e.g. cam03=9.5)")
        name, val = (x.strip() for x in item.split("=", 1))
        try:
            v = float(val)
        except ValueError:
            raise ClothFitError(f"per-camera threshold {item!r}: {val!r} is not a number") from None
        if not (math.isfinite(v) and v > 0):
            raise ClothFitError(f"per-camera threshold {item!r}: the threshold must be a positive number")
        if name in out:
            raise ClothFitError(f"per-camera threshold: camera '{name}' is given twice")
        if camera_names is not None and name not in camera_names:
            raise ClothFitError(f"per-camera threshold {item!r}: no camera '{name}' in the calibration (cameras: "
                                f"{', '.join(list(camera_names)[:20])})")
        out[name] = v
    return out


def _footage_cameras(scene, footage, sizes=None):
    """The calibration for an extraction: the Calibration property, else the footage's own
    (footage.json's, cameras.* / calibration.*, a COLMAP folder), else the rig's exact cameras
    (imported or loaded). Returns (cameras, where they came from)."""
    from ..core.footage import calib_io
    from ..core.footage import extract as X
    p = props(scene)
    if p.extract_calibration.strip():
        path = abspath(p.extract_calibration, "calibration")
        return calib_io.import_cameras(path, sizes=sizes), path
    meta, meta_path = X._read_footage_json(footage)
    if isinstance(meta.get("cameras"), str):
        path = os.path.join(footage, meta["cameras"])
        return calib_io.import_cameras(path), path
    path = X._find_calibration(footage)
    if path is not None:
        return calib_io.import_cameras(path, sizes=sizes), path
    if p.rig_cameras_json.strip():
        return cameras_from_json(p.rig_cameras_json), "the scene's imported cameras"
    raise ClothFitError(f"footage {footage}: no calibration: set Calibration, put a cameras.yml (or footage.json, "
                        f"or a COLMAP folder) in the footage folder, or import cameras into the rig first")


def extract_silhouettes(scene, progress=None):
    """Silhouettes from the footage folder (``core.footage.extract.extract_capture``) into a capture,
    then load it (cameras become the rig, observed silhouettes the camera backgrounds).

    With the Empties manipulation the capture's scenario is the empties' (sampled at the
    footage's frame times); otherwise footage.json's, else the paper's (with a warning).
    ``progress(fraction)`` is called per camera. Returns (Capture, report); ``report["warnings"]``
    lists every warning of the extraction, ``report["notes"]`` what the scene changed (frame rate).
    Errors (every bad file in one message) write nothing."""
    from ..core.footage import extract as X
    p = props(scene)
    footage = abspath(p.footage_dir, "footage directory")
    if not os.path.isdir(footage):
        raise ClothFitError(f"footage folder not found: {footage}")
    out = abspath(p.extract_capture_dir, "output capture directory") if p.extract_capture_dir.strip() \
        else capture_dir(scene)
    if os.path.normpath(out) == os.path.normpath(footage):
        raise ClothFitError(f"the output capture directory is the footage folder {footage}: choose another one")
    _refuse_foreign_capture(out, EXTRACT_GENERATOR, "Extract Silhouettes", "extractions")
    videos = getattr(p, "footage_kind", "IMAGES") == "VIDEOS"
    sizes = None
    if videos:
        from ..core.footage import video as V
        sizes = V.video_sizes(footage)
    cams, cam_source = _footage_cameras(scene, footage, sizes)
    times = parse_times(p.extract_times) if p.extract_times.strip() else None
    if videos and times is None:
        raise ClothFitError("extraction from videos needs the capture times (Times)")
    mode = p.extract_threshold_mode
    opts = X.ExtractOptions(
        threshold=THRESHOLD_MODES.get(mode, float(p.extract_threshold)),
        thresholds=parse_camera_thresholds(p.extract_camera_thresholds, [c.name for c in cams]),
        luma_weight=float(p.extract_luma_weight), shadow_min=float(p.extract_shadow_min),
        debug_dir=os.path.join(out, "debug") if p.extract_debug else None).check()
    scenario, notes = None, []
    if p.scenario_source == "EMPTIES":
        ft = times
        if ft is None:
            ft = X._read_footage_json(footage)[0].get("frame_times")
            if not isinstance(ft, list) or not ft:
                raise ClothFitError(f"footage {footage}: no frame times (set Times, or frame_times in footage.json)")
        scenario = empties_scenario(scene, scene_grid(scene), ft, notes)

    def cb(i, n, name):
        if progress:
            progress(i / max(n, 1))
    if videos:
        names = [c.name for c in cams]
        sync_path = abspath(p.footage_sync, "sync file") if p.footage_sync.strip() else None
        if p.footage_find_sync:
            sync = V.flash_sync(footage, names, p.footage_flash_time, sync_path)
            notes.append("sync from the flash: " + ", ".join(f"{k} {v:.4f} s" for k, v in sync.items()))
        elif sync_path:
            sync = sync_path
        else:
            raise ClothFitError("extraction from videos needs a Sync file (or Sync from Flash)")
        if not p.footage_plates.strip():
            raise ClothFitError("extraction from videos needs the Plates folder")
        report = X.extract_videos(footage, abspath(p.footage_plates, "plates folder"), sync, out, cams, times,
                                  scenario=scenario, options=opts, progress=cb)
    else:
        report = X.extract_capture(footage, out, cameras=cams, frame_times=times, scenario=scenario, options=opts,
                                   progress=cb)
    if progress:
        progress(1.0)
    cap = load_capture(scene, out)
    thr = [r["threshold"] for r in report["cameras"].values()]
    nw = len(report.get("warnings", []))
    p.extract_status = (f"{cap.n_cameras} cameras x {cap.n_frames} frames, thresholds {min(thr):.2f}.."
                        f"{max(thr):.2f}, {nw} warning{'s' if nw != 1 else ''}")
    report["calibration"] = cam_source
    report["notes"] = notes
    return cap, report


def load_capture(scene, path=None):
    """Read and fully validate a capture; its cameras become the rig, its scenario the settings,
    and each camera shows its observed silhouette (frame ``view_frame``) as background image."""
    from ..core.observation.capture import load_capture as core_load
    p = props(scene)
    root = abspath(path, "capture directory") if path else capture_dir(scene)
    cap = core_load(root)
    cap.validate(full=True)
    set_rig(scene, cap.cameras)
    g = cap.scenario.grid
    p.cloth_nx, p.cloth_side, p.cloth_height = g.nx, g.side, g.height
    p.settle_time = cap.scenario.settle_time
    p.frame_times = ", ".join(f"{t:g}" for t in cap.frame_times)
    released = [h for h in cap.scenario.handles if h.release_time is not None]
    if released and released[0].vertex in g.corners():
        p.released_corner = g.corners().index(released[0].vertex)
    p.capture_dir = root
    p.scenario_source = "CAPTURE"
    p["view_frame"] = min(p.view_frame, cap.n_frames - 1)
    show_observations(scene, p.view_frame, cap)
    return cap


def _load_image(name, path):
    img = bpy.data.images.get(name)
    if img is None:
        img = bpy.data.images.load(path, check_existing=False)
        img.name = name
    elif bpy.path.abspath(img.filepath) != path:
        img.filepath = path
        img.reload()
    else:
        img.reload()
    return img


def show_background(cam_obj, image, alpha=0.6):
    cd = cam_obj.data
    bg = cd.background_images[0] if len(cd.background_images) else cd.background_images.new()
    bg.image = image
    bg.alpha = alpha
    bg.display_depth = "FRONT"
    cd.show_background_images = True
    return bg


def show_observations(scene, frame_index, cap=None, kind="observed"):
    """Camera backgrounds: observed silhouettes (or overlays) of capture frame ``frame_index``."""
    from ..core.observation.capture import load_capture as core_load
    cap = cap or core_load(capture_dir(scene))
    fi = max(0, min(int(frame_index), cap.n_frames - 1))
    objs = {o.name: o for o in S.rig_objects(scene)}
    shown = 0
    for ci, c in enumerate(cap.cameras):
        obj = objs.get(c.name)
        if obj is None:
            continue
        if kind == "overlay":
            path = overlay_path(cap, ci, fi)
        else:
            path = cap.silhouette_path(ci, fi)
        if os.path.isfile(path):
            show_background(obj, _load_image(f"clothfit {kind} {c.name}", path))
            shown += 1
    return shown


# ===================================================================== fitting

def fit_config(scene, capture):
    from ..core.fitting.job import FitConfig
    p = props(scene)
    ncam = len(capture.cameras)
    if p.train_cameras > ncam:
        raise ClothFitError(f"{p.train_cameras} training cameras asked but the capture has {ncam}")
    train, _ = select_training(capture.cameras, p.train_cameras)
    times = None
    if p.train_times == "PAPER":
        have = [t for t in D.TRAIN_TIMES if np.any(np.abs(capture.frame_times - t) < 1e-6)]
        times = have or None
    res = None if p.fit_resolution == "FULL" else [int(x) for x in p.fit_resolution.split("x")]
    model = None
    if p.fit_model == "BLENDER":      # Blender's cloth for this scene's frame rate
        from .cloth import scene_fps
        model = {"name": "blender", "fps": scene_fps(scene), "quality": int(p.fit_quality),
                 "bending_model": p.fit_bending_model}
    return FitConfig(train_cameras=train, train_times=times, optimizer=p.optimizer, seed=p.seed,
                     max_evaluations=p.max_evaluations, resolution=res,
                     cloth_mass=p.fit_cloth_mass if p.fit_cloth_mass > 0 else None, model=model)


class FitSession:
    """One fit in progress: the core job plus what the UI shows. ``step`` = one generation."""

    def __init__(self, scene, job, result_path):
        self.scene_name = scene.name
        self.job = job
        self.result_path = result_path
        self.timer = None
        self.started = time.time()
        self.threaded = False       # the modal operator runs generations in a worker thread
        self.worker = None          # threading.Thread running one job.step() (threaded mode)
        self._outcome = None        # (more, exception) of the worker's step

    def _work(self):
        try:
            self._outcome = (self.job.step(), None)
        except BaseException as e:  # handed over to the main thread, which re-raises it
            self._outcome = (False, e)

    def wait(self):
        """Block until the running worker step (if any) has finished."""
        if self.worker is not None:
            self.worker.join()

    @property
    def scene(self):
        return bpy.data.scenes.get(self.scene_name)

    def status_text(self):
        j = self.job
        bp = j.best_params
        s = (f"Cloth Fit: generation {j.generation}, {j.evaluations}/{j.config.max_evaluations} evaluations, "
             f"best E_all {j.best_error:.4g}")
        if bp:
            s += " | " + _params_text(bp)
        return s + " | Esc cancels (keeps the best)"


def _params_text(bp) -> str:
    """One line of fitted parameters: paper m, k, l, d or the main Blender cloth settings."""
    if "k" in bp:
        return f"m={bp['m']:.3g} k={bp['k']:.4g} l={bp['l']:.4g} d={bp['d']:.3g}"
    return (f"tension={bp['tension_stiffness']:.4g} shear={bp['shear_stiffness']:.4g} "
            f"bending={bp['bending_stiffness']:.4g} air={bp['air_damping']:.4g}")


def start_fit(scene, capture=None):
    """Load the capture, build the core ``FitJob``; returns a ``FitSession``."""
    from ..core.fitting.job import FitJob
    from ..core.observation.capture import load_capture as core_load
    p = props(scene)
    if p.fit_running:
        raise ClothFitError("a fit is already running in this scene")
    cap = capture or core_load(capture_dir(scene))
    job = FitJob(cap, fit_config(scene, cap))
    name = RESULT_JSON if job.par.model.name == "paper" else RESULT_JSON_BLENDER
    sess = FitSession(scene, job, os.path.join(cap.root, name))
    p.fit_running = True
    p.fit_progress = 0.0
    p.fit_generation = p.fit_evaluations = 0
    p.fit_status = f"fitting {len(job.train_cameras)} cameras x {len(job.train_times)} times"
    return sess


def _publish(scene, job):
    p = props(scene)
    p.fit_progress = job.progress
    p.fit_generation = job.generation
    p.fit_evaluations = job.evaluations
    bp = job.best_params
    if bp:
        p.fit_best_error = job.best_error
        p.fit_best_pct = 100.0 * job.best_error / max(1, job.objective.n_images)
        if "k" in bp:
            p.fit_best_m, p.fit_best_k, p.fit_best_l, p.fit_best_d = bp["m"], bp["k"], bp["l"], bp["d"]
            p.fit_best_blender = ""
        else:
            p.fit_best_blender = json.dumps(bp)
        p.fit_has_result = True


def fit_step(session) -> bool:
    """One generation; publishes the live status. Returns False when the job is finished."""
    more = session.job.step()
    _publish(session.scene, session.job)
    return more


def fit_tick(session):
    """Threaded stepping for the modal operator: the generation runs in a worker thread (numpy /
    numba only, no bpy), the main thread publishes. Returns None while a generation is running,
    True after a generation when there are more (the next one is started at once), False when the
    job is finished. Exceptions of the worker are re-raised here, on the main thread."""
    import threading
    if session.worker is not None:
        if session.worker.is_alive():
            return None
        session.worker.join()
        session.worker = None
        more, err = session._outcome
        session._outcome = None
        if err is not None:
            raise err
        _publish(session.scene, session.job)
        if not more:
            return False
    elif session.job.finished:
        return False
    else:
        more = None
    session.worker = threading.Thread(target=session._work, name="clothfit-fit-step", daemon=True)
    session.worker.start()
    return more


def finish_fit(session, cancelled=False):
    """Stop (cancel keeps the best), write the result JSON, update the status. -> (level, message)."""
    session.wait()  # a generation still running in the worker finishes first (its result is kept)
    if session.worker is not None:
        session.worker = None
        if session._outcome and session._outcome[1] is None:
            _publish(session.scene, session.job)
    job = session.job
    scene = session.scene
    if cancelled and not job.finished:
        job.cancel()
    elif cancelled:
        job.cancelled = True
    p = props(scene)
    p.fit_running = False
    _publish(scene, job)
    job.save_result(session.result_path)
    p.result_path = session.result_path
    bp = job.best_params
    if job.error:
        p.fit_status = f"failed: {job.error}"
        return "ERROR", f"Fit failed: {job.error} (result so far: {session.result_path})"
    if bp is None:
        p.fit_status = "cancelled before the first generation: no result"
        return "WARNING", "Fit cancelled before the first generation finished: no result"
    kept = f"best E_sil {p.fit_best_pct:.3f} % after {job.evaluations} evaluations"
    if job.cancelled:
        p.fit_status = f"cancelled at generation {job.generation}; {kept} kept"
        return "WARNING", f"Fit cancelled at generation {job.generation}: {kept} kept ({session.result_path})"
    p.fit_status = f"finished: {kept}"
    return "INFO", f"Fit finished: {kept}; {_params_text(bp)} ({session.result_path})"


def run_fit(scene, callback=None):
    """Synchronous fit (background mode, scripts). ``callback(session) -> True`` cancels."""
    sess = start_fit(scene)
    cancelled = False
    try:
        while fit_step(sess):
            if callback is not None and callback(sess):
                cancelled = True
                break
    except BaseException as e:
        props(scene).fit_running = False
        if isinstance(e, Exception):       # keep the best so far on disk before reporting the error
            sess.job.fail(str(e) if isinstance(e, ClothFitError) else f"{type(e).__name__}: {e}")
            with contextlib.suppress(ClothFitError, OSError):
                sess.job.save_result(sess.result_path)
        raise
    level, msg = finish_fit(sess, cancelled)
    return sess.job.result(), level, msg


def load_result(scene, path=None):
    p = props(scene)
    path = path or (bpy.path.abspath(p.result_path) if p.result_path else os.path.join(capture_dir(scene), RESULT_JSON))
    if not os.path.isfile(path):
        raise ClothFitError(f"no fit result at {path}: run the fit first")
    try:
        with open(path) as f:
            res = json.load(f)
    except (OSError, json.JSONDecodeError) as e:
        raise ClothFitError(f"fit result {path} is unreadable: {e}") from None
    if not isinstance(res, dict) or not (isinstance(res.get("params"), dict) or
                                         isinstance(res.get("blender_cloth"), dict)):
        raise ClothFitError(f"fit result {path} has no parameters (the fit found none)")
    return res


def apply_fit(scene, result=None):
    """Fitted parameters -> the scene's m, k, l, d; then re-simulate and bake. (A Blender-model
    result goes to a Cloth modifier instead: ``apply_blender_cloth``.)"""
    p = props(scene)
    if result is None and p.fit_best_blender:
        raise ClothFitError("the fit is a Blender-cloth fit: use Apply Blender Cloth")
    if result is None and p.fit_has_result and p.fit_best_k > 0:
        par = Params(p.fit_best_m, p.fit_best_k, p.fit_best_l, p.fit_best_d)
        try:  # prefer the full-precision numbers of the result file
            par = Params.from_dict(load_result(scene)["params"], "fit result")
        except ClothFitError:
            pass
    else:
        res = result if result is not None else load_result(scene)
        par = Params.from_dict(res["params"] if "params" in res else res, "fit result")
    par.check("fitted parameters")
    params_to_scene(scene, par)
    return simulate(scene)


def apply_blender_cloth(scene, obj=None, result=None, set_fps=True):
    """A Blender-model fit result -> a Cloth modifier. On the scene's own cloth (or with no mesh
    active) a "Blender Cloth (fitted)" object is built beside it from the capture's scenario: the
    same mesh, pins and release as the fit, so Blender replays the fitted motion. On any other
    mesh its Cloth modifier is added or updated (its own pin group is kept). The scene's frame rate
    is set to the one the settings are for (``set_fps``), else a differing rate is an error.
    Returns (object, message)."""
    from ..core.physics.models import BlenderModel, model_and_row
    from . import cloth as BC
    res = result if result is not None else load_result(scene)
    model, row = model_and_row(res)
    if not isinstance(model, BlenderModel):
        raise ClothFitError("the fit result is a paper-model fit: it has no Blender cloth settings "
                            "(fit with the Blender Cloth model)")
    settings = model.settings(row)
    fps = BC.scene_fps(scene)
    note = ""
    if abs(fps - model.fps) > 1e-6:
        if not set_fps:
            raise ClothFitError(f"the settings are for {model.fps:g} fps but the scene runs at {fps:g} fps: "
                                f"Blender's cloth moves per frame, so they would move it differently")
        BC.set_scene_fps(scene, model.fps)
        note = f"; scene frame rate set from {fps:g} to {model.fps:g} fps"
    own = None
    try:
        own = cloth_object(scene)
    except ClothFitError:
        pass
    if obj is None or (own is not None and obj == own):
        sc, _ = scene_scenario(scene)
        net, plan = model.plan(sc)
        old = bpy.data.objects.get(BLENDER_CLOTH_NAME)
        if old is not None:
            me = old.data
            bpy.data.objects.remove(old, do_unlink=True)
            if me is not None and me.users == 0:
                bpy.data.meshes.remove(me)
        new = BC.build_cloth_object(scene, net, plan, settings, name=BLENDER_CLOTH_NAME,
                                    frame_start=scene.frame_start)
        return new, (f"Built '{new.name}' with the fitted Cloth settings, pins and release of the scenario "
                     f"(t = 0 at frame {scene.frame_start + plan.release_frame}){note}")
    if obj.type != "MESH":
        raise ClothFitError(f"the active object '{obj.name}' is a {obj.type.lower()}, not a mesh")
    cl = BC.cloth_modifier(obj) or obj.modifiers.new("Cloth", "CLOTH")
    BC.apply_settings(cl, settings)
    pins = cl.settings.vertex_group_mass
    return obj, (f"Cloth settings applied to '{obj.name}'"
                 + (f" (pins: vertex group '{pins}')" if pins else " (no pin group set)") + note)


# ==================================================================== overlays

BLENDER_CLOTH_NAME = "Blender Cloth (fitted)"


def overlay_path(cap, ci, fi):
    return os.path.join(cap.root, OVERLAY_DIR, cap.cameras[ci].name, f"{fi:03d}.png")


def model_masks_core(scene, cap, frame_indices):
    from ..core.observation.raster import silhouette
    from ..core.physics.models import simulate as core_simulate
    sc = cap.scenario.with_frames([float(cap.frame_times[i]) for i in frame_indices])
    res = core_simulate(sc, [params_from_scene(scene)])
    if res.exploded[0]:
        raise ClothFitError(f"the scene's parameters make the simulation unstable: {res.reason[0]}")
    X = res.positions[0]
    tris = sc.grid.triangles
    return [[silhouette(c, X[k], tris) for k in range(len(frame_indices))] for c in cap.cameras]


def model_masks_blender(scene, cap, frame_indices):
    distorted = [c.name for c in cap.cameras if c.dist.size and np.any(c.dist != 0)]
    if distorted:
        raise ClothFitError(f"the capture's cameras have lens distortion ({', '.join(distorted[:4])}"
                            f"{', ...' if len(distorted) > 4 else ''}) but Blender renders pinhole images: "
                            f"choose the Core model source for these overlays")
    cloth = cloth_object(scene)
    baked = {round(t, 3) for t in S.baked_times(cloth)}
    times = [float(cap.frame_times[i]) for i in frame_indices]
    miss = [t for t in times if round(t, 3) not in baked]
    if miss:
        raise ClothFitError(f"the cloth is not baked at t = {miss[0]:.3f} s: simulate (or apply the fit) first")
    objs = {o.name: o for o in S.rig_objects(scene)}
    cam_objs = []
    for c in cap.cameras:
        if c.name not in objs:
            raise ClothFitError(f"the rig has no camera '{c.name}' of the capture: load the capture first")
        cam_objs.append(objs[c.name])
    out = [[None] * len(times) for _ in cap.cameras]
    frame0 = scene.frame_current
    try:
        for k, t in enumerate(times):
            scene.frame_set(S.frame_of_time(scene, t))
            for ci, m in enumerate(R.render_masks(scene, cloth, cam_objs)):
                out[ci][k] = m
    finally:
        scene.frame_set(frame0)
    return out


def make_overlays(scene, source=None, frame_indices=None, sheet_frame=None):
    """Observed vs. model silhouettes per camera and frame -> ``<capture>/overlays/<cam>/<f>.png``,
    a contact sheet of all cameras at one frame, E_sil per image in ``overlays/summary.json``;
    cameras show their overlay as background. Returns the summary dict."""
    from ..core.observation.capture import load_capture as core_load
    from ..core.observation.metrics import e_sil
    from ..core.observation.overlay import contact_sheet, label, overlay_image, write_rgb
    p = props(scene)
    cap = core_load(capture_dir(scene))
    fidx = list(range(cap.n_frames)) if frame_indices is None else [int(i) for i in frame_indices]
    for i in fidx:
        if not 0 <= i < cap.n_frames:
            raise ClothFitError(f"overlay frame index {i} outside 0..{cap.n_frames - 1}")
    source = source or p.overlay_source
    model = (model_masks_blender if source == "BLENDER" else model_masks_core)(scene, cap, fidx)
    errs = np.zeros((cap.n_cameras, len(fidx)))
    sheet_fi = fidx[len(fidx) // 2] if sheet_frame is None else int(sheet_frame)
    tiles = []
    for ci, c in enumerate(cap.cameras):
        for k, fi in enumerate(fidx):
            obs, ign = cap.load_observation(ci, fi)
            mod = model[ci][k]
            if mod.shape != obs.shape:
                raise ClothFitError(f"camera '{c.name}': model silhouette {mod.shape} and observed {obs.shape} differ "
                                    f"in size")
            # pixels of unknown truth (occluders) leave eq. 6: the model is not judged there
            errs[ci, k] = e_sil(obs, mod if ign is None else mod & ~ign, name=cap.silhouette_path(ci, fi))
            img = overlay_image(obs, mod, ign)
            write_rgb(overlay_path(cap, ci, fi), img)
            if fi == sheet_fi:
                tiles.append(label(img, f"{c.name} t={cap.frame_times[fi]:.2f} E={100 * errs[ci, k]:.2f}%"))
    out_dir = os.path.join(cap.root, OVERLAY_DIR)
    sheet_path = None
    if tiles:
        sheet = contact_sheet(tiles, cols=min(6, len(tiles)))
        sheet_path = os.path.join(out_dir, "contact_sheet.png")
        write_rgb(sheet_path, sheet)
        img = _load_image("clothfit contact sheet", sheet_path)
        img.use_fake_user = False
    summary = {"source": source, "params": params_from_scene(scene).as_dict(),
               "frames": fidx, "times": [float(cap.frame_times[i]) for i in fidx],
               "cameras": cap.camera_names, "E_sil_pct": (100 * errs).tolist(),
               "mean_E_sil_pct": float(100 * errs.mean()), "contact_sheet": sheet_path,
               "contact_sheet_frame": sheet_fi}
    from ..core.safeio import atomic_json
    atomic_json(os.path.join(out_dir, "summary.json"), summary)
    p.overlay_dir = out_dir
    p.overlay_error = summary["mean_E_sil_pct"]
    show_observations(scene, p.view_frame if p.view_frame in fidx else fidx[0], cap, kind="overlay")
    return summary
