"""Tests of the line at the first stage's end scored on the first training frames (``StagedCMA``'s
``first_restart_grid_frames``, ``fit --search staged_restart_grid_frames=K``): its cells are scored on the first K
frames, the best of them again on every frame; the first frames' values never become the search's; it is counted at
its cost; resume is exact; older checkpoints have none; FitJob scores the batch on the first frames it asks for."""

import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import json
import math

import numpy as np
import pytest
from clothfit.core import defaults as D
from clothfit.core.errors import ClothFitError
from clothfit.core.fitting.optimise import optimizer_from_state
from clothfit.core.fitting.space import SearchSpace
from clothfit.core.fitting.staged import StagedCMA

FIRST = ["x0", "x1", "x2"]
# the line of x0 (20 cells) at the first stage's end, also a step either side in x2, on the first 5 frames
WINDOW_LINE = {
    "first_restart_grid": ["x0", "x1"],
    "first_restart_grid_points": [20, 1],
    "first_restart_grid_near": {"x2": 0.05},
    "first_restart_grid_at_end": True,
    "first_restart_grid_frames": 5,
    "first_restart_grid_window_share": 0.4,
}


def space(n=5):
    return SearchSpace(
        [f"x{i}" for i in range(n)], {f"x{i}": (-5.0, 5.0) for i in range(n)}, {f"x{i}": False for i in range(n)}
    )


def pulled(X):
    """A wide worse basin at x0 = -2 with x2 at 1.5, and a better one at x0 = 2 that is deep only near x2 = 1."""
    X = np.atleast_2d(X)
    worse = 1.0 + 0.1 * (X[:, 0] + 2.0) ** 2 + X[:, 1] ** 2 + (X[:, 2] - 1.5) ** 2
    return np.minimum(worse, 0.5 * (X[:, 0] - 2.0) ** 2 + X[:, 1] ** 2 + 50.0 * (X[:, 2] - 1.0) ** 2)


def early(X):
    """The first frames' values: the same valleys on another scale (far below any value on every frame), and
    blind to x2 (the first frames do not see it)."""
    X = np.atleast_2d(X)
    return 0.01 * np.minimum(1.0 + 0.1 * (X[:, 0] + 2.0) ** 2, 0.5 * (X[:, 0] - 2.0) ** 2) - 100.0


def roundtrip(opt):
    return optimizer_from_state(json.loads(json.dumps(opt.state_dict())))


def test_the_line_on_the_first_frames_then_its_best_cells_on_every_frame():
    kw = {"first_restart_step": 0.0, "first_fraction": 0.3, "budget": 1500, "sigma0": 0.1}
    opt = StagedCMA(space(), seed=0, first=FIRST, initial=[np.array([-2.0, 0.0, 1.5, 0.0, 0.0])], **kw, **WINDOW_LINE)
    assert opt.window is None
    seen = []
    while opt.stage == 1:
        X = opt.ask()
        if opt.window is None:
            opt.tell(X, pulled(X))
            continue
        # the line: 20 cells at the run's x2 and a step either side, asked for on the first 5 frames
        assert opt.window == 5 and len(X) == 60 and not seen
        resumed = roundtrip(opt)
        assert resumed.window == 5 and np.array_equal(resumed.ask(), X)
        evals, best = opt.evaluations, opt.best_f
        opt.tell(X, early(X))
        # counted at their cost (0.4 of an evaluation on every frame each), never the search's values
        assert opt.evaluations == evals + math.ceil(60 * 0.4) and opt.best_f == best > 0.0
        assert opt.window is None and opt.stage == 1
        R = opt.ask()
        n = D.STAGED_FIRST_RESTART_GRID_RESCORE
        assert np.allclose(R, X[np.argsort(early(X), kind="stable")[:n]])  # the best cells, best first
        assert np.all(R[:, 0] > 0.0)  # in the better basin, at the x2 steps the first frames cannot tell apart
        assert np.array_equal(roundtrip(opt).ask(), R)
        opt.tell(R, pulled(R))
        assert opt.evaluations == evals + math.ceil(60 * 0.4) + n
        assert opt.best_f == min(best, pulled(R).min())
        seen.append(R)
    assert seen and opt.stage == 2
    # the second stage starts from the best point of all: a cell of the better basin, scored on every frame
    assert opt.best_x[0] > 0.0
    assert opt.space.decode(opt.children[-1].mean[None])[0] == pytest.approx(opt.best_x)
    while not opt.stopped and opt.evaluations < 1500:
        X = opt.ask()
        assert opt.window is None
        opt.tell(X, pulled(X))
    assert opt.best_x[:3] == pytest.approx([2.0, 0.0, 1.0], abs=0.02)


