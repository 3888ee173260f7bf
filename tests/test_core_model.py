import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

"""The mass-spring model (docs/method.md#spec-2): topology, forces, integrator, backends, explosions, handles,
parameter validation and identifiability."""

import math

import numpy as np
import pytest
from clothfit.core import defaults as D
from clothfit.core.errors import ClothFitError
from clothfit.core.physics import jit
from clothfit.core.physics import paper as S
from clothfit.core.physics.models import simulate
from clothfit.core.physics.paper import Params, identifiable, identifiable_errors
from clothfit.core.physics.scenario import ClothGrid, Handle, Scenario, paper_scenario

GT = dict(D.GT_PARAMS)
GT_ROW = [GT["m"], GT["k"], GT["l"], GT["d"]]
BACKENDS = ["numpy", pytest.param("numba", marks=pytest.mark.skipif(not jit.available(), reason="numba missing"))]
needs_numba = pytest.mark.skipif(not jit.available(), reason="numba not importable: no second backend")


# ------------------------------------------------------------------ topology


def _edges_of_triangles(tris):
    e = set()
    for a, b, c in tris:
        for i, j in ((a, b), (b, c), (c, a)):
            e.add((min(i, j), max(i, j)))
    return e


def test_grid_counts_16x16_match_the_paper():
    g = ClothGrid()
    assert (g.nx, g.ny) == (16, 16)
    assert g.n_vertices == 256 and g.rest.shape == (256, 3)
    assert g.triangles.shape == (450, 3)
    assert g.springs.shape == (705, 2)
    # 240 horizontal + 240 vertical (rest factor 1) and 225 diagonal (rest factor sqrt 2)
    assert np.count_nonzero(g.rest_factor == 1.0) == 480
    assert np.count_nonzero(np.isclose(g.rest_factor, math.sqrt(2.0))) == 225
    h = g.springs[:240]
    v = g.springs[240:480]
    assert np.all(h[:, 1] - h[:, 0] == 1)  # same row, next column
    assert np.all(v[:, 1] - v[:, 0] == 16)  # next row, same column
    assert np.all(g.springs[480:, 1] - g.springs[480:, 0] == 17)
    assert abs(g.spacing - 0.10 / 15) < 1e-15
    assert g.corners() == [0, 15, 240, 255]


@pytest.mark.parametrize("nx,ny", [(5, 3), (3, 7), (16, 9)])
def test_grid_counts_non_square(nx, ny):
    g = ClothGrid(nx=nx, ny=ny, side=0.12, side_y=0.06)
    assert g.n_vertices == nx * ny
    assert g.triangles.shape == (2 * (nx - 1) * (ny - 1), 3)
    nh, nv, nd = ny * (nx - 1), (ny - 1) * nx, (ny - 1) * (nx - 1)
    assert g.springs.shape == (nh + nv + nd, 2)
    assert g.corners() == [0, nx - 1, (ny - 1) * nx, ny * nx - 1]
    # every spring is a triangle edge and every triangle edge is a spring, no duplicates
    springs = {(min(a, b), max(a, b)) for a, b in g.springs}
    assert len(springs) == len(g.springs)
    assert springs == _edges_of_triangles(g.triangles)
    # triangles counter-clockwise seen from +z, none degenerate
    P = g.rest[g.triangles]
    area2 = (P[:, 1, 0] - P[:, 0, 0]) * (P[:, 2, 1] - P[:, 0, 1]) - (P[:, 2, 0] - P[:, 0, 0]) * (
        P[:, 1, 1] - P[:, 0, 1]
    )
    assert np.all(area2 > 0)
    assert np.all(g.triangles.min() >= 0) and g.triangles.max() == nx * ny - 1
    # extent of the rest sheet
    assert np.isclose(np.ptp(g.rest[:, 0]), 0.12) and np.isclose(np.ptp(g.rest[:, 1]), 0.06)


def test_square_grid_rest_lengths_are_l_times_rest_factor():
    g = ClothGrid(nx=7)
    s = g.springs
    ln = np.linalg.norm(g.rest[s[:, 1]] - g.rest[s[:, 0]], axis=1)
    assert np.allclose(ln, g.spacing * g.rest_factor, rtol=1e-12, atol=0)
    assert S.spring_energy(g.rest, g, k=10.0, l=g.spacing) < 1e-25
    assert np.abs(S.spring_forces(g.rest, g, 10.0, g.spacing)).max() < 1e-12


