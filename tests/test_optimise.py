"""Tests of the optimisers (addon/core/fitting/optimise.py and its modules): encoding, SPX, MGG, CMA-ES, non-finite fitness, checkpoints."""

import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import json
import math

import numpy as np
import pytest
from clothfit.core import defaults as D
from clothfit.core.errors import ClothFitError
from clothfit.core.fitting.evolution_strategy import CMAES
from clothfit.core.fitting.ga import SPXMGG, spx_children
from clothfit.core.fitting.optimise import make_optimizer, optimizer_from_state
from clothfit.core.fitting.space import SearchSpace, reflect_unit, sanitize_fitness
from clothfit.core.fitting.steppable import Optimizer

SHIFT = np.array([1.2, -0.7, 2.3, 0.4])
# a physical-looking space, independent of the project's current defaults
PHYS_BOUNDS = {"k": (0.5, 50.0), "l": (0.004, 0.01), "d": (2.0e-6, 2.0e-4)}
PHYS_LOG = {"k": True, "l": False, "d": True}


def box(n, lo=-3.0, hi=4.0):
    names = list("abcd")[:n]
    return SearchSpace(names, {k: (lo, hi) for k in names})


def sphere(X):
    X = np.atleast_2d(X)
    return ((X - SHIFT[: X.shape[1]]) ** 2).sum(axis=1)


def rosenbrock(X):
    X = np.atleast_2d(X)
    return (100.0 * (X[:, 1:] - X[:, :-1] ** 2) ** 2 + (1.0 - X[:, :-1]) ** 2).sum(axis=1)


# --------------------------------------------------------------------------- SearchSpace


def test_space_round_trip_linear_and_log():
    sp = SearchSpace(["k", "l", "d"], PHYS_BOUNDS, PHYS_LOG)
    rng = np.random.default_rng(0)
    U = rng.random((50, 3))
    X = sp.decode(U)
    assert X.shape == (50, 3)
    assert np.all(X >= sp.lo) and np.all(X <= sp.hi)
    np.testing.assert_allclose(sp.encode(X), U, rtol=0, atol=1e-12)
    np.testing.assert_allclose(sp.decode(sp.encode(X)), X, rtol=1e-12)
    # single vectors keep their shape; bounds map to the cube's faces
    lo, hi = sp.lo, sp.hi
    np.testing.assert_allclose(sp.encode(lo), 0.0, atol=1e-15)
    np.testing.assert_allclose(sp.encode(hi), 1.0, atol=1e-15)
    # log scale: the centre of the cube is the geometric mean of the bounds (linear: arithmetic)
    np.testing.assert_allclose(
        sp.decode(np.full(3, 0.5)), [np.sqrt(0.5 * 50.0), 0.007, np.sqrt(2e-6 * 2e-4)], rtol=1e-12
    )
    np.testing.assert_allclose(sp.encode([5.0, 0.0055, 2e-5]), [0.5, 0.25, 0.5], atol=1e-12)
    # the project's own defaults make a valid space
    SearchSpace(list(D.SEARCH_BOUNDS), D.SEARCH_BOUNDS, D.LOG_SCALED)
    # linear scale: the centre is the arithmetic mean
    lin = SearchSpace(["a", "b"], {"a": (-1.0, 3.0), "b": (2.0, 4.0)}, {"b": False})
    np.testing.assert_allclose(lin.decode([0.5, 0.25]), [1.0, 2.5])
    np.testing.assert_allclose(lin.encode([[1.0, 2.5], [3.0, 2.0]]), [[0.5, 0.25], [1.0, 0.0]])


