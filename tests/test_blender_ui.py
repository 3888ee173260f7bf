"""The add-on's UI as Blender users expect it, through the bpy module: preferences, File > Import /
Export entries, file browsers on path properties, tooltips, undo, and the long operators (Render
Silhouettes, Simulate, Extract Silhouettes) modal with a progress bar and Esc, driven headless
through the same functions the operators' modal handlers call (as tests/test_blender_fit.py does)."""

import os
import types

import clothfit  # noqa: E402
import numpy as np
import pytest
from blender_support import addon_preferences, bpy, factory, run_error, small_capture, small_settings  # noqa: F401
from clothfit.blender import api, menus, ops, prefs, registration  # noqa: E402
from clothfit.blender import scene as S  # noqa: E402
from clothfit.core.observation.capture import load_capture  # noqa: E402

pytestmark = pytest.mark.usefixtures("factory")


def _menu_draws(menu):
    return list(menu._dyn_ui_initialize())


# ================================================================= registration


def test_register_unregister_preferences_and_menus():
    imp, exp = bpy.types.TOPBAR_MT_file_import, bpy.types.TOPBAR_MT_file_export
    for _ in range(2):
        assert _menu_draws(imp).count(menus.menu_import) == 1
        assert _menu_draws(exp).count(menus.menu_export) == 1
        assert prefs.ClothFitPreferences.is_registered
        clothfit.unregister()
        assert menus.menu_import not in _menu_draws(imp) and menus.menu_export not in _menu_draws(exp)
        assert not prefs.ClothFitPreferences.is_registered
        clothfit.register()
    assert _menu_draws(imp).count(menus.menu_import) == 1  # registered again: once, not twice


def test_preferences_idname_is_the_add_on_module():
    assert (
        prefs.addon_name("bl_ext.user_default.silhouette_cloth_fit.addon.blender")
        == "bl_ext.user_default.silhouette_cloth_fit"
    )
    assert prefs.addon_name("clothfit.blender") == "clothfit"
    assert prefs.ClothFitPreferences.bl_idname == prefs.ADDON_NAME == "clothfit"
    # not enabled under that name (a checkout): the operators get the defaults
    assert bpy.context.preferences.addons.get("clothfit") is None
    d = prefs.preferences()
    assert (d.workers, d.ray_address, d.cache_dir) == (0, "", "")
    p = addon_preferences()
    p.workers, p.ray_address = 3, "auto"
    assert prefs.preferences().workers == 3 and prefs.preferences().ray_address == "auto"


class _Layout:
    def __init__(self):
        self.ops = []

    def operator(self, idname, text="", **kw):
        mod, name = idname.split(".")
        getattr(getattr(bpy.ops, mod), name).get_rna_type()  # exists
        props = types.SimpleNamespace()
        self.ops.append((idname, text, props))
        return props


def test_file_menu_entries_open_the_file_browser():
    for draw, want in (
        (menus.menu_import, ["clothfit.load_capture", "clothfit.import_cameras"]),
        (menus.menu_export, ["clothfit.export_cameras"]),
    ):
        me = types.SimpleNamespace(layout=_Layout())
        draw(me, bpy.context)
        assert [i for i, _, _ in me.layout.ops] == want
        assert all(p.browse is True and text for _, text, p in me.layout.ops)
    assert [t for _, t, _ in _draw(menus.menu_import)] == ["Cloth Capture (.json)", "Cameras (OpenCV, COLMAP, JSON)"]


def _draw(fn):
    me = types.SimpleNamespace(layout=_Layout())
    fn(me, bpy.context)
    return me.layout.ops


def test_import_capture_by_its_capture_json(small_capture):
    """File > Import > Cloth Capture picks the capture.json; without a window (here) the browser is
    skipped and the file given is loaded; the scene's Capture is its folder."""
    p = bpy.context.scene.clothfit
    path = str(small_capture / "capture.json")
    assert bpy.ops.clothfit.load_capture("INVOKE_DEFAULT", browse=True, filepath=path) == {"FINISHED"}
    assert p.capture_dir == str(small_capture) and p.scenario_source == "CAPTURE"
    assert len(S.rig_objects(bpy.context.scene)) == 4


# ============================================================ properties, undo

PLAIN_TEXT = {
    "name",
    "frame_times",
    "extract_times",
    "extract_camera_thresholds",
    "extract_status",
    "rig_cameras_json",
    "fit_best_blender",
    "fit_status",
    "fit_verdict",
    "fit_verdict_kind",
    "fit_intervals",
    "capture_releases",
    "apply_take",
}


