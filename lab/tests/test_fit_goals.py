"""lab/fit_goals.py's pure parts: the declared (shifted) capture of the offsets goal really is
20 ms and 2 mm off the truth, in the sign the fit's time offset is defined by; the rows and the
Markdown table. No fits here."""

import json
import os
import sys

import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.join(ROOT, "lab"))

import fit_goals as G  # noqa: E402
from clothfit.core import defaults as D  # noqa: E402
from clothfit.core.observation.capture import load_capture  # noqa: E402
from clothfit.core.observation.synth import synth_capture  # noqa: E402
from clothfit.core.physics.models import simulate  # noqa: E402
from clothfit.core.physics.paper import Params  # noqa: E402
from clothfit.core.physics.scenario import ClothGrid, Scenario, paper_scenario  # noqa: E402

EARLY, OFF = 0.020, 0.002


def small_scenario():
    return paper_scenario(ClothGrid(6, 6, D.CLOTH_SIDE), frame_times=[0.05, 0.1, 0.15, 0.2, 0.25])


def test_unit_directions_are_unit_random_and_repeatable():
    u = G.unit_directions(4, 20)
    assert np.allclose(np.linalg.norm(u, axis=1), 1.0)
    assert np.array_equal(u, G.unit_directions(4, 20))
    assert not np.allclose(u, G.unit_directions(4, 21))
    assert np.linalg.matrix_rank(u) == 3  # not all along one axis


def test_shifted_scenario_is_20_ms_early_and_each_pin_2_mm_off():
    """Marked 20 ms early: every frame's capture time 20 ms later than its time after the true release;
    the manipulation's own clock (keys, release, settle) unchanged; each pin 2 mm off."""
    true = small_scenario()
    offs = OFF * G.unit_directions(len(true.handles), 3)
    d = Scenario.from_dict(G.shift_scenario(true.to_dict(), EARLY, offs))
    assert d.settle_time == true.settle_time
    assert np.allclose(d.frame_times - true.frame_times, EARLY, atol=1e-12, rtol=0)
    for h, g in zip(true.handles, d.handles):
        assert g.vertex == h.vertex and g.release_time == h.release_time and np.array_equal(g.times, h.times)
        assert np.linalg.norm(g.positions - h.positions, axis=1) == pytest.approx(OFF, abs=1e-12)


def test_the_fit_definition_of_the_offsets_recovers_the_truth_from_the_declared_scenario():
    """true time = capture time - time_offset_s: the declared scenario moved by +20 ms and by -d per pin
    is the truth's motion; unmoved, moved the other way or with the pins alone it is not."""
    true = small_scenario()
    offs = OFF * G.unit_directions(len(true.handles), 3)
    declared = Scenario.from_dict(G.shift_scenario(true.to_dict(), EARLY, offs))
    p = [Params.from_dict(dict(D.GT_PARAMS, l=D.CLOTH_SIDE / 5))]
    X = simulate(true, p).positions[0]
    mm = lambda sc: float(np.linalg.norm(simulate(sc, p).positions[0] - X, axis=-1).max() * 1000)  # noqa: E731
    assert mm(declared.moved(EARLY, -offs)) < 1e-6
    pins_only, time_only = mm(declared.moved(0.0, -offs)), mm(declared.moved(EARLY, None))
    unmoved, wrong_sign = mm(declared), mm(declared.moved(-EARLY, -offs))
    assert min(pins_only, unmoved, wrong_sign) > 5.0, (pins_only, unmoved, wrong_sign)
    assert time_only > 0.5, time_only
    assert wrong_sign > pins_only


def test_shift_capture_copies_the_capture_with_the_declared_scenario_and_the_uncertain_block(tmp_path):
    true_root = str(tmp_path / "true")
    synth_capture(true_root, rig="lab18", resolution=(48, 64), scenario=small_scenario(), seed=1)
    shift = G.shift_capture(true_root, str(tmp_path / "declared"), EARLY, OFF, 20, G.OFFSETS["uncertain"])
    t, d = load_capture(true_root), load_capture(str(tmp_path / "declared"))
    assert d.uncertain is not None and d.uncertain.time_offset == 0.05 and set(d.uncertain.handles) == {0.005}
    assert t.uncertain is None
    assert np.array_equal(t.load_silhouette(3, 2), d.load_silhouette(3, 2))
    assert np.allclose(d.frame_times - t.frame_times, EARLY, atol=1e-9, rtol=0)
    assert np.allclose(np.load(tmp_path / "declared" / "shapes.npz")["frame_times"], d.frame_times)
    assert np.array_equal(
        np.load(tmp_path / "declared" / "shapes.npz")["positions"],
        np.load(tmp_path / "true" / "shapes.npz")["positions"],
    )
    exp = np.array(shift["expected_handle_offset_m"])
    for h, g, e in zip(t.scenario.handles, d.scenario.handles, exp):
        assert np.allclose(g.positions + e, h.positions, atol=1e-15)  # declared + expected offset = true
    assert shift["expected_time_offset_s"] == EARLY
    with open(tmp_path / "declared" / "capture.json") as f:
        assert json.load(f)["meta"]["declared_shift"]["direction_seed"] == 20


