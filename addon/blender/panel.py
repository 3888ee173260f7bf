# SPDX-License-Identifier: GPL-3.0-or-later
"""The "Cloth Fit" sidebar tab of the 3D viewport: one small draw function per section."""

from __future__ import annotations

import os

import bpy

from ..core.physics.paper import identifiable
from . import render as R


def draw_rig(layout, scene, p):
    layout.prop(p, "rig_source", expand=True)
    if p.rig_source == "PRESET":
        layout.prop(p, "rig_preset")
    else:
        col = layout.column(align=True)
        for name in ("ring_cameras", "ring_elevation", "ring_distance", "ring_target_z", "ring_fx"):
            col.prop(p, name)
        row = layout.row(align=True)
        row.prop(p, "ring_width")
        row.prop(p, "ring_height")
    layout.operator("clothfit.build_rig", icon="OUTLINER_OB_CAMERA")
    box = layout.box()
    box.label(text="Calibrated cameras", icon="CAMERA_DATA")
    box.prop(p, "cameras_file")
    box.operator("clothfit.import_cameras", icon="IMPORT")
    row = box.row(align=True)
    row.prop(p, "cameras_export_format", text="")
    row.prop(p, "cameras_export_path", text="")
    box.operator("clothfit.export_cameras", icon="EXPORT")
    if p.rig_cameras_json and '"dist"' in p.rig_cameras_json:
        box.label(text="Lens distortion: Blender shows the pinhole view", icon="INFO")


def draw_cloth(layout, scene, p):
    layout.prop(p, "scenario_source", expand=True)
    if p.scenario_source == "SETTINGS":
        col = layout.column(align=True)
        col.prop(p, "cloth_nx")
        col.prop(p, "cloth_side")
        col.prop(p, "cloth_height")
        layout.prop(p, "released_corner")
    elif p.scenario_source == "EMPTIES":
        col = layout.column(align=True)
        col.prop(p, "cloth_nx")
        col.prop(p, "cloth_side")
        col.prop(p, "cloth_height")
    else:
        layout.label(text="Cloth and handles from the capture")
        if p.capture_releases:
            layout.label(text=f"Released: {p.capture_releases}", icon="UNLOCKED")
    layout.operator("clothfit.build_cloth", icon="MESH_GRID")
    if p.cloth_object is not None:
        layout.label(text=f"Cloth: {p.cloth_object.name}", icon="OBJECT_DATA")
    if p.scenario_source == "EMPTIES" or len(p.handles):
        draw_handles(layout, scene, p)


def draw_handles(layout, scene, p):
    """The Empties manipulation: grid vertices linked to (animated) empties."""
    box = layout.box()
    box.label(text="Handles (grid vertex follows empty)", icon="EMPTY_AXIS")
    row = box.row()
    row.template_list("CLOTHFIT_UL_handles", "", p, "handles", p, "handles_index", rows=3)
    col = row.column(align=True)
    col.operator("clothfit.add_handle_empty", icon="ADD", text="")
    col.operator("clothfit.remove_handle", icon="REMOVE", text="")
    row = box.row(align=True)
    row.label(text="New at")
    row.prop(p, "new_handle_row")
    row.prop(p, "new_handle_column")
    if 0 <= p.handles_index < len(p.handles):
        link = p.handles[p.handles_index]
        col = box.column(align=True)
        col.prop(link, "empty")
        r = col.row(align=True)
        r.prop(link, "row")
        r.prop(link, "column")
        r = col.row(align=True)
        r.prop(link, "use_release")
        sub = r.row(align=True)
        sub.enabled = link.use_release
        sub.prop(link, "release_time")


