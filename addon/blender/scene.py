# SPDX-License-Identifier: GPL-3.0-or-later
"""Scene builders: OpenCV cameras <-> Blender cameras, the rig collection, the cloth mesh, the bake.

Camera conversion (Blender's ``BKE_camera_params_compute_viewplane``; pixel centres at integers as
in ``core/observation/camera.py``). With ``W, H`` the render size (resolution x percentage / 100, integer
division as Blender does), ``par = pixel_aspect_y / pixel_aspect_x``:

* sensor fit AUTO is horizontal when ``pixel_aspect_x * W >= pixel_aspect_y * H``;
* the sensor size is ``sensor_height`` for fit VERTICAL only, else ``sensor_width``;
* ``view_fac = W`` if horizontal else ``par * H``;
* ``fx = lens / sensor * view_fac``, ``fy = fx / par``;
* ``cx = (W - 1)/2 - shift_x * view_fac``, ``cy = (H - 1)/2 + shift_y * view_fac / par``;
* camera-to-world (OpenCV) = ``matrix_world @ diag(1, -1, -1, 1)``, so
  ``R = diag(1, -1, -1) @ R_world^T`` and ``t = -R @ C`` (evaluated matrix: constraints apply).

The way back keeps the Blender camera's sensor fit and sensor size and solves lens and shift; it
keeps the scene's resolution/percentage and pixel aspect when they already give the camera's
image size and ``fx / fy``, otherwise it sets them (percentage 100). Skew cannot be represented
(error); lens distortion is dropped (the Blender camera is then the undistorted pinhole).

Blender has one render size per scene: every camera of a rig must share it.
"""

from __future__ import annotations

import bpy
import numpy as np
from mathutils import Matrix

from ..core.errors import ClothFitError
from ..core.observation.camera import Camera
from ..core.physics.scenario import ClothGrid

RIG_COLLECTION = "ClothFit Rig"
CLOTH_COLLECTION = "ClothFit"
CLOTH_NAME = "ClothFit Cloth"
CAMERA_INDEX_KEY = "clothfit_camera_index"
FLIP = np.diag([1.0, -1.0, -1.0])


# ====================================================================== cameras


def render_size(scene):
    """(W, H) in pixels of the scene's render, as Blender computes it."""
    r = scene.render
    return (r.resolution_x * r.resolution_percentage) // 100, (r.resolution_y * r.resolution_percentage) // 100


def _fit_is_horizontal(fit, W, H, ax, ay):
    if fit == "AUTO":
        return ax * W >= ay * H
    return fit == "HORIZONTAL"


def camera_from_blender(obj, scene, name=None, depsgraph=None) -> Camera:
    """The OpenCV camera of Blender camera object ``obj`` rendering ``scene``."""
    if obj is None or obj.type != "CAMERA":
        raise ClothFitError(f"object {getattr(obj, 'name', None)!r} is not a camera")
    cam = obj.data
    if cam.type != "PERSP":
        raise ClothFitError(f"camera '{obj.name}' is {cam.type}; only perspective cameras are supported")
    W, H = render_size(scene)
    if W <= 0 or H <= 0:
        raise ClothFitError(f"scene '{scene.name}': render size {W}x{H} is empty")
    ax, ay = scene.render.pixel_aspect_x, scene.render.pixel_aspect_y
    par = ay / ax
    horizontal = _fit_is_horizontal(cam.sensor_fit, W, H, ax, ay)
    sensor = cam.sensor_height if cam.sensor_fit == "VERTICAL" else cam.sensor_width
    view_fac = W if horizontal else par * H
    fx = cam.lens / sensor * view_fac
    fy = fx / par
    cx = (W - 1) / 2.0 - cam.shift_x * view_fac
    cy = (H - 1) / 2.0 + cam.shift_y * view_fac / par
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    if depsgraph is not None:
        mw = obj.evaluated_get(depsgraph).matrix_world
    else:
        mw = obj.matrix_world
    Rw = _orthonormal(np.array(mw.to_3x3(), dtype=np.float64))
    C = np.array(mw.translation, dtype=np.float64)
    R = FLIP @ Rw.T
    t = -R @ C
    return Camera(K, R, t, W, H, name=name or obj.name)


def _orthonormal(M):
    """The rotation nearest to M (drops scale and float32 noise)."""
    U, _, Vt = np.linalg.svd(M)
    R = U @ Vt
    if np.linalg.det(R) < 0:
        U[:, -1] *= -1
        R = U @ Vt
    return R


