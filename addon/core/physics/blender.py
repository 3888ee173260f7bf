"""Blender's cloth (the Cloth modifier of Blender 4.2+) as its solver computes it.

Written from the equations of Blender's own source (no code copied): ``blenkernel/intern/cloth.cc``
(which springs a mesh gets, their rest lengths and rest angles, pins from the pin vertex group),
``simulation/intern/SIM_mass_spring.cc`` (forces, pins and the step loop of one frame) and
``simulation/intern/implicit_blender.cc`` (spring forces and their Jacobians, the solver).

The network (``Network.from_mesh``): every mesh edge is a *structural* spring; every polygon with
more than three corners gets *shear* springs between its non-adjacent corners (both diagonals of
a quad). Bending is either *angular* (default): a hinge across every edge shared by exactly two
polygons and across every shear diagonal (the two halves of the polygon), restoring the rest
angle; or *linear* (legacy): springs between vertices reached by two shear diagonals, resisting
compression only. Rest lengths and angles are those of the first frame's mesh, and
``avg_spring_len`` is the mean structural rest length.

Forces (all in Blender's units: metres, kilograms, and one *solver time unit* per frame times the
Speed Multiplier ``time_scale``):

* gravity ``mass * 0.001 * g`` per vertex (the scene gravity, scaled by 1/1000);
* air drag ``-0.01 * air_damping * v`` per vertex (not scaled by the mass);
* structural: tension ``k = tension_stiffness / avg_spring_len`` when stretched, damping
  ``tension_damping`` along the spring; when compressed (angular model) Choi and Ko's buckling
  curve with ``kb = cb = compression_stiffness / avg_spring_len``, damping ``compression_damping``;
  with the linear bending model a compressed structural spring exerts no force;
* shear: ``k = shear_stiffness / avg_spring_len``, damping ``shear_damping``, tension only;
* angular bending: torque ``k (angle - rest angle) - bending_damping * (normal velocities)`` with
  ``k = 0.1 * bending_stiffness * rest length``, explicit (it has no Jacobian in Blender);
* linear bending: Choi and Ko's curve with ``kb = bending_stiffness / (20 avg_spring_len)`` and
  ``cb = kb * bending_damping``, under compression only;
* pins: a vertex whose pin-group weight ``w`` gives ``w^4 >= 0.999`` follows the mesh input (its
  velocity is filtered out of the solve); a smaller weight is a goal spring of stiffness
  ``w^4 * pin_stiffness / avg_spring_len`` towards the input position.

Time: a frame is ``quality`` solver steps of ``dt = time_scale / quality``, counted the way Blender
counts them (a float32 ``while step < time_scale: step += dt`` loop, which takes one extra step for
some qualities, e.g. 13 steps at quality 12). A step is one linearised backward Euler step
(Baraff and Witkin): ``(M - dt dF/dv - dt^2 dF/dx) dv = dt F + dt^2 dF/dx v``, solved by
Blender's filtered conjugate gradient (no preconditioner, pinned vertices filtered out, starting
from zero, at most 100 iterations, stopping when the residual falls below 1 % of the right-hand
side), then ``x += dt (v + dv)``. The CG's early stop is part of the model's numerical damping.

Blender computes in float32; this model computes the same operations in float64.

A model *row* is one value per name of ``FLOAT_SETTINGS`` (``bpy.types.ClothSettings`` attribute
names and units); ``quality`` and ``bending_model`` are structural and fixed per simulation.
Scaling ``mass``, every stiffness, every damping (``bending_damping`` too with angular bending, not
with linear bending, where it is a ratio) and ``air_damping`` by one factor leaves the motion
unchanged: silhouettes cannot tell them apart (``mass_scaled``).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from .. import defaults as D
from ..errors import ClothFitError
from .blender_collide import collide
from .blender_settings import (  # noqa: F401  (re-exported: blender.X is the public path)
    AIR_SCALE,
    ALMOST_ZERO,
    BENDING_MODELS,
    CG_MAX_ITERATIONS,
    CG_TOLERANCE,
    DEFAULTS,
    EXPLODE_FACTOR,
    FLOAT_SETTINGS,
    GRAVITY_SCALE,
    MASS_SCALED,
    MAX_STEPS_PER_FRAME,
    MAX_STRAIN,
    POSITIVE,
    PRESETS,
    RANGES,
    SOFTGOALSNAP,
    check_settings,
    mass_scaled,
    physical_time_scale,
    row_settings,
    settings_row,
    steps_per_frame,
)
from .colliders import Collisions
from .scenario import ClothGrid, Scenario

# --------------------------------------------------------------------------- the spring network


def _mesh_edges(V: int, faces, bending_model: str, edges) -> tuple[list, list]:
    """Checked faces (lists of ints) and the mesh's edges ``(i, j)``, i < j, in mesh order (``edges``
    or, by default, each face's sides in face order, each once)."""
    faces = [list(map(int, f)) for f in faces]
    if bending_model not in BENDING_MODELS:
        raise ClothFitError(f"bending_model {bending_model!r} must be one of {', '.join(BENDING_MODELS)}")
    if not faces:
        raise ClothFitError("cloth mesh has no faces")
    for f in faces:
        if len(f) < 3 or len(set(f)) != len(f) or min(f) < 0 or max(f) >= V:
            raise ClothFitError(f"cloth mesh: bad face {f} (at least 3 distinct corners in 0..{V - 1})")
    sides = []
    for f in faces:
        for c in range(len(f)):
            a, b = f[c], f[(c + 1) % len(f)]
            sides.append((min(a, b), max(a, b)))
    if edges is None:
        seen, elist = set(), []
        for key in sides:
            if key not in seen:
                seen.add(key)
                elist.append(key)
    else:
        elist = [(min(int(a), int(b)), max(int(a), int(b))) for a, b in np.asarray(edges).reshape(-1, 2)]
        if set(elist) != set(sides) or len(set(elist)) != len(elist):
            raise ClothFitError("cloth mesh: the edges do not match the faces (loose or missing edges)")
    return faces, elist


