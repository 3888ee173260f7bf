"""The cloth placed for ``clothfit handles``: a flat rectangle of the measured size moved rigidly
onto the triangulated pins (Kabsch; hanging below a line of pins), the grid resolution, and each
handle assigned to its grid vertex.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from .. import defaults as D
from ..errors import ClothFitError
from ..physics.rotation import rotation_vector
from ..physics.scenario import ClothGrid

if TYPE_CHECKING:
    from collections.abc import Iterable, Sequence

    from .handle_marks import HandleMarks, HandleOptions

# ================================================================== placement


@dataclass
class Placement:
    grid: ClothGrid
    method: str
    residuals_m: np.ndarray  # per handle with 'at': |placed at-point - pin|
    with_at: list  # indices of those handles
    ats: list  # per handle the (u, v) used (the given 'at', the top-edge rule's) or None


def cloth_local(at: Sequence[float], width: float, height: float) -> np.ndarray:
    """Local grid coordinates of a point ``(u, v)`` on the cloth (from its top-left corner)."""
    return np.array([at[0] - width / 2.0, at[1] - height / 2.0, 0.0])


def _kabsch(Q, P):
    """Rotation R and translation o minimising sum |o + R q - p|^2 (proper rotation)."""
    qc, pc = Q.mean(0), P.mean(0)
    Hm = (Q - qc).T @ (P - pc)
    U, _, Vt = np.linalg.svd(Hm)
    dfix = np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0
    R = Vt.T @ np.diag([1.0, 1.0, dfix]) @ U.T
    return R, pc - R @ qc


def _hanging(Q, P, width, height, gravity):
    """Placement from points on one line (two clips, or several along an edge): the line of the ``at``
    points onto the line of the pins, the cloth hanging below it (its centre as low as it can be)."""
    down = -np.asarray(gravity, dtype=np.float64)
    down = -down / np.linalg.norm(down)  # unit vector along gravity
    qc, pc = Q.mean(0), P.mean(0)
    i0, i1 = _extremes(Q)
    uq = Q[i1] - Q[i0]
    up_ = P[i1] - P[i0]
    if np.linalg.norm(uq) < 1e-9 or np.linalg.norm(up_) < 1e-9:
        raise ClothFitError("the clips with 'at' sit on one point: give 'at' for clips at 2 different places")
    uq /= np.linalg.norm(uq)
    up_ /= np.linalg.norm(up_)
    # in the cloth: the in-plane direction from the line towards the cloth's centre (rows downward if on it)
    cq = -qc - np.dot(-qc, uq) * uq
    cq = np.array([0.0, 1.0, 0.0]) - np.dot([0.0, 1.0, 0.0], uq) * uq if np.linalg.norm(cq) < 1e-9 else cq
    cq /= np.linalg.norm(cq)
    # in the world: gravity's component across the pins' line
    cw = down - np.dot(down, up_) * up_
    if np.linalg.norm(cw) < 1e-6:
        raise ClothFitError(
            "the clips with 'at' lie on a vertical line: the cloth's plane is unknown; give 'at' for "
            "a clip off that line"
        )
    cw /= np.linalg.norm(cw)
    A = np.stack([uq, cq, np.cross(uq, cq)], 1)
    B = np.stack([up_, cw, np.cross(up_, cw)], 1)
    R = B @ A.T
    o = pc - R @ qc
    return R, o


def _extremes(Q):
    n = len(Q)
    best, pair = -1.0, (0, min(1, n - 1))
    for i in range(n):
        for j in range(i + 1, n):
            d = float(np.linalg.norm(Q[i] - Q[j]))
            if d > best:
                best, pair = d, (i, j)
    return pair


def _collinear(Q, tol=1e-6):
    if len(Q) < 3:
        return True
    s = np.linalg.svd(Q - Q.mean(0), compute_uv=False)
    return s[1] <= tol * max(s[0], 1e-12)


def place_cloth(
    width: float,
    height: float,
    nx: int,
    ny: int,
    pins: np.ndarray,
    ats: Sequence[Sequence[float] | None],
    gravity: Sequence[float] = D.GRAVITY,
) -> Placement:
    """The rigid placement of the flat ``width x height`` cloth (grid ``nx x ny``) that puts the
    ``at`` points of the handles on their pins. ``pins (H, 3)``; ``ats``: per handle (u, v) or None.
    Without any ``at``: the cloth hangs by its top edge, the two pins furthest apart at its top
    corners and the others on the edge between them."""
    pins = np.asarray(pins, dtype=np.float64)
    with_at = [k for k, a in enumerate(ats) if a is not None]
    if not with_at:
        if len(pins) < 2:
            raise ClothFitError("one handle without 'at': say where it holds the cloth ('at': [u, v] or a corner)")
        i, j = _extremes(pins)
        e = pins[j] - pins[i]
        L = float(np.linalg.norm(e))
        method = "top edge (no 'at' given: the two clips furthest apart at the top corners)"
        ats = [None] * len(pins)
        for k in range(len(pins)):
            u = float(np.dot(pins[k] - pins[i], e / L)) if L > 0 else 0.0
            ats[k] = (min(max(u, 0.0), width), 0.0)
        ats[i], ats[j] = (0.0, 0.0), (width, 0.0)
        with_at = list(range(len(pins)))
    else:
        method = "the clips' 'at' onto their pins"
    if len(with_at) < 2:
        raise ClothFitError(
            "only one handle says where it holds the cloth ('at'): give 'at' for at least 2 handles "
            "(or for none: the cloth then hangs by its top edge)"
        )
    Q = np.array([cloth_local(ats[k], width, height) for k in with_at])
    P = pins[with_at]
    if _collinear(Q) or _collinear(P, 1e-3):
        R, o = _hanging(Q, P, width, height, gravity)
        method += ", hanging below their line"
    else:
        R, o = _kabsch(Q, P)
        method += ", rigid fit (Kabsch)"
    grid = ClothGrid(nx, ny, width, side_y=height, origin=o, rotation=rotation_vector(R))
    res = np.linalg.norm(o + Q @ R.T - P, axis=1)
    return Placement(grid, method, res, with_at, list(ats))


def grid_resolution(
    width: float,
    height: float,
    n: int | None = None,
    nx: int | None = None,
    ny: int | None = None,
    ats: Iterable[Sequence[float] | None] = (),
) -> tuple[int, int]:
    """(nx, ny): given; else ``n`` vertices along the longer side and the other side's count making the
    cells as square as possible; without ``n``, the count within HANDLE_GRID_N - 4 .. + 8 that puts the
    given ``at`` points (u, v) nearest to grid vertices (ties: nearest to HANDLE_GRID_N), so that the
    pins sit where the clips are."""
    if nx is not None or ny is not None:
        if nx is None or ny is None:
            raise ClothFitError("give both grid counts (columns x rows), or one count for the longer side")
        for v in (nx, ny):
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 2:
                raise ClothFitError(f"grid resolution {nx} x {ny} must be whole numbers >= 2")
        return int(nx), int(ny)

    def square(n):
        if width >= height:
            return n, max(2, int(round(height / (width / (n - 1)))) + 1)
        return max(2, int(round(width / (height / (n - 1)))) + 1), n

    if n is not None:
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 2:
            raise ClothFitError(f"grid resolution {n!r} must be a whole number >= 2")
        return square(int(n))
    pts = np.array([a for a in ats if a is not None], dtype=np.float64).reshape(-1, 2)
    if pts.size == 0:
        return square(D.HANDLE_GRID_N)

    def miss(n):
        cx, cy = square(n)
        gu = np.linspace(0, width, cx)
        gv = np.linspace(0, height, cy)
        return max(float(np.hypot(np.abs(gu - u).min(), np.abs(gv - v).min())) for u, v in pts)

    cands = range(max(2, D.HANDLE_GRID_N - 4), D.HANDLE_GRID_N + 9)
    return square(min(cands, key=lambda n: (round(miss(n), 4), abs(n - D.HANDLE_GRID_N))))


def assign_vertices(
    marks: Sequence[HandleMarks],
    keys: Sequence[tuple[np.ndarray, np.ndarray]],
    width: float,
    height: float,
    nx: int,
    ny: int,
    rows: Sequence[dict[str, Any]],
    opts: HandleOptions,
    warnings: list[str],
) -> tuple[Placement, list[int]]:
    """The cloth placed on the handles' pins (``place_cloth``) and each handle's grid vertex: the one
    nearest its ``at`` (else its pin); ``rows`` (the report rows) get the vertex and its offset,
    ``warnings`` a line when the placement misses the clips. Returns ``(Placement, vertices)``."""
    pins = np.array([kx[0] for _, kx in keys])
    ats = [h.at for h in marks]
    place = place_cloth(width, height, nx, ny, pins, ats)
    grid = place.grid
    vertices = []
    for k, h in enumerate(marks):
        a = place.ats[k]
        if a is not None:
            v = int(np.argmin(np.linalg.norm(grid.local - cloth_local(a, width, height), axis=1)))
        else:
            v = int(np.argmin(np.linalg.norm(grid.rest - pins[k], axis=1)))
        for k2, v2 in enumerate(vertices):
            if v2 == v:
                raise ClothFitError(
                    f"handles '{marks[k2].name}' and '{h.name}' fall on the same grid vertex (row "
                    f"{v // nx}, column {v % nx}): they are closer than a grid cell "
                    f"({grid.spacing * 1000:.1f} mm) on the cloth; use a finer grid or check their "
                    f"'at' and marks"
                )
        vertices.append(v)
    for k, h in enumerate(marks):
        v, a = vertices[k], place.ats[k]
        off = float(np.linalg.norm(grid.rest[v] - pins[k]))
        if off > opts.max_pin_offset:
            raise ClothFitError(
                f"handle '{h.name}' is {off * 1000:.0f} mm from its vertex (row {v // nx}, column "
                f"{v % nx}) of the placed {width:g} x {height:g} m cloth (at most "
                f"{opts.max_pin_offset * 1000:g} mm): check the cloth size, its 'at' and its marks"
            )
        rows[k].update(
            vertex=v, row=v // nx, column=v % nx, pin_offset_mm=off * 1000.0, at=list(a) if a is not None else None
        )
    if float(place.residuals_m.max(initial=0.0)) > 0.5 * grid.spacing:
        warnings.append(
            f"the placed cloth misses the clips by up to {place.residuals_m.max() * 1000:.1f} mm (more than "
            f"half a grid cell): the model's clips pull the cloth there while it settles, which a real cloth of that size would "
            f"not need; check the cloth size and 'at'"
        )
    return place, vertices