def test_every_path_property_has_a_file_browser():
    rna = bpy.types.Scene.bl_rna.properties["clothfit"].fixed_type
    strings = {q.identifier: q.subtype for q in rna.properties if q.type == "STRING"}
    paths = {k: v for k, v in strings.items() if k not in PLAIN_TEXT}
    assert paths and all(v in ("FILE_PATH", "DIR_PATH") for v in paths.values()), paths
    assert prefs.ClothFitPreferences.bl_rna.properties["cache_dir"].subtype == "DIR_PATH"
    for op in ("render_silhouettes", "load_capture", "import_cameras", "export_cameras"):
        rna = getattr(bpy.ops.clothfit, op).get_rna_type()
        for q in rna.properties:
            if q.identifier in ("filepath", "directory"):
                assert q.subtype in ("FILE_PATH", "DIR_PATH"), (op, q.identifier)


def test_every_property_and_operator_has_a_tooltip():
    base = {q.identifier for q in bpy.types.PropertyGroup.bl_rna.properties} | {
        q.identifier for q in bpy.types.AddonPreferences.bl_rna.properties
    }
    missing = []
    for cls in registration.CLASSES:
        if issubclass(cls, bpy.types.Operator):
            mod, name = cls.bl_idname.split(".")
            rna = getattr(getattr(bpy.ops, mod), name).get_rna_type()
            qs = [q for q in rna.properties if q.identifier != "rna_type"]
            if not rna.description:  # the operator's tooltip: its docstring
                missing.append(cls.__name__)
        elif issubclass(cls, (bpy.types.PropertyGroup, bpy.types.AddonPreferences)):
            rna = cls.bl_rna
            qs = [q for q in rna.properties if q.identifier not in base]
        else:
            continue
        missing += [f"{cls.__name__}.{q.identifier}" for q in qs if not q.description]
    assert not missing, missing


def test_operators_that_change_the_scene_support_undo():
    for cls in registration.CLASSES:
        if issubclass(cls, bpy.types.Operator):
            assert "UNDO" in cls.bl_options, cls.__name__


# ======================================================== modal long operators


def _scene_ready(tmp_path):
    scene = bpy.context.scene
    small_settings(scene, tmp_path / "cap")
    for f in (api.build_rig, api.build_cloth, api.simulate):
        f(scene)
    return scene


def _tick_to_end(run, limit=100000):
    states = []
    for _ in range(limit):
        assert ops.steps_tick(bpy.context, run, "MOUSEMOVE")[0] == "RUNNING"  # other events pass
        state, level, msg = ops.steps_tick(bpy.context, run, "TIMER")
        states.append(run.steps.fraction)
        if state != "RUNNING":
            return state, level, msg, states
    raise AssertionError("the run never ended")


def test_modal_render_runs_to_completion(tmp_path):
    scene = _scene_ready(tmp_path)
    run = ops.begin_steps(bpy.context, api.render_steps(scene), "Render Silhouettes", ops._render_done)
    assert not (tmp_path / "cap" / "sil").exists()  # the first step only read and checked
    state, level, msg, fractions = _tick_to_end(run)
    assert (state, level) == ("FINISHED", "INFO") and msg.startswith("Rendered 4 x 3 silhouettes")
    assert fractions == pytest.approx([1 / 3, 2 / 3, 1.0])  # one capture time per TIMER event
    cap = load_capture(str(tmp_path / "cap"), validate=True)
    assert cap.n_cameras == 4 and cap.n_frames == 3
    assert run.timer is None and not (tmp_path / "cap" / ".render_tmp").exists()


def test_esc_keeps_the_rendered_silhouettes(tmp_path):
    scene = _scene_ready(tmp_path)
    frame0 = scene.frame_current
    run = ops.begin_steps(bpy.context, api.render_steps(scene), "Render Silhouettes", ops._render_done)
    assert ops.steps_tick(bpy.context, run, "TIMER")[0] == "RUNNING"  # capture time 1 of 3 rendered
    state, level, msg = ops.steps_tick(bpy.context, run, "ESC")
    assert (state, level) == ("CANCELLED", "WARNING")
    assert "Render Silhouettes stopped: kept the silhouettes of 1 of 3 capture times (4 files)" in msg
    assert "capture.json not written" in msg
    sil = tmp_path / "cap" / "sil"
    kept = sorted(str(p.relative_to(sil)) for p in sil.rglob("*.png"))
    assert kept == [f"cam{i:02d}/000.png" for i in range(4)]
    assert not (tmp_path / "cap" / "capture.json").exists()
    assert not (tmp_path / "cap" / ".render_tmp").exists() and scene.frame_current == frame0
    assert "capture.json missing" in run_error("load_capture")
    # and a render to the end then completes the capture
    assert bpy.ops.clothfit.render_silhouettes() == {"FINISHED"}
    assert load_capture(str(tmp_path / "cap")).n_frames == 3


