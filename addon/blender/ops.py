# SPDX-License-Identifier: GPL-3.0-or-later
"""Operators of the ``clothfit`` namespace (the scripting API: keep the names).

Each operator calls one function of ``api``; a ``ClothFitError`` (bad input) becomes
``self.report({'ERROR'}, message)`` and ``{'CANCELLED'}``, never a traceback; any other exception
is reported the same way as one line naming it (its traceback goes to the system console).

The fit is modal when invoked from the UI: a window-manager timer, one ``job.step()`` (one
optimiser generation) per TIMER event, progress bar + status text + live panel, Esc cancels and
keeps the best so far; the generation itself runs in a worker thread (numpy/numba only), every
bpy call stays on the main thread. ``execute`` (scripts, ``blender -b``: no event loop, timers never fire)
runs the same steps synchronously to completion. The event handling lives in the module
functions ``begin_modal`` / ``modal_tick`` / ``end_modal`` so tests can drive it directly;
``end_modal`` is the one finish routine for finish, cancel and error.
"""

from __future__ import annotations

import os

import bpy
from bpy.props import BoolProperty, EnumProperty, IntProperty, StringProperty

from ..core.errors import ClothFitError
from . import api
from .props import CAMERA_FORMATS


def failure_text(e: BaseException) -> str:
    """One line for the user: bad input as it is; anything else named, its traceback printed to
    the system console (never raised into Blender's UI)."""
    if isinstance(e, (ClothFitError, OSError)):
        return " ".join(str(e).split())
    import traceback

    traceback.print_exception(type(e), e, e.__traceback__)
    return f"unexpected {type(e).__name__}: {' '.join(str(e).split()) or 'no message'} (details in the system console)"


class _ClothFitOperator:
    """Runs ``self.run(context)`` and turns bad input into an error report."""

    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        try:
            msg = self.run(context)
        except Exception as e:  # noqa: BLE001 - an operator reports, never raises
            self.report({"ERROR"}, failure_text(e))
            return {"CANCELLED"}
        if msg:
            self.report({"INFO"}, msg)
        _redraw(context)
        return {"FINISHED"}


def _redraw(context):
    screen = getattr(context, "screen", None)
    if screen is None:
        return
    for area in screen.areas:
        if area.type in {"VIEW_3D", "PROPERTIES"}:
            area.tag_redraw()


class CLOTHFIT_OT_build_rig(_ClothFitOperator, bpy.types.Operator):
    """Create the rig's cameras (preset or ring) in the 'ClothFit Rig' collection"""

    bl_idname = "clothfit.build_rig"
    bl_label = "Build Rig"

    def run(self, context):
        objs = api.build_rig(context.scene)
        W, H = api.S.render_size(context.scene)
        return f"Built a rig of {len(objs)} cameras ({W}x{H})"


class CLOTHFIT_OT_build_cloth(_ClothFitOperator, bpy.types.Operator):
    """Create the cloth grid mesh with one vertex group per handle"""

    bl_idname = "clothfit.build_cloth"
    bl_label = "Build Cloth"

    def run(self, context):
        obj = api.build_cloth(context.scene)
        return f"Built cloth '{obj.name}': {len(obj.data.vertices)} vertices, {len(obj.data.polygons)} triangles"


def _simulate_done(context, r):
    """(warnings, message) after Simulate."""
    return list(r["notes"]), (
        f"Simulated and baked {len(r['frames'])} shapes (frames {r['frames'][0]}.."
        f"{r['frames'][-1]}) in {r['seconds']:.1f} s"
    )


def _render_done(context, cap):
    """(warnings, message) after Render Silhouettes."""
    notes = []
    dropped = cap.meta.get("distortion_dropped")
    if dropped:
        notes.append(
            f"{len(dropped)} camera(s) have lens distortion ({', '.join(dropped[:4])}"
            f"{', ...' if len(dropped) > 4 else ''}): Blender rendered pinhole images, so "
            f"the capture's cameras are written without distortion"
        )
    return notes, f"Rendered {cap.n_cameras} x {cap.n_frames} silhouettes into {cap.root}"


MAX_LISTED_WARNINGS = 3


