"""A user's cloth object read as Blender's cloth reads it, for the core's ``blender`` model
(``core/physics/blender_scene.SceneCloth``): the core model built from what this returns follows
Blender's solver bit for bit on the user's own mesh, transform, pin group and release set-up.

What the Cloth modifier reads (``blenkernel/intern/cloth.cc``): at its cache's first frame the
mesh it receives (the result of the modifiers above it), transformed to world space in float32
(``mul_m4_v3``): rest lengths, rest angles and the first positions come from there; every later
frame, the world positions of the same input for the pinned vertices and the weights of its pin
group (``vertex_group_mass``) in that input; its springs from that input's edges and faces (a
Subdivision modifier above the cloth is simulated subdivided). So the input is read with the Cloth modifier (and
everything below it) switched off, frame by frame: hooks, armatures, keyed Vertex Weight
modifiers and object animation all show up as they reach the cloth, whatever the user used.

Not modelled by the core (listed in ``SceneCloth.info["not_modelled"]``, the caller decides):
collisions with collider objects and self-collision, pressure, internal springs, sewing,
shrinking, Dynamic Mesh, per-vertex stiffness groups, force fields.
"""

from __future__ import annotations

import bpy
import numpy as np

from ..core.errors import ClothFitError
from ..core.physics.blender_scene import SceneCloth, world_f32
from .cloth import cloth_modifier, read_settings, scene_fps


def _input_mesh(obj, group_index, topology=False):
    """(local positions (V, 3) float32, pin weights (V,) float32, matrix_world float32 and, with
    ``topology``, (edges, faces, loop triangles)) of the evaluated object at the current frame."""
    dg = bpy.context.evaluated_depsgraph_get()
    ev = obj.evaluated_get(dg)
    me = ev.to_mesh()
    try:
        V = len(me.vertices)
        co = np.zeros(V * 3, dtype=np.float32)
        me.vertices.foreach_get("co", co)
        w = np.zeros(V, dtype=np.float32)
        if group_index >= 0:
            for v in me.vertices:
                for g in v.groups:
                    if g.group == group_index:
                        w[v.index] = g.weight
        M = np.array(ev.matrix_world, dtype=np.float32)
        topo = None
        if topology:
            edges = np.zeros(len(me.edges) * 2, dtype=np.int64)
            me.edges.foreach_get("vertices", edges)
            faces = [list(p.vertices) for p in me.polygons]
            me.calc_loop_triangles()
            tris = np.zeros(len(me.loop_triangles) * 3, dtype=np.int64)
            me.loop_triangles.foreach_get("vertices", tris)
            topo = (edges.reshape(-1, 2), faces, tris.reshape(-1, 3))
    finally:
        ev.to_mesh_clear()
    return co.reshape(-1, 3), w, M, topo


def not_modelled(scene, obj, cl) -> list:
    """The features of this cloth the core's blender model does not have."""
    cs, co = cl.settings, cl.collision_settings
    out = []
    colliders = sorted(
        o.name
        for o in scene.objects
        if o is not obj and o.type == "MESH" and any(m.type == "COLLISION" for m in o.modifiers)
    )
    if co.use_collision and colliders:
        out.append(f"collisions with {', '.join(colliders)}")
    if co.use_self_collision:
        out.append("self-collision")
    if cs.use_pressure:
        out.append("pressure")
    if cs.use_internal_springs:
        out.append("internal springs")
    if cs.use_sewing_springs:
        out.append("sewing springs")
    if cs.shrink_min != 0.0 or cs.shrink_max != 0.0 or cs.vertex_group_shrink:
        out.append("shrinking")
    if cs.use_dynamic_mesh:
        out.append("dynamic mesh")
    for n in (
        "vertex_group_structural_stiffness",
        "vertex_group_shear_stiffness",
        "vertex_group_bending",
        "vertex_group_intern",
        "vertex_group_pressure",
    ):
        if getattr(cs, n, ""):
            out.append(f"{n} '{getattr(cs, n)}'")
    fields = sorted(o.name for o in scene.objects if o.field is not None and o.field.type != "NONE")
    if fields:
        out.append(f"force fields {', '.join(fields)}")
    if cs.effector_weights.gravity != 1.0 or not scene.use_gravity:
        out.append(
            f"gravity weight {cs.effector_weights.gravity:g} (scene gravity {'on' if scene.use_gravity else 'off'})"
        )
    return out


def read_scene_cloth(scene, obj, n_frames: int, info=None) -> SceneCloth:
    """Read ``obj``'s cloth as Blender's solver receives it, from its cache's first frame through
    ``n_frames`` more. Leaves the scene at the first frame with the Cloth modifier as it was (its
    cache is freed by the read)."""
    cl = cloth_modifier(obj)
    if cl is None:
        raise ClothFitError(f"object '{obj.name}' has no Cloth modifier")
    f0 = int(cl.point_cache.frame_start)
    if cl.point_cache.frame_end < f0 + n_frames:
        raise ClothFitError(
            f"the cloth cache of '{obj.name}' ends at frame {cl.point_cache.frame_end}, before frame {f0 + n_frames}"
        )
    cs = cl.settings
    gname = cs.vertex_group_mass
    gi = obj.vertex_groups[gname].index if gname and gname in obj.vertex_groups else -1
    stack = list(obj.modifiers)
    below = stack[stack.index(cl) :]  # the cloth and what comes after it
    was = [m.show_viewport for m in below]
    frames_co, frames_w, mats, topo = [], [], [], None
    try:
        for m in below:
            m.show_viewport = False
        for f in range(f0, f0 + n_frames + 1):
            scene.frame_set(f)
            co, w, M, t = _input_mesh(obj, gi, topology=topo is None)
            topo = topo or t
            frames_co.append(co)
            frames_w.append(w)
            mats.append(M)
    finally:
        for m, s in zip(below, was):
            m.show_viewport = s
        scene.frame_set(f0)
    V = frames_co[0].shape[0]
    if any(c.shape[0] != V for c in frames_co):
        raise ClothFitError(
            f"object '{obj.name}': the cloth's input changes its vertex count over the frames "
            f"(Blender restarts such a cloth)"
        )
    W = np.array(frames_w)
    hv = np.nonzero((W > 0).any(0))[0]
    rest = world_f32(mats[0], frames_co[0])
    targets = np.array([world_f32(M, c[hv]) for M, c in zip(mats, frames_co)]).reshape(len(mats), hv.size, 3)
    edges, faces, tris = topo  # the mesh the cloth receives (modifiers above it applied)
    g = np.array(scene.gravity, dtype=np.float64) * float(cs.effector_weights.gravity) * float(scene.use_gravity)
    meta = {
        "object": obj.name,
        "scene": scene.name,
        "pin_group": gname,
        "modifiers": [f"{m.name} ({m.type})" for m in stack],
        "matrix_world": np.array(mats[0], dtype=np.float64).tolist(),
        "not_modelled": not_modelled(scene, obj, cl),
        "blender": bpy.app.version_string,
    }
    meta.update(info or {})
    return SceneCloth(
        rest,
        faces,
        edges,
        tris,
        hv.astype(np.int64),
        W[:, hv].astype(np.float64),
        targets,
        read_settings(cl),
        g,
        float(scene_fps(scene)),
        f0,
        meta,
    )
