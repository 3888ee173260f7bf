"""The noise-floor estimate (observation/floor.py) and its marks in the overlays.

Truths the estimator did not make: star-shaped polygons rasterised at pixel centres, with a known
number of flipped boundary pixels (``metrics.add_boundary_noise``, the synthetic captures' noise).
Tolerance of the floor tests: +-25 %, the accuracy asked of the floor. The calibration
(``lab/floor_calibration.py``, docs/noise_floor.md) has the capture-level ratio within 0.93-1.18
on captures at 120 x 160 and above with 1-10 % noise; a capture of 12 such polygons averages the
per-image spread (10th-90th percentile 0.75-1.17 at 5 %) down to a few per cent.
"""

import json
import os

import numpy as np
import pytest
from clothfit.core.errors import ClothFitError
from clothfit.core.observation import floor as FL
from clothfit.core.observation.metrics import add_boundary_noise
from clothfit.core.observation.raster import rasterize


def star(rng, H, W, n=9, r0=0.3):
    cx, cy = W / 2 + rng.uniform(-5, 5), H / 2 + rng.uniform(-5, 5)
    ang = np.sort(rng.uniform(0, 2 * np.pi, n))
    rad = min(H, W) * r0 * rng.uniform(0.6, 1.0, n)
    pts = np.concatenate([[[cx, cy]], np.stack([cx + rad * np.cos(ang), cy + rad * np.sin(ang)], 1)])
    tris = np.array([[0, 1 + i, 1 + (i + 1) % n] for i in range(n)])
    return rasterize(pts, tris, H, W), pts, tris


def stars(H, W, k=12, seed=1):
    rng = np.random.default_rng(seed)
    return [star(rng, H, W) for _ in range(k)]


def mean_floor(images):
    return float(np.mean([[e.floor for e in row] for row in images]))


# ---------------------------------------------------------------- quantisation is not noise


def test_a_clean_digitised_straight_edge_gets_no_votes_at_any_slope():
    H = W = 64
    yy, xx = np.mgrid[0:H, 0:W]
    rng = np.random.default_rng(0)
    for _ in range(200):
        a, c = rng.uniform(-4, 4), rng.uniform(-20, 20)
        m = (yy - H / 2) <= a * (xx - W / 2) + c
        inner = np.ones_like(m)
        inner[0, :] = inner[-1, :] = inner[:, 0] = inner[:, -1] = False
        assert not np.any((FL.majority3(m) ^ m) & inner)


def test_clean_polygons_have_a_floor_near_zero_and_a_flip_is_one_vote():
    for H, W in [(240, 320), (480, 640)]:
        clean = [s for s, _, _ in stars(H, W)]
        images, rate, basis = FL.pooled_floors([[c] for c in clean])
        assert basis == "straight outline"
        assert mean_floor(images) < 0.0002  # 0.02 %: a tenth of a 1 % noise floor at 240 x 320
    # an isolated flipped pixel on a straight edge is one vote, missing or extra
    m = np.zeros((200, 260), bool)
    m[50:150, 60:200] = True
    assert FL.estimate_floor(m).votes == 0
    m[50, 130] = False
    m[149, 100] = False
    m[100, 200] = True
    assert FL.estimate_floor(m).votes == 3


# ---------------------------------------------------------------- the estimate against known noise


@pytest.mark.parametrize("H,W", [(240, 320), (480, 640)])
@pytest.mark.parametrize("noise", [0.05, 0.10])
def test_floor_of_noisy_polygons_within_25_percent(H, W, noise):
    clean = [s for s, _, _ in stars(H, W)]
    obs = [add_boundary_noise(c, noise, np.random.default_rng(i)) for i, c in enumerate(clean)]
    true = np.mean([np.count_nonzero(o ^ c) / np.count_nonzero(o) for o, c in zip(obs, clean)])
    images, rate, _ = FL.pooled_floors([[o] for o in obs])
    assert mean_floor(images) == pytest.approx(true, rel=0.25)
    assert rate == pytest.approx(noise, rel=0.25)  # votes per straight boundary pixel = the flip fraction
    e = images[0][0]
    assert e.resampling == 0 and e.floor == e.noise and e.fit_area == e.area