def _extract_done(context, result):
    """(warnings, message) after Extract Silhouettes."""
    cap, rep = result
    notes = list(rep.get("notes", []))
    warnings = rep.get("warnings", [])
    notes += [f"Extraction: {w}" for w in warnings[:MAX_LISTED_WARNINGS]]
    if len(warnings) > MAX_LISTED_WARNINGS:
        notes.append(
            f"Extraction: {len(warnings) - MAX_LISTED_WARNINGS} more warnings ({len(warnings)} in all) in "
            f"{cap.root}/extract_report.json"
        )
    notes += api.blender_view_cameras(cap.cameras)[1]
    return notes, (
        f"Extracted {cap.n_cameras} x {cap.n_frames} silhouettes into {cap.root} "
        f"({context.scene.clothfit.extract_status})"
    )


class _StepsOperator(_ClothFitOperator):
    """A long operator: modal when invoked from the UI (one step of the API's ``Steps`` per TIMER
    event, progress bar, status text, Esc stops and keeps what is done: ``begin_steps`` /
    ``steps_tick`` / ``end_steps``); ``execute`` (scripts, ``blender -b``) runs every step at once.
    Subclasses give ``steps(context)`` (the one API call) and ``done`` (warnings, message)."""

    done = None
    _run = None

    def run(self, context):
        wm = context.window_manager
        window = getattr(context, "window", None) is not None
        if window:
            wm.progress_begin(0, 100)
        try:
            result = self.steps(context).run((lambda f: wm.progress_update(int(100 * f))) if window else None)
        finally:
            if window:
                wm.progress_end()
        notes, msg = type(self).done(context, result)
        for note in notes:
            self.report({"WARNING"}, note)
        return msg

    def invoke(self, context, event):
        if bpy.app.background or context.window is None:
            return self.execute(context)
        try:
            self._run = begin_steps(context, self.steps(context), self.bl_label, type(self).done)
        except Exception as e:  # noqa: BLE001 - bad input: reported before anything runs
            self.report({"ERROR"}, failure_text(e))
            return {"CANCELLED"}
        context.window_manager.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        if event.type == "Z" and (event.ctrl or event.oskey):
            return {"RUNNING_MODAL"}  # no undo while the run holds the scene's data (undo reloads it)
        state, level, msg = steps_tick(context, self._run, event.type)
        if state == "RUNNING":
            return {"RUNNING_MODAL"} if event.type in {"TIMER", "ESC"} else {"PASS_THROUGH"}
        for note in self._run.notes:
            self.report({"WARNING"}, note)
        self.report({level}, msg)
        return {"FINISHED"} if state == "FINISHED" else {"CANCELLED"}

    def cancel(self, context):  # Blender ends the operator (file load, window closed)
        if self._run is not None and not self._run.steps.finished:
            steps_tick(context, self._run, "ESC")


class CLOTHFIT_OT_simulate(_StepsOperator, bpy.types.Operator):
    """Simulate the mass-spring cloth with the scene's parameters and bake it into shape keys (Esc stops
    before the bake and leaves the scene as it was)"""

    bl_idname = "clothfit.simulate"
    bl_label = "Simulate"
    done = _simulate_done

    def steps(self, context):
        return api.simulate_steps(context.scene, threaded=not bpy.app.background)


class CLOTHFIT_OT_render_silhouettes(_StepsOperator, bpy.types.Operator):
    """Render the cloth's silhouette from every rig camera at every capture time into a capture directory
    (Esc stops and keeps the silhouettes rendered so far)"""

    bl_idname = "clothfit.render_silhouettes"
    bl_label = "Render Silhouettes"
    # UNDO restores the scene's settings; the files written to the capture directory stay on disk
    directory: StringProperty(
        name="Directory",
        default="",
        subtype="DIR_PATH",
        options={"SKIP_SAVE"},
        description="Capture directory (default: the scene's)",
    )
    done = _render_done

    def steps(self, context):
        return api.render_steps(context.scene, self.directory or None)


class CLOTHFIT_OT_extract_silhouettes(_StepsOperator, bpy.types.Operator):
    """Silhouettes from camera footage (background plates + frames per camera) into a capture, then load it
    (Esc stops and writes the cameras extracted so far as a capture)"""

    bl_idname = "clothfit.extract_silhouettes"
    bl_label = "Extract Silhouettes"
    done = _extract_done

    def steps(self, context):
        return api.extract_steps(context.scene)


