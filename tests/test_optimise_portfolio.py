"""Tests of the CMA-ES portfolio (addon/core/fitting/portfolio.py CMAPortfolio): its schedule
(successive halving, refine, polishes), exact JSON resume in every phase, bad checkpoints."""

import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import json

import numpy as np
import pytest
from clothfit.core.errors import ClothFitError
from clothfit.core.fitting.evolution_strategy import CMAES
from clothfit.core.fitting.optimise import make_optimizer, optimizer_from_state
from clothfit.core.fitting.portfolio import CMAPortfolio
from clothfit.core.fitting.space import SearchSpace


def space(n=4):
    return SearchSpace(
        [f"x{i}" for i in range(n)], {f"x{i}": (-5.0, 5.0) for i in range(n)}, {f"x{i}": False for i in range(n)}
    )


def rastrigin(X):
    X = np.atleast_2d(X) - 1.3
    return 10 * X.shape[1] + np.sum(X**2 - 10 * np.cos(2 * np.pi * X), axis=1)


def two_basins(X):
    """A wide basin (value 1 at its bottom) around the centre and a narrower one (value 0) off it."""
    X = np.atleast_2d(X)
    wide = np.sum(X**2, axis=1) / 10 + 1.0
    narrow = 0.3 * np.sum((X - 3.0) ** 2, axis=1)
    return np.minimum(wide, narrow)


def test_names_and_schedule_phases_in_order():
    assert type(make_optimizer("portfolio", space(), seed=0)) is CMAPortfolio
    assert type(make_optimizer("cma-portfolio", space(), seed=0)) is CMAPortfolio
    opt = CMAPortfolio(space(), seed=1, runs=4, explore=0.5, budget=1200, max_polishes=2, tolfun=1e-9)
    assert opt.n_rounds == 3 and len(opt.children) == 4 and opt.alive == [0, 1, 2, 3]
    # the first run starts at the centre, the others at random means
    assert np.allclose(opt.children[0].mean, 0.5) and not np.allclose(opt.children[1].mean, 0.5)
    seen, explore_evals, alive_sizes = [], 0, []
    while not opt.stopped and opt.evaluations < 20000:
        phase = opt.phase
        alive_sizes.append(len(opt.alive))
        X = opt.ask()
        opt.tell(X, rastrigin(X))
        if phase == "explore":
            explore_evals += len(X)
        if not seen or seen[-1] != phase:
            seen.append(phase)
    assert seen == ["explore", "refine", "polish"]
    assert opt.stopped and opt.stop_reason == "polishes" and opt.polishes == 2
    # successive halving 4 -> 2 -> 1; the exploration spends its share (one generation over at most per round)
    assert [s for i, s in enumerate(alive_sizes) if i == 0 or alive_sizes[i - 1] != s] == [4, 2, 1]
    assert 600 <= explore_evals <= 600 + 3 * opt.popsize
    # the kept run is the best of those that took part; dropped runs are forgotten
    assert sum(c is not None for c in opt.children[:4]) == 1
    assert opt.best_f == min(c.best_f for c in opt.children if c is not None)
    with pytest.raises(ClothFitError, match="stopped"):
        opt.ask()


def test_halving_keeps_the_better_runs():
    opt = CMAPortfolio(space(2), seed=5, runs=4, explore=0.6, budget=600)
    bests = None
    while opt.phase == "explore" and opt.round == 0:
        bests = {i: opt.children[i].best_f for i in range(4)}
        X = opt.ask()
        opt.tell(X, two_basins(X))
    bests = {i: (opt.children[i].best_f if opt.children[i] is not None else bests[i]) for i in range(4)}
    ranked = sorted(bests, key=lambda i: (bests[i], i))
    assert sorted(opt.alive) == sorted(ranked[:2])


def test_portfolio_finds_the_narrow_basin_more_often_than_one_run():
    """Measured on 8 seeds (budget 1500, 4-D): the portfolio found the narrower basin (best < 0.5)
    in 8 of 8, a single CMA-ES run from the centre with the same population in 2 of 8 (IPOP with
    4 restarts: 5 of 8)."""
    found_p = found_c = 0
    for seed in range(8):
        p = CMAPortfolio(space(), seed=seed, runs=8, explore=0.6, budget=1500, tolfun=1e-9)
        p.run(two_basins, 1500)
        c = CMAES(space(), seed=seed, tolfun=1e-9)
        c.run(two_basins, 1500)
        found_p += p.best_f < 0.5
        found_c += c.best_f < 0.5
    assert found_p >= 7 and found_c <= 3


@pytest.mark.parametrize("mid_ask", [False, True])
def test_resume_is_exact_in_every_phase(mid_ask):
    def fn(X):  # some non-finite values too
        return np.where(X[:, 0] > 4.5, np.nan, rastrigin(X))

    kw = dict(seed=3, runs=3, explore=0.5, budget=500, max_polishes=3, tolfun=1e-8, initial=[[0.1, 0.2, 0.3, 0.4]])
    ref = CMAPortfolio(space(), **kw)
    opt = CMAPortfolio(space(), **kw)
    phases = set()
    while not ref.stopped and ref.evaluations < 20000:
        if mid_ask:
            opt.ask()
        opt = optimizer_from_state(json.loads(json.dumps(opt.state_dict(), allow_nan=False)))
        X, Y = ref.ask(), opt.ask()
        np.testing.assert_array_equal(X, Y)
        ref.tell(X, fn(X))
        opt.tell(Y, fn(Y))
        phases.add(ref.phase)
    assert phases == {"explore", "refine", "polish"} and ref.stopped and opt.stopped
    assert opt.best_f == ref.best_f and np.array_equal(opt.best_x, ref.best_x)
    assert opt.history == ref.history and opt.evaluations == ref.evaluations
    assert opt.state_dict() == ref.state_dict()


