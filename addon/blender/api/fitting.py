# SPDX-License-Identifier: GPL-3.0-or-later
"""Fitting from the scene: the core ``FitJob`` in a ``FitSession`` that the modal operator steps
(one optimiser generation per step, in a worker thread), the synchronous ``run_fit``, and the
result back into the scene (``apply_fit``: m, k, l, d; ``apply_blender_cloth``: a Cloth modifier)."""

from __future__ import annotations

import contextlib
import os
import time

import bpy
import numpy as np

from ...core import defaults as D
from ...core.errors import ClothFitError
from ...core.fitting.result import FitResult
from ...core.jsonio import dumps
from ...core.observation.camera import select_training
from ...core.physics.paper import Params
from .building import simulate
from .reading import capture_dir, cloth_object, params_to_scene, props, scene_scenario
from .takes import chosen_take, show_take_verdicts, take_captures

RESULT_JSON = "fit_result.json"
RESULT_JSON_BLENDER = "fit_result_blender.json"  # a Blender-cloth fit keeps the paper fit's result
BLENDER_CLOTH_NAME = "Blender Cloth (fitted)"


def fit_config(scene, capture):
    """The core ``FitConfig`` the scene's Fitting settings describe for ``capture``, or for a list of takes
    (the loaded capture first): then each take's training cameras and times are chosen in that take, and
    each take is simulated at its own frame rate (the one its capture declares, else its frame times')."""
    from ...core.fitting.job import FitConfig

    p = props(scene)
    caps = list(capture) if isinstance(capture, (list, tuple)) else [capture]
    cams, times = [], []
    for cap in caps:
        ncam = len(cap.cameras)
        if p.train_cameras > ncam:
            where = f"the capture {cap.root}" if len(caps) > 1 else "the capture"
            raise ClothFitError(f"{p.train_cameras} training cameras asked but {where} has {ncam}")
        cams.append(select_training(cap.cameras, p.train_cameras)[0])
        have = None
        if p.train_times == "PAPER":
            have = [t for t in D.TRAIN_TIMES if np.any(np.abs(cap.frame_times - t) < 1e-6)] or None
        times.append(have)
    train, train_times = (cams[0], times[0]) if len(caps) == 1 else (cams, times)
    if len(caps) > 1 and all(t is None for t in times):
        train_times = None  # every frame of every take
    res = None if p.fit_resolution == "FULL" else [int(x) for x in p.fit_resolution.split("x")]
    model = None
    if p.fit_model == "BLENDER":  # Blender's cloth for this scene's frame rate (one take)
        from ..cloth import scene_fps

        model = {"name": "blender", "quality": int(p.fit_quality), "bending_model": p.fit_bending_model}
        if len(caps) == 1:
            model["fps"] = scene_fps(scene)
    return FitConfig(
        train_cameras=train,
        train_times=train_times,
        optimizer=p.optimizer,
        seed=p.seed,
        max_evaluations=p.max_evaluations,
        resolution=res,
        cloth_mass=p.fit_cloth_mass if p.fit_cloth_mass > 0 else None,
        model=model,
    )


class FitSession:
    """One fit in progress: the core job plus what the UI shows. ``step`` = one generation."""

    def __init__(self, scene, job, result_path):
        self.scene_name = scene.name
        self.job = job
        self.result_path = result_path
        self.timer = None
        self.started = time.time()
        self.threaded = False  # the modal operator runs generations in a worker thread
        self.worker = None  # threading.Thread running one job.step() (threaded mode)
        self._outcome = None  # (more, exception) of the worker's step

    def _work(self):
        try:
            self._outcome = (self.job.step(), None)
        except BaseException as e:  # handed over to the main thread, which re-raises it
            self._outcome = (False, e)

    def wait(self):
        """Block until the running worker step (if any) has finished."""
        if self.worker is not None:
            self.worker.join()

    @property
    def scene(self):
        return bpy.data.scenes.get(self.scene_name)

    def status_text(self):
        j = self.job
        bp = j.best_params
        s = (
            f"Cloth Fit: generation {j.generation}, {j.evaluations}/{j.config.max_evaluations} evaluations, "
            f"best E_all {j.best_error:.4g}"
        )
        if bp:
            s += " | " + _params_text(bp)
        return s + " | Esc cancels (keeps the best)"