def _linear_bend_springs(shear_created: list) -> list:
    """Linear bending springs ``(i, j, 2)`` in creation order: from each shear spring (i, j), newest
    first, springs to the far end of every shear spring at j (in creation order), each vertex pair
    once."""
    out = []
    at = {}
    for sij in shear_created:
        at.setdefault(sij[0], []).append(sij)
        at.setdefault(sij[1], []).append(sij)
    seen = set()
    for i, j in reversed(shear_created):
        for t in at.get(j, []):
            other = t[1] if t[0] == j else t[0]
            key = (min(i, other), max(i, other))
            if other != i and key not in seen:
                seen.add(key)
                out.append((key[0], key[1], 2))
    return out


@dataclass
class Network:
    """Blender's springs of a polygon mesh (cloth.cc's rules) for one bending model.

    Springs are (i, j) with i < j. The *list* arrays (``sp_*``) hold every spring in the order of
    Blender's spring list (newest first: linear bending springs, then shear springs face by face,
    then structural springs, each group in reverse creation order), which is the order Blender
    accumulates forces and matrix blocks in; ``sp_hinge`` is the hinge (angular bending) a spring
    carries or -1. Hinges have the polygon corners on each side (``hinge_pa``/``hinge_pb``,
    padded with -1) and the rest angle. The per-family arrays (``struct``, ``shear``, ``bend``) are
    the same springs grouped, for the vectorised reference solver.
    """

    rest: np.ndarray  # (V, 3) first-frame positions
    bending_model: str
    edges: np.ndarray  # (E, 2) mesh edges in mesh order (structural springs)
    struct: np.ndarray  # (S, 2)
    struct_len: np.ndarray  # (S,)
    shear: np.ndarray  # (H, 2)
    shear_len: np.ndarray
    hinge: np.ndarray  # (B, 2) the spring a hinge bends across (angular)
    hinge_len: np.ndarray  # its rest length
    hinge_pa: np.ndarray  # (B, maxlen) corners of the polygon on side a, -1 padded
    hinge_pb: np.ndarray
    hinge_rest: np.ndarray  # (B,) rest angle
    bend: np.ndarray  # (L, 2) linear bending springs
    bend_len: np.ndarray
    avg_spring_len: float
    sp_i: np.ndarray  # Blender's spring list
    sp_j: np.ndarray
    sp_kind: np.ndarray  # 0 structural, 1 shear, 2 linear bending
    sp_hinge: np.ndarray
    struct_creation: np.ndarray  # list positions of the structural springs in creation (edge) order
    triangles: np.ndarray  # the faces as triangles (corners 0, c, c + 1), for silhouettes
    faces: list

    @property
    def n_vertices(self) -> int:
        return int(self.rest.shape[0])

    @classmethod
    def from_mesh(
        cls,
        rest: ArrayLike,
        faces: Iterable[Iterable[int]],
        bending_model: str = "ANGULAR",
        edges: ArrayLike | None = None,
    ) -> Network:
        """Springs of the mesh ``(rest, faces)``; ``edges`` gives the mesh's edge order (default: each
        face's sides in face order, which is what Cloth Fit builds its Blender meshes with)."""
        rest = np.asarray(rest, dtype=np.float64).reshape(-1, 3)
        faces, elist = _mesh_edges(rest.shape[0], faces, bending_model, edges)
        angular = bending_model == "ANGULAR"
        created = [(a, b, 0) for a, b in elist]  # (i, j, kind) in creation order
        spring_of_edge = {e: k for k, e in enumerate(elist)}
        hinges = []  # (spring creation index, pa, pb)
        edge_faces = {}
        for fi, f in enumerate(faces):
            n = len(f)
            if n > 3:
                for j in range(1, n - 1):
                    pairs = ([(0, j)] if j > 1 else []) + [(j, k) for k in range(j + 2, n)]
                    for jj, kk in pairs:
                        a, b = f[jj], f[kk]
                        created.append((min(a, b), max(a, b), 1))
                        if angular:
                            hinges.append((len(created) - 1, f[jj : kk + 1], f[: jj + 1] + f[kk:]))
            if angular:
                for c in range(n):
                    a, b = f[c], f[(c + 1) % n]
                    edge_faces.setdefault((min(a, b), max(a, b)), []).append(fi)
        if angular:
            for key, fl in edge_faces.items():
                if len(fl) == 2:  # a third polygon on the edge removes its hinge in Blender
                    hinges.append((spring_of_edge[key], faces[fl[0]], faces[fl[1]]))
        shear_created = [(a, b) for a, b, k in created if k == 1]
        if not angular and shear_created:
            created.extend(_linear_bend_springs(shear_created))
        N = len(created)
        order = np.arange(N)[::-1]  # list position p holds creation index order[p]
        pos_of = np.empty(N, dtype=np.int64)
        pos_of[order] = np.arange(N)
        cr = np.array([(a, b, k) for a, b, k in created], dtype=np.int64).reshape(-1, 3)
        sp_i, sp_j, sp_kind = cr[order, 0].copy(), cr[order, 1].copy(), cr[order, 2].copy()
        sp_hinge = np.full(N, -1, dtype=np.int64)
        B = len(hinges)
        maxlen = max([max(len(h[1]), len(h[2])) for h in hinges], default=1)
        hinge = np.zeros((B, 2), dtype=np.int64)
        pa = np.full((B, maxlen), -1, dtype=np.int64)
        pb = np.full((B, maxlen), -1, dtype=np.int64)
        for k, (ci, a, b) in enumerate(hinges):
            hinge[k] = cr[ci, :2]
            pa[k, : len(a)] = a
            pb[k, : len(b)] = b
            sp_hinge[pos_of[ci]] = k

        def fam(kind):
            ij = cr[cr[:, 2] == kind, :2]
            return ij, np.linalg.norm(rest[ij[:, 1]] - rest[ij[:, 0]], axis=1) if len(ij) else np.zeros(0)

        struct, struct_len = fam(0)
        shear, shear_len = fam(1)
        bend, bend_len = fam(2)
        hinge_len = np.linalg.norm(rest[hinge[:, 1]] - rest[hinge[:, 0]], axis=1) if B else np.zeros(0)
        tris = []
        for f in faces:
            tris.extend([(f[0], f[c], f[c + 1]) for c in range(1, len(f) - 1)])
        return cls(
            rest,
            bending_model,
            np.array(elist, dtype=np.int64).reshape(-1, 2),
            struct,
            struct_len,
            shear,
            shear_len,
            hinge,
            hinge_len,
            pa,
            pb,
            hinge_angles(rest, hinge, pa, pb),
            bend,
            bend_len,
            float(struct_len.mean()),
            sp_i,
            sp_j,
            sp_kind,
            sp_hinge,
            pos_of[: len(elist)].copy(),
            np.array(tris, dtype=np.int64).reshape(-1, 3),
            faces,
        )

    @classmethod
    def from_grid(
        cls, grid: ClothGrid, bending_model: str = "ANGULAR", first_frame: np.ndarray | None = None
    ) -> Network:
        """The grid's quads; ``first_frame`` (V, 3) replaces the rest positions (Blender's rest shape
        is the first frame's mesh)."""
        rest = grid.rest if first_frame is None else first_frame
        return cls.from_mesh(rest, grid.quads, bending_model)


