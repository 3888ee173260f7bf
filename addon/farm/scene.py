"""The ``blender`` evaluation backend of a fit: candidates simulated by Blender's own solver on a
user's scene (a .blend with a cloth object: colliders, self-collision, its own mesh), in worker
processes (``executors``), and scored by the core's rasteriser and objective like any core model.

``BlendSceneEvaluator`` is *model-like* for ``SilhouetteObjective``: ``simulate(scenario, rows)``
returns a ``SimResult`` (rows of ``blender.FLOAT_SETTINGS``), and ``scenario(times)`` is what the
objective rasterises (the scene mesh's triangles, the capture times). Capture time ``t`` is scene
frame ``frame_zero + t * fps`` (``frame_zero`` defaults to the scene's ``frame_start``, ``fps`` is
the scene's), read linearly between whole frames.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..core.errors import ClothFitError
from ..core.location import qualified
from ..core.observation.raster import paired_quads
from ..core.physics import blender as B
from ..core.physics.paper import SimResult
from .executors import make_executor

WORKER = qualified("blender.scene_worker:BlendScene")


@dataclass
class SceneMesh:
    """What the rasteriser needs of the scene's cloth: its triangles, the same in pairs (``quads``:
    ``raster.paired_quads``) and its vertex count."""

    triangles: np.ndarray
    n_vertices: int

    @property
    def quads(self) -> np.ndarray:
        return paired_quads(self.triangles)


@dataclass
class SceneScenario:
    grid: SceneMesh
    frame_times: np.ndarray
    crop: Any = None  # the capture's crop plane (``core.physics.crop``): the model's silhouettes honour it

    def with_frames(self, times):
        return SceneScenario(self.grid, np.asarray(times, dtype=np.float64), self.crop)


class BlendSceneEvaluator:
    """Candidates' ClothSettings set on ``object_name``'s Cloth modifier in ``workers`` copies of the
    scene ``blend`` (Ray actors, or spawned processes without Ray)."""

    name = "blender"
    row_names = B.FLOAT_SETTINGS

    def __init__(self, blend, object_name=None, frame_zero=None, workers=None, address=None, executor="auto"):
        if not blend or not os.path.isfile(blend):
            raise ClothFitError(f"Blender scene {blend}: file not found")
        if not str(blend).lower().endswith(".blend"):
            raise ClothFitError(f"Blender scene {blend}: not a .blend file")
        self.blend = os.path.abspath(blend)
        t0 = time.perf_counter()
        self.executor = make_executor(WORKER, (self.blend, object_name), workers, address, executor)
        try:
            self.info = self.executor.call_first("info")
        except BaseException:
            self.executor.close()
            raise
        self.startup_s = time.perf_counter() - t0
        info = self.info
        self.object = info["object"]
        self.fps = float(info["fps"])
        self.frame_zero = float(info["frame_start"] if frame_zero is None else frame_zero)
        s = B.check_settings(info["settings"], f"Cloth settings of '{self.object}'")
        self.initial = s
        self.quality, self.bending_model = s["quality"], s["bending_model"]
        self.mesh = SceneMesh(np.asarray(info["triangles"], dtype=np.int64).reshape(-1, 3), int(info["n_vertices"]))
        self.evaluations = 0
        self.seconds = 0.0  # wall time inside simulate() (workers + transfer)
        self.worker_seconds = 0.0  # summed simulation time reported by the workers
        self.worker_cpu_seconds = 0.0  # and their CPU time

    @property
    def workers(self):
        return self.executor.workers

    def to_dict(self) -> dict:
        return {"name": "blender", "fps": self.fps, "quality": self.quality, "bending_model": self.bending_model}

    def settings(self, row) -> dict:
        return B.row_settings(row, self.quality, self.bending_model)

    def frames(self, times) -> np.ndarray:
        t = np.asarray(times, dtype=np.float64)
        f = self.frame_zero + t * self.fps
        i = self.info
        lo, hi = i["cache_start"], i["cache_end"]
        bad = (f < lo) | (np.ceil(f - 1e-9) > hi)
        if bad.any():
            k = int(np.nonzero(bad)[0][0])
            raise ClothFitError(
                f"capture time {t[k]:g} s is frame {f[k]:g} of {os.path.basename(self.blend)} "
                f"(frame zero {self.frame_zero:g}, {self.fps:g} fps), outside the cloth cache of "
                f"'{self.object}' (frames {lo}..{hi}): the scene's frame range is shorter than the "
                f"capture, or --frame-zero is wrong"
            )
        return f

    def scenario(self, times, crop: Any = None) -> SceneScenario:
        self.frames(times)
        return SceneScenario(self.mesh, np.asarray(times, dtype=np.float64), crop)

    def simulate(self, scenario, rows, backend: str = "auto", offsets=None) -> SimResult:
        """``offsets`` (``scenario.Offsets``): each candidate reads the scene ``offsets.time[p]`` s
        earlier (fractional frames, clamped at the cache's first frame); handle offsets are not
        supported (the scene's pins are its own objects)."""
        rows = np.atleast_2d(np.asarray(rows, dtype=np.float64))
        frames = self.frames(scenario.frame_times).tolist()
        per = [frames] * len(rows)
        if offsets is not None:
            if offsets.moves_handles:
                raise ClothFitError("handle offsets cannot be simulated on a Blender scene (its pins are its own)")
            lo = float(self.info["cache_start"])
            per = [np.maximum(np.asarray(frames) - float(t) * self.fps, lo).tolist() for t in offsets.time]
        args = [(B.check_settings(self.settings(r), "candidate Blender settings"), per[p]) for p, r in enumerate(rows)]
        t0 = time.perf_counter()
        out = self.executor.map("simulate", args)
        self.seconds += time.perf_counter() - t0
        n, F, V = len(rows), len(frames), self.mesh.n_vertices
        pos = np.full((n, F, V, 3), np.nan)
        exploded = np.zeros(n, bool)
        reason = [""] * n
        steps = np.zeros(n, dtype=np.int64)
        for p, r in enumerate(out):
            self.worker_seconds += r["seconds"]
            self.worker_cpu_seconds += r.get("cpu_seconds", 0.0)
            steps[p] = r["frames"] * self.quality
            if r["exploded"]:
                exploded[p], reason[p] = True, r["reason"]
            else:
                pos[p] = r["positions"]
        self.evaluations += n
        return SimResult(pos, exploded, steps, reason)

    def describe(self) -> dict:
        """What the result JSON says about where the candidates ran."""
        i = self.info
        return {
            "backend": "blender",
            "executor": self.executor.kind,
            "workers": self.workers,
            "scene": {
                "blend": self.blend,
                "object": self.object,
                "frame_zero": self.frame_zero,
                "fps": self.fps,
                "cache_frames": [i["cache_start"], i["cache_end"]],
                "colliders": i["colliders"],
                "self_collision": i["self_collision"],
                "n_vertices": self.mesh.n_vertices,
                "blender": i["blender"],
            },
            "blender_evaluations": self.evaluations,
            "blender_seconds": self.seconds,
            "worker_startup_s": self.startup_s,
        }

    def close(self):
        self.executor.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
