"""``api.read_scene``: the Blender scene read once into core objects (scenario, rig, grid, params,
capture directory, bake), and the render path that works on what it read."""

import dataclasses
import os

import numpy as np
import pytest
from blender_support import bpy, factory, small_settings  # noqa: F401
from clothfit.blender import api  # noqa: E402
from clothfit.blender import scene as S  # noqa: E402
from clothfit.blender.api import rendering  # noqa: E402
from clothfit.core import defaults as D  # noqa: E402
from clothfit.core.errors import ClothFitError  # noqa: E402
from clothfit.core.observation.camera import load_rig  # noqa: E402
from clothfit.core.physics.scenario import ClothGrid, paper_scenario  # noqa: E402

pytestmark = pytest.mark.usefixtures("factory")


def _same_cameras(a, b, atol=1e-9):
    assert [c.name for c in a] == [c.name for c in b]
    for x, y in zip(a, b):
        assert (x.width, x.height) == (y.width, y.height)
        np.testing.assert_allclose(x.K, y.K, atol=atol)
        np.testing.assert_allclose(x.R, y.R, atol=atol)
        np.testing.assert_allclose(x.t, y.t, atol=atol)


def test_default_scene_reads_the_paper_scenario_and_the_lab18_rig():
    scene = bpy.context.scene
    api.build_rig(scene)
    api.build_cloth(scene)
    inp = api.read_scene(scene, rig=True)
    # the defaults: the paper's 16x16 sheet, its times, corner release and ground truth
    want = paper_scenario(
        ClothGrid(D.GRID_N, side=D.CLOTH_SIDE, height=D.CLOTH_HEIGHT),
        frame_times=inp.times,
        released_corner=D.RELEASED_CORNER,
    )
    want.settle_time = float(scene.clothfit.settle_time)
    assert inp.times == pytest.approx(D.FRAME_TIMES)
    assert (inp.grid.nx, inp.grid.ny) == (D.GRID_N, D.GRID_N)
    np.testing.assert_allclose(inp.scenario.frame_times, want.frame_times)
    assert inp.scenario.settle_time == pytest.approx(want.settle_time)
    assert [(h.vertex, h.release_time) for h in inp.scenario.handles] == [
        (h.vertex, h.release_time) for h in want.handles
    ]
    for h, w in zip(inp.scenario.handles, want.handles):
        np.testing.assert_allclose(h.position(inp.scenario.frame_times), w.position(want.frame_times), atol=1e-6)
    # the rig is the lab18 preset exactly (float64, from the stored cameras), and within float32 of
    # what the Blender cameras show
    _same_cameras(inp.cameras, load_rig(D.DEFAULT_RIG))
    _same_cameras(inp.cameras, S.rig_cameras(scene), atol=1e-3)
    assert [o.name for o in inp.camera_objects] == [c.name for c in inp.cameras]
    assert inp.params.as_dict() == pytest.approx(D.GT_PARAMS, rel=1e-6)
    assert inp.cloth == scene.clothfit.cloth_object and inp.shapes is None and inp.capture_dir is None
    # the same as the readers one by one (what the API used before it read once)
    sc, _ = api.scene_scenario(scene, list(inp.times))
    np.testing.assert_allclose(
        [h.position(sc.frame_times) for h in sc.handles],
        [h.position(inp.scenario.frame_times) for h in inp.scenario.handles],
    )
    with pytest.raises(dataclasses.FrozenInstanceError):
        inp.times = (0.0,)


def test_bake_and_capture_directory(tmp_path):
    scene = bpy.context.scene
    small_settings(scene, tmp_path / "cap")
    api.build_rig(scene)
    api.build_cloth(scene)
    with pytest.raises(ClothFitError, match=r"not baked at t = 0\.100 s \(3 capture times missing\)"):
        api.read_scene(scene, baked=True)
    api.simulate(scene)
    inp = api.read_scene(scene, capture=True, baked=True)
    assert inp.capture_dir == os.path.normpath(str(tmp_path / "cap"))
    np.testing.assert_allclose(inp.shapes, S.baked_positions(inp.cloth, [0.1, 0.2, 0.3]))
    assert api.read_scene(scene, out_dir=str(tmp_path / "other")).capture_dir == str(tmp_path / "other")


@pytest.mark.parametrize(
    "prop, value, msg",
    [
        ("frame_times", "0.1:zero:0.1", "frame times '0.1:zero:0.1'"),
        ("frame_times", "", "frame times are empty"),
        ("capture_dir", "//relative_capture", "relative to the .blend file, which is not saved yet"),
        ("scenario_source", "CAPTURE", "capture not found"),
    ],
)
def test_bad_property_is_a_one_line_error(tmp_path, prop, value, msg):
    scene = bpy.context.scene
    p = small_settings(scene, tmp_path / "nowhere")
    api.build_cloth(scene)
    setattr(p, prop, value)
    with pytest.raises(ClothFitError) as ei:
        api.read_scene(scene, capture=True)
    text = str(ei.value)
    assert msg in text and "\n" not in text, text


def test_missing_cloth_and_rig_are_one_line_errors(tmp_path):
    scene = bpy.context.scene
    small_settings(scene, tmp_path / "c")
    with pytest.raises(ClothFitError, match="cloth object is missing"):
        api.read_scene(scene)
    api.build_cloth(scene)
    with pytest.raises(ClothFitError, match="no camera in the rig"):
        api.read_scene(scene, rig=True)


def test_render_reads_the_scene_once_up_front(tmp_path, monkeypatch):
    """One read per render, and what it read is what is rendered: settings changed while the render
    runs (between its steps) do not leak into it."""
    scene = bpy.context.scene
    p = small_settings(scene, tmp_path / "cap")
    for f in (api.build_rig, api.build_cloth, api.simulate):
        f(scene)
    reads = []
    real = rendering.read_scene

    def counting(*a, **k):
        reads.append(k)
        return real(*a, **k)

    monkeypatch.setattr(rendering, "read_scene", counting)
    steps = api.render_steps(scene)
    assert steps.step()  # the read (and the checks) come first
    p.frame_times = "0.1, 0.2"  # the user edits the scene while the render runs
    p.capture_dir = str(tmp_path / "elsewhere")
    while steps.step():
        pass
    cap = steps.result
    assert len(reads) == 1 and reads[0]["rig"] and reads[0]["baked"]
    assert cap.n_frames == 3 and cap.root == str(tmp_path / "cap")
    assert not (tmp_path / "elsewhere").exists()
