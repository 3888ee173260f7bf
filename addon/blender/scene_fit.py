"""*Fit this cloth's settings*: the active object's Cloth modifier fitted to the scene's capture by
Blender's own solver (``fit --backend blender``), from the UI.

Blender's UI process has imported bpy, so it must not start the workers itself (their children
could not import bpy): the operator saves a copy of the .blend and runs ``python -m clothfit fit ...
--backend blender`` as a separate process (the Python of ``CLOTHFIT_PYTHON``, default this
process's interpreter, which must have the ``bpy`` module: the repository's venv), which starts its
own workers (Ray, or spawned processes). The modal operator polls the fit's checkpoint for progress;
Esc interrupts it (Ctrl-C: the CLI keeps the best so far and writes the result). *Apply Fitted
Cloth* writes the result's settings onto the modifier.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile

import bpy
from bpy.props import FloatProperty, IntProperty

from ..core.errors import ClothFitError
from ..core.fitting.result import FitResult
from ..core.jsonio import read_json
from ..core.location import IMPORT_NAME, PACKAGE_PARENT
from ..core.physics.blender_settings import check_settings
from . import api
from .cloth import cloth_modifier, scene_fps
from .cloth_script import ClothTargetError, apply_cloth_settings
from .ops import show_status, ui_begin, ui_end

RESULT_KEY = "clothfit_scene_fit_result"  # object custom property: the last fit's result JSON


class SceneFitSession:
    """A fit of ``obj``'s Cloth settings running in its own process."""

    timer = None  # the operator's UI timer while it runs modal (ops.ui_begin / ui_end)

    def __init__(
        self,
        scene,
        obj,
        capture_dir,
        budget,
        workers=2,
        frame_zero=None,
        out_dir=None,
        extra=(),
        address=None,
        cache_dir=None,
    ):
        """``workers``: None = the fit's default (the cores); ``address``: a running Ray cluster
        (checked here first: an unreachable one is a one-line error before anything is written);
        ``out_dir``: the working folder, default a new one in ``cache_dir`` (default: the system's
        temporary folder)."""
        if obj is None or cloth_modifier(obj) is None:
            raise ClothFitError(f"object '{getattr(obj, 'name', None)}' has no Cloth modifier: select the cloth")
        capture_dir = bpy.path.abspath(capture_dir or "")
        if not os.path.isfile(os.path.join(capture_dir, "capture.json")):
            raise ClothFitError(f"capture {capture_dir}: no capture.json there (set the capture directory)")
        if address:  # only connect (a socket): never start a cluster from Blender's process
            from ..farm.executors import check_address

            check_address(address)
        self.obj_name = obj.name
        self.out_dir = out_dir or tempfile.mkdtemp(prefix="clothfit_scene_fit_", dir=cache_dir)
        os.makedirs(self.out_dir, exist_ok=True)
        self.blend = os.path.join(self.out_dir, "scene.blend")
        bpy.ops.wm.save_as_mainfile(filepath=self.blend, copy=True)
        self.result_path = os.path.join(self.out_dir, "fit.json")
        self.checkpoint = self.result_path + ".checkpoint.json"
        self.log_path = os.path.join(self.out_dir, "fit.log")
        self.budget = int(budget)
        f0 = scene.frame_start if frame_zero is None else frame_zero
        cmd = [
            os.environ.get("CLOTHFIT_PYTHON") or sys.executable,
            "-m",
            IMPORT_NAME,
            "fit",
            capture_dir,
            "--backend",
            "blender",
            "--blend",
            self.blend,
            "--object",
            obj.name,
            "--frame-zero",
            str(f0),
            "--max-evaluations",
            str(self.budget),
            "--out",
            self.result_path,
            "--quiet",
        ] + list(extra)
        if workers:
            cmd += ["--workers", str(int(workers))]
        if address:
            cmd += ["--address", address]
        self.cmd = cmd
        env = dict(os.environ)
        env["PYTHONPATH"] = PACKAGE_PARENT + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
        self.log = open(self.log_path, "w")
        # Esc sends SIGINT: the child must not inherit an ignored SIGINT from Blender's process (an
        # ignored signal stays ignored across exec, and Python then installs no KeyboardInterrupt)
        self.proc = subprocess.Popen(
            cmd,
            cwd=PACKAGE_PARENT,
            env=env,
            stdout=self.log,
            stderr=subprocess.STDOUT,
            preexec_fn=_default_sigint if os.name == "posix" else None,
        )
        self.cancelled = False

    def progress(self):
        """(evaluations, best mean E_sil %) so far, from the checkpoint (None before the first)."""
        if not os.path.isfile(self.checkpoint):
            return 0, None
        try:
            r = read_json(self.checkpoint, "fit checkpoint").get("result") or {}
        except ClothFitError:
            return 0, None
        return int(r.get("evaluations") or 0), r.get("best_E_sil_mean_pct")

    def running(self):
        return self.proc.poll() is None

    def cancel(self, timeout=120):
        """Esc: interrupt the fit; it keeps the best so far and writes the result."""
        self.cancelled = True
        if self.running():
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()

    def finish(self, scene):
        """The result (and it is remembered on the object), or a one-line error."""
        self.log.close()
        if not os.path.isfile(self.result_path):
            with open(self.log_path) as f:
                lines = [ln for ln in f.read().splitlines() if ln.strip()]
            last = next((ln for ln in reversed(lines) if ln.startswith("error: ")), lines[-1] if lines else "")
            raise ClothFitError(f"the fit wrote no result ({last.removeprefix('error: ') or 'no output'})")
        res = FitResult.from_json(self.result_path, "fit result", need_parameters=False)
        obj = scene.objects.get(self.obj_name)
        if obj is not None:
            obj[RESULT_KEY] = self.result_path
        return res

    def wait(self, scene, poll=None):
        """Run to the end without a UI (scripts, tests)."""
        while self.running():
            if poll is not None and poll(self):
                self.cancel()
                break
            try:
                self.proc.wait(0.5)
            except subprocess.TimeoutExpired:
                pass
        return self.finish(scene)


