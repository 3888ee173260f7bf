"""A continuum cloth in another engine: NVIDIA Warp's ``warp.sim`` FEM triangles + hinge bending, on the CPU.

Used by ``lab/continuum_truth.py`` to make test truths that neither of our cloth models made.
Nothing here is our code's physics: the forces are Warp's own kernels (``warp.sim.integrator_euler``:
``eval_triangles``, ``eval_bending``) and its semi-implicit Euler step (``integrate_particles``); this
module only builds the mesh, turns physical material values into Warp's parameters, drives the pins
and records positions. ``warp-lang`` is pinned to 1.9.1, the last release that ships ``warp.sim``.

The physics (SI units, world Z up):

* Membrane: Warp's constant-strain triangles with its "stable Neo-Hookean" membrane energy
  ``mu/2 (|F|^2 - 2) + lambda_w/2 (J - 1 - mu/lambda_w)^2`` per rest area (F the 3x2 deformation
  gradient, J the area ratio), plus Kelvin-Voigt damping ``k_damp dF/dt``. Its small-strain limit is
  the plane-stress membrane of stretch stiffness ``E h`` [N/m] and Poisson ratio ``nu`` when
  ``mu = E h / (2 (1 + nu))`` and ``lambda_w = mu + E h nu / (1 - nu^2)`` (expand the energy to
  second order in the strain; tests check a hanging strip's stretch).
* Bending: Warp's hinge (discrete-shell) energy ``ke_e |e| (theta - theta0)^2 / 2`` per interior edge
  e (theta the dihedral angle). ``ke_e = D |e| / (A1 + A2)`` (A1, A2 the rest areas of the two
  triangles) makes a cylinder of radius R hold ``D / (2 R^2)`` per area on this mesh, i.e. ``D``
  [N m] is the continuum bending rigidity (Kawabata's B); tests check the cantilever droop of a strip
  against the heavy elastica.
* Air: Warp's per-triangle drag ``c_air A |n . v| v`` (quadratic, normal velocity), with
  ``c_air = rho_air C_d / 2``; bending damping ``kd_e = beta_b ke_e``.
* Gravity 9.81 m/s^2, lumped masses ``rho_A A / 3`` per triangle corner, semi-implicit Euler with a
  step far below the membrane's stability limit (tests: halving it changes nothing visible).
* Pins: zero inverse mass (Warp's kinematic particles); moved by their velocity (a linear ramp to
  the hold position), released by giving the particle its mass back.

The mesh is NOT our grid: ``n x n`` vertices with alternating ("criss-cross") diagonals.
Warp runs in float32: positions are simulated relative to the cloth's centre to keep precision.
"""

from __future__ import annotations

import math
import os
from dataclasses import asdict, dataclass

import numpy as np

GRAVITY = 9.81
RHO_AIR = 1.2  # kg/m^3, air at 20 C
WARP_VERSION = "1.9.1"  # the last warp-lang with warp.sim (removed in 1.10)

_wp = None


def warp():
    """Import and initialise warp once (quiet, CPU)."""
    global _wp
    if _wp is None:
        import warnings

        os.environ.setdefault("WARP_CACHE_PATH", os.path.join(os.path.expanduser("~"), ".cache", "warp"))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            import warp as wp
            import warp.sim  # noqa: F401
        wp.config.quiet = True
        wp.init()
        _wp = wp
    return _wp


@dataclass(frozen=True)
class Material:
    """A fabric in SI units (see the module doc for how each enters the physics)."""

    name: str
    areal_density: float  # rho_A [kg/m^2]
    stretch: float  # E h [N/m], in-plane stretch stiffness (initial tensile modulus x thickness)
    poisson: float  # nu
    bending: float  # D [N m], bending rigidity per width (Kawabata B)
    drag_cd: float = 1.2  # C_d of a flat plate moving normal to itself
    membrane_damping: float = 0.0  # beta [s]: k_damp = beta mu; 0: Warp's F-rate damping also resists rigid rotation
    bending_damping: float = 0.02  # beta_b [s]: kd_e = beta_b ke_e
    source: str = ""

    def to_dict(self):
        return asdict(self)


# ----------------------------------------------------------------------------------------- mesh