def test_space_subspace_keeps_bounds_and_scaling_of_the_names_given():
    sp = SearchSpace(
        ["a", "b", "c"], {"a": (0.1, 10.0), "b": (-1.0, 1.0), "c": (1.0, 100.0)}, {"a": True, "b": False, "c": True}
    )
    sub = sp.subspace(["c", "a"])
    assert sub.names == ["c", "a"] and sub.bounds == {"c": (1.0, 100.0), "a": (0.1, 10.0)}
    assert sub.log_scaled == {"c": True, "a": True}
    x = np.array([[5.0, 0.3, 20.0]])
    np.testing.assert_allclose(sub.encode(x[:, [2, 0]]), sp.encode(x)[:, [2, 0]])


def test_space_decode_clips_and_clip():
    sp = SearchSpace(["a", "b"], {"a": (1e-3, 1e3), "b": (0.0, 1.0)}, {"a": True})
    X = sp.decode([[-0.5, 1.5]])
    np.testing.assert_allclose(X, [[1e-3, 1.0]])
    np.testing.assert_allclose(sp.clip([5e3, -2.0]), [1e3, 0.0])
    assert sp.to_dict([2.0, 0.5]) == {"a": 2.0, "b": 0.5}
    np.testing.assert_allclose(sp.from_dict({"b": 0.5, "a": 2.0}), [2.0, 0.5])


@pytest.mark.parametrize(
    "bounds, log, name",
    [
        ({"a": (0.0, 1.0), "k": (2.0, 1.0)}, {}, "k"),  # lo > hi
        ({"a": (0.0, 1.0), "k": (1.0, 1.0)}, {}, "k"),  # lo == hi
        ({"a": (0.0, 1.0), "k": (0.0, math.inf)}, {}, "k"),  # not finite
        ({"a": (0.0, 1.0), "k": (math.nan, 1.0)}, {}, "k"),  # nan
        ({"a": (0.0, 1.0), "k": (0.0, 1.0)}, {"k": True}, "k"),  # log with lo = 0
        ({"a": (-1.0, 1.0), "k": (1.0, 2.0)}, {"a": True}, "a"),  # log with lo < 0
        ({"a": (0.0, 1.0)}, {}, "k"),  # missing
        ({"a": (0.0, 1.0), "k": "oops"}, {}, "k"),  # not a pair
    ],
)
def test_space_bad_bounds_name_the_parameter(bounds, log, name):
    with pytest.raises(ClothFitError, match=f"'{name}'"):
        SearchSpace(["a", "k"], bounds, log)


def test_space_encode_rejects_non_positive_log_value():
    sp = SearchSpace(["k", "d"], {"k": (1.0, 10.0), "d": (1e-6, 1e-3)}, {"k": True, "d": True})
    with pytest.raises(ClothFitError, match="'d'"):
        sp.encode([2.0, 0.0])
    with pytest.raises(ClothFitError, match="shape"):
        sp.encode([1.0, 2.0, 3.0])


# --------------------------------------------------------------------------- SPX


def _barycentric(Y, C):
    """Barycentric coordinates of the points C (N, n) in the simplex with vertices Y (n+1, n)."""
    A = np.vstack([Y.T, np.ones(len(Y))])  # (n+1, n+1)
    B = np.vstack([C.T, np.ones(len(C))])
    return np.linalg.solve(A, B).T  # (N, n+1)


@pytest.mark.parametrize("n", [2, 3, 4])
def test_spx_children_uniform_in_expanded_simplex(n):
    rng = np.random.default_rng(n)
    parents = rng.random((n + 1, n))
    eps = math.sqrt(n + 2)
    kids = spx_children(parents, 40000, eps, np.random.Generator(np.random.PCG64(1)))
    assert kids.shape == (40000, n)
    G = parents.mean(axis=0)
    Y = G + eps * (parents - G)
    # inside the expanded simplex
    lam = _barycentric(Y, kids)
    assert lam.min() > -1e-9
    # the mean is the parents' centroid
    scale = np.abs(Y - G).max()
    np.testing.assert_allclose(kids.mean(axis=0), G, atol=0.02 * scale)
    # and the spread is that of the uniform distribution on the simplex:
    # Cov = sum_k (y_k - G)(y_k - G)^T / ((n + 1)(n + 2))
    cov_expected = (Y - G).T @ (Y - G) / ((n + 1) * (n + 2))
    np.testing.assert_allclose(np.cov(kids.T), cov_expected, atol=0.03 * np.abs(cov_expected).max())
    # uniform barycentric coordinates: each has mean 1 / (n + 1)
    np.testing.assert_allclose(lam.mean(axis=0), 1.0 / (n + 1), atol=0.01)


