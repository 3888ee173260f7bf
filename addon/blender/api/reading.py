# SPDX-License-Identifier: GPL-3.0-or-later
"""Reading the Blender scene into core objects: the settings (``scene.clothfit``), the capture
times, the rig's cameras, the cloth's grid, the manipulation (scenario) and the parameters.

``read_scene`` reads everything a step needs once, up front, into a frozen ``SceneInputs``; the
steps then work on those core objects (and on the few Blender objects a render needs). The
smaller readers below are what it is made of, and stay usable from scripts.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import bpy
import numpy as np

from ...core.errors import ClothFitError
from ...core.jsonio import dumps, loads, read_json
from ...core.observation.camera import Camera, load_rig, ring_rig
from ...core.physics.paper import Params
from ...core.physics.scenario import ClothGrid, Handle, Scenario, paper_scenario
from .. import scene as S

# ================================================================ settings


def props(scene):
    p = getattr(scene, "clothfit", None)
    if p is None:
        raise ClothFitError("Cloth Fit is not registered (scene.clothfit is missing)")
    return p


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
        raise ClothFitError(
            f"{what} {path!r} is relative to the .blend file, which is not saved yet: "
            f"save the file or give an absolute path"
        )
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


# ===================================================================== rig


def rig_from_props(scene):
    p = props(scene)
    if p.rig_source == "PRESET":
        return load_rig(bpy.path.abspath(p.rig_preset) if p.rig_preset.startswith("//") else p.rig_preset)
    return ring_rig(
        n_per_ring=(p.ring_cameras,),
        elevations_deg=(p.ring_elevation,),
        distance=p.ring_distance,
        target=(0.0, 0.0, p.ring_target_z),
        width=p.ring_width,
        height=p.ring_height,
        fx=p.ring_fx,
        azimuth_offsets_deg=(0.0,),
    )


def rig_cameras(scene):
    """Core Cameras of the rig as Blender renders it now (float32 settings, evaluated transforms)."""
    return S.rig_cameras(scene)


PAR_APPROX_LIMIT = 0.01  # fx/fy ratios of one rig may differ this much (relative) and still be shown


EXACT_MATCH_TOL = {"K": 1e-3, "R": 1e-5, "C": 1e-5}  # px, -, m: a Blender camera still shows its exact one


def cameras_to_json(cameras) -> str:
    """Exact JSON of cameras (float64 repr); all-zero distortion is left out."""
    out = []
    for c in cameras:
        d = c.to_dict()
        if not np.any(c.dist != 0):
            d.pop("dist", None)
        out.append(d)
    return dumps(out, indent=None)


def cameras_from_json(text, where="scene.clothfit.rig_cameras_json"):
    data = loads(text, where)
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
                f"rig must share fx/fy (within {100 * PAR_APPROX_LIMIT:g} % they are shown approximately)"
            )
        shown, off = [], 0.0
        for c in cameras:
            K = c.K.copy()
            K[1, 1] = K[0, 0] / par
            off = max(off, abs(K[1, 1] - c.K[1, 1]))
            shown.append(Camera(K, c.R, c.t, c.width, c.height, c.name))
        notes.append(
            f"the cameras' fx/fy differ ({pars.min():.6g} to {pars.max():.6g}) but Blender has one pixel "
            f"aspect per scene: the Blender cameras use fx/fy = {par:.6g} (fy off by up to {off:.3g} px); "
            f"export keeps the exact cameras"
        )
    else:
        shown = [Camera(c.K, c.R, c.t, c.width, c.height, c.name) for c in cameras]
    distorted = [c.name for c in cameras if c.dist.size and np.any(c.dist != 0)]
    if distorted:
        notes.append(
            f"{len(distorted)} camera(s) have lens distortion ({', '.join(distorted[:4])}"
            f"{', ...' if len(distorted) > 4 else ''}): Blender shows the undistorted pinhole view; "
            f"the exact cameras (with distortion) are kept for export and fitting"
        )
    S.check_rig(shown)
    return shown, notes


def _same_view(a, b):
    tol = EXACT_MATCH_TOL
    return (
        (a.width, a.height) == (b.width, b.height)
        and np.abs(a.K - b.K).max() <= tol["K"]
        and np.abs(a.R - b.R).max() <= tol["R"]
        and np.abs(a.center - b.center).max() <= tol["C"]
    )


def exact_rig_cameras(scene, objs=None):
    """Per rig camera (rig order): ``(blender, exact, shown)``.

    ``blender``: the camera as Blender renders it now (float32 settings); ``exact``: the imported
    or loaded camera (float64, lens distortion) when the Blender camera still shows it (not moved,
    not re-aimed: within ``EXACT_MATCH_TOL``), else None; ``shown``: float64 pinhole that Blender
    shows for it (``exact`` without distortion, fy adjusted to the scene's pixel aspect), or None."""
    p = props(scene)
    objs = S.rig_objects(scene) if objs is None else objs
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


# =================================================================== cloth


def grid_from_props(scene) -> ClothGrid:
    p = props(scene)
    return ClothGrid(p.cloth_nx, side=p.cloth_side, height=p.cloth_height)


def capture_scenario(scene):
    """The loaded capture's scenario (handles, settling), for scenario source CAPTURE."""
    from ...core.observation.capture import load_capture as core_load

    return core_load(capture_dir(scene)).scenario


def scenario_for(scene, grid: ClothGrid, times=None, notes=None):
    """The manipulation to simulate: the paper's (panel settings), the loaded capture's, or the
    linked empties' (``scenario_source`` SETTINGS / CAPTURE / EMPTIES; ``notes`` as in
    ``empties_scenario``)."""
    p = props(scene)
    times = times if times is not None else parse_times(p.frame_times)
    if p.scenario_source == "CAPTURE":
        sc = capture_scenario(scene)
        g = sc.grid
        if (g.nx, g.ny) != (grid.nx, grid.ny):
            raise ClothFitError(
                f"the capture's cloth is a {g.nx}x{g.ny} grid but the scene's cloth is "
                f"{grid.nx}x{grid.ny}: rebuild the cloth"
            )
        return sc.with_frames(times)
    if p.scenario_source == "EMPTIES":
        return empties_scenario(scene, grid, times, notes)
    if not 0 <= p.released_corner <= 3:
        raise ClothFitError(f"released corner {p.released_corner} must be 0..3")
    sc = paper_scenario(grid, frame_times=times, released_corner=p.released_corner)
    sc.settle_time = float(p.settle_time)
    return sc


def cloth_object(scene):
    """The cloth object, checked against the grid it was built from (missing / edited = error)."""
    return _checked_cloth(scene)[0]


def _checked_cloth(scene):
    """(cloth object, its grid), checked (missing / edited = error)."""
    obj = props(scene).cloth_object
    if obj is None or obj.name not in bpy.data.objects or obj.users == 0:
        obj = bpy.data.objects.get(S.CLOTH_NAME)
    if obj is None:
        raise ClothFitError("the cloth object is missing: build the cloth first")
    return obj, S.check_cloth(obj)


def scene_scenario(scene, times=None):
    """(the manipulation at ``times`` on the built cloth's grid, the cloth object)."""
    obj, grid = _checked_cloth(scene)
    return scenario_for(scene, grid, times), obj


def scene_grid(scene) -> ClothGrid:
    """The grid of the built cloth, else the one the cloth settings describe."""
    try:
        return S.grid_from_object(cloth_object(scene))
    except ClothFitError:
        return grid_from_props(scene)


# ==================================================== handles from empties


def handle_links(scene, grid: ClothGrid):
    """The Empties manipulation's links, checked: [(link, vertex index)]. Errors name the link."""
    p = props(scene)
    if not len(p.handles):
        raise ClothFitError(
            "the manipulation source is Empties but no handle is linked: add a handle empty "
            "(or link an empty to a grid vertex)"
        )
    out, seen = [], {}
    for i, link in enumerate(p.handles):
        obj = link.empty
        name = f"handle #{i + 1}"
        if obj is None:
            raise ClothFitError(
                f"{name} (row {link.row}, column {link.column}) has no empty: pick one or remove the handle"
            )
        name += f" ('{obj.name}')"
        if obj.name not in scene.objects:
            raise ClothFitError(
                f"{name}: the empty is not in the scene (deleted?): link another one or remove the handle"
            )
        if obj.type != "EMPTY":
            raise ClothFitError(f"{name}: '{obj.name}' is a {obj.type}, not an empty")
        if not (0 <= link.row < grid.ny and 0 <= link.column < grid.nx):
            raise ClothFitError(
                f"{name}: vertex row {link.row}, column {link.column} is outside the {grid.nx}x"
                f"{grid.ny} cloth grid (rows 0..{grid.ny - 1}, columns 0..{grid.nx - 1})"
            )
        v = link.row * grid.nx + link.column
        if v in seen:
            raise ClothFitError(
                f"{name}: vertex row {link.row}, column {link.column} is already linked by "
                f"{seen[v]}: one handle per vertex"
            )
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
        notes.append(
            f"frame rate changed from {old:g} to {scene.render.fps} fps so that every capture time is a "
            f"whole frame: the empties' keyframes are read at {scene.render.fps} fps"
        )
    rate = scene.render.fps / scene.render.fps_base
    f0 = scene.frame_start - int(math.ceil(settle * rate - 1e-6))  # settle is float32
    f1 = S.frame_of_time(scene, times[-1])
    frames = np.arange(f0, f1 + 1)
    pos = S.sample_world_positions(scene, [link.empty for link, _ in links], frames)
    ts = S.time_of_frame(scene, frames)
    handles = []
    for (link, v), P in zip(links, pos):
        kt, kp = S.simplify_track(ts, P)
        handles.append(Handle(v, kt, kp, float(link.release_time) if link.use_release else None))
    return Scenario(grid, handles, times, settle_time=settle)


# ======================================================= capture directory


def refuse_foreign_capture(root, own_prefix, who, what):
    """Never overwrite a capture that this writer did not write (real footage, synthetic...): the
    capture.json in ``root`` must name a generator starting with ``own_prefix``."""
    path = os.path.join(root, "capture.json")
    if not os.path.isfile(path):
        return
    try:
        gen = str((read_json(path, "capture").get("meta") or {}).get("generator", ""))
    except (ClothFitError, AttributeError):
        gen = "?"
    if not gen.startswith(own_prefix):
        raise ClothFitError(
            f"{root} already holds a capture written by {gen or 'another tool'!r}; {who} "
            f"only overwrites its own {what}: choose another capture directory"
        )


# ============================================================ read once


@dataclass(frozen=True)
class SceneInputs:
    """What the scene holds for a step, read once (``read_scene``) as core objects.

    ``times``: the capture times [s]; ``grid``: the built cloth's grid; ``scenario``: the
    manipulation at ``times``; ``params``: m, k, l, d. Read on request (else None):
    ``capture_dir`` (absolute); ``cameras`` (the rig as Blender renders it: the exact imported
    camera without lens distortion while the Blender camera still shows it, else the Blender
    camera) with ``exact`` (per camera the imported camera with distortion, or None);
    ``shapes`` (the baked positions (F, V, 3) at ``times``). The Blender objects a renderer
    needs: ``cloth`` and ``camera_objects`` (rig order). ``notes``: what reading changed in the
    scene (the Empties manipulation sets a frame rate at which every time is a whole frame)."""

    times: tuple
    grid: ClothGrid
    scenario: Scenario
    params: Params
    capture_dir: str | None = None
    cameras: tuple | None = None
    exact: tuple | None = None
    shapes: np.ndarray | None = None
    cloth: object = None
    camera_objects: tuple = ()
    notes: tuple = ()

    @property
    def distortion_dropped(self):
        """Names of the cameras whose lens distortion a Blender render cannot show."""
        return [e.name for e in self.exact or () if e is not None and e.dist.size and np.any(e.dist != 0)]


def read_scene(scene, times=None, *, capture=False, out_dir=None, rig=False, baked=False) -> SceneInputs:
    """Read the scene once into a ``SceneInputs``; errors are one-line ``ClothFitError``.

    Always: the capture times (``times``, default the Times property), the cloth (checked), its
    grid, the manipulation at those times and the parameters. ``capture``: also the capture
    directory (``out_dir`` when given, else the Capture property); ``rig``: the rig's cameras;
    ``baked``: the cloth's baked shapes at the times (error when one is missing)."""
    p = props(scene)
    times = parse_times(p.frame_times) if times is None else sorted(float(t) for t in times)
    root = None
    if capture or out_dir:
        root = abspath(out_dir, "capture directory") if out_dir else capture_dir(scene)
    objs = S.rig_objects(scene) if rig else ()
    cloth, grid = _checked_cloth(scene)
    notes = []
    scenario = scenario_for(scene, grid, times, notes)
    shapes = None
    if baked:
        have = {f"{t:.3f}" for t in S.baked_times(cloth)}
        missing = [t for t in times if f"{t:.3f}" not in have]
        if missing:
            raise ClothFitError(
                f"the cloth is not baked at t = {missing[0]:.3f} s ({len(missing)} capture times "
                f"missing): simulate first"
            )
        shapes = S.baked_positions(cloth, times)
    cameras = exact = None
    if rig:
        rows = exact_rig_cameras(scene, objs)
        cameras = tuple(sh if sh is not None else b for b, _, sh in rows)
        exact = tuple(ex for _, ex, _ in rows)
    return SceneInputs(
        times=tuple(times),
        grid=grid,
        scenario=scenario,
        params=params_from_scene(scene),
        capture_dir=root,
        cameras=cameras,
        exact=exact,
        shapes=shapes,
        cloth=cloth,
        camera_objects=tuple(objs),
        notes=tuple(notes),
    )
