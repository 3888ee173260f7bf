"""Blender's own Cloth modifier driven by a core scenario: the same mesh, pins and frames as the
core's ``blender`` model (``core.physics.blender``), so that both can be compared and a fitted
result can be replayed and applied.

The manipulation on Blender's timeline (``FramePlan``): the first frame is the rest frame, the
cloth settles for ``settle_frames`` frames and t = 0 is the release frame. Pins are the vertex
group ``clothfit_pin``: handles that stay held have weight 1; every group of handles released at
the same time gets its own group, added into ``clothfit_pin`` by a *Vertex Weight Mix* modifier
whose influence is keyed (constant interpolation) to the plan's weights: Blender re-reads the pin
weights every frame, so a handle is free from the step into the first frame after its release.
Handles that move follow a keyed empty through a *Hook* modifier. The Cloth modifier comes last.
"""

from __future__ import annotations

import time

import bpy
import mathutils
import numpy as np

from ..core.errors import ClothFitError
from ..core.physics import blender as B
from ..core.physics.colliders import blender_objects
from .cloth_script import add_colliders, set_frame_rate
from .scene import evaluated_positions, set_key_interpolation

PIN_GROUP = "clothfit_pin"
CLOTH_MODIFIER = "Cloth (Cloth Fit)"


def set_scene_fps(scene, fps: float):
    """Set the scene's frame rate to ``fps`` (fractional rates through fps_base)."""
    set_frame_rate(scene, fps)


def scene_fps(scene) -> float:
    return scene.render.fps / scene.render.fps_base


def apply_settings(cloth_modifier, settings: dict):
    """Write validated settings (ClothSettings names) onto a Cloth modifier."""
    s = B.check_settings(settings)
    cs = cloth_modifier.settings
    cs.quality = s["quality"]
    cs.bending_model = s["bending_model"]
    for n in B.FLOAT_SETTINGS:
        setattr(cs, n, s[n])
    return s


def read_settings(cloth_modifier) -> dict:
    cs = cloth_modifier.settings
    d = {"quality": int(cs.quality), "bending_model": cs.bending_model}
    d.update({n: float(getattr(cs, n)) for n in B.FLOAT_SETTINGS})
    return d


def add_pins(scene, obj, plan: B.FramePlan, frame_start: int, name_prefix="clothfit"):
    """Pin group, release animation and hooks for the plan's handles on ``obj``. Returns the names of
    the modifiers added (in stack order)."""
    hv = [int(v) for v in plan.handle_vertices]
    pin = obj.vertex_groups.get(PIN_GROUP) or obj.vertex_groups.new(name=PIN_GROUP)
    added = []
    if not hv:
        return added
    W = plan.weights  # (n_frames + 1, H)
    static = [k for k in range(len(hv)) if np.all(W[:, k] == W[0, k])]
    pin.add(hv, 0.0, "REPLACE")
    for k in static:
        pin.add([hv[k]], float(W[0, k]), "REPLACE")
    # moving handles: hooks to keyed empties (positions at every frame, linear between)
    T = plan.targets
    for k, v in enumerate(hv):
        if np.allclose(T[:, k], T[0, k], rtol=0, atol=1e-12):
            continue
        emp = bpy.data.objects.new(f"{name_prefix}_handle_{v}", None)
        emp.empty_display_size = 0.005
        scene.collection.objects.link(emp)
        emp.location = T[0, k]
        for f in range(T.shape[0]):
            emp.location = T[f, k]
            emp.keyframe_insert("location", frame=frame_start + f)
        set_key_interpolation(emp, "LINEAR")
        hook = obj.modifiers.new(f"{name_prefix} hook {v}", "HOOK")
        hook.object = emp
        hook.vertex_indices_set([v])
        hook.falloff_type = "NONE"
        hook.strength = 1.0
        # the hook moves the vertex by the empty's displacement from its first-frame place (a Matrix:
        # a nested list is read column by column, which put the translation in the bottom row)
        hook.matrix_inverse = mathutils.Matrix.Translation([-float(c) for c in T[0, k]])
        added.append(hook.name)
    # handles released (or re-pinned) over time: one group and one keyed mix per weight track
    tracks = {}
    for k in range(len(hv)):
        if k in static:
            continue
        tracks.setdefault(tuple(np.round(W[:, k], 12)), []).append(k)
    for n, (track, ks) in enumerate(tracks.items()):
        g = obj.vertex_groups.new(name=f"{PIN_GROUP}_{n}")
        g.add([hv[k] for k in ks], 1.0, "REPLACE")
        mix = obj.modifiers.new(f"{name_prefix} pin release {n}", "VERTEX_WEIGHT_MIX")
        mix.vertex_group_a, mix.vertex_group_b = PIN_GROUP, g.name
        mix.mix_mode, mix.mix_set = "ADD", "B"
        prev = None
        for f, w in enumerate(track):
            if w != prev:
                mix.mask_constant = float(w)
                mix.keyframe_insert("mask_constant", frame=frame_start + f)
                prev = w
        added.append(mix.name)
    set_key_interpolation(obj, "CONSTANT")
    return added