def test_rows_pass_fail_and_not_measured():
    run = {"command": "python -m clothfit fit a|b", "wall_s": 12.34, "cpu_s": 20.0, "load": "load 1.00, 2.00, 3.00"}
    ok = G.row(
        "exact", "exact", "heldout_ratio", 1.1, run, details={"heldout_E_sil_pct": 0.4125, "floor_E_sil_pct": 0.375}
    )
    bad = G.row("time", "time", "wall_s", 200.0, run)
    none = G.row("offsets", "offsets", "time_offset_error_ms", None, run, "not estimated: needs fit --uncertain")
    assert (ok["pass"], bad["pass"], none["pass"]) == (True, False, None)
    assert ok["target"] == 1.2 and bad["target"] == 180.0
    for r in (ok, bad, none):
        r["label"] = "before"
    table = G.format_table(
        {
            "rows": [ok, bad, none],
            "runs": {"exact (before)": {"commit": "abc1234", "main_commit": "def5678", "dirty": False}},
        }
    )
    lines = table.splitlines()
    assert lines[0].startswith("| capture | goal | figure | target | pass | command | wall s | load |")
    body = lines[2:5]
    assert "1.10x (0.41 % / 0.375 %)" in body[0] and "<= 1.20x" in body[0] and "| pass |" in body[0]
    assert "200 s (CPU 20 s)" in body[1] and "FAIL" in body[1]
    assert "not measured (not estimated: needs fit --uncertain)" in body[2] and "| - |" in body[2]
    assert all(r.count("|") - r.count("\\|") == 9 for r in body)  # the pipe in the command escaped
    assert "exact (before): held-out E_sil / floor" in body[0]
    assert "exact (before) at abc1234 (main def5678)" in table


def test_merge_keeps_the_other_goals_rows(tmp_path):
    path = str(tmp_path / "goals.json")
    run = {"command": "c", "wall_s": 1.0, "cpu_s": 1.0, "load": "load 0"}
    G.merge_rows(path, "time", [G.row("time", "t", "wall_s", 100.0, run)], label="before")
    G.merge_rows(path, "exact", [G.row("exact", "e", "heldout_ratio", 2.0, run)], label="before")
    G.merge_rows(path, "time", [G.row("time", "t", "wall_s", 90.0, run)], label="after")
    doc = G.merge_rows(path, "time", [G.row("time", "t", "wall_s", 120.0, run)], label="before")
    assert [(r["goal"], r["label"], r["value"]) for r in doc["rows"]] == [
        ("exact", "before", 2.0),
        ("time", "before", 120.0),
        ("time", "after", 90.0),
    ]
    assert set(doc["runs"]) == {"exact (before)", "time (before)", "time (after)"}
    assert doc["runs"]["time (before)"]["commit"]


def test_every_goal_reads_the_options_its_subcommand_and_all_define(tmp_path, monkeypatch):
    """``all`` runs every goal with its own namespace: an option a goal reads (exact's and offsets' --seeds and
    --optimizer) must be defined on ``all`` too, or ``all`` stops at that goal."""
    seen = {}

    def fake(goal):
        def run(a, _run):
            seen[goal] = (a.seeds, a.optimizer) if goal in ("exact", "offsets") else a.out
            return [], {}

        return run

    for g in G.GOALS:
        monkeypatch.setitem(G.RUNNERS, g, fake(g))
    out = str(tmp_path / "goals")
    assert G.main(["all", "--out", out, "--json", str(tmp_path / "all.json")]) == 0
    assert set(seen) == set(G.GOALS)
    assert seen["exact"] == ("0", None) and seen["offsets"] == ("0", None)
    seen.clear()
    G.main(["offsets", "--out", out, "--json", str(tmp_path / "one.json"), "--seeds", "3", "--optimizer", "cma-es"])
    assert seen == {"offsets": ("3", "cma-es")}


def test_the_collider_and_time_goals_pass_the_search_asked_to_their_fit(tmp_path, monkeypatch):
    """``collider`` and ``time`` take ``--search``, ``--optimizer`` and ``--seeds`` like the other goals, so a
    candidate default is measured on them without changing the default; their fits' files are named by it."""
    out = tmp_path / "goals"
    os.makedirs(out / "collider" / "capture")
    (out / "collider" / "capture" / "capture.json").write_text("{}")
    for name in ("time21_true", "time21_real"):
        os.makedirs(out / name)
        (out / name / "capture.json").write_text(json.dumps({"meta": {"declared_shift": {}}}))

    class Fitted(Exception):
        pass

    fits = []

    def runner(_log):
        def run(argv, parse=True):
            if argv[0] == "fit":
                fits.append(argv)
                raise Fitted
            raise AssertionError(f"only the fit should run: {argv}")

        return run

    monkeypatch.setattr(G, "Runner", runner)
    asked = ["--search", "staged_restart_step=0.01", "--seeds", "2", "--out", str(out)]
    for goal in ("collider", "time"):
        with pytest.raises(Fitted):
            G.main([goal, *asked, "--json", str(tmp_path / "g.json")])
    collider, time_fit = fits
    for argv in fits:
        i = argv.index("--search")
        assert argv[i + 1] == "staged_restart_step=0.01" and argv[argv.index("--seed") + 1] == "2"
    assert collider[collider.index("--out") + 1].endswith("collider_staged_restart_step0p01_s2.json")
    assert time_fit[time_fit.index("--out") + 1].endswith("time21_real_staged_restart_step0p01_s2.json")


