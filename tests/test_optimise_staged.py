"""Tests of the strong-settings-first search (addon/core/fitting/staged.py StagedCMA): its two stages,
the held coordinates, exact JSON resume in either stage, bad checkpoints, and FitJob's wiring."""

import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import json

import numpy as np
import pytest
from clothfit.core import defaults as D
from clothfit.core.errors import ClothFitError
from clothfit.core.fitting.optimise import make_optimizer, optimizer_from_state
from clothfit.core.fitting.restart_grid import near_offsets
from clothfit.core.fitting.space import SearchSpace
from clothfit.core.fitting.staged import StagedCMA


def space(n=5):
    return SearchSpace(
        [f"x{i}" for i in range(n)], {f"x{i}": (-5.0, 5.0) for i in range(n)}, {f"x{i}": False for i in range(n)}
    )


def strong_weak(X):
    """x0, x1 matter a lot (minimum at 1.5, -2), x2..x4 a little (minimum at 2)."""
    X = np.atleast_2d(X)
    return 10 * ((X[:, 0] - 1.5) ** 2 + (X[:, 1] + 2.0) ** 2) + 0.01 * np.sum((X[:, 2:] - 2.0) ** 2, axis=1)


def test_first_stage_holds_the_others_then_searches_everything():
    assert type(make_optimizer("staged", space(), seed=0)) is StagedCMA
    opt = StagedCMA(
        space(),
        seed=3,
        first=["x1", "x0"],
        hold={"x2": 0.5, "x3": -1.0},
        budget=600,
        tolfun=1e-12,
        race=1,
        scan_points=0,
    )
    assert opt.first == ["x0", "x1"]  # in the space's order
    stage1 = []
    while opt.stage == 1:
        X = opt.ask()
        assert X.shape[1] == 5
        # held: x2, x3 at the given values, x4 at the middle of its range
        assert np.allclose(X[:, 2], 0.5) and np.allclose(X[:, 3], -1.0) and np.allclose(X[:, 4], 0.0)
        stage1.append(len(X))
        opt.tell(X, strong_weak(X))
    # the first stage spends its share (one generation over at most)
    assert D.STAGED_FIRST_FRACTION * 600 <= sum(stage1) < D.STAGED_FIRST_FRACTION * 600 + 10
    assert abs(opt.best_x[0] - 1.5) < 0.01 and abs(opt.best_x[1] + 2.0) < 0.01
    # the second stage starts at the first's best point, with the small step, over all five
    c2 = opt.children[-1]
    assert c2.space.n == 5 and np.allclose(c2.mean, opt.space.encode(opt.best_x), atol=1e-9)
    moved = False
    while opt.evaluations < 3000 and not opt.stopped:
        X = opt.ask()
        moved |= bool(np.any(np.abs(X[:, 2] - 0.5) > 1e-6))
        opt.tell(X, strong_weak(X))
    assert moved and abs(opt.best_x[2] - 2.0) < 0.3


def test_a_tied_coordinate_follows_its_leader_in_the_first_stage_only():
    opt = StagedCMA(space(), seed=4, first=["x0", "x1"], tie={"x3": "x0"}, budget=200, scan_points=0)
    assert opt.tie == {"x3": "x0"}
    while opt.stage == 1:
        X = opt.ask()
        assert np.array_equal(X[:, 3], X[:, 0]) and np.ptp(X[:, 3]) > 0  # follows x0, not held
        assert np.allclose(X[:, 4], 0.0)
        opt.tell(X, strong_weak(X))
    for _ in range(5):
        X = opt.ask()
        assert not np.allclose(X[:, 3], X[:, 0])  # free in the second stage
        opt.tell(X, strong_weak(X))
    # a state without 'tie' (written before it existed) resumes with none
    d = json.loads(json.dumps(StagedCMA(space(), seed=4, first=["x0"]).state_dict()))
    del d["tie"]
    assert optimizer_from_state(d).tie == {}


def test_no_first_stage_is_plain_cma_over_everything():
    opt = StagedCMA(space(), seed=1, first=["x0"], first_fraction=0.0)
    assert opt.first == list(opt.space.names) and opt.stage == 1
    X = opt.ask()
    assert len(X) == opt.popsize and not np.allclose(X[:, 4], X[0, 4])


def flat(X):
    """Only x0, x1 matter, in steps of 0.1: once the first stage has found 0.0 nothing beats it."""
    X = np.atleast_2d(X)
    return np.round(10 * ((X[:, 0] - 1.5) ** 2 + (X[:, 1] + 2.0) ** 2), 1)


# 6 per generation over 2 coordinates: the first run converges and a second starts at the 22nd tell (132
# evaluations), the second stage at the 36th (216, the first stage's share of 300): checkpointed in the
# first run, with the batch whose tell starts the second run pending, in the second run, with the batch
# whose tell switches stages pending, and in the second stage
@pytest.mark.parametrize("warm", ["", "second", "tail"])
@pytest.mark.parametrize("cut", [7, 21, 22, 35, 36, 60])
def test_resume_is_exact_in_either_stage(cut, warm):
    def make():
        return StagedCMA(
            space(),
            seed=5,
            first=["x0", "x1"],
            hold={"x4": 1.0},
            tie={"x2": "x1"},
            budget=300,
            first_restart_step=0.005,
            first_fraction=0.72,
            first_explore=0.56,
            second_warm=warm == "second",
            warm_tail=0.2 if warm == "tail" else 0.0,  # from the 240th evaluation: the 41st tell
            warm_tail_stuck=False,
        )

    a = make()
    for _ in range(cut):
        X = a.ask()
        a.tell(X, strong_weak(X))
    X = a.ask()  # checkpointed between ask and tell
    state = json.loads(json.dumps(a.state_dict(), allow_nan=False))
    b = optimizer_from_state(state)
    assert type(b) is StagedCMA and b.stage == a.stage and b.first_runs == a.first_runs == (1 if cut < 22 else 2)
    for _ in range(25):
        Xb = b.ask() if _ else X
        assert np.array_equal(Xb, X)
        a.tell(X, strong_weak(X))
        b.tell(Xb, strong_weak(Xb))
        X = a.ask()
    assert a.best_f == b.best_f and a.evaluations == b.evaluations
    assert a.stage == b.stage == (1 if cut < 21 else 3 if warm == "tail" else 2)  # tail: the 60 cut is in it


def test_a_warm_tail_runs_from_the_best_point_with_the_first_stages_steps():
    """warm_tail: the last share of the budget a third run over everything from the best point so far,
    its first covariance as a warm second stage's; the second stage before it as by default."""
    opt = StagedCMA(
        space(),
        seed=3,
        first=["x0", "x1"],
        budget=600,
        warm_tail=0.25,
        warm_tail_stuck=False,
        second_sigma=0.05,
        first_restart_step=0.0,  # one first-stage run: this test is the tail's
    )
    assert "stage 1" in opt.phase_info()
    while opt.stage < 3:
        if opt.stage == 2:
            assert np.allclose(opt.children[-1].C[2:, 2:], np.eye(3), atol=0.5)  # the default second stage
        X = opt.ask()
        opt.tell(X, strong_weak(X))
    assert 0.75 * 600 <= opt.evaluations < 0.75 * 600 + 10 and len(opt.children) == 3
    first, tail = opt.children[0], opt.children[-1]
    assert np.allclose(tail.mean, opt.space.encode(opt.best_x[None])[0])
    assert np.allclose(tail.C[np.ix_([0, 1], [0, 1])] * tail.sigma**2, first.sigma**2 * first.C)
    assert np.allclose(tail.C[2:, 2:], np.eye(3)) and "first stage's steps" in opt.phase_info()
    b = optimizer_from_state(json.loads(json.dumps(opt.state_dict())))
    assert b.stage == 3 and len(b.children) == 3
    before = opt.best_f
    while opt.evaluations < 600 and not opt.stopped:
        X = opt.ask()
        opt.tell(X, strong_weak(X))
    assert opt.best_f < before  # the tail found better points
    with pytest.raises(ClothFitError, match="warm_tail"):
        StagedCMA(space(), first=["x0"], warm_tail=1.5)