def test_floor_at_a_lower_fit_resolution_counts_the_resampling():
    """480 x 640 polygons fitted at 240 x 320: the true floor is the resampled observation against the
    polygon rasterised at the low-resolution pixel centres."""
    H, W, h, w = 480, 640, 240, 320
    true, est = [], []
    for i, (s, pts, tris) in enumerate(stars(H, W)):
        o = add_boundary_noise(s, 0.05, np.random.default_rng(i))
        r = FL.resample_silhouette(o, h, w)
        low = rasterize((pts + 0.5) * [w / W, h / H] - 0.5, tris, h, w)  # pixel centres at integers
        true.append(np.count_nonzero(r ^ low) / np.count_nonzero(r))
        e = FL.estimate_floor(o, fit_shape=(h, w))
        assert e.fit_shape == (h, w) and e.resampling > 0
        est.append(e.floor)
    assert np.mean(true) > 0.003  # the resampling is most of it (noise alone: ~0.2 %)
    assert np.mean(est) == pytest.approx(np.mean(true), rel=0.25)


def test_the_resampling_copy_matches_the_fitters():
    from clothfit.core.fitting import job

    rng = np.random.default_rng(3)
    for _ in range(5):
        m = rng.random((96, 128)) < 0.4
        for h, w in [(48, 64), (24, 32), (30, 50)]:
            assert np.array_equal(FL.resample_silhouette(m, h, w), job.resample_silhouette(m, h, w))
            assert np.array_equal(FL.resample_ignore(m, h, w), job.resample_ignore(m, h, w))


def test_an_ignore_mask_hides_the_edge_it_cuts():
    """A ragged cut along an occluder is no observation noise: pixels next to the ignore mask do not vote."""
    s, _, _ = stars(240, 320, k=1)[0]
    ign = np.zeros_like(s)
    ign[:, 160:] = True
    rng = np.random.default_rng(0)
    ragged = s.copy()
    band = np.zeros_like(s)
    rows = np.nonzero(s[:, 158:162].any(1))[0]
    band[rows.min() : rows.max() + 1, 158:160] = True  # 2 px of the cloth's cut along the occluder
    ragged[band & (rng.random(s.shape) < 0.5)] ^= True
    clean_half = FL.estimate_floor(s, ign)
    ragged_half = FL.estimate_floor(ragged, ign)
    assert ragged_half.votes == clean_half.votes
    assert ragged_half.floor < 0.0005
    assert ragged_half.area == np.count_nonzero(ragged & ~ign)


# ---------------------------------------------------------------- a model's silhouette as the baseline


def wavy(H, W, phase, lobes=7, amp=0.25, r0=0.32, n=120):
    """A folded outline (a disc whose radius waves ``lobes`` times round), rasterised at pixel centres: at
    60 x 80 its staircase votes like noise."""
    cx, cy = W / 2 + 0.3, H / 2 - 0.2
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    rad = min(H, W) * r0 * (1 + amp * np.sin(lobes * t + phase))
    pts = np.concatenate([[[cx, cy]], np.stack([cx + rad * np.cos(t), cy + rad * np.sin(t)], 1)])
    tris = np.array([[0, 1 + i, 1 + (i + 1) % n] for i in range(n)])
    return rasterize(pts, tris, H, W)


def folded_capture(H=60, W=80, k=12, noise=0.05):
    clean = [wavy(H, W, 0.7 * i) for i in range(k)]
    obs = [add_boundary_noise(c, noise, np.random.default_rng(i)) for i, c in enumerate(clean)]
    true = np.mean([np.count_nonzero(o ^ c) / np.count_nonzero(o) for o, c in zip(obs, clean)])
    return clean, obs, true


def test_a_models_clean_silhouette_as_baseline_brings_a_folded_outline_to_its_floor():
    """At 60 x 80 the image-only estimate counts the folds' staircase as noise; with the clean model as the
    baseline the floor is within 15 % of the truth's error."""
    clean, obs, true = folded_capture()
    image_only = mean_floor(FL.pooled_floors([[o] for o in obs])[0])
    images, _, basis = FL.pooled_floors([[o] for o in obs], model=[[c] for c in clean])
    assert image_only > 1.3 * true  # the failure this mends
    assert mean_floor(images) == pytest.approx(true, rel=0.15)
    assert basis.startswith("model baseline") and images[0][0].basis == basis
    # noise-free: the model's own staircase is no noise
    assert mean_floor(FL.pooled_floors([[c] for c in clean], model=[[c] for c in clean])[0]) < 0.1 * true


