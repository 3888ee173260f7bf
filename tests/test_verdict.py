"""A fit's verdict: one line a person reads and a kind a program reads, computed from the result alone; degenerate
inputs get words instead of numbers (a floor of 0, silhouettes with every pixel set, settings ended at their
bounds); the blender model's frame rate comes from the capture (given, declared, read from its frame times, or
the default, saying why)."""

import json
import os
import shutil
import subprocess
import sys
import types

import cv2
import numpy as np
import pytest
from clothfit.core import defaults as D
from clothfit.core.errors import ClothFitError
from clothfit.core.fitting.job import FitConfig, FitJob
from clothfit.core.fitting.parameters import make_parameters, scene_frame_rate
from clothfit.core.fitting.verdict import KINDS, determined_by, verdict
from clothfit.core.observation.capture import load_capture
from clothfit.core.observation.frame_rate import frame_rate_from_times
from clothfit.core.observation.synth import synth_capture

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TIMES = [0.1, 0.2, 0.3, 0.4]


def _floor(train_ratio, heldout_ratio=None, **kw):
    """A floor block as ``diagnose.report`` writes it, at the given ratios to the floor."""
    d = {
        "train_E_sil_pct": 2.0 * train_ratio,
        "train_floor_pct": 2.0,
        "train_ratio": train_ratio,
        "threshold": D.FLOOR_FAR_ABOVE,
        "far_above": max(train_ratio, heldout_ratio or 0) > D.FLOOR_FAR_ABOVE,
        "likely_cause": None,
    }
    if heldout_ratio is not None:
        d.update(heldout_E_sil_pct=1.5 * heldout_ratio, heldout_floor_pct=1.5, heldout_ratio=heldout_ratio)
    d.update(kw)
    return d


# ============================================================ the verdict of a result dict


def test_a_fit_within_its_floor_reads_at_the_floor_and_a_missing_undetermined_list_counts_as_empty():
    below = 0.5 * D.FLOOR_FAR_ABOVE
    kind, line = verdict({"floor": _floor(below, below)})
    assert kind == "at_floor" and line.startswith("at the floor") and f"{below:.1f}x" in line
    kind, line = verdict({"floor": _floor(below, below), "intervals": {}, "undetermined": []})
    assert kind == "at_floor" and "every free setting determined" in line


def test_undetermined_settings_are_named_with_what_would_determine_them():
    below = 0.5 * D.FLOOR_FAR_ABOVE
    r = {"floor": _floor(below, below), "intervals": {}, "undetermined": ["bending_stiffness", "air_damping"]}
    kind, line = verdict(r)
    assert kind == "at_floor_undetermined"
    for n in r["undetermined"]:
        assert f"{n} ({determined_by(n)})" in line
    assert "resolution" in determined_by("bending_stiffness") and "handling" in determined_by("air_damping")


def test_far_above_gives_the_cause_the_floor_report_tested():
    above = 2.0 * D.FLOOR_FAR_ABOVE
    cause = "manipulation (the capture read half a frame (25 ms) earlier or later: error x0.50)"
    kind, line = verdict({"floor": _floor(1.0, above, likely_cause=cause)})
    assert kind == "far_above" and cause in line and f"held-out {above:.1f}x" in line


def test_a_setting_at_its_bound_is_named_with_its_bound_even_at_the_floor():
    below = 0.5 * D.FLOOR_FAR_ABOVE
    at = {"bending_stiffness": {"side": "lower", "bound": 0.001}}
    r = {"floor": _floor(below), "settings_at_bound": at, "at_bound": ["bending_stiffness", "time_offset_s"]}
    kind, line = verdict(r)
    assert kind == "at_bound"
    assert "bending_stiffness at its lower bound 0.001" in line and "--bounds" in line
    assert "time_offset_s" in line and "--uncertain" in line  # an offset at its declared bound
    # a setting at its bound that is also undetermined is said once, as at its bound
    r["undetermined"] = ["bending_stiffness"]
    assert verdict(r)[1].count("bending_stiffness") == 1


def test_a_floor_of_zero_gets_words_not_a_ratio():
    fl = dict(_floor(1.0), floor_zero=True, train_ratio=None, train_E_sil_pct=1.2, train_rim_pct=6.0, far_above=False)
    kind, line = verdict({"floor": fl})
    assert kind == "noise_free" and "the ratio is not meaningful" in line and "x above" not in line
    assert "0.2x a one-pixel shift of the outline" in line  # 1.2 % against a one-pixel shift's 6 %


def test_an_unfinished_or_failed_fit_has_no_floor_verdict():
    assert verdict({"cancelled": True, "evaluations": 12})[0] == "unfinished"
    assert "cancelled after 12 evaluations" in verdict({"cancelled": True, "evaluations": 12})[1]
    assert verdict({"error": "worker died", "floor": _floor(1.0)}) == ("failed", "failed: worker died")
    assert {verdict(r)[0] for r in ({}, {"floor": {}}, {"floor": _floor(1.0)})} <= set(KINDS)


# ============================================================ degenerate captures, fitted