def test_initial_guess_is_the_first_candidate():
    opt = CMAPortfolio(space(), seed=0, initial=[[1.0, -2.0, 3.0, 0.5]])
    np.testing.assert_allclose(opt.ask()[0], [1.0, -2.0, 3.0, 0.5])


@pytest.mark.parametrize(
    "kw, match",
    [
        ({"runs": 0}, "runs"),
        ({"runs": 100}, "runs"),
        ({"explore": 1.5}, "explore"),
        ({"explore": "x"}, "explore"),
        ({"polish_sigma": 0}, "polish_sigma"),
        ({"budget": -1}, "budget"),
        ({"active": "yes"}, "active"),
        ({"popsize": 1}, "popsize"),
    ],
)
def test_bad_settings_are_one_line_errors(kw, match):
    with pytest.raises(ClothFitError, match=match) as e:
        CMAPortfolio(space(), seed=0, **kw)
    assert "\n" not in str(e.value)


@pytest.mark.parametrize(
    "change, match",
    [
        (lambda d: d.update(phase="nowhere"), "phase"),
        (lambda d: d.update(alive=[]), "alive"),
        (lambda d: d.update(alive=[1]), "alive"),  # a dropped run
        (lambda d: d.update(current=0), "current"),  # no pending batch
        (lambda d: d.update(children="x"), "children"),
        (lambda d: d["children"][0].update(popsize=99), "children|lam"),
        (lambda d: d.update(extra=1), "unknown"),
        (lambda d: d.update(round=7), "round"),
    ],
)
def test_corrupt_state_is_one_line_error(change, match):
    opt = CMAPortfolio(space(), seed=2, runs=2, explore=0.5, budget=200)
    while opt.phase == "explore":
        X = opt.ask()
        opt.tell(X, rastrigin(X))
    d = json.loads(json.dumps(opt.state_dict()))
    d["alive"] = [0] if opt.children[0] is not None else [1]
    change(d)
    with pytest.raises(ClothFitError, match=match) as e:
        optimizer_from_state(d)
    assert "\n" not in str(e.value)


# --------------------------------------------------------------------------- coordinate polish


def test_coordinate_polish_keeps_a_step_per_coordinate():
    """A knife edge in x0 (the value jumps past 0.2) and a flat, far optimum in x1: the edge
    coordinate's step shrinks while x1's grows and walks the distance."""
    sp = SearchSpace(["a", "b"], {"a": (0.0, 1.0), "b": (0.0, 1.0)})

    def f(X):
        X = np.atleast_2d(X)
        return np.where(X[:, 0] > 0.2, 10.0, (0.2 - X[:, 0]) + 0.01 * (X[:, 1] - 0.9) ** 2)

    p = make_optimizer("coord-polish", sp, initial=[[0.15, 0.1]], step=0.05, tolx=1e-9)
    assert type(p).__name__ == "CoordinatePolish"
    steps_b = []
    while not p.stopped and p.evaluations < 3000:
        X = p.ask()
        p.tell(X, f(X))
        steps_b.append(p.steps[1])
    assert abs(p.best_x[1] - 0.9) < 1e-3 and 0.2 - 1e-3 < p.best_x[0] <= 0.2
    assert max(steps_b) >= 0.2  # x1 took large steps while x0's shrank
    assert p.stopped and p.stop_reason == "tolx"


def test_coordinate_polish_with_f0_does_not_evaluate_its_start_and_resumes():
    sp = space(3)
    p = make_optimizer("coord-polish", sp, initial=[[1.0, 1.0, 1.0]], f0=float(rastrigin([[1.0, 1.0, 1.0]])[0]))
    assert len(p.ask()) == 6
    q = make_optimizer("coord-polish", sp, initial=[[1.0, 1.0, 1.0]])
    assert len(q.ask()) == 7  # its start is evaluated too
    for _ in range(6):
        q.tell(q.ask(), rastrigin(q.ask()))
    r = optimizer_from_state(json.loads(json.dumps(q.state_dict(), allow_nan=False)))
    for _ in range(10):
        X, Y = q.ask(), r.ask()
        np.testing.assert_array_equal(X, Y)
        q.tell(X, rastrigin(X))
        r.tell(Y, rastrigin(Y))
    assert q.state_dict() == r.state_dict()


def test_portfolio_coordinate_polish_after_refine_cut_resumes_exactly():
    kw = dict(seed=4, runs=2, explore=0.3, budget=600, refine_until=0.6, polish="coord", max_polishes=3, tolx=1e-6)
    ref = CMAPortfolio(space(), **kw)
    opt = CMAPortfolio(space(), **kw)
    phases = []
    while not ref.stopped and ref.evaluations < 20000:
        opt = optimizer_from_state(json.loads(json.dumps(opt.state_dict(), allow_nan=False)))
        X, Y = ref.ask(), opt.ask()
        np.testing.assert_array_equal(X, Y)
        if not phases or phases[-1][0] != ref.phase:
            phases.append((ref.phase, ref.evaluations))
        ref.tell(X, rastrigin(X))
        opt.tell(Y, rastrigin(Y))
    assert [p for p, _ in phases] == ["explore", "refine", "polish"]
    assert 360 <= dict(phases)["polish"] <= 360 + 2 * ref.popsize  # the refine is cut at 0.6 x budget
    assert ref.stop_reason == "polishes" and type(ref.children[-1]).__name__ == "CoordinatePolish"
    assert opt.state_dict() == ref.state_dict()
    # the polish never loses the best point: the portfolio's best is the last polish's
    assert ref.best_f == min(c.best_f for c in ref.children if c is not None)