def test_a_wrong_models_silhouette_does_not_lower_the_floor():
    clean, obs, true = folded_capture()
    right = mean_floor(FL.pooled_floors([[o] for o in obs], model=[[c] for c in clean])[0])
    for kw in (dict(phase=0.04), dict(amp=0.27)):  # 2.6x and 4x the truth's error: a wrong basin
        wrong = [wavy(60, 80, 0.7 * i + kw.get("phase", 0), amp=kw.get("amp", 0.25)) for i in range(len(clean))]
        assert np.mean([np.count_nonzero(o ^ m) / np.count_nonzero(o) for o, m in zip(obs, wrong)]) > 2 * true
        images, _, basis = FL.pooled_floors([[o] for o in obs], model=[[m] for m in wrong])
        assert basis.startswith("model baseline")
        assert mean_floor(images) >= 0.9 * right
    # a model far from the images (another shape) is no baseline: the image-only estimate, and the basis says so
    far = [wavy(60, 80, 0.7 * i, lobes=5) for i in range(len(clean))]
    images, _, basis = FL.pooled_floors([[o] for o in obs], model=[[m] for m in far])
    assert "too little to serve as the baseline" in basis
    assert mean_floor(images) == pytest.approx(mean_floor(FL.pooled_floors([[o] for o in obs])[0]))


def test_model_silhouettes_of_another_size_or_count_are_refused():
    clean, obs, _ = folded_capture(k=2)
    with pytest.raises(ClothFitError, match="model silhouette is 30x40"):
        FL.pooled_floors([[o] for o in obs], model=[[c[::2, ::2]] for c in clean])
    with pytest.raises(ClothFitError, match="camera by camera"):
        FL.pooled_floors([[o] for o in obs], model=[[clean[0]]])


# ---------------------------------------------------------------- bad input: one line


@pytest.mark.parametrize(
    "obs,ign,fs,msg",
    [
        (np.zeros((20, 30), bool), None, None, "empty"),
        (np.ones((20, 30), bool), np.ones((20, 30), bool), None, "empty outside the ignore mask"),
        (np.ones((20, 30), bool), np.zeros((10, 30), bool), None, "ignore mask is 10x30"),
        (np.full((20, 30), 7, np.uint8), None, None, "not binary"),
        (np.ones((2, 20, 30), bool), None, None, "2D"),
        (np.ones((20, 30), bool), None, (0, 15), "fit resolution"),
        (np.ones((20, 30), bool), None, "10x15", "fit resolution"),
    ],
)
def test_bad_input_is_one_line(obs, ign, fs, msg):
    with pytest.raises(ClothFitError) as e:
        FL.estimate_floor(obs, ign, fs, name="camera 'c1' frame 2")
    assert msg in str(e.value) and "\n" not in str(e.value)
    if msg != "fit resolution" and msg != "2D" and msg != "not binary":
        assert "camera 'c1' frame 2" in str(e.value)


def test_bad_input_of_the_other_helpers():
    with pytest.raises(ClothFitError, match="no silhouettes"):
        FL.pooled_floors([])
    with pytest.raises(ClothFitError, match="errors but"):
        FL.floor_ratios([0.1, 0.2], [0.1])
    with pytest.raises(ClothFitError, match="non-negative"):
        FL.floor_ratios([0.1], [-0.1])
    r, far = FL.floor_ratios([0.0, 0.02, 0.05], [0.0, 0.0, 0.01])
    assert r[0] == 1 and np.isinf(r[1]) and r[2] == pytest.approx(5) and list(far) == [False, True, True]
    with pytest.raises(ClothFitError, match="differ in size"):
        FL.residual_profile(np.ones((5, 5)), np.ones((5, 6)))


def test_a_tiny_shape_falls_back_to_the_whole_outline():
    m = np.zeros((20, 20), bool)
    m[5:12, 6:11] = True
    e = FL.estimate_floor(m)
    assert e.straight < FL.MIN_STRAIGHT and e.basis.startswith("whole outline")


# ---------------------------------------------------------------- where a residual lies


def test_residual_profile_tells_a_rim_from_a_shift():
    s, _, _ = stars(240, 320, k=1)[0]
    eroded = s & ~FL.inner_boundary(s)  # a segmenter that lost a 1-px rim all round
    p = FL.residual_profile(eroded, s)
    assert p["rim_share"] > 0.98 and p["balance"] == 1.0 and p["bias_px"] == pytest.approx(1.0, rel=0.15)
    shifted = np.roll(s, 12, axis=1)  # the shape in the wrong place
    q = FL.residual_profile(s, shifted)
    assert q["rim_share"] < 0.5 and abs(q["balance"]) < 0.05
    assert np.isnan(FL.residual_profile(s, s)["rim_share"])


# ---------------------------------------------------------------- a capture, the overlays, the CLI