def _params_text(bp) -> str:
    """One line of fitted parameters: paper m, k, l, d or the main Blender cloth settings."""
    if "k" in bp:
        return f"m={bp['m']:.3g} k={bp['k']:.4g} l={bp['l']:.4g} d={bp['d']:.3g}"
    return (
        f"tension={bp['tension_stiffness']:.4g} shear={bp['shear_stiffness']:.4g} "
        f"bending={bp['bending_stiffness']:.4g} air={bp['air_damping']:.4g}"
    )


def start_fit(scene, capture=None):
    """Load the capture and the scene's other takes (``takes.take_captures``), build the core ``FitJob`` of
    them all (the loaded capture first); returns a ``FitSession``."""
    from ...core.fitting.job import FitJob
    from ...core.observation.capture import load_capture as core_load

    p = props(scene)
    if p.fit_running:
        raise ClothFitError("a fit is already running in this scene")
    cap = capture or core_load(capture_dir(scene))
    caps = [cap, *take_captures(scene)]
    job = FitJob(caps if len(caps) > 1 else cap, fit_config(scene, caps))
    name = RESULT_JSON if job.par.model.name == "paper" else RESULT_JSON_BLENDER
    sess = FitSession(scene, job, os.path.join(cap.root, name))
    p.fit_running = True
    p.fit_verdict = p.fit_verdict_kind = ""
    p.fit_progress = 0.0
    p.fit_generation = p.fit_evaluations = 0
    p.fit_take_results.clear()
    if len(job.takes) > 1:
        n = sum(len(t.train_cameras) * len(t.train_times) for t in job.takes)
        p.fit_status = f"fitting {len(job.takes)} takes together, {n} images"
    else:
        p.fit_status = f"fitting {len(job.train_cameras)} cameras x {len(job.train_times)} times"
    return sess


def _publish(scene, job):
    p = props(scene)
    p.fit_progress = job.progress
    p.fit_generation = job.generation
    p.fit_evaluations = job.evaluations
    bp = job.best_params
    if bp:
        p.fit_best_error = job.best_error
        p.fit_best_pct = 100.0 * job.best_error / max(1, job.objective.n_images)
        if "k" in bp:
            p.fit_best_m, p.fit_best_k, p.fit_best_l, p.fit_best_d = bp["m"], bp["k"], bp["l"], bp["d"]
            p.fit_best_blender = ""
        else:
            p.fit_best_blender = dumps(bp, indent=None)
        p.fit_has_result = True


def fit_step(session) -> bool:
    """One generation; publishes the live status. Returns False when the job is finished."""
    more = session.job.step()
    _publish(session.scene, session.job)
    return more


def fit_tick(session):
    """Threaded stepping for the modal operator: the generation runs in a worker thread (numpy /
    numba only, no bpy), the main thread publishes. Returns None while a generation is running,
    True after a generation when there are more (the next one is started at once), False when the
    job is finished. Exceptions of the worker are re-raised here, on the main thread."""
    import threading

    if session.worker is not None:
        if session.worker.is_alive():
            return None
        session.worker.join()
        session.worker = None
        more, err = session._outcome
        session._outcome = None
        if err is not None:
            raise err
        _publish(session.scene, session.job)
        if not more:
            return False
    elif session.job.state.finished:
        return False
    else:
        more = None
    session.worker = threading.Thread(target=session._work, name="clothfit-fit-step", daemon=True)
    session.worker.start()
    return more


def finish_fit(session, cancelled=False):
    """Stop (cancel keeps the best), write the result JSON, update the status. -> (level, message)."""
    session.wait()  # a generation still running in the worker finishes first (its result is kept)
    if session.worker is not None:
        session.worker = None
        if session._outcome and session._outcome[1] is None:
            _publish(session.scene, session.job)
    job = session.job
    scene = session.scene
    if cancelled and not job.state.finished:
        job.cancel()
    elif cancelled:
        job.state.cancelled = True
    p = props(scene)
    p.fit_running = False
    _publish(scene, job)
    job.save_result(session.result_path)
    p.result_path = session.result_path
    show_verdict(scene, job.result())
    bp = job.best_params
    if job.state.error:
        p.fit_status = f"failed: {job.state.error}"
        return "ERROR", f"Fit failed: {job.state.error} (result so far: {session.result_path})"
    if bp is None:
        p.fit_status = "cancelled before the first generation: no result"
        return "WARNING", "Fit cancelled before the first generation finished: no result"
    kept = f"best E_sil {p.fit_best_pct:.3f} % after {job.evaluations} evaluations"
    if job.state.cancelled:
        p.fit_status = f"cancelled at generation {job.generation}; {kept} kept"
        return "WARNING", f"Fit cancelled at generation {job.generation}: {kept} kept ({session.result_path})"
    p.fit_status = f"finished: {kept}"
    return "INFO", f"Fit finished: {kept}; {_params_text(bp)} ({session.result_path})"