def test_modal_render_reports_bad_input_before_going_modal(tmp_path):
    small_settings(bpy.context.scene, tmp_path / "cap")
    api.build_rig(bpy.context.scene)
    api.build_cloth(bpy.context.scene)
    with pytest.raises(Exception, match="not baked"):
        ops.begin_steps(bpy.context, api.render_steps(bpy.context.scene), "Render Silhouettes")
    assert not (tmp_path / "cap").exists()


def test_modal_simulate_and_esc_leaves_the_previous_bake(tmp_path):
    scene = _scene_ready(tmp_path)
    cloth = scene.clothfit.cloth_object
    before = S.baked_positions(cloth, [0.1, 0.2, 0.3])
    scene.clothfit.k *= 3
    run = ops.begin_steps(bpy.context, api.simulate_steps(scene), "Simulate", ops._simulate_done)
    state, level, msg = ops.steps_tick(bpy.context, run, "ESC")
    assert (state, level) == ("CANCELLED", "WARNING") and "the scene is unchanged" in msg
    np.testing.assert_array_equal(S.baked_positions(cloth, [0.1, 0.2, 0.3]), before)
    run = ops.begin_steps(bpy.context, api.simulate_steps(scene), "Simulate", ops._simulate_done)
    state, level, msg, _ = _tick_to_end(run)
    assert (state, level) == ("FINISHED", "INFO") and msg.startswith("Simulated and baked 4 shapes")
    after = S.baked_positions(cloth, [0.1, 0.2, 0.3])
    assert not np.allclose(after, before, atol=1e-5)  # the stiffer cloth moved otherwise


def _footage(root, **kw):
    from test_extract import write_footage

    return write_footage(str(root), **kw)


def test_modal_extract_to_completion_and_esc_keeps_the_cameras_done(tmp_path):
    scene = bpy.context.scene
    p = scene.clothfit
    _footage(tmp_path / "f", n_cams=3)
    p.footage_dir, p.capture_dir = str(tmp_path / "f"), str(tmp_path / "cap")
    run = ops.begin_steps(bpy.context, api.extract_steps(scene), "Extract Silhouettes", ops._extract_done)
    state, level, msg, fractions = _tick_to_end(run)
    assert (state, level) == ("FINISHED", "INFO") and msg.startswith("Extracted 3 x 3 silhouettes")
    assert fractions[-1] == 1.0 and fractions == sorted(fractions)
    assert [o.name for o in S.rig_objects(scene)] == ["cam00", "cam01", "cam02"]
    # Esc once the first camera is done: the cameras extracted by then are written as a capture
    p.capture_dir = str(tmp_path / "cap2")
    run = ops.begin_steps(bpy.context, api.extract_steps(scene), "Extract Silhouettes", ops._extract_done)
    for _ in range(100000):
        assert ops.steps_tick(bpy.context, run, "TIMER")[0] == "RUNNING"
        if run.steps.fraction >= 1 / 3:
            break
    state, level, msg = ops.steps_tick(bpy.context, run, "ESC")
    assert (state, level) == ("CANCELLED", "WARNING") and "Extract Silhouettes stopped: kept" in msg
    cap = load_capture(str(tmp_path / "cap2"), validate=True)
    assert cap.camera_names[0] == "cam00" and 1 <= cap.n_cameras <= 3
    if cap.n_cameras < 3:
        assert f"capture of the {cap.n_cameras} of 3 cameras" in msg
        assert cap.meta["extraction"]["stopped"] == {"cameras_done": cap.n_cameras, "cameras": 3}
    else:  # the worker finished the last camera before the stop
        assert "the whole capture" in msg


def test_extract_operator_runs_to_completion_from_a_script(tmp_path):
    p = bpy.context.scene.clothfit
    _footage(tmp_path / "f", n_cams=2)
    p.footage_dir, p.capture_dir = str(tmp_path / "f"), str(tmp_path / "cap")
    assert bpy.ops.clothfit.extract_silhouettes("INVOKE_DEFAULT") == {"FINISHED"}  # -b: no modal, to the end
    assert os.path.isfile(tmp_path / "cap" / "capture.json")