def _normal_tri(a, b, c):
    """Unit normal of the triangle (a, b, c) the way Blender computes it: (a - b) x (b - c)."""
    n = np.cross(a - b, b - c)
    ln = np.linalg.norm(n, axis=-1, keepdims=True)
    return np.where(ln > 0, n / np.where(ln > 0, ln, 1.0), 0.0)


def _poly_mean(X, idx):
    """Mean of X over each row of corner indices (padded with -1)."""
    w = (idx >= 0).astype(np.float64)
    cnt = w.sum(1, keepdims=True)
    return (X[np.where(idx >= 0, idx, 0)] * w[..., None]).sum(1) / cnt


def _unit(v):
    ln = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.where(ln > 0, v / np.where(ln > 0, ln, 1.0), 0.0)


def hinge_angles(X: np.ndarray, hinge: np.ndarray, pa: np.ndarray, pb: np.ndarray) -> np.ndarray:
    """Bending angle across every hinge at positions X (Blender's sign convention)."""
    if len(hinge) == 0:
        return np.zeros(0)
    i, j = hinge[:, 0], hinge[:, 1]
    da = _normal_tri(X[j], X[i], _poly_mean(X, pa))
    db = _normal_tri(X[i], X[j], _poly_mean(X, pb))
    e = _unit(X[i] - X[j])
    return np.arctan2(np.einsum("ij,ij->i", np.cross(da, db), e), np.einsum("ij,ij->i", da, db))


