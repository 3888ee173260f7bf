"""Handles that move along paths: the named handlings (``core.physics.handling``, ``synth --handling``),
both cloth models following a keyed handle and letting it go, and the fit's manipulation offsets
moving a path (a handle offset the whole path, a time offset its keys and release together)."""

import filecmp
import json
import os

import numpy as np
import pytest
from clothfit import cli
from clothfit.core import defaults as D
from clothfit.core.errors import ClothFitError
from clothfit.core.fitting.parameters import ManipulationParameters, fitted_scenario
from clothfit.core.observation import camera as C
from clothfit.core.observation.capture import load_capture
from clothfit.core.observation.synth import synth_capture
from clothfit.core.physics import blender as B
from clothfit.core.physics.handling import handling_scenario, moving_handles, two_hands
from clothfit.core.physics.models import BlenderModel, PaperModel
from clothfit.core.physics.scenario import ClothGrid, Handle, Offsets, Scenario, Uncertainty, paper_scenario

FPS = 24.0


def _files(root):
    return sorted(os.path.relpath(os.path.join(d, f), root) for d, _, fs in os.walk(root) for f in fs)


def test_release_handling_is_the_papers_scenario():
    assert handling_scenario().to_dict() == paper_scenario().to_dict()
    assert handling_scenario("release", released_corner=2).to_dict() == paper_scenario(released_corner=2).to_dict()
    assert moving_handles(handling_scenario("release")) == []


def test_synth_by_default_and_with_release_writes_the_capture_it_always_wrote(tmp_path, capsys):
    """``synth`` without ``--handling`` and with ``--handling release`` write, byte for byte, the capture
    the paper's scenario given explicitly writes."""
    ref = tmp_path / "ref"
    synth_capture(str(ref), scenario=paper_scenario(), resolution=(30, 40))
    for name, extra in (("default", []), ("release", ["--handling", "release"])):
        out = tmp_path / name
        assert cli.main(["synth", "--out", str(out), "--resolution", "30x40", *extra]) == 0
        assert json.loads(capsys.readouterr().out)["handling"] == "release"
        files = _files(ref)
        assert files == _files(out) and len(files) > 18
        match, mismatch, errors = filecmp.cmpfiles(ref, out, files, shallow=False)
        assert mismatch == [] and errors == [], (name, mismatch, errors)


def test_wave_waves_one_corner_up_and_down_and_holds_the_others_still():
    sc = handling_scenario("wave")
    c = sc.grid.corners()
    waved = c[D.WAVE_CORNER]
    assert moving_handles(sc) == [waved] and all(h.release_time is None for h in sc.handles)
    h = next(h for h in sc.handles if h.vertex == waved)
    start = sc.grid.rest[waved]
    assert h.times[0] == 0.0 and h.times[-1] == sc.frame_times[-1]
    assert np.diff(h.times).max() <= D.HANDLING_KEY_STEP + 1e-12
    quarter, half = 1.0 / (4 * D.WAVE_FREQUENCY), 1.0 / (2 * D.WAVE_FREQUENCY)
    up = start + D.WAVE_AMPLITUDE * np.asarray(D.WAVE_DIRECTION)
    assert np.abs(h.position(quarter) - up).max() < 0.01 * D.WAVE_AMPLITUDE  # the top of the wave, between keys
    assert np.abs(h.position(3 * quarter) - (2 * start - up)).max() < 0.01 * D.WAVE_AMPLITUDE  # and its bottom
    assert np.abs(h.position(half) - start).max() < 1e-12 + 0.01 * D.WAVE_AMPLITUDE
    assert np.array_equal(h.position(-0.2), start)  # held where it settled before t = 0
    side = handling_scenario("wave", direction=(1.0, 0.0, 0.0), amplitude=0.01)
    hs = next(h for h in side.handles if h.vertex == waved)
    assert np.ptp(hs.positions[:, 0]) > 0.019 and np.ptp(hs.positions[:, 2]) == 0.0