def sheet_mesh(n: int, side: float, side_y: float | None = None):
    """A flat ``side x side_y`` sheet centred at the origin (z = 0): ``n x n`` vertices (index
    ``i * n + j``, row i along y, column j along x), each square split along alternating diagonals.
    Returns (vertices (V, 3), triangles (T, 3) counter-clockwise seen from +z)."""
    side_y = side if side_y is None else side_y
    xs = np.linspace(-side / 2, side / 2, n)
    ys = np.linspace(-side_y / 2, side_y / 2, n)
    X, Y = np.meshgrid(xs, ys)
    V = np.stack([X, Y, np.zeros_like(X)], -1).reshape(-1, 3)
    idx = np.arange(n * n).reshape(n, n)
    tris = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = idx[i, j], idx[i, j + 1], idx[i + 1, j], idx[i + 1, j + 1]
            if (i + j) % 2 == 0:
                tris += [(a, b, d), (a, d, c)]
            else:
                tris += [(a, b, c), (b, d, c)]
    return V, np.asarray(tris, dtype=np.int64)


def strip_mesh(nx: int, ny: int, length: float, width: float):
    """A flat strip along x (``nx x ny`` vertices, index ``i * nx + j``), alternating diagonals, for tests."""
    xs = np.linspace(0.0, length, nx)
    ys = np.linspace(-width / 2, width / 2, ny)
    X, Y = np.meshgrid(xs, ys)
    V = np.stack([X, Y, np.zeros_like(X)], -1).reshape(-1, 3)
    idx = np.arange(nx * ny).reshape(ny, nx)
    tris = []
    for i in range(ny - 1):
        for j in range(nx - 1):
            a, b, c, d = idx[i, j], idx[i, j + 1], idx[i + 1, j], idx[i + 1, j + 1]
            tris += [(a, b, d), (a, d, c)] if (i + j) % 2 == 0 else [(a, b, c), (b, d, c)]
    return V, np.asarray(tris, dtype=np.int64)


def hinges(tris):
    """Interior edges as (o0, o1, v0, v1): the edge v0-v1 and the opposite vertices of its two triangles."""
    seen = {}
    for t in tris:
        for k in range(3):
            a, b, o = int(t[k]), int(t[(k + 1) % 3]), int(t[(k + 2) % 3])
            seen.setdefault((min(a, b), max(a, b)), []).append(o)
    out = [(os_[0], os_[1], e[0], e[1]) for e, os_ in seen.items() if len(os_) == 2]
    return np.asarray(out, dtype=np.int64)


def tri_areas(V, tris):
    return 0.5 * np.linalg.norm(np.cross(V[tris[:, 1]] - V[tris[:, 0]], V[tris[:, 2]] - V[tris[:, 0]]), axis=1)


def lame(mat: Material):
    """Warp's (k_mu, k_lambda) of the membrane: the plane-stress membrane (E h, nu) in the small-strain limit."""
    mu = mat.stretch / (2.0 * (1.0 + mat.poisson))
    lam = mat.stretch * mat.poisson / (1.0 - mat.poisson**2)
    return mu, mu + lam


def hinge_stiffness(V, tris, H, bending):
    """Per-hinge ``ke_e = D |e| / (A1 + A2)`` (module doc)."""
    area = {}
    for ti, t in enumerate(tris):
        for k in range(3):
            a, b = int(t[k]), int(t[(k + 1) % 3])
            area.setdefault((min(a, b), max(a, b)), []).append(ti)
    A = tri_areas(V, tris)
    ke = np.empty(len(H))
    for h, (_, _, v0, v1) in enumerate(H):
        ts = area[(min(v0, v1), max(v0, v1))]
        ke[h] = bending * np.linalg.norm(V[v0] - V[v1]) / (A[ts[0]] + A[ts[1]])
    return ke


def stable_dt(V, tris, mat: Material, safety: float = 0.7):
    """A step inside the explicit stability limit of the damped membrane: ``safety * 2 / (w (z +
    sqrt(1 + z^2)))`` with ``w = 2 c / h_min`` its highest frequency (c = sqrt(E h / ((1 - nu^2)
    rho_A)) the membrane's P-wave speed, h_min the smallest triangle height) and ``z = beta w / 2``
    the Kelvin-Voigt damping ratio at that frequency (symplectic Euler on a damped oscillator)."""
    A = tri_areas(V, tris)
    longest = np.max(
        np.stack([np.linalg.norm(V[tris[:, a]] - V[tris[:, b]], axis=1) for a, b in ((0, 1), (1, 2), (2, 0))]), axis=0
    )
    hmin = float(np.min(2 * A / longest))
    c = math.sqrt(mat.stretch / ((1 - mat.poisson**2) * mat.areal_density))
    w = 2.0 * c / hmin
    z = mat.membrane_damping * w / 2.0
    return safety * 2.0 / (w * (z + math.sqrt(1.0 + z * z)))