def _browse(op, context, path):
    """Open Blender's file browser on ``path`` for ``op`` (menus: File > Import / Export); without a
    window (background, scripts) run at once."""
    if bpy.app.background or getattr(context, "window", None) is None:
        return op.execute(context)
    op.filepath = path
    context.window_manager.fileselect_add(op)
    return {"RUNNING_MODAL"}


BROWSE = BoolProperty(
    name="File Browser",
    default=False,
    options={"HIDDEN", "SKIP_SAVE"},
    description="Pick the file in Blender's file browser first (the File menu's entries)",
)


class CLOTHFIT_OT_load_capture(_ClothFitOperator, bpy.types.Operator):
    """Read a capture: its cameras become the rig, observed silhouettes show as camera backgrounds"""

    bl_idname = "clothfit.load_capture"
    bl_label = "Load Capture"
    directory: StringProperty(
        name="Directory",
        default="",
        subtype="DIR_PATH",
        options={"SKIP_SAVE"},
        description="Capture directory (default: the scene's)",
    )
    filepath: StringProperty(
        name="Capture File",
        default="",
        subtype="FILE_PATH",
        options={"SKIP_SAVE"},
        description="The capture's capture.json (or its folder); default: the scene's Capture",
    )
    filter_glob: StringProperty(default="*.json", options={"HIDDEN"}, description="Files the file browser lists")
    browse: BROWSE

    def invoke(self, context, event):
        if not self.browse:
            return self.execute(context)
        p = context.scene.clothfit
        start = os.path.join(bpy.path.abspath(p.capture_dir), "capture.json") if p.capture_dir else "capture.json"
        return _browse(self, context, start)

    def run(self, context):
        cap = api.load_capture(context.scene, self.filepath or self.directory or None)
        for note in api.blender_view_cameras(cap.cameras)[1]:
            self.report({"WARNING"}, note)
        return f"Loaded {cap.root}: {cap.n_cameras} cameras, {cap.n_frames} frames"


class CLOTHFIT_OT_import_cameras(_ClothFitOperator, bpy.types.Operator):
    """Import calibrated cameras (OpenCV YAML/JSON/XML file or folder, COLMAP text model) as the rig"""

    bl_idname = "clothfit.import_cameras"
    bl_label = "Import Cameras"
    filepath: StringProperty(
        name="File",
        default="",
        subtype="FILE_PATH",
        options={"SKIP_SAVE"},
        description="Calibration file or folder (default: the scene's Calibration); in the "
        "file browser, a folder (OpenCV per camera, COLMAP) is picked by entering it",
    )
    filter_glob: StringProperty(
        default="*.yml;*.yaml;*.json;*.xml;*.txt", options={"HIDDEN"}, description="Files the file browser lists"
    )
    browse: BROWSE

    def invoke(self, context, event):
        if not self.browse:
            return self.execute(context)
        return _browse(self, context, bpy.path.abspath(context.scene.clothfit.cameras_file))

    def run(self, context):
        cams, notes = api.import_cameras(context.scene, self.filepath or None)
        for note in notes:
            self.report({"WARNING"}, note)
        W, H = api.S.render_size(context.scene)
        return f"Imported {len(cams)} cameras ({W}x{H}) from {context.scene.clothfit.cameras_file}"


class CLOTHFIT_OT_export_cameras(_ClothFitOperator, bpy.types.Operator):
    """Write the rig's cameras as an OpenCV calibration file/folder, a COLMAP text model or Cloth Fit JSON"""

    bl_idname = "clothfit.export_cameras"
    bl_label = "Export Cameras"
    filepath: StringProperty(
        name="File",
        default="",
        subtype="FILE_PATH",
        options={"SKIP_SAVE"},
        description="Destination (default: the scene's Export To)",
    )
    file_format: EnumProperty(
        name="Format",
        items=[("SCENE", "Scene Setting", "The scene's export format")] + CAMERA_FORMATS,
        default="SCENE",
        options={"SKIP_SAVE"},
        description="File format of the exported cameras",
    )
    check_existing: BoolProperty(
        default=True, options={"HIDDEN", "SKIP_SAVE"}, description="The file browser warns before replacing a file"
    )
    browse: BROWSE

    def invoke(self, context, event):
        if not self.browse:
            return self.execute(context)
        p = context.scene.clothfit
        return _browse(
            self, context, bpy.path.abspath(p.cameras_export_path) if p.cameras_export_path else "calibration.yml"
        )

    def run(self, context):
        fmt = None if self.file_format == "SCENE" else self.file_format
        path, cams, from_blender = api.export_cameras(context.scene, self.filepath or None, fmt)
        if from_blender:
            self.report(
                {"WARNING"},
                f"{len(from_blender)} camera(s) were moved or changed in Blender "
                f"({', '.join(from_blender[:4])}{', ...' if len(from_blender) > 4 else ''}): "
                f"written as Blender shows them (no lens distortion)",
            )
        return f"Exported {len(cams)} cameras to {path}"


