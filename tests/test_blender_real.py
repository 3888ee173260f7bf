"""Real-footage features of the Blender layer: calibrated cameras in and out, silhouette
extraction from footage, handles driven by (animated) empties. Real ``bpy`` module, factory scene."""

import json
import os

import numpy as np
import pytest
from blender_support import bpy, factory, run_error, small_settings  # noqa: F401

cv2 = pytest.importorskip("cv2")

from clothfit.blender import api  # noqa: E402
from clothfit.blender import scene as S  # noqa: E402
from clothfit.core.footage import calib_io  # noqa: E402
from clothfit.core.observation.camera import Camera, load_rig  # noqa: E402
from clothfit.core.observation.capture import load_capture  # noqa: E402
from clothfit.core.physics.scenario import Handle  # noqa: E402

pytestmark = pytest.mark.usefixtures("factory")


def same_cameras(a, b, atol=1e-6):
    assert [c.name for c in a] == [c.name for c in b]
    for x, y in zip(a, b):
        assert (x.width, x.height) == (y.width, y.height), x.name
        np.testing.assert_allclose(x.K, y.K, rtol=0, atol=atol, err_msg=x.name)
        np.testing.assert_allclose(x.R, y.R, rtol=0, atol=atol, err_msg=x.name)
        np.testing.assert_allclose(x.t, y.t, rtol=0, atol=atol, err_msg=x.name)
        dx = np.zeros(5) if x.dist.size == 0 else x.dist
        dy = np.zeros(5) if y.dist.size == 0 else y.dist
        np.testing.assert_allclose(dx, dy, rtol=0, atol=atol, err_msg=x.name)


def blender_cameras(scene):
    return [S.camera_from_blender(o, scene) for o in S.rig_objects(scene)]


# ====================================================================== cameras


@pytest.mark.parametrize("fmt", ["OPENCV", "COLMAP"])
def test_lab18_round_trip_through_blender(tmp_path, fmt):
    """lab18 -> OpenCV YAML / COLMAP -> Import Cameras -> Blender cameras -> Export Cameras (both
    formats) -> OpenCV: the same cameras to 1e-6; the Blender cameras themselves project the same."""
    scene = bpy.context.scene
    lab = load_rig("lab18")
    src = str(tmp_path / ("lab18.yml" if fmt == "OPENCV" else "lab18_colmap"))
    calib_io.export_cameras(lab, src, "opencv" if fmt == "OPENCV" else "colmap")
    assert bpy.ops.clothfit.import_cameras(filepath=src) == {"FINISHED"}
    assert scene.clothfit.cameras_file == src
    assert [o.name for o in S.rig_objects(scene)] == [c.name for c in lab]
    assert S.render_size(scene) == (640, 480)
    for b, c in zip(blender_cameras(scene), lab):  # Blender's float32 settings show the same camera
        np.testing.assert_allclose(b.K, c.K, rtol=1e-6, atol=1e-4)
        np.testing.assert_allclose(b.R, c.R, atol=1e-6)
        np.testing.assert_allclose(b.t, c.t, atol=1e-6)
    yml, colmap = str(tmp_path / "out" / "rig.yml"), str(tmp_path / "out" / "colmap")
    assert bpy.ops.clothfit.export_cameras(filepath=yml, file_format="OPENCV") == {"FINISHED"}
    assert bpy.ops.clothfit.export_cameras(filepath=colmap, file_format="COLMAP") == {"FINISHED"}
    same_cameras(calib_io.import_cameras(yml), lab)
    same_cameras(calib_io.import_cameras(colmap), lab)
    # and the exported files come back into Blender as the same cameras
    assert bpy.ops.clothfit.import_cameras(filepath=colmap) == {"FINISHED"}
    for b, c in zip(blender_cameras(scene), lab):
        np.testing.assert_allclose(b.K, c.K, rtol=1e-6, atol=1e-4)
        np.testing.assert_allclose(b.t, c.t, atol=1e-6)


def _ring(n=4, w=160, h=120, dist=None, fy_scale=None):
    from clothfit.core.observation.camera import ring_rig

    cams = ring_rig(
        n_per_ring=(n,), elevations_deg=(30.0,), distance=0.5, target=(0, 0, 0.06), width=w, height=h, fx=250.0
    )
    for i, c in enumerate(cams):
        if dist is not None:
            c.dist = np.array(dist) * (1 + 0.1 * i)
        if fy_scale is not None:
            c.K[1, 1] *= fy_scale[i]
    return cams