@pytest.fixture(scope="module")
def caps(tmp_path_factory):
    """The paper scenario on a ring of 8 cameras at 240 x 320: noise-free, and with the usual boundary noise."""
    base = tmp_path_factory.mktemp("verdict")
    out = {}
    for name, noise in (("clean", 0.0), ("noisy", D.NOISE_FRACTION)):
        synth_capture(str(base / name), rig="ring8", resolution=(240, 320), noise=noise)
        out[name] = base / name
    return out


def _fit(path, **kw):
    cfg = dict(train_cameras=[0, 2, 4, 6], train_times=TIMES, max_evaluations=40, seed=0)
    cfg.update(kw)
    job = FitJob(load_capture(str(path)), FitConfig(**cfg))
    job.run()
    return job.result()


def test_a_noise_free_capture_has_a_floor_of_zero_and_no_ratio_to_it(caps):
    r = _fit(caps["clean"])
    fl = r["floor"]
    assert fl["floor_zero"] and fl["train_ratio"] is None and not fl["far_above"]
    assert "not meaningful" in fl["warning"] and "above its images' noise floor" not in fl["warning"]
    assert r["verdict_kind"] == "noise_free" and "not meaningful" in r["verdict"]


def test_bounds_that_exclude_the_cloth_are_blamed_not_quality(caps):
    """The truth's k/m is 1e6 1/s^2: a search up to 1e5 ends against that bound and says so."""
    bounds = dict(D.SEARCH_BOUNDS, k_over_m=(5.0e4, 1.0e5))
    r = _fit(caps["noisy"], bounds=bounds, max_evaluations=200)
    fl = r["floor"]
    assert not fl["floor_zero"] and fl["far_above"]  # a noisy capture has a floor, and this fit is far above it
    assert r["settings_at_bound"] == {"k_over_m": {"side": "upper", "bound": pytest.approx(1.0e5)}}
    assert r["at_bound"] == ["k_over_m"]
    assert fl["likely_cause"].startswith("bounds (k_over_m at its upper bound")
    assert r["verdict_kind"] == "far_above" and "k_over_m at its upper bound" in r["verdict"]


def test_silhouettes_with_every_pixel_set_are_refused_naming_camera_and_file(caps, tmp_path):
    root = tmp_path / "white"
    shutil.copytree(caps["clean"], root)
    cap = load_capture(str(root))
    path = cap.silhouette_path(2, cap.frame_index(TIMES[0]))
    cv2.imwrite(path, np.full((cap.cameras[2].height, cap.cameras[2].width), 255, np.uint8))
    with pytest.raises(ClothFitError, match="every pixel set") as e:
        FitJob(load_capture(str(root)), FitConfig(train_cameras=[0, 2], train_times=TIMES, max_evaluations=8))
    msg = str(e.value)
    assert (
        f"camera '{cap.cameras[2].name}' frame {cap.frame_index(TIMES[0])}" in msg and path in msg and "\n" not in msg
    )


def test_an_empty_silhouette_is_refused_by_name(caps, tmp_path):
    root = tmp_path / "black"
    shutil.copytree(caps["clean"], root)
    cap = load_capture(str(root))
    path = cap.silhouette_path(0, cap.frame_index(TIMES[1]))
    cv2.imwrite(path, np.zeros((cap.cameras[0].height, cap.cameras[0].width), np.uint8))
    with pytest.raises(ClothFitError, match=os.path.basename(path)):
        FitJob(load_capture(str(root)), FitConfig(train_cameras=[0, 2], train_times=TIMES, max_evaluations=8))


# ============================================================ the frame rate


def test_the_frame_rate_is_the_one_whose_period_divides_every_gap():
    assert frame_rate_from_times(D.FRAME_TIMES)[0] == 20.0  # the paper's 0.05 s
    fps, why = frame_rate_from_times([0.1, 0.2, 0.35, 0.4])  # frames missing: gaps of 2, 3 and 1 periods
    assert fps == 20.0 and "missing" in why
    rng = np.random.default_rng(0)
    jittered = np.arange(1, 40) / 30 + rng.normal(0, 1e-4, 39)  # a clock's jitter, timestamps to 0.1 ms
    assert frame_rate_from_times(np.round(jittered, 4))[0] == 30.0
    assert frame_rate_from_times(np.arange(1, 40) / (30 / 1.001))[0] == pytest.approx(30 / 1.001)


def test_irregular_or_too_few_frame_times_give_no_rate_and_say_why():
    fps, why = frame_rate_from_times([0.1, 0.2])
    assert fps is None and "too few" in why
    fps, why = frame_rate_from_times(np.cumsum(np.random.default_rng(1).uniform(0.02, 0.05, 20)))
    assert fps is None and "irregular" in why