def test_a_warm_second_stage_keeps_the_first_stages_steps_on_its_coordinates():
    """second_warm: the second stage's first covariance is the first stage's run's (sigma^2 C, in units of
    second_sigma) on the first stage's coordinates and the identity on the others, so its first samples
    vary the strong ones by the steps they converged at and the held ones by second_sigma."""

    def run(warm):
        opt = StagedCMA(space(), seed=3, first=["x0", "x1"], budget=600, second_warm=warm, second_sigma=0.05)
        while opt.stage == 1:
            first = opt.children[-1]
            X = opt.ask()
            opt.tell(X, strong_weak(X))
        return opt, first

    opt, first = run(True)
    c2 = opt.children[-1]
    S1 = first.sigma**2 * first.C
    assert np.sqrt(np.diag(S1)).max() < 0.05  # converged: steps below the second stage's
    assert np.allclose(c2.C[np.ix_([0, 1], [0, 1])] * c2.sigma**2, S1)
    assert np.allclose(c2.C[2:, 2:], np.eye(3)) and np.allclose(c2.C[:2, 2:], 0.0)
    U = opt.space.encode(opt.ask())
    spread = U.std(axis=0)
    assert spread[:2].max() < 0.2 * spread[2:].min()
    with pytest.raises(ClothFitError, match="only before the run's first generation"):
        c2.shape_start(np.eye(5))  # asked already
    from clothfit.core.fitting.evolution_strategy import CMAES

    fresh = CMAES(space(), seed=0)
    for bad, match in (
        (np.eye(4), "symmetric 5 x 5"),
        (-np.eye(5), "positive definite"),
        (np.triu(np.ones((5, 5))), "symmetric"),
    ):
        with pytest.raises(ClothFitError, match=match):
            fresh.shape_start(bad)
    plain, _ = run(False)
    assert np.allclose(plain.children[-1].C, np.eye(5))  # the default: one step for all
    # a first-stage run that has just restarted (steps as large as its sigma0) is scaled down to second_sigma
    opt = StagedCMA(space(), seed=3, first=["x0", "x1"], budget=600, second_warm=True, second_sigma=0.05)
    C = opt.children[-1].warm_covariance(opt.second_sigma, [0, 1], 5)
    assert np.isclose(np.sqrt(np.diag(C)).max(), 1.0) and np.allclose(C[2:, 2:], np.eye(3))
    # a checkpoint from before the option resumes without it
    d = json.loads(json.dumps(opt.state_dict()))
    del d["second_warm"]
    assert optimizer_from_state(d).second_warm is False


def test_a_stuck_warm_tail_runs_only_where_the_second_stage_found_nothing_better():
    """warm_tail_stuck: the tail starts only if the second stage has not beaten the first stage's best
    point by the tail's share; a second stage that improves goes on to the end as by default."""

    def run(f):
        opt = StagedCMA(
            space(), seed=3, first=["x0", "x1"], budget=600, warm_tail=0.3, warm_tail_stuck=True, first_restart_step=0.0
        )
        stages = set()
        while opt.evaluations < 600 and not opt.stopped:
            X = opt.ask()
            opt.tell(X, f(X))
            stages.add(opt.stage)
        return opt, stages

    opt, stages = run(flat)
    assert stages == {1, 2, 3} and opt.first_best_f == 0.0 and opt.best_f == 0.0
    opt, stages = run(strong_weak)
    assert stages == {1, 2} and opt.best_f < opt.first_best_f  # improved: no tail
    d = json.loads(json.dumps(opt.state_dict()))
    assert optimizer_from_state(d).first_best_f == opt.first_best_f
    del d["warm_tail_stuck"], d["first_best_f"]  # a checkpoint from before them
    b = optimizer_from_state(d)
    assert b.warm_tail_stuck is False and b.first_best_f is None


def test_a_stalled_second_stage_gives_way_to_the_tail_early():
    """warm_tail_stall: the tail starts as soon as the second stage gains less than warm_tail_stall_gain of its
    best over warm_tail_stall of the budget (before the tail's own share); a second stage that still gains goes on
    to the tail's share. The mark it measures from is checkpointed; older checkpoints have no stall rule."""

    def run(f, stall, stop_at=None):
        opt = StagedCMA(
            space(),
            seed=3,
            first=["x0", "x1"],
            budget=600,
            warm_tail=0.2,
            warm_tail_stall=stall,
            first_restart_step=0.0,
        )
        started = None
        while opt.evaluations < (stop_at or 600) and not opt.stopped:
            X = opt.ask()
            opt.tell(X, f(X))
            if started is None and opt.stage == 3:
                started = opt.evaluations
        return opt, started

    opt, started = run(flat, 0.1)  # the second stage starts at 288: stalled after 60 more
    assert 288 + 60 <= started < 288 + 60 + 20 and opt.best_f == 0.0
    _, started = run(flat, 0.0)  # no stall rule: at the tail's share (80 %)
    assert 480 <= started < 500
    # a second stage that gains keeps going: strong_weak's weak settings, held in the first stage, gain more than 1 % per 60
    _, started = run(strong_weak, 0.1)
    assert started is not None and started >= 480
    opt, _ = run(strong_weak, 0.1, stop_at=330)
    assert opt.stage == 2 and opt.stall_mark is not None
    d = json.loads(json.dumps(opt.state_dict()))
    b = optimizer_from_state(d)
    assert b.stall_mark == opt.stall_mark and (b.warm_tail_stall, b.warm_tail_stall_gain) == (0.1, 0.01)
    del d["warm_tail_stall"], d["warm_tail_stall_gain"], d["stall_mark"]  # a checkpoint from before them
    b = optimizer_from_state(d)
    assert b.warm_tail_stall == 0.0 and b.stall_mark is None


