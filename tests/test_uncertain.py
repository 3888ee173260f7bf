"""The manipulation's unknowns a capture declares (capture.json "uncertain", fit --uncertain)."""

import json

import numpy as np
import pytest
from clothfit.core.errors import ClothFitError
from clothfit.core.observation.capture import load_capture
from clothfit.core.observation.synth import synth_capture
from clothfit.core.physics import blender as B
from clothfit.core.physics.scenario import Uncertainty


def test_text_and_object_forms_agree():
    u = Uncertainty.from_text("time_offset=0.05,handles=0.005", 4)
    assert u == Uncertainty.parse({"time_offset": 0.05, "handles": 0.005}, 4)
    assert u.active and u.handles == (0.005,) * 4
    assert Uncertainty.parse(u.to_dict(), 4) == u
    per = Uncertainty.parse({"handles": [0.001, 0, 0, 0.002]}, 4)
    assert per.time_offset == 0 and per.handles == (0.001, 0.0, 0.0, 0.002)
    assert Uncertainty.parse(per.to_dict(), 4) == per
    off = Uncertainty.from_text("none", 4)
    assert not off.active


@pytest.mark.parametrize(
    "text, key",
    [
        ("time_offset=-0.01", "time_offset"),
        ("time_offset=abc", "time_offset"),
        ("time_offset=1.5", "time_offset"),
        ("handles=0.06", "handles"),
        ("handles=nan", "handles"),
        ("handels=0.001", "handels"),
        ("time_offset", "time_offset"),
        ("time_offset=0.1,time_offset=0.2", "time_offset"),
        ("", "empty"),
    ],
)
def test_bad_bounds_are_one_line_errors_naming_the_key(text, key):
    with pytest.raises(ClothFitError) as e:
        Uncertainty.from_text(text, 4)
    assert key in str(e.value) and "\n" not in str(e.value)


def test_bad_object_forms():
    for bad, key in (
        ({"handles": [0.001, 0.002]}, "handles"),
        ({"handles": True}, "handles"),
        ([0.1], "expected an object"),
        ({"time_offset": "0.1"}, "time_offset"),
    ):
        with pytest.raises(ClothFitError) as e:
            Uncertainty.parse(bad, 4, "capture x: uncertain")
        assert key in str(e.value) and "\n" not in str(e.value)


def test_a_capture_carries_its_uncertain_block(tmp_path):
    cap = synth_capture(tmp_path / "c", rig="ring8", resolution=(60, 80), noise=0.0)
    d = json.loads((tmp_path / "c" / "capture.json").read_text())
    assert "uncertain" not in d and cap.uncertain is None
    d["uncertain"] = {"time_offset": 0.02, "handles": 0.002}
    (tmp_path / "c" / "capture.json").write_text(json.dumps(d))
    cap = load_capture(tmp_path / "c")
    assert cap.uncertain == Uncertainty(0.02, (0.002,) * 4)
    assert cap.subset([0], [0]).uncertain == cap.uncertain
    d["uncertain"] = {"time_offset": 0.02, "pins": 0.002}
    (tmp_path / "c" / "capture.json").write_text(json.dumps(d))
    with pytest.raises(ClothFitError, match="unknown key 'pins'"):
        load_capture(tmp_path / "c")


def test_settle_not_a_whole_number_of_frames_is_rounded_and_said():
    assert B.settle_frames(2.95, 24) == 71
    note = B.settle_note(2.95, 24)
    assert "70.80 frames" in note and "71 frames" in note
    assert B.settle_note(0.5, 24) is None
    from clothfit.core.physics.scenario import paper_scenario

    sc = paper_scenario(frame_times=np.array([0.1, 0.2]))
    sc.settle_time = 0.51
    plan = B.FramePlan.from_scenario(sc, 24.0)
    assert plan.settle_frames == 12 and abs(plan.settle_time - 0.5) < 1e-12