def test_distortion_and_per_camera_fx_fy_kept_exactly(tmp_path):
    """A real calibration: lens distortion and slightly different fx/fy per camera. Blender shows
    an approximation (one pixel aspect, no distortion); export writes the exact cameras; a camera
    moved in Blender is exported as Blender shows it."""
    scene = bpy.context.scene
    cams = _ring(dist=[-0.1, 0.03, 0.001, -0.0005, 0.0], fy_scale=[1.0, 1.002, 0.999, 1.0005])
    calib_io.export_cameras(cams, str(tmp_path / "calib.yml"))
    got, notes = api.import_cameras(scene, str(tmp_path / "calib.yml"))
    assert any("lens distortion" in n and "cam00" in n for n in notes)
    assert any("fx/fy differ" in n for n in notes)
    par = scene.render.pixel_aspect_y / scene.render.pixel_aspect_x
    shown = blender_cameras(scene)
    for b, c in zip(shown, cams):
        assert b.K[0, 0] == pytest.approx(c.K[0, 0], rel=1e-6)  # fx kept, fy from the common aspect
        assert b.K[0, 0] / b.K[1, 1] == pytest.approx(par, rel=1e-6)
        np.testing.assert_allclose(b.K[:2, 2], c.K[:2, 2], atol=1e-4)
    out = str(tmp_path / "exp.yml")
    path, exported, from_blender = api.export_cameras(scene, out, "OPENCV")
    assert from_blender == []
    same_cameras(calib_io.import_cameras(out), cams)
    stored = json.loads(scene.clothfit.rig_cameras_json)
    assert stored[2]["dist"] == pytest.approx(list(cams[2].dist), abs=0)
    # move one camera: it is exported as Blender shows it now (and said so)
    obj = S.rig_objects(scene)[1]
    obj.location.x += 0.01
    bpy.context.view_layer.update()
    _, exported, from_blender = api.export_cameras(scene, out, "OPENCV")
    assert from_blender == ["cam01"]
    back = calib_io.import_cameras(out)
    assert back[1].center[0] == pytest.approx(cams[1].center[0] + 0.01, abs=1e-6)
    same_cameras([back[0], back[2]], [cams[0], cams[2]])


def test_render_with_distorted_cameras_writes_pinhole_cameras(tmp_path):
    """Blender renders pinhole images: the rendered capture's cameras are the exact imported ones
    without their distortion (and the capture says it dropped it)."""
    scene = bpy.context.scene
    p = small_settings(scene, tmp_path / "cap")
    cams = _ring(dist=[-0.1, 0.03, 0.0, 0.0, 0.0])
    calib_io.export_cameras(cams, str(tmp_path / "calib.yml"))
    assert bpy.ops.clothfit.import_cameras(filepath=str(tmp_path / "calib.yml")) == {"FINISHED"}
    p.frame_times = "0.1"
    for op in ("build_cloth", "simulate", "render_silhouettes"):
        assert getattr(bpy.ops.clothfit, op)() == {"FINISHED"}
    cap = load_capture(tmp_path / "cap")
    assert cap.meta["distortion_dropped"] == [c.name for c in cams]
    for a, c in zip(cap.cameras, cams):
        assert not np.any(a.dist)
        np.testing.assert_allclose(a.K, c.K, atol=1e-12)
        np.testing.assert_allclose(a.R, c.R, atol=1e-12)
    # Blender-rendered overlays of a distorted capture would be wrong: refused, Core works
    bpy.ops.clothfit.load_capture()
    cap_json = tmp_path / "cap" / "cameras.json"
    d = json.loads(cap_json.read_text())
    for c in d["cameras"]:
        c["dist"] = [-0.1, 0.0, 0.0, 0.0, 0.0]
    cap_json.write_text(json.dumps(d))
    p.overlay_source = "BLENDER"
    assert "lens distortion" in run_error("overlays")
    p.overlay_source = "CORE"
    assert bpy.ops.clothfit.overlays() == {"FINISHED"}


