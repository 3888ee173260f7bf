import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import json

import numpy as np
import pytest
from clothfit.core.errors import ClothFitError
from clothfit.core.observation import camera as camera_mod
from clothfit.core.observation.capture import (
    DEFAULT_PATTERN,
    FORMAT,
    Capture,
    PendingCapture,
    finalize_capture,
    load_capture,
    read_shapes,
    write_capture,
)
from clothfit.core.observation.silhouette_files import read_silhouette, save_silhouette
from clothfit.core.physics.scenario import ClothGrid, paper_scenario

H, W = 48, 64
TIMES = [0.05, 0.10, 0.15]


def _rig():
    return camera_mod.ring_rig(n_per_ring=(3,), elevations_deg=(20,), width=W, height=H, fx=80)


def _scenario(times=TIMES):
    return paper_scenario(ClothGrid(nx=4), frame_times=times)


def _masks(n_cams, n_frames, seed=0):
    rng = np.random.default_rng(seed)
    out = []
    for c in range(n_cams):
        row = []
        for f in range(n_frames):
            m = np.zeros((H, W), bool)
            r0, c0 = rng.integers(5, 20), rng.integers(5, 30)
            m[r0 : r0 + 15 + f, c0 : c0 + 20 + c] = True
            m[rng.integers(0, H), rng.integers(0, W)] = True
            row.append(m)
        out.append(row)
    return out


def _shapes(scen, seed=1):
    rng = np.random.default_rng(seed)
    return rng.normal(size=(len(scen.frame_times), scen.grid.n_vertices, 3)) * 0.05


META = {
    "gt_params": {"m": 1e-5, "k": 10.0, "l": 0.0333, "d": 2e-5},
    "noise": {"fraction": 0.05},
    "generator": "test",
    "seed": 7,
}


@pytest.fixture
def cap_dir(tmp_path):
    root = tmp_path / "cap"
    cams, scen = _rig(), _scenario()
    masks = _masks(len(cams), len(TIMES))
    write_capture(str(root), cams, scen, masks, shapes=_shapes(scen), cloth_mass=0.0025, meta=META)
    return root, cams, scen, masks


def _err(fn, *a, **k):
    with pytest.raises(ClothFitError) as ei:
        fn(*a, **k)
    return str(ei.value)


# ------------------------------------------------------------------- round trip


def test_round_trip(cap_dir):
    root, cams, scen, masks = cap_dir
    for p in (str(root), str(root / "capture.json")):
        cap = load_capture(p)
        assert cap.root == str(root)
        assert [c.name for c in cap.cameras] == [c.name for c in cams]
        for a, b in zip(cap.cameras, cams):
            assert np.array_equal(a.K, b.K) and np.array_equal(a.R, b.R) and np.array_equal(a.t, b.t)
            assert (a.width, a.height) == (b.width, b.height)
            assert np.array_equal(a.dist, b.dist)
        assert cap.scenario.to_dict() == scen.to_dict()
        assert np.array_equal(cap.frame_times, np.array(TIMES))
        assert cap.pattern == DEFAULT_PATTERN
        assert np.array_equal(cap.shapes, _shapes(scen))
        assert cap.cloth_mass == 0.0025
        assert cap.point_mass == pytest.approx(0.0025 / 16)
        assert cap.meta == META
        sils = cap.load_silhouettes()
        assert len(sils) == 3 and all(len(r) == 3 for r in sils)
        for c in range(3):
            for f in range(3):
                assert sils[c][f].dtype == bool and sils[c][f].shape == (H, W)
                assert np.array_equal(sils[c][f], masks[c][f])
        cap.validate(full=True)
        assert load_capture(p, validate=True).n_cameras == 3