# --------------------------------------------------------------------------- the manipulation in frames


def settle_frames(settle_time: float, fps: float) -> int:
    """Blender steps whole frames: the settle (which only brings the cloth to rest before t = 0) is
    rounded to the nearest whole number of frames at ``fps`` (``settle_note`` says so)."""
    return int(round(settle_time * fps))


def settle_note(settle_time: float, fps: float) -> str | None:
    """A sentence when ``settle_time`` is not a whole number of frames at ``fps``, else None."""
    n = settle_time * fps
    sf = settle_frames(settle_time, fps)
    if abs(n - sf) <= 1e-6:
        return None
    return (
        f"settle_time {settle_time:g} s is {n:.2f} frames at {fps:g} fps: rounded to {sf} frames "
        f"({sf / fps:.4g} s); the settle only brings the cloth to rest before t = 0"
    )


def settle_ramp(settle_frames: int, n_frames: int) -> np.ndarray | None:
    """(n_frames + 1,) the handles' way from the flat cloth to their held positions: 0 at the start
    frame, rising smoothly (smoothstep) to 1 over the first ``SETTLE_RAMP_FRACTION`` of the settle,
    then 1; None without a settle (the handles are where they are held from the start frame on).

    The cloth's rest shape, and with it every spring's rest length, is its first frame (Blender's
    rule): a flat sheet of the declared size. Hands hold a cloth with slack (its corners closer than
    its size), so putting the handles there at the start frame would drag their vertices across the
    sheet and build the slack into the rest lengths; the ramp brings them there while it settles."""
    if settle_frames <= 0:
        return None
    n_ramp = max(int(round(settle_frames * D.SETTLE_RAMP_FRACTION)), 1)
    s = np.clip(np.arange(n_frames + 1, dtype=np.float64) / n_ramp, 0.0, 1.0)
    return s * s * (3.0 - 2.0 * s)


