"""Colliders a cloth lands on: a plane or a box, with Blender's collision settings.

A scenario (``scenario.Scenario.colliders``) may carry a ``Collisions``: the colliders, each a
Blender object with a Collision modifier, and the cloth's own collision settings. In a capture or
scenario file (``docs/capture_format.md``)::

    "colliders": [
      {"type": "plane", "point": [0, 0, 0.47], "normal": [0, 0, 1], "distance": 0.004, "friction": 5},
      {"type": "box", "centre": [0, 0, 0.4], "size": [0.2, 0.2, 0.1], "rotation": [0, 0, 0.3]}
    ],
    "collision_settings": {"distance_min": 0.004, "collision_quality": 2}

* ``plane``: the half-space above ``point`` along ``normal`` (unbounded: Blender gets a square mesh
  ``defaults.PLANE_MESH_SIZE`` on a side, or ``size`` [sx, sy] when given);
* ``box``: ``size`` (x, y, z) [m] about ``centre``, turned by ``rotation`` (a rotation vector: axis
  times angle [rad], default none);
* ``distance``: the collider's outer thickness (Collision modifier ``thickness_outer``, Blender's
  default 0.02 m), ``friction``: its ``cloth_friction`` (default 5);
* ``collision_settings``: the cloth's ``distance_min`` (default 0.015 m) and ``collision_quality``
  (collision passes per step, default 2).

Colliders are single sided (Blender's default *Single Sided*): the cloth is pushed out along the
plane's normal, or out of the box. ``blender_collide`` is the solver's contact step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .. import defaults as D
from ..errors import ClothFitError
from .rotation import rotation_matrix

TYPES = ("plane", "box")
KIND = {"plane": 0, "box": 1}
MAX_COLLIDERS = 64
MAX_EXTENT_M = 1000.0
MAX_QUALITY = 20
N_COLUMNS = 20  # one packed collider triangle for the kernel (``Collider.packed``)
KEYS = {
    "plane": {"type", "point", "normal", "size", "distance", "friction"},
    "box": {"type", "centre", "size", "rotation", "distance", "friction"},
}


def _vec(v: Any, what: str, n: int = 3) -> np.ndarray:
    try:
        a = np.asarray(v, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise ClothFitError(f"{what} must be {n} numbers, got {v!r}") from None
    if a.size != n or not np.all(np.isfinite(a)) or np.abs(a).max(initial=0.0) > MAX_EXTENT_M:
        raise ClothFitError(f"{what} must be {n} finite numbers within {MAX_EXTENT_M:g} m, got {v!r}")
    return a


def _number(v: Any, what: str, lo: float, hi: float) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and lo <= v <= hi):
        raise ClothFitError(f"{what} must be a number in [{lo:g}, {hi:g}], got {v!r}")
    return float(v)


def _plane_axes(normal: np.ndarray) -> np.ndarray:
    """Rows: two unit vectors in the plane and the unit normal (a right-handed frame)."""
    n = normal / np.linalg.norm(normal)
    a = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(a, n)
    u /= np.linalg.norm(u)
    return np.stack([u, np.cross(n, u), n])


@dataclass
class Collider:
    """One collider: ``kind`` plane or box, its frame (``centre`` and ``axes``: rows = the local x, y, z
    in the world; a plane's z is its normal), ``size`` (a box's sides; a plane's [sx, sy, 0] or None =
    unbounded), Blender's ``distance`` (thickness_outer) and ``friction`` (cloth_friction)."""

    kind: str
    centre: np.ndarray
    axes: np.ndarray
    size: np.ndarray | None
    distance: float = D.COLLIDER_DISTANCE
    friction: float = D.COLLIDER_FRICTION
    rotation: np.ndarray | None = None  # a box's rotation vector as given (kept for to_dict)

    @property
    def normal(self) -> np.ndarray:
        return self.axes[2].copy()

    def to_dict(self) -> dict[str, Any]:
        if self.kind == "plane":
            d: dict[str, Any] = {"type": "plane", "point": self.centre.tolist(), "normal": self.normal.tolist()}
            if self.size is not None:
                d["size"] = self.size[:2].tolist()
        else:
            d = {"type": "box", "centre": self.centre.tolist(), "size": self.size.tolist()}
            if self.rotation is not None:
                d["rotation"] = self.rotation.tolist()
        d["distance"] = self.distance
        d["friction"] = self.friction
        return d

    @classmethod
    def from_dict(cls, d: Any, source: str = "collider") -> Collider:
        if not isinstance(d, dict):
            raise ClothFitError(f"{source}: expected an object with 'type', got {d!r}")
        kind = d.get("type")
        if kind not in TYPES:
            raise ClothFitError(f"{source}: type {kind!r} must be one of {', '.join(TYPES)}")
        extra = sorted(set(d) - KEYS[kind])
        if extra:
            raise ClothFitError(
                f"{source}: unknown key {extra[0]!r} for a {kind} (keys: {', '.join(sorted(KEYS[kind]))})"
            )
        dist = _number(d.get("distance", D.COLLIDER_DISTANCE), f"{source}: distance", 0.001, 1.0)
        fric = _number(d.get("friction", D.COLLIDER_FRICTION), f"{source}: friction", 0.0, 80.0)
        if kind == "plane":
            for k in ("point", "normal"):
                if k not in d:
                    raise ClothFitError(f"{source}: a plane needs {k!r}")
            point = _vec(d["point"], f"{source}: point")
            normal = _vec(d["normal"], f"{source}: normal")
            if np.linalg.norm(normal) < 1e-9:
                raise ClothFitError(f"{source}: normal {d['normal']!r} must be a non-zero vector")
            size = None
            if d.get("size") is not None:
                sxy = _vec(d["size"], f"{source}: size", 2)
                if sxy.min() <= 0:
                    raise ClothFitError(f"{source}: size {d['size']!r} must be positive")
                size = np.array([sxy[0], sxy[1], 0.0])
            return cls("plane", point, _plane_axes(normal), size, dist, fric)
        for k in ("centre", "size"):
            if k not in d:
                raise ClothFitError(f"{source}: a box needs {k!r}")
        centre = _vec(d["centre"], f"{source}: centre")
        size = _vec(d["size"], f"{source}: size")
        if size.min() <= 0:
            raise ClothFitError(f"{source}: size {d['size']!r} must be three positive lengths")
        rot = None if d.get("rotation") is None else _vec(d["rotation"], f"{source}: rotation")
        axes = np.eye(3) if rot is None else rotation_matrix(rot).T  # rows: the box's local axes in the world
        return cls("box", centre, axes, size, dist, fric, rot)

    def packed(self, distance_min: float, quality: int, index: int = 0) -> np.ndarray:
        """The kernel's rows (``blender_collide``), one per triangle of ``mesh`` split as Blender splits a
        quad (corners 0, 1, 2 and 0, 2, 3): corners (9), unit normal (3), distance, friction, the cloth's
        distance_min and collision quality, the collider's index."""
        verts, faces = self.mesh()
        rows = []
        for f in faces:
            for tri in ((f[0], f[1], f[2]), (f[0], f[2], f[3])):
                p = verts[list(tri)]
                n = np.cross(p[1] - p[0], p[2] - p[1])
                n /= np.linalg.norm(n)
                rows.append(
                    np.concatenate([p.reshape(-1), n, [self.distance, self.friction, distance_min, quality, index]])
                )
        out = np.zeros((len(rows), N_COLUMNS), dtype=np.float32)
        out[:, :17] = rows
        return out

    def mesh(self) -> tuple[np.ndarray, list[list[int]]]:
        """The collider as Blender gets it: world vertices and quads whose normals point outwards
        (Blender's single-sided collisions push along them). A plane is one square quad
        (``size`` or ``defaults.PLANE_MESH_SIZE`` on a side) facing along its normal."""
        if self.kind == "plane":
            sx, sy = (D.PLANE_MESH_SIZE, D.PLANE_MESH_SIZE) if self.size is None else self.size[:2]
            local = np.array([[-sx, -sy, 0.0], [sx, -sy, 0.0], [sx, sy, 0.0], [-sx, sy, 0.0]]) / 2.0
            faces = [[0, 1, 2, 3]]
        else:
            h = self.size / 2.0
            local = np.array([[a * h[0], b * h[1], c * h[2]] for a in (-1, 1) for b in (-1, 1) for c in (-1, 1)])
            faces = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
        return self.centre + local @ self.axes, faces

    def signed_distance(self, points: ArrayLike) -> np.ndarray:
        """Signed distance [m] of points (..., 3) from the collider's surface (negative inside)."""
        p = np.asarray(points, dtype=np.float64)
        q = (p - self.centre) @ self.axes.T
        if self.kind == "plane":
            return q[..., 2]
        d = np.abs(q) - self.size / 2.0
        outside = np.linalg.norm(np.maximum(d, 0.0), axis=-1)
        return outside + np.minimum(d.max(axis=-1), 0.0)