def build_cloth_object(
    scene,
    net: B.Network,
    plan: B.FramePlan,
    settings: dict,
    name="Blender Cloth",
    frame_start: int = 1,
    faces=None,
    colliders=None,
):
    """A mesh object with the network's first-frame positions and ``faces``, its pins and a Cloth
    modifier with ``settings``; ``colliders`` (a scenario's ``Collisions``): collider objects with a
    Collision modifier and the cloth's collisions on (``add_scene_colliders``), else collisions off."""
    faces = net.faces if faces is None else faces
    me = bpy.data.meshes.new(name)
    # the edges in the network's order: Blender builds its structural springs in mesh edge order
    me.from_pydata(net.rest.tolist(), net.edges.tolist(), [list(map(int, f)) for f in faces])
    me.update()
    obj = bpy.data.objects.new(name, me)
    scene.collection.objects.link(obj)
    add_pins(scene, obj, plan, frame_start)
    cl = obj.modifiers.new(CLOTH_MODIFIER, "CLOTH")
    apply_settings(cl, settings)
    cs = cl.settings
    cs.vertex_group_mass = PIN_GROUP if len(plan.handle_vertices) else ""
    cs.use_pressure = False
    cs.use_internal_springs = False
    cs.use_dynamic_mesh = False
    cs.shrink_min = 0.0
    cl.collision_settings.use_collision = False
    cl.collision_settings.use_self_collision = False
    if colliders is not None:
        add_scene_colliders(scene, obj, colliders)
    cl.point_cache.frame_start = frame_start
    cl.point_cache.frame_end = frame_start + plan.n_frames
    set_scene_fps(scene, plan.fps)
    scene.frame_start = frame_start
    scene.frame_end = max(scene.frame_end, frame_start + plan.n_frames)
    return obj


def add_scene_colliders(scene, obj, colliders):
    """A scenario's colliders (``Collisions``) beside the cloth ``obj``: mesh objects with a Collision
    modifier (``cloth_script.add_colliders``, what the exported script does) and the cloth's collision
    settings; their names are kept on ``obj`` so that ``remove_cloth_object`` removes them too."""
    made = add_colliders(
        blender_objects(colliders, f"{obj.name} collider"), colliders.settings_dict(), obj.name, scene=scene
    )
    obj["clothfit_colliders"] = [o.name for o in made]
    return made


def cloth_modifier(obj):
    for m in obj.modifiers:
        if m.type == "CLOTH":
            return m
    return None


def simulate_frames(scene, obj, n_frames: int, frame_start: int | None = None):
    """Step Blender's cloth on ``obj`` from its first frame through ``n_frames`` more, in order
    (the point cache holds the simulation); returns world positions ``(n_frames + 1, V, 3)``, the
    seconds it took and the solver's mean CG iterations per step (None if Blender does not say)."""
    cl = cloth_modifier(obj)
    if cl is None:
        raise ClothFitError(f"object '{obj.name}' has no Cloth modifier")
    f0 = cl.point_cache.frame_start if frame_start is None else frame_start
    if cl.point_cache.frame_end < f0 + n_frames:
        raise ClothFitError(
            f"the cloth cache of '{obj.name}' ends at frame {cl.point_cache.frame_end}, before frame {f0 + n_frames}"
        )
    t0 = time.perf_counter()
    scene.frame_set(f0)
    out = [evaluated_positions(obj)]
    its = []
    for f in range(f0 + 1, f0 + n_frames + 1):
        scene.frame_set(f)
        out.append(evaluated_positions(obj))
        sr = getattr(cl, "solver_result", None)
        if sr is not None and sr.status:
            its.append(sr.avg_iterations)
    secs = time.perf_counter() - t0
    return np.array(out), secs, (float(np.mean(its)) if its else None)


def remove_cloth_object(obj):
    """Remove a cloth object ``build_cloth_object`` made: the object, its mesh when nothing else uses
    it, and the keyed empties its hooks follow (``add_pins``) when no other object hooks them."""
    empties = [m.object for m in obj.modifiers if m.type == "HOOK" and m.object is not None]
    for name in obj.get("clothfit_colliders", []):
        col = bpy.data.objects.get(name)
        if col is not None:
            cme = col.data
            bpy.data.objects.remove(col, do_unlink=True)
            if cme is not None and cme.users == 0:
                bpy.data.meshes.remove(cme)
    me = obj.data
    bpy.data.objects.remove(obj, do_unlink=True)
    if me is not None and me.users == 0:
        bpy.data.meshes.remove(me)
    for emp in empties:
        hooked = any(m.type == "HOOK" and m.object == emp for o in bpy.data.objects for m in o.modifiers)
        if not hooked:
            bpy.data.objects.remove(emp, do_unlink=True)


def free_cache(obj):
    cl = cloth_modifier(obj)
    if cl is not None:
        cl.point_cache.frame_end = cl.point_cache.frame_end  # touching the cache settings frees it


def replay(scene, scenario, settings: dict, fps: float, frame_start: int = 1):
    """Blender's own solver on a core scenario: build the cloth (the core blender model's mesh, pins
    and release) with ``settings``, step it and return its vertices at the scenario's capture
    times ``(F, V, 3)`` (read like the core model: linear between frames), then remove it."""
    from ..core.physics.models import BlenderModel

    given = dict(settings)
    given.setdefault("time_scale", B.physical_time_scale(fps))
    s = B.check_settings(given, "replay settings")
    model = BlenderModel(fps, s["quality"], s["bending_model"])
    net, plan = model.plan(scenario)
    set_scene_fps(scene, fps)
    obj = build_cloth_object(
        scene, net, plan, s, name="Replay Cloth", frame_start=frame_start, colliders=scenario.colliders
    )
    try:
        frames, _, _ = simulate_frames(scene, obj, plan.n_frames, frame_start)
    finally:
        remove_cloth_object(obj)
    return plan.sample(frames)
