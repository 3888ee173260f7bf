"""A Blender scene the core's models cannot emulate, for the ``--backend blender`` fit:
a square cloth hung by its four corners, settled, released at t = 0, falling onto a box collider
narrower than the cloth (so it drapes over the box's edges), with cloth-object collisions on.

``build_scene`` writes the .blend (the cloth with *starting* settings, not the truth);
``observe`` simulates it with Blender's own solver at the *true* settings and writes a capture
(silhouettes by the core rasteriser from a camera rig, the true vertices as shapes), so a fit
on the capture with the .blend must find settings that make Blender replay the observed motion.
Needs the bpy module.
"""

from __future__ import annotations

import os

import bpy
import numpy as np

from ..core import defaults as D
from ..core.errors import ClothFitError
from ..core.observation.camera import load_rig
from ..core.observation.capture import write_capture
from ..core.observation.raster import silhouette
from ..core.physics import blender as B
from ..core.physics.models import BlenderModel
from ..core.physics.scenario import ClothGrid, Handle, Scenario
from .cloth import build_cloth_object, cloth_modifier

# true settings of the observed cloth (a soft cotton at 24 fps, real-time time scale)
TRUTH = {
    "tension_stiffness": 40.0,
    "compression_stiffness": 40.0,
    "shear_stiffness": 8.0,
    "bending_stiffness": 0.2,
    "tension_damping": 5.0,
    "shear_damping": 5.0,
    "bending_damping": 0.5,
    "air_damping": 2.0,
}


def collider_scenario(n=9, side=0.10, settle=0.25, after=0.5, fps=24.0, every=1, release="all") -> Scenario:
    """All four corners held for ``settle`` s; at t = 0 all of them released (``release="all"``: the
    cloth falls flat onto the box) or only the first (``"corner"``, the paper's release: the cloth
    swings free about the other corners before its corner strikes the box); capture times every
    ``every`` frames for ``after`` s."""
    if release not in ("all", "corner"):
        raise ClothFitError(f"collider scene: release must be 'all' or 'corner', got {release!r}")
    grid = ClothGrid(n, n, side)
    corners = grid.corners()
    handles = [
        Handle(v, [0.0], grid.rest[v][None], 0.0 if release == "all" or v == corners[0] else None) for v in corners
    ]
    times = np.arange(every, int(round(after * fps)) + 1, every) / fps
    return Scenario(grid, handles, times, settle, D.GRAVITY)


def _box(name, centre, size):
    cx, cy, cz = centre
    sx, sy, sz = (s / 2 for s in size)
    V = [(cx + a * sx, cy + b * sy, cz + c * sz) for a in (-1, 1) for b in (-1, 1) for c in (-1, 1)]
    F = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    me = bpy.data.meshes.new(name)
    me.from_pydata(V, [], F)
    me.update()
    return bpy.data.objects.new(name, me)


def build_scene(path, scenario: Scenario, settings=None, fps=24.0, drop=0.03, box=0.06, frame_start=1):
    """Write the .blend: the cloth ("Cloth", a Cloth modifier with ``settings`` (default: Blender's
    own defaults with the real-time time scale) and collisions on) over a box collider ("Table")
    whose top lies ``drop`` below the cloth. Returns the scene frame of t = 0."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    given = dict(settings or {})
    given.setdefault("time_scale", B.physical_time_scale(fps))
    s = B.check_settings(given, "scene cloth settings")
    model = BlenderModel(fps, s["quality"], s["bending_model"])
    net, plan = model.plan(scenario)
    obj = build_cloth_object(scene, net, plan, s, name="Cloth", frame_start=frame_start)
    cl = cloth_modifier(obj)
    cl.collision_settings.use_collision = True
    cl.collision_settings.distance_min = 0.002
    top = scenario.grid.height - drop
    table = _box("Table", (0.0, 0.0, top - box / 2), (box, box, box))
    scene.collection.objects.link(table)
    col = table.modifiers.new("Collision", "COLLISION")
    table.collision.thickness_outer = 0.002
    table.collision.cloth_friction = 5.0
    del col
    scene.frame_start = frame_start
    scene.frame_end = frame_start + plan.n_frames
    scene.frame_set(frame_start)
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    bpy.ops.wm.save_as_mainfile(filepath=os.path.abspath(path))
    return frame_start + plan.settle_frames


def observe(path, scenario: Scenario, capture_dir, settings=None, frame_zero=None, rig="ring8", resolution=(90, 120)):
    """Blender's own solver on the scene ``path`` at ``settings`` (default ``TRUTH`` on the scene's
    other values) at the scenario's capture times; silhouettes by the core rasteriser. Writes the
    capture (with the true vertices as its shapes) and returns ``(capture, true settings)``."""
    from .scene_worker import BlendScene

    bs = BlendScene(path)
    info = bs.info()
    truth = dict(info["settings"])
    truth.update(TRUTH if settings is None else settings)
    truth = B.check_settings(truth, "true settings")
    f0 = info["frame_start"] if frame_zero is None else frame_zero
    frames = f0 + np.asarray(scenario.frame_times) * info["fps"]
    r = bs.simulate(truth, frames)
    if r["exploded"]:
        raise ClothFitError(f"the true settings explode: {r['reason']}")
    X = r["positions"]
    tris = np.asarray(info["triangles"], dtype=np.int64)
    cams = [c.resized(int(resolution[0]), int(resolution[1])) for c in load_rig(rig)]
    sils = [[silhouette(cam, X[f], tris) for f in range(X.shape[0])] for cam in cams]
    for c, row in enumerate(sils):
        for f, s in enumerate(row):
            if not s.any():
                raise ClothFitError(
                    f"camera '{cams[c].name}' does not see the cloth at t = {scenario.frame_times[f]:g} s"
                )
    meta = {
        "generator": "Blender's own cloth solver on a scene with a collider (addon/blender/collider_scene.py), "
        "core rasteriser",
        "true_blender_cloth": truth,
        "blend": os.path.abspath(path),
        "frame_zero": float(f0),
        "rig": rig,
    }
    cap = write_capture(capture_dir, cams, scenario, sils, shapes=X, cloth_mass=truth["mass"] * X.shape[1], meta=meta)
    return cap, truth