@dataclass
class FramePlan:
    """A scenario on Blender's timeline: frame ``frame_start`` is the first (rest) frame, the
    cloth settles for ``settle_frames`` frames and t = 0 is frame ``release_frame``; time t is
    frame ``release_frame + t * fps``.

    Per simulated frame (1 .. n_frames after the start): the pin targets of the handle vertices
    (``targets[f]``, the mesh input at that frame) and their pin weights (1 = pinned, 0 = free; a
    handle is pinned during the step into every frame at or before its release time, and all of
    them while settling). Capture times between frames are read by linear interpolation
    (``lo``, ``hi``, ``w``)."""

    fps: float
    settle_frames: int
    n_frames: int  # frames simulated after the start frame
    handle_vertices: np.ndarray  # (H,)
    targets: np.ndarray  # (n_frames + 1, H, 3): index 0 = start frame
    weights: np.ndarray  # (n_frames + 1, H)
    lo: np.ndarray  # (F,) frame index (from the start frame) at or before each capture time
    hi: np.ndarray
    w: np.ndarray  # weight of hi
    between: int  # capture times that fall between frames
    # (n_frames + 1,) how far each handle has come from its vertex's place on the flat cloth to its
    # held position (0 at the start frame, 1 from the end of the settle's ramp on); None: 1 throughout
    ramp: np.ndarray | None = None

    @property
    def release_frame(self) -> int:  # relative to the start frame
        return self.settle_frames

    @classmethod
    def from_scenario(cls, scenario: Scenario, fps: float) -> FramePlan:
        if not (fps > 0 and math.isfinite(fps)):
            raise ClothFitError(f"frame rate {fps} must be a positive number")
        sf = settle_frames(scenario.settle_time, fps)
        ft = np.asarray(scenario.frame_times, dtype=np.float64) * fps + sf
        fr = np.round(ft)
        exact = np.abs(ft - fr) < 1e-6
        lo = np.where(exact, fr, np.floor(ft)).astype(np.int64)
        hi = np.where(exact, fr, np.floor(ft) + 1).astype(np.int64)
        w = np.where(exact, 0.0, ft - np.floor(ft))
        n_frames = int(hi.max())
        if n_frames > 100000:
            raise ClothFitError(f"{n_frames} frames to simulate at {fps:g} fps: too many")
        hs = scenario.handles
        hv = np.array([h.vertex for h in hs], dtype=np.int64)
        t = (np.arange(n_frames + 1) - sf) / fps
        ramp = settle_ramp(sf, n_frames)
        rest = scenario.grid.rest
        targets = np.zeros((n_frames + 1, len(hs), 3))
        weights = np.zeros((n_frames + 1, len(hs)))
        for k, h in enumerate(hs):
            held_at = h.position(t)
            targets[:, k] = held_at if ramp is None else rest[h.vertex] + ramp[:, None] * (held_at - rest[h.vertex])
            held = h.held(t) | (t < 0)
            weights[:, k] = np.where(held, getattr(h, "weight", 1.0), 0.0)
        return cls(float(fps), sf, n_frames, hv, targets, weights, lo, hi, w, int((~exact).sum()), ramp)

    @property
    def settle_time(self) -> float:
        """The settle actually simulated [s]: whole frames (``settle_frames``)."""
        return self.settle_frames / self.fps

    def frame_of(self, t: np.ndarray) -> np.ndarray:
        return self.settle_frames + np.asarray(t) * self.fps

    def sample(self, frames: np.ndarray) -> np.ndarray:
        """Positions at the capture times from positions at every frame ``(n_frames + 1, V, 3)``."""
        return (1.0 - self.w)[:, None, None] * frames[self.lo] + self.w[:, None, None] * frames[self.hi]


# --------------------------------------------------------------------------- the reference solver


@dataclass
class Trajectory:
    positions: np.ndarray  # (F, V, 3) at the capture times (NaN if exploded)
    frames: np.ndarray | None  # (n_frames + 1, V, 3) every frame, if kept
    exploded: bool
    reason: str
    cg_iterations: np.ndarray  # per step
    steps_per_frame: int


def _sym_outer(d):
    return d[:, :, None] * d[:, None, :]


def _fb(x):
    return -11.541 * x**4 + 34.193 * x**3 - 39.083 * x**2 + 23.116 * x - 9.713


def _fb_deriv(x):
    return -46.164 * x**3 + 102.579 * x**2 - 78.166 * x + 23.116


def _fbstar(length, L, kb, cb):
    """Choi and Ko's compression force and its -d/dlength (Blender's fbstar / fbstar_jacobi)."""
    x = length / L
    tempfb = kb * _fb(x)
    lin = cb * (length - L)
    use_lin = tempfb < lin
    f = np.where(use_lin, lin, tempfb)
    jac = np.where(use_lin, -cb, -kb * _fb_deriv(x))
    return f, jac