class CLOTHFIT_UL_handles(bpy.types.UIList):
    """One row per handle link: empty, grid vertex, release."""

    def draw_item(self, context, layout, data, item, icon, active_data, active_property, index=0, flt_flag=0):
        row = layout.row(align=True)
        row.prop(item, "empty", text="", emboss=False, icon="EMPTY_AXIS")
        nx = data.cloth_nx
        row.label(text=f"r{item.row} c{item.column} (#{item.row * nx + item.column})")
        row.label(
            text=f"free at {item.release_time:g} s" if item.use_release else "held",
            icon="UNLOCKED" if item.use_release else "LOCKED",
        )


def draw_simulation(layout, scene, p):
    col = layout.column(align=True)
    for name in ("m", "k", "l", "d"):
        col.prop(p, name)
    n = p.cloth_nx * p.cloth_nx
    layout.label(text=f"Cloth mass m x {n} = {1000 * p.m * n:.3g} g")
    if p.scenario_source in ("SETTINGS", "EMPTIES"):
        layout.prop(p, "settle_time")
    layout.prop(p, "frame_times")
    layout.operator("clothfit.simulate", icon="PHYSICS")


def draw_observations(layout, scene, p):
    layout.prop(p, "capture_dir")
    row = layout.row(align=True)
    row.prop(p, "noise")
    row.prop(p, "noise_seed")
    layout.prop(p, "render_engine")
    n_occ = len(R.occluder_objects(scene))
    if n_occ:
        layout.label(text=f"{n_occ} occluder(s) in 'Occluders': written as ignore masks", icon="HOLDOUT_ON")
    layout.operator("clothfit.render_silhouettes", icon="RENDER_STILL")
    layout.operator("clothfit.load_capture", icon="FILE_FOLDER")
    layout.prop(p, "view_frame")
    draw_extract(layout, scene, p)


def draw_extract(layout, scene, p):
    """Silhouettes from real footage (background plates + frames per camera)."""
    box = layout.box()
    box.label(text="From footage", icon="IMAGE_BACKGROUND")
    box.prop(p, "footage_kind", expand=True)
    col = box.column(align=True)
    col.prop(p, "footage_dir")
    if p.footage_kind == "VIDEOS":
        col.prop(p, "footage_plates")
        col.prop(p, "footage_sync")
        row = col.row(align=True)
        row.prop(p, "footage_find_sync")
        if p.footage_find_sync:
            row.prop(p, "footage_flash_time")
    col.prop(p, "extract_calibration")
    col.prop(p, "extract_times")
    col.prop(p, "extract_capture_dir")
    row = box.row(align=True)
    row.prop(p, "extract_threshold_mode", text="")
    if p.extract_threshold_mode == "NUMBER":
        row.prop(p, "extract_threshold")
    box.prop(p, "extract_camera_thresholds")
    row = box.row(align=True)
    row.prop(p, "extract_luma_weight")
    row.prop(p, "extract_shadow_min")
    box.prop(p, "extract_debug")
    box.operator("clothfit.extract_silhouettes", icon="SELECT_SUBTRACT")
    if p.extract_status:
        box.label(text=p.extract_status)


def draw_takes(layout, scene, p):
    """The takes the fit fits together: the loaded capture and the other takes of the same cloth."""
    box = layout.box()
    name = os.path.basename(os.path.normpath(p.capture_dir)) if p.capture_dir else "none"
    box.label(text=f"Capture: {name}", icon="FILE_FOLDER")
    box.label(text="Other takes of this cloth, fitted together:")
    row = box.row()
    row.template_list("CLOTHFIT_UL_takes", "", p, "fit_takes", p, "fit_takes_index", rows=2)
    col = row.column(align=True)
    col.operator("clothfit.add_take", icon="ADD", text="")
    col.operator("clothfit.remove_take", icon="REMOVE", text="")


class CLOTHFIT_UL_takes(bpy.types.UIList):
    """One row per other take: its folder."""

    def draw_item(self, context, layout, data, item, icon, active_data, active_property, index=0, flt_flag=0):
        layout.label(text=item.name or item.directory, icon="FILE_FOLDER")