@dataclass
class Collisions:
    """The colliders of a scenario and the cloth's collision settings (Blender's names)."""

    colliders: list = field(default_factory=list)
    distance_min: float = D.COLLISION_DISTANCE_MIN
    quality: int = D.COLLISION_QUALITY

    def __post_init__(self):
        if not self.colliders:
            raise ClothFitError("colliders: an empty list (leave 'colliders' out for a cloth with none)")
        if len(self.colliders) > MAX_COLLIDERS:
            raise ClothFitError(f"colliders: {len(self.colliders)} colliders (at most {MAX_COLLIDERS})")

    def settings_dict(self) -> dict[str, Any]:
        return {"distance_min": self.distance_min, "collision_quality": self.quality}

    def packed(self) -> np.ndarray:
        """(triangles, N_COLUMNS) float32: the kernel's rows (``Collider.packed``)."""
        return np.concatenate([c.packed(self.distance_min, self.quality, i) for i, c in enumerate(self.colliders)])

    @classmethod
    def from_dicts(cls, colliders: Any, settings: Any = None, source: str = "scenario") -> Collisions:
        if not isinstance(colliders, list):
            raise ClothFitError(f"{source}: 'colliders' must be a list, got {colliders!r}")
        items = [Collider.from_dict(c, f"{source} collider #{i}") for i, c in enumerate(colliders)]
        s = {} if settings is None else settings
        if not isinstance(s, dict) or set(s) - {"distance_min", "collision_quality"}:
            raise ClothFitError(
                f"{source}: 'collision_settings' must be an object with distance_min and collision_quality, got {s!r}"
            )
        dmin = _number(s.get("distance_min", D.COLLISION_DISTANCE_MIN), f"{source}: distance_min", 0.001, 1.0)
        q = s.get("collision_quality", D.COLLISION_QUALITY)
        if isinstance(q, bool) or not isinstance(q, int) or not 1 <= q <= MAX_QUALITY:
            raise ClothFitError(f"{source}: collision_quality must be a whole number 1..{MAX_QUALITY}, got {q!r}")
        return cls(items, dmin, q)


def packed_or_empty(collisions: Collisions | None) -> np.ndarray:
    """The kernel's collider rows, (0, N_COLUMNS) without colliders."""
    if collisions is None:
        return np.zeros((0, N_COLUMNS), dtype=np.float32)
    return np.ascontiguousarray(collisions.packed())


def blender_objects(collisions: Collisions, prefix: str = "Cloth Fit collider") -> list[dict[str, Any]]:
    """The colliders as plain data for a Blender script (``blender/cloth_script.add_colliders``): name,
    mesh (``Collider.mesh``), the Collision modifier's ``thickness_outer`` and ``cloth_friction``."""
    out = []
    for i, c in enumerate(collisions.colliders):
        verts, faces = c.mesh()
        out.append(
            {
                "name": f"{prefix} {i + 1} ({c.kind})",
                "vertices": np.round(verts, 9).tolist(),
                "faces": faces,
                "thickness_outer": c.distance,
                "cloth_friction": c.friction,
            }
        )
    return out