# ------------------------------------------------------------------------------------ simulate


@dataclass
class Pin:
    """A vertex held by a hand: it moves in a straight line from its rest position to ``hold``
    during the first ``ramp`` seconds of the settling, stays there, and is released (free) at
    ``release`` [s] if given (t = 0 ends the settling).

    A moving hand: ``path_times`` [s] (increasing, the first >= 0) and ``path_positions`` (one per
    time, the first = ``hold``) key a path read as the capture's handles are
    (``clothfit.core.physics.scenario.Handle.position``): piecewise linear between the keys, at the
    first key's position before it and at the last one's after it."""

    vertex: int
    hold: tuple
    release: float | None = None
    path_times: tuple | None = None
    path_positions: tuple | None = None

    def __post_init__(self):
        if self.path_times is None:
            return
        t = np.asarray(self.path_times, dtype=np.float64).reshape(-1)
        p = np.asarray(self.path_positions, dtype=np.float64).reshape(-1, 3)
        if t.size == 0 or t.size != len(p) or np.any(np.diff(t) <= 0) or t[0] < 0:
            raise ValueError(f"pin {self.vertex}: path keys must be increasing times >= 0, one position each")
        if not np.allclose(p[0], self.hold, atol=1e-12):
            raise ValueError(f"pin {self.vertex}: the path starts at {p[0].tolist()}, not at the hold {self.hold}")

    @property
    def moves(self) -> bool:
        return self.path_times is not None and len(self.path_times) > 1

    def position(self, t):
        """Where the hand holds the vertex at times ``t`` [s] >= 0 (relative to the simulation's origin)."""
        t = np.asarray(t, dtype=np.float64)
        if not self.moves:
            return np.broadcast_to(np.asarray(self.hold, dtype=np.float64), t.shape + (3,)).copy()
        kt = np.asarray(self.path_times, dtype=np.float64)
        kp = np.asarray(self.path_positions, dtype=np.float64)
        return np.stack([np.interp(t, kt, kp[:, a]) for a in range(3)], -1)


def energy(V_rest, tris, H, mat, x, v, masses, gravity=GRAVITY, origin_z=0.0):
    """Total energy [J] of a state in Warp's model (kinetic + gravity + membrane + hinge), for tests."""
    mu, lam = lame(mat)
    alpha = 1.0 + mu / lam
    ke = hinge_stiffness(V_rest, tris, H, mat.bending)
    kin = 0.5 * float(np.sum(masses * np.sum(v * v, axis=1)))
    pot = float(np.sum(masses * gravity * (x[:, 2] + origin_z)))
    A0 = tri_areas(V_rest, tris)
    # rest frame per triangle: Dm = inverse of the 2x2 rest edge matrix in a local 2D basis
    e1 = V_rest[tris[:, 1]] - V_rest[tris[:, 0]]
    e2 = V_rest[tris[:, 2]] - V_rest[tris[:, 0]]
    Dm = np.linalg.inv(np.stack([np.stack([e1[:, 0], e2[:, 0]], -1), np.stack([e1[:, 1], e2[:, 1]], -1)], 1))
    x1 = x[tris[:, 1]] - x[tris[:, 0]]
    x2 = x[tris[:, 2]] - x[tris[:, 0]]
    F = np.stack([x1, x2], -1) @ Dm  # (T, 3, 2)
    J = 0.5 * np.linalg.norm(np.cross(x1, x2), axis=1) / A0
    mem = float(
        np.sum(
            A0
            * (
                0.5 * mu * (np.sum(F * F, axis=(1, 2)) - 2.0)
                + 0.5 * lam * (J - alpha) ** 2
                - 0.5 * lam * (1 - alpha) ** 2
            )
        )
    )
    theta = dihedral(x, H)
    ecur = np.linalg.norm(x[H[:, 3]] - x[H[:, 2]], axis=1)  # Warp scales by the current edge length
    bend = float(np.sum(0.5 * ke * ecur * theta**2))
    return kin + pot + mem + bend