def test_import_cameras_bad_input(tmp_path):
    scene = bpy.context.scene
    p = scene.clothfit
    assert "no camera file" in run_error("import_cameras")
    assert "not found" in run_error("import_cameras", filepath=str(tmp_path / "nope.yml"))
    (tmp_path / "junk.yml").write_text("this: [is, not, a calibration\n")
    msg = run_error("import_cameras", filepath=str(tmp_path / "junk.yml"))
    assert "junk.yml" in msg
    (tmp_path / "empty").mkdir()
    assert "empty" in run_error("import_cameras", filepath=str(tmp_path / "empty"))
    # one image size per scene: the error names the camera
    cams = _ring()
    cams[2] = Camera(cams[2].K, cams[2].R, cams[2].t, 320, 240, "cam02")
    calib_io.export_cameras(cams, str(tmp_path / "sizes.yml"))
    msg = run_error("import_cameras", filepath=str(tmp_path / "sizes.yml"))
    assert "camera 'cam02' images 320x240" in msg and "one image size per scene" in msg
    # fx/fy too different for one pixel aspect: names the camera
    calib_io.export_cameras(_ring(fy_scale=[1.0, 1.0, 1.05, 1.0]), str(tmp_path / "par.yml"))
    msg = run_error("import_cameras", filepath=str(tmp_path / "par.yml"))
    assert "camera 'cam02'" in msg and "pixel aspect" in msg
    assert not bpy.data.collections.get(S.RIG_COLLECTION)  # nothing was built
    # export without a rig, to a bad place
    p.cameras_export_path = str(tmp_path / "x.yml")
    assert "no camera in the rig" in run_error("export_cameras")
    calib_io.export_cameras(_ring(), str(tmp_path / "ok.yml"))
    assert bpy.ops.clothfit.import_cameras(filepath=str(tmp_path / "ok.yml")) == {"FINISHED"}
    assert "must end with .json" in run_error("export_cameras", filepath=str(tmp_path / "c.txt"), file_format="JSON")
    (tmp_path / "afile").write_text("x")
    assert "is a file" in run_error("export_cameras", filepath=str(tmp_path / "afile"), file_format="COLMAP")
    assert bpy.ops.clothfit.export_cameras(filepath=str(tmp_path / "dir"), file_format="JSON") == {"FINISHED"}
    same_cameras(calib_io.import_cameras(str(tmp_path / "dir" / "cameras.json")), _ring())


# =================================================================== extraction


def _footage(root, **kw):
    from test_extract import write_footage

    return write_footage(str(root), **kw)


def _iou(a, b):
    return (a & b).sum() / max((a | b).sum(), 1)


def test_extract_silhouettes_operator(tmp_path, capfd):
    scene = bpy.context.scene
    p = scene.clothfit
    cams, truths = _footage(tmp_path / "footage", plates=2)
    os.makedirs(tmp_path / "footage" / "notes")
    cv2.imwrite(str(tmp_path / "footage" / "notes" / "sketch.png"), np.zeros((4, 4), np.uint8))
    p.footage_dir = str(tmp_path / "footage")
    p.capture_dir = str(tmp_path / "cap")
    p.extract_camera_thresholds = "cam01=12"
    p.extract_debug = True
    capfd.readouterr()
    assert bpy.ops.clothfit.extract_silhouettes() == {"FINISHED"}
    out = capfd.readouterr().out
    assert "Warning: Extraction: no scenario given" in out  # the extraction's warnings, reported
    assert "Warning: Extraction: folders with images that are not calibrated cameras" in out
    cap = load_capture(tmp_path / "cap", validate=True)
    assert cap.camera_names == ["cam00", "cam01"] and cap.cloth_mass == 0.0025
    assert cap.meta["extraction"]["thresholds"]["cam01"] == 12.0
    sils = cap.load_silhouettes()
    for ci, c in enumerate(cams):
        for fi in range(3):
            assert _iou(sils[ci][fi], truths[c.name][fi]) > 0.97
    # loaded: the cameras are the rig, the observed silhouettes their backgrounds
    assert [o.name for o in S.rig_objects(scene)] == ["cam00", "cam01"]
    bg = S.rig_objects(scene)[1].data.background_images[0].image
    assert bg.filepath.endswith(os.path.join("cam01", "000.png"))
    assert p.scenario_source == "CAPTURE" and "2 cameras x 3 frames" in p.extract_status
    assert (tmp_path / "cap" / "debug" / "cam00" / "000_7_final.png").is_file()
    rep = json.loads((tmp_path / "cap" / "extract_report.json").read_text())
    assert rep["cameras"]["cam00"]["mode"] == "auto"
    # again with a fixed threshold, overwriting its own extraction
    p.extract_threshold_mode, p.extract_threshold, p.extract_camera_thresholds = "NUMBER", 15.0, ""
    assert bpy.ops.clothfit.extract_silhouettes() == {"FINISHED"}
    rep = json.loads((tmp_path / "cap" / "extract_report.json").read_text())
    assert rep["cameras"]["cam00"]["threshold"] == 15.0 and rep["cameras"]["cam01"]["threshold"] == 15.0