def test_a_blender_fit_takes_the_given_then_the_declared_then_the_frame_times_rate():
    paper = types.SimpleNamespace(frame_times=np.array(D.FRAME_TIMES), model=None)
    assert scene_frame_rate(paper, FitConfig(model="blender")) == (20.0, "frame times")
    assert scene_frame_rate(paper, FitConfig(model={"name": "blender", "fps": 30})) == (30.0, "given")
    assert scene_frame_rate(paper, FitConfig(model="blender", fps=25)) == (25.0, "given")
    # a synthetic capture simulated at 24 fps declares it: that wins over its frames 0.05 s apart
    declared = types.SimpleNamespace(frame_times=np.array(D.FRAME_TIMES), model={"name": "blender", "fps": 24.0})
    assert scene_frame_rate(declared, FitConfig(model="blender")) == (24.0, "capture")
    odd = types.SimpleNamespace(frame_times=np.array([0.1, 0.13, 0.2, 0.31]), model=None)
    fps, src = scene_frame_rate(odd, FitConfig(model="blender"))
    assert fps == D.BLENDER_FPS and src.startswith("default (the frame times are irregular")


def test_the_result_says_which_frame_rate_a_blender_fit_used(caps):
    par = make_parameters(load_capture(str(caps["clean"])), FitConfig(model="blender"))
    scene = par.describe(par.space.lo)["blender_scene"]
    assert scene == {"fps": 20.0, "fps_source": "frame times"} and par.model.fps == 20.0


# ============================================================ the command line and the demo


def _run(*args):
    p = subprocess.run(
        [sys.executable, "-m", "clothfit", *[str(a) for a in args]], cwd=ROOT, capture_output=True, text=True
    )
    return p.returncode, p.stdout, p.stderr


def test_fit_ends_with_its_verdict_and_the_verdict_command_reads_it_back(caps, tmp_path):
    out = tmp_path / "fit.json"
    rc, so, err = _run(
        "fit", caps["noisy"], "--out", out, "--cameras", "0,2", "--times", "0.1,0.2", "--max-evaluations", 20, "--quiet"
    )
    assert rc == 0, err
    r = json.loads(out.read_text())
    assert r["verdict_kind"] in KINDS and f"verdict: {r['verdict']}" in err.splitlines()
    assert json.loads(so)["verdict"] == r["verdict"]  # the summary on stdout has it too
    rc, so, err = _run("verdict", out, out)
    assert rc == 0, err
    assert json.loads(so)["verdicts"] == 2 * [
        {"result": str(out), "verdict_kind": r["verdict_kind"], "verdict": r["verdict"]}
    ]
    assert err.splitlines().count(f"{out}: {r['verdict']}") == 2
    rc, so, err = _run("evaluate", caps["noisy"], "--params", out, "--cameras", "1", "--times", "0.1")
    assert rc == 0, err
    assert (
        json.loads(so)["fit_verdict"] == r["verdict"]
        and f"the fit's verdict (on the takes it fitted): {r['verdict']}" in err
    )


def test_the_demo_ends_by_printing_its_fits_verdicts():
    with open(os.path.join(ROOT, "Makefile")) as f:
        text = f.read()
    recipe = text.split("\ndemo:", 1)[1].split("\n\n", 1)[0].strip().splitlines()
    assert "clothfit verdict" in recipe[-1] and "fit_result" in recipe[-1]
    assert not any("demo done" in line for line in recipe)


def test_a_blender_model_fit_says_on_stderr_which_frame_rate_it_took(caps, tmp_path):
    out = tmp_path / "blender.json"
    args = ["--cameras", "0,2", "--times", "0.1,0.2", "--resolution", "60x80", "--max-evaluations", 8, "--quiet"]
    rc, so, err = _run("fit", caps["clean"], "--model", "blender", "--out", out, *args)
    assert rc == 0, err
    assert json.loads(out.read_text())["blender_scene"] == {"fps": 20.0, "fps_source": "frame times"}
    assert "frame rate 20 fps (frame times)" in err.splitlines()
    rc, so, err = _run("fit", caps["clean"], "--model", "blender", "--fps", 30, "--out", tmp_path / "b30.json", *args)
    assert rc == 0, err
    assert "frame rate 30 fps (given)" in err.splitlines()


def test_the_verdict_says_how_many_of_the_searchs_starts_ended_in_its_basin():
    below = 0.5 * D.FLOOR_FAR_ABOVE
    looks = {"starts": 3, "agreeing": 3, "ended_E_sil_pct": [1.0, 1.01, 1.02], "settings": ["tension_stiffness"]}
    kind, line = verdict({"floor": _floor(below, below), "looks": looks})
    assert kind == "at_floor" and "; all 3 starts of the search ended in this basin (no proof" in line
    looks = dict(looks, agreeing=1)
    kind, line = verdict({"floor": _floor(1.0, 3.0, likely_cause="search"), "looks": looks})
    assert kind == "far_above" and "1 of 3 starts of the search ended in this basin, the others in worse ones" in line
    # one start says nothing; a fit without a floor report has no verdict to add it to
    assert (
        "1 of 2 starts of the search ended in this basin, the other in a worse one"
        in verdict({"floor": _floor(below, below), "looks": dict(looks, starts=2)})[1]
    )
    assert "starts" not in verdict({"floor": _floor(below, below), "looks": dict(looks, starts=1, agreeing=1)})[1]
    assert "starts" not in verdict({"cancelled": True, "evaluations": 5, "looks": looks})[1]