def test_a_line_whose_first_frames_all_explode_ends_the_stage():
    kw = {"first_restart_step": 0.0, "first_fraction": 0.3, "budget": 600, "sigma0": 0.1}
    opt = StagedCMA(space(), seed=1, first=FIRST, **kw, **WINDOW_LINE)
    while opt.stage == 1:
        X = opt.ask()
        windowed = opt.window is not None
        opt.tell(X, np.full(len(X), np.inf) if windowed else pulled(X))
        if windowed:
            assert opt.grid_pending is None and opt.stage == 2  # nothing to score again: the second stage
    assert opt.grid_done


def test_cells_that_explode_on_the_first_frames_are_not_scored_again():
    kw = {"first_restart_step": 0.0, "first_fraction": 0.3, "budget": 600, "sigma0": 0.1}
    opt = StagedCMA(space(), seed=2, first=FIRST, **kw, **WINDOW_LINE)
    while opt.window is None:
        X = opt.ask()
        opt.tell(X, pulled(X))
    X = opt.ask()
    f = early(X)
    f[np.argsort(f, kind="stable")[2:]] = np.inf  # all but the two best explode
    opt.tell(X, f)
    R = opt.ask()
    assert len(R) == 2 and np.allclose(R, X[np.argsort(early(X), kind="stable")[:2]])
    resumed = roundtrip(opt)  # a checkpoint holding the two cells left
    assert np.array_equal(resumed.ask(), R)
    d = json.loads(json.dumps(opt.state_dict()))
    d["grid_pending"] = []
    with pytest.raises(ClothFitError, match="grid_pending"):
        optimizer_from_state(d)


def test_older_checkpoints_and_bad_values():
    opt = StagedCMA(space(), seed=0, first=FIRST, **WINDOW_LINE)
    d = json.loads(json.dumps(opt.state_dict()))
    assert (d["grid_frames"], d["grid_window_share"], d["grid_windowed"]) == (5, 0.4, False)
    for k in ("grid_frames", "grid_window_share", "grid_windowed"):
        del d[k]
    old = optimizer_from_state(d)  # a checkpoint from before the window: every frame
    assert (old.grid_frames, old.grid_window_share, old.grid_windowed, old.window) == (0, 1.0, False, None)
    d = json.loads(json.dumps(opt.state_dict()))
    d["grid_windowed"] = True  # nothing waits to be scored
    with pytest.raises(ClothFitError, match="grid_windowed"):
        optimizer_from_state(d)
    not_at_end = {k: v for k, v in WINDOW_LINE.items() if k != "first_restart_grid_at_end"}
    for bad, match in (
        (not_at_end, "needs the grid at the first stage's end"),
        ({**WINDOW_LINE, "first_restart_grid_frames": -1}, "first_restart_grid_frames"),
        ({**WINDOW_LINE, "first_restart_grid_window_share": 0.0}, "first_restart_grid_window_share"),
        ({**WINDOW_LINE, "first_restart_grid_window_share": 1.5}, "first_restart_grid_window_share"),
    ):
        with pytest.raises(ClothFitError, match=match):
            StagedCMA(space(), seed=0, first=FIRST, **bad)


def test_fitjob_scores_the_line_on_the_first_frames(tmp_path):
    """FitJob with --search staged_restart_grid_frames=2: the line's batch is scored on the first two training frames
    (the same values a job trained on those frames alone gives), counted at their share of the simulation."""
    from clothfit.core.fitting.job import FitConfig, FitJob
    from clothfit.core.fitting.takes import window_objective
    from staged_support import small_blender_capture

    cap = small_blender_capture(tmp_path)
    times = [0.1, 0.2, 0.3, 0.4]
    common = {"max_evaluations": 60, "train_cameras": [0, 2], "optimizer": "cma-staged", "seed": 3}
    line = {"staged_restart_grid_rows": 8, "staged_restart_grid_columns": 1, "staged_restart_grid_at_end": True}
    cfg = FitConfig(train_times=times, staged_restart_grid_frames=2, **common, **line)
    job = FitJob(cap, cfg)
    settle = cap.scenario.settle_time
    share = max(2 / 4, (0.2 + settle) / (0.4 + settle))
    assert job.opt.grid_frames == 2 and job.opt.grid_window_share == pytest.approx(share)
    with pytest.raises(ClothFitError, match="staged_restart_grid_frames"):
        FitConfig(staged_restart_grid_frames=-2).checked()
    while job.opt.window is None:
        assert job.step()
    X = job.opt.ask()
    evals = job.evaluations
    expect = FitJob(cap, FitConfig(train_times=times[:2], **common, **line)).evaluate(X)
    assert np.array_equal(job.evaluate(X, window_objective(job, 2)), expect)
    assert np.all(job.evaluate(X) > expect)  # every frame's values are not the first two's
    job.step()
    assert job.evaluations == evals + math.ceil(len(X) * share)
    cells = job.opt.ask()
    assert np.allclose(cells, X[np.argsort(expect, kind="stable")[: len(cells)]])
    job.run()
    assert job.best_x is not None and job.evaluations >= 60