class _Blocks:
    """Symmetric block-sparse 3x3 matrix: diagonal blocks plus one block per spring pair."""

    def __init__(self, V):
        self.V = V
        self.diag = np.zeros((V, 3, 3))
        self.r = []
        self.c = []
        self.off = []

    def matvec(self, x):
        y = np.einsum("vab,vb->va", self.diag, x)
        if self.off:
            r = np.concatenate(self.r)
            c = np.concatenate(self.c)
            o = np.concatenate(self.off)
            np.add.at(y, r, np.einsum("kab,kb->ka", o, x[c]))
            np.add.at(y, c, np.einsum("kba,kb->ka", o, x[r]))
        return y


def _linear_springs(X, Vel, ij, L, k_t, d_t, k_c, d_c, compress, F, dfdx, dfdv):
    """Blender's linear spring (tension, optional Choi-Ko compression, damping along the spring)."""
    if len(ij) == 0:
        return
    i, j = ij[:, 0], ij[:, 1]
    ext = X[j] - X[i]
    vel = Vel[j] - Vel[i]
    length = np.linalg.norm(ext, axis=1)
    ok = length > ALMOST_ZERO
    d = np.where(ok[:, None], ext / np.where(ok, length, 1.0)[:, None], 0.0)
    dd = _sym_outer(d)
    tension = (length >= L) & (length > 0)
    active = tension | (compress if isinstance(compress, np.ndarray) else np.full(len(L), bool(compress)))
    f = np.zeros_like(ext)
    jx = np.zeros((len(L), 3, 3))
    I = np.eye(3)
    # tension branch
    ft = (k_t * (length - L))[:, None] * d
    with np.errstate(divide="ignore", invalid="ignore"):
        jt = k_t * ((I - dd) * (L / length)[:, None, None] - I)
    # compression branch (Choi & Ko, kb = cb = k_c)
    fc_s, jc_s = _fbstar(length, L, k_c, k_c)
    fc = fc_s[:, None] * d
    jc = dd * jc_s[:, None, None]
    f = np.where(tension[:, None], ft, fc)
    jx = np.where(tension[:, None, None], jt, jc)
    damp = np.where(tension, d_t, d_c)
    f = f + (damp * np.einsum("ij,ij->i", vel, d))[:, None] * d
    jv = -damp[:, None, None] * dd
    a = np.nonzero(active)[0]
    _apply(F, dfdx, dfdv, i[a], j[a], f[a], jx[a], jv[a])


def _apply(F, dfdx, dfdv, i, j, f, jx, jv):
    np.add.at(F, i, f)
    np.add.at(F, j, -f)
    np.add.at(dfdx.diag, i, jx)
    np.add.at(dfdx.diag, j, jx)
    np.add.at(dfdv.diag, i, jv)
    np.add.at(dfdv.diag, j, jv)
    dfdx.r.append(i)
    dfdx.c.append(j)
    dfdx.off.append(-jx)
    dfdv.r.append(i)
    dfdv.c.append(j)
    dfdv.off.append(-jv)


def _bending_linear(X, ij, L, kb, cb, F, dfdx, dfdv):
    if len(ij) == 0:
        return
    i, j = ij[:, 0], ij[:, 1]
    ext = X[j] - X[i]
    length = np.linalg.norm(ext, axis=1)
    ok = length > ALMOST_ZERO
    d = np.where(ok[:, None], ext / np.where(ok, length, 1.0)[:, None], 0.0)
    a = np.nonzero(length < L)[0]
    if not len(a):
        return
    fs, js = _fbstar(length[a], L[a], kb, cb)
    dd = _sym_outer(d[a])
    _apply(F, dfdx, dfdv, i[a], j[a], fs[:, None] * d[a], dd * js[:, None, None], np.zeros((len(a), 3, 3)))