def test_reflect_unit():
    v = np.array([-0.2, 1.3, 2.5, -1.7, 0.0, 1.0, 0.42])
    np.testing.assert_allclose(reflect_unit(v), [0.2, 0.7, 0.5, 0.3, 0.0, 1.0, 0.42], atol=1e-12)


# --------------------------------------------------------------------------- MGG


def test_mgg_population_constant_best_never_worsens():
    sp = box(3)
    opt = SPXMGG(sp, seed=3)
    X = opt.ask()
    assert X.shape == (D.GA_POPULATION, 3)
    opt.tell(X, sphere(X))
    pop_best = [opt.pop_f.min()]
    for _ in range(200):
        old_u, old_f = opt.pop_u.copy(), opt.pop_f.copy()
        X = opt.ask()
        assert X.shape == (D.GA_CHILDREN, 3)
        assert np.all(X >= sp.lo) and np.all(X <= sp.hi)
        f = sphere(X)
        opt.tell(X, f)
        assert opt.pop_u.shape == (D.GA_POPULATION, 3) and opt.pop_f.shape == (D.GA_POPULATION,)
        changed = np.nonzero(np.any(opt.pop_u != old_u, axis=1))[0]
        assert len(changed) <= 2  # only the two chosen parents are replaced
        # the best of the family survives
        fam_best = min(f.min(), old_f[changed].min()) if len(changed) else f.min()
        assert opt.pop_f.min() <= min(old_f.min(), fam_best) + 0.0
        pop_best.append(opt.pop_f.min())
        # fitness bookkeeping matches the objective
        np.testing.assert_allclose(opt.pop_f, sphere(sp.decode(opt.pop_u)), rtol=1e-12)
    assert np.all(np.diff(pop_best) <= 0)
    bests = [b for _, b in opt.history]
    assert np.all(np.diff(bests) <= 0)
    assert opt.evaluations == D.GA_POPULATION + 200 * D.GA_CHILDREN
    assert opt.generation == 201
    assert opt.history[-1] == (opt.evaluations, opt.best_f)
    assert opt.best_f == pytest.approx(opt.pop_f.min())


def test_mgg_initial_guesses_in_first_population():
    sp = SearchSpace(["k", "l", "d"], PHYS_BOUNDS, PHYS_LOG)
    gt = [10.0, 0.1 / 15, 2e-5]
    other = {"k": 2.0, "l": 0.005, "d": 1e-5}
    opt = SPXMGG(sp, seed=0, initial=[gt, other, [100.0, 0.001, 1e-5]])
    X = opt.ask()
    np.testing.assert_allclose(X[0], gt, rtol=1e-12)
    np.testing.assert_allclose(X[1], [2.0, 0.005, 1e-5], rtol=1e-12)
    np.testing.assert_allclose(X[2], [50.0, 0.004, 1e-5], rtol=1e-12)  # clipped to the bounds
    assert np.all(X >= sp.lo) and np.all(X <= sp.hi)
    assert SPXMGG(sp, seed=0).population == D.GA_POPULATION
    with pytest.raises(ClothFitError):
        SPXMGG(sp, seed=0, population=3)  # < n + 1


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("n", [3, 4])
def test_spx_mgg_minimises_shifted_sphere(seed, n):
    opt = make_optimizer("spx-mgg", box(n), seed=seed)
    x, f = opt.run(sphere, 10000)
    assert f < 1e-5
    np.testing.assert_allclose(x, SHIFT[:n], atol=5e-3)


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("n", [3, 4])
def test_spx_mgg_minimises_rosenbrock(seed, n):
    opt = make_optimizer("ga", box(n), seed=seed)
    x, f = opt.run(rosenbrock, 30000)
    assert f < 1e-6
    np.testing.assert_allclose(x, np.ones(n), atol=1e-2)