def test_files_on_disk(cap_dir):
    root, cams, scen, _ = cap_dir
    d = json.loads((root / "capture.json").read_text())
    assert d["format"] == FORMAT and d["version"] == 1
    assert d["cameras"] == "cameras.json" and d["shapes"] == "shapes.npz"
    assert d["silhouettes"] == "sil/{camera}/{frame:03d}.png"
    assert d["frame_times"] == TIMES == d["scenario"]["frame_times"]
    assert (root / "sil" / "cam00" / "000.png").is_file()
    assert (root / "sil" / "cam02" / "002.png").is_file()
    import cv2

    img = cv2.imread(str(root / "sil" / "cam01" / "001.png"), cv2.IMREAD_UNCHANGED)
    assert img.dtype == np.uint8 and img.ndim == 2 and set(np.unique(img)) == {0, 255}
    z = np.load(root / "shapes.npz")
    assert z["positions"].shape == (3, 16, 3) and np.allclose(z["frame_times"], TIMES)
    assert not any(p.name.endswith(".tmp") for p in root.rglob("*"))


def test_metadata_only_then_render(tmp_path):
    cams, scen = _rig(), _scenario()
    cap = write_capture(str(tmp_path / "c"), cams, scen, None)
    assert os.path.isfile(cap.json_path)
    assert cap.silhouette_path(1, 2) == os.path.join(str(tmp_path / "c"), "sil", "cam01", "002.png")
    masks = _masks(3, 3)
    for c in range(3):
        for f in range(3):
            save_silhouette(cap.silhouette_path(c, f), masks[c][f].astype(np.uint8))  # 0/1 input
    cap2 = load_capture(str(tmp_path / "c")).validate()
    assert cap2.shapes is None and cap2.cloth_mass is None and cap2.meta == {}
    assert np.array_equal(cap2.load_silhouette(2, 1), masks[2][1])


def test_pending_capture_then_finalize(tmp_path):
    """Two-step writing for renderers: no capture.json until finalize, which writes it last."""
    root = tmp_path / "c"
    cams, scen = _rig(), _scenario()
    pending = write_capture(
        str(root), cams, scen, None, shapes=_shapes(scen), cloth_mass=0.002, meta=META, finalize=False
    )
    assert isinstance(pending, PendingCapture) and not pending.finalized
    assert (root / "cameras.json").is_file() and (root / "shapes.npz").is_file()
    assert not (root / "capture.json").exists()
    assert (root / "sil" / "cam02").is_dir()
    # a renderer that stops midway: some PNGs written, never finalised -> not loadable
    masks = _masks(3, 3)
    save_silhouette(pending.silhouette_path(0, 0), masks[0][0])
    msg = _err(load_capture, str(root))
    assert "capture.json missing" in msg and "incomplete" in msg and str(root) in msg
    # finalising before every PNG is there is refused, naming the missing files
    msg = _err(finalize_capture, pending)
    assert "8 of 9 silhouette files are missing" in msg and os.path.join("cam00", "001.png") in msg
    assert not (root / "capture.json").exists()
    for c in range(3):
        for f in range(3):
            save_silhouette(pending.silhouette_path(c, f), masks[c][f])
    cap = finalize_capture(pending)
    assert pending.finalized and isinstance(cap, Capture)
    cap2 = load_capture(str(root)).validate()
    assert cap2.cloth_mass == 0.002 and cap2.meta == META and cap2.shapes.shape == (3, 16, 3)
    assert np.array_equal(cap2.load_silhouette(1, 2), masks[1][2])
    assert not any(p.name.endswith(".tmp") for p in root.rglob("*"))
    # rewriting a finished capture as pending removes its capture.json first
    write_capture(str(root), cams, scen, None, finalize=False)
    assert "capture.json missing" in _err(load_capture, str(root))
    assert "PendingCapture" in _err(finalize_capture, cap)


def test_missing_capture_json_messages(tmp_path):
    assert "capture.json missing" in _err(load_capture, str(tmp_path))
    assert "incomplete" not in _err(load_capture, str(tmp_path))


def test_time_pattern_and_subset(tmp_path):
    cams, scen = _rig(), _scenario()
    masks = _masks(3, 3)
    cap = write_capture(str(tmp_path / "c"), cams, scen, masks, pattern="masks/{camera}_t{time}.png")
    assert cap.silhouette_path(0, 0).endswith(os.path.join("masks", "cam00_t0.050.png"))
    assert os.path.isfile(os.path.join(str(tmp_path / "c"), "masks", "cam02_t0.150.png"))
    cap = load_capture(str(tmp_path / "c")).validate()
    sub = cap.subset([2], [1, 2])
    assert sub.camera_names == ["cam02"] and np.allclose(sub.frame_times, [0.10, 0.15])
    assert np.array_equal(sub.load_silhouette(0, 0), masks[2][1])
    sub.validate()
    assert cap.camera_index("cam01") == 1
    assert cap.frame_index(0.1) == 1 and cap.frame_indices([0.15, 0.05]) == [2, 0]