def test_a_converged_first_run_starts_again_where_the_first_began():
    """A first-stage run whose every step is below first_restart_step has settled in its basin: another
    starts at the same point with the same step and a new random stream, until the first stage's share is
    spent; the second stage starts from the best point of them all. With first_restart_step 0, one run."""
    start = np.array([1.0, -1.0, 0.0, 0.0, 0.0])
    runs_again = {"first_restart_step": 0.05, "first_fraction": 0.72, "first_explore": 0.56}
    opt = StagedCMA(space(), seed=2, first=["x0", "x1"], initial=[start], budget=1000, **runs_again)
    assert opt.first_runs == 1  # one run so far
    seeds = [opt.children[-1].seed]
    ended = []  # (best value, evaluations) of each converged run, as it converged
    while opt.stage == 1:
        runs, c = opt.first_runs, opt.children[-1]
        X = opt.ask()
        opt.tell(X, strong_weak(X))
        if opt.first_runs > runs:
            ended.append((c.best_f, c.evaluations))
        if opt.first_runs > runs and opt.stage == 1:
            c = opt.children[-1]
            assert len(opt.children) == 1 and c.evaluations == 0
            # where the first began (the initial point's x0, x1), at the first step, with a new stream
            assert np.allclose(c.space.decode(c.mean), start[:2]) and c.sigma == opt.sigma0
            assert c.seed not in seeds and f"run {opt.first_runs}" in opt.phase_info()
            seeds.append(c.seed)
    assert opt.first_runs >= 3 and len(seeds) == opt.first_runs
    assert 720 <= opt.evaluations < 720 + 10
    # past first_explore of the budget no run starts again; the best converged run went on (unless the run
    # under way then was better), to the end of the first stage
    went_on = opt.children[0]
    kept_f, kept_evals = min(ended)
    assert went_on.best_f <= kept_f and went_on.best_f == opt.best_f
    assert went_on.seed in seeds and (went_on.evaluations > kept_evals or went_on.seed == seeds[-1])
    assert opt.first_best_run is None
    assert np.allclose(opt.children[-1].mean, opt.space.encode(opt.best_x), atol=1e-9)
    one = StagedCMA(space(), seed=2, first=["x0", "x1"], initial=[start], budget=1000, first_restart_step=0.0)
    while one.stage == 1:
        X = one.ask()
        one.tell(X, strong_weak(X))
    assert one.first_runs == 1  # without runs again (the default's since: D.STAGED_FIRST_RESTART_STEP)
    # a checkpoint written before runs again existed resumes with one run
    d = json.loads(json.dumps(StagedCMA(space(), seed=4, first=["x0"]).state_dict()))
    for key in ("first_restart_step", "first_init", "first_runs", "first_explore", "first_best_run"):
        del d[key]
    old = optimizer_from_state(d)
    assert old.first_restart_step == 0.0 and old.first_runs == 1
    with pytest.raises(ClothFitError, match="first_restart_step"):
        StagedCMA(space(), first=["x0"], first_restart_step=-1.0)


def needle(X):
    """x0 a smooth bowl (minimum at 1.5); x1 a plateau with a narrow valley at 3.2 (0.6 wide), like
    Blender's bending seen in silhouettes; x2..x4 weak."""
    X = np.atleast_2d(X)
    valley = np.clip(np.abs(X[:, 1] - 3.2) / 0.3, 0.0, 1.0)
    return (X[:, 0] - 1.5) ** 2 + 5 * valley + 0.01 * np.sum((X[:, 2:] - 2.0) ** 2, axis=1)


def test_between_the_stages_each_first_coordinate_is_scanned_across_its_range():
    opt = StagedCMA(space(), seed=1, first=["x0", "x1"], budget=400, scan_points=20)
    while not opt.scanning:
        X = opt.ask()
        opt.tell(X, needle(X))
    assert opt.stage == 1 and opt.scan_left == ["x0", "x1"] and "scan of x0" in opt.phase_info()
    best = opt.best_x.copy()
    for name in ("x0", "x1"):
        j = int(name[1])
        X = opt.ask()
        assert np.array_equal(opt.ask(), X)  # asked again before its tell: the same batch
        # one coordinate at 20 values evenly across its range [-5, 5], the others at the best point
        assert X.shape == (20, 5) and np.allclose(X[:, j], -5 + 10 * (np.arange(20) + 0.5) / 20)
        others = [i for i in range(5) if i != j]
        assert np.allclose(X[:, others], opt.best_x[others])
        opt.tell(X, needle(X))
    # the scan found the needle's valley that CMA-ES steps on the plateau cannot see (x1 = 3.25 is on the
    # grid), then the second stage starts from there
    assert not opt.scanning and opt.stage == 2 and abs(opt.best_x[1] - 3.2) < 0.3
    assert opt.best_f <= needle(best)[0]
    assert np.allclose(opt.children[-1].ask().mean(axis=0)[1], 3.2, atol=0.6)
    # no scan (scan_points=0) goes straight to the second stage
    plain = StagedCMA(space(), seed=1, first=["x0", "x1"], budget=400, scan_points=0)
    while plain.stage == 1:
        X = plain.ask()
        assert not plain.scanning
        plain.tell(X, needle(X))


def test_the_first_stage_races_runs_then_the_best_goes_on_alone():
    opt = StagedCMA(space(), seed=6, first=["x0", "x1"], budget=1000, race=3, race_evals=60)
    assert opt.racing and len(opt.children) == 3 and opt.race_evals == 60
    starts = [tuple(np.round(c.ask()[0], 6)) for c in opt.children]  # each run its own first point
    assert len(set(starts)) == 3
    opt = StagedCMA(space(), seed=6, first=["x0", "x1"], budget=1000, race=3, race_evals=60)
    seen = []
    while opt.racing:
        seen.append(opt.turn)
        X = opt.ask()
        assert "race" in opt.phase_info()
        opt.tell(X, strong_weak(X))
    # the runs took turns, one generation each, and each had its 60 evaluations (one generation over)
    assert seen[:6] == [0, 1, 2, 0, 1, 2] and 180 <= opt.evaluations < 180 + 3 * 6
    assert len(opt.children) == 1 and opt.stage == 1
    # the run that goes on is the one with the best point so far
    assert opt.children[0].best_f == opt.best_f
    # the race is part of the first stage's share: a small budget shortens each run
    small = StagedCMA(space(), seed=6, first=["x0", "x1"], budget=200, race=3, race_evals=250)
    assert small.race_evals == int(D.STAGED_FIRST_FRACTION * 200) // 4
    # one run (race=1) and no first stage race no more
    assert not StagedCMA(space(), seed=6, first=["x0", "x1"], race=1).racing
    assert not StagedCMA(space(), seed=6, first=["x0"], first_fraction=0.0).racing


@pytest.mark.parametrize(
    "change, match",
    [
        (lambda d: d.update(first=["nope"]), "'first'"),
        (lambda d: d.update(stage=4), "'stage'"),
        (lambda d: d.update(stage=3), "'children'"),
        (lambda d: d.update(warm_tail=2.0), "'warm_tail'"),
        (lambda d: d.update(first_best_f="low"), "'first_best_f'"),
        (lambda d: d.update(stall_mark=[1, 2, 3]), "'stall_mark'"),
        (lambda d: d.update(warm_tail_stall=-1), "'warm_tail_stall'"),
        (lambda d: d.update(hold_u=[2.0] * 5), "'hold_u'"),
        (lambda d: d.update(children=[]), "'children'"),
        (lambda d: d.update(turn=7), "'turn'"),
        (lambda d: d.update(racing=True, stage=2), "'children'"),
        (lambda d: d.update(scan_left=["x4"]), "'scan_left'"),
        (lambda d: d.update(scan_pending=[[0.5] * 5] * 24), "'scan_pending'"),
        (lambda d: d.update(tie={"x0": "x1"}), "'tie'"),
        (lambda d: d.update(first_init=[0.5] * 3), "'first_init'"),
        (lambda d: d.update(first_runs=0), "'first_runs'"),
        (lambda d: d.update(first_best_run={"algorithm": "spx-mgg"}), "'first_best_run'"),
        (lambda d: d["children"][0].update(algorithm="spx-mgg"), "wrong algorithm"),
    ],
)
def test_corrupt_state_is_one_line_error(change, match):
    opt = StagedCMA(space(), seed=2, first=["x0", "x1"])
    X = opt.ask()
    opt.tell(X, strong_weak(X))
    d = json.loads(json.dumps(opt.state_dict()))
    change(d)
    with pytest.raises(ClothFitError, match=match):
        optimizer_from_state(d)