class CLOTHFIT_OT_add_handle_empty(_ClothFitOperator, bpy.types.Operator):
    """Add an empty at a grid vertex's rest position and link the vertex to it (manipulation: Empties)"""

    bl_idname = "clothfit.add_handle_empty"
    bl_label = "Add Handle Empty"
    row: IntProperty(name="Row", default=-1, min=-1, options={"SKIP_SAVE"}, description="Grid row (-1: the panel's)")
    column: IntProperty(
        name="Column", default=-1, min=-1, options={"SKIP_SAVE"}, description="Grid column (-1: the panel's)"
    )

    def run(self, context):
        link = api.add_handle_empty(context.scene, self.row, self.column)
        return f"Linked grid vertex row {link.row}, column {link.column} to '{link.empty.name}'"


class CLOTHFIT_OT_remove_handle(_ClothFitOperator, bpy.types.Operator):
    """Remove a handle link (the empty stays unless asked)"""

    bl_idname = "clothfit.remove_handle"
    bl_label = "Remove Handle"
    index: IntProperty(
        name="Index",
        default=-1,
        min=-1,
        options={"SKIP_SAVE"},
        description="Handle to remove (0-based; -1: the active one)",
    )
    delete_empty: BoolProperty(
        name="Delete Empty", default=False, options={"SKIP_SAVE"}, description="Also delete the handle's empty"
    )

    def run(self, context):
        api.remove_handle(context.scene, self.index, self.delete_empty)
        return f"Removed the handle; {len(context.scene.clothfit.handles)} left"


class CLOTHFIT_OT_add_take(_ClothFitOperator, bpy.types.Operator):
    """Add another take of the same cloth (a capture folder): the fit fits it together with the loaded capture"""

    bl_idname = "clothfit.add_take"
    bl_label = "Add Take"
    directory: StringProperty(
        name="Directory",
        default="",
        subtype="DIR_PATH",
        options={"SKIP_SAVE"},
        description="The take's capture folder (capture.json, cameras.json, silhouettes)",
    )

    def invoke(self, context, event):
        if self.directory or bpy.app.background or getattr(context, "window", None) is None:
            return self.execute(context)
        p = context.scene.clothfit
        if p.capture_dir:  # start beside the loaded capture
            self.directory = os.path.dirname(os.path.normpath(bpy.path.abspath(p.capture_dir))) + os.sep
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def run(self, context):
        cap = api.add_take(context.scene, self.directory)
        n = len(context.scene.clothfit.fit_takes)
        return f"Added take {cap.root}: {cap.n_cameras} cameras, {cap.n_frames} frames; {n + 1} takes in the fit"


class CLOTHFIT_OT_remove_take(_ClothFitOperator, bpy.types.Operator):
    """Remove a take from the fit's other takes (its folder stays)"""

    bl_idname = "clothfit.remove_take"
    bl_label = "Remove Take"
    index: IntProperty(
        name="Index",
        default=-1,
        min=-1,
        options={"SKIP_SAVE"},
        description="Take to remove (0-based; -1: the active one)",
    )

    def run(self, context):
        folder = api.remove_take(context.scene, self.index)
        return f"Removed take {folder}; {len(context.scene.clothfit.fit_takes)} other take(s) left"


class CLOTHFIT_OT_apply_fit(_ClothFitOperator, bpy.types.Operator):
    """Write the fitted parameters into the scene and re-simulate"""

    bl_idname = "clothfit.apply_fit"
    bl_label = "Apply Fit"

    def run(self, context):
        api.apply_fit(context.scene)
        p = context.scene.clothfit
        return f"Applied m={p.m:.4g} k={p.k:.4g} l={p.l:.4g} d={p.d:.4g} and re-simulated"