@pytest.fixture(scope="module")
def small_cap(tmp_path_factory):
    from clothfit.core.observation.camera import load_rig
    from clothfit.core.observation.capture import load_capture
    from clothfit.core.observation.synth import synth_capture
    from clothfit.core.physics.scenario import paper_scenario

    root = str(tmp_path_factory.mktemp("floorcap") / "cap")
    cams = [c.resized(240, 320) for c in load_rig("lab18")][:3]
    synth_capture(root, None, noise=0.05, cameras=cams, scenario=paper_scenario(frame_times=[0.3, 0.6, 0.9]))
    return load_capture(root)


def test_capture_floor_pools_and_reports(small_cap):
    cf = FL.capture_floor(small_cap, cams=[0, 2], fidx=[0, 2])
    d = cf.to_dict()
    assert cf.per_image().shape == (2, 2) and d["cameras"] == ["cam00", "cam02"] and d["frame_times"] == [0.3, 0.9]
    assert d["floor"] == pytest.approx(cf.per_image().mean()) and d["resampling"] == 0
    assert d["rate"] == pytest.approx(0.05, rel=0.3) and "lower bound" in d["limits"]
    json.dumps(d)
    low = FL.capture_floor(small_cap, cams=[0], resolution=(120, 160)).to_dict()
    assert low["fit_resolution"] == [120, 160] and low["resampling"] > 0
    with pytest.raises(ClothFitError, match="no cameras"):
        FL.capture_floor(small_cap, cams=[])


def test_mark_floor_and_floor_sheet_colours():
    from clothfit.core.observation import overlay as OV

    img = np.zeros((60, 80, 3), np.uint8)
    assert tuple(OV.mark_floor(img, 0.012, 0.01)[0, 40]) == OV.FLOOR_AT_RGB
    assert tuple(OV.mark_floor(img, 0.02, 0.01)[0, 40]) == OV.FLOOR_ABOVE_RGB
    assert tuple(OV.mark_floor(img, 0.05, 0.01)[0, 40]) == OV.FLOOR_FAR_RGB
    assert tuple(OV.mark_floor(img, 0.05, 0.0)[0, 40]) == OV.FLOOR_FAR_RGB
    e = np.array([[0.01, 0.05], [0.02, 0.011]])
    f = np.full((2, 2), 0.01)
    sheet = OV.floor_sheet(e, f, ["a", "b"], [0.1, 0.2], cell=64)
    lw, hh = max(60, 64 // 2 + 20), 22
    colour = lambda i, j: tuple(sheet[hh + i * 64 + 2, lw + j * 64 + 2])  # noqa: E731
    assert colour(0, 0) == OV.FLOOR_AT_RGB and colour(0, 1) == OV.FLOOR_FAR_RGB
    assert colour(1, 0) == OV.FLOOR_ABOVE_RGB and colour(1, 1) == OV.FLOOR_AT_RGB
    with pytest.raises(ClothFitError, match="2 x 2 errors but 1 cameras"):
        OV.floor_sheet(e, f, ["a"], [0.1, 0.2])


def test_capture_overlays_with_floors_adds_the_sheet_and_keeps_the_rest(small_cap, tmp_path):
    import cv2
    from clothfit.core import defaults as D
    from clothfit.core.observation.overlay import capture_overlays

    plain = capture_overlays(small_cap, D.GT_PARAMS, str(tmp_path / "plain"))
    floors = FL.capture_floor(small_cap).per_image()
    marked = capture_overlays(small_cap, D.GT_PARAMS, str(tmp_path / "marked"), floors=floors)
    assert os.path.basename(marked[-2]) == "floor_sheet.png" and len(marked) == len(plain) + 1
    for a, b in zip(plain[:-1], marked[:-2]):  # the per-image overlays are unchanged
        assert os.path.relpath(a, tmp_path / "plain") == os.path.relpath(b, tmp_path / "marked")
        assert np.array_equal(cv2.imread(a), cv2.imread(b))
    with pytest.raises(ClothFitError, match="floors are"):
        capture_overlays(small_cap, D.GT_PARAMS, str(tmp_path / "bad"), floors=floors[:1])


def test_cli_floor_and_overlay_floor(small_cap, tmp_path, capsys):
    from clothfit.cli import main

    assert (
        main(["floor", small_cap.root, "--cameras", "0,1", "--times", "0.3", "--json", str(tmp_path / "f.json")]) == 0
    )
    d = json.loads(capsys.readouterr().out)
    assert d["n_images"] == 2 and d == json.loads((tmp_path / "f.json").read_text())
    assert main(["overlay", small_cap.root, "--floor", "--out", str(tmp_path / "ov"), "--cameras", "0"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert os.path.isfile(d["floor_sheet"]) and d["floor_sheet"] not in d["images"]