# --------------------------------------------------------------------------- CMA-ES


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("fn, xopt", [(sphere, SHIFT), (rosenbrock, np.ones(4))])
@pytest.mark.parametrize("n", [3, 4])
def test_cma_minimises(seed, fn, xopt, n):
    # Rosenbrock in 4-D has a local minimum (f = 3.70) that a single small-population run can end
    # in (seed 3 does, below): IPOP restarts are the remedy
    restarts = 2 if fn is rosenbrock else 0
    opt = make_optimizer("cma", box(n), seed=seed, restarts=restarts)
    assert opt.ask().shape == (D.CMA_POPSIZE, n)
    x, f = opt.run(fn, 6000)
    assert f < 1e-8
    np.testing.assert_allclose(x, xopt[:n], atol=1e-3)
    assert opt.evaluations <= 6000 + opt.run_popsize
    assert opt.stopped or opt.evaluations >= 6000


def test_cma_stops_by_itself_and_ipop_restarts_double_the_population():
    # seed 3's single run ends in Rosenbrock's local minimum (4-D); its IPOP restarts leave it
    opt = make_optimizer("cma", box(4), seed=3)
    x, f = opt.run(rosenbrock, 100_000)
    assert opt.stopped and opt.evaluations < 5000  # converged (to the local minimum)
    assert opt.run_stops == [opt.stop_reason] and opt.stop_reason in ("tolfun", "tolx")
    assert f == pytest.approx(3.7014, abs=1e-3)
    ipop = make_optimizer("cma", box(4), seed=3, restarts=3)
    x, f = ipop.run(rosenbrock, 100_000)
    assert ipop.stopped and len(ipop.run_stops) == 4 and ipop.run_popsize == 8 * D.CMA_POPSIZE
    assert f < 1e-10 and ipop.evaluations < 40_000


def test_cma_samples_are_a_smooth_function_of_the_covariance():
    """A covariance whose eigenvalues are nearly equal has eigenvectors that turn on its last bits, and
    those bits differ between CPUs (NumPy's AVX-512 exp and log): the samples must not turn with them,
    or a seed gives another fit on another machine."""
    rng = np.random.default_rng(4)
    Q, _ = np.linalg.qr(rng.standard_normal((4, 4)))
    C = (Q * np.array([1.0, 1.0 + 1e-13, 0.5, 2.0])) @ Q.T
    E = rng.standard_normal((4, 4)) * 1e-16
    batches = []
    for c in (C, C + (E + E.T)):
        opt = make_optimizer("cma", box(4), seed=11)
        opt.C = (c + c.T) / 2
        batches.append(opt.ask())
    assert np.abs(batches[0] - batches[1]).max() < 1e-12


def test_cma_initial_guess_and_global_rng_untouched():
    sp = box(3)
    np.random.seed(123)
    before = np.random.get_state()[1].copy()
    opt = CMAES(sp, seed=5, initial=[[1.0, 2.0, 3.0]])
    X = opt.ask()
    np.testing.assert_allclose(X[0], [1.0, 2.0, 3.0], atol=1e-9)
    opt.tell(X, sphere(X))
    opt.run(sphere, 300)
    assert np.array_equal(np.random.get_state()[1], before)


# --------------------------------------------------------------------------- non-finite fitness