def test_a_held_value_outside_the_range_is_held_at_its_bound():
    """A scene's own settings may hold 0 where the search is log-scaled (a damping): held at the bound."""
    logspace = SearchSpace(["a", "b"], {"a": (0.1, 10.0), "b": (0.01, 1.0)}, {"a": True, "b": True})
    opt = StagedCMA(logspace, seed=0, first=["a"], hold={"b": 0.0})
    X = opt.ask()
    assert np.allclose(X[:, 1], 0.01)


def test_first_popsize_sets_the_first_stages_population():
    opt = StagedCMA(space(), seed=0, first=["x0", "x1"], first_popsize=6, popsize=9)
    assert len(opt.ask()) == 6 and opt.popsize == 9
    with pytest.raises(ClothFitError, match="first_popsize"):
        StagedCMA(space(), first=["x0"], first_popsize=1)


def test_bad_arguments_are_one_line_errors():
    with pytest.raises(ClothFitError, match="'first'"):
        StagedCMA(space(), first=["y"])
    with pytest.raises(ClothFitError, match="'hold'"):
        StagedCMA(space(), first=["x0"], hold={"y": 1.0})
    for tie in ({"x2": "x3"}, {"x0": "x0"}, {"y": "x0"}, ["x2"]):  # the leader must be searched, the follower held
        with pytest.raises(ClothFitError, match="'tie'"):
            StagedCMA(space(), first=["x0"], tie=tie)


def test_fitjob_searches_the_strong_settings_first(tmp_path):
    """FitJob with --optimizer cma-staged: the four strong settings first, the others at the defaults
    the fit would have fixed them at; a checkpoint resumes it."""
    from clothfit.core.fitting.job import FitConfig, FitJob
    from staged_support import small_blender_capture

    cap = small_blender_capture(tmp_path)
    ck = str(tmp_path / "fit.json.checkpoint.json")
    cfg = FitConfig(optimizer="cma-staged", max_evaluations=40, train_cameras=[0, 2, 4, 6], train_times=[0.3, 0.6])
    look = FitJob(cap, cfg)
    opt = look.opt
    assert isinstance(opt, StagedCMA)
    assert opt.first == [n for n in look.space.names if n in D.STAGED_STRONG]
    held = [n for n in look.space.names if n not in D.STAGED_STRONG]
    assert held
    X = opt.ask()
    assert opt.tie == {}  # compression following tension: tried and not kept (docs/search.md)
    for n in held:
        k = look.space.names.index(n)
        assert np.allclose(X[:, k], look.par._coord(n, look.par.fixed[n]))
    job = FitJob(cap, cfg, checkpoint=ck)
    job.run()
    assert job.evaluations >= 40 and job.best_x is not None
    # runs again (settled at 0.01 of the cube since "Shorter runs again") and the warm tail in every fit
    # (docs/search.md, "Runs again and the tail"), in main searches, not in rungs; --search reaches both
    assert (opt.first_restart_step, opt.first_fraction, opt.first_explore) == (0.01, 0.48, 0.36)
    assert (opt.warm_tail, opt.warm_tail_stuck) == (D.STAGED_WARM_TAIL, D.STAGED_WARM_TAIL_STUCK) == (0.2, False)
    rung = FitJob(cap, cfg)._rung_optimizer(look.space.decode(np.full(look.space.n, 0.5)))
    assert not isinstance(rung, StagedCMA) or (rung.warm_tail, rung.first_restart_step) == (0.0, 0.0)
    again = FitConfig(
        optimizer="auto",
        max_evaluations=40,
        train_cameras=[0, 2],
        train_times=[0.3],
        staged_restart_step=0.0,
        staged_first_fraction=0.72,
        staged_explore=0.56,
        staged_second_warm=not D.STAGED_SECOND_WARM,
        staged_warm_tail_stuck=True,
    )
    o = FitJob(cap, again).opt
    assert isinstance(o, StagedCMA) and (o.first_restart_step, o.first_fraction, o.first_explore) == (0.0, 0.72, 0.56)
    assert o.warm_tail_stuck is True
    # runs again from a grid over bending and air damping: the default's, or as --search asks
    assert opt.first_restart_grid == (list(D.FIT_RESTART_GRID) if D.FIT_RESTART_GRID_ON else None)
    for on in (True, False):
        g = FitJob(cap, FitConfig(max_evaluations=40, train_cameras=[0, 2], staged_restart_grid=on)).opt
        assert g.first_restart_grid == (list(D.FIT_RESTART_GRID) if on else None)
    with pytest.raises(ClothFitError, match="staged_restart_grid must be true or false"):
        FitConfig(staged_restart_grid="yes").checked()
    # its shape and step as --search asks: a line of 48 bendings at the run's own air damping
    line = FitConfig(
        max_evaluations=40,
        train_cameras=[0, 2],
        staged_restart_grid_rows=48,
        staged_restart_grid_columns=1,
        staged_restart_grid_sigma=0.02,
    )
    g = FitJob(cap, line).opt
    assert g.grid_points == (48, 1) and g.grid_sigma == 0.02
    assert g.first_run_cap == D.STAGED_FIRST_RUN_CAP  # the run cap: the default's, or as --search asks
    capped = FitConfig(max_evaluations=40, train_cameras=[0, 2], staged_run_cap=0.16)
    assert FitJob(cap, capped).opt.first_run_cap == 0.16
    # the grid also around the run's end in tension and shear, as --search asks; none by default
    near = FitConfig(max_evaluations=40, train_cameras=[0, 2], staged_restart_grid_near=0.01)
    assert FitJob(cap, near).opt.grid_near == {n: 0.01 for n in D.FIT_RESTART_NEAR} and opt.grid_near == {}
    at_end = FitConfig(max_evaluations=40, train_cameras=[0, 2], staged_restart_grid_at_end=True)
    assert FitJob(cap, at_end).opt.grid_at_end is True and opt.grid_at_end is False
    with pytest.raises(ClothFitError, match="staged_restart_grid_at_end must be true or false"):
        FitConfig(staged_restart_grid_at_end="yes").checked()
    end_run = FitConfig(
        max_evaluations=40, train_cameras=[0, 2], staged_restart_grid_at_end=True, staged_restart_grid_end_run=0.1
    )
    assert FitJob(cap, end_run).opt.grid_end_run == 0.1 and opt.grid_end_run == 0.0
    with pytest.raises(ClothFitError, match="staged_restart_grid_end_run"):
        FitConfig(staged_restart_grid_end_run=1.5).checked()
    assert opt.grid_points == (D.STAGED_FIRST_RESTART_GRID_POINTS,) * 2
    assert FitJob(
        cap, FitConfig(max_evaluations=40, train_cameras=[0, 2], staged_restart_grid_columns=3)
    ).opt.grid_points == (
        D.STAGED_FIRST_RESTART_GRID_POINTS,
        3,
    )
    # a shape asked for where no grid runs is refused, not ignored
    off = FitConfig(max_evaluations=40, train_cameras=[0, 2], staged_restart_grid=False, staged_restart_grid_rows=48)
    with pytest.raises(ClothFitError, match="runs no grid"):
        FitJob(cap, off)
    with pytest.raises(ClothFitError, match="runs no grid"):
        FitJob(cap, FitConfig(max_evaluations=40, staged_restart_grid=False, staged_restart_grid_near=0.01))
    for bad in (
        {"staged_restart_grid_rows": 1},
        {"staged_restart_grid_columns": 0},
        {"staged_restart_grid_sigma": 0.0},
        {"staged_run_cap": 1.5},
        {"staged_restart_grid_near": 0.3},
    ):
        with pytest.raises(ClothFitError, match=next(iter(bad))):
            FitConfig(**bad).checked()
    assert opt.second_warm is D.STAGED_SECOND_WARM and o.second_warm is not D.STAGED_SECOND_WARM
    with pytest.raises(ClothFitError, match="staged_second_warm must be true or false"):
        FitConfig(staged_second_warm=1).checked()
    with pytest.raises(ClothFitError, match="staged_restart_step is a setting of cma-staged"):
        FitConfig(optimizer="cma-es", staged_restart_step=0.005).checked()
    with pytest.raises(ClothFitError, match="staged_explore"):
        FitConfig(staged_explore=2.0).checked()
    again = FitJob.resume(ck, cap, cfg)
    assert isinstance(again.opt, StagedCMA) and again.evaluations == job.evaluations
    # the fit's default ("auto") on Blender's cloth is this search, and the result names it
    auto = FitJob(cap, FitConfig(max_evaluations=40, train_cameras=[0, 2, 4, 6], train_times=[0.3, 0.6]))
    assert isinstance(auto.opt, StagedCMA) and auto.optimizer_name == "cma-staged"
    # a capture's uncertain manipulation: its time offset is searched with the strong settings, the
    # handles' offsets wait for the second stage at the declared positions (zero offset)
    unc = FitJob(
        cap,
        FitConfig(
            optimizer="cma-staged",
            max_evaluations=40,
            train_cameras=[0, 2, 4, 6],
            train_times=[0.3, 0.6],
            uncertain="time_offset=0.02,handles=0.003",
        ),
    )
    names = list(unc.space.names)
    assert "time_offset_s" in names and any(n.startswith("handle") for n in names)
    assert unc.opt.first == [n for n in names if n in D.STAGED_STRONG] + ["time_offset_s"]
    X = unc.opt.ask()
    for k, n in enumerate(names):
        if n.startswith("handle"):
            assert np.allclose(X[:, k], 0.0)
    # only strong settings free: nothing to stage, so the default is CMA-ES
    few = FitJob(cap, FitConfig(max_evaluations=40, train_cameras=[0, 2], free=["tension_stiffness", "air_damping"]))
    assert few.optimizer_name == "cma-es"