def test_extract_progress_and_many_warnings(tmp_path, capfd):
    scene = bpy.context.scene
    p = scene.clothfit
    _footage(tmp_path / "f", n_cams=3)
    for d in ("a", "b", "c", "d"):  # noise the extractor warns about
        os.makedirs(tmp_path / "f" / d)
        cv2.imwrite(str(tmp_path / "f" / d / "x.png"), np.zeros((4, 4), np.uint8))
    p.footage_dir, p.capture_dir = str(tmp_path / "f"), str(tmp_path / "cap")
    fractions = []
    cap, rep = api.extract_silhouettes(scene, progress=fractions.append)
    assert fractions == pytest.approx([0.0, 1 / 3, 2 / 3, 1.0])
    assert cap.n_cameras == 3 and len(rep["warnings"]) >= 2


def test_extract_bad_input(tmp_path):
    scene = bpy.context.scene
    p = scene.clothfit
    p.capture_dir = str(tmp_path / "cap")
    assert "no footage directory" in run_error("extract_silhouettes")
    p.footage_dir = str(tmp_path / "nowhere")
    assert "footage folder not found" in run_error("extract_silhouettes")
    _footage(tmp_path / "f")
    p.footage_dir = str(tmp_path / "f")
    p.extract_camera_thresholds = "cam99=3"
    assert "no camera 'cam99'" in run_error("extract_silhouettes")
    p.extract_camera_thresholds = "cam01"
    assert "expected CAMERA=VALUE" in run_error("extract_silhouettes")
    p.extract_camera_thresholds = "cam01=-2"
    assert "positive" in run_error("extract_silhouettes")
    p.extract_camera_thresholds = ""
    # a corrupt frame: every problem in one message, nothing written
    with open(tmp_path / "f" / "cam00" / "001.png", "wb") as f:
        f.write(b"not a png")
    msg = run_error("extract_silhouettes")
    assert "001.png" in msg and "nothing written" in msg
    assert not (tmp_path / "cap").exists()
    # the output may not be the footage folder, nor a capture another tool wrote
    p.extract_capture_dir = str(tmp_path / "f")
    assert "is the footage folder" in run_error("extract_silhouettes")
    from clothfit.core.observation.synth import synth_capture
    from clothfit.core.physics.scenario import paper_scenario

    synth_capture(tmp_path / "synth", scenario=paper_scenario(frame_times=[0.1]), cameras=_ring(2), noise=0.0)
    p.extract_capture_dir = str(tmp_path / "synth")
    assert "only overwrites its own extractions" in run_error("extract_silhouettes")
    # no calibration anywhere
    _footage(tmp_path / "g", footage_json=False)
    os.remove(tmp_path / "g" / "cameras.yml")
    p.footage_dir, p.extract_capture_dir, p.extract_times = str(tmp_path / "g"), "", "0.1, 0.2, 0.3"
    assert "no calibration" in run_error("extract_silhouettes")


def test_extract_uses_the_imported_cameras(tmp_path):
    """Footage without a calibration of its own: the cameras imported into the rig are used."""
    scene = bpy.context.scene
    p = scene.clothfit
    cams, _ = _footage(tmp_path / "f", footage_json=False)
    os.rename(tmp_path / "f" / "cameras.yml", tmp_path / "calib.yml")
    assert bpy.ops.clothfit.import_cameras(filepath=str(tmp_path / "calib.yml")) == {"FINISHED"}
    p.footage_dir, p.capture_dir, p.extract_times = str(tmp_path / "f"), str(tmp_path / "cap"), "0.1:0.3:0.1"
    cap, rep = api.extract_silhouettes(scene)
    assert rep["calibration"] == "the scene's imported cameras"
    same_cameras(cap.cameras, cams)
    np.testing.assert_allclose(cap.frame_times, [0.1, 0.2, 0.3])