def set_render_format(scene, width: int, height: int, par: float = 1.0):
    """Make the scene render ``width x height`` pixels with pixel aspect ratio ``par`` (= fx / fy).

    Keeps the current resolution/percentage and pixel aspect when they already match."""
    r = scene.render
    if render_size(scene) != (width, height):
        r.resolution_x, r.resolution_y, r.resolution_percentage = int(width), int(height), 100
    cur = r.pixel_aspect_y / r.pixel_aspect_x
    if abs(cur - par) > 1e-9 * par:
        if par >= 1.0:
            r.pixel_aspect_x, r.pixel_aspect_y = 1.0, par
        else:
            r.pixel_aspect_x, r.pixel_aspect_y = 1.0 / par, 1.0


def camera_to_blender(camera: Camera, obj, scene):
    """Set Blender camera object ``obj`` (and the scene's render size) to reproduce ``camera``."""
    K = camera.K
    if abs(K[0, 1]) > 1e-9 * K[0, 0]:
        raise ClothFitError(f"camera '{camera.name}': skew K[0,1] = {K[0, 1]:g} cannot be represented in Blender")
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    W, H = camera.width, camera.height
    par = fx / fy
    if not (1.0 / 200.0 <= par <= 200.0):
        raise ClothFitError(f"camera '{camera.name}': fx/fy = {par:g} is outside Blender's pixel aspect range")
    set_render_format(scene, W, H, par)
    cam = obj.data
    cam.type = "PERSP"
    ax, ay = scene.render.pixel_aspect_x, scene.render.pixel_aspect_y
    par = ay / ax
    horizontal = _fit_is_horizontal(cam.sensor_fit, W, H, ax, ay)
    view_fac = W if horizontal else par * H
    sensor = cam.sensor_height if cam.sensor_fit == "VERTICAL" else cam.sensor_width
    lens = fx * sensor / view_fac
    if not (1.0 <= lens <= 5000.0):  # Blender's lens range: pick a sensor that gives a 50 mm lens
        sensor = 50.0 * view_fac / fx
        if cam.sensor_fit == "VERTICAL":
            cam.sensor_height = sensor
        else:
            cam.sensor_width = sensor
        lens = 50.0
    cam.lens = lens
    cam.shift_x = ((W - 1) / 2.0 - cx) / view_fac
    cam.shift_y = (cy - (H - 1) / 2.0) * par / view_fac
    # clipping around a scene of metres: near enough for a 10 cm cloth half a metre away
    dist = float(np.linalg.norm(camera.center))
    cam.clip_start = max(1e-3, min(0.1, 0.05 * dist))
    cam.clip_end = max(100.0, 10.0 * dist)
    Rw = (FLIP @ camera.R).T
    C = camera.center
    M = np.eye(4)
    M[:3, :3] = Rw
    M[:3, 3] = C
    obj.matrix_world = Matrix(M.tolist())
    return obj


# ========================================================================= rig


def ensure_collection(scene, name, parent=None):
    coll = bpy.data.collections.get(name)
    if coll is None:
        coll = bpy.data.collections.new(name)
    parent = parent or scene.collection
    if coll.name not in parent.children:
        parent.children.link(coll)
    return coll


def _remove_object(obj):
    data = obj.data
    bpy.data.objects.remove(obj, do_unlink=True)
    if data is not None and data.users == 0:
        if isinstance(data, bpy.types.Camera):
            bpy.data.cameras.remove(data)
        elif isinstance(data, bpy.types.Mesh):
            bpy.data.meshes.remove(data)


PAR_RANGE = (1.0 / 200.0, 200.0)  # Blender's pixel aspect range (fx / fy)


def check_rig(cameras):
    """Raise unless Blender can show every camera of ``cameras`` in one scene: one image size and
    one fx/fy ratio (Blender has one render size and pixel aspect per scene), no skew, unique
    names. The message names the first camera at fault."""
    cameras = list(cameras)
    if not cameras:
        raise ClothFitError("the rig has no camera")
    c0 = cameras[0]
    names = set()
    for c in cameras:
        if c.name in names:
            raise ClothFitError(f"two cameras are named '{c.name}': camera names must be unique")
        names.add(c.name)
        if (c.width, c.height) != (c0.width, c0.height):
            raise ClothFitError(
                f"camera '{c.name}' images {c.width}x{c.height} (WxH) but camera '{c0.name}' "
                f"{c0.width}x{c0.height}: Blender renders one image size per scene, so every "
                f"camera of the rig must have the same size"
            )
        if abs(c.K[0, 1]) > 1e-9 * c.K[0, 0]:
            raise ClothFitError(f"camera '{c.name}': skew K[0,1] = {c.K[0, 1]:g} cannot be represented in Blender")
        par = c.K[0, 0] / c.K[1, 1]
        if not (PAR_RANGE[0] <= par <= PAR_RANGE[1]):
            raise ClothFitError(f"camera '{c.name}': fx/fy = {par:g} is outside Blender's pixel aspect range")
    par0 = c0.K[0, 0] / c0.K[1, 1]
    for c in cameras[1:]:
        par = c.K[0, 0] / c.K[1, 1]
        if round(par, 9) != round(par0, 9):
            raise ClothFitError(
                f"camera '{c.name}' has fx/fy = {par:.9g} but camera '{c0.name}' {par0:.9g}: "
                f"Blender has one pixel aspect per scene, so every camera of the rig must have "
                f"the same fx/fy"
            )
    return cameras