def _nasty(X):
    """Sphere, but nan / inf / -inf wherever the first coordinate is above 1.5 (and always -inf
    for the exact first row of the first batch would be the lowest if it were taken as a value)."""
    f = sphere(X)
    a = X[:, 0]
    f = np.where(a > 1.5, np.nan, f)
    f = np.where((a > 0.5) & (a <= 0.8), np.inf, f)
    f = np.where((a > -1.0) & (a <= -0.5), -np.inf, f)
    return f


@pytest.mark.parametrize("name", ["spx-mgg", "cma-es"])
def test_non_finite_fitness_never_best(name):
    opt = make_optimizer(name, box(3), seed=4)
    seen_bad = 0
    for _ in range(120):
        X = opt.ask()
        f = _nasty(X)
        seen_bad += int(np.sum(~np.isfinite(f)))
        opt.tell(X, f)
        if opt.best_x is not None:
            assert math.isfinite(opt.best_f)
            assert math.isfinite(_nasty(opt.best_x[None])[0])
            assert _nasty(opt.best_x[None])[0] == pytest.approx(opt.best_f)
    assert seen_bad > 0
    assert opt.best_x is not None and math.isfinite(opt.best_f)
    assert all(math.isfinite(b) for _, b in opt.history[-5:])
    json.dumps(opt.state_dict(), allow_nan=False)
    if name == "spx-mgg":
        assert not np.any(np.isnan(opt.pop_f)) and not np.any(opt.pop_f == -np.inf)
        assert np.isinf(opt.pop_f).any() or np.isfinite(opt.pop_f).all()


@pytest.mark.parametrize("name", ["spx-mgg", "cma-es"])
def test_all_non_finite_does_not_crash(name):
    opt = make_optimizer(name, box(3), seed=0)
    for k in range(6):
        X = opt.ask()
        opt.tell(X, np.full(len(X), [np.nan, np.inf, -np.inf][k % 3]))
    assert opt.best_x is None and opt.best_f == math.inf
    assert opt.best_params is None
    if name == "spx-mgg":
        assert np.all(opt.pop_f == np.inf)  # -inf and nan are stored as +inf (worst)
    d = json.loads(json.dumps(opt.state_dict(), allow_nan=False))
    assert d["best_f"] is None
    again = optimizer_from_state(d)
    assert again.best_f == math.inf and again.best_x is None
    X = again.ask()
    again.tell(X, sphere(X))  # recovers as soon as values are finite
    assert math.isfinite(again.best_f)


def test_sanitize_fitness():
    f = sanitize_fitness([1.0, np.nan, -np.inf, np.inf, -2.0], 5)
    assert f.tolist() == [1.0, np.inf, np.inf, np.inf, -2.0]
    with pytest.raises(ClothFitError):
        sanitize_fitness([1.0, 2.0], 3)


def test_tell_checks_its_input():
    opt = SPXMGG(box(3), seed=0)
    with pytest.raises(ClothFitError):
        opt.tell(np.zeros((2, 3)), [1.0, 2.0])  # nothing asked
    X = opt.ask()
    np.testing.assert_array_equal(opt.ask(), X)  # asking twice gives the same batch
    with pytest.raises(ClothFitError, match="expected"):
        opt.tell(X, np.zeros(len(X) - 1))
    with pytest.raises(ClothFitError):
        opt.tell(X + 0.1, np.zeros(len(X)))
    opt.tell(X, sphere(X))


# --------------------------------------------------------------------------- determinism, checkpoints


def _trace(opt, fn, gens):
    out = []
    for _ in range(gens):
        X = opt.ask()
        out.append(X)
        opt.tell(X, fn(X))
    return out


@pytest.mark.parametrize("name", ["spx-mgg", "cma-es"])
def test_same_seed_same_run(name):
    a = _trace(make_optimizer(name, box(3), seed=11), rosenbrock, 40)
    b = _trace(make_optimizer(name, box(3), seed=11), rosenbrock, 40)
    c = _trace(make_optimizer(name, box(3), seed=12), rosenbrock, 40)
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    assert not np.array_equal(a[0], c[0])