def test_flat_pattern_with_underscored_names(tmp_path):
    cams = _rig()
    for i, c in enumerate(cams):
        c.name = f"cam_{'abc'[i]}"
    cap = write_capture(str(tmp_path / "c"), cams, _scenario(), _masks(3, 3), pattern="{camera}_{frame:02d}.png")
    assert os.path.isfile(os.path.join(str(tmp_path / "c"), "cam_b_01.png"))
    load_capture(str(tmp_path / "c")).validate()
    save_silhouette(os.path.join(cap.root, "cam_z_00.png"), np.ones((H, W), bool))
    msg = _err(cap.validate, full=False)
    assert "camera count mismatch" in msg and "cam_z" in msg


def test_subset_allows_missing_files_of_other_cameras(cap_dir):
    root, *_ = cap_dir
    os.remove(root / "sil" / "cam00" / "001.png")
    cap = load_capture(str(root))
    sub = cap.subset([1, 2], [0, 1])
    sub.validate(full=True)
    assert len(sub.load_silhouettes()) == 2
    cap.load_silhouettes([0], [0, 2])  # the missing one not asked for: fine
    msg = _err(cap.validate, full=True)
    assert "001.png" in msg and "not found" in msg


def test_subset_shapes_and_frame_mapping(cap_dir):
    root, cams, scen, masks = cap_dir
    cap = load_capture(str(root))
    sub = cap.subset(None, [0, 2])
    assert np.array_equal(sub.shapes, cap.shapes[[0, 2]])
    assert sub.silhouette_path(0, 1).endswith(os.path.join("cam00", "002.png"))
    assert np.array_equal(sub.load_silhouette(1, 1), masks[1][2])


# -------------------------------------------------------------- silhouette reader


def test_read_silhouette_variants(tmp_path):
    import cv2

    m = np.zeros((H, W), bool)
    m[10:20, 5:40] = True
    p = str(tmp_path / "a.png")
    cv2.imwrite(p, m.astype(np.uint8))  # 0/1
    assert np.array_equal(read_silhouette(p, (H, W)), m)
    cv2.imwrite(p, np.repeat((m * 255).astype(np.uint8)[..., None], 3, 2))  # equal BGR
    assert np.array_equal(read_silhouette(p, (H, W)), m)
    bgra = np.dstack([np.repeat((m * 255).astype(np.uint8)[..., None], 3, 2), np.full((H, W), 255, np.uint8)])
    cv2.imwrite(p, bgra)  # opaque RGBA
    assert np.array_equal(read_silhouette(p, (H, W)), m)
    cv2.imwrite(p, (m * 65535).astype(np.uint16))  # 16-bit 0/65535
    assert np.array_equal(read_silhouette(p, (H, W)), m)


def test_colour_image_with_differing_channels(tmp_path):
    import cv2

    img = np.zeros((H, W, 3), np.uint8)
    img[10:20, 10:20] = (0, 0, 255)
    p = str(tmp_path / "col.png")
    cv2.imwrite(p, img)
    msg = _err(read_silhouette, p, (H, W))
    assert "col.png" in msg and "100 pixels" in msg
    assert read_silhouette(p, (H, W), binarize_threshold=50).sum() == 100


def test_transparent_alpha_rejected(tmp_path):
    import cv2

    img = np.full((H, W, 4), 255, np.uint8)
    img[..., 3] = 0
    p = str(tmp_path / "alpha.png")
    cv2.imwrite(p, img)
    msg = _err(read_silhouette, p)
    assert "alpha.png" in msg and "alpha" in msg


