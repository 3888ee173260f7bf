"""A fit that started from a user's settings (a scene's Cloth modifier, a warm start) says when those settings
predict the cameras and frames it did not see as well as its answer does: the verdict ``start_better``, with
both errors and the start's settings in the result, so a fit never reads as an improvement it is not."""

import json

import numpy as np
import pytest
from clothfit.core.fitting.diagnose import report
from clothfit.core.fitting.job import FitConfig, FitJob
from clothfit.core.fitting.verdict import KINDS, verdict
from clothfit.core.observation.synth import synth_capture
from clothfit.core.physics import blender as B
from takes_support import TRUTH, released

pytest.importorskip("numba")


@pytest.fixture(scope="module")
def cap(tmp_path_factory):
    root = tmp_path_factory.mktemp("start")
    return synth_capture(
        str(root / "cap"),
        TRUTH,
        model={"name": "blender", "fps": 24},
        rig="ring8",
        resolution=(60, 80),
        scenario=released([0], [k / 8 for k in range(1, 7)]),
        noise=0.05,
    )


@pytest.fixture(scope="module")
def job(cap, tmp_path_factory):
    """A fit warm-started from the capture's own truth, its start scored (the first step)."""
    s = B.check_settings(dict(B.DEFAULTS, **TRUTH, time_scale=B.physical_time_scale(24), quality=5))
    p = tmp_path_factory.mktemp("init") / "truth.json"
    p.write_text(
        json.dumps({"model": {"name": "blender", "fps": 24}, "blender_cloth": s, "blender_scene": {"fps": 24}})
    )
    cfg = FitConfig(model="blender", quality=5, init=str(p), train_cameras=[0, 2, 4, 6], intervals=False)
    j = FitJob(cap, cfg)
    j.step()
    assert j.state.start_f is not None and np.isfinite(j.state.start_f)
    return j


def _set_best(job, x):
    x = np.asarray(x, dtype=np.float64)
    job.state.best_by_quality[job.state.stage_quality] = [float(job.evaluate(x[None])[0]), x.tolist()]


def _away(job, x):
    """``x`` with its first free setting moved a quarter of its search range."""
    y = np.array(x, dtype=np.float64)
    y[0] = y[0] + 0.25 if y[0] < 0.5 else y[0] - 0.25
    return y


def test_a_fit_whose_start_predicts_the_unseen_cameras_better_says_so_and_keeps_the_start_settings(job):
    truth_x = np.array(job.start_x)
    _set_best(job, _away(job, truth_x))
    fl = report(job)
    assert fl["start_heldout_E_sil_pct"] < fl["heldout_E_sil_pct"]
    assert "no better than what it was given" in fl["start_note"]
    job.state.final = fl  # what the fit's end writes
    r = job.result()
    kind, line = verdict(r)
    assert kind == "start_better" and kind in KINDS and "held-out" in line
    assert r["start_settings"]["tension_stiffness"] == pytest.approx(TRUTH["tension_stiffness"], rel=1e-6)


def test_a_fit_that_predicts_them_clearly_better_than_its_start_has_no_such_note(job):
    truth_x = np.array(job.start_x)
    start_x, start_f = job.start_x, job.state.start_f
    try:
        job.start_x = _away(job, truth_x)
        job.state.start_f = float(job.evaluate(job.start_x[None])[0])
        _set_best(job, truth_x)
        fl = report(job)
        assert fl["start_heldout_E_sil_pct"] > fl["heldout_E_sil_pct"]
        assert "start_note" not in fl
    finally:
        job.start_x, job.state.start_f = start_x, start_f