@pytest.mark.parametrize("name", ["spx-mgg", "cma-es"])
@pytest.mark.parametrize("mid_ask", [False, True])
def test_checkpoint_resume_is_exact(name, mid_ask):
    def fn(X):  # with some non-finite values, to exercise their storage too
        return np.where(X[:, 0] > 3.0, np.nan, rosenbrock(X))

    sp = SearchSpace(["a", "b", "c"], {"a": (-3.0, 4.0), "b": (0.01, 10.0), "c": (-3.0, 4.0)}, {"b": True})
    full = make_optimizer(name, sp, seed=7, initial=[[0.5, 0.5, 0.5]])
    ref = _trace(full, fn, 60)

    part = make_optimizer(name, sp, seed=7, initial=[[0.5, 0.5, 0.5]])
    got = _trace(part, fn, 25)
    if mid_ask:
        part.ask()
    text = json.dumps(part.state_dict(), allow_nan=False)
    del part
    resumed = Optimizer.from_state(json.loads(text))
    assert type(resumed).__name__ == ("SPXMGG" if name == "spx-mgg" else "CMAES")
    assert resumed.evaluations == sum(len(x) for x in got)
    assert resumed.generation == 25
    got += _trace(resumed, fn, 35)

    assert len(got) == len(ref)
    for x, y in zip(got, ref):
        assert np.array_equal(x, y)
    assert resumed.best_f == full.best_f
    assert np.array_equal(resumed.best_x, full.best_x)
    assert resumed.history == full.history
    assert resumed.evaluations == full.evaluations


def test_from_state_rejects_wrong_algorithm():
    d = SPXMGG(box(3), seed=0).state_dict()
    with pytest.raises(ClothFitError, match="cma-es"):
        CMAES.from_state(d)
    with pytest.raises(ClothFitError):
        optimizer_from_state({"nothing": 1})


# --------------------------------------------------------------------------- driving, factory


@pytest.mark.parametrize("name", ["spx-mgg", "cma-es"])
def test_run_target_callback_and_budget(name):
    opt = make_optimizer(name, box(3), seed=1)
    opt.run(sphere, 100000, target=1e-2)
    assert opt.best_f <= 1e-2 and opt.evaluations < 100000
    calls = []
    opt2 = make_optimizer(name, box(3), seed=1)
    opt2.run(sphere, 100000, callback=lambda o: calls.append(o.generation) or len(calls) >= 5)
    assert calls == [1, 2, 3, 4, 5] and opt2.generation == 5
    opt3 = make_optimizer(name, box(3), seed=1)
    opt3.run(sphere, 500)
    assert 500 <= opt3.evaluations < 500 + max(D.GA_POPULATION, D.CMA_POPSIZE)
    # run() continues a total budget (cma may also stop by its own criteria: sphere is easy)
    opt3.run(sphere, 800)
    assert opt3.evaluations < 800 + max(D.GA_POPULATION, D.CMA_POPSIZE)
    assert opt3.evaluations >= 800 or (name == "cma-es" and opt3.stopped)
    assert opt3.step(sphere) == opt3.best_f


def test_make_optimizer_names():
    sp = box(3)
    for alias in ("spx-mgg", "ga", "spx_mgg", "GA"):
        assert isinstance(make_optimizer(alias, sp, seed=0), SPXMGG)
    for alias in ("cma-es", "cma"):
        assert isinstance(make_optimizer(alias, sp, seed=0), CMAES)
    with pytest.raises(ClothFitError) as err:
        make_optimizer("pso", sp, seed=0)
    assert "spx-mgg" in str(err.value) and "cma-es" in str(err.value) and "pso" in str(err.value)
    opt = make_optimizer("ga", sp, seed=0, population=12, children=7)
    assert len(opt.ask()) == 12
    opt.tell(opt.ask(), sphere(opt.ask()))
    assert len(opt.ask()) == 7


