"""Videos as people record them (our own encodes: H.264, variable frame rate, sensor noise, textured
background, cameras started at different moments), EasyMocap and COLMAP binary calibrations, and
the one-line errors of bad input."""

import json
import os
import shutil
import struct
import sys

import numpy as np
import pytest

pytest.importorskip("av")

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "tools"))

from clothfit.cli import main as cli  # noqa: E402
from clothfit.core.errors import ClothFitError  # noqa: E402
from clothfit.core.footage import calib_io, colmap, video  # noqa: E402
from clothfit.core.observation import camera as C  # noqa: E402
from clothfit.core.observation.capture import load_capture  # noqa: E402
from video_footage import FLASH_BEFORE, iou, make_video_footage  # noqa: E402

RES = (180, 240)


@pytest.fixture(scope="module")
def footage(tmp_path_factory):
    root = str(tmp_path_factory.mktemp("footage"))
    truth = make_video_footage(root, n_cameras=3, resolution=RES, seed=3)
    return root, truth


def extract_args(root, out, times, sync=None):
    return [
        "extract",
        "--videos",
        os.path.join(root, "videos"),
        "--plates",
        os.path.join(root, "plates"),
        "--cameras",
        root,
        "--times",
        ",".join(str(t) for t in times),
        "--out",
        out,
        "--sync",
        sync or os.path.join(root, "sync.json"),
    ]


def test_videos_extract_to_true_masks(footage, tmp_path):
    root, truth = footage
    out = str(tmp_path / "cap")
    assert cli(extract_args(root, out, truth["times"])) == 0
    cap = load_capture(out, validate=True)
    assert cap.camera_names == [c.name for c in truth["cameras"]]
    ious = [iou(cap.load_silhouette(c, f), truth["masks"][c][f]) for c in range(3) for f in range(cap.n_frames)]
    assert np.mean(ious) >= 0.95, ious
    rep = json.load(open(os.path.join(out, "extract_report.json")))
    for name, r in rep["video"].items():  # every frame read at exactly sync + t (ms container timestamps)
        want = [truth["sync"][name] + t for t in truth["times"]]
        assert np.allclose(r["frame_timestamps"], want, atol=5e-4)
        assert r["video"].endswith(".mkv" if name == "cam00" else ".mp4")
    assert "median of" in rep["video"]["cam06"]["plate"]  # plate from a video of the empty scene


def test_one_frame_late_is_visible(footage):
    """The IoU test can fail: the frame after the right one (a few tens of ms later) is clearly different."""
    root, truth = footage
    cam = truth["cameras"][1]
    v = video.Video(os.path.join(root, "videos", cam.name + ".mp4"))
    t = truth["times"][3]
    i = v.frame_index(truth["sync"][cam.name] + t)
    assert abs(v.times[i] - truth["sync"][cam.name] - t) < 1e-3
    assert v.times[i + 1] - v.times[i] >= 0.004


def test_flash_sync(footage, tmp_path):
    root, truth = footage
    names = [c.name for c in truth["cameras"]]
    out = str(tmp_path / "sync.json")
    sync = video.flash_sync(os.path.join(root, "videos"), names, -FLASH_BEFORE, out)
    for n in names:
        assert sync[n] == pytest.approx(truth["sync"][n], abs=1e-3)
    assert json.load(open(out)) == sync


def test_easymocap_cameras(footage):
    root, truth = footage
    sizes = video.video_sizes(os.path.join(root, "videos"))
    cams = calib_io.import_cameras(root, sizes=sizes)
    assert calib_io.detect_format(os.path.join(root, "intri.yml")) == "easymocap"
    for a, b in zip(cams, truth["cameras"]):
        assert a.name == b.name and (a.height, a.width) == RES
        assert np.allclose(a.K, b.K) and np.allclose(a.R, b.R, atol=1e-12) and np.allclose(a.t, b.t)
    with pytest.raises(ClothFitError, match="no image size.*--width"):
        calib_io.import_cameras(root)


def _one_line_error(capsys, args):
    assert cli(args) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "\n" not in err, err
    return err


