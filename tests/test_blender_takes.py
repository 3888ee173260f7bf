"""Several takes of one cloth in the add-on: the loaded capture and the takes added beside it are fitted
together from the scene; the Fitting section shows each take's verdict; Apply Blender Cloth replays any take
of the result (its capture, its fitted handles, its frame rate)."""

import textwrap

import numpy as np
import pytest
from blender_support import FakeLayout, bpy, factory, run_error  # noqa: F401
from clothfit.blender import api  # noqa: E402
from clothfit.blender import cloth as BC  # noqa: E402
from clothfit.core.fitting.checkpoint import capture_hash  # noqa: E402
from clothfit.core.physics import blender as B  # noqa: E402
from takes_support import make_takes  # noqa: E402

pytest.importorskip("numba")
pytestmark = pytest.mark.usefixtures("factory")


@pytest.fixture(scope="module")
def takes(tmp_path_factory):
    """Two takes of one cloth: one corner let go (24 fps), two corners let go (20 fps)."""
    return make_takes(tmp_path_factory.mktemp("takes"), 4, 5)


def _released_vertices(obj):
    """The vertices of the fitted cloth's release groups (the pins let go over time)."""
    groups = {g.index: g.name for g in obj.vertex_groups}
    return sorted(
        v.index
        for v in obj.data.vertices
        if any(groups[e.group].startswith(f"{BC.PIN_GROUP}_") and e.weight > 0 for e in v.groups)
    )


def _scene_with_takes(takes):
    one, two = takes
    scene = bpy.context.scene
    api.load_capture(scene, one.root)
    assert bpy.ops.clothfit.add_take(directory=two.root) == {"FINISHED"}
    return scene, scene.clothfit


def test_a_take_is_added_once_from_a_capture_folder_and_removed(takes, tmp_path):
    one, two = takes
    scene, p = _scene_with_takes(takes)
    assert [t.directory for t in p.fit_takes] == [two.root] and p.fit_takes[0].name == "two_corners"
    assert "listed already" in run_error("add_take", directory=two.root)
    assert "is the loaded capture" in run_error("add_take", directory=one.root)
    (tmp_path / "not_a_capture").mkdir()
    msg = run_error("add_take", directory=str(tmp_path / "not_a_capture"))
    assert "not_a_capture" in msg and "capture.json" in msg and "\n" not in msg.strip()
    assert bpy.ops.clothfit.remove_take() == {"FINISHED"}
    assert len(p.fit_takes) == 0
    assert "no take #0" in run_error("remove_take")


def test_the_fit_config_chooses_each_takes_cameras_in_that_take_and_leaves_each_its_frame_rate(takes):
    scene, p = _scene_with_takes(takes)
    p.fit_model, p.train_cameras, p.train_times = "BLENDER", 4, "ALL"
    caps = [api.load_capture(scene, takes[0].root), *api.take_captures(scene)]
    cfg = api.fit_config(scene, caps)
    assert cfg.train_cameras == [api.fit_config(scene, c).train_cameras for c in caps]
    assert len(cfg.train_cameras) == 2 and all(len(c) == 4 for c in cfg.train_cameras)
    assert "fps" not in cfg.model  # each take its own rate, the scene's only for a fit of one take
    assert api.fit_config(scene, caps[0]).model["fps"] == BC.scene_fps(scene)
    p.train_cameras = 9
    with pytest.raises(api.ClothFitError, match="9 training cameras asked but the capture .*one_corner has 8"):
        api.fit_config(scene, caps)