def _bending_angular(X, Vel, net, k, damping, F):
    if len(net.hinge) == 0:
        return
    i, j = net.hinge[:, 0], net.hinge[:, 1]
    pa, pb = net.hinge_pa, net.hinge_pb
    da = _normal_tri(X[j], X[i], _poly_mean(X, pa))
    db = _normal_tri(X[i], X[j], _poly_mean(X, pb))
    e = _unit(X[i] - X[j])
    angle = np.arctan2(np.einsum("ij,ij->i", np.cross(da, db), e), np.einsum("ij,ij->i", da, db))
    ve = 0.5 * (Vel[i] + Vel[j])
    va = _poly_mean(Vel, pa) - ve
    vb = _poly_mean(Vel, pb) - ve
    force = k * (angle - net.hinge_rest) - damping * (np.einsum("ij,ij->i", va, da) + np.einsum("ij,ij->i", vb, db))
    la = (pa >= 0).sum(1)
    lb = (pb >= 0).sum(1)
    fa = da * (force / la)[:, None]
    fb = db * (force / lb)[:, None]
    for col in range(pa.shape[1]):
        m = pa[:, col] >= 0
        np.add.at(F, pa[m, col], fa[m])
    for col in range(pb.shape[1]):
        m = pb[:, col] >= 0
        np.add.at(F, pb[m, col], fb[m])
    fe = 0.5 * force[:, None] * (da + db)
    np.add.at(F, i, -fe)
    np.add.at(F, j, -fe)


def _cg_filtered(A, B, pinned):
    """Blender's cg_filtered: plain CG on the free vertices, from dv = 0, relative tolerance 1 %."""
    free = (~pinned).astype(np.float64)[:, None]
    dV = np.zeros_like(B)
    fB = B * free
    bnorm2 = float(np.sum(fB * fB))
    target = CG_TOLERANCE * CG_TOLERANCE * bnorm2
    r = (B - A.matvec(dV)) * free
    c = r * free
    delta = float(np.sum(r * c))
    it = 0
    while delta > target and it < CG_MAX_ITERATIONS:
        q = A.matvec(c) * free
        alpha = delta / float(np.sum(c * q))
        dV += alpha * c
        r -= alpha * q
        old = delta
        delta = float(np.sum(r * r))
        c = (r + c * (delta / old)) * free
        it += 1
    return dV, it