def _default_sigint():
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def apply_result(obj, result_path=None) -> dict:
    """Write a scene fit's ``blender_cloth`` onto ``obj``'s Cloth modifier (found by type) and set the
    scene's frame rate to the fit's, through ``cloth_script.apply_cloth_settings``: the function the
    script of ``export-blender-cloth --python`` calls. Returns the settings."""
    cl = cloth_modifier(obj) if obj is not None else None
    if cl is None:
        raise ClothFitError(f"object '{getattr(obj, 'name', None)}' has no Cloth modifier")
    path = result_path or obj.get(RESULT_KEY)
    if not path:
        raise ClothFitError(f"object '{obj.name}' has no fitted settings yet (run Fit This Cloth's Settings)")
    res = FitResult.from_json(path, "fit result", need_parameters=False)
    if not res.is_blender:
        raise ClothFitError(f"fit result {path}: no blender_cloth (the fit never evaluated a candidate?)")
    settings = check_settings(res.blender_cloth, f"fit result {path}")
    fps = (res.get("blender_scene") or {}).get("fps") or (res.get("model") or {}).get("fps")
    try:
        apply_cloth_settings(settings, float(fps) if fps else scene_fps(bpy.context.scene), obj.name)
    except ClothTargetError as e:
        raise ClothFitError(str(e)) from None
    return settings


class CLOTHFIT_OT_fit_scene_cloth(bpy.types.Operator):
    """Fit the active cloth's Cloth settings to the capture with Blender's own solver, in worker processes
    started outside Blender's UI (Esc stops and keeps the best)"""

    bl_idname = "clothfit.fit_scene_cloth"
    bl_label = "Fit This Cloth's Settings"
    # UNDO: what the fit changes in the .blend (the object's result path) is undone; the working files
    # it writes (the .blend copy, the result, the log in the cache folder) stay on disk
    bl_options = {"REGISTER", "UNDO"}

    workers: IntProperty(
        name="Workers", default=0, min=0, max=256, description="Worker processes (0: the add-on preferences' Workers)"
    )
    frame_zero: FloatProperty(
        name="Frame of t = 0", default=-1.0, description="Scene frame of capture time 0 (-1: the scene's start frame)"
    )

    _session = None

    def _start(self, context):
        from .prefs import cache_folder, preferences

        p = context.scene.clothfit
        prefs = preferences(context)
        fz = None if self.frame_zero < 0 else self.frame_zero
        return SceneFitSession(
            context.scene,
            context.active_object,
            p.capture_dir,
            p.max_evaluations,
            self.workers or prefs.workers or None,
            fz,
            address=prefs.ray_address.strip() or None,
            cache_dir=cache_folder(context),
        )

    def _report_result(self, context, res):
        self.report(
            {"INFO"},
            f"Fitted {res.get('evaluations')} candidates: E_sil {res.get('best_E_sil_mean_pct') or 0:.3f} %"
            f"{' (stopped: best so far)' if res.get('cancelled') else ''}; Apply Fitted Cloth writes them; "
            f"{api.show_verdict(context.scene, res)}",
        )

    def execute(self, context):
        try:
            res = self._start(context).wait(context.scene)
        except (ClothFitError, OSError) as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        self._report_result(context, res)
        return {"FINISHED"}

    def invoke(self, context, event):
        if bpy.app.background or context.window is None:
            return self.execute(context)
        try:
            self._session = self._start(context)
        except (ClothFitError, OSError) as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        ui_begin(context, self._session, None, interval=0.5)
        context.window_manager.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def _end(self, context):
        ui_end(context, self._session)
        try:
            res = self._session.finish(context.scene)
        except ClothFitError as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        self._report_result(context, res)
        return {"FINISHED"}

    def cancel(self, context):
        if self._session is not None and self._session.running():
            self._session.cancel()

    def modal(self, context, event):
        s = self._session
        if event.type == "ESC":
            s.cancel()
            return self._end(context)
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        n, e = s.progress()
        context.window_manager.progress_update(int(1000 * min(1.0, n / max(1, s.budget))))
        show_status(
            context,
            f"Fitting '{s.obj_name}' with Blender's solver: {n}/{s.budget} candidates"
            + (f", E_sil {e:.3f} %" if e is not None else "")
            + " (Esc: stop, keep the best)",
        )
        if s.running():
            return {"RUNNING_MODAL"}
        return self._end(context)


class CLOTHFIT_OT_apply_scene_fit(bpy.types.Operator):
    """Write the last fitted settings onto the active object's Cloth modifier"""

    bl_idname = "clothfit.apply_scene_fit"
    bl_label = "Apply Fitted Cloth"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        try:
            s = apply_result(context.active_object)
        except ClothFitError as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        self.report(
            {"INFO"},
            f"Cloth settings written (tension {s['tension_stiffness']:.4g}, "
            f"bending {s['bending_stiffness']:.4g}, air {s['air_damping']:.4g})",
        )
        return {"FINISHED"}


CLASSES = (CLOTHFIT_OT_fit_scene_cloth, CLOTHFIT_OT_apply_scene_fit)
