"""Several takes of one cloth in one fit: one set of settings, each take its own cameras, frame rate and
manipulation's unknowns; a result scores any take, one it fitted or one it never saw."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from clothfit.core import defaults as D
from clothfit.core.errors import ClothFitError
from clothfit.core.fitting.evaluate import UNSEEN, evaluate
from clothfit.core.fitting.job import FitConfig, FitJob
from clothfit.core.fitting.takes import TAKE_SEP
from clothfit.core.observation.synth import synth_capture
from clothfit.core.physics import blender as B
from clothfit.core.physics.scenario import ClothGrid, paper_scenario
from takes_support import TRUTH, make_takes

pytest.importorskip("numba")


@pytest.fixture(scope="module")
def takes(tmp_path_factory):
    return make_takes(tmp_path_factory.mktemp("takes"), 6, 7)


def _cfg(**kw):
    base = dict(model="blender", quality=5, max_evaluations=60, train_cameras=[0, 2, 4, 6], intervals=False)
    base.update(kw)
    return FitConfig(**base)


def test_the_error_of_two_takes_is_the_sum_of_each_take_fitted_alone_at_its_own_frame_rate(takes):
    one, two = takes
    both = FitJob([one, two], _cfg())
    assert [t.fps for t in both.takes] == [24.0, 20.0]
    alone = [FitJob(c, _cfg()) for c in takes]
    assert alone[1].par.fixed["time_scale"] == pytest.approx(B.physical_time_scale(20))
    X = both.space.decode(np.random.default_rng(1).uniform(0.2, 0.8, (3, both.space.n)))
    total = both.evaluate(X)
    parts = sum(j.evaluate(X) for j in alone)
    assert np.allclose(total, parts, rtol=1e-9)
    assert both.objective.n_images == sum(j.objective.n_images for j in alone)


def test_each_take_has_its_own_unknowns_and_they_reach_only_their_take(takes):
    both = FitJob(list(takes), _cfg(uncertain="time_offset=0.02,handles=0"))
    names = list(both.space.names)[both.npar :]
    assert names == [f"one_corner{TAKE_SEP}time_offset_s", f"two_corners{TAKE_SEP}time_offset_s"]
    x = both.space.decode(np.full(both.space.n, 0.5))
    moved = x.copy()
    moved[-1] = 0.015  # the second take's clock only
    per = both.objective.per_take(
        both.par.rows(np.stack([x, moved])[:, : both.npar]), both.manip.offsets(np.stack([x, moved])[:, both.npar :])
    )
    assert per[0, 0] == per[1, 0]
    assert per[0, 1] != per[1, 1]


def test_a_fit_of_two_takes_reports_each_take_and_resumes_exactly(takes, tmp_path):
    ck = str(tmp_path / "ck.json")
    job = FitJob(list(takes), _cfg(max_evaluations=90), checkpoint=ck)
    for _ in range(4):
        job.step()
    again = FitJob.resume(ck, config=_cfg(max_evaluations=90))
    assert [t.name for t in again.takes] == ["one_corner", "two_corners"]
    r1, r2 = job.run().to_json(), again.run().to_json()
    assert r1["blender_cloth"] == r2["blender_cloth"]
    entries = r1["takes"]
    assert [e["take"] for e in entries] == ["one_corner", "two_corners"]
    assert [e["fps"] for e in entries] == [24.0, 20.0]
    for e in entries:
        assert e["floor"]["train_floor_pct"] > 0 and e["heldout_E_sil_pct"] > 0
        assert e["verdict_kind"] in ("at_floor", "far_above")
        # each take's own jitter floor, measured at the shared settings with the take's own unknowns
        q = e["floor"]["heldout_jitter_floor_pct"]
        assert e["floor"]["heldout_floor_pct"] <= q["p10"] <= q["p50"] <= q["p90"]
        assert e["floor"]["at_jitter_floor"] == (
            not e["floor"]["far_above"]
            and max(e["floor"]["train_ratio"], e["floor"]["heldout_ratio"]) > D.FLOOR_FAR_ABOVE
        )
    n = [e["n_train_images"] for e in entries]
    mean = sum(e["train_E_sil_pct"] * k for e, k in zip(entries, n)) / sum(n)
    assert r1["floor"]["train_E_sil_pct"] == pytest.approx(mean, rel=1e-6)


def test_a_checkpoint_of_two_takes_refuses_another_take(takes, tmp_path):
    one, two = takes
    ck = str(tmp_path / "ck.json")
    job = FitJob([one, two], _cfg(), checkpoint=ck)
    job.step()
    with pytest.raises(ClothFitError, match="takes"):
        FitJob.resume(ck, capture=[two, one], config=_cfg())


def test_cameras_per_take_must_name_every_take(takes):
    with pytest.raises(ClothFitError, match="one list per take"):
        FitJob(list(takes), _cfg(train_cameras=[[0, 2], [1, 3], [4, 5]]))
    job = FitJob(list(takes), _cfg(train_cameras=[[0, 2], [1, 3, 5]]))
    assert [t.train_cameras for t in job.takes] == [[0, 2], [1, 3, 5]]


def test_a_result_scores_a_take_it_fitted_with_its_manipulation_and_another_with_the_takes_own(takes, tmp_path):
    one, two = takes
    res = FitJob([one], _cfg(uncertain="time_offset=0.02,handles=0", max_evaluations=40)).run().to_json()
    assert res["time_offset_s"] != 0.0
    mine = evaluate(one, res, cameras=[1, 3])
    other = evaluate(two, res, cameras=[1, 3])
    assert mine["manipulation"] == "fitted"
    assert other["manipulation"] == UNSEEN
    assert other["model"]["fps"] == 20.0  # the take's own rate, not the fit's 24
    # the unseen take replays its declared release: the same as the bare settings at its own rate
    settings = dict(res["blender_cloth"], time_scale=B.physical_time_scale(20))
    bare = evaluate(two, {"blender_cloth": settings, "blender_scene": {"fps": 20.0}}, cameras=[1, 3])
    assert other["silhouette_error_pct"] == pytest.approx(bare["silhouette_error_pct"], rel=1e-9)


def test_the_command_line_fits_two_takes_and_scores_each(takes, tmp_path):
    one, two = takes
    out = str(tmp_path / "fit.json")
    env = dict(os.environ, CLOTHFIT_PROGRESS="0")
    run = subprocess.run(
        [
            sys.executable,
            "-m",
            "clothfit",
            "fit",
            one.root,
            two.root,
            "--cameras",
            "n:4",
            "--times",
            "even",
            "--max-evaluations",
            "40",
            "--no-intervals",
            "--quality",
            "5",
            "--out",
            out,
        ],
        capture_output=True,
        text=True,
        env=env,
        check=False,
    )
    assert run.returncode == 0, run.stderr
    assert "take two_corners: 20 fps" in run.stderr
    assert "take one_corner: training" in run.stderr
    res = json.load(open(out))
    assert [e["train_times"] for e in res["takes"]] == [list(one.frame_times[::2]), list(two.frame_times[::2])]
    ev = subprocess.run(
        [
            sys.executable,
            "-m",
            "clothfit",
            "evaluate",
            two.root,
            "--params",
            out,
            "--times",
            "odd",
            "--json",
            str(tmp_path / "ev.json"),
        ],
        capture_output=True,
        text=True,
        env=env,
        check=False,
    )
    assert ev.returncode == 0, ev.stderr
    assert json.load(open(tmp_path / "ev.json"))["manipulation"] == "fitted: take two_corners of the fit"


def test_an_unseen_takes_declared_unknowns_are_fitted_with_the_settings_held_when_asked(takes, tmp_path):
    import shutil

    from clothfit.core.fitting.evaluate import FITTED_HERE, FITTED_ON_OTHERS, for_take
    from clothfit.core.observation.capture import load_capture

    one, two = takes
    late = tmp_path / "late_clock"
    shutil.copytree(two.root, late)
    d = json.load(open(late / "capture.json"))
    for h in d["scenario"]["handles"]:  # the clock read 25 ms late: the release declared after it happened
        if h.get("release_time") is not None:
            h["release_time"] = 0.025
    d["uncertain"] = {"time_offset": 0.04, "handles": 0.0}
    json.dump(d, open(late / "capture.json", "w"))
    cap = load_capture(str(late))
    res = FitJob([one], _cfg(max_evaluations=30)).run().to_json()
    plain = evaluate(cap, res, cameras=[1, 3, 5])
    fitted = evaluate(cap, res, cameras=[1, 3, 5], fit_unknowns=60)
    assert plain["manipulation"] == UNSEEN and plain["time_offset_s"] is None
    assert fitted["manipulation"] == FITTED_HERE
    assert fitted["silhouette_error_pct"] <= plain["silhouette_error_pct"]
    assert fitted["time_offset_s"] != 0.0
    # the unknowns it found replay as they are: fitted on some images, they score others without refitting
    d["uncertain"] = {"time_offset": 0.04, "handles": 0.005}
    json.dump(d, open(late / "capture.json", "w"))
    cap = load_capture(str(late))
    fitted = evaluate(cap, res, cameras=[1, 3, 5], fit_unknowns=60)
    assert len(fitted["handles"]) == 4 and fitted["time_offset_s"] != 0.0  # its four pinned corners
    held, _ = for_take(cap, res)
    again = dict(held, time_offset_s=fitted["time_offset_s"], handles=fitted["handles"])
    del again["capture_hash"]
    assert evaluate(cap, again, cameras=[1, 3, 5])["silhouette_error_pct"] == fitted["silhouette_error_pct"]
    # fitted on some cameras and frames, scored on others: the unknowns those give, these scored with them
    fair = evaluate(
        cap,
        res,
        cameras=[0, 2, 4],
        times=cap.frame_times[1::2],
        fit_unknowns=60,
        unknowns_on=([1, 3, 5], cap.frame_times[::2]),
    )
    on = evaluate(cap, res, cameras=[1, 3, 5], times=cap.frame_times[::2], fit_unknowns=60)
    assert fair["manipulation"] == FITTED_ON_OTHERS and fair["handles"] == on["handles"]
    again = dict(held, time_offset_s=on["time_offset_s"], handles=on["handles"])
    del again["capture_hash"]
    assert evaluate(cap, again, cameras=[0, 2, 4], times=cap.frame_times[1::2]) == {**fair, "manipulation": "declared"}
    json.dump(res, open(tmp_path / "res.json", "w"))
    from clothfit import cli

    argv = ["evaluate", str(late), "--params", str(tmp_path / "res.json"), "--cameras", "0,2,4", "--times", "odd"]
    assert (
        cli.main(
            [
                *argv,
                "--fit-unknowns",
                "60",
                "--unknowns-cameras",
                "1,3,5",
                "--unknowns-times",
                "even",
                "--json",
                str(tmp_path / "e.json"),
            ]
        )
        == 0
    )
    got = json.load(open(tmp_path / "e.json"))
    assert got["manipulation"] == FITTED_ON_OTHERS and got["silhouette_error_pct"] == fair["silhouette_error_pct"]
    assert cli.main([*argv, "--unknowns-times", "even", "--json", str(tmp_path / "f.json")]) == 0  # implies fitting
    assert json.load(open(tmp_path / "f.json"))["manipulation"] == FITTED_ON_OTHERS


def test_no_selection_means_every_camera_and_frame_of_every_take(takes):
    job = FitJob(list(takes), _cfg(train_cameras=[None, [1, 3]], train_times=[None, None]))
    assert job.takes[0].train_cameras == list(range(8)) and job.takes[1].train_cameras == [1, 3]
    assert [len(t.train_times) for t in job.takes] == [6, 7]


def test_takes_of_another_cloth_or_without_the_training_frames_are_refused_naming_them(takes, tmp_path):
    one, _ = takes
    small = synth_capture(
        str(tmp_path / "small"),
        TRUTH,
        model={"name": "blender", "fps": 24},
        rig="ring8",
        resolution=(60, 80),
        scenario=paper_scenario(ClothGrid(5, 5, 0.1), frame_times=[0.125, 0.25]),
        noise=0.0,
    )
    with pytest.raises(ClothFitError, match=r"takes one_corner and small are not of one cloth: a 7 x 7 grid"):
        FitJob([one, small], _cfg())
    with pytest.raises(ClothFitError, match=r"^take two_corners: .*time 0.125 s is not a frame"):
        FitJob(list(takes), _cfg(train_times=[0.125, 0.25]))


def test_each_take_is_searched_alone_and_a_take_the_shared_settings_do_not_serve_is_named(takes, tmp_path):
    from clothfit.core.fitting.alone import disagreement_text
    from clothfit.core.fitting.verdict import verdict

    ck = str(tmp_path / "ck.json")
    job = FitJob(list(takes), _cfg(max_evaluations=4 * 2 * 150, intervals=True), checkpoint=ck)
    while job.state.stage != "alone":
        job.step()
    job.step()
    job.step()
    again = FitJob.resume(ck, config=_cfg(max_evaluations=4 * 2 * 150, intervals=True))
    r1, r2 = job.run().to_json(), again.run().to_json()
    assert [e["alone_E_sil_pct"] for e in r1["takes"]] == [e["alone_E_sil_pct"] for e in r2["takes"]]
    assert r1["intervals"] is not None  # the intervals came first: alone starts from the final best point
    for e in r1["takes"]:  # searched alone from the shared settings, a take is served at least as well
        assert e["alone_E_sil_pct"] <= e["train_E_sil_pct"] + 1e-9
    assert r1["blender_cloth"] == r2["blender_cloth"]
    results = [
        {"take": "a", "alone_E_sil_pct": 1.0, "joint_E_sil_pct": 1.2},
        {"take": "b", "alone_E_sil_pct": 1.0, "joint_E_sil_pct": 3.0},
    ]
    line = disagreement_text(results)
    assert "take b 3.00 %" in line and "take a" not in line
    kind, text = verdict({"floor": {"train_floor_pct": 1.0, "train_ratio": 1.5, "takes_note": line}})
    assert kind == "takes_disagree" and "take b" in text