def simulate_reference(
    net: Network,
    plan: FramePlan,
    settings: dict,
    gravity: ArrayLike = D.GRAVITY,
    keep_frames: bool = False,
    colliders: Collisions | None = None,
) -> Trajectory:
    """One candidate, step by step as Blender's solver runs it (numpy; the numba kernels of
    ``blender_kernels`` compute the same and are tested against it). ``colliders``: the contact step
    of ``blender_collide`` (in float32, as the kernels) after every velocity solve."""
    s = check_settings(settings)
    V = net.n_vertices
    m = s["mass"]
    ts = s["time_scale"]
    dt, starts = steps_per_frame(ts, s["quality"])
    avg = net.avg_spring_len + 1.1920928955078125e-07
    k_t = s["tension_stiffness"] / avg
    k_c = s["compression_stiffness"] / avg
    k_s = s["shear_stiffness"] / avg
    angular = s["bending_model"] == "ANGULAR"
    drag = AIR_SCALE * s["air_damping"]
    g = GRAVITY_SCALE * np.asarray(gravity, dtype=np.float64)
    k_goal = s["pin_stiffness"] / avg
    X = net.rest.copy()
    X[plan.handle_vertices] = plan.targets[0]
    Vel = np.zeros_like(X)
    xconst = X.copy()
    hv = plan.handle_vertices
    frames = np.zeros((plan.n_frames + 1, V, 3))
    frames[0] = X
    centre, limit = explosion_limits(net, plan)
    iters = []
    reason = ""
    for fr in range(1, plan.n_frames + 1):
        xold = xconst.copy()
        xconst = xold.copy()
        xconst[hv] = plan.targets[fr]
        goal = np.zeros(V)
        goal[hv] = plan.weights[fr] ** 4
        pinned = goal >= SOFTGOALSNAP
        soft = ~pinned & (goal > 1.1920928955078125e-07)
        Vel[pinned] = (xconst[pinned] - xold[pinned]) / ts
        for step in starts:
            F = np.zeros((V, 3))
            dfdx, dfdv = _Blocks(V), _Blocks(V)
            F += m * g
            if soft.any():
                gx = xold + (xconst - xold) * (step / ts)
                gv = xconst - xold
                ext = gx[soft] - X[soft]
                vel = gv[soft] - Vel[soft]
                ln = np.linalg.norm(ext, axis=1)
                ok = ln > ALMOST_ZERO
                dgo = np.where(ok[:, None], ext / np.where(ok, ln, 1.0)[:, None], 0.0)
                kg = goal[soft] * k_goal
                cg = AIR_SCALE * 0.0  # goal friction is not modelled (0 by default)
                f = (kg * ln)[:, None] * dgo + (cg * np.einsum("ij,ij->i", vel, dgo))[:, None] * dgo
                idx = np.nonzero(soft)[0][ok]
                F[idx] += f[ok]
                dfdx.diag[idx] += -kg[ok][:, None, None] * np.eye(3)
            F += -drag * Vel
            dfdv.diag += -drag * np.eye(3)
            if angular:
                _bending_angular(X, Vel, net, 0.1 * s["bending_stiffness"] * net.hinge_len, s["bending_damping"], F)
            _linear_springs(
                X,
                Vel,
                net.struct,
                net.struct_len,
                k_t,
                s["tension_damping"],
                k_c,
                s["compression_damping"],
                angular,
                F,
                dfdx,
                dfdv,
            )
            _linear_springs(X, Vel, net.shear, net.shear_len, k_s, s["shear_damping"], 0.0, 0.0, False, F, dfdx, dfdv)
            if not angular:
                kb = s["bending_stiffness"] / (20.0 * avg)
                _bending_linear(X, net.bend, net.bend_len, kb, kb * s["bending_damping"], F, dfdx, dfdv)
            A = _Blocks(V)
            A.diag = m * np.broadcast_to(np.eye(3), (V, 3, 3)) - dt * dfdv.diag - dt * dt * dfdx.diag
            A.r = dfdx.r
            A.c = dfdx.c
            A.off = [-dt * ov - dt * dt * ox for ov, ox in zip(dfdv.off, dfdx.off)]
            B = dt * F + dt * dt * dfdx.matvec(Vel)
            dV, it = _cg_filtered(A, B, pinned)
            iters.append(it)
            Vel = Vel + dV
            if colliders is not None:
                Vel = _collided(X, Vel, pinned, net, colliders, dt)
            X = X + dt * Vel
            if pinned.any():
                X[pinned] = xold[pinned] + (xconst[pinned] - xold[pinned]) * ((step + dt) / ts)
        frames[fr] = X
        reason = _exploded(X, Vel, net, centre, limit)
        if reason:
            reason = f"exploded in frame {fr} ({reason})"
            break
    if reason:
        pos = np.full((plan.lo.size, V, 3), np.nan)
    else:
        pos = plan.sample(frames)
    return Trajectory(pos, frames if keep_frames else None, bool(reason), reason, np.array(iters), len(starts))


def _collided(X, Vel, pinned, net: Network, colliders: Collisions, dt: float) -> np.ndarray:
    """The velocities after ``blender_collide``'s contact step (float32, one lane)."""
    X32 = np.ascontiguousarray(X.reshape(-1, 1), dtype=np.float32)
    V32 = np.ascontiguousarray(Vel.reshape(-1, 1), dtype=np.float32)
    free = np.where(pinned, 0.0, 1.0).astype(np.float32)
    tris = np.ascontiguousarray(net.triangles, dtype=np.int64)
    collide(X32, V32, free, tris, colliders.packed(), np.float32(dt))
    return V32.reshape(-1, 3).astype(np.float64)


def explosion_limits(net: Network, plan: FramePlan) -> tuple[np.ndarray, float]:
    size = float(np.ptp(net.rest, axis=0).max())
    pts = plan.targets.reshape(-1, 3) if plan.targets.size else net.rest
    centre = pts.mean(0) if plan.targets.size else net.rest.mean(0)
    span = float(np.ptp(pts, axis=0).max()) if plan.targets.size else 0.0
    return centre, EXPLODE_FACTOR * (size + span)


def _exploded(X, Vel, net, centre, limit) -> str:
    if not (np.all(np.isfinite(X)) and np.all(np.isfinite(Vel))):
        return "non-finite state"
    if np.abs(X - centre).max() > limit:
        return "flew away"
    s = net.struct
    ln = np.linalg.norm(X[s[:, 1]] - X[s[:, 0]], axis=1)
    if np.any(ln > (1.0 + MAX_STRAIN) * net.struct_len):
        return "spring overstretched"
    return ""