def show_verdict(scene, result: dict) -> str:
    """Put a fit result's one-line verdict (``core.fitting.verdict``), its settings' intervals
    (``core.fitting.result.interval_lines``) and, for a fit of several takes, each take's verdict
    (``takes.show_take_verdicts``) in the Fitting section; returns the verdict."""
    from ...core.fitting.result import interval_lines
    from ...core.fitting.verdict import verdict

    p = props(scene)
    p.fit_verdict_kind, p.fit_verdict = verdict(result)
    p.fit_intervals = "\n".join(interval_lines(result))
    show_take_verdicts(scene, result)
    return p.fit_verdict


def run_fit(scene, callback=None):
    """Synchronous fit (background mode, scripts). ``callback(session) -> True`` cancels."""
    sess = start_fit(scene)
    cancelled = False
    try:
        while fit_step(sess):
            if callback is not None and callback(sess):
                cancelled = True
                break
    except BaseException as e:
        props(scene).fit_running = False
        if isinstance(e, Exception):  # keep the best so far on disk before reporting the error
            sess.job.fail(str(e) if isinstance(e, ClothFitError) else f"{type(e).__name__}: {e}")
            with contextlib.suppress(ClothFitError, OSError):
                sess.job.save_result(sess.result_path)
        raise
    level, msg = finish_fit(sess, cancelled)
    return sess.job.result(), level, msg


def load_result(scene, path=None) -> FitResult:
    """The scene's fit result (``FitResult``, checked: it must hold parameters)."""
    p = props(scene)
    path = path or (bpy.path.abspath(p.result_path) if p.result_path else os.path.join(capture_dir(scene), RESULT_JSON))
    if not os.path.isfile(path):
        raise ClothFitError(f"no fit result at {path}: run the fit first")
    return FitResult.from_json(path, "fit result")


def apply_fit(scene, result=None):
    """Fitted parameters -> the scene's m, k, l, d; then re-simulate and bake. (A Blender-model
    result goes to a Cloth modifier instead: ``apply_blender_cloth``.)"""
    p = props(scene)
    if result is None and p.fit_best_blender:
        raise ClothFitError("the fit is a Blender-cloth fit: use Apply Blender Cloth")
    if result is None and p.fit_has_result and p.fit_best_k > 0:
        par = Params(p.fit_best_m, p.fit_best_k, p.fit_best_l, p.fit_best_d)
        try:  # prefer the full-precision numbers of the result file
            par = Params.from_dict(load_result(scene)["params"], "fit result")
        except ClothFitError:
            pass
    else:
        res = result if result is not None else load_result(scene)
        par = Params.from_dict(res["params"] if "params" in res else res, "fit result")
    par.check("fitted parameters")
    params_to_scene(scene, par)
    return simulate(scene)


def take_settings(res: FitResult, entry: dict | None):
    """(BlenderModel, ClothSettings values) of a Blender-model fit for one of its takes (``entry``, an item of
    its ``takes``; None: the fit's own): the same cloth at the take's frame rate, its Speed Multiplier scaled
    as the fit scaled it for that take (``core.fitting.evaluate.at_rate``). A paper-model fit is an error."""
    from ...core.fitting.evaluate import at_rate
    from ...core.physics.models import BlenderModel, model_and_row

    model, row = model_and_row(at_rate(dict(res), (entry or {}).get("fps")))
    if not isinstance(model, BlenderModel):
        raise ClothFitError(
            "the fit result is a paper-model fit: it has no Blender cloth settings (fit with the Blender Cloth model)"
        )
    return model, model.settings(row)