def build_rig(scene, cameras):
    """Replace the rig collection's cameras by ``cameras`` (core Cameras). Returns the objects.

    Everything is checked (``check_rig``) before the old rig is touched."""
    cameras = check_rig(cameras)
    coll = ensure_collection(scene, RIG_COLLECTION)
    for obj in list(coll.objects):
        _remove_object(obj)
    objs = []
    for i, c in enumerate(cameras):
        data = bpy.data.cameras.new(c.name)
        data.sensor_fit = "HORIZONTAL"
        data.sensor_width = 36.0
        data.display_size = 0.03
        obj = bpy.data.objects.new(c.name, data)
        coll.objects.link(obj)
        obj[CAMERA_INDEX_KEY] = i
        camera_to_blender(c, obj, scene)
        objs.append(obj)
    if scene.camera is None or scene.camera.name not in coll.objects:
        scene.camera = objs[0]
    return objs


def rig_objects(scene):
    """The rig's camera objects in rig order (index property, then name)."""
    coll = bpy.data.collections.get(RIG_COLLECTION)
    objs = [o for o in (coll.all_objects if coll else []) if o.type == "CAMERA"]
    if not objs:
        raise ClothFitError(
            f"no camera in the rig: the collection '{RIG_COLLECTION}' is missing or holds no "
            f"camera (build the rig or load a capture first)"
        )
    return sorted(objs, key=lambda o: (int(o.get(CAMERA_INDEX_KEY, 1 << 30)), o.name))


def rig_cameras(scene):
    """Core Cameras of the rig as the scene renders them now (evaluated transforms)."""
    objs = rig_objects(scene)
    dg = bpy.context.evaluated_depsgraph_get()
    return [camera_from_blender(o, scene, depsgraph=dg) for o in objs]


# ======================================================================== cloth


def grid_from_object(obj) -> ClothGrid:
    try:
        return ClothGrid.from_dict(dict(obj["clothfit_grid"].to_dict()), source=f"cloth object '{obj.name}'")
    except KeyError:
        raise ClothFitError(
            f"object '{obj.name}' is not a Cloth Fit cloth (no grid description): build the cloth with Cloth Fit"
        ) from None


def build_cloth(scene, grid: ClothGrid, handles=(), name=CLOTH_NAME):
    """Create (or replace) the cloth mesh: the grid's rest shape and triangles, handle groups."""
    coll = ensure_collection(scene, CLOTH_COLLECTION)
    old = bpy.data.objects.get(name)
    if old is not None:
        _remove_object(old)
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(grid.rest.tolist(), [], grid.triangles.tolist())
    mesh.update()
    obj = bpy.data.objects.new(name, mesh)
    coll.objects.link(obj)
    obj["clothfit_grid"] = grid.to_dict()
    allg = obj.vertex_groups.new(name="handles")
    for k, h in enumerate(handles):
        g = obj.vertex_groups.new(name=f"handle_{k:02d}" + ("_released" if h.release_time is not None else ""))
        g.add([int(h.vertex)], 1.0, "REPLACE")
        allg.add([int(h.vertex)], 1.0, "REPLACE")
    return obj