class CLOTHFIT_OT_apply_blender_cloth(_ClothFitOperator, bpy.types.Operator):
    """Put the fitted Blender cloth settings on a Cloth modifier: on the active mesh, or (scene's own cloth
    or no mesh active) on a new cloth with the fit's mesh, pins and release, so Blender replays the fit"""

    bl_idname = "clothfit.apply_blender_cloth"
    bl_label = "Apply Blender Cloth"

    set_fps: bpy.props.BoolProperty(
        name="Set Frame Rate",
        default=True,
        description="Set the scene's frame rate to the one the settings were fitted "
        "for (Blender's cloth moves per frame)",
    )

    def run(self, context):
        obj = context.active_object if context.active_object and context.active_object.type == "MESH" else None
        new, msg = api.apply_blender_cloth(context.scene, obj, set_fps=self.set_fps)
        return msg


class CLOTHFIT_OT_overlays(_ClothFitOperator, bpy.types.Operator):
    """Observed vs. model silhouettes per camera and frame (white agree, red missing, blue extra)"""

    bl_idname = "clothfit.overlays"
    bl_label = "Overlays"

    def run(self, context):
        s = api.make_overlays(context.scene)
        return (
            f"Overlays of {len(s['cameras'])} cameras x {len(s['frames'])} frames: mean E_sil "
            f"{s['mean_E_sil_pct']:.3f} %, contact sheet {s['contact_sheet']}"
        )


# ======================================================= modal long operators


class StepsRun:
    """One long operator's run in the UI: the API's ``Steps``, its timer and what it reports."""

    def __init__(self, steps, label, done=None):
        self.steps, self.label, self.done = steps, label, done
        self.timer = None
        self.notes = []  # warnings to report with the final message

    def status_text(self):
        pct = 100.0 * self.steps.fraction
        return f"{self.label}: {self.steps.text} ({pct:.0f} %) | Esc stops (keeps what is done)"


def begin_steps(context, steps, label, done=None):
    """Start a long operator for the UI. Its first step runs at once (it reads the scene and checks
    the input, so bad input fails here, before anything is written); then progress bar, status
    text, timer. Returns the ``StepsRun``. ``done(context, result) -> (warnings, message)``."""
    run = StepsRun(steps, label, done)
    steps.step()
    ui_begin(context, run, run.status_text())
    return run


def steps_tick(context, run, event_type):
    """Handle one event of a long operator: TIMER does one step, ESC stops and keeps what is done.
    Returns (state, level, message), state RUNNING / FINISHED / CANCELLED; warnings of a finished
    run are in ``run.notes``."""
    if event_type == "ESC":
        kept = run.steps.cancel()
        end_steps(context, run)
        return "CANCELLED", "WARNING", f"{run.label} stopped: {kept}"
    if event_type != "TIMER":
        return "RUNNING", None, None
    try:
        more = run.steps.step()
        if not more and run.done is not None:
            run.notes, msg = run.done(context, run.steps.result)
        else:
            msg = f"{run.label} finished"
    except Exception as e:  # noqa: BLE001 - reported; what the steps wrote so far stays
        end_steps(context, run)
        kept = run.steps.kept
        return "CANCELLED", "ERROR", f"{run.label} failed: {failure_text(e)}" + (f" ({kept})" if kept else "")
    if more:
        context.window_manager.progress_update(int(1000 * run.steps.fraction))
        show_status(context, run.status_text())
        return "RUNNING", None, None
    end_steps(context, run)
    return "FINISHED", "INFO", msg


def end_steps(context, run):
    """The one finish routine of a long operator: timer, progress bar, status text, redraw."""
    ui_end(context, run)
    _redraw(context)


def ui_begin(context, run, text, interval=0.02):
    """Progress bar, timer (``run.timer``, every ``interval`` s) and status text of a modal run (the
    fits, a long operator)."""
    wm = context.window_manager
    wm.progress_begin(0, 1000)
    if context.window is not None:
        run.timer = wm.event_timer_add(interval, window=context.window)
    show_status(context, text)


def ui_end(context, run):
    wm = context.window_manager
    if run.timer is not None:
        wm.event_timer_remove(run.timer)
        run.timer = None
    wm.progress_end()
    show_status(context, None)


# ============================================================= the modal fit