def test_the_fit_default_is_staged_on_blenders_cloth_and_cma_es_on_the_papers():
    from clothfit.core.fitting.config import FitConfig, resolve_optimizer

    assert FitConfig().optimizer == D.FIT_OPTIMIZER == "auto"
    assert resolve_optimizer("auto", stageable=True) == D.BLENDER_OPTIMIZER == "cma-staged"
    assert resolve_optimizer("auto", stageable=False) == D.DEFAULT_OPTIMIZER == "cma-es"
    assert resolve_optimizer("CMA", stageable=True) == "cma-es"  # a named search is kept
    with pytest.raises(ClothFitError, match="unknown optimiser 'nope'"):
        FitConfig(optimizer="nope").checked()
    FitConfig(optimizer="auto", cma_active=True).checked()  # auto is a CMA-ES either way


def test_runs_again_can_start_each_at_another_level_of_one_coordinate():
    """first_restart_vary: each run after the first starts where the first began but for that coordinate,
    at first_restart_levels in turn (unit cube); the state resumes exactly; a name outside the first stage or
    levels outside [0, 1] are one-line errors; older checkpoints resume with every run where the first began."""
    start = np.array([1.0, -1.0, 0.0, 0.0, 0.0])
    kw = dict(first=["x0", "x1"], initial=[start], budget=1000, first_restart_step=0.05, first_fraction=0.72)
    opt = StagedCMA(space(), seed=2, first_explore=0.56, first_restart_vary="x1", first_restart_levels=(0.2, 0.9), **kw)
    starts = []
    while opt.stage == 1:
        runs = opt.first_runs
        X = opt.ask()
        opt.tell(X, strong_weak(X))
        if opt.first_runs > runs and opt.stage == 1:
            c = opt.children[-1]
            starts.append(c.space.encode(c.space.decode(c.mean)[None])[0])
            copy = optimizer_from_state(json.loads(json.dumps(opt.state_dict())))
            Xa, Xb = opt.ask(), copy.ask()
            assert np.array_equal(Xa, Xb)  # resumed exactly, mid-way through the runs
            opt.tell(Xa, strong_weak(Xa))
            copy.tell(Xb, strong_weak(Xb))
    assert len(starts) >= 2
    x0_where_it_began = opt._subspace().encode(start[None, :2])[0][0]
    for k, u in enumerate(starts):
        assert u[1] == pytest.approx((0.2, 0.9)[k % 2], abs=1e-12)  # x1 at the levels in turn
        assert u[0] == pytest.approx(x0_where_it_began, abs=1e-12)  # x0 where the first run began
    for bad, what in (
        (dict(first_restart_vary="x3"), "first-stage coordinate"),
        (dict(first_restart_vary="x1", first_restart_levels=(1.5,)), r"in \[0, 1\]"),
    ):
        with pytest.raises(ClothFitError, match=what):
            StagedCMA(space(), seed=2, **dict(kw, **bad))
    d = json.loads(json.dumps(StagedCMA(space(), seed=4, first=["x0"]).state_dict()))
    del d["first_restart_vary"], d["first_restart_levels"]
    assert optimizer_from_state(d).first_restart_vary is None
    d["first_restart_vary"] = "x4"
    with pytest.raises(ClothFitError, match="checkpoint"):
        optimizer_from_state(d)


def two_basins(X):
    """x0: two basins, at -2 (0.5 worse) and at 2; x1 a bowl at 1; x2..x4 weak."""
    X = np.atleast_2d(X)
    basins = np.minimum((X[:, 0] - 2.0) ** 2, (X[:, 0] + 2.0) ** 2 + 0.5)
    return basins + (X[:, 1] - 1.0) ** 2 + 0.01 * np.sum((X[:, 2:] - 2.0) ** 2, axis=1)