def test_two_takes_fitted_from_the_scene_show_each_verdict_and_apply_replays_the_take_chosen(takes):
    one, two = takes
    scene, p = _scene_with_takes(takes)
    p.fit_model, p.fit_quality, p.train_cameras, p.train_times = "BLENDER", 5, 4, "ALL"
    p.max_evaluations = 24
    res, level, msg = api.run_fit(scene)
    entries = res["takes"]
    assert [e["take"] for e in entries] == ["one_corner", "two_corners"]
    assert [e["fps"] for e in entries] == [24.0, 20.0]
    assert [e["capture_hash"] for e in entries] == [capture_hash(one), capture_hash(two)]
    assert level in ("INFO", "WARNING"), msg
    # the Fitting section: each take's verdict under the fit's own
    assert [t.name for t in p.fit_take_results] == ["one_corner", "two_corners"]
    drawn = []
    from clothfit.blender import panel

    panel.draw_fitting(FakeLayout(drawn), scene, p)
    labels = [x for k, x in drawn if k == "label"]
    text = " ".join(labels)
    for e in entries:
        assert e["verdict"] and f"take {e['take']}: {e['verdict'][:20]}" in text
    first = textwrap.wrap(p.fit_verdict, 56)[0]
    fit_line = [i for i, (k, x) in enumerate(drawn) if k == "label" and x == first]
    take_lines = [i for i, (k, x) in enumerate(drawn) if k == "label" and x.startswith("take ")]
    assert len(fit_line) == 1 and len(take_lines) == 2 and min(take_lines) > fit_line[0]
    panel.draw_results(FakeLayout(drawn), scene, p)
    assert ("prop", "apply_take") in drawn and ("list", "CLOTHFIT_UL_takes") in drawn

    # Apply on the second take: its released corners, its frame rate, its Speed Multiplier
    corners = one.scenario.grid.corners()
    bpy.context.view_layer.objects.active = None
    p.apply_take = "two_corners"
    assert bpy.ops.clothfit.apply_blender_cloth() == {"FINISHED"}
    obj = bpy.data.objects[api.BLENDER_CLOTH_NAME]
    assert _released_vertices(obj) == sorted([corners[0], corners[1]])
    assert BC.scene_fps(scene) == 20.0
    got = BC.read_settings(BC.cloth_modifier(obj))
    assert got["time_scale"] == pytest.approx(res["blender_cloth"]["time_scale"] * 24.0 / 20.0, rel=1e-6)
    assert got["tension_stiffness"] == pytest.approx(res["blender_cloth"]["tension_stiffness"], rel=1e-6)
    # the loaded capture's take (the default): its one corner, its 24 fps
    p.apply_take = ""
    assert bpy.ops.clothfit.apply_blender_cloth() == {"FINISHED"}
    obj = bpy.data.objects[api.BLENDER_CLOTH_NAME]
    assert _released_vertices(obj) == [corners[0]]
    assert BC.scene_fps(scene) == 24.0
    assert sum(o.name.startswith(api.BLENDER_CLOTH_NAME) for o in bpy.data.objects) == 1
    # a take the result does not hold: one line naming it
    p.apply_take = "three_corners"
    msg = run_error("apply_blender_cloth")
    assert "three_corners" in msg and "one_corner, two_corners" in msg


def _result_of_two_takes(one, two, offset, t_off):
    """A result of two takes as the fit writes it, the second take's first handle moved by ``offset``."""
    s = B.check_settings({"quality": 5, "time_scale": B.physical_time_scale(24)})
    hs = [{"vertex": h.vertex, "offset_m": [0.0, 0.0, 0.0]} for h in two.scenario.handles]
    hs[0]["offset_m"] = list(offset)
    return {
        "model": {"name": "blender", "fps": 24.0, "quality": 5, "bending_model": "ANGULAR"},
        "blender_cloth": s,
        "blender_scene": {"fps": 24.0},
        "capture_hash": "both",
        "takes": [
            {"take": "one_corner", "capture": one.root, "capture_hash": capture_hash(one), "fps": 24.0},
            {
                "take": "two_corners",
                "capture": two.root,
                "capture_hash": capture_hash(two),
                "fps": 20.0,
                "handles": hs,
                "time_offset_s": t_off,
            },
        ],
    }


def test_apply_moves_the_takes_handles_by_its_fitted_offsets_and_says_its_time_offset(takes):
    one, two = takes
    scene, p = _scene_with_takes(takes)
    offset = (0.004, -0.003, 0.002)
    v = two.scenario.handles[0].vertex
    _, msg = api.apply_blender_cloth(
        scene, None, result=_result_of_two_takes(one, two, (0, 0, 0), 0.0), take="two_corners"
    )
    assert "ms off" not in msg and "take two_corners" in msg and "from 24 to 20 fps" in msg
    assert not [o for o in bpy.data.objects if o.type == "EMPTY"]  # its pins stay where the capture has them
    res = _result_of_two_takes(one, two, offset, 0.006)
    obj, msg = api.apply_blender_cloth(scene, None, result=res, take="two_corners")
    hook = [m.object for m in obj.modifiers if m.type == "HOOK"]
    assert len(hook) == 1 and hook[0].name == f"clothfit_handle_{v}"
    scene.frame_set(scene.frame_end)  # after the settle the pin is held where the fit moved it
    got = np.array(hook[0].matrix_world.translation)
    assert got - two.scenario.grid.rest[v] == pytest.approx(np.array(offset), abs=1e-6)
    assert "+6.0 ms" in msg
    api.apply_blender_cloth(scene, None, result=res, take="two_corners")  # again: replaced, its empty too
    assert [o.name for o in bpy.data.objects if o.type == "EMPTY"] == [f"clothfit_handle_{v}"]
    # a user's own mesh: only the settings, at the chosen take's frame rate
    me = bpy.data.meshes.new("user")
    me.from_pydata([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], [], [(0, 1, 2, 3)])
    user = bpy.data.objects.new("user cloth", me)
    scene.collection.objects.link(user)
    user.modifiers.new("Cloth", "CLOTH")
    BC.set_scene_fps(scene, 30.0)
    _, msg = api.apply_blender_cloth(scene, user, result=res, take="two_corners")
    assert "from 30 to 20 fps" in msg and BC.scene_fps(scene) == 20.0
    assert BC.cloth_modifier(user).settings.time_scale == pytest.approx(B.physical_time_scale(20), rel=1e-6)
    with pytest.raises(api.ClothFitError, match="take 'nope' is not in the fit result"):
        api.apply_blender_cloth(scene, user, result=res, take="nope")