def test_bad_videos(footage, tmp_path, capsys):
    root, truth = footage
    bad = str(tmp_path / "bad")
    shutil.copytree(root, bad)
    times = truth["times"]
    # a sync time outside the video
    sync = dict(truth["sync"], cam06=500.0)
    sp = str(tmp_path / "sync_bad.json")
    json.dump(sync, open(sp, "w"))
    err = _one_line_error(capsys, extract_args(bad, str(tmp_path / "o1"), times, sp))
    assert "sync_bad.json" in err and "cam06" in err and "outside video" in err and "cam06.mp4" in err
    # a capture time past the video's end
    err = _one_line_error(capsys, extract_args(bad, str(tmp_path / "o2"), times + [40.0]))
    assert "cam00.mkv" in err and "past the video's end" in err
    # a camera without a sync time
    json.dump({"cam00": 0.5}, open(sp, "w"))
    err = _one_line_error(capsys, extract_args(bad, str(tmp_path / "o3"), times, sp))
    assert "sync_bad.json" in err and "cam06" in err
    # a video that does not open
    with open(os.path.join(bad, "videos", "cam12.mp4"), "wb") as f:
        f.write(b"\x00\x01 not a video at all" * 50)
    err = _one_line_error(capsys, extract_args(bad, str(tmp_path / "o4"), times))
    assert "cam12.mp4" in err and "cannot be opened" in err
    # a camera without a video
    os.remove(os.path.join(bad, "videos", "cam12.mp4"))
    err = _one_line_error(capsys, extract_args(bad, str(tmp_path / "o5"), times))
    assert "cam12" in err and "no video" in err
    # a camera without a plate
    shutil.copy(os.path.join(root, "videos", "cam12.mp4"), os.path.join(bad, "videos", "cam12.mp4"))
    os.remove(os.path.join(bad, "plates", "cam00.png"))
    err = _one_line_error(capsys, extract_args(bad, str(tmp_path / "o6"), times))
    assert "cam00" in err and "no plate" in err
    assert not os.path.exists(str(tmp_path / "o1" / "capture.json"))


# ------------------------------------------------------------------ COLMAP binary models


def write_colmap_bin(folder, cams, model="OPENCV"):
    """cameras.bin / images.bin in COLMAP's documented layout (independent of our reader)."""
    ids = {"PINHOLE": 1, "OPENCV": 4}
    os.makedirs(folder, exist_ok=True)
    with open(os.path.join(folder, "cameras.bin"), "wb") as f:
        f.write(struct.pack("<Q", len(cams)))
        for i, c in enumerate(cams):
            fx, fy, cx, cy = c.K[0, 0], c.K[1, 1], c.K[0, 2] + 0.5, c.K[1, 2] + 0.5
            params = [fx, fy, cx, cy] + ([0.01 * (i + 1), -0.002, 0.0005, 0.0] if model == "OPENCV" else [])
            f.write(struct.pack("<iiQQ", i + 1, ids[model], c.width, c.height))
            f.write(struct.pack("<" + "d" * len(params), *params))
    with open(os.path.join(folder, "images.bin"), "wb") as f:
        f.write(struct.pack("<Q", len(cams)))
        for i, c in enumerate(cams):
            q = colmap._R_to_quat(c.R)
            f.write(struct.pack("<idddddddi", 10 + i, *q, *c.t, i + 1))
            f.write(f"{c.name}.jpg".encode() + b"\0")
            f.write(struct.pack("<Q", 2))
            f.write(struct.pack("<ddq", 1.0, 2.0, -1) * 2)


def test_colmap_binary_model(tmp_path):
    cams = C.load_rig("ring8")[:3]
    folder = str(tmp_path / "sparse" / "0")
    write_colmap_bin(folder, cams)
    got = calib_io.import_cameras(str(tmp_path))
    assert [c.name for c in got] == [c.name for c in cams]
    for a, b in zip(got, cams):
        assert np.allclose(a.K, b.K) and np.allclose(a.R, b.R, atol=1e-12) and np.allclose(a.t, b.t)
    assert got[1].dist[:4].tolist() == [0.02, -0.002, 0.0005, 0.0]
    # the same cameras through the text model
    txt = str(tmp_path / "txt")
    colmap.write_colmap(txt, got)
    for a, b in zip(calib_io.import_cameras(txt), got):
        assert np.allclose(a.K, b.K) and np.allclose(a.R, b.R) and np.allclose(a.dist[:4], b.dist[:4])
    data = open(os.path.join(folder, "images.bin"), "rb").read()
    open(os.path.join(folder, "images.bin"), "wb").write(data[:-30])
    with pytest.raises(ClothFitError, match="images.bin.*truncated"):
        calib_io.import_cameras(folder)