def test_save_silhouette_rejects_bad_masks(tmp_path):
    assert "not binary" in _err(save_silhouette, str(tmp_path / "x.png"), np.full((4, 4), 7, np.uint8))
    assert "2D" in _err(save_silhouette, str(tmp_path / "x.png"), np.zeros((4, 4, 3), bool))
    assert ".png" in _err(save_silhouette, str(tmp_path / "x.jpg"), np.ones((4, 4), bool))


# -------------------------------------------------------------- bad inputs: files


def test_missing_capture_json(tmp_path):
    (tmp_path / "empty").mkdir()
    msg = _err(load_capture, str(tmp_path / "empty"))
    assert "capture.json" in msg and "empty" in msg
    msg = _err(load_capture, str(tmp_path / "nowhere"))
    assert "nowhere" in msg


def test_corrupt_json(cap_dir):
    root, *_ = cap_dir
    (root / "capture.json").write_text('{\n "format": "silhouette-cloth-fit/capture",\n "version": 1,,\n}')
    msg = _err(load_capture, str(root))
    assert "capture.json" in msg and "line 3" in msg


def test_wrong_format_tag_and_missing_keys(cap_dir):
    root, *_ = cap_dir
    d = json.loads((root / "capture.json").read_text())
    bad = dict(d, format="something-else")
    (root / "capture.json").write_text(json.dumps(bad))
    msg = _err(load_capture, str(root))
    assert "something-else" in msg and "capture.json" in msg
    bad = {k: v for k, v in d.items() if k not in ("silhouettes", "scenario")}
    (root / "capture.json").write_text(json.dumps(bad))
    msg = _err(load_capture, str(root))
    assert "'silhouettes'" in msg and "'scenario'" in msg
    (root / "capture.json").write_text(json.dumps(dict(d, version=2)))
    assert "version 2" in _err(load_capture, str(root))
    (root / "capture.json").write_text(json.dumps([1, 2]))
    assert "object" in _err(load_capture, str(root))


def test_frame_times_mismatch(cap_dir):
    root, *_ = cap_dir
    d = json.loads((root / "capture.json").read_text())
    d["frame_times"] = [0.05, 0.10, 0.20]
    (root / "capture.json").write_text(json.dumps(d))
    msg = _err(load_capture, str(root))
    assert "frame_times mismatch" in msg and "0.2" in msg and "capture.json" in msg


def test_bad_scenario_names_file(cap_dir):
    root, *_ = cap_dir
    d = json.loads((root / "capture.json").read_text())
    d["scenario"]["handles"] = "nope"
    (root / "capture.json").write_text(json.dumps(d))
    msg = _err(load_capture, str(root))
    assert "capture.json" in msg and "handles" in msg


def test_bad_pattern(cap_dir):
    root, *_ = cap_dir
    d = json.loads((root / "capture.json").read_text())
    for pat, word in (
        ("sil/{frame}.png", "{camera}"),
        ("sil/{camera}/{idx}.png", "{idx}"),
        ("../{camera}/{frame}.png", ".."),
        ("sil/{camera}.png", "{frame}"),
    ):
        (root / "capture.json").write_text(json.dumps(dict(d, silhouettes=pat)))
        msg = _err(load_capture, str(root))
        assert word in msg and "capture.json" in msg


def test_bad_cloth_mass(cap_dir):
    root, *_ = cap_dir
    d = json.loads((root / "capture.json").read_text())
    (root / "capture.json").write_text(json.dumps(dict(d, cloth_mass=-1)))
    msg = _err(load_capture, str(root))
    assert "cloth_mass" in msg and "-1" in msg


def test_missing_cameras_json(cap_dir):
    root, *_ = cap_dir
    os.remove(root / "cameras.json")
    msg = _err(load_capture, str(root))
    assert "cameras.json" in msg and "not found" in msg


def test_missing_silhouette(cap_dir):
    root, *_ = cap_dir
    os.remove(root / "sil" / "cam01" / "002.png")
    cap = load_capture(str(root))
    msg = _err(cap.load_silhouette, 1, 2)
    assert os.path.join("cam01", "002.png") in msg and "not found" in msg
    msg = _err(load_capture, str(root), validate=True)
    assert "002.png" in msg