def test_the_search_says_how_many_of_its_starts_ended_in_the_best_ones_basin():
    """Runs again from one start land in either basin; ``looks`` counts the starts, keeps each one's best
    value, and counts those that ended in the best one's basin; a resumed search keeps them; a spoiled
    record is refused in one line."""
    runs_again = {"first_restart_step": 0.05, "first_fraction": 0.72, "first_explore": 0.56}
    start = np.array([0.0, 0.0, 0.0, 0.0, 0.0])
    seen = {}
    for seed in range(8):
        opt = StagedCMA(space(), seed=seed, first=["x0", "x1"], initial=[start], budget=1200, **runs_again)
        ends = []  # each converged run's best value and x0, x1 as it ended
        resumed = None
        while opt.stage == 1:
            runs, c = opt.first_runs, opt.children[-1]
            assert opt.looks() is None  # before the first stage has ended
            X = opt.ask()
            opt.tell(X, two_basins(X))
            if opt.first_runs > runs:
                ends.append((c.best_f, c.best_x[:2].copy()))
            if resumed is None and opt.first_runs == 2 and opt.stage == 1:  # a checkpoint between runs
                resumed = optimizer_from_state(json.loads(json.dumps(opt.state_dict())))
                assert resumed.run_ends == opt.run_ends and len(opt.run_ends) == 1
        lk = opt.looks()
        assert lk["starts"] == opt.first_runs == len(lk["ended"]) and lk["settings"] == ["x0", "x1"]
        assert sorted(lk["ended"])[0] == pytest.approx(min(f for f, _ in opt.run_ends))
        assert [f for f, _ in ends] == lk["ended"][: len(ends)]  # the converged runs, in order
        # the last run (cut by the first stage's end, or gone on past first_explore) is the last one kept
        at = [x for _, x in ends] + [-5.0 + 10.0 * np.array(opt.run_ends[-1][1])]  # x0, x1 range from -5 to 5
        best = at[int(np.argmin(lk["ended"]))]
        assert lk["agreeing"] == sum(np.all(np.abs(x - best) <= 10 * D.LOOKS_AGREE_UNIT + 1e-9) for x in at)
        assert len(at) == lk["starts"]
        seen[seed] = (lk["starts"], lk["agreeing"])
        if resumed is not None:  # the resumed search ends the same
            while resumed.stage == 1:
                X = resumed.ask()
                resumed.tell(X, two_basins(X))
            assert resumed.looks() == lk
    assert any(k < n for n, k in seen.values()) and all(n >= 2 for n, _ in seen.values())
    # no first stage (every coordinate searched at once): no starts to count
    whole = StagedCMA(space(), seed=0, budget=300)
    while whole.evaluations < 100:
        X = whole.ask()
        whole.tell(X, two_basins(X))
    assert whole.looks() is None
    # a checkpoint from before the runs' ends were kept resumes with none; a spoiled one is one line
    d = json.loads(json.dumps(opt.state_dict()))
    del d["run_ends"]
    assert optimizer_from_state(d).run_ends == []
    for bad in ([[0.1, [0.5]]], [[0.1, [0.5, 1.5]]], "x", [[0.1, [0.5, 0.5]]] * 99):
        d["run_ends"] = bad
        with pytest.raises(ClothFitError, match="run_ends"):
            optimizer_from_state(d)


def test_a_grid_of_one_column_is_a_line_through_the_run_end():
    """``first_restart_grid_points`` [rows, 1]: the first named coordinate at ``rows`` cell centres, the second held
    at the converged run's own value (not at a cell's centre); the runs after it start at the line's best cells, none
    within a basin's width (``STAGED_FIRST_RESTART_GRID_APART``) of where a run ended; the shape survives a
    checkpoint, a checkpoint with one count means the square grid it was, and a bad shape is one line."""
    kw = {"first_restart_step": 0.05, "first_fraction": 0.72, "first_explore": 0.56}
    grid = {"first_restart_grid": ["x0", "x1"], "first_restart_grid_points": [20, 1], "first_restart_grid_sigma": 0.02}
    start = np.array([-2.0, 0.0, 0.0, 0.0, 0.0])  # in the worse basin of x0
    opt = StagedCMA(space(), seed=2, first=["x0", "x1"], initial=[start], budget=1500, **kw, **grid)
    seen = None
    while opt.stage == 1:
        X = opt.ask()
        if opt.grid_pending is not None and seen is None:
            run_end = opt.space.subspace(["x0", "x1"]).decode(np.array(opt.run_ends[-1][1])[None])[0]
            assert len(X) == 20
            assert X[:, 0] == pytest.approx(-5.0 + 10.0 * (np.arange(20) + 0.5) / 20)
            assert X[:, 1] == pytest.approx(np.full(20, run_end[1]))  # the run's own x1, not a cell's centre
            assert abs(run_end[1] - round(run_end[1] * 2) / 2) > 1e-6
            resumed = optimizer_from_state(json.loads(json.dumps(opt.state_dict())))
            assert resumed.grid_points == (20, 1) and np.array_equal(resumed.ask(), X)
            seen = X
        opt.tell(X, two_basins(X))
    assert seen is not None and opt.grid_done
    # no run started within a basin's width of where another ended
    apart = D.STAGED_FIRST_RESTART_GRID_APART
    assert all(abs(s[0] - e[1][0]) > apart for s in opt.grid_starts for e in opt.run_ends)
    assert opt.best_x[0] == pytest.approx(2.0, abs=0.05)  # the better basin of x0, which its first run missed
    d = json.loads(json.dumps(opt.state_dict()))
    d["grid_points"] = 6
    assert optimizer_from_state(d).grid_points == (6, 6)
    for bad in (1, [1, 4], [8, 0], [8, 65], [8], "8x1", True):
        with pytest.raises(ClothFitError, match="first_restart_grid_points"):
            StagedCMA(
                space(), seed=0, first=["x0", "x1"], first_restart_grid=["x0", "x1"], first_restart_grid_points=bad
            )
    d["grid_points"] = [8, 0]
    with pytest.raises(ClothFitError, match="first_restart_grid_points"):
        optimizer_from_state(d)