def check_cloth(obj, grid: ClothGrid | None = None) -> ClothGrid:
    """Raise if ``obj`` is not the grid mesh Cloth Fit built (missing, or topology edited)."""
    if obj is None or obj.name not in bpy.data.objects:
        raise ClothFitError("the cloth object is missing: build the cloth first")
    if obj.type != "MESH":
        raise ClothFitError(f"the cloth object '{obj.name}' is a {obj.type}, not a mesh")
    grid = grid or grid_from_object(obj)
    me = obj.data
    nv, nt = len(me.vertices), len(me.polygons)
    if nv != grid.n_vertices or nt != len(grid.triangles):
        raise ClothFitError(
            f"the cloth mesh '{obj.name}' has {nv} vertices and {nt} faces but the {grid.nx}x{grid.ny} grid needs "
            f"{grid.n_vertices} vertices and {len(grid.triangles)} triangles: its topology was edited "
            f"(rebuild the cloth)"
        )
    tri = np.zeros(nt * 3, dtype=np.int32)
    sizes = np.zeros(nt, dtype=np.int32)
    me.polygons.foreach_get("loop_total", sizes)
    if np.any(sizes != 3):
        raise ClothFitError(
            f"the cloth mesh '{obj.name}' has non-triangle faces: its topology was edited (rebuild the cloth)"
        )
    me.polygons.foreach_get("vertices", tri)
    have = {tuple(sorted(t)) for t in tri.reshape(-1, 3).tolist()}
    want = {tuple(sorted(t)) for t in grid.triangles.tolist()}
    if have != want:
        raise ClothFitError(
            f"the cloth mesh '{obj.name}' has different triangles from the grid: its topology "
            f"was edited (rebuild the cloth)"
        )
    return grid


def rest_positions(obj) -> np.ndarray:
    me = obj.data
    co = np.zeros(len(me.vertices) * 3, dtype=np.float32)
    me.vertices.foreach_get("co", co)
    return co.reshape(-1, 3).astype(np.float64)


def evaluated_positions(obj, depsgraph=None) -> np.ndarray:
    """World vertex positions of the evaluated cloth (shape keys applied) at the current frame."""
    dg = depsgraph or bpy.context.evaluated_depsgraph_get()
    ev = obj.evaluated_get(dg)
    me = ev.to_mesh()
    try:
        co = np.zeros(len(me.vertices) * 3, dtype=np.float32)
        me.vertices.foreach_get("co", co)
        M = np.array(ev.matrix_world, dtype=np.float64)
    finally:
        ev.to_mesh_clear()
    co = co.reshape(-1, 3).astype(np.float64)
    return co @ M[:3, :3].T + M[:3, 3]


# ====================================================================== timing

FPS_CANDIDATES = (20, 24, 25, 30, 40, 50, 60, 100, 120, 200, 1000)


def choose_fps(times, preferred=None):
    """An integer frame rate at which every time is a whole frame (within 1e-6 s)."""
    t = np.asarray(times, dtype=np.float64)
    cands = ([int(preferred)] if preferred else []) + list(FPS_CANDIDATES)
    for fps in cands:
        if fps > 0 and np.all(np.abs(t * fps - np.round(t * fps)) < 1e-6 * fps):
            return fps
    raise ClothFitError(
        f"frame times {t.tolist()[:6]}... are not whole frames at any of the frame rates {list(FPS_CANDIDATES)}"
    )


def frame_of_time(scene, t: float) -> int:
    return scene.frame_start + int(round(t * scene.render.fps / scene.render.fps_base))


def time_of_frame(scene, frame) -> np.ndarray:
    """Seconds of scene frame(s) ``frame`` (frame_start is t = 0, as the bake keys it)."""
    return (np.asarray(frame, dtype=np.float64) - scene.frame_start) * scene.render.fps_base / scene.render.fps


def ensure_fps(scene, times):
    """Set the scene's frame rate to one at which every time is a whole frame (as the bake does),
    keeping the current rate when it already is. Returns the old rate if it changed, else None."""
    fps = choose_fps(times, scene.render.fps if scene.render.fps_base == 1.0 else None)
    old = scene.render.fps / scene.render.fps_base
    if scene.render.fps != fps or scene.render.fps_base != 1.0:
        scene.render.fps, scene.render.fps_base = fps, 1.0
        return old
    return None


def sample_world_positions(scene, objects, frames) -> np.ndarray:
    """World positions (len(objects), len(frames), 3) of the objects' evaluated origins at the
    given scene frames (animation, drivers, constraints and parents applied). The current frame
    is restored."""
    frames = [int(f) for f in frames]
    out = np.zeros((len(objects), len(frames), 3))
    frame0 = scene.frame_current
    try:
        for k, f in enumerate(frames):
            scene.frame_set(f)
            dg = bpy.context.evaluated_depsgraph_get()
            for i, o in enumerate(objects):
                out[i, k] = np.array(o.evaluated_get(dg).matrix_world.translation, dtype=np.float64)
    finally:
        scene.frame_set(frame0)
    return out


