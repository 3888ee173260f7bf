"""A frame interval known only to a factor: the fit's time_scale stretches the frame times and the handle's
path alike, is bounded by the capture's declaration and flows through results to the replay."""

import math

import numpy as np
import pytest
from clothfit.core import defaults as D
from clothfit.core.errors import ClothFitError
from clothfit.core.fitting.evaluate import held_unknowns
from clothfit.core.fitting.objective import SilhouetteObjective
from clothfit.core.fitting.parameters import ManipulationParameters, release_instants
from clothfit.core.observation.camera import ring_rig
from clothfit.core.observation.capture import write_capture
from clothfit.core.observation.raster import silhouette
from clothfit.core.physics import jit
from clothfit.core.physics.handling import handling_scenario
from clothfit.core.physics.models import PaperModel, simulate
from clothfit.core.physics.paper import Params
from clothfit.core.physics.scenario import ClothGrid, Handle, Offsets, Uncertainty, fitted_scenario

TRUE_SCALE = 1.3


def _lift():
    """A cloth lifted by two hands (a keyed path) seen at nominal frame times."""
    sc = handling_scenario("lift", ClothGrid(7), frame_times=[0.1, 0.2, 0.3, 0.4])
    truth = Params.from_dict(D.GT_PARAMS | {"l": D.CLOTH_SIDE / 6})
    cams = ring_rig((3,), (20.0,), distance=0.5, target=(0.0, 0.0, 0.1), width=64, height=48, fx=90.0)
    return sc, truth, cams


def _observed(sc, truth, cams, scale):
    X = simulate(sc.moved(0.0, None, scale), [truth]).positions[0]
    return [[silhouette(c, X[f], sc.grid.triangles) for f in range(X.shape[0])] for c in cams]


def test_a_stretched_scenario_stretches_its_frames_and_its_handles_keys_and_releases_alike():
    sc, _, _ = _lift()
    st = sc.moved(0.01, None, 1.5)
    assert np.allclose(st.frame_times, 1.5 * sc.frame_times - 0.01)
    for h, g in zip(sc.handles, st.handles):
        assert np.allclose(g.times, 1.5 * h.times) and np.array_equal(g.positions, h.positions)
    rel = handling_scenario("release", ClothGrid(4), frame_times=[0.1]).moved(0.0, None, 2.0)
    assert [h.release_time for h in rel.handles if h.release_time is not None] == [0.0]
    same = sc.moved(0.0, None, 1.0)
    assert np.array_equal(same.frame_times, sc.frame_times) and all(
        np.array_equal(a.times, b.times) for a, b in zip(same.handles, sc.handles)
    )


@pytest.mark.parametrize("backend", ["numpy", "numba"])
def test_the_objective_scores_the_true_stretch_zero_and_the_declared_interval_worse(backend):
    if backend == "numba" and not jit.available():
        pytest.skip("numba not importable")
    sc, truth, cams = _lift()
    obj = SilhouetteObjective(sc, cams, _observed(sc, truth, cams, TRUE_SCALE), backend=backend)
    row = np.array([[truth.m, truth.k, truth.l, truth.d]] * 2)
    h = np.zeros((2, len(sc.handles), 3))
    e = obj(row, offsets=Offsets(np.zeros(2), h, np.array([TRUE_SCALE, 1.0])))
    assert e[0] == 0.0 and e[1] > 0.05


def test_the_capture_declares_the_bound_and_the_fit_searches_its_logarithm_symmetrically():
    u = Uncertainty.parse({"time_scale": 1.4}, 2)
    assert u.active and u.to_dict()["time_scale"] == 1.4
    assert "time_scale" not in Uncertainty.parse({"time_offset": 0.1}, 2).to_dict()  # as before when not declared
    sc, _, _ = _lift()
    manip = ManipulationParameters(u, sc)
    assert manip.names == ["log_time_scale"]
    lo, hi = manip.bounds["log_time_scale"]
    assert lo == pytest.approx(-math.log(1.4)) and hi == pytest.approx(math.log(1.4))
    off = manip.offsets([[math.log(1.2)], [0.0]])
    assert np.allclose(off.scale, [1.2, 1.0]) and off.stretches and not off.take([1]).stretches
    d = manip.describe([math.log(1.2)], sc)
    assert d["time_scale"] == pytest.approx(1.2)
    replay = fitted_scenario(sc, d)
    assert np.allclose(replay.frame_times, 1.2 * sc.frame_times)


@pytest.mark.parametrize(
    "value, says", [(0.8, "factor >= 1"), (3.0, "at most 2"), ("x", "not a number"), (float("nan"), "bound >= 0")]
)
def test_a_bad_time_scale_bound_is_one_line_naming_it(value, says):
    with pytest.raises(ClothFitError) as e:
        Uncertainty.parse({"time_scale": value}, 1, "capture.json: uncertain")
    assert "time_scale" in str(e.value) and says in str(e.value) and "\n" not in str(e.value)


def test_fitting_the_unknowns_of_a_capture_recovers_its_frame_interval(tmp_path):
    sc, truth, cams = _lift()
    cap = write_capture(
        tmp_path / "cap", cams, sc, _observed(sc, truth, cams, TRUE_SCALE), uncertain={"time_scale": 1.5}
    )
    obs = [[cap.load_silhouette(c, f) for f in range(cap.n_frames)] for c in range(cap.n_cameras)]
    row = np.array([truth.m, truth.k, truth.l, truth.d])
    got = held_unknowns(cap, None, row, cams, obs, [[None] * cap.n_frames] * 3, list(sc.frame_times), "auto", 80)
    assert got["time_scale"] == pytest.approx(TRUE_SCALE, rel=0.03)


def test_a_fitted_release_lands_on_the_capture_clock_through_the_stretch_and_the_offset():
    sc = handling_scenario("release", ClothGrid(4), frame_times=[0.1, 0.3])
    h = sc.handles[D.RELEASED_CORNER]
    sc.handles[D.RELEASED_CORNER] = Handle(h.vertex, h.times, h.positions, 0.2)
    (rel,) = release_instants(PaperModel(), sc, 0.01, None, 1.5)
    assert rel["model_s"] == pytest.approx(0.3)  # the declared release, stretched
    assert 1.5 * rel["capture_s"] - 0.01 == pytest.approx(rel["model_s"])  # true = scale x capture - offset
    (plain,) = release_instants(PaperModel(), sc, 0.01, None)
    assert plain["capture_s"] == pytest.approx(0.21)


def test_the_command_line_declares_a_time_scale_like_the_other_unknowns():
    u = Uncertainty.from_text("time_offset=0.02,time_scale=1.3", 1)
    assert (u.time_offset, u.time_scale) == (0.02, 1.3)
    assert Uncertainty.from_text("none", 1).time_scale == 1.0
