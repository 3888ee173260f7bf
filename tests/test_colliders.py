"""Colliders in the core: a scenario or capture declares a plane or a box (Blender's collision settings),
the blender model's cloth lands on it instead of falling through, and bad declarations are refused in
one line naming the file and the value."""

import json

import numpy as np
import pytest
from clothfit.core import defaults as D
from clothfit.core.errors import ClothFitError
from clothfit.core.observation import camera as C
from clothfit.core.observation.capture import load_capture
from clothfit.core.observation.synth import synth_capture
from clothfit.core.physics import blender as B
from clothfit.core.physics.colliders import Collisions
from clothfit.core.physics.handling import handling_scenario
from clothfit.core.physics.models import BlenderModel, PaperModel
from clothfit.core.physics.scenario import ClothGrid, Handle, Scenario

FPS = 24.0
TIMES = np.arange(1, 25) / FPS


def _drag(n=9, **kw):
    sc = handling_scenario("drag", ClothGrid(n, n, 0.10), TIMES, **kw)
    return Scenario(sc.grid, sc.handles, sc.frame_times, 0.25, sc.gravity, sc.colliders)


def _settings():
    return B.check_settings({"time_scale": B.physical_time_scale(FPS)})


def _run(sc, backend="auto"):
    r = BlenderModel(FPS, 5).simulate(sc, B.settings_row(_settings())[None], backend)
    assert not r.exploded[0], r.reason
    return r.positions[0]


def test_the_dragged_cloth_lands_on_the_table_and_without_it_falls_through():
    sc = _drag()
    top = sc.colliders.colliders[0].centre[2]
    on = _run(sc)
    off = _run(Scenario(sc.grid, sc.handles, sc.frame_times, sc.settle_time, sc.gravity))
    gap = on[..., 2].min(axis=1) - top
    assert gap.min() > 0.0  # never below the table
    # at rest it lies about Blender's 8/9 of (distance_min + thickness_outer) above it
    rest = (D.DRAG_CLOTH_DISTANCE + D.DRAG_TABLE_DISTANCE) * 8.0 / 9.0
    assert abs(np.median(on[-1, :, 2] - top) - rest) < 0.25 * rest
    assert (off[-1, :, 2] - top).min() < -0.02  # the same cloth with no table goes through it
    # the dragged corner pulls the cloth along the table
    assert np.linalg.norm(on[-1].mean(0)[:2] - on[0].mean(0)[:2]) > 0.01


def test_the_numpy_reference_keeps_the_cloth_on_the_table_too():
    sc = _drag(n=6)
    top = sc.colliders.colliders[0].centre[2]
    ref = _run(sc, "numpy")
    assert (ref[..., 2] - top).min() > 0.0
    assert np.abs(ref - _run(sc)).max() < 0.01  # float64 solver against the float32 kernel


def test_a_cloth_dropped_on_a_narrower_box_lies_on_its_top_and_hangs_over_its_edges():
    grid = ClothGrid(11, 11, 0.10)
    top = grid.rest[0, 2] - 0.02
    cols = Collisions.from_dicts(
        [{"type": "box", "centre": [0.0, 0.0, top - 0.05], "size": [0.05, 0.05, 0.1], "distance": 0.003}],
        {"distance_min": 0.003},
    )
    hs = [Handle(v, [0.0], grid.rest[v][None], 0.0) for v in grid.corners()]
    sc = Scenario(grid, hs, TIMES, 0.1, colliders=cols)
    last = _run(sc)[-1]
    centre = last[5 * 11 + 5]
    assert 0.0 < centre[2] - top < 0.01  # on the box's top
    assert last[grid.corners(), 2].max() < top - 0.01  # the corners hang down over the edges
    assert cols.colliders[0].signed_distance(last).min() > 0.0  # nothing inside the box


def test_the_paper_model_refuses_a_scenario_with_colliders():
    with pytest.raises(ClothFitError, match="paper model has no colliders"):
        PaperModel().simulate(_drag(), [[0.0025, 20.0, 0.01, 0.01]])


def test_a_capture_declares_its_colliders_and_reads_them_back(tmp_path):
    sc = _drag(n=5)
    cams = [c.resized(20, 30) for c in C.load_rig("lab18")[:2]]
    synth_capture(str(tmp_path / "cap"), _settings(), scenario=sc, cameras=cams, noise=0.0, model={"name": "blender"})
    cap = load_capture(str(tmp_path / "cap"))
    got = cap.scenario.colliders
    assert got is not None and got.settings_dict() == sc.colliders.settings_dict()
    assert [c.to_dict() for c in got.colliders] == [c.to_dict() for c in sc.colliders.colliders]
    plain = Scenario(sc.grid, sc.handles, sc.frame_times, sc.settle_time, sc.gravity)
    assert "colliders" not in plain.to_dict() and "collision_settings" not in plain.to_dict()


@pytest.mark.parametrize(
    "colliders, settings, said",
    [
        ([{"type": "cone", "centre": [0, 0, 0]}], None, "'cone'"),
        ([{"type": "plane", "point": [0, 0, 0], "normal": [0, 0, 0]}], None, "normal"),
        ([{"type": "box", "centre": [0, 0, 0], "size": [0.1, -1, 0.1]}], None, "size"),
        ([{"type": "plane", "point": [0, 0, 0], "normal": [0, 0, 1], "friction": "high"}], None, "'high'"),
        ([{"type": "plane", "point": [0, 0, 0], "normal": [0, 0, 1]}], {"collision_quality": 0}, "collision_quality"),
        ("table", None, "'table'"),
    ],
)
def test_a_bad_collider_is_refused_in_one_line_naming_the_capture_file_and_the_value(
    tmp_path, colliders, settings, said
):
    sc = _drag(n=5)
    cams = [c.resized(20, 30) for c in C.load_rig("lab18")[:2]]
    synth_capture(str(tmp_path / "cap"), _settings(), scenario=sc, cameras=cams, noise=0.0, model={"name": "blender"})
    path = tmp_path / "cap" / "capture.json"
    d = json.loads(path.read_text())
    d["scenario"]["colliders"] = colliders
    if settings is not None:
        d["scenario"]["collision_settings"] = settings
    path.write_text(json.dumps(d))
    with pytest.raises(ClothFitError) as e:
        load_capture(str(tmp_path / "cap"))
    msg = str(e.value)
    assert "\n" not in msg and "capture.json" in msg and said in msg, msg