@pytest.mark.parametrize("name", ["lift", "apart"])
def test_two_hands_lift_the_cloth_or_move_apart_and_come_back(name):
    sc = handling_scenario(name)
    a, b = two_hands(sc.grid)
    assert [h.vertex for h in sc.handles] == [a, b] and moving_handles(sc) == [a, b]
    assert sc.settle_time == D.TWO_HAND_SETTLE_TIME
    ha, hb = sc.handles
    dur = D.LIFT_DURATION if name == "lift" else D.APART_DURATION
    width = np.linalg.norm(sc.grid.rest[b] - sc.grid.rest[a])
    for t, share in ((0.0, 0.0), (dur / 2, 1.0), (dur, 0.0), (dur + 0.3, 0.0)):
        pa, pb = ha.position(t), hb.position(t)
        if name == "lift":
            np.testing.assert_allclose(pa - sc.grid.rest[a], [0, 0, share * D.LIFT_HEIGHT], atol=1e-12)
            np.testing.assert_allclose(pb - sc.grid.rest[b], [0, 0, share * D.LIFT_HEIGHT], atol=1e-12)
        else:
            want = D.APART_HOLD + share * (D.APART_SPREAD - D.APART_HOLD)
            assert abs(np.linalg.norm(pb - pa) - want * width) < 1e-12
            np.testing.assert_allclose((pa + pb) / 2, (sc.grid.rest[a] + sc.grid.rest[b]) / 2, atol=1e-12)


def test_handlings_and_their_options_are_checked():
    with pytest.raises(ClothFitError, match="'shake' is not one of release, wave, lift, apart"):
        handling_scenario("shake")
    with pytest.raises(ClothFitError, match="has no option 'height'"):
        handling_scenario("wave", height=0.1)
    with pytest.raises(ClothFitError, match="frequency must be positive"):
        handling_scenario("wave", frequency=0.0)
    with pytest.raises(ClothFitError, match="corner must be a corner index"):
        handling_scenario("wave", corner=4)
    with pytest.raises(ClothFitError, match="non-zero vector"):
        handling_scenario("wave", direction=(0, 0, 0))
    with pytest.raises(ClothFitError, match="a scenario or a handling, not both"):
        synth_capture("/nonexistent", scenario=paper_scenario(), handling="wave")


# ------------------------------------------------------------------ the models follow a keyed handle

GRID = ClothGrid(6, 6, 0.10)
C0 = GRID.corners()[0]
KEY0, KEY1, RELEASE = 4 / FPS, 10 / FPS, 14 / FPS  # keys and release on whole frames of the blender model
P0 = GRID.rest[C0]
P1 = P0 + np.array([0.01, -0.005, 0.02])
TIMES = np.arange(1, 20) / FPS


def _keyed(release=RELEASE, p1=P1):
    hs = [Handle(C0, [KEY0, KEY1], [P0, p1], release)] + [
        Handle(v, [0.0], GRID.rest[v][None]) for v in GRID.corners()[1:]
    ]
    return Scenario(GRID, hs, TIMES, 0.25)


def _model_and_row(name):
    if name == "paper":
        return PaperModel(), np.array([[D.GT_PARAMS["m"], D.GT_PARAMS["k"], GRID.spacing, D.GT_PARAMS["d"]]])
    return BlenderModel(FPS), B.settings_row(B.check_settings({"time_scale": B.physical_time_scale(FPS)}))[None]


MODELS = [("paper", "numba"), ("paper", "numpy"), ("blender", "numba"), ("blender", "numpy")]


@pytest.mark.parametrize("name,backend", MODELS, ids=[f"{m}-{b}" for m, b in MODELS])
def test_both_models_follow_a_keyed_handle_between_before_and_after_its_keys_and_let_it_go(name, backend):
    """A corner keyed at two times and released later: before the first key it is at the first, between
    the keys on the line between them, after the last at the last until its release, then it falls."""
    model, row = _model_and_row(name)
    sc = _keyed()
    X = model.simulate(sc, row, backend).positions[0][:, C0]
    want = sc.handles[0].position(TIMES)
    held = TIMES <= RELEASE
    tol = 1e-9 if name == "paper" else 1e-6  # the blender model's positions are float32
    assert np.abs(X[held] - want[held]).max() < tol
    between = (TIMES > KEY0) & (TIMES < KEY1)
    assert between.sum() >= 4 and np.abs(X[between] - P0).max(axis=1).min() > 1e-3  # on the way, not at a key
    assert np.abs(X[TIMES <= KEY0] - P0).max() < tol and np.abs(X[held & (TIMES >= KEY1)] - P1).max() < tol
    gone = np.linalg.norm(X[~held] - P1, axis=1)
    assert gone.min() > 1e-3 and X[~held][-1, 2] < P1[2] - 0.01  # let go: it falls away from its last key
    # the rest of the cloth follows the moving corner: not the motion of a corner held still
    still = model.simulate(_keyed(p1=P0), row, backend).positions[0]
    moved = model.simulate(sc, row, backend).positions[0]
    assert np.linalg.norm(moved[held] - still[held], axis=-1)[:, GRID.nx + 1].max() > 1e-3