def draw_fitting(layout, scene, p):
    draw_takes(layout, scene, p)
    col = layout.column(align=True)
    col.prop(p, "fit_model")
    if p.fit_model == "BLENDER":
        col.prop(p, "fit_quality")
        col.prop(p, "fit_bending_model")
        fps = scene.render.fps / scene.render.fps_base
        if len(p.fit_takes):
            col.label(text="Each take at its own frame rate", icon="TIME")
        else:
            col.label(text=f"For this scene's {fps:g} fps", icon="TIME")
    col = layout.column(align=True)
    col.prop(p, "train_cameras")
    col.prop(p, "train_times")
    col.prop(p, "optimizer")
    col.prop(p, "seed")
    col.prop(p, "max_evaluations")
    col.prop(p, "fit_resolution")
    layout.prop(p, "fit_cloth_mass")
    if p.fit_running:
        layout.prop(p, "fit_progress", text="Progress", slider=True)
        layout.label(text=f"Generation {p.fit_generation}, {p.fit_evaluations} evaluations", icon="TIME")
        layout.label(text="Esc cancels and keeps the best")
    else:
        layout.operator("clothfit.fit", icon="PLAY")
    if p.fit_status:
        layout.label(text=p.fit_status)
    if p.fit_verdict and not p.fit_running:
        draw_verdict(layout, p)
    obj = getattr(bpy.context, "active_object", None)
    if obj is not None and any(m.type == "CLOTH" for m in obj.modifiers):
        # the active cloth's own settings by Blender's solver (colliders and all), workers outside the UI
        row = layout.row(align=True)
        row.operator("clothfit.fit_scene_cloth", icon="MOD_CLOTH")
        row.operator("clothfit.apply_scene_fit", text="Apply", icon="CHECKMARK")


VERDICT_ICONS = {
    "at_floor": "CHECKMARK",
    "far_above": "ERROR",
    "at_bound": "ERROR",
    "takes_disagree": "ERROR",
    "start_better": "ERROR",
    "failed": "CANCEL",
}


def draw_verdict(layout, p, width=56):
    """The finished fit's verdict (``core.fitting.verdict``), wrapped over a few lines of a box."""
    import textwrap

    box = layout.box()
    lines = textwrap.wrap(p.fit_verdict, width) or [""]
    box.label(text=lines[0], icon=VERDICT_ICONS.get(p.fit_verdict_kind, "INFO"))
    for line in lines[1:]:
        box.label(text=line)
    for t in p.fit_take_results:  # a fit of several takes: each take's own verdict under the fit's
        lines = textwrap.wrap(f"take {t.name}: {t.verdict or 'no verdict'}", width) or [""]
        box.label(text=lines[0], icon=VERDICT_ICONS.get(t.verdict_kind, "INFO"))
        for line in lines[1:]:
            box.label(text=line)
    if p.fit_intervals:  # how sure each setting is; the undetermined ones flagged
        col = box.column(align=True)
        for line in p.fit_intervals.split("\n"):
            if line.startswith("CAUTION"):  # what the intervals cannot say (a fit far above its floor), wrapped
                for k, part in enumerate(textwrap.wrap(line, width)):
                    col.label(text=part, icon="ERROR" if k == 0 else "NONE")
                continue
            col.label(text=line, icon="ERROR" if line.endswith("UNDETERMINED") else "NONE")


