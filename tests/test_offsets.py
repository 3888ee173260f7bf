"""The manipulation's unknowns inside the models: a population whose candidates each read the
manipulation with their own time offset and handle offsets runs, candidate by candidate, exactly as
the moved scenario (``Scenario.moved``) runs alone, in both models and both back ends."""

import numpy as np
import pytest
from clothfit.core.errors import ClothFitError
from clothfit.core.fitting.parameters import ManipulationParameters, fitted_scenario
from clothfit.core.physics import blender as B
from clothfit.core.physics.models import BlenderModel, PaperModel
from clothfit.core.physics.scenario import ClothGrid, Handle, Offsets, Scenario, Uncertainty, paper_scenario


def _scenario():
    sc = paper_scenario(ClothGrid(7, 7, 0.10), frame_times=np.arange(1, 9) / 24)
    return Scenario(sc.grid, sc.handles, sc.frame_times, 0.25, sc.gravity)


def _offsets(n, H, seed=1):
    rng = np.random.default_rng(seed)
    off = Offsets(rng.uniform(-0.03, 0.03, n), rng.uniform(-0.002, 0.002, (n, H, 3)))
    off.time[0] = 0.0
    off.handles[0] = 0.0
    return off


def test_moved_scenario_shifts_frames_and_handles():
    sc = _scenario()
    h = np.zeros((len(sc.handles), 3))
    h[1] = [0.001, -0.002, 0.003]
    m = sc.moved(0.01, h)
    np.testing.assert_allclose(m.frame_times, sc.frame_times - 0.01)
    np.testing.assert_allclose(
        np.asarray(m.handles[1].positions) - np.asarray(sc.handles[1].positions),
        [[0.001, -0.002, 0.003]] * len(sc.handles[1].positions),
    )
    assert m.handles[0].release_time == sc.handles[0].release_time
    early = sc.moved(-10.0)  # before the settle's start: read at its start
    assert early.frame_times.min() >= -sc.settle_time - 1e-12


def test_blender_kernel_with_offsets_is_the_moved_scenario_exactly():
    sc = _scenario()
    n = 4
    off = _offsets(n, len(sc.handles))
    m = BlenderModel(24, 3)
    rows = np.repeat(B.settings_row(dict(B.DEFAULTS, time_scale=B.physical_time_scale(24)))[None], n, 0)
    a = m.simulate(sc, rows, "numba", offsets=off)
    assert np.array_equal(a.positions[0], m.simulate(sc, rows[:1], "numba").positions[0])
    for p in range(1, n):
        ref = m.simulate(sc.moved(off.time[p], off.handles[p]), rows[p : p + 1], "numba")
        assert np.array_equal(a.positions[p], ref.positions[0]), p
    r = m.simulate(sc, rows[1:3], "numpy", offsets=off.take([1, 2]))
    assert np.abs(r.positions - a.positions[1:3]).mean() < 1e-4  # float64 reference against float32 (measured 1.6e-5 m)


def test_spans_ending_within_one_frame_share_one_set_up_and_give_the_same_motion():
    sc = _scenario()
    m = BlenderModel(24, 3)
    rows = np.repeat(B.settings_row(dict(B.DEFAULTS, time_scale=B.physical_time_scale(24)))[None], 2, 0)
    ends = []
    for t in (0.011, 0.013, 0.029, 0.045):  # the last frame (8/24 s) read up to 11-29 ms later: the next frame
        off = Offsets(np.array([0.0, -t]), np.zeros((2, len(sc.handles), 3)))
        a = m.simulate(sc, rows, "numba", offsets=off)
        ref = m.simulate(sc.moved(-t), rows[1:], "numba")
        assert np.array_equal(a.positions[1], ref.positions[0]), t
        ends.append(m.spanning(sc, t).frame_times[-1])
    assert ends[0] == ends[1] == ends[2] == 9 / 24 and ends[3] == 10 / 24
    assert m.spanning(sc, 0.011) is m.spanning(sc, 0.017)  # one extended scenario, one kernel set-up
    assert len(m._spans) == 2


def test_paper_model_with_offsets_is_the_moved_scenario():
    sc = _scenario()
    n = 4
    off = _offsets(n, len(sc.handles), seed=2)
    pm = PaperModel()
    P = np.repeat(np.array([[1e-5, 10.0, 0.0125, 1e-4]]), n, 0)
    a = pm.simulate(sc, P, "numba", offsets=off)
    b = pm.simulate(sc, P, "numpy", offsets=off)
    assert np.abs(a.positions - b.positions).max() < 1e-7  # measured 3.9e-9 m
    for p in range(n):
        one = pm.simulate(sc.moved(off.time[p], off.handles[p]), P[:1], "numba")
        assert np.array_equal(one.positions[0], a.positions[p]), p