# --------------------------------------------------------------------------- untrusted checkpoints


class _Boom:
    """Unpickling this would create the file ``_Boom.path``."""

    path = None

    def __reduce__(self):
        return (open, (self.path, "w"))


def _cma_state(gens=5):
    opt = make_optimizer("cma-es", box(3), seed=3)
    _trace(opt, rosenbrock, gens)
    opt.ask()
    return json.loads(json.dumps(opt.state_dict(), allow_nan=False))


def test_a_pickle_payload_is_never_run(tmp_path):
    import base64
    import pickle

    marker = tmp_path / "pwned"
    _Boom.path = str(marker)
    d = _cma_state()
    d["pickle_b64"] = base64.b64encode(pickle.dumps({"es": _Boom()})).decode()
    with pytest.raises(ClothFitError) as err:
        optimizer_from_state(d)
    assert "unknown fields" in str(err.value) and "pickle_b64" in str(err.value)
    assert "\n" not in str(err.value)
    assert not marker.exists()
    # the old (version 1, pickled) format is refused by its version, before any field is read
    d["version"] = 1
    with pytest.raises(ClothFitError, match="version"):
        optimizer_from_state(d)
    assert not marker.exists()


def _set(path, value):
    def f(d):
        node = d
        for k in path[:-1]:
            node = node[k]
        node[path[-1]] = value

    return f


def _del(key):
    return lambda d: d.pop(key)


