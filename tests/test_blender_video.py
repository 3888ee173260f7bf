"""Extract Silhouettes from videos inside Blender (OpenCV's video backend, as in Blender without PyAV)."""

import os
import sys

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "tools"))

from blender_support import factory, run_error  # noqa: E402,F401
from clothfit.core.observation.capture import load_capture  # noqa: E402
from video_footage import FLASH_BEFORE, iou, make_video_footage  # noqa: E402

pytestmark = pytest.mark.usefixtures("factory")


def test_extract_videos_operator(tmp_path, monkeypatch):
    monkeypatch.setenv("CLOTHFIT_VIDEO_BACKEND", "opencv")
    root = str(tmp_path / "footage")
    truth = make_video_footage(root, n_cameras=2, resolution=(120, 160), seed=5, times=[0.1, 0.3])
    p = bpy.context.scene.clothfit
    p.footage_kind = "VIDEOS"
    p.footage_dir = os.path.join(root, "videos")
    p.footage_plates = os.path.join(root, "plates")
    p.extract_calibration = os.path.join(root, "intri.yml")
    p.extract_times = "0.1, 0.3"
    p.extract_capture_dir = str(tmp_path / "cap")
    assert "Sync" in run_error("extract_silhouettes")
    p.footage_find_sync = True
    p.footage_flash_time = -FLASH_BEFORE
    p.footage_sync = str(tmp_path / "sync_found.json")
    assert bpy.ops.clothfit.extract_silhouettes() == {"FINISHED"}
    cap = load_capture(str(tmp_path / "cap"))
    assert cap.camera_names == [c.name for c in truth["cameras"]]
    ious = [iou(cap.load_silhouette(c, f), truth["masks"][c][f]) for c in range(2) for f in range(2)]
    assert np.mean(ious) > 0.9
    assert os.path.isfile(tmp_path / "sync_found.json")