@pytest.mark.parametrize("name", ["paper", "blender"])
def test_the_fits_offsets_move_a_whole_path_and_shift_its_keys_and_release_together(name):
    """The manipulation unknowns on a keyed, released handle (the population path a fit runs): a
    handle offset moves every key of the path; a time offset of two frames reads the same motion two
    frames earlier: the keys and the release shift together against the frames."""
    model, row = _model_and_row(name)
    sc = _keyed()
    H = len(sc.handles)
    shift = np.array([0.002, -0.001, 0.003])
    tau = 2 / FPS
    handles = np.zeros((3, H, 3))
    handles[1, 0] = shift
    off = Offsets([0.0, 0.0, tau], handles)
    res = model.simulate(sc, np.repeat(row, 3, axis=0), "auto", offsets=off)
    assert not res.exploded.any()
    X = res.positions  # (3, F, V, 3)
    path = sc.handles[0].position(TIMES)
    held = TIMES <= RELEASE
    tol = 1e-9 if name == "paper" else 2e-6
    assert np.abs(X[1, held, C0] - (path[held] + shift)).max() < tol  # the whole path moved
    assert np.abs(X[1, held, C0] - path[held]).max(axis=1).min() > 0.002  # by the offset, at every held frame
    late = TIMES - tau
    held_late = late <= RELEASE
    assert held_late.sum() == held.sum() + 2  # the release comes two frames later on the capture's clock
    assert np.abs(X[2, held_late, C0] - sc.handles[0].position(late[held_late])).max() < tol
    # the same motion, two frames later (to a micrometre: the paper sheet's steps fall differently
    # against the shifted frames): the keys and the release moved together
    assert np.abs(X[2, 2:] - X[0, :-2]).max() < 1e-6
    # the fitted scenario a result describes is the same moved manipulation
    fitted = fitted_scenario(
        sc,
        {
            "time_offset_s": tau,
            "handles": [dict(h.to_dict(), offset_m=list(o)) for h, o in zip(sc.handles, handles[1])],
        },
    )
    np.testing.assert_allclose(fitted.handles[0].positions, sc.handles[0].positions + shift)
    assert fitted.handles[0].release_time == RELEASE and np.allclose(fitted.frame_times, TIMES - tau)


def test_synth_handlings_write_captures_whose_paths_the_truth_follows(tmp_path, capsys):
    """``synth --handling wave`` writes the waved path into the capture; scored with the truth's own
    parameters the capture's silhouettes match, and the same truth with the corner held still does not."""
    from clothfit.core.fitting.evaluate import evaluate

    cams = [c.resized(60, 80) for c in C.load_rig("lab18")[:4]]
    times = list(np.arange(1, 13) / 24)
    sc = handling_scenario("wave", frame_times=times)
    cap = synth_capture(str(tmp_path / "wave"), scenario=sc, cameras=cams, noise=0.0)
    back = load_capture(cap.root)
    assert moving_handles(back.scenario) == [sc.grid.corners()[D.WAVE_CORNER]]
    good = evaluate(back, D.GT_PARAMS)
    still = handling_scenario("release", frame_times=times)
    still.handles = [Handle(h.vertex, h.times, h.positions) for h in still.handles]  # nothing released or waved
    back.scenario = still
    bad = evaluate(back, D.GT_PARAMS)
    assert good["shape_error_mm"] < 1e-6 and good["silhouette_error_pct"] < 0.2 * bad["silhouette_error_pct"]
    assert bad["shape_error_mm"] > 1.0, bad
    for name in ("lift", "apart"):
        out = tmp_path / name
        assert cli.main(["synth", "--out", str(out), "--handling", name, "--resolution", "30x40"]) == 0
        assert json.loads(capsys.readouterr().out)["handling"] == name
        c = load_capture(str(out))
        assert moving_handles(c.scenario) == list(two_hands(c.scenario.grid)) and c.meta["handling"] == name