def test_opencv_backend_reads_the_same(footage, tmp_path, monkeypatch):
    """Without PyAV (inside Blender) OpenCV's FFmpeg backend gives the same timestamps and frames."""
    root, truth = footage
    for cam in truth["cameras"]:
        path = video.find_camera_file(os.path.join(root, "videos"), cam.name, video.VIDEO_EXTS, "videos")
        a, b = video.Video(path, "av"), video.Video(path, "opencv")
        assert np.allclose(a.times, b.times, atol=1e-9, rtol=0) and (a.width, a.height) == (b.width, b.height)
        ts = [truth["sync"][cam.name] + t for t in truth["times"][::3]]
        fa, ua = a.frames_at(ts)
        fb, ub = b.frames_at(ts)
        assert np.allclose(ua, ub, atol=1e-9, rtol=0)
        assert all(np.abs(x.astype(int) - y.astype(int)).max() <= 2 for x, y in zip(fa, fb))
    monkeypatch.setenv("CLOTHFIT_VIDEO_BACKEND", "opencv")
    out = str(tmp_path / "cap_cv")
    assert cli(extract_args(root, out, truth["times"][:3])) == 0
    cap = load_capture(out)
    ious = [iou(cap.load_silhouette(c, f), truth["masks"][c][f]) for c in range(3) for f in range(3)]
    assert np.mean(ious) >= 0.95


def _mat(name, a):
    a = np.atleast_2d(np.asarray(a, dtype=float))
    return (
        f"{name}: !!opencv-matrix\r\n  rows: {a.shape[0]}\r\n  cols: {a.shape[1]}\r\n  dt: d\r\n"
        f"  data: [{', '.join(repr(float(v)) for v in a.ravel())}]\r\n"
    )


def test_easymocap_text_as_its_own_writer_makes_it(tmp_path):
    """intri.yml / extri.yml typed the way EasyMocap's text FileStorage writer lays them out (CRLF,
    quoted numeric names, Rodrigues R_ and 3x3 Rot_), plus EasyVolcap's H_/W_ image size."""
    import cv2

    cams = C.load_rig("ring8")[:2]
    names = ["01", "02"]
    intri = "%YAML:1.0\r\n---\r\nnames:\r\n" + "".join(f'  - "{n}"\r\n' for n in names)
    extri = intri
    for n, c in zip(names, cams):
        intri += _mat(f"K_{n}", c.K) + _mat(f"dist_{n}", [[0.01, -0.02, 0.0, 0.0, 0.0]])
        intri += f"H_{n}: {c.height}\r\nW_{n}: {c.width}\r\n" if n == "01" else ""
        extri += _mat(f"R_{n}", cv2.Rodrigues(c.R)[0].T) + _mat(f"T_{n}", c.t.reshape(3, 1))
        if n == "01":
            extri += _mat(f"Rot_{n}", c.R)
    (tmp_path / "intri.yml").write_bytes(intri.encode())
    (tmp_path / "extri.yml").write_bytes(extri.encode())
    got = calib_io.import_cameras(str(tmp_path), width=cams[1].width, height=cams[1].height)
    assert [c.name for c in got] == names
    for a, b in zip(got, cams):
        assert np.allclose(a.K, b.K) and np.allclose(a.R, b.R, atol=1e-9) and np.allclose(a.t, b.t)
        assert (a.width, a.height) == (b.width, b.height) and np.allclose(a.dist[:2], [0.01, -0.02])
    (tmp_path / "extri.yml").write_bytes(extri.replace("T_02", "X_02").encode())
    with pytest.raises(ClothFitError, match="extri.yml: T_02 missing"):
        calib_io.import_cameras(str(tmp_path), width=640, height=480)
