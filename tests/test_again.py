"""Searching again (``fitting/again.py``): a search that ends above the floor its own jitter allows runs again from
another seed, with its budget added, up to ``searches`` in all; the best point of all is kept, the later stages start
from it, the result and the verdict say so, and a checkpoint taken in a search again resumes to the same fit."""

import numpy as np
import pytest
from clothfit.core import defaults as D
from clothfit.core.fitting import again as A
from clothfit.core.fitting.diagnose import above_jitter_floor
from clothfit.core.fitting.job import FitConfig, FitJob
from clothfit.core.observation.capture import load_capture
from clothfit.core.observation.synth import synth_capture

pytest.importorskip("numba")

TRUTH = {"tension_stiffness": 40.0, "shear_stiffness": 8.0, "bending_stiffness": 0.2, "air_damping": 2.0}
TIMES = [0.1, 0.2, 0.3, 0.4]


@pytest.fixture(scope="module")
def cap(tmp_path_factory):
    """A blender-model capture with the usual boundary noise (ring of 8 cameras, 90 x 120)."""
    path = tmp_path_factory.mktemp("again") / "noisy"
    synth_capture(str(path), TRUTH, model={"name": "blender", "fps": 24}, rig="ring8", resolution=(90, 120), noise=0.05)
    return load_capture(str(path))


def _cfg(**kw):
    cfg = dict(
        train_cameras=[0, 2, 4, 6],
        train_times=TIMES,
        free=["tension_stiffness", "bending_stiffness", "air_damping"],
        fixed={"shear_stiffness": 8.0},
        max_evaluations=240,
        seed=3,
        intervals=False,
    )
    cfg.update(kw)
    return FitConfig(**cfg)


@pytest.fixture
def above(monkeypatch):
    """Every search ends above the floor its jitter allows (whatever its error), and short fits may search
    again: the mechanism, apart from the measurement."""
    monkeypatch.setattr(D, "SEARCH_AGAIN_MIN_BUDGET", 100)
    monkeypatch.setattr(A, "above_jitter_floor", lambda job, x, f: f"above ({f:.6g})")
    monkeypatch.setattr(A, "one_basin", lambda job, ends: None)  # never two searches in one basin


def test_a_search_above_its_jitter_floor_searches_again_from_other_seeds_and_keeps_the_best(cap, above):
    job = FitJob(cap, _cfg())
    first_end = job.search_end
    r = job.run().to_json()
    searches = [s for s in r["stages"] if s["stage"] == "search"]
    assert len(searches) == D.FIT_SEARCHES == r["searches"]["count"]
    assert len(set(s["best_f"] for s in searches)) == len(searches)  # other seeds: other searches
    assert r["best_E_all"] == pytest.approx(min(s["best_f"] for s in searches))
    assert r["evaluations"] <= 240 + (D.FIT_SEARCHES - 1) * first_end + 10  # each search again adds its budget
    assert sum(s["evaluations"] for s in searches) > 1.5 * first_end
    assert len(r["searches"]["why"]) == D.FIT_SEARCHES - 1 and r["searches"]["ended"] is None
    assert f"searched {D.FIT_SEARCHES} times from different seeds" in r["verdict"]


def test_a_search_that_ends_in_an_earlier_searchs_basin_ends_the_searching(cap, monkeypatch):
    """Above its floor every time, but no ridge between the second search's best point and the first's (any
    ridge allowed here): no third search; the check's evaluations are counted, and the result says why."""
    monkeypatch.setattr(D, "SEARCH_AGAIN_MIN_BUDGET", 100)
    monkeypatch.setattr(A, "above_jitter_floor", lambda job, x, f: "above")
    monkeypatch.setattr(D, "SEARCH_AGAIN_BARRIER", 1e9)
    job = FitJob(cap, _cfg())
    r = job.run().to_json()
    assert len([s for s in r["stages"] if s["stage"] == "search"]) == 2 == r["searches"]["count"]
    assert r["searches"]["ended"].startswith("in the basin search 1 ended in (the points between their best score")
    assert "what keeps it above its floor is not the basin" in r["verdict"]
    assert len(job.state.again["ends"]) == 2


