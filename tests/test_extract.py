"""Silhouette extraction (addon/core/footage/extract.py) on tiny synthetic footage: no renders needed."""

import argparse
import json
import os
import shutil

import cv2
import numpy as np
import pytest
from clothfit.core.errors import ClothFitError
from clothfit.core.footage import extract as X
from clothfit.core.observation.camera import Camera, intrinsics, look_at
from clothfit.core.observation.capture import load_capture

H, W = 90, 120


def _smooth(rng, h, w, lo, hi, cells, ch=3):
    shape = (max(2, h // cells), max(2, w // cells)) + ((ch,) if ch > 1 else ())
    return cv2.resize(rng.uniform(lo, hi, shape).astype(np.float32), (w, h), interpolation=cv2.INTER_CUBIC)


def scene(seed=0, h=H, w=W, shadow=True, noise=3.0, cloth_bgr=(200, 120, 60), centre=(0.45, 0.45)):
    """(background, second background plate, frame, true mask) as uint8 BGR images.

    A low-saturation textured background, a textured coloured blob, and a shadow (the background
    dimmed to 60 %) overlapping the blob, plus Gaussian sensor noise.
    """
    rng = np.random.default_rng(seed)
    base = _smooth(rng, h, w, 90, 200, 8)
    bg = 0.7 * base.mean(-1, keepdims=True) + 0.3 * base
    yy, xx = np.mgrid[0:h, 0:w]
    cy, cx = centre
    truth = ((xx - w * cx) / (w * 0.2)) ** 2 + ((yy - h * cy) / (h * 0.25)) ** 2 < 1
    fr = bg.copy()
    if shadow:
        sh = ((xx - w * (cx + 0.17)) / (w * 0.2)) ** 2 + ((yy - h * (cy + 0.17)) / (h * 0.25)) ** 2 < 1
        fr[sh & ~truth] *= 0.6
    tex = _smooth(rng, h, w, 0.7, 1.2, 6, ch=1)[..., None]
    cloth = np.array(cloth_bgr, np.float32) * tex
    fr[truth] = cloth[truth]

    def noisy(img):
        return np.clip(img + rng.normal(0, noise, img.shape), 0, 255).astype(np.uint8)

    return noisy(bg), noisy(bg), noisy(fr), truth


def iou(a, b):
    return (a & b).sum() / max((a | b).sum(), 1)


# ----------------------------------------------------------------- the method


def test_auto_threshold_finds_blob_and_ignores_shadow():
    bg, _, fr, truth = scene()
    res = X.extract_camera([bg], [fr], X.ExtractOptions(), "camA")
    assert not res.errors
    assert iou(res.masks[0], truth) > 0.98
    rep = res.report
    assert rep["mode"] == "auto" and rep["threshold"] == pytest.approx(max(rep["noise"], X.MIN_AUTO_THRESHOLD))
    assert rep["frames"][0]["area"] == res.masks[0].sum()


def test_chroma_weighting_and_shadow_model_against_shadows():
    """Plain YUV difference with full luma weight and no shadow model takes the (hard-edged)
    shadow in; weighing luma down helps at Otsu's (high) threshold; the shadow model removes it
    at the noise threshold."""
    bg, _, fr, truth = scene()
    plain = X.extract_camera([bg], [fr], X.ExtractOptions(luma_weight=1.0, shadow_min=1.0, threshold="otsu")).masks[0]
    weighted = X.extract_camera([bg], [fr], X.ExtractOptions(luma_weight=0.35, shadow_min=1.0, threshold="otsu")).masks[
        0
    ]
    no_model = X.extract_camera([bg], [fr], X.ExtractOptions(shadow_min=1.0)).masks[0]
    per_pixel = X.extract_camera([bg], [fr], X.ExtractOptions(luma_weight=1.0, shadow_min=0.5, shadow_window=1)).masks[
        0
    ]
    assert iou(plain, truth) < 0.8
    assert iou(weighted, truth) > 0.97
    assert iou(no_model, truth) < 0.8
    assert iou(per_pixel, truth) > 0.97


def test_windowed_shadow_model_sees_texture_under_a_uniform_object():
    """A uniform grey patch over a textured background, exactly as dark as a shadow would make the
    background on average: per pixel it passes for a shadow, per window it does not."""
    rng = np.random.default_rng(5)
    h, w = 60, 80
    bg = np.repeat(_smooth(rng, h, w, 60, 220, 3, ch=1)[..., None], 3, -1)
    bg[..., 2] *= 1.15  # a warm tint
    fr = bg.copy()
    truth = np.zeros((h, w), bool)
    truth[20:40, 25:55] = True
    fr[truth] = 0.7 * bg[truth].mean(0)
    bg8, fr8 = np.clip(bg, 0, 255).astype(np.uint8), np.clip(fr, 0, 255).astype(np.uint8)
    d1 = X.difference(X.bgr_to_yuv(fr8.astype(np.float32)), X.bgr_to_yuv(bg8.astype(np.float32)), 0.35, 0, 0.5, 1)
    d9 = X.difference(X.bgr_to_yuv(fr8.astype(np.float32)), X.bgr_to_yuv(bg8.astype(np.float32)), 0.35, 0, 0.5, 9)
    inner = np.zeros_like(truth)
    inner[24:36, 29:51] = True
    assert np.median(d9[inner]) > 3 * np.median(d1[inner])


def test_shadow_model_closed_form_is_the_minimum():
    rng = np.random.default_rng(3)
    f = rng.uniform(-50, 200, (4, 5, 3)).astype(np.float32)
    b = rng.uniform(-50, 200, (4, 5, 3)).astype(np.float32)
    d = X.difference(f, b, 0.35, 0, shadow_min=0.5)
    w = np.array([0.35, 1, 1], np.float32)
    alphas = np.linspace(0.5, 1.0, 2001)
    brute = np.min([np.linalg.norm((f - a * b) * w, axis=-1) for a in alphas], axis=0)
    assert np.allclose(d, brute, atol=1e-2)


def test_noise_threshold_from_two_plates_and_per_camera_override():
    bg, bg2, fr, truth = scene(noise=4.0)
    res = X.extract_camera([bg, bg2], [fr], X.ExtractOptions(threshold="noise"), "c")
    assert res.report["noise_source"] == "background plates"
    assert res.report["mode"] == "noise"
    # the noise threshold sits above the noise: a background-only frame gives (almost) nothing raw
    d = X.difference(X.bgr_to_yuv(X.as_float_image(bg2)), X.bgr_to_yuv(X.as_float_image(bg)), 0.35, 1.0, 0.5)
    assert (d > res.report["threshold"]).mean() < 0.002
    assert iou(res.masks[0], truth) > 0.97
    one = X.extract_camera([bg], [fr], X.ExtractOptions(threshold="noise"), "c")
    assert one.report["noise_source"] == "frames (robust)"
    over = X.extract_camera([bg], [fr], X.ExtractOptions(thresholds={"c": 7.5}), "c")
    assert over.report["threshold"] == 7.5 and over.report["mode"] == "per-camera"
    fixed = X.extract_camera([bg], [fr], X.ExtractOptions(threshold=9.0), "c")
    assert fixed.report["threshold"] == 9.0 and fixed.report["mode"] == "fixed"


def test_otsu_threshold_on_two_modes():
    rng = np.random.default_rng(0)
    v = np.concatenate([rng.normal(5, 1, 9000), rng.normal(40, 4, 1000)])
    t = X.otsu_threshold(v)
    assert (v[:9000] > t).mean() < 0.01 and (v[9000:] < t).mean() < 0.01


def test_cleanup_keeps_largest_fills_holes_and_removes_specks():
    raw = np.zeros((60, 80), bool)
    raw[10:40, 10:40] = True
    raw[20:24, 20:24] = False  # a hole
    raw[50:53, 60:63] = True  # a second, small object
    raw[5, 70] = True  # a speck
    final, steps, info = X.clean_mask(raw, X.ExtractOptions())
    assert final[11:39, 11:39].all() and abs(int(final.sum()) - 900) <= 4  # the opening rounds corners
    assert not final[:10].any() and not final[40:].any()
    assert info["components"] == 2 and info["dropped_area"] > 0
    assert set(steps) == {"threshold", "open", "close", "largest", "refine", "final"}
    keep_all, _, _ = X.clean_mask(raw, X.ExtractOptions(keep_largest=False, fill_holes=False, close_radius=0))
    assert keep_all[51, 61] and not keep_all[21, 21]


def test_grey_and_16bit_images():
    bg, _, fr, truth = scene(shadow=False)  # without chroma a shadow is a darker object
    g_bg = cv2.cvtColor(bg, cv2.COLOR_BGR2GRAY)
    g_fr = cv2.cvtColor(fr, cv2.COLOR_BGR2GRAY)
    res = X.extract_camera([g_bg], [g_fr], X.ExtractOptions(), "g")
    assert not res.errors and iou(res.masks[0], truth) > 0.9
    r16 = X.extract_camera([bg.astype(np.uint16) * 257], [fr.astype(np.uint16) * 257], X.ExtractOptions(), "w")
    r8 = X.extract_camera([bg], [fr], X.ExtractOptions(), "w")
    assert iou(r16.masks[0], r8.masks[0]) > 0.999


def test_in_memory_problems_are_reported_not_silent():
    bg, _, fr, _ = scene()
    res = X.extract_camera([bg], [bg.copy(), fr], X.ExtractOptions(), "camZ", ["a.png", "b.png"])
    assert any("camZ" in e and "a.png" in e and "nothing found" in e for e in res.errors)
    res = X.extract_camera([bg], [bg.copy()], X.ExtractOptions(allow_empty=True), "camZ", ["a.png"])
    assert not res.errors and not res.masks[0].any()
    assert any("a.png" in w and "empty" in w for w in res.warnings)
    res = X.extract_camera([bg], [fr[:-2]], X.ExtractOptions(), "camZ", ["small.png"])
    assert any("small.png" in e and "size" in e for e in res.errors)
    assert X.extract_camera([], [fr], X.ExtractOptions(), "camZ").errors


def test_border_touch_and_area_warnings():
    bg, _, fr, _ = scene(centre=(0.45, 0.1))  # blob cut by the left border
    res = X.extract_camera([bg], [fr], X.ExtractOptions(), "c", ["edge.png"])
    assert any("edge.png" in w and "border" in w for w in res.warnings)


@pytest.mark.parametrize("bad", ["threshold", "luma", "shadow"])
def test_bad_options(bad):
    kw = {"threshold": {"threshold": "median"}, "luma": {"luma_weight": -1}, "shadow": {"shadow_min": 0}}[bad]
    with pytest.raises(ClothFitError):
        X.ExtractOptions(**kw).check()


# ------------------------------------------------------------- footage folders


def _cams(n=2):
    cams = []
    for i in range(n):
        R, t = look_at([0.5 * np.cos(i), 0.5 * np.sin(i), 0.3], [0, 0, 0.06])
        cams.append(Camera(intrinsics(150.0, W, H), R, t, W, H, name=f"cam{i:02d}"))
    return cams


def write_footage(root, n_cams=2, times=(0.1, 0.2, 0.3), plates=1, footage_json=True):
    from clothfit.core.footage.calib_io import export_cameras

    os.makedirs(root, exist_ok=True)
    cams = _cams(n_cams)
    export_cameras(cams, os.path.join(root, "cameras.yml"))
    truths = {}
    for ci, cam in enumerate(cams):
        d = os.path.join(root, cam.name)
        os.makedirs(d, exist_ok=True)
        truths[cam.name] = []
        for fi, _ in enumerate(times):
            bg, bg2, fr, truth = scene(seed=10 * ci, centre=(0.4 + 0.05 * fi, 0.45))
            if fi == 0:
                cv2.imwrite(os.path.join(d, "background.png"), bg)
                if plates > 1:
                    cv2.imwrite(os.path.join(d, "background_2.png"), bg2)
            cv2.imwrite(os.path.join(d, f"{fi:03d}.png"), fr)
            truths[cam.name].append(truth)
    if footage_json:
        with open(os.path.join(root, "footage.json"), "w") as f:
            json.dump({"cameras": "cameras.yml", "frame_times": list(times), "cloth_mass": 0.0025}, f)
    return cams, truths


def test_extract_capture_end_to_end(tmp_path):
    root, out, dbg = str(tmp_path / "footage"), str(tmp_path / "cap"), str(tmp_path / "dbg")
    cams, truths = write_footage(root, plates=2)
    os.makedirs(os.path.join(root, "notes"))
    cv2.imwrite(os.path.join(root, "notes", "sketch.png"), np.zeros((4, 4), np.uint8))
    rep = X.extract_capture(root, out, debug_dir=dbg)
    cap = load_capture(out, validate=True)
    assert cap.camera_names == [c.name for c in cams]
    assert np.allclose(cap.frame_times, [0.1, 0.2, 0.3]) and cap.cloth_mass == 0.0025
    sils = cap.load_silhouettes()
    for ci, c in enumerate(cams):
        for fi in range(3):
            assert iou(sils[ci][fi], truths[c.name][fi]) > 0.97
        assert rep["cameras"][c.name]["noise_source"] == "background plates"
        assert len(rep["cameras"][c.name]["frames"]) == 3
    assert any("paper's manipulation" in w for w in rep["warnings"])
    assert any("notes" in w for w in rep["warnings"])
    assert os.path.isfile(os.path.join(out, X.REPORT_JSON))
    assert cap.meta["extraction"]["thresholds"].keys() == {"cam00", "cam01"}
    names = sorted(os.listdir(os.path.join(dbg, "cam00")))
    for step in ("1_difference", "2_threshold", "3_open", "4_close", "5_largest", "6_refine", "7_final", "8_overlay"):
        assert f"000_{step}.png" in names
    assert "histogram.png" in names
    assert "threshold" in X.format_report(rep)


def test_extract_capture_stopped_keeps_the_cameras_done(tmp_path):
    """``should_stop`` (Esc in Blender): the capture holds the cameras extracted before the stop."""
    write_footage(str(tmp_path / "f"), n_cams=3)
    asked = []

    def stop_after_one():
        asked.append(1)
        return len(asked) > 1  # False before camera 0, True before camera 1

    rep = X.extract_capture(str(tmp_path / "f"), str(tmp_path / "cap"), should_stop=stop_after_one)
    assert rep["stopped"] == {"cameras_done": 1, "cameras": 3} and len(asked) == 2
    assert any("stopped after 1 of 3 cameras" in w for w in rep["warnings"])
    cap = load_capture(str(tmp_path / "cap"), validate=True)
    assert cap.camera_names == ["cam00"] and cap.meta["extraction"]["stopped"]["cameras_done"] == 1
    with pytest.raises(ClothFitError, match="stopped before the first camera finished: nothing written"):
        X.extract_capture(str(tmp_path / "f"), str(tmp_path / "cap_none"), should_stop=lambda: True)
    assert not (tmp_path / "cap_none").exists()


def test_extract_capture_undistort(tmp_path):
    root, out = str(tmp_path / "f"), str(tmp_path / "c")
    write_footage(root, n_cams=1, times=(0.1,))
    from clothfit.core.footage.calib_io import export_cameras, import_cameras

    cams = import_cameras(os.path.join(root, "cameras.yml"))
    cams[0].dist = np.array([-0.2, 0.05, 0.0, 0.0, 0.0])
    export_cameras(cams, os.path.join(root, "cameras.yml"))
    X.extract_capture(root, out, undistort=True)
    cap = load_capture(out)
    assert not np.any(cap.cameras[0].dist)
    X.extract_capture(root, out + "2")
    assert np.allclose(load_capture(out + "2").cameras[0].dist, [-0.2, 0.05, 0, 0, 0])


def _expect(root, out, *needles, **kw):
    with pytest.raises(ClothFitError) as ei:
        X.extract_capture(root, out, **kw)
    msg = str(ei.value)
    for n in needles:
        assert n in msg, msg
    assert not os.path.exists(os.path.join(out, "capture.json"))
    return msg


def test_extract_capture_bad_inputs(tmp_path):
    root, out = str(tmp_path / "f"), str(tmp_path / "c")
    write_footage(root)
    # size mismatch
    p = os.path.join(root, "cam00", "001.png")
    cv2.imwrite(p, np.zeros((H - 10, W, 3), np.uint8))
    _expect(root, out, "001.png", f"{H - 10}x{W}", "cam00")
    # unreadable file
    with open(p, "wb") as f:
        f.write(b"this is not a png")
    _expect(root, out, "001.png", "unreadable")
    with open(p, "wb"):
        pass
    _expect(root, out, "001.png", "zero-byte")
    # nothing found: the frame is the background
    bg = cv2.imread(os.path.join(root, "cam00", "background.png"))
    cv2.imwrite(p, bg)
    _expect(root, out, "001.png", "nothing found")
    rep = X.extract_capture(root, out, allow_empty=True)
    assert any("001.png" in w for w in rep["warnings"])
    os.remove(os.path.join(out, "capture.json"))
    # missing background, several problems in one message
    os.remove(os.path.join(root, "cam01", "background.png"))
    msg = _expect(root, out, "cam01", "no background image", "001.png", "nothing found")
    assert "2 problems" in msg
    # missing camera folder, frame count mismatch
    import shutil

    shutil.rmtree(os.path.join(root, "cam01"))
    os.remove(os.path.join(root, "cam00", "002.png"))
    _expect(root, out, "cam01", "not found", "2 foreground images", "3 frame times")


def test_extract_capture_missing_metadata(tmp_path):
    root, out = str(tmp_path / "f"), str(tmp_path / "c")
    write_footage(root, footage_json=False)
    _expect(root, out, "no frame times")
    rep = X.extract_capture(root, out, frame_times=[0.1, 0.2, 0.3], cloth_mass=0.002)
    assert load_capture(out).cloth_mass == 0.002 and rep["cameras"]
    os.remove(os.path.join(root, "cameras.yml"))
    _expect(root, out + "x", "no cameras given")
    with pytest.raises(ClothFitError, match="footage folder not found"):
        X.extract_capture(str(tmp_path / "nope"), out)


def test_cli_glue(tmp_path, capsys):
    root, out = str(tmp_path / "f"), str(tmp_path / "c")
    write_footage(root, footage_json=False)
    scen = tmp_path / "scen.json"
    from clothfit.core.physics.scenario import paper_scenario

    scen.write_text(json.dumps({"scenario": paper_scenario(frame_times=[9.0]).to_dict()}))
    from clothfit.cli.footage import add_extract_arguments, cmd_extract

    p = add_extract_arguments(argparse.ArgumentParser())
    args = p.parse_args(
        [
            root,
            "-o",
            out,
            "--cameras",
            os.path.join(root, "cameras.yml"),
            "--times",
            "0.1,0.2,0.3",
            "--camera-threshold",
            "cam01=12",
            "--scenario",
            str(scen),
            "--cloth-mass",
            "0.003",
        ]
    )
    rep = cmd_extract(args)
    assert rep["cameras"]["cam01"]["threshold"] == 12.0
    assert "wrote capture" in capsys.readouterr().out
    cap = load_capture(out)
    assert np.allclose(cap.frame_times, [0.1, 0.2, 0.3]) and cap.cloth_mass == 0.003
    bad = p.parse_args([root, "-o", out, "--camera-threshold", "cam01"])
    with pytest.raises(ClothFitError, match="NAME=VALUE"):
        cmd_extract(bad)


def test_boundary_refinement_moves_edge_to_half_contrast():
    yy, xx = np.mgrid[0:80, 0:80]
    disk = (xx - 40.0) ** 2 + (yy - 38.0) ** 2 < 15.0**2
    d = cv2.GaussianBlur(disk.astype(np.float32) * 60.0, (0, 0), 1.5)
    fat = d > 4.0  # a low (noise-level) threshold on a blurred edge
    thin = d > 50.0  # a high one
    for m in (fat, thin):
        assert iou(m, disk) < 0.93
        r = X.refine_boundary(m, d, 2)
        assert iou(r, disk) > 0.98
    assert X.refine_boundary(fat, d, 0) is fat


def test_cli_extract(tmp_path, capsys):
    from clothfit.cli import main as cli

    root, out = str(tmp_path / "f"), str(tmp_path / "c")
    write_footage(root)
    assert cli(["extract", root, "-o", out, "--threshold", "noise"]) == 0
    io = capsys.readouterr()
    assert "wrote capture" in io.err and json.loads(io.out)["frame_times"] == [0.1, 0.2, 0.3]
    assert load_capture(out, validate=True).n_frames == 3
    os.remove(os.path.join(root, "cam00", "background.png"))
    assert cli(["extract", root, "-o", out]) == 2  # the capture it wrote: refused
    assert "--force" in capsys.readouterr().err
    assert cli(["extract", root, "-o", out, "--force"]) == 2
    assert "no background image" in capsys.readouterr().err


def test_overlays_on_the_footage_frames(tmp_path, capsys):
    """overlay --on-images draws the comparison on the camera images the silhouettes came from."""
    from clothfit.cli import main as cli
    from clothfit.core.observation.overlay import capture_overlays

    root, out = str(tmp_path / "f"), str(tmp_path / "c")
    write_footage(root, n_cams=1, times=(0.1, 0.2))
    X.extract_capture(root, out)
    cap = load_capture(out)
    images = X.footage_images(cap)
    frame = images(0, 1)
    assert frame.shape == (H, W, 3) and frame.dtype == np.uint8
    assert np.array_equal(frame, cv2.imread(os.path.join(root, "cam00", "001.png"))[..., ::-1])
    paths = capture_overlays(cap, {"m": 1e-5, "k": 10.0, "l": 0.1 / 15, "d": 1e-4}, str(tmp_path / "ov"), images=images)
    ov = cv2.imread(paths[0])[..., ::-1]
    far = np.ones((H, W), bool)
    far[H // 4 : 3 * H // 4, W // 4 : 3 * W // 4] = False  # away from the cloth: the frame itself
    same = np.all(ov == cv2.imread(os.path.join(root, "cam00", "000.png"))[..., ::-1], axis=2)
    assert same[far].mean() > 0.9
    assert (
        cli(
            [
                "overlay",
                out,
                "--params",
                '{"m": 1e-5, "k": 10, "l": 0.00667, "d": 1e-4}',
                "--out",
                str(tmp_path / "ov2"),
                "--on-images",
            ]
        )
        == 0
    )
    capsys.readouterr()
    X.extract_capture(root, out + "u", undistort=True)
    with pytest.raises(ClothFitError, match="undistorted"):
        X.footage_images(load_capture(out + "u"))
    shutil.rmtree(root)
    with pytest.raises(ClothFitError, match="not extracted from image footage"):
        X.footage_images(cap)
