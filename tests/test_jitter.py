"""The floor a take's chaos allows, measured at the fit (``fitting/jitter.py``): the neighbours it is measured on,
a measurement that reads 0 where nothing moves, and the report and verdict that put a fit beside it."""

import numpy as np
import pytest
from clothfit.core import defaults as D
from clothfit.core.fitting import diagnose
from clothfit.core.fitting.jitter import allowed, floor_with_jitter, jitter
from clothfit.core.fitting.job import FitConfig, FitJob
from clothfit.core.fitting.space import SearchSpace
from clothfit.core.fitting.verdict import verdict
from clothfit.core.observation.capture import load_capture
from clothfit.core.observation.synth import synth_capture

TIMES = [0.1, 0.2, 0.3, 0.4]


def test_neighbours_move_each_setting_by_a_part_of_its_size_or_range_and_keep_the_rest():
    sp = SearchSpace(["a", "b"], {"a": (1.0, 100.0), "b": (0.0, 2.0)}, {"a": True, "b": False})
    x = np.array([10.0, 2.0, 0.123])  # b at its upper bound; a third value (an offset) after the settings
    X = sp.neighbours(x, 6, 1e-3, seed=3)
    assert X.shape == (6, 3)
    assert np.allclose(np.abs(X[:, 0] - 10.0), 1e-2)  # log-scaled: a part of its value
    assert set(np.round(X[:, 1], 6)) <= {2.0, round(2.0 - 2e-3, 6)}  # linear: a part of its range, clipped
    assert np.all(X[:, 2] == 0.123)
    assert np.array_equal(X, sp.neighbours(x, 6, 1e-3, seed=3))  # reproducible
    assert not np.array_equal(X, sp.neighbours(x, 6, 1e-3, seed=4))


def test_the_floor_allowed_is_the_noise_floor_plus_the_jitter_at_its_quantile():
    jit = {"samples": 5, "relative": 1e-7, "pct": [0.0, 0.1, 0.2, 0.3, 0.4]}
    q = floor_with_jitter(1.0, jit)
    assert q["p50"] == pytest.approx(1.2) and q["p10"] < q["p50"] < q["p90"] <= 1.4
    assert allowed(1.0, jit) == pytest.approx(1.0 + np.quantile(jit["pct"], D.JITTER_QUANTILE))
    assert floor_with_jitter(1.0, None) is None and allowed(1.0, None) is None


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """A short fit of the paper scenario with the usual boundary noise (ring of 8 cameras, 240 x 320)."""
    path = tmp_path_factory.mktemp("jitter") / "noisy"
    synth_capture(str(path), rig="ring8", resolution=(240, 320), noise=D.NOISE_FRACTION)
    job = FitJob(
        load_capture(str(path)), FitConfig(train_cameras=[0, 2, 4, 6], train_times=TIMES, max_evaluations=40, seed=0)
    )
    job.run()
    return job


def test_the_fits_own_point_measures_no_jitter_and_its_neighbours_measure_a_little(fitted, monkeypatch):
    """The neighbours are scored by the fitting kernels against silhouettes drawn by the floor's rasteriser:
    at the fit's own point the two must agree to the pixel, or the jitter would carry their difference."""
    x, obj = fitted.best_x, fitted.objective
    sils = diagnose._model_silhouettes(fitted, x, obj)
    monkeypatch.setattr(D, "JITTER_RELATIVE", 0.0)
    same = jitter(fitted, x, obj, sils)
    assert same["samples"] == D.JITTER_SAMPLES and max(same["pct"]) < 1e-9
    monkeypatch.undo()
    near = jitter(fitted, x, obj, sils)
    assert near["relative"] == D.JITTER_RELATIVE and len(near["pct"]) == D.JITTER_SAMPLES
    assert 0.0 <= min(near["pct"]) and max(near["pct"]) < 1.0  # the paper's sheet here is not chaotic
    assert jitter(fitted, x, obj, None) is None  # no silhouettes (a scene evaluator's fit): nothing measured


def test_the_result_states_the_jitter_floor_beside_the_noise_floor(fitted):
    fl = fitted.result()["floor"]
    for side in ("train", "heldout"):
        q = fl[f"{side}_jitter_floor_pct"]
        assert fl[f"{side}_floor_pct"] <= q["p10"] <= q["p50"] <= q["p90"]
        assert fl[f"{side}_allowed_ratio"] >= 1.0
    assert fl["jitter_samples"] == D.JITTER_SAMPLES and fl["jitter_relative"] == D.JITTER_RELATIVE


def _report_with_jitter(job, monkeypatch, pct):
    """``diagnose.report`` of ``job`` as if the neighbours of its fit differed from it by ``pct`` % per image."""
    monkeypatch.setattr(
        diagnose, "jitter", lambda *a: {"samples": 3, "relative": D.JITTER_RELATIVE, "pct": [pct, pct, pct]}
    )
    job.floor_cache = {}  # the fit's own measurement at this point is kept (deterministic): replaced here
    return diagnose.report(job)


def test_a_fit_far_above_its_noise_floor_is_at_the_floor_its_chaos_allows_or_not(fitted, monkeypatch):
    """A fit 40 evaluations long ends far above its noise floor; were its neighbours' silhouettes as far from its
    own as its error is from the images, no search could tell it from the cloth's settings: it is at the jitter
    floor, said with its figures. With a small jitter it stays far above, the jitter's figures beside the cause."""
    fl = diagnose.report(fitted)
    worst = max(fl["train_ratio"], fl["heldout_ratio"])
    assert fl["far_above"] and worst > D.FLOOR_FAR_ABOVE and not fl["at_jitter_floor"]
    big = worst * max(fl["train_floor_pct"], fl["heldout_floor_pct"])  # F + J above either error
    fl = _report_with_jitter(fitted, monkeypatch, big)
    assert not fl["far_above"] and fl["at_jitter_floor"] and fl["likely_cause"] is None
    kind, line = verdict({"floor": fl})
    assert kind == "at_floor" and line.startswith("at the jitter floor (training ")
    assert "the floor this take's chaos allows" in line and "held-out, median" in line
    fl = _report_with_jitter(fitted, monkeypatch, 0.01 * fl["heldout_floor_pct"])
    assert fl["far_above"] and not fl["at_jitter_floor"] and "the floor this take's chaos allows" in fl["warning"]
    kind, line = verdict({"floor": fl})
    assert kind == "far_above" and "the floor this take's chaos allows" in line


def test_a_fit_within_twice_its_noise_floor_is_at_the_floor_whatever_the_jitter(fitted, monkeypatch):
    fl = dict(diagnose.report(fitted))
    fl.update(train_ratio=1.5, heldout_ratio=1.5, far_above=False, at_jitter_floor=False)
    kind, line = verdict({"floor": fl})
    assert kind == "at_floor" and line.startswith("at the floor (") and "jitter" not in line