def test_grid_rejects_tiny_grid():
    with pytest.raises(ClothFitError, match="2 x 2"):
        ClothGrid(nx=1)


# ------------------------------------------------------------------ forces


@pytest.mark.parametrize("nx,ny", [(16, 16), (6, 4)])
def test_spring_forces_are_minus_energy_gradient(nx, ny):
    g = ClothGrid(nx=nx, ny=ny)
    rng = np.random.default_rng(nx * 100 + ny)
    x = g.rest + rng.normal(scale=0.3 * g.spacing, size=g.rest.shape)
    k, l = 7.5, 0.9 * g.spacing
    F = S.spring_forces(x, g, k, l)
    assert F.shape == x.shape
    assert np.abs(F).max() > 1e-3  # not trivially zero
    h = 1e-7
    num = np.zeros_like(x)
    verts = rng.choice(g.n_vertices, size=min(40, g.n_vertices), replace=False)
    for i in verts:
        for a in range(3):
            xp = x.copy()
            xm = x.copy()
            xp[i, a] += h
            xm[i, a] -= h
            num[i, a] = -(S.spring_energy(xp, g, k, l) - S.spring_energy(xm, g, k, l)) / (2 * h)
    err = np.abs(num[verts] - F[verts]).max()
    assert err < 1e-5 * np.abs(F[verts]).max(), err
    # internal forces sum to zero (Newton's third law)
    assert np.abs(F.sum(0)).max() < 1e-12


@pytest.mark.parametrize("backend", BACKENDS)
def test_simulator_first_step_uses_the_model_forces(backend):
    """One semi-implicit Euler step from rest: x1 = x0 + dt^2 (g + F(x0)/m) (d = 0): the simulator's
    grid-structured forces equal ``spring_forces`` on a perturbed, non-square grid."""
    g = ClothGrid(nx=7, ny=5)
    rng = np.random.default_rng(3)
    g.rest = g.rest + rng.normal(scale=0.2 * g.spacing, size=g.rest.shape)
    m, k, l = 2e-5, 8.0, 1.1 * g.spacing
    dt = 0.5 * D.DT_SAFETY * math.sqrt(m / k)  # one substep in the interval
    grav = np.array([0.3, -0.2, -9.81])
    sc = Scenario(g, [], [dt], settle_time=0.0, gravity=grav)
    r = simulate(sc, [[m, k, l, 0.0]], backend=backend)
    assert not r.exploded[0] and r.substeps[0] == 1
    expect = g.rest + dt * dt * (grav + S.spring_forces(g.rest, g, k, l) / m)
    disp = expect - g.rest
    assert np.abs(r.positions[0, 0] - expect).max() < 1e-9 * np.abs(disp).max()


# --------------------------------------------------------------- integrator


def _free_scenario(n_steps, m, k, nx=8, seed=0):
    """No gravity, no handles, no settling, a stretched and randomly perturbed start; one frame per
    integrator step (frame interval = the stability-bound step)."""
    g = ClothGrid(nx=nx)
    rng = np.random.default_rng(seed)
    g.rest = g.rest.copy()
    g.rest[:, :2] *= 1.2
    g.rest += rng.normal(scale=0.0005, size=g.rest.shape)
    dt = D.DT_SAFETY * math.sqrt(m / k)
    times = dt * np.arange(1, n_steps + 1)
    return g, dt, Scenario(g, [], times, settle_time=0.0, gravity=[0.0, 0.0, 0.0])


def _energies(g, X, dt, m, k, l):
    """Total energy at interior frames: central-difference velocity (exact for the leapfrog form of
    semi-implicit Euler, up to O(dt^2)) and spring energy at the frame."""
    v = (X[2:] - X[:-2]) / (2 * dt)
    return np.array([0.5 * m * np.sum(v[i] ** 2) + S.spring_energy(X[i + 1], g, k, l) for i in range(len(v))])