CMA_MUTATIONS = {
    "C not positive definite": _set(["C"], [[1.0, 2.0, 0.0], [2.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),
    "C not symmetric": _set(["C"], [[1.0, 0.1, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),
    "C nan": _set(["C", 0, 0], float("nan")),
    "C wrong shape": _set(["C"], [[1.0, 0.0], [0.0, 1.0]]),
    "C strings": _set(["C"], "eye"),
    "sigma negative": _set(["sigma"], -1.0),
    "sigma inf": _set(["sigma"], float("inf")),
    "sigma string": _set(["sigma"], "0.3"),
    "mean short": _set(["mean"], [0.5, 0.5]),
    "mean far": _set(["mean"], [1e300, 0.5, 0.5]),
    "mean nested": _set(["mean"], [[0.5], [0.5], [0.5]]),
    "pending wrong rows": _set(["pending"], [[0.5, 0.5, 0.5]]),
    "lam not popsize": _set(["lam"], 1000),
    "lam bool": _set(["lam"], True),
    "rng garbage": _set(["rng"], {"bit_generator": "MT19937", "state": {}}),
    "rng negative": _set(["rng", "state", "state"], -5),
    "rng float": _set(["rng", "state", "inc"], 1.5),
    "history bad": _set(["history"], [["a", 1.0]]),
    "history object": _set(["history"], {"x": 1}),
    "evaluations negative": _set(["evaluations"], -1),
    "best_u without best_f": _set(["best_f"], None),
    "restarts huge": _set(["restarts"], 10**9),
    "stop reason unknown": _set(["stop_reason"], "os.system"),
    "space not object": _set(["space"], [1, 2]),
    "space bounds": _set(["space", "bounds", "a"], [4.0, -3.0]),
    "space extra": _set(["space", "code"], "x"),
    "seed string": _set(["seed"], "0"),
    "no mean": _del("mean"),
    "no rng": _del("rng"),
    "not a dict": lambda d: None,
}


@pytest.mark.parametrize("case", sorted(CMA_MUTATIONS))
def test_corrupt_cma_state_is_one_line_error(case):
    d = _cma_state()
    CMA_MUTATIONS[case](d)
    if case == "not a dict":
        d = ["cma-es"]
    with pytest.raises(ClothFitError) as err:
        optimizer_from_state(d)
    assert "\n" not in str(err.value)


GA_MUTATIONS = {
    "pop_f nan": _set(["pop_f", 0], float("nan")),
    "pop_u shape": _set(["pop_u"], [[0.5, 0.5, 0.5]]),
    "pop_u without pop_f": _set(["pop_f"], None),
    "replace same": _set(["replace"], [1, 1]),
    "replace outside": _set(["replace"], [0, 10**6]),
    "children zero": _set(["children"], 0),
    "population below n+1": _set(["population"], 2),
    "eps nan": _set(["eps"], float("nan")),
    "unknown field": _set(["__reduce__"], "os.system"),
}


@pytest.mark.parametrize("case", sorted(GA_MUTATIONS))
def test_corrupt_ga_state_is_one_line_error(case):
    opt = make_optimizer("spx-mgg", box(3), seed=3)
    _trace(opt, rosenbrock, 5)
    opt.ask()
    d = json.loads(json.dumps(opt.state_dict(), allow_nan=False))
    optimizer_from_state(json.loads(json.dumps(d)))  # the unmodified state loads
    GA_MUTATIONS[case](d)
    with pytest.raises(ClothFitError) as err:
        optimizer_from_state(d)
    assert "\n" not in str(err.value)


def test_ga_stops_on_stagnation_and_collapse():
    opt = make_optimizer("ga", box(3), seed=0, stall_evaluations=3000, tolfun=1e-9)
    opt.run(sphere, 10**6)
    assert opt.stopped and opt.stop_reason == "stagnation" and opt.evaluations < 200_000
    assert opt.best_f < 1e-6
    off = make_optimizer("ga", box(3), seed=0)
    off.run(sphere, 5000)
    assert not off.stopped and off.evaluations >= 5000
    collapse = make_optimizer("ga", box(3), seed=0, tolx=1e-3)
    collapse.run(sphere, 10**6)
    assert collapse.stop_reason == "tolx" and np.all(np.ptp(collapse.pop_u, axis=0) < 1e-3)


def test_active_cma_minimises_an_ill_conditioned_ellipsoid_and_resumes_exactly():
    """Active CMA-ES (negative weights for the worse half; off by default) converges on an
    8-D ellipsoid, keeps C positive definite, and its state round-trips through JSON."""
    n = 8
    space = SearchSpace(
        [f"x{i}" for i in range(n)], {f"x{i}": (-1.0, 1.0) for i in range(n)}, {f"x{i}": False for i in range(n)}
    )
    scale = 10.0 ** (np.arange(n) / (n - 1) * 3)

    def f(X):
        return np.sum((scale * (np.atleast_2d(X) - 0.3)) ** 2, axis=1)

    # One seed is a coin toss (seed 3: 5.2e-5 against 4.6e-3); over 8 seeds, measured: active
    # better in every one (ratio 7e-7 .. 0.062, median 7e-4), its median best 3e-5.
    ratios, bests = [], []
    for seed in range(8):
        a = CMAES(space, seed=seed, active=True, tolx=1e-12)
        p = CMAES(space, seed=seed, tolx=1e-12)
        for _ in range(400):
            for o in (a, p):
                X = o.ask()
                o.tell(X, f(X))
            assert np.linalg.eigvalsh(a.C).min() > 0
        ratios.append(a.best_f / p.best_f)
        bests.append(a.best_f)
    assert max(ratios) < 0.2 and np.median(ratios) < 1e-2 and np.median(bests) < 1e-4
    b = CMAES(space, seed=3, active=True)
    for _ in range(5):
        b.tell(b.ask(), f(b.ask()))
    c = optimizer_from_state(json.loads(json.dumps(b.state_dict())))
    assert c.active
    for _ in range(5):
        xb, xc = b.ask(), c.ask()
        np.testing.assert_array_equal(xb, xc)
        b.tell(xb, f(xb))
        c.tell(xc, f(xc))
    bad = b.state_dict()
    bad["active"] = "yes"
    with pytest.raises(ClothFitError, match="'active' must be true or false"):
        optimizer_from_state(bad)
