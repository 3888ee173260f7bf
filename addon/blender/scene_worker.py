"""One Blender scene in a worker process: a user's .blend with a cloth object, simulated by
Blender's own solver for candidate Cloth settings (the ``--backend blender`` fit).

Runs only in worker processes (Ray actors or spawned pool processes, ``addon.farm``): it imports
``bpy``; the fitting process never does. The .blend is opened once per worker; each candidate's
``ClothSettings`` are written onto the object's Cloth modifier, the scene is stepped frame by frame
from the cloth cache's first frame, and the evaluated (world) vertices are read at the asked
frames (linear between whole frames, as the core's blender model reads capture times).
"""

from __future__ import annotations

import os
import time

import bpy
import numpy as np

from ..core.errors import ClothFitError
from .cloth import apply_settings, cloth_modifier, read_settings, scene_fps
from .render import quiet_stdout
from .scene import evaluated_positions

FLY_AWAY_M = 100.0  # a vertex this far from where it started = a failed (exploded) candidate


def cloth_objects(scene):
    return [o for o in scene.objects if o.type == "MESH" and cloth_modifier(o) is not None]


def find_cloth_object(scene, name=None, where="scene"):
    """The named object (it must have a Cloth modifier) or the scene's only mesh with one."""
    if name:
        obj = scene.objects.get(name)
        if obj is None:
            raise ClothFitError(f"{where}: no object named '{name}' in scene '{scene.name}'")
        if cloth_modifier(obj) is None:
            raise ClothFitError(f"{where}: object '{name}' has no Cloth modifier")
        return obj
    found = cloth_objects(scene)
    if not found:
        raise ClothFitError(f"{where}: no mesh object with a Cloth modifier in scene '{scene.name}'")
    if len(found) > 1:
        raise ClothFitError(
            f"{where}: {len(found)} objects have a Cloth modifier "
            f"({', '.join(sorted(o.name for o in found))}): choose one with --object"
        )
    return found[0]


def _free_bake(cl):
    cache = cl.point_cache
    if cache.is_baked:
        with bpy.context.temp_override(point_cache=cache):
            bpy.ops.ptcache.free_bake()
        if cache.is_baked:
            raise ClothFitError("the cloth cache is baked and could not be freed: free the bake in the .blend")


class BlendScene:
    """The .blend ``path`` opened in this process, its cloth object found (``object_name`` or the
    only mesh with a Cloth modifier)."""

    def __init__(self, path, object_name=None):
        if not os.path.isfile(path):
            raise ClothFitError(f"Blender scene {path}: file not found")
        try:
            with quiet_stdout():  # Blender's 'Read blend: ...' line: noise in the driver's output
                bpy.ops.wm.open_mainfile(filepath=str(path), load_ui=False)
        except RuntimeError as e:
            raise ClothFitError(f"Blender scene {path}: cannot open it ({str(e).strip().splitlines()[-1]})") from None
        self.path = str(path)
        self.scene = bpy.context.scene
        self.obj = find_cloth_object(self.scene, object_name, f"Blender scene {os.path.basename(path)}")
        self.cloth = cloth_modifier(self.obj)
        _free_bake(self.cloth)
        self.initial = read_settings(self.cloth)
        self.evaluations = 0

    def info(self) -> dict:
        sc, cl = self.scene, self.cloth
        cache = cl.point_cache
        sc.frame_set(cache.frame_start)
        dg = bpy.context.evaluated_depsgraph_get()
        ev = self.obj.evaluated_get(dg)
        me = ev.to_mesh()
        try:
            me.calc_loop_triangles()
            tris = np.zeros(len(me.loop_triangles) * 3, dtype=np.int32)
            me.loop_triangles.foreach_get("vertices", tris)
            n_ev = len(me.vertices)
        finally:
            ev.to_mesh_clear()
        if n_ev != len(self.obj.data.vertices):
            raise ClothFitError(
                f"object '{self.obj.name}': its modifiers change the vertex count "
                f"({len(self.obj.data.vertices)} -> {n_ev}); the cloth must be read as simulated"
            )
        colliders = sorted(
            o.name
            for o in sc.objects
            if o is not self.obj and o.type == "MESH" and any(m.type == "COLLISION" for m in o.modifiers)
        )
        return {
            "blend": self.path,
            "object": self.obj.name,
            "scene": sc.name,
            "n_vertices": int(n_ev),
            "triangles": tris.reshape(-1, 3).tolist(),
            "settings": dict(self.initial),
            "fps": float(scene_fps(sc)),
            "frame_start": int(sc.frame_start),
            "frame_end": int(sc.frame_end),
            "cache_start": int(cache.frame_start),
            "cache_end": int(cache.frame_end),
            "colliders": colliders,
            "self_collision": bool(cl.collision_settings.use_self_collision),
            "blender": bpy.app.version_string,
            "pid": os.getpid(),
        }

    def simulate(self, settings: dict, frames) -> dict:
        """Blender's cloth with ``settings`` (ClothSettings values) read at the (fractional) scene
        ``frames``: ``{"positions": (F, V, 3), "exploded": bool, "reason": str, "seconds": float, "cpu_seconds": float}``
        (this process's CPU time: above ``seconds`` when Blender's solver runs on several threads)."""
        t0, c0 = time.perf_counter(), time.process_time()
        sc, cl = self.scene, self.cloth
        frames = np.asarray(frames, dtype=np.float64)
        apply_settings(cl, settings)
        cache = cl.point_cache
        cache.frame_end = cache.frame_end  # touching the cache settings frees it
        f0 = int(cache.frame_start)
        lo = np.floor(frames).astype(np.int64)
        w = frames - lo
        hi = np.where(w > 1e-9, lo + 1, lo)
        last = int(hi.max())
        if lo.min() < f0 or last > cache.frame_end:
            raise ClothFitError(
                f"frames {frames.min():g}..{frames.max():g} outside the cloth cache "
                f"{f0}..{cache.frame_end} of '{self.obj.name}'"
            )
        need = set(lo.tolist()) | set(hi.tolist())
        got = {}
        sc.frame_set(f0)
        if f0 in need:
            got[f0] = evaluated_positions(self.obj)
        start = got[f0] if f0 in got else evaluated_positions(self.obj)
        exploded, reason = False, ""
        for f in range(f0 + 1, last + 1):
            sc.frame_set(f)
            if f in need:
                x = got[f] = evaluated_positions(self.obj)
                if not np.all(np.isfinite(x)):
                    exploded, reason = True, f"non-finite vertices at frame {f}"
                    break
                if np.max(np.linalg.norm(x - start, axis=-1)) > FLY_AWAY_M:
                    exploded, reason = True, f"flew away (> {FLY_AWAY_M:g} m) by frame {f}"
                    break
        self.evaluations += 1
        if exploded:
            pos = None
        else:
            pos = (1.0 - w)[:, None, None] * np.stack([got[int(f)] for f in lo]) + w[:, None, None] * np.stack(
                [got[int(f)] for f in hi]
            )
        return {
            "positions": pos,
            "exploded": exploded,
            "reason": reason,
            "seconds": time.perf_counter() - t0,
            "cpu_seconds": time.process_time() - c0,
            "frames": last - f0,
        }

    def pid(self):
        return os.getpid()