def take_scenario(scene, res: FitResult, entry: dict | None):
    """(scenario, the result's part that holds its fitted manipulation) of the take Apply replays: for a fit of
    one take the scene's own scenario and the result; for a take of a fit of several, that take's capture (its
    folder in the result) and its entry."""
    if entry is None:
        return scene_scenario(scene)[0], res
    from ...core.observation.capture import load_capture as core_load

    folder = entry.get("capture")
    if not isinstance(folder, str) or not os.path.isdir(folder):
        raise ClothFitError(f"take {entry.get('take')!r}: its capture folder {folder!r} is not there any more")
    return core_load(folder).scenario, entry


def _replace_fitted_object():
    """Remove the fitted cloth built before, with the empties its moving pins followed."""
    from .. import cloth as BC

    old = bpy.data.objects.get(BLENDER_CLOTH_NAME)
    if old is not None:
        BC.remove_cloth_object(old)


def apply_blender_cloth(scene, obj=None, result=None, set_fps=True, take=None):
    """A Blender-model fit result -> a Cloth modifier. On the scene's own cloth (or with no mesh
    active) a "Blender Cloth (fitted)" object is built beside it from the fit's scenario: the
    same mesh, pins and release as the fit, so Blender replays the fitted motion. A fit of several
    takes replays the take ``take`` (None: the scene's Take; empty: the loaded capture's;
    ``takes.chosen_take``): that take's capture, its fitted handles and frame rate. On any other
    mesh its Cloth modifier (found by type; none is an error) gets the settings, its own pin group
    kept, through ``cloth_script.apply_cloth_settings``, the function the script of
    ``export-blender-cloth --python`` calls. The scene's frame rate is set to the one the settings
    are for (the take's; ``set_fps``), else a differing rate is an error. The message names the nearest of
    Blender's own presets. Returns (object, message)."""
    from ...core.physics.cloth_presets import nearest_preset
    from ...core.physics.scenario import fitted_scenario
    from .. import cloth as BC
    from ..cloth_script import ClothTargetError, apply_cloth_settings

    res = FitResult.from_json(result) if result is not None else load_result(scene)
    entry = chosen_take(scene, res, take)
    model, settings = take_settings(res, entry)
    fps = BC.scene_fps(scene)
    note = f"; take {entry['take']}" if entry is not None else ""
    if abs(fps - model.fps) > 1e-6:
        if not set_fps:
            raise ClothFitError(
                f"the settings are for {model.fps:g} fps but the scene runs at {fps:g} fps: "
                f"Blender's cloth moves per frame, so they would move it differently"
            )
        note += f"; scene frame rate set from {fps:g} to {model.fps:g} fps"
    near = nearest_preset(settings)
    note += f"; nearest Blender preset {near['name']} (typically {near['factor']:.2g}x apart)"
    own = None
    try:
        own = cloth_object(scene)
    except ClothFitError:
        pass
    if obj is None or (own is not None and obj == own):
        sc, manip = take_scenario(scene, res, entry)
        # the pins where the fit put them, on the clock it read (a fitted time_scale stretches their keys)
        sc = fitted_scenario(sc, {"handles": manip.get("handles"), "time_scale": manip.get("time_scale")})
        net, plan = model.plan(sc)
        t_off = manip.get("time_offset_s")
        if t_off:
            note += (
                f"; the fit read the footage {1000 * t_off:+.1f} ms off: the release is at capture time "
                f"{1000 * t_off:+.1f} ms"
            )
        BC.set_scene_fps(scene, model.fps)
        _replace_fitted_object()
        new = BC.build_cloth_object(
            scene, net, plan, settings, name=BLENDER_CLOTH_NAME, frame_start=scene.frame_start, colliders=sc.colliders
        )
        return new, (
            f"Built '{new.name}' with the fitted Cloth settings, pins and release of the scenario "
            f"(t = 0 at frame {scene.frame_start + plan.release_frame}){note}"
        )
    if obj.type != "MESH":
        raise ClothFitError(f"the active object '{obj.name}' is a {obj.type.lower()}, not a mesh")
    try:  # the function the script of `export-blender-cloth --python` calls
        apply_cloth_settings(settings, model.fps, obj.name, scene=scene)
    except ClothTargetError as e:
        raise ClothFitError(str(e)) from None
    pins = BC.cloth_modifier(obj).settings.vertex_group_mass
    return obj, (
        f"Cloth settings applied to '{obj.name}'"
        + (f" (pins: vertex group '{pins}')" if pins else " (no pin group set)")
        + note
    )