# ====================================================================== empties


def _key_linear(obj, frames_locs):
    for f, loc in frames_locs:
        obj.location = loc
        obj.keyframe_insert("location", frame=f)
    for fc in S._action_fcurves(obj.animation_data):
        for kp in fc.keyframe_points:
            kp.interpolation = "LINEAR"


DELTA = np.array([0.02, -0.01, 0.015])


def _empties_scene(tmp_path, fps=20, release=None):
    """Small scene, Empties manipulation: corner (0, 0) follows an empty keyed to move linearly by
    DELTA from t = 0 to t = 0.3 s; corner (0, 15) follows a resting empty."""
    scene = bpy.context.scene
    p = small_settings(scene, tmp_path / "cap")
    scene.render.fps, scene.render.fps_base = fps, 1.0
    assert bpy.ops.clothfit.build_rig() == {"FINISHED"}
    assert bpy.ops.clothfit.build_cloth() == {"FINISHED"}
    assert bpy.ops.clothfit.add_handle_empty(row=0, column=0) == {"FINISHED"}
    assert p.scenario_source == "EMPTIES"
    p.new_handle_row, p.new_handle_column = 0, 15
    assert bpy.ops.clothfit.add_handle_empty() == {"FINISHED"}
    moving = p.handles[0].empty
    grid = S.grid_from_object(p.cloth_object)
    rest = grid.rest[0]
    np.testing.assert_allclose(np.array(moving.location), rest, atol=1e-7)
    np.testing.assert_allclose(np.array(p.handles[1].empty.location), grid.rest[15], atol=1e-7)
    f0 = scene.frame_start
    _key_linear(moving, [(f0, rest), (f0 + round(0.3 * fps), rest + DELTA)])
    if release is not None:
        p.handles[0].use_release, p.handles[0].release_time = True, release
    assert bpy.ops.clothfit.build_cloth() == {"FINISHED"}  # vertex groups of the linked vertices
    return scene, p, moving, rest


def test_empty_moves_a_corner(tmp_path):
    scene, p, moving, rest = _empties_scene(tmp_path)
    cloth = p.cloth_object
    assert {"handle_00", "handle_01"} <= {g.name for g in cloth.vertex_groups}
    r = api.simulate(scene)
    assert r["notes"] == []
    times = [0.1, 0.2, 0.3]
    baked = S.baked_positions(cloth, times)
    for k, t in enumerate(times):
        scene.frame_set(S.frame_of_time(scene, t))
        emp = np.array(moving.matrix_world.translation)
        np.testing.assert_allclose(baked[k, 0], emp, atol=1e-6)
        np.testing.assert_allclose(baked[k, 0], rest + DELTA * t / 0.3, atol=1e-6)
        np.testing.assert_allclose(baked[k, 15], S.grid_from_object(cloth).rest[15], atol=1e-6)
    # the handles the simulation used: keys from the start of settling; a resting empty = 1 key
    h0, h1 = r["scenario"].handles
    assert h0.vertex == 0 and h0.times[0] == pytest.approx(-0.3) and h0.times[-1] == pytest.approx(0.3)
    assert h1.vertex == 15 and h1.times.size == 1
    # Render Silhouettes writes the same handles into the capture's scenario
    assert bpy.ops.clothfit.render_silhouettes() == {"FINISHED"}
    d = json.loads((tmp_path / "cap" / "capture.json").read_text())
    hs = [Handle.from_dict(h) for h in d["scenario"]["handles"]]
    assert [h.vertex for h in hs] == [0, 15] and hs[0].release_time is None
    assert d["scenario"]["settle_time"] == pytest.approx(0.3)
    t = np.array([-0.3, -0.1, 0.0, 0.05, 0.1, 0.2, 0.25, 0.3])
    want = rest + DELTA * np.clip(t / 0.3, 0, 1)[:, None]
    np.testing.assert_allclose(hs[0].position(t), want, atol=1e-6)
    # the fitter replays it: the capture's scenario reproduces the bake
    from clothfit.core.physics.models import simulate as core_simulate

    cap = load_capture(tmp_path / "cap")
    res = core_simulate(cap.scenario, [api.params_from_scene(scene)])
    np.testing.assert_allclose(res.positions[0], cap.shapes, atol=1e-6)
    # moving the empty after the bake: rendering refuses the stale bake
    moving.animation_data_clear()
    moving.location = rest + 2 * DELTA
    assert "does not follow the current manipulation" in run_error("render_silhouettes")