def test_corrupt_png(cap_dir):
    root, *_ = cap_dir
    p = root / "sil" / "cam00" / "001.png"
    p.write_bytes(np.random.default_rng(3).integers(0, 256, 500, dtype=np.uint8).tobytes())
    cap = load_capture(str(root))
    msg = _err(cap.load_silhouette, 0, 1)
    assert "001.png" in msg and "corrupt" in msg
    good = (root / "sil" / "cam00" / "000.png").read_bytes()
    p.write_bytes(good[: len(good) // 2])  # truncated PNG
    msg = _err(cap.load_silhouette, 0, 1)
    assert "001.png" in msg
    p.write_bytes(b"")
    msg = _err(cap.load_silhouette, 0, 1)
    assert "001.png" in msg and "empty" in msg


def test_wrong_size_png(cap_dir):
    root, *_ = cap_dir
    m = np.zeros((H // 2, W // 2), bool)
    m[3:9, 3:9] = True
    save_silhouette(str(root / "sil" / "cam02" / "000.png"), m)
    cap = load_capture(str(root))
    msg = _err(cap.load_silhouette, 2, 0)
    assert "000.png" in msg and "24 x 32" in msg and "48 x 64" in msg and "cam02" in msg


def test_non_binary_png_and_binarize_threshold(cap_dir):
    import cv2

    root, *_ = cap_dir
    img = np.zeros((H, W), np.uint8)
    img[10:30, 10:40] = 200
    img[10:30, 40:50] = 255
    img[0, 0:5] = 100
    p = str(root / "sil" / "cam01" / "000.png")
    cv2.imwrite(p, img)
    cap = load_capture(str(root))
    msg = _err(cap.load_silhouette, 1, 0)
    assert "000.png" in msg and "not binary" in msg and "605 pixels" in msg and "100, 200" in msg
    m = cap.load_silhouette(1, 0, binarize_threshold=127)
    assert m.sum() == 20 * 40 and not m[0, 0]
    assert cap.load_silhouette(1, 0, binarize_threshold=50).sum() == 20 * 40 + 5
    assert "binarize_threshold" in _err(cap.load_silhouette, 1, 0, binarize_threshold=300)
    cap.validate(binarize_threshold=127)
    assert "not binary" in _err(cap.validate)


def test_empty_silhouette(cap_dir):
    root, *_ = cap_dir
    save_silhouette(str(root / "sil" / "cam00" / "002.png"), np.zeros((H, W), bool))
    cap = load_capture(str(root))
    msg = _err(cap.load_silhouette, 0, 2)
    assert "002.png" in msg and "empty" in msg
    assert not cap.load_silhouette(0, 2, allow_empty=True).any()
    assert "002.png" in _err(cap.validate)
    cap.validate(allow_empty=True)


def test_write_rejects_empty_and_wrong_size(tmp_path):
    cams, scen = _rig(), _scenario()
    masks = _masks(3, 3)
    masks[1][2] = np.zeros((H, W), bool)
    msg = _err(write_capture, str(tmp_path / "c"), cams, scen, masks)
    assert "cam01" in msg and "empty" in msg
    masks[1][2] = np.ones((H, W + 1), bool)
    msg = _err(write_capture, str(tmp_path / "c"), cams, scen, masks)
    assert "cam01" in msg and "(48, 65)" in msg
    msg = _err(write_capture, str(tmp_path / "c"), cams, scen, masks[:2])
    assert "2 cameras" in msg
    msg = _err(write_capture, str(tmp_path / "c"), cams, scen, None, pattern="s/{camera}/{frame}.jpg")
    assert ".jpg" in msg and ".png" in msg
    assert not (tmp_path / "c").exists()


def test_camera_count_mismatch_extra_dir(cap_dir):
    root, *_ = cap_dir
    (root / "sil" / "cam99").mkdir()
    save_silhouette(str(root / "sil" / "cam99" / "000.png"), np.ones((H, W), bool))
    cap = load_capture(str(root))
    msg = _err(cap.validate, full=False)
    assert "camera count mismatch" in msg and "cam99" in msg


def test_camera_count_mismatch_empty_extra_dir(cap_dir):
    root, *_ = cap_dir
    (root / "sil" / "cam05").mkdir()
    (root / "sil" / ".hidden").mkdir()
    msg = _err(load_capture(str(root)).validate, full=False)
    assert "camera count mismatch" in msg and "cam05" in msg and ".hidden" not in msg


def test_camera_count_mismatch_fewer_cameras_in_json(cap_dir):
    root, cams, *_ = cap_dir
    camera_mod.save_cameras(str(root / "cameras.json"), cams[:2])
    msg = _err(load_capture(str(root)).validate)
    assert "camera count mismatch" in msg and "cam02" in msg and "lists 2" in msg


def test_camera_count_mismatch_camera_without_silhouettes(cap_dir):
    import shutil

    root, *_ = cap_dir
    shutil.rmtree(root / "sil" / "cam02")
    cap = load_capture(str(root))
    msg = _err(cap.validate, full=False)
    assert "camera count mismatch" in msg and "cam02" in msg
    cap.subset([0, 1]).validate()


def test_shapes_wrong_vertex_count(cap_dir):
    root, cams, scen, masks = cap_dir
    np.savez(root / "shapes.npz", positions=np.zeros((3, 15, 3)), frame_times=np.array(TIMES))
    msg = _err(load_capture, str(root))
    assert "shapes.npz" in msg and "15 vertices" in msg and "16" in msg
    msg = _err(write_capture, str(root / "other"), cams, scen, masks, shapes=np.zeros((3, 17, 3)))
    assert "17 vertices" in msg


def test_shapes_other_problems(cap_dir):
    root, *_ = cap_dir
    p = root / "shapes.npz"
    np.savez(p, positions=np.zeros((2, 16, 3)))
    assert "2 frames" in _err(load_capture, str(root))
    np.savez(p, positions=np.zeros((3, 16, 3)), frame_times=np.array([0.05, 0.1, 0.2]))
    assert "frame_times" in _err(load_capture, str(root))
    np.savez(p, pos=np.zeros((3, 16, 3)))
    msg = _err(load_capture, str(root))
    assert "shapes.npz" in msg and "'positions'" in msg
    p.write_bytes(b"not a zip at all")
    msg = _err(load_capture, str(root))
    assert "shapes.npz" in msg and "corrupt" in msg
    os.remove(p)
    msg = _err(load_capture, str(root))
    assert "shapes.npz" in msg and "not found" in msg
    assert "shapes.npz" in _err(read_shapes, str(p))


def test_frame_time_not_present(cap_dir):
    root, *_ = cap_dir
    cap = load_capture(str(root))
    msg = _err(cap.frame_index, 0.12)
    assert "0.12" in msg and "0.05, 0.1, 0.15" in msg
    assert cap.frame_index(0.1 + 1e-8) == 1


def test_unknown_camera_and_bad_indices(cap_dir):
    root, *_ = cap_dir
    cap = load_capture(str(root))
    msg = _err(cap.camera_index, "camX")
    assert "camX" in msg and "cam00, cam01, cam02" in msg
    assert "3" in _err(cap.silhouette_path, 3, 0)
    assert "-1" in _err(cap.silhouette_path, 0, -1)


def test_meta_not_serialisable(tmp_path):
    msg = _err(write_capture, str(tmp_path / "c"), _rig(), _scenario(), None, meta={"x": object()})
    assert "meta" in msg
    cap = write_capture(str(tmp_path / "d"), _rig(), _scenario(), None, meta={"a": np.float64(1.5), "b": np.arange(3)})
    assert cap.meta == {"a": 1.5, "b": [0, 1, 2]} == load_capture(str(tmp_path / "d")).meta


def test_capture_in_memory_checks(tmp_path):
    cams = _rig()
    cams[1].name = "bad/name"
    assert "bad/name" in _err(Capture, str(tmp_path), cams, _scenario())
    cams = _rig()
    cams[1].name = "cam00"
    assert "not unique" in _err(Capture, str(tmp_path), cams, _scenario())
    msg = _err(Capture, str(tmp_path), _rig(), _scenario([0.05, 0.050001]), pattern="s/{camera}/{time}.png")
    assert "same file" in msg
