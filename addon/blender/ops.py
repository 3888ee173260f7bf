# SPDX-License-Identifier: GPL-3.0-or-later
"""Operators of the ``clothfit`` namespace (the scripting API: keep the names).

Each operator calls one function of ``api``; a ``ClothFitError`` (bad input) becomes
``self.report({'ERROR'}, message)`` and ``{'CANCELLED'}``, never a traceback.

The fit is modal when invoked from the UI: a window-manager timer, one ``job.step()`` (one
optimiser generation) per TIMER event, progress bar + status text + live panel, Esc cancels and
keeps the best so far; the generation itself runs in a worker thread (numpy/numba only), every
bpy call stays on the main thread. ``execute`` (scripts, ``blender -b``: no event loop, timers never fire)
runs the same steps synchronously to completion. The event handling lives in the module
functions ``begin_modal`` / ``modal_tick`` / ``end_modal`` so tests can drive it directly;
``end_modal`` is the one finish routine for finish, cancel and error.
"""
from __future__ import annotations

import bpy
from bpy.props import StringProperty

from ..core.errors import ClothFitError
from . import api


class _ClothFitOperator:
    """Runs ``self.run(context)`` and turns bad input into an error report."""
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        try:
            msg = self.run(context)
        except (ClothFitError, OSError) as e:
            self.report({"ERROR"}, str(e))
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


class CLOTHFIT_OT_simulate(_ClothFitOperator, bpy.types.Operator):
    """Simulate the mass-spring cloth with the scene's parameters and bake it into shape keys"""
    bl_idname = "clothfit.simulate"
    bl_label = "Simulate"

    def run(self, context):
        r = api.simulate(context.scene)
        return f"Simulated and baked {len(r['frames'])} shapes (frames {r['frames'][0]}..{r['frames'][-1]}) in {r['seconds']:.1f} s"


class CLOTHFIT_OT_render_silhouettes(_ClothFitOperator, bpy.types.Operator):
    """Render the cloth's silhouette from every rig camera at every capture time into a capture directory"""
    bl_idname = "clothfit.render_silhouettes"
    bl_label = "Render Silhouettes"
    directory: StringProperty(name="Directory", default="", subtype="DIR_PATH", options={"SKIP_SAVE"},
                              description="Capture directory (default: the scene's)")

    def run(self, context):
        wm = context.window_manager
        wm.progress_begin(0, 100)
        try:
            cap = api.render_silhouettes(context.scene, self.directory or None,
                                         progress=lambda f: wm.progress_update(int(100 * f)))
        finally:
            wm.progress_end()
        return f"Rendered {cap.n_cameras} x {cap.n_frames} silhouettes into {cap.root}"


class CLOTHFIT_OT_load_capture(_ClothFitOperator, bpy.types.Operator):
    """Read a capture: its cameras become the rig, observed silhouettes show as camera backgrounds"""
    bl_idname = "clothfit.load_capture"
    bl_label = "Load Capture"
    directory: StringProperty(name="Directory", default="", subtype="DIR_PATH", options={"SKIP_SAVE"},
                              description="Capture directory (default: the scene's)")

    def run(self, context):
        cap = api.load_capture(context.scene, self.directory or None)
        distorted = [c.name for c in cap.cameras if c.dist.size and (c.dist != 0).any()]
        if distorted:
            self.report({"WARNING"}, f"{len(distorted)} cameras have lens distortion: their Blender cameras show "
                                     f"the undistorted pinhole (the fit uses the distortion)")
        return f"Loaded {cap.root}: {cap.n_cameras} cameras, {cap.n_frames} frames"


class CLOTHFIT_OT_apply_fit(_ClothFitOperator, bpy.types.Operator):
    """Write the fitted parameters into the scene and re-simulate"""
    bl_idname = "clothfit.apply_fit"
    bl_label = "Apply Fit"

    def run(self, context):
        api.apply_fit(context.scene)
        p = context.scene.clothfit
        return f"Applied m={p.m:.4g} k={p.k:.4g} l={p.l:.4g} d={p.d:.4g} and re-simulated"


class CLOTHFIT_OT_overlays(_ClothFitOperator, bpy.types.Operator):
    """Observed vs. model silhouettes per camera and frame (white agree, red missing, blue extra)"""
    bl_idname = "clothfit.overlays"
    bl_label = "Overlays"

    def run(self, context):
        s = api.make_overlays(context.scene)
        return (f"Overlays of {len(s['cameras'])} cameras x {len(s['frames'])} frames: mean E_sil "
                f"{s['mean_E_sil_pct']:.3f} %, contact sheet {s['contact_sheet']}")


# ============================================================= the modal fit

def begin_modal(context, threaded=True):
    """Start a fit for the UI: job, progress bar, status text, timer. Returns the session.

    ``threaded``: each generation runs in a worker thread (the UI stays responsive; bpy is only
    touched on the main thread); otherwise one generation runs inside each TIMER event."""
    sess = api.start_fit(context.scene)
    sess.threaded = threaded
    wm = context.window_manager
    wm.progress_begin(0, 1000)
    if context.window is not None:
        sess.timer = wm.event_timer_add(0.02, window=context.window)
    _status(context, sess.status_text())
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
    except (ClothFitError, OSError) as e:
        session.job.error = str(e)
        end_modal(context, session, cancelled=True)
        return "CANCELLED", "ERROR", f"Fit stopped: {e}"
    context.window_manager.progress_update(int(1000 * session.job.progress))
    _status(context, session.status_text())
    _redraw(context)
    if more:
        return "RUNNING", None, None
    level, msg = end_modal(context, session, cancelled=False)
    return "FINISHED", level, msg


def end_modal(context, session, cancelled):
    """The one finish routine: timer, progress bar, status text, result file, panel."""
    wm = context.window_manager
    if session.timer is not None:
        wm.event_timer_remove(session.timer)
        session.timer = None
    wm.progress_end()
    _status(context, None)
    out = api.finish_fit(session, cancelled)
    _redraw(context)
    return out


def _status(context, text):
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
    bl_options = {"REGISTER"}

    _session = None

    def execute(self, context):
        try:
            _, level, msg = api.run_fit(context.scene)
        except (ClothFitError, OSError) as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        self.report({level}, msg)
        _redraw(context)
        return {"FINISHED"}

    def invoke(self, context, event):
        if bpy.app.background or context.window is None:
            return self.execute(context)
        try:
            self._session = begin_modal(context)
        except (ClothFitError, OSError) as e:
            self.report({"ERROR"}, str(e))
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
    CLOTHFIT_OT_fit,
    CLOTHFIT_OT_apply_fit,
    CLOTHFIT_OT_overlays,
)