def test_one_basin_scores_the_line_between_two_ends_and_sees_a_ridge(cap, monkeypatch):
    """The points a quarter, half and three quarters of the way between two ends (in the unit cube) are scored and
    counted: within 1.25x of the worse end, one basin; above it, a ridge. (Whether real basins have such ridges is
    measured on fits, not here: lab/search_again_line.py.)"""
    job = FitJob(cap, _cfg(max_evaluations=40, searches=1))
    job.run()
    a = np.array([job.par._coord(n, TRUTH[n]) for n in job.par.free])
    b = a * np.array([1.0, 0.01, 1.0])  # bending 100x lower: halfway is 10x lower (log-scaled)
    seen = []

    def scored(ridge):
        def evaluate(X):
            seen.append(np.asarray(X))
            return np.array([1.0, ridge, 1.0])

        return evaluate

    ends = [[1.0, a.tolist()], [0.9, b.tolist()]]
    before = job.state.done_evals
    monkeypatch.setattr(job, "evaluate", scored(1.2))
    assert A.one_basin(job, ends).startswith("in the basin search 1 ended in (the points between their best score")
    assert job.state.done_evals == before + 3
    np.testing.assert_allclose(seen[0][1], a * np.array([1.0, 0.1, 1.0]), rtol=1e-9)
    monkeypatch.setattr(job, "evaluate", scored(1.3))
    assert A.one_basin(job, ends) is None
    monkeypatch.setattr(job, "evaluate", scored(np.inf))  # a point between that explodes: not one basin
    assert A.one_basin(job, ends) is None
    assert A.one_basin(job, [ends[0], []]) is None  # a search that found nothing
    assert A.one_basin(job, [[], ends[1]]) is None


def test_a_search_again_resumes_to_the_same_fit(cap, above, tmp_path):
    ref = FitJob(cap, _cfg()).run().to_json()
    ck = str(tmp_path / "ck.json")
    job = FitJob(cap, _cfg(), checkpoint=ck)
    while not job.state.again:
        job.step()
    job.step()
    job.save_checkpoint(ck)
    resumed = FitJob.resume(ck, capture=cap, config=_cfg())
    assert resumed.state.stage == "search" and resumed.state.again["searches"] == 1
    assert resumed.evaluations == job.evaluations and resumed.opt.seed == 3 + D.SEARCH_AGAIN_SEED
    r = resumed.run().to_json()
    assert r["best_E_all"] == ref["best_E_all"] and r["blender_cloth"] == ref["blender_cloth"]
    assert r["searches"] == ref["searches"]


def test_a_fit_that_searched_again_resumes_in_its_quality_ladder_and_when_finished(cap, above, tmp_path):
    """A rung's optimiser keeps the fit's seed, whatever the searches again's: a checkpoint taken in a rung, or at
    the end, resumes."""
    cfg = _cfg(quality="auto")
    ck = str(tmp_path / "ck.json")
    job = FitJob(cap, cfg, checkpoint=ck)
    while job.state.stage != "rung":
        assert job.step()
    job.step()
    job.save_checkpoint(ck)
    resumed = FitJob.resume(ck, capture=cap, config=cfg)
    assert resumed.state.stage == "rung" and resumed.state.again["searches"] == D.FIT_SEARCHES - 1
    r = resumed.run().to_json()
    assert r["searches"]["count"] == D.FIT_SEARCHES
    resumed.save_checkpoint(ck)
    assert FitJob.resume(ck, capture=cap, config=cfg).state.finished


def test_a_search_at_its_jitter_floor_a_short_fit_and_a_fit_of_one_search_search_once(cap, monkeypatch):
    monkeypatch.setattr(D, "SEARCH_AGAIN_MIN_BUDGET", 100)
    monkeypatch.setattr(A, "above_jitter_floor", lambda job, x, f: None)
    r = FitJob(cap, _cfg()).run().to_json()
    assert "searches" not in r and len([s for s in r["stages"] if s["stage"] == "search"]) == 1
    monkeypatch.setattr(A, "above_jitter_floor", lambda job, x, f: "above")
    assert "searches" not in FitJob(cap, _cfg(searches=1)).run().to_json()
    monkeypatch.setattr(D, "SEARCH_AGAIN_MIN_BUDGET", 1000)
    assert "searches" not in FitJob(cap, _cfg()).run().to_json()  # a quick look of 240 evaluations


def test_the_check_puts_the_search_beside_its_noise_floor_and_its_jitter(cap):
    """A search of a few dozen evaluations ends far above the floor of its training images and of its jitter;
    the true settings do not."""
    job = FitJob(cap, _cfg(max_evaluations=40, searches=1))
    job.run()
    f, x = job.state.best_by_quality[job.state.stage_quality]
    why = above_jitter_floor(job, np.asarray(x), f)
    assert why is not None and "x the training images' noise floor, above the" in why
    truth = np.array([job.par._coord(n, TRUTH[n]) for n in job.par.free])  # search coordinates (per unit mass)
    ft = float(job.evaluate(truth[None])[0])
    assert above_jitter_floor(job, truth, ft) is None


def test_searches_is_checked():
    with pytest.raises(Exception, match="searches must be an integer in 1..10"):
        FitConfig(searches=0).checked()