def test_manipulation_parameters_coordinates_and_the_fitted_scenario():
    sc = _scenario()
    mp = ManipulationParameters(Uncertainty.parse({"time_offset": 0.05, "handles": [0.005, 0, 0.002, 0]}, 4), sc)
    assert mp.names == ["time_offset_s", "handle0_x", "handle0_y", "handle0_z", "handle2_x", "handle2_y", "handle2_z"]
    assert mp.bounds["handle2_z"] == (-0.002, 0.002)
    m = np.array([0.012, 0.001, 0.0, -0.003, 0.0, 0.0, 0.0015])
    off = mp.offsets(m)
    assert off.time[0] == 0.012 and off.handles[0, 0].tolist() == [0.001, 0.0, -0.003]
    assert not off.handles[0, 1].any() and off.handles[0, 2, 2] == 0.0015
    d = mp.describe(m, sc, spread=np.full(7, 1e-4))
    assert d["time_offset_s"] == 0.012 and d["time_offset_uncertainty_s"] == 1e-4
    assert d["handles"][1].get("offset_uncertainty_m") is None and d["handles"][0]["offset_bound_m"] == 0.005
    back = fitted_scenario(sc, d)
    ref = sc.moved(0.012, off.handles[0])
    np.testing.assert_allclose(back.frame_times, ref.frame_times)
    for h, r in zip(back.handles, ref.handles):
        np.testing.assert_allclose(h.positions, r.positions)
    assert fitted_scenario(sc, {}) is sc
    # at the edge of the bound: |value| >= 95 % of it (either sign)
    edge = np.array([-0.049, 0.001, 0.0, -0.0048, 0.0, 0.0, 0.0019])
    assert mp.at_bound(edge) == ["time_offset_s", "handle0_z", "handle2_z"]
    assert mp.at_bound(m) == [] and mp.at_bound(edge, share=0.99) == []
    bad = dict(d, handles=d["handles"][:2])
    with pytest.raises(ClothFitError, match="2 fitted handles for a scenario with 4"):
        fitted_scenario(sc, bad)


def _released_at(sc, t_release):
    hs = [Handle(h.vertex, h.times, h.positions, t_release if h.release_time is not None else None) for h in sc.handles]
    return Scenario(sc.grid, hs, sc.frame_times, sc.settle_time, sc.gravity)


def test_blender_release_instant_is_where_the_cloth_starts_to_fall():
    """Blender's cloth pins per frame: every declared release inside a frame interval falls as one
    declared at the interval's start (``release_instant``), and one declared just before that start
    falls a frame earlier: the simulation, not the formula, is the truth here."""
    sc = _scenario()
    model = BlenderModel(24.0, 2)
    row = B.settings_row(dict(B.DEFAULTS, time_scale=B.physical_time_scale(24.0)))[None]
    fall = {}
    for tr in (2.3 / 24, 2.0 / 24, 2.97 / 24, 1.98 / 24):
        fall[tr] = model.simulate(_released_at(sc, tr), row).positions[0]
        assert model.release_instant(tr) == pytest.approx(2.0 / 24 if tr >= 2.0 / 24 else 1.0 / 24)
    np.testing.assert_array_equal(fall[2.3 / 24], fall[2.0 / 24])
    np.testing.assert_array_equal(fall[2.97 / 24], fall[2.0 / 24])
    assert np.abs(fall[1.98 / 24] - fall[2.0 / 24]).max() > 1e-4
    assert model.release_instant(-0.01) == pytest.approx(-1.0 / 24)  # released while settling: the step into t = 0
    assert PaperModel().release_instant(2.3 / 24) == 2.3 / 24


def test_release_instants_put_the_models_release_on_the_capture_clock():
    from clothfit.core.fitting.parameters import release_instants

    sc = _released_at(_scenario(), 0.1)
    (r,) = release_instants(BlenderModel(30.0, 5), sc, 0.02, 0.004)
    assert r["declared_s"] == 0.1 and r["model_s"] == pytest.approx(3 / 30) and r["capture_s"] == pytest.approx(0.12)
    assert r["uncertainty_s"] == 0.004 and r["vertex"] == sc.handles[r["handle"]].vertex
    assert release_instants(BlenderModel(30.0, 5), sc, None, None) == []
    assert release_instants(object(), sc, 0.02, None) == []  # a model that does not say when it lets go
    assert release_instants(PaperModel(), sc, -0.01, None)[0]["capture_s"] == pytest.approx(0.09)