def dihedral(x, H):
    """Signed hinge angles as Warp's eval_bending measures them."""
    x1, x2, x3, x4 = (x[H[:, k]] for k in range(4))
    n1 = np.cross(x3 - x1, x4 - x1)
    n2 = np.cross(x4 - x2, x3 - x2)
    c = np.sum(n1 * n2, 1) / (np.linalg.norm(n1, axis=1) * np.linalg.norm(n2, axis=1))
    e = x4 - x3
    s = np.sign(np.sum(np.cross(n2, n1) * e, 1))
    return np.arccos(np.clip(c, -1, 1)) * s


def simulate(
    V,
    tris,
    mat: Material,
    pins,
    times,
    settle: float = 2.0,
    ramp: float = 0.5,
    settle_damping: float = 20.0,
    dt: float | None = None,
    origin=(0.0, 0.0, 0.0),
    gravity: float = GRAVITY,
    dt_safety: float = 0.7,
    progress=None,
    velocities: bool = False,
):
    """Simulate the sheet ``V`` (rest positions, relative to ``origin``), ``tris`` in Warp.

    From t = -settle: the pins ramp to their hold positions (relative to ``origin``) over ``ramp`` s,
    a viscous settle damping (``settle_damping`` [1/s], the air made thick: a still, hanging cloth at
    t = 0) acts until t = 0, pins with a ``release`` time are freed then, and only Warp's own forces
    act after t = 0. Returns positions (F, V, 3) at ``times`` [s] (world: + origin) and a dict of
    facts (dt, steps, cpu seconds, masses; with ``velocities`` also the velocities (F, V, 3)).
    """
    import time as _time

    wp = warp()
    import warp.sim as wsim
    from warp.sim.integrator import integrate_particles
    from warp.sim.integrator_euler import eval_bending, eval_triangles

    times = np.asarray(times, dtype=np.float64)
    V = np.asarray(V, dtype=np.float64)
    H = hinges(tris)
    mu, lam = lame(mat)
    ke = hinge_stiffness(V, tris, H, mat.bending)
    A = tri_areas(V, tris)
    masses = np.zeros(len(V))
    for t, a in zip(tris, A):
        masses[t] += mat.areal_density * a / 3.0
    if dt is None:
        dt = stable_dt(V, tris, mat, dt_safety)

    b = wsim.ModelBuilder(up_vector=(0.0, 0.0, 1.0), gravity=-gravity)
    for p, m in zip(V, masses):
        b.add_particle(wp.vec3(*p), wp.vec3(0.0, 0.0, 0.0), float(m), radius=0.0)
    b.add_triangles(
        tris[:, 0],
        tris[:, 1],
        tris[:, 2],
        [mu] * len(tris),
        [lam] * len(tris),
        [mat.membrane_damping * mu] * len(tris),
        [0.5 * RHO_AIR * mat.drag_cd] * len(tris),
        [0.0] * len(tris),
    )
    b.add_edges(H[:, 0], H[:, 1], H[:, 2], H[:, 3], edge_ke=ke.tolist(), edge_kd=(mat.bending_damping * ke).tolist())
    model = b.finalize(device="cpu")
    model.ground = False
    model.enable_tri_collisions = False
    pv = np.array([p.vertex for p in pins], dtype=np.int64)
    inv = model.particle_inv_mass.numpy()
    inv[pv] = 0.0
    model.particle_inv_mass.assign(inv)

    s = [model.state(), model.state()]
    ctl = model.control()
    grav = wp.vec3(0.0, 0.0, -gravity)

    @wp.kernel
    def damp(qd: wp.array(dtype=wp.vec3), w: wp.array(dtype=float), factor: float):
        i = wp.tid()
        if w[i] > 0.0:
            qd[i] = qd[i] * factor

    def record(a, bb, settling):
        """The launches of one step from state a to state bb."""
        L = [
            wp.launch(
                eval_triangles,
                dim=model.tri_count,
                inputs=[
                    a.particle_q,
                    a.particle_qd,
                    model.tri_indices,
                    model.tri_poses,
                    ctl.tri_activations,
                    model.tri_materials,
                ],
                outputs=[a.particle_f],
                device="cpu",
                record_cmd=True,
            ),
            wp.launch(
                eval_bending,
                dim=model.edge_count,
                inputs=[
                    a.particle_q,
                    a.particle_qd,
                    model.edge_indices,
                    model.edge_rest_angle,
                    model.edge_bending_properties,
                ],
                outputs=[a.particle_f],
                device="cpu",
                record_cmd=True,
            ),
            wp.launch(
                integrate_particles,
                dim=model.particle_count,
                inputs=[
                    a.particle_q,
                    a.particle_qd,
                    a.particle_f,
                    model.particle_inv_mass,
                    model.particle_flags,
                    grav,
                    dt,
                    model.particle_max_velocity,
                ],
                outputs=[bb.particle_q, bb.particle_qd],
                device="cpu",
                record_cmd=True,
            ),
        ]
        if settling:
            L.append(
                wp.launch(
                    damp,
                    dim=model.particle_count,
                    inputs=[bb.particle_qd, model.particle_inv_mass, math.exp(-settle_damping * dt)],
                    device="cpu",
                    record_cmd=True,
                )
            )
        return L

    def step_fn(settling):
        cmds = [record(s[0], s[1], settling), record(s[1], s[0], settling)]
        return cmds

    n_settle = int(round(settle / dt))
    n_ramp = max(1, int(round(ramp / dt)))
    hold = np.array([p.hold for p in pins], dtype=np.float64)
    vel = (hold - V[pv]) / (n_ramp * dt)
    t_cpu = _time.process_time()
    cur = 0

    def set_pin_velocity(vv):
        q = s[cur].particle_qd.numpy()
        q[pv] = vv
        s[cur].particle_qd.assign(q)

    def run(n, cmds):
        nonlocal cur
        for _ in range(n):
            s[cur].particle_f.zero_()
            for c in cmds[cur]:
                c.launch()
            cur ^= 1

    settle_cmds = step_fn(True)
    free_cmds = step_fn(False)
    set_pin_velocity(vel)
    run(min(n_ramp, n_settle), settle_cmds)
    set_pin_velocity(np.zeros_like(vel))
    q = s[cur].particle_q.numpy()  # land exactly on the hold positions (float32 drift)
    q[pv] = hold
    s[cur].particle_q.assign(q)
    run(max(0, n_settle - n_ramp), settle_cmds)
    # after t = 0: Warp's forces only; a pin is released by giving its particle its mass back; a
    # moving pin is kinematic (no mass): between two events (a key of its path, a release, a frame)
    # it is put on its path and given the velocity that takes it to the path's point at the next one
    pending = sorted((float(p.release), p.vertex) for p in pins if p.release is not None)
    moving = [p for p in pins if p.moves]
    keys = sorted({int(math.ceil(k / dt - 1e-9)) for p in moving for k in p.path_times})
    released = set()
    out = np.empty((len(times), len(V), 3))
    vout = np.empty((len(times), len(V), 3)) if velocities else None
    k_step = 0
    for fi, t in enumerate(times):
        n_to = int(round(t / dt))
        while k_step < n_to:
            if pending and pending[0][0] <= k_step * dt + 1e-12:
                inv = model.particle_inv_mass.numpy()
                while pending and pending[0][0] <= k_step * dt + 1e-12:
                    v = pending.pop(0)[1]
                    inv[v] = 1.0 / masses[v]
                    released.add(v)
                model.particle_inv_mass.assign(inv)
            nxt = n_to if not pending else min(n_to, max(k_step + 1, int(math.ceil(pending[0][0] / dt - 1e-9))))
            nxt = min([nxt] + [k for k in keys if k > k_step])
            held = [p for p in moving if p.vertex not in released]
            if held:
                q, qd = s[cur].particle_q.numpy(), s[cur].particle_qd.numpy()
                for p in held:
                    a, b = p.position(k_step * dt), p.position(nxt * dt)
                    q[p.vertex] = a
                    qd[p.vertex] = (b - a) / ((nxt - k_step) * dt)
                s[cur].particle_q.assign(q)
                s[cur].particle_qd.assign(qd)
            run(nxt - k_step, free_cmds)
            k_step = nxt
        out[fi] = s[cur].particle_q.numpy().astype(np.float64)
        if velocities:
            vout[fi] = s[cur].particle_qd.numpy().astype(np.float64)
        if progress:
            progress(fi, len(times))
    out += np.asarray(origin, dtype=np.float64)
    facts = {
        "dt": dt,
        "steps": n_settle + k_step,
        "cpu_s": _time.process_time() - t_cpu,
        "vertices": len(V),
        "triangles": len(tris),
        "hinges": len(H),
    }
    if velocities:
        facts["velocities"] = vout
        facts["masses"] = masses
    return out, facts
