"""The fit operator's step path: the modal handler functions driven with TIMER / ESC events."""

import json
import time

import pytest
from blender_support import bpy, factory, small_capture, small_settings  # noqa: F401
from clothfit.blender import api, ops  # noqa: E402
from clothfit.core.fitting.result import interval_lines

pytestmark = pytest.mark.usefixtures("factory")


def _start(scene, capture_dir, budget=40, threaded=False):
    p = small_settings(scene, capture_dir)
    p.max_evaluations = budget
    return ops.begin_modal(bpy.context, threaded=threaded)


def _tick_until_generation(sess, n):
    """TIMER events until the job has done ``n`` generations (threaded: the worker needs time)."""
    for _ in range(20000):
        if sess.job.generation >= n and (sess.worker is None or not sess.worker.is_alive()):
            return
        assert ops.modal_tick(bpy.context, sess, "TIMER")[0] == "RUNNING"
        time.sleep(0.001)
    raise AssertionError("no progress")


@pytest.mark.parametrize("threaded", [False, True])
def test_modal_steps_to_completion(small_capture, threaded):
    scene = bpy.context.scene
    sess = _start(scene, small_capture, budget=120, threaded=threaded)  # initial population + a few generations
    p = scene.clothfit
    assert p.fit_running
    seen = []  # (generation, best error shown in the panel) after each tick
    for _ in range(20000):
        assert ops.modal_tick(bpy.context, sess, "MOUSEMOVE")[0] == "RUNNING"  # other events pass through
        state, level, msg = ops.modal_tick(bpy.context, sess, "TIMER")
        seen.append((p.fit_generation, p.fit_best_error))
        if state != "RUNNING":
            break
        if threaded:
            time.sleep(0.001)
    assert state == "FINISHED" and level == "INFO" and "Fit finished" in msg
    gens = sorted({g for g, _ in seen})
    assert gens[-1] == sess.job.generation >= 2
    if not threaded:
        assert len(seen) == sess.job.generation  # exactly one generation per TIMER event
    else:
        assert len(seen) > sess.job.generation  # ticks while the worker computes
    # the panel's live fields followed the generations; the best never got worse
    errs = [e for g, e in seen if g > 0]
    assert all(b <= a + 1e-12 for a, b in zip(errs, errs[1:]))
    assert not p.fit_running and p.fit_progress == 1.0 and p.fit_evaluations == sess.job.evaluations
    assert sess.timer is None and sess.worker is None
    res = json.loads((small_capture / "fit_result.json").read_text())
    assert res["finished"] and not res["cancelled"]
    # the fit section shows the result's one-line verdict
    assert p.fit_verdict == res["verdict"] and p.fit_verdict_kind == res["verdict_kind"] != "unfinished"
    assert p.fit_intervals.split("\n") == interval_lines(res)  # and how sure each setting is (or why not)


@pytest.mark.parametrize("threaded", [False, True])
def test_escape_cancels_and_keeps_best(small_capture, threaded):
    scene = bpy.context.scene
    sess = _start(scene, small_capture, budget=10_000, threaded=threaded)
    _tick_until_generation(sess, 2)
    best = dict(sess.job.best_params)
    state, level, msg = ops.modal_tick(bpy.context, sess, "ESC")
    assert state == "CANCELLED" and level == "WARNING"
    assert f"cancelled at generation {sess.job.generation}" in msg and "kept" in msg
    p = scene.clothfit
    assert not p.fit_running and p.fit_has_result
    assert p.fit_best_k == pytest.approx(best["k"], rel=1e-6)
    res = json.loads((small_capture / "fit_result.json").read_text())
    assert res["cancelled"] and res["params"] == pytest.approx(best)
    # the kept result can be applied (needs a cloth: build it)
    bpy.ops.clothfit.build_cloth()
    assert bpy.ops.clothfit.apply_fit() == {"FINISHED"}
    assert p.k == pytest.approx(best["k"], rel=1e-6)


def test_cancel_before_first_generation(small_capture):
    sess = _start(bpy.context.scene, small_capture)
    state, level, msg = ops.modal_tick(bpy.context, sess, "ESC")
    assert state == "CANCELLED" and level == "WARNING" and "no result" in msg
    assert not bpy.context.scene.clothfit.fit_running


def test_second_fit_while_running_is_refused(small_capture):
    sess = _start(bpy.context.scene, small_capture)
    with pytest.raises(RuntimeError, match="already running"):
        bpy.ops.clothfit.fit()
    ops.end_modal(bpy.context, sess, cancelled=True)


def test_background_invoke_runs_synchronously(small_capture):
    """Under -b (no event loop) INVOKE_DEFAULT falls back to execute and finishes."""
    assert bpy.app.background
    small_settings(bpy.context.scene, small_capture)
    assert bpy.ops.clothfit.fit("INVOKE_DEFAULT") == {"FINISHED"}
    assert bpy.context.scene.clothfit.fit_has_result


def test_run_fit_callback_cancel(small_capture):
    small_settings(bpy.context.scene, small_capture).max_evaluations = 10_000
    res, level, msg = api.run_fit(bpy.context.scene, callback=lambda s: s.job.generation >= 1)
    assert res["cancelled"] and level == "WARNING"
    assert bpy.context.scene.clothfit.fit_verdict_kind == "unfinished"


def test_escape_while_worker_runs_waits_and_keeps_its_generation(small_capture):
    sess = _start(bpy.context.scene, small_capture, budget=10_000, threaded=True)
    _tick_until_generation(sess, 1)
    assert ops.modal_tick(bpy.context, sess, "TIMER")[0] == "RUNNING"  # starts generation 2 in the worker
    state, level, msg = ops.modal_tick(bpy.context, sess, "ESC")
    assert state == "CANCELLED" and level == "WARNING"
    assert sess.worker is None and not sess.job.step()  # the job is finished (cancelled)
    p = bpy.context.scene.clothfit
    assert p.fit_generation == sess.job.generation and p.fit_best_error == pytest.approx(sess.job.best_error)