def test_runs_again_start_at_the_best_cells_of_a_grid_over_two_coordinates():
    """With ``first_restart_grid``, the first run's end is followed by a grid over two first-stage coordinates
    (the others at that run's best point); the next run starts at the grid's best cell, the one after at the next
    cell no run has ended in, with the grid's own step; a checkpoint taken while the grid waits resumes exactly;
    a bad grid is refused in one line."""
    kw = {"first_restart_step": 0.05, "first_fraction": 0.72, "first_explore": 0.56}
    grid = {"first_restart_grid": ["x0", "x1"], "first_restart_grid_points": 6, "first_restart_grid_sigma": 0.07}
    start = np.array([-2.0, 0.0, 0.0, 0.0, 0.0])  # in the worse basin of x0
    opt = StagedCMA(space(), seed=2, first=["x0", "x1"], initial=[start], budget=1500, **kw, **grid)
    resumed, starts = None, []
    while opt.stage == 1:
        X = opt.ask()
        if opt.grid_pending is not None:
            assert len(X) == 36 and resumed is None
            # the grid's two coordinates at the cells' centres, every other where the search holds it
            centres = -5.0 + 10.0 * (np.arange(6) + 0.5) / 6
            assert np.allclose(X[:, 2:], X[0, 2:]) and X[0, 2:] == pytest.approx(0.0)
            assert X[:, 0] == pytest.approx(np.repeat(centres, 6)) and X[:, 1] == pytest.approx(np.tile(centres, 6))
            resumed = optimizer_from_state(json.loads(json.dumps(opt.state_dict())))
            assert np.array_equal(resumed.ask(), X)
            f = two_basins(X)
            best_cell = X[int(np.argmin(f)), :2]
            runs = opt.first_runs
            opt.tell(X, f)
            resumed.tell(X, f)
            c = opt.children[-1]
            assert opt.first_runs == runs and c.sigma == pytest.approx(0.07)
            starts.append((c.mean, best_cell))
            continue
        if resumed is not None:
            assert np.array_equal(resumed.ask(), X)
            resumed.tell(X, two_basins(X))
        opt.tell(X, two_basins(X))
    assert opt.grid_done and len(starts) == 1 and opt.first_runs >= 2
    mean, cell = starts[0]
    assert opt.space.subspace(["x0", "x1"]).decode(mean[None])[0] == pytest.approx(cell)
    assert cell[0] == pytest.approx(-5.0 + 10.0 * 4.5 / 6) and cell[1] == pytest.approx(-5.0 + 10.0 * 3.5 / 6)
    # the search found the better basin of x0, which its first run missed
    assert opt.run_ends[0][1][0] < 0.5 and opt.best_x[0] == pytest.approx(2.0, abs=0.05)
    assert resumed.state_dict() == opt.state_dict()
    # runs after the grid's: the next best cell no run has ended in
    assert all(
        abs(s[0] - opt.run_ends[-1][1][0]) > 1 / 6 or abs(s[1] - opt.run_ends[-1][1][1]) > 1 / 6
        for s in opt.grid_starts
    )
    for bad in (["x0"], ["x0", "x0"], ["x0", "x3"], "x0"):
        with pytest.raises(ClothFitError, match="first_restart_grid"):
            StagedCMA(space(), seed=0, first=["x0", "x1"], first_restart_grid=bad)
    d = json.loads(json.dumps(opt.state_dict()))
    d["grid_starts"] = [[0.5, 2.0]]
    with pytest.raises(ClothFitError, match="grid_starts"):
        optimizer_from_state(d)
    del d["grid_starts"], d["first_restart_grid"], d["grid_points"], d["grid_sigma"], d["grid_done"], d["grid_pending"]
    old = optimizer_from_state(d)  # a checkpoint from before the grid: none
    assert old.first_restart_grid is None and old.grid_starts == [] and old.grid_pending is None


def test_a_first_run_that_never_settles_ends_at_its_cap():
    """``first_run_cap``: a first-stage run that has had that share of the budget ends as if it had settled, so
    the grid and the runs after it happen where no run settles within the explore share (a settle step of 0 here:
    none ever settles); its end is kept like a settled run's; the cap survives a checkpoint, a checkpoint from
    before it has none, and a bad cap is one line."""
    # a first step of 0.1 keeps the first run in its start's basin
    kw = {"first_restart_step": 0.0, "first_fraction": 0.72, "first_explore": 0.56, "budget": 1500, "sigma0": 0.1}
    grid = {"first_restart_grid": ["x0", "x1"], "first_restart_grid_points": [20, 1], "first_restart_grid_sigma": 0.02}
    start = np.array([-2.0, 0.0, 0.0, 0.0, 0.0])  # in the worse basin of x0
    never = StagedCMA(space(), seed=0, first=["x0", "x1"], initial=[start], **kw, **grid)
    capped = StagedCMA(space(), seed=0, first=["x0", "x1"], initial=[start], first_run_cap=0.2, **kw, **grid)
    cut = None
    for opt in (never, capped):
        while opt.stage == 1:
            c = opt.children[-1]
            X = opt.ask()
            if opt is capped and opt.grid_pending is not None and cut is None:
                cut = c.evaluations  # the first run, as it was cut
                resumed = optimizer_from_state(json.loads(json.dumps(opt.state_dict())))
                assert resumed.first_run_cap == 0.2 and np.array_equal(resumed.ask(), X)
            opt.tell(X, two_basins(X))
    assert never.first_runs == 1 and not never.grid_done and never.best_x[0] < 0  # one look: the worse basin
    assert 0.2 * 1500 <= cut < 0.2 * 1500 + 12  # the first run ended at its cap, not before
    assert capped.grid_done and capped.first_runs >= 2 and len(capped.run_ends) >= 2
    assert capped.best_x[0] == pytest.approx(2.0, abs=0.05)  # the better basin, which the first run missed
    d = json.loads(json.dumps(StagedCMA(space(), seed=4, first=["x0"]).state_dict()))
    del d["first_run_cap"]
    assert optimizer_from_state(d).first_run_cap == 0.0
    for bad in (-0.1, 1.5, "a"):
        with pytest.raises(ClothFitError, match="first_run_cap"):
            StagedCMA(space(), first=["x0"], first_run_cap=bad)


def pulled(X):
    """A wide worse basin at x0 = -2 with x2 at 1.5, and a better one at x0 = 2 that is deep only near x2 = 1: a step
    off the worse basin's x2 (the grid's tests)."""
    X = np.atleast_2d(X)
    worse = 1.0 + 0.1 * (X[:, 0] + 2.0) ** 2 + X[:, 1] ** 2 + (X[:, 2] - 1.5) ** 2
    return np.minimum(worse, 0.5 * (X[:, 0] - 2.0) ** 2 + X[:, 1] ** 2 + 50.0 * (X[:, 2] - 1.0) ** 2)


# the line of x0 (20 cells) at the first stage's end, also a step either side in x2 (the grid-at-the-end tests)
AT_END_LINE = {
    "first_restart_grid": ["x0", "x1"],
    "first_restart_grid_points": [20, 1],
    "first_restart_grid_near": {"x2": 0.05},
    "first_restart_grid_at_end": True,
}


def test_the_line_is_also_tried_around_the_run_end():
    """``first_restart_grid_near``: the line is tried again with another first-stage coordinate moved a step either
    side of the run's end, so a better basin that only shows near the truth's value of that coordinate (here x2,
    which the worse basin has pulled off) is found; its points survive a checkpoint, a checkpoint from before it
    has none, and a bad step is one line."""

    kw = {"first_restart_step": 0.05, "first_fraction": 0.72, "first_explore": 0.56, "budget": 1500, "sigma0": 0.1}
    grid = {"first_restart_grid": ["x0", "x1"], "first_restart_grid_points": [20, 1], "first_restart_grid_sigma": 0.02}
    start = np.array([-2.0, 0.0, 1.5, 0.0, 0.0])  # in the worse basin
    first = ["x0", "x1", "x2"]
    runs = {}
    for near in (None, {"x2": 0.05}):
        opt = StagedCMA(space(), seed=0, first=first, initial=[start], first_restart_grid_near=near, **kw, **grid)
        while opt.stage == 1:
            X = opt.ask()
            if opt.grid_pending is not None:
                end = opt.space.subspace(first).decode(np.array(opt.run_ends[-1][1])[None])[0]
                assert end[0] == pytest.approx(-2.0, abs=0.2) and end[2] == pytest.approx(1.5, abs=0.1)
                assert len(X) == (20 if near is None else 60)
                # the run's own x2 first, then a step (0.05 of the cube: 0.5) below and above it
                shifts = [0.0] if near is None else [0.0, -0.5, 0.5]
                assert X[:, 2] == pytest.approx(np.repeat(end[2] + np.array(shifts), 20))
                assert X[:, 0] == pytest.approx(np.tile(-5.0 + 10.0 * (np.arange(20) + 0.5) / 20, len(shifts)))
                runs[str(near)] = X[int(np.argmin(pulled(X)))]
                resumed = optimizer_from_state(json.loads(json.dumps(opt.state_dict())))
                assert resumed.grid_near == (near or {}) and np.array_equal(resumed.ask(), X)
            opt.tell(X, pulled(X))
        # at the run's own x2 the line's best cell is in the worse basin, and so is the search's end (on this
        # seed); a step below it, the line's best cell and the search's end are in the better one
        ends = (opt.best_x[0], opt.best_x[2])
        if near is None:
            assert runs["None"][0] < 0.0 and ends == pytest.approx((-2.0, 1.5), abs=0.05)
        else:
            assert runs[str(near)][0] > 0.0 and ends == pytest.approx((2.0, 1.0), abs=0.05)
    # two named coordinates: the run's own values, then each moved by -step and by +step, one at a time
    two = near_offsets({"x2": 0.05, "x1": 0.1}, first)
    assert two.tolist() == [[0, 0, 0], [0, 0, -0.05], [0, 0, 0.05], [0, -0.1, 0], [0, 0.1, 0]]
    d = json.loads(json.dumps(opt.state_dict()))
    del d["grid_near"]
    assert optimizer_from_state(d).grid_near == {}  # a checkpoint from before it
    for bad in ({"x0": 0.05}, {"x4": 0.05}, {"x2": 0.0}, {"x2": 0.3}, {"x2": True}, ["x2"]):
        with pytest.raises(ClothFitError, match="first_restart_grid_near"):
            StagedCMA(space(), seed=0, first=first, first_restart_grid=["x0", "x1"], first_restart_grid_near=bad)
    d["grid_near"] = {"x2": -1}
    with pytest.raises(ClothFitError, match="first_restart_grid_near"):
        optimizer_from_state(d)