def begin_modal(context, threaded=True):
    """Start a fit for the UI: job, progress bar, status text, timer. Returns the session.

    ``threaded``: each generation runs in a worker thread (the UI stays responsive; bpy is only
    touched on the main thread); otherwise one generation runs inside each TIMER event."""
    sess = api.start_fit(context.scene)
    sess.threaded = threaded
    ui_begin(context, sess, sess.status_text())
    return sess


def modal_tick(context, session, event_type):
    """Handle one event. Returns (state, level, message), state RUNNING / FINISHED / CANCELLED."""
    if event_type == "ESC":
        level, msg = end_modal(context, session, cancelled=True)
        return "CANCELLED", level, msg
    if event_type != "TIMER":
        return "RUNNING", None, None
    try:
        more = api.fit_tick(session) if session.threaded else api.fit_step(session)
        if more is None:  # the worker is still computing this generation
            return "RUNNING", None, None
    except Exception as e:  # noqa: BLE001 - reported, the best so far kept
        text = failure_text(e)
        session.job.fail(text)
        try:
            end_modal(context, session, cancelled=True)
        except Exception as e2:  # noqa: BLE001
            text += f"; and then: {failure_text(e2)}"
        return "CANCELLED", "ERROR", f"Fit stopped: {text}"
    context.window_manager.progress_update(int(1000 * session.job.progress))
    show_status(context, session.status_text())
    _redraw(context)
    if more:
        return "RUNNING", None, None
    level, msg = end_modal(context, session, cancelled=False)
    return "FINISHED", level, msg


def end_modal(context, session, cancelled):
    """The one finish routine: timer, progress bar, status text, result file, panel."""
    ui_end(context, session)
    out = api.finish_fit(session, cancelled)
    _redraw(context)
    return out


def show_status(context, text):
    ws = getattr(context, "workspace", None)
    if ws is not None:
        try:
            ws.status_text_set(text)
        except (AttributeError, RuntimeError):
            pass


class CLOTHFIT_OT_fit(bpy.types.Operator):
    """Fit k, l, d to the capture's silhouettes (one generation per tick; Esc cancels and keeps the best)"""

    bl_idname = "clothfit.fit"
    bl_label = "Fit"
    # UNDO takes the scene back to before the fit (its live status and best parameters); the result
    # file written into the capture directory stays on disk
    bl_options = {"REGISTER", "UNDO"}

    _session = None

    def execute(self, context):
        try:
            _, level, msg = api.run_fit(context.scene)
        except Exception as e:  # noqa: BLE001
            self.report({"ERROR"}, failure_text(e))
            return {"CANCELLED"}
        self.report({level}, msg)
        _redraw(context)
        return {"FINISHED"}

    def invoke(self, context, event):
        if bpy.app.background or context.window is None:
            return self.execute(context)
        try:
            self._session = begin_modal(context)
        except Exception as e:  # noqa: BLE001
            self.report({"ERROR"}, failure_text(e))
            return {"CANCELLED"}
        context.window_manager.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def cancel(self, context):  # Blender ends the operator (file load, window closed)
        if self._session is not None and self._session.job is not None and context.scene.clothfit.fit_running:
            end_modal(context, self._session, cancelled=True)

    def modal(self, context, event):
        state, level, msg = modal_tick(context, self._session, event.type)
        if state == "RUNNING":
            return {"RUNNING_MODAL"} if event.type in {"TIMER", "ESC"} else {"PASS_THROUGH"}
        self.report({level}, msg)
        return {"FINISHED"} if state == "FINISHED" else {"CANCELLED"}


CLASSES = (
    CLOTHFIT_OT_build_rig,
    CLOTHFIT_OT_build_cloth,
    CLOTHFIT_OT_simulate,
    CLOTHFIT_OT_render_silhouettes,
    CLOTHFIT_OT_load_capture,
    CLOTHFIT_OT_extract_silhouettes,
    CLOTHFIT_OT_import_cameras,
    CLOTHFIT_OT_export_cameras,
    CLOTHFIT_OT_add_handle_empty,
    CLOTHFIT_OT_remove_handle,
    CLOTHFIT_OT_add_take,
    CLOTHFIT_OT_remove_take,
    CLOTHFIT_OT_fit,
    CLOTHFIT_OT_apply_fit,
    CLOTHFIT_OT_apply_blender_cloth,
    CLOTHFIT_OT_overlays,
)
