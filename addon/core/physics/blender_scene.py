"""Blender's cloth on a user's own scene, as the core's ``blender`` model can run it exactly.

The core's ``BlenderModel`` builds its cloth from a scenario: our grid, our vertex and edge order,
pins declared as handles. A cloth a user built in Blender differs in every one of those: the mesh
(a Grid primitive, a subdivided Plane, ...) numbers its vertices, edges and faces its own way,
its first-frame positions are float32 products of the object's transform, its pins are a vertex
group whose weights some modifier changes over time. Blender's solver is chaotic at float32
rounding level (its CG stops at a 1 % residual, so one rounding changes an iteration count), so
any of those differences makes the two drift apart (``docs/user_scenes.md``).

``SceneCloth`` holds what Blender's cloth reads from such a scene (the Blender layer's
``addon/blender/user_cloth.py`` reads it; it is saved as ``.npz``): the first frame's world
positions as Blender computes them (``world_f32``), the mesh's faces and edges in the mesh's
order, and per frame the pin-group weights and world positions of every vertex that has a pin
weight, plus the Cloth settings and gravity. ``network()`` and ``plan()`` turn it into the core
model's inputs; ``simulate()`` runs the kernel. Built this way the core model follows Blender's
solver bit for bit (tests/test_blender_user_scenes.py).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from ..errors import ClothFitError
from ..jsonio import loads
from . import blender as B
from .scenario import ClothGrid

FORMAT = "silhouette-cloth-fit/scene-cloth"


def world_f32(matrix: ArrayLike, local: ArrayLike) -> np.ndarray:
    """World positions of ``local`` (V, 3) under the 4 x 4 ``matrix`` (row-major, as mathutils
    prints it) computed as Blender's ``mul_m4_v3`` does in float32:
    ``((x m[r,0] + y m[r,1]) + m[r,2] z) + m[r,3]`` per row ``r``. Returned as float64 (exact)."""
    M = np.asarray(matrix, dtype=np.float32).reshape(4, 4)
    X = np.asarray(local, dtype=np.float32).reshape(-1, 3)
    x, y, z = X[:, 0], X[:, 1], X[:, 2]
    out = np.empty_like(X)
    for r in range(3):
        out[:, r] = ((x * M[r, 0] + y * M[r, 1]) + M[r, 2] * z) + M[r, 3]
    return out.astype(np.float64)


@dataclass
class SceneCloth:
    """What Blender's cloth reads from one cloth object, frame by frame from its cache's first frame.

    ``weights[f, h]`` and ``targets[f, h]`` are the pin-group weight and the world position of
    vertex ``handle_vertices[h]`` as the Cloth modifier receives them at frame ``frame_start + f``
    (its input: the mesh after the modifiers above it); every vertex that has a non-zero weight in
    some frame is a handle. ``rest`` is the first frame's world positions (float32 values)."""

    rest: np.ndarray  # (V, 3)
    faces: list  # polygons, corner order as in the mesh
    edges: np.ndarray  # (E, 2) mesh edge order
    triangles: np.ndarray  # (T, 3) the mesh's loop triangles (for silhouettes)
    handle_vertices: np.ndarray  # (H,)
    weights: np.ndarray  # (n_frames + 1, H)
    targets: np.ndarray  # (n_frames + 1, H, 3)
    settings: dict  # ClothSettings values (quality, bending_model, FLOAT_SETTINGS)
    gravity: np.ndarray  # (3,) m/s^2
    fps: float
    frame_start: int  # the cloth cache's first frame (the rest frame)
    info: dict = field(default_factory=dict)  # blend, object, notes: anything for people

    @property
    def n_frames(self) -> int:
        return int(self.weights.shape[0]) - 1

    @property
    def n_vertices(self) -> int:
        return int(self.rest.shape[0])

    def network(self, bending_model: str | None = None, edges: str | ArrayLike | None = "mesh") -> B.Network:
        """The spring network of the scene's mesh; ``edges="mesh"`` keeps the mesh's edge order
        (Blender builds its structural springs in it), ``None`` takes each face's sides in face
        order instead (what the core builds for its own grid)."""
        bm = bending_model or self.settings.get("bending_model", "ANGULAR")
        return B.Network.from_mesh(self.rest, self.faces, bm, edges=self.edges if isinstance(edges, str) else edges)

    def plan(self, frames: ArrayLike | None = None, release_frame: int = 0) -> B.FramePlan:
        """Frame plan reading the scene's frames ``frames`` (relative to ``frame_start``, may be
        fractional: linear between whole frames; default every frame)."""
        n = self.n_frames
        f = np.arange(n + 1, dtype=np.float64) if frames is None else np.asarray(frames, dtype=np.float64).reshape(-1)
        if f.size == 0 or f.min() < 0 or np.ceil(f.max() - 1e-9) > n:
            raise ClothFitError(
                f"scene cloth: frames {f.min():g}..{f.max():g} outside the {n} frames read from the scene"
            )
        fr = np.round(f)
        exact = np.abs(f - fr) < 1e-9
        lo = np.where(exact, fr, np.floor(f)).astype(np.int64)
        hi = np.where(exact, fr, np.floor(f) + 1).astype(np.int64)
        w = np.where(exact, 0.0, f - np.floor(f))
        return B.FramePlan(
            float(self.fps),
            int(release_frame),
            n,
            np.asarray(self.handle_vertices, dtype=np.int64),
            np.asarray(self.targets, dtype=np.float64),
            np.asarray(self.weights, dtype=np.float64),
            lo,
            hi,
            w,
            int((~exact).sum()),
        )

    def settings_row(self, **changes: float | str) -> np.ndarray:
        s = dict(self.settings)
        s.update(changes)
        return B.settings_row(B.check_settings(s, "scene cloth settings"))

    def simulate(
        self,
        rows: ArrayLike | None = None,
        net: B.Network | None = None,
        plan: B.FramePlan | None = None,
        quality: int | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Every frame ``(P, n_frames + 1, V, 3)`` (float64 of the kernel's float32) and the
        explosion codes, for parameter rows (default: the scene's own settings). All rows must share
        one ``time_scale`` (the kernel runs one time step)."""
        from .blender_kernels import Prepared

        rows = np.atleast_2d(self.settings_row() if rows is None else np.asarray(rows, dtype=np.float64))
        ts = rows[:, B.FLOAT_SETTINGS.index("time_scale")]
        if np.any(ts != ts[0]):
            raise ClothFitError("scene cloth: simulate rows of one time_scale at a time")
        net = self.network() if net is None else net
        plan = self.plan() if plan is None else plan
        q = int(self.settings["quality"] if quality is None else quality)
        prep = Prepared(net, plan, q, float(ts[0]), self.gravity, all_frames=True)
        out, codes, _ = prep.run(rows)
        return out.astype(np.float64), codes

    # ------------------------------------------------------------------ files

    def save(self, path: str | os.PathLike) -> None:
        """Write the scene cloth as one ``.npz`` (arrays, and the rest as JSON text)."""
        import io

        from ..jsonio import dumps
        from ..safeio import atomic_write

        meta = {
            "format": FORMAT,
            "version": 1,
            "faces": [list(map(int, f)) for f in self.faces],
            "settings": self.settings,
            "gravity": np.asarray(self.gravity, dtype=np.float64).tolist(),
            "fps": float(self.fps),
            "frame_start": int(self.frame_start),
            "info": self.info,
        }
        buf = io.BytesIO()
        np.savez(
            buf,
            rest=self.rest,
            edges=self.edges,
            triangles=self.triangles,
            handle_vertices=self.handle_vertices,
            weights=self.weights,
            targets=self.targets,
            meta=np.array(dumps(meta)),
        )
        atomic_write(path, buf.getvalue())

    @classmethod
    def load(cls, path: str | os.PathLike) -> SceneCloth:
        if not os.path.isfile(path):
            raise ClothFitError(f"scene cloth {path}: file not found")
        try:
            with np.load(path, allow_pickle=False) as z:
                meta = loads(str(z["meta"]), f"scene cloth {path}: its meta", expect=dict)
                arr = {k: z[k] for k in ("rest", "edges", "triangles", "handle_vertices", "weights", "targets")}
        except (OSError, ValueError, KeyError) as e:
            raise ClothFitError(f"scene cloth {path}: not a scene-cloth file ({e})") from None
        if meta.get("format") != FORMAT or meta.get("version") != 1:
            raise ClothFitError(
                f"scene cloth {path}: format {meta.get('format')!r} version {meta.get('version')!r} "
                f"is not {FORMAT!r} version 1"
            )
        return cls(
            arr["rest"].astype(np.float64),
            meta["faces"],
            arr["edges"].astype(np.int64),
            arr["triangles"].astype(np.int64),
            arr["handle_vertices"].astype(np.int64),
            arr["weights"].astype(np.float64),
            arr["targets"].astype(np.float64),
            B.check_settings(meta["settings"], f"scene cloth {path}"),
            np.asarray(meta["gravity"], dtype=np.float64),
            float(meta["fps"]),
            int(meta["frame_start"]),
            meta.get("info", {}),
        )


def grid_order(positions: ArrayLike, grid: ClothGrid, tol: float = 1e-6) -> np.ndarray | None:
    """The permutation ``p`` with ``positions[p[g]]`` at grid vertex ``g`` of ``grid`` (a
    ``ClothGrid``), matching each mesh vertex to the nearest grid point within ``tol`` times the
    spacing; None when the mesh is not that grid (different count, or a vertex off every point,
    or two on one)."""
    P = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    G = grid.rest
    if P.shape[0] != G.shape[0]:
        return None
    sx = grid.side / (grid.nx - 1)
    sy = grid.side_y / (grid.ny - 1)
    j = np.rint((P[:, 0] + grid.side / 2) / sx).astype(np.int64)
    i = np.rint((P[:, 1] + grid.side_y / 2) / sy).astype(np.int64)
    if j.min() < 0 or i.min() < 0 or j.max() >= grid.nx or i.max() >= grid.ny:
        return None
    g = i * grid.nx + j
    if np.abs(P - G[g]).max() > tol * min(sx, sy) or np.unique(g).size != g.size:
        return None
    p = np.empty(G.shape[0], dtype=np.int64)
    p[g] = np.arange(P.shape[0])
    return p