def test_the_grid_can_wait_for_the_first_stage_end():
    """``first_restart_grid_at_end``: no grid at the first run's end; once the first stage's share is spent, the grid
    (here the line, also a step either side in x2) through the stage's best point, and the second stage from the best
    point of all, the grid's cells among them, so a better basin that only the grid sees is where the search goes on;
    resume is exact while the grid waits, and a checkpoint from before it has the grid at the first run's end."""

    kw = {"first_restart_step": 0.0, "first_fraction": 0.5, "budget": 1500, "sigma0": 0.1}
    grid = AT_END_LINE
    first = ["x0", "x1", "x2"]
    opt = StagedCMA(space(), seed=0, first=first, initial=[np.array([-2.0, 0.0, 1.5, 0.0, 0.0])], **kw, **grid)
    seen = None
    while opt.stage == 1:
        X = opt.ask()
        if opt.grid_pending is not None:
            assert seen is None and opt.evaluations >= 0.5 * 1500 and opt.first_runs == 1
            end = opt.best_x
            assert X[:, 2] == pytest.approx(np.repeat(end[2] + np.array([0.0, -0.5, 0.5]), 20))
            assert np.allclose(X[:, 3:], end[3:])
            resumed = optimizer_from_state(json.loads(json.dumps(opt.state_dict())))
            assert resumed.grid_at_end and np.array_equal(resumed.ask(), X)
            seen = X
        opt.tell(X, pulled(X))
    assert seen is not None and opt.first_runs == 1  # no runs from the grid's cells: the second stage instead
    cell = seen[int(np.argmin(pulled(seen)))]
    assert cell[0] > 0.0 and opt.space.decode(opt.children[-1].mean[None])[0] == pytest.approx(cell)
    while not opt.stopped and opt.evaluations < 1500:
        X = opt.ask()
        opt.tell(X, pulled(X))
    assert opt.best_x[:3] == pytest.approx([2.0, 0.0, 1.0], abs=0.05)
    d = json.loads(json.dumps(opt.state_dict()))
    del d["grid_at_end"]
    assert optimizer_from_state(d).grid_at_end is False
    with pytest.raises(ClothFitError, match="first_restart_grid_at_end"):
        StagedCMA(space(), seed=0, first=first, first_restart_grid=["x0", "x1"], first_restart_grid_at_end="yes")


def test_a_run_from_the_grid_at_the_stage_end():
    """``first_restart_grid_end_run``: after the grid at the first stage's end, one more first-stage run from the best
    point of all (the grid's best cell here), for that share of the budget, counted as a start of ``looks``; then the
    second stage. Resume is exact during that run; a checkpoint from before it has none; bad values are refused."""

    kw = {"first_restart_step": 0.0, "first_fraction": 0.3, "budget": 1500, "sigma0": 0.1}
    grid = {**AT_END_LINE, "first_restart_grid_end_run": 0.1}
    first = ["x0", "x1", "x2"]
    opt = StagedCMA(space(), seed=0, first=first, initial=[np.array([-2.0, 0.0, 1.5, 0.0, 0.0])], **kw, **grid)
    cell = after_grid = None
    while opt.stage == 1:
        X = opt.ask()
        grid_now = opt.grid_pending is not None
        if opt.grid_end_until is not None and after_grid is None:
            after_grid = opt.evaluations
            # one more first-stage run, from the grid's best cell, at the grid's step, over the strong settings only
            assert opt.first_runs == 2 and len(opt.run_ends) == 1 and opt.grid_end_until == after_grid + 150
            start = opt.space.subspace(first).decode(opt.children[-1].mean[None])[0]
            assert start == pytest.approx(cell[:3]) and np.allclose(X[:, 3:], cell[3:])
            resumed = optimizer_from_state(json.loads(json.dumps(opt.state_dict())))
            assert resumed.grid_end_until == opt.grid_end_until and np.array_equal(resumed.ask(), X)
        opt.tell(X, pulled(X))
        if grid_now:
            cell = X[int(np.argmin(pulled(X)))]
            assert cell[0] > 0.0 and opt.stage == 1  # the better basin's cell; the first stage goes on
    assert after_grid is not None and opt.evaluations <= opt.grid_end_until + opt.children[0].popsize
    assert opt.evaluations >= opt.grid_end_until or opt.children[0].stopped
    looks = opt.looks()  # the first run ended in the worse basin, the run from the cell in the better one
    assert looks["starts"] == 2 and looks["agreeing"] == 1 and looks["ended"][1] < looks["ended"][0]
    # the run from the cell went on down the better basin: the second stage starts at its best point, below the cell's
    assert opt.best_f < pulled(cell)[0] and opt.best_x[0] > 0.0
    assert opt.space.decode(opt.children[-1].mean[None])[0] == pytest.approx(opt.best_x)
    while not opt.stopped and opt.evaluations < 1500:
        X = opt.ask()
        opt.tell(X, pulled(X))
    assert opt.best_x[:3] == pytest.approx([2.0, 0.0, 1.0], abs=0.02)
    d = json.loads(json.dumps(opt.state_dict()))
    del d["grid_end_run"], d["grid_end_until"]
    old = optimizer_from_state(d)  # a checkpoint from before it
    assert old.grid_end_run == 0.0 and old.grid_end_until is None
    d = json.loads(json.dumps(opt.state_dict()))
    d["grid_end_run"] = 0.0
    with pytest.raises(ClothFitError, match="grid_end_run"):
        optimizer_from_state(d)
    no_end = {k: v for k, v in grid.items() if k != "first_restart_grid_at_end"}
    for bad in ({**grid, "first_restart_grid_end_run": 1.5}, no_end):
        with pytest.raises(ClothFitError, match="first_restart_grid_end_run"):
            StagedCMA(space(), seed=0, first=first, **bad)
