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


def _resumed_in(stage, cap, cfg, tmp_path):
    """A fit stepped into ``stage`` and one step on, its checkpoint saved there and resumed: (the resumed job, the
    checkpoint's path)."""
    ck = str(tmp_path / "ck.json")
    job = FitJob(cap, cfg, checkpoint=ck)
    while job.state.stage != stage:
        assert job.step()
    job.step()
    job.save_checkpoint(ck)
    return FitJob.resume(ck, capture=cap, config=cfg), ck


@pytest.fixture
def above(monkeypatch):
    """Every search ends above the floor its jitter allows (whatever its error), and short fits may search
    again: the mechanism, apart from the measurement."""
    monkeypatch.setattr(D, "SEARCH_AGAIN_MIN_BUDGET", 100)
    monkeypatch.setattr(A, "above_jitter_floor", lambda job, x, f: f"above ({f:.6g})")


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
    at = r["searches"]["ended_at"]  # where each search ended, in the result's units
    assert len(at) == D.FIT_SEARCHES and set(at[0]) == {"tension_stiffness", "bending_stiffness", "air_damping"}
    assert len({a["bending_stiffness"] for a in at}) == D.FIT_SEARCHES  # other seeds, other ends


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


def test_a_fit_that_searched_again_resumes_in_its_quality_ladder_and_when_finished(cap, above, tmp_path, monkeypatch):
    """A rung's optimiser keeps the fit's seed, whatever the searches again's: a checkpoint taken in a rung, or at
    the end, resumes."""
    monkeypatch.setattr(A, "searches_allowed", lambda job: D.FIT_SEARCHES)  # (a fit with a ladder searches once)
    cfg = _cfg(quality="auto")
    resumed, ck = _resumed_in("rung", cap, cfg, tmp_path)
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
    r = FitJob(cap, _cfg(quality="auto")).run().to_json()  # the quality still to be chosen
    assert "searches" not in r and len([s for s in r["stages"] if s["stage"] == "search"]) == 1
    assert len([s for s in r["stages"] if s["stage"] == "rung"]) >= 1
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


def test_the_training_floor_and_its_jitter_are_measured_once_per_point(cap, monkeypatch):
    """The check for searching again and the report at the end measure the same thing where the point is the same:
    measured once (deterministic, so the figures are the same either way)."""
    from clothfit.core.fitting import diagnose

    job = FitJob(cap, _cfg(max_evaluations=40, searches=1))
    job.run()
    f, x = job.state.best_by_quality[job.state.stage_quality]
    calls = []
    real = diagnose.jitter
    monkeypatch.setattr(diagnose, "jitter", lambda *a: calls.append(1) or real(*a))
    x1, x2 = np.asarray(x) * (1 + 1e-3), np.asarray(x) * (1 - 1e-3)
    first = above_jitter_floor(job, x1, f)
    assert above_jitter_floor(job, x1, f) == first and len(calls) == 1
    above_jitter_floor(job, x2, f)
    assert len(calls) == 2
    job.floor_cache = {}
    assert above_jitter_floor(job, x1, f) == first and len(calls) == 3  # measured again: the same figures


def test_searches_is_checked():
    with pytest.raises(Exception, match="searches must be an integer in 1..10"):
        FitConfig(searches=0).checked()


def test_a_fit_that_searched_again_resumes_in_its_intervals(cap, above, tmp_path, monkeypatch):
    """After searches alone (no rung), the intervals keep the last search's optimiser, whose seed is a search
    again's: a checkpoint taken while the intervals are measured resumes to the same fit (it was refused as a rung's
    optimiser of another seed)."""
    monkeypatch.setattr(D, "INTERVAL_BUDGET_FACTOR", 0)  # (a short fit may measure its intervals)
    cfg = _cfg(intervals=True)
    ref = FitJob(cap, cfg).run().to_json()
    resumed, _ = _resumed_in("intervals", cap, cfg, tmp_path)
    assert resumed.state.stage == "intervals" and resumed.state.again["searches"] == D.FIT_SEARCHES - 1
    r = resumed.run().to_json()
    assert r["best_E_all"] == ref["best_E_all"] and r["intervals"] == ref["intervals"]