def test_offsets_sensitivity_scores_the_truth_at_its_floor_and_moves_one_thing_at_a_time(tmp_path, monkeypatch):
    """The offsets capture's truth, scored as the goal scores a fit, is at its floor exactly (the declared
    capture plus the expected offsets is the true set-up); the time offset or a pin moved costs more; the
    jitter floor is the held-out error of points a part in 10^7 away (lab/fit_goals.py
    offsets_sensitivity, figure source fit_goals_offsets_sensitivity)."""
    true_root, declared = str(tmp_path / "true"), str(tmp_path / "declared")
    truth = {"tension_stiffness": 15.0, "shear_stiffness": 5.0, "bending_stiffness": 0.5, "air_damping": 1.0}
    synth_capture(
        true_root,
        truth,
        model={"name": "blender", "fps": 24, "quality": 5},
        rig="lab18",
        resolution=(48, 64),
        scenario=small_scenario(),
        seed=1,
    )
    G.shift_capture(true_root, declared, EARLY, OFF, 20, G.OFFSETS["uncertain"])
    monkeypatch.setattr(G, "_offsets_captures", lambda a, run, hold=False: (true_root, declared))
    monkeypatch.setattr(G, "SENSITIVITY", dict(G.SENSITIVITY, time_ms=(3.0,), pin_mm=(1.0,), jitter=3))
    out = G.offsets_sensitivity(None, None, times=([0.1, 0.2], [0.15, 0.25]))
    assert out["truth"]["heldout_ratio"] == pytest.approx(1.0, abs=1e-12) and out["floor_pct"] > 0
    assert [r["moved_ms"] for r in out["time"]] == [3.0, -3.0]
    assert [(r["pin"], r["moved_mm"]) for r in out["pins"]] == [(k, 1.0) for k in range(4)]
    assert max(r["heldout_ratio"] for r in out["time"] + out["pins"]) > 1.0
    assert out["jitter_floor"]["points"] == 3 and out["jitter_floor"]["min_ratio"] >= 0
    assert 0 < out["pixel_mm"] < 100


def test_offsets_coverage_counts_each_stated_offset_against_its_uncertainty(tmp_path):
    """offsets_coverage (figure source fit_goals_offsets_coverage): each stated offset's error (fitted minus the shift
    the capture was made with) over the uncertainty the fit states; an offset stated without one counted apart; the
    other rows of a recording (time and pin errors) ignored."""

    def fit(time_s, handles):
        return {
            "capture": "offsets [seed 0]",
            "key": "heldout_ratio",
            "value": 2.0,
            "details": {
                "shift": {"expected_time_offset_s": 0.02, "expected_handle_offset_m": [[0.001, 0.0, 0.0]]},
                "time_offset_s": time_s[0],
                "time_offset_uncertainty_s": time_s[1],
                "handles": handles,
            },
        }

    # time 1 ms off stated 2 ms: 0.5x; x 0.3 mm off stated 0.1 mm: 3x; y exact: 0x; z not separated
    one = fit(
        (0.021, 0.002), [{"vertex": 7, "offset_m": [0.0013, 0.0, 0.004], "offset_uncertainty_m": [1e-4, 1e-4, None]}]
    )
    rec = tmp_path / "rec.json"
    rec.write_text(json.dumps({"data": {"rows": [one, {"key": "time_offset_error_ms", "value": 1.0}]}}))
    out = G.offsets_coverage([str(rec)])
    (f,) = out["fits"]
    assert out["stated"] == f["stated"] == 3 and f["not_separated"] == ["vertex 7 z"] and out["not_separated"] == 1
    ratios = {r["offset"]: r["error_over_stated"] for r in f["offsets"]}
    assert ratios["time_offset"] == pytest.approx(0.5) and ratios["vertex 7 x"] == pytest.approx(3.0)
    assert ratios["vertex 7 y"] == 0.0 and f["worst"]["offset"] == "vertex 7 x"
    assert out["share_within_1"] == pytest.approx(2 / 3) and out["share_within_2"] == pytest.approx(2 / 3)
    assert out["median_error_over_stated"] == pytest.approx(0.5) and out["max_error_over_stated"] == pytest.approx(3.0)
    nothing = tmp_path / "none.json"
    nothing.write_text(json.dumps({"data": {"rows": [fit((None, None), [])]}}))
    with pytest.raises(SystemExit, match="no offsets fit with stated uncertainties"):
        G.offsets_coverage([str(nothing)])