def test_a_fitted_manipulation_describes_the_whole_moved_path():
    """What a result writes of a fitted handle offset on a keyed handle: every key moved by it, the key
    times and the release as declared; read back it is the scenario the fit scored."""
    sc = _keyed()
    mp = ManipulationParameters(Uncertainty.parse({"time_offset": 0.1, "handles": [0.005, 0, 0, 0]}, 4), sc)
    m = np.array([0.03, 0.001, -0.002, 0.0025])
    d = mp.describe(m, sc)
    h = d["handles"][0]
    np.testing.assert_allclose(np.asarray(h["positions"]) - sc.handles[0].positions, [[0.001, -0.002, 0.0025]] * 2)
    assert h["times"] == sc.handles[0].times.tolist() and h["release_time"] == RELEASE
    back = fitted_scenario(sc, d)
    ref = sc.moved(0.03, mp.offsets(m).handles[0])
    np.testing.assert_allclose(back.handles[0].position(TIMES), ref.handles[0].position(TIMES))
    np.testing.assert_allclose(back.frame_times, ref.frame_times)


def test_a_tiny_fit_of_a_waved_capture_reports_the_moved_path_and_evaluate_scores_it_the_same(tmp_path, capsys):
    """End to end on a capture whose corner is waved: a fit with uncertain handles writes each fitted
    handle as the capture's whole path moved by its offset, and ``evaluate`` with that result scores
    the training images as the fit did (the same moved path simulated again)."""
    cap = tmp_path / "wave"
    assert cli.main(["synth", "--out", str(cap), "--handling", "wave", "--resolution", "60x80"]) == 0
    res = tmp_path / "fit.json"
    args = ["--cameras", "n:2", "--times", "0.1,0.3,0.5,0.7"]
    assert cli.main(["fit", str(cap), *args, "--max-evaluations", "30", "--uncertain", "handles=0.003",
                     "--no-intervals", "--out", str(res)]) == 0  # fmt: skip
    capsys.readouterr()
    r = json.loads(res.read_text())
    declared = load_capture(str(cap)).scenario.handles
    for d, h in zip(r["handles"], declared):
        assert d["times"] == h.times.tolist()
        np.testing.assert_allclose(np.asarray(d["positions"]) - h.positions, np.tile(d["offset_m"], (len(h.times), 1)))
    assert any(np.any(d["offset_m"]) for d in r["handles"]) and len(r["handles"][0]["times"]) > 10
    assert cli.main(["evaluate", str(cap), "--params", str(res), *args]) == 0
    ev = json.loads(capsys.readouterr().out)
    assert abs(ev["silhouette_error_pct"] - r["best_E_sil_mean_pct"]) < 1e-6 * max(1.0, r["best_E_sil_mean_pct"])


def test_the_exported_script_says_which_pins_move_along_a_path(tmp_path, capsys):
    """The script of ``export-blender-cloth --python`` sets Cloth settings only: for a fit whose
    manipulation moves a pin along a path it says so in a comment, and says nothing of a pin held still."""
    sc = handling_scenario("wave", frame_times=np.arange(1, 7) / FPS)
    res = {
        "model": {"name": "blender", "fps": FPS, "quality": 5, "bending_model": "ANGULAR"},
        "blender_cloth": B.check_settings({"time_scale": B.physical_time_scale(FPS)}),
        "blender_scene": {"fps": FPS},
        "handles": [dict(h.to_dict(), offset_m=[0.0, 0.0, 0.0]) for h in sc.handles],
    }
    p = tmp_path / "r.json"
    p.write_text(json.dumps(res))
    assert cli.main(["export-blender-cloth", str(p), "--python"]) == 0
    text = capsys.readouterr().out
    waved = sc.grid.corners()[D.WAVE_CORNER]
    moving = [line for line in text.splitlines() if "moves along a path" in line]
    assert len(moving) == 1 and f"vertex {waved}:" in moving[0], moving
    compile(text, "script", "exec")  # still a whole Python script