def draw_results(layout, scene, p):
    if not p.fit_has_result:
        layout.label(text="No fit yet")
    elif p.fit_best_blender:
        layout.label(text=f"Best E_all {p.fit_best_error:.4g} (mean E_sil {p.fit_best_pct:.3f} %)")
        draw_blender_cloth(layout, p)
    else:
        layout.label(text=f"Best E_all {p.fit_best_error:.4g} (mean E_sil {p.fit_best_pct:.3f} %)")
        col = layout.column(align=True)
        col.label(text=f"m = {p.fit_best_m:.4g} kg (fixed from the cloth mass)")
        col.label(text=f"k = {p.fit_best_k:.4g} N/m")
        col.label(text=f"l = {1000 * p.fit_best_l:.4g} mm")
        col.label(text=f"d = {p.fit_best_d:.4g} N s/m")
        if p.fit_best_m > 0:
            ident = identifiable({"m": p.fit_best_m, "k": p.fit_best_k, "l": p.fit_best_l, "d": p.fit_best_d})
            box = layout.box()
            box.label(text="Observable from silhouettes:")
            box.label(text=f"k/m = {ident['k_over_m']:.5g} 1/s^2")
            box.label(text=f"d/m = {ident['d_over_m']:.5g} 1/s")
            box.label(text=f"l = {1000 * ident['l']:.4g} mm")
        layout.operator("clothfit.apply_fit", icon="CHECKMARK")
    layout.prop(p, "overlay_source")
    layout.operator("clothfit.overlays", icon="IMAGE_RGB_ALPHA")
    if p.overlay_dir:
        layout.label(text=f"Overlay mean E_sil {p.overlay_error:.3f} %")
    if p.result_path:
        layout.label(text=f"Result: {bpy.path.basename(p.result_path)}", icon="FILE")


def draw_blender_cloth(layout, p):
    from ..core.errors import ClothFitError
    from ..core.jsonio import loads

    try:
        s = loads(p.fit_best_blender, "fitted Blender cloth", expect=dict)
    except ClothFitError:
        layout.label(text="Fitted Blender cloth unreadable", icon="ERROR")
        return
    col = layout.column(align=True)
    col.label(text=f"Blender cloth, quality {s.get('quality')}, {s.get('bending_model', '').lower()} bending")
    for k in (
        "mass",
        "tension_stiffness",
        "compression_stiffness",
        "shear_stiffness",
        "bending_stiffness",
        "tension_damping",
        "shear_damping",
        "bending_damping",
        "air_damping",
        "time_scale",
    ):
        if k in s:
            col.label(text=f"{k.replace('_', ' ').capitalize()} = {s[k]:.4g}")
    if len(p.fit_take_results):  # a fit of several takes: the take Apply replays (empty: the loaded capture's)
        layout.prop_search(p, "apply_take", p, "fit_take_results", icon="FILE_FOLDER")
    layout.operator("clothfit.apply_blender_cloth", icon="MOD_CLOTH")


SECTIONS = (
    ("rig", "Rig", draw_rig),
    ("cloth", "Cloth", draw_cloth),
    ("simulation", "Simulation", draw_simulation),
    ("observations", "Observations", draw_observations),
    ("fitting", "Fitting", draw_fitting),
    ("results", "Results", draw_results),
)


class _Base:
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "Cloth Fit"

    @classmethod
    def poll(cls, context):
        return context.scene is not None and hasattr(context.scene, "clothfit")


class CLOTHFIT_PT_main(_Base, bpy.types.Panel):
    bl_label = "Silhouette Cloth Fit"
    bl_idname = "CLOTHFIT_PT_main"

    def draw(self, context):
        p = context.scene.clothfit
        if p.fit_running:
            self.layout.label(text=f"Fitting... {100 * p.fit_progress:.0f} %", icon="SORTTIME")


def _section_panel(key, label, func):
    def draw(self, context):
        self.layout.use_property_split = False
        func(self.layout, context.scene, context.scene.clothfit)

    return type(
        f"CLOTHFIT_PT_{key}",
        (_Base, bpy.types.Panel),
        {
            "bl_label": label,
            "bl_idname": f"CLOTHFIT_PT_{key}",
            "bl_parent_id": "CLOTHFIT_PT_main",
            "bl_options": set() if key in ("rig", "fitting", "results") else {"DEFAULT_CLOSED"},
            "draw": draw,
            "__doc__": f"Cloth Fit: {label}",
        },
    )


CLASSES = (CLOTHFIT_UL_handles, CLOTHFIT_UL_takes, CLOTHFIT_PT_main) + tuple(_section_panel(*s) for s in SECTIONS)