def simplify_track(times, positions, tol=1e-7):
    """Keys of a piecewise-linear track without the ones linear interpolation reproduces within
    ``tol`` (m): a resting empty keeps 1 key, a linear move 2. Every dropped key is within ``tol``
    of the simplified track."""
    t = np.asarray(times, dtype=np.float64)
    P = np.asarray(positions, dtype=np.float64)
    n = len(t)
    if n <= 1:
        return t, P
    keep = [0]
    i = 0
    while i < n - 1:
        j = i + 1
        while j + 1 < n:
            seg = slice(i + 1, j + 1)
            w = ((t[seg] - t[i]) / (t[j + 1] - t[i]))[:, None]
            if np.abs(P[i] + w * (P[j + 1] - P[i]) - P[seg]).max() > tol:
                break
            j += 1
        keep.append(j)
        i = j
    if len(keep) == 2 and np.abs(P[keep[1]] - P[0]).max() <= tol:
        keep = [0]
    return t[keep], P[keep]


# ======================================================================== bake


def bake_shape_keys(scene, obj, times, positions):
    """Store ``positions`` (F, V, 3) as one shape key per time, keyed so the timeline scrubs.

    The scene's frame rate becomes one at which every time is a whole frame (frame_start is
    t = 0); each key has value 1 at its frame and 0 at its neighbours' frames (linear), so the
    frames in between blend and a capture frame shows exactly its shape.
    """
    times = np.asarray(times, dtype=np.float64)
    positions = np.asarray(positions, dtype=np.float64)
    if positions.shape[0] != times.size or positions.shape[1] != len(obj.data.vertices):
        raise ClothFitError(
            f"bake: {positions.shape} positions for {times.size} times and {len(obj.data.vertices)} vertices"
        )
    fps = choose_fps(times, scene.render.fps if scene.render.fps_base == 1.0 else None)
    scene.render.fps, scene.render.fps_base = fps, 1.0
    clear_bake(obj)
    obj.shape_key_add(name="Basis", from_mix=False)
    frames = [frame_of_time(scene, t) for t in times]
    blocks = []
    for t, pos in zip(times, positions):
        kb = obj.shape_key_add(name=f"t={t:.3f}", from_mix=False)
        kb.data.foreach_set("co", pos.astype(np.float32).ravel())
        kb.slider_min, kb.slider_max = 0.0, 1.0
        blocks.append(kb)
    key = obj.data.shape_keys
    key.use_relative = True
    for i, kb in enumerate(blocks):
        keys = [(frames[i], 1.0)]
        if i > 0:
            keys.append((frames[i - 1], 0.0))
        if i + 1 < len(blocks):
            keys.append((frames[i + 1], 0.0))
        for f, v in sorted(keys):
            kb.value = v
            kb.keyframe_insert("value", frame=f)
    set_key_interpolation(key, "LINEAR")
    scene.frame_start = min(scene.frame_start, frames[0])
    scene.frame_end = frames[-1]
    obj.data.update()
    return frames


def set_key_interpolation(id_data, mode="LINEAR"):
    """Every keyframe of ``id_data``'s action gets interpolation ``mode`` (LINEAR, CONSTANT)."""
    ad = getattr(id_data, "animation_data", None)
    if ad is None or ad.action is None:
        return
    for fc in _action_fcurves(ad):
        for kp in fc.keyframe_points:
            kp.interpolation = mode


def _action_fcurves(ad):
    act = ad.action
    fcs = getattr(act, "fcurves", None)
    try:
        if fcs is not None and len(fcs):
            return list(fcs)
    except (AttributeError, RuntimeError):
        pass
    out = []  # layered actions (4.4+): walk layers/strips/channelbags
    for layer in getattr(act, "layers", []):
        for strip in layer.strips:
            for cb in getattr(strip, "channelbags", []):
                out.extend(cb.fcurves)
    return out


def clear_bake(obj):
    if obj.data.shape_keys is not None:
        ad = obj.data.shape_keys.animation_data
        act = ad.action if ad else None
        obj.shape_key_clear()
        if act is not None and act.users == 0:
            bpy.data.actions.remove(act)


def baked_times(obj):
    """Times of the baked shape keys (empty if none)."""
    key = obj.data.shape_keys
    if key is None:
        return []
    out = []
    for kb in key.key_blocks[1:]:
        if kb.name.startswith("t="):
            try:
                out.append(float(kb.name[2:]))
            except ValueError:
                pass
    return out


def baked_positions(obj, times):
    """Shape-key positions (F, V, 3) for the given baked times."""
    key = obj.data.shape_keys
    out = []
    for t in times:
        kb = key.key_blocks.get(f"t={t:.3f}") if key else None
        if kb is None:
            raise ClothFitError(f"the cloth '{obj.name}' has no baked shape at t = {t:.3f} s: simulate first")
        co = np.zeros(len(kb.data) * 3, dtype=np.float32)
        kb.data.foreach_get("co", co)
        out.append(co.reshape(-1, 3))
    return np.array(out, dtype=np.float64)