@pytest.mark.parametrize("backend", BACKENDS)
def test_undamped_energy_is_conserved_without_drift(backend):
    m, k = 1e-5, 10.0
    n = 4000
    g, dt, sc = _free_scenario(n, m, k)
    l = g.spacing
    r = simulate(sc, [[m, k, l, 0.0]], backend=backend)
    assert not r.exploded[0]
    assert r.substeps[0] == n
    X = np.concatenate([g.rest[None], r.positions[0]])
    E0 = S.spring_energy(g.rest, g, k, l)
    assert E0 > 1e-3
    E = _energies(g, X, dt, m, k, l)
    # the sheet really moves: most of the energy changes form (spring <-> kinetic)
    ke = 0.5 * m * np.sum(((X[2:] - X[:-2]) / (2 * dt)) ** 2, axis=(1, 2))
    assert ke.max() > 0.3 * E0
    assert E.min() > 0.92 * E0 and E.max() < 1.08 * E0, (E.min() / E0, E.max() / E0)
    drift = abs(E[-1000:].mean() - E[:1000].mean()) / E0
    assert drift < 0.02, drift


@pytest.mark.parametrize("backend", BACKENDS)
def test_damped_energy_decreases(backend):
    m, k, d = 1e-5, 10.0, 2e-5
    n = 4000
    g, dt, sc = _free_scenario(n, m, k)
    l = g.spacing
    r = simulate(sc, [[m, k, l, d]], backend=backend)
    X = np.concatenate([g.rest[None], r.positions[0]])
    E0 = S.spring_energy(g.rest, g, k, l)
    E = _energies(g, X, dt, m, k, l)
    blocks = E[: (len(E) // 400) * 400].reshape(-1, 400).max(1)
    assert np.all(np.diff(blocks) < 0), blocks / E0
    assert E[-1] < 0.05 * E0


# ------------------------------------------------------------------ backends


@needs_numba
def test_numpy_and_numba_agree_on_the_paper_scenario():
    sc = paper_scenario()
    l = GT["l"]
    pop = [
        GT_ROW,
        [GT["m"], GT["k"] * 1.1, l * 0.97, GT["d"] * 0.8],
        [1e-5, 1e9, l, 0.0],  # k/m = 1e14: too many steps
        [-1e-5, 10.0, l, 0.0],  # m <= 0: invalid
        [1e-5, 10.0, l, 0.0],
    ]  # undamped: chaotic but valid
    a = simulate(sc, pop, backend="numpy")
    b = simulate(sc, pop, backend="numba")
    assert a.positions.shape == b.positions.shape == (5, 30, 256, 3)
    assert np.array_equal(a.exploded, b.exploded)
    assert a.exploded.tolist() == [False, False, True, True, False]
    assert np.array_equal(a.substeps[~a.exploded], b.substeps[~b.exploded])
    for p in (0, 1):
        diff = np.abs(a.positions[p] - b.positions[p]).max()
        assert diff < 1e-4, (p, diff)
    assert np.all(np.isnan(a.positions[a.exploded])) and np.all(np.isnan(b.positions[b.exploded]))


ABSURD = {
    "too_stiff": [1e-5, 1e9, GT["l"], 0.0],  # k/m = 1e14 -> more than MAX_TOTAL_STEPS
    "zero_mass": [0.0, 10.0, GT["l"], 0.0],
    "negative_mass": [-1e-5, 10.0, GT["l"], 0.0],
    "negative_damping": [1e-5, 10.0, GT["l"], -1e-5],
    "nan_mass": [float("nan"), 10.0, GT["l"], 5e-5],
    "nan_k": [1e-5, float("nan"), GT["l"], 5e-5],
    "inf_k": [1e-5, float("inf"), GT["l"], 5e-5],
}


def _absurd_cases():
    out = []
    for b in BACKENDS:
        bname = b if isinstance(b, str) else b.values[0]
        bmarks = [] if isinstance(b, str) else list(b.marks)
        for kind in ABSURD:
            out.append(pytest.param(bname, kind, marks=bmarks, id=f"{bname}-{kind}"))
    return out


@pytest.fixture(scope="module")
def short_paper():
    return paper_scenario(frame_times=[0.05, 0.2, 0.4])


@pytest.fixture(scope="module")
def short_paper_gt(short_paper):
    return simulate(short_paper, [GT_ROW], backend="numpy")


@pytest.mark.parametrize("backend,kind", _absurd_cases())
def test_absurd_candidate_is_flagged_not_raised(backend, kind, short_paper, short_paper_gt):
    pop = [GT_ROW, ABSURD[kind], GT_ROW]
    r = simulate(short_paper, pop, backend=backend)  # never an exception
    assert r.exploded.tolist() == [False, True, False]
    assert isinstance(r.reason[1], str) and r.reason[1]
    if kind == "too_stiff":
        assert "too many steps" in r.reason[1]
    elif kind in ("zero_mass", "negative_mass", "negative_damping", "nan_mass", "nan_k", "inf_k"):
        assert "invalid" in r.reason[1]
    assert r.reason[0] == "" and r.reason[2] == ""
    assert np.all(np.isnan(r.positions[1]))
    # the good candidates are those of a run without the bad one
    ref = short_paper_gt.positions[0]
    for p in (0, 2):
        assert np.abs(r.positions[p] - ref).max() < 1e-6


def test_numpy_population_of_only_bad_candidates_is_flagged_not_raised(short_paper):
    r = simulate(short_paper, [[-1.0, 10.0, GT["l"], 0.0]], backend="numpy")
    assert r.exploded.tolist() == [True]
    assert "invalid" in r.reason[0]


@needs_numba
def test_numba_population_of_only_bad_candidates_is_flagged(short_paper):
    r = simulate(short_paper, [[-1.0, 10.0, GT["l"], 0.0], [1e-5, 1e9, GT["l"], 0.0]], backend="numba")
    assert r.exploded.tolist() == [True, True]
    assert all(r.reason)


def test_unknown_backend_is_an_error(short_paper):
    with pytest.raises(ClothFitError, match="gpu"):
        simulate(short_paper, [GT_ROW], backend="gpu")


# -------------------------------------------------------------------- handles


def _handle_scenario():
    g = ClothGrid(nx=6)
    c = g.corners()
    hs = [
        Handle(c[0], [0.0], g.rest[c[0]][None], release_time=0.3),
        Handle(c[1], [0.0], g.rest[c[1]][None]),
        Handle(c[2], [0.0], g.rest[c[2]][None]),
        Handle(
            c[3], [0.0, 0.2, 0.4], [g.rest[c[3]], g.rest[c[3]] + [0.0, 0.0, 0.02], g.rest[c[3]] + [0.01, -0.005, 0.0]]
        ),
    ]
    times = [0.05, 0.1, 0.2, 0.25, 0.29, 0.3, 0.35, 0.4, 0.5]
    sc = Scenario(g, hs, times, settle_time=0.2)
    n = g.n_vertices
    p = [2.5e-3 / n, 10.0, g.spacing, 5.0 * 2.5e-3 / n]
    return g, hs, sc, p


@pytest.mark.parametrize("backend", BACKENDS)
def test_held_vertices_follow_their_trajectory_at_frame_times(backend):
    g, hs, sc, p = _handle_scenario()
    r = simulate(sc, [p], backend=backend)
    assert not r.exploded[0]
    X = r.positions[0]
    t = sc.frame_times
    for h in hs[1:]:
        err = np.abs(X[:, h.vertex] - h.position(t)).max()
        assert err < 1e-12, (h.vertex, err)
    # the moving handle really moved along its keys (interpolated between them)
    mv = hs[3]
    assert np.allclose(X[list(t).index(0.1), mv.vertex], g.rest[mv.vertex] + [0, 0, 0.01], atol=1e-12)
    assert np.allclose(X[list(t).index(0.5), mv.vertex], g.rest[mv.vertex] + [0.01, -0.005, 0.0], atol=1e-12)
    # free vertices do move (gravity)
    free = np.setdiff1d(np.arange(g.n_vertices), [h.vertex for h in hs])
    assert np.abs(X[-1, free] - g.rest[free]).max() > 1e-3


@pytest.mark.parametrize("backend", BACKENDS)
def test_released_corner_moves_after_release_and_not_before(backend):
    g, hs, sc, p = _handle_scenario()
    r = simulate(sc, [p], backend=backend)
    X = r.positions[0]
    v = hs[0].vertex
    dist = np.linalg.norm(X[:, v] - g.rest[v], axis=1)
    t = sc.frame_times
    before = t < 0.3
    after = t > 0.3
    assert np.all(dist[before] == 0.0), dist
    assert np.all(dist[after] > 1e-3), dist
    assert np.all(np.diff(dist[after]) > 0)  # it keeps falling away over the next 0.2 s


@pytest.mark.parametrize("backend", BACKENDS)
def test_released_corner_is_still_at_its_hold_position_at_the_release_time(backend):
    g, hs, sc, p = _handle_scenario()
    r = simulate(sc, [p], backend=backend)
    v = hs[0].vertex
    i = list(sc.frame_times).index(0.3)
    assert np.linalg.norm(r.positions[0, i, v] - g.rest[v]) < 1e-12


def test_paper_scenario_holds_three_corners_and_releases_one():
    sc = paper_scenario()
    assert sc.frame_times.tolist() == D.FRAME_TIMES and len(D.FRAME_TIMES) == 30
    rel = [h for h in sc.handles if h.release_time is not None]
    assert len(sc.handles) == 4 and len(rel) == 1 and rel[0].release_time == 0.0
    assert rel[0].vertex == sc.grid.corners()[D.RELEASED_CORNER]
    r = simulate(sc.with_frames([0.05, 0.5, 1.0]), [GT_ROW], backend="numpy")
    X = r.positions[0]
    for h in sc.handles:
        d = np.linalg.norm(X[:, h.vertex] - sc.grid.rest[h.vertex], axis=1)
        if h.release_time is None:
            assert np.all(d == 0.0)
        else:
            assert np.all(d > 1e-3)


def test_handle_and_scenario_validation():
    g = ClothGrid(nx=4)
    with pytest.raises(ClothFitError, match="increase"):
        Handle(0, [0.0, 0.0], [[0, 0, 0], [1, 1, 1]])
    with pytest.raises(ClothFitError, match="2 times but 1 positions"):
        Handle(0, [0.0, 1.0], [[0, 0, 0]])
    with pytest.raises(ClothFitError, match="vertex 99"):
        Scenario(g, [Handle(99, [0.0], [[0, 0, 0]])], [0.1])
    with pytest.raises(ClothFitError, match="two handles"):
        Scenario(g, [Handle(1, [0.0], [[0, 0, 0]]), Handle(1, [0.0], [[0, 0, 0]])], [0.1])
    with pytest.raises(ClothFitError, match="increase"):
        Scenario(g, [], [0.2, 0.1])


# ------------------------------------------------------------------ params


@pytest.mark.parametrize(
    "kw,needle",
    [
        (dict(m=float("nan")), "m = nan"),
        (dict(k=float("inf")), "k = inf"),
        (dict(m=-2e-5), "m=-2e-05"),
        (dict(k=0.0), "k=0.0"),
        (dict(l=-0.5), "l=-0.5"),
        (dict(d=-0.25), "d = -0.25"),
    ],
)
def test_params_validation_names_the_value(kw, needle):
    d = dict(GT, **kw)
    with pytest.raises(ClothFitError) as e:
        Params.from_dict(d, source="my params")
    assert needle in str(e.value) and "my params" in str(e.value)


def test_params_from_dict_missing_and_non_numeric():
    with pytest.raises(ClothFitError, match="'l'"):
        Params.from_dict({"m": 1, "k": 1, "d": 0})
    with pytest.raises(ClothFitError, match="abc"):
        Params.from_dict(dict(GT, k="abc"))
    p = Params.from_dict(GT)
    assert p.as_dict() == GT


def test_identifiable_combinations():
    p = Params(m=2e-5, k=20.0, l=0.007, d=1e-4)
    ident = p.identifiable()
    assert ident == pytest.approx({"k_over_m": 1e6, "d_over_m": 5.0, "l": 0.007}, rel=1e-12)
    assert identifiable(p.as_dict()) == ident
    q = {"m": 3e-5, "k": 33.0, "l": 0.007 * 1.02, "d": 1.5e-4}  # k/m +10 %, d/m same, l +2 %
    err = identifiable_errors(q, p.as_dict())
    assert err["k_over_m"] == pytest.approx(10.0, rel=1e-9)
    assert err["d_over_m"] == pytest.approx(0.0, abs=1e-9)
    assert err["l"] == pytest.approx(2.0, rel=1e-9)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("factor", [3.7, 0.013])
def test_scaling_m_k_d_together_gives_identical_motion(backend, factor):
    """docs/method.md#identifiability-what-silhouettes-can-tell: the motion depends on k/m, d/m and l only."""
    sc = paper_scenario(frame_times=[0.05, 0.3, 0.7, 1.2])
    scaled = [GT["m"] * factor, GT["k"] * factor, GT["l"], GT["d"] * factor]
    other = [GT["m"], GT["k"] * 1.3, GT["l"], GT["d"] * 1.3]  # scaling k, d but not m does change it
    r = simulate(sc, [GT_ROW, scaled, other], backend=backend)
    assert not r.exploded.any()
    diff = np.abs(r.positions[0] - r.positions[1]).max()
    assert diff < 1e-9, diff
    assert np.abs(r.positions[0] - r.positions[2]).max() > 1e-3