def test_empty_release_and_frame_rate(tmp_path):
    """A released link frees its vertex; at 24 fps (capture times not whole frames) the frame
    rate is changed before the empties are read, and said so."""
    scene, p, moving, rest = _empties_scene(tmp_path, fps=20, release=0.1)
    api.simulate(scene)
    baked = S.baked_positions(p.cloth_object, [0.1, 0.3])
    np.testing.assert_allclose(baked[0, 0], rest + DELTA / 3, atol=1e-6)  # held up to 0.1 s
    assert np.linalg.norm(baked[1, 0] - (rest + DELTA)) > 1e-3  # then free
    scene.render.fps = 24
    r = api.simulate(scene)
    assert scene.render.fps == 20 and any("frame rate changed from 24 to 20" in n for n in r["notes"])


def test_empty_links_bad_input(tmp_path):
    scene, p, moving, rest = _empties_scene(tmp_path)
    p.handles[1].row = 16
    msg = run_error("simulate")
    assert "handle #2" in msg and "row 16" in msg and "outside the 16x16 cloth grid" in msg
    p.handles[1].row = 0
    p.handles[1].column = 0
    assert "already linked by handle #1" in run_error("simulate")
    p.handles[1].column = 15
    bpy.data.objects.remove(moving, do_unlink=True)  # a deleted empty
    assert "handle #1" in run_error("simulate") and "has no empty" in run_error("simulate")
    other = p.handles[1].empty
    scene.collection.children[api.HANDLE_COLLECTION].objects.unlink(other)  # still in bpy.data, not in the scene
    p.handles[0].empty = other
    assert "not in the scene" in run_error("simulate")
    assert "outside the 16x16" in run_error("add_handle_empty", row=3, column=40)
    assert bpy.ops.clothfit.remove_handle(index=0) == {"FINISHED"}
    assert bpy.ops.clothfit.remove_handle() == {"FINISHED"}
    assert len(p.handles) == 0
    assert "no handle is linked" in run_error("simulate")
    assert "no handle #1" in run_error("remove_handle")
    assert bpy.ops.clothfit.add_handle_empty(row=2, column=3) == {"FINISHED"}
    name = p.handles[0].empty.name
    assert "already linked" in run_error("add_handle_empty", row=2, column=3)
    assert bpy.ops.clothfit.remove_handle(delete_empty=True) == {"FINISHED"}
    assert name not in bpy.data.objects


def test_empty_links_survive_save_reload(tmp_path):
    scene, p, moving, rest = _empties_scene(tmp_path, release=0.2)
    name = moving.name
    path = str(tmp_path / "h.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.wm.open_mainfile(filepath=path)
    q = bpy.context.scene.clothfit
    assert q.scenario_source == "EMPTIES" and len(q.handles) == 2
    h = q.handles[0]
    assert h.empty is not None and h.empty.name == name
    assert (h.row, h.column, h.use_release) == (0, 0, True) and h.release_time == pytest.approx(0.2)
    assert (q.handles[1].row, q.handles[1].column) == (0, 15)
    assert bpy.ops.clothfit.simulate() == {"FINISHED"}


def test_extract_with_empties_writes_their_handles(tmp_path):
    """Real footage + the set-up's handles given by empties: the capture's scenario is theirs."""
    scene, p, moving, rest = _empties_scene(tmp_path)
    _footage(tmp_path / "f")
    p.footage_dir, p.extract_capture_dir = str(tmp_path / "f"), str(tmp_path / "ext")
    scene.render.fps = 24  # capture times 0.1, 0.2, 0.3 are not whole frames at 24 fps
    cap, rep = api.extract_silhouettes(scene)
    assert not any("paper's manipulation" in w for w in rep["warnings"])
    assert any("frame rate changed from 24 to 20" in n for n in rep["notes"])
    hs = cap.scenario.handles
    assert [h.vertex for h in hs] == [0, 15]
    np.testing.assert_allclose(hs[0].position(np.array([0.1, 0.3])), [rest + DELTA / 3, rest + DELTA], atol=1e-6)
