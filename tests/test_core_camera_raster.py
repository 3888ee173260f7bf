import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

"""Cameras (OpenCV convention, resizing, look_at, files, the lab18 rig, the training-camera rule),
the rasteriser (pixel-centre sampling) and the silhouette metrics / noise model."""

import json

import cv2
import numpy as np
import pytest
from clothfit.core import defaults as D
from clothfit.core.errors import ClothFitError
from clothfit.core.observation import camera as C
from clothfit.core.observation import metrics, raster
from clothfit.core.physics.models import simulate
from clothfit.core.physics.scenario import paper_scenario


def _random_rotation(rng):
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


def _random_camera(rng, dist=None, w=640, h=480):
    R = _random_rotation(rng)
    t = rng.normal(scale=0.1, size=3) + [0, 0, 0.8]
    K = np.array(
        [
            [rng.uniform(400, 1200), 0, rng.uniform(250, 390)],
            [0, rng.uniform(400, 1200), rng.uniform(180, 300)],
            [0, 0, 1],
        ]
    )
    return C.Camera(K, R, t, w, h, name="rnd", dist=np.zeros(0) if dist is None else dist)


def _points_in_front(cam, rng, n=200):
    """World points whose camera-frame z is in 0.3..2 and which are within ~45 degrees of the axis."""
    xc = np.stack([rng.uniform(-0.6, 0.6, n), rng.uniform(-0.5, 0.5, n), np.ones(n)], 1) * rng.uniform(0.3, 2.0, (n, 1))
    return (xc - cam.t) @ cam.R  # X = R^T (xc - t)


# -------------------------------------------------------------------- projection


@pytest.mark.parametrize(
    "dist", [None, np.array([-0.21, 0.07, 1.3e-3, -7e-4, 0.012]), np.array([0.1, -0.05, -2e-3, 1e-3])]
)
def test_project_equals_cv2_projectPoints(dist):
    rng = np.random.default_rng(11)
    for _ in range(5):
        cam = _random_camera(rng, dist)
        X = _points_in_front(cam, rng)
        ours = cam.project(X)
        rvec, _ = cv2.Rodrigues(cam.R)
        ref, _ = cv2.projectPoints(X.reshape(-1, 1, 3), rvec, cam.t, cam.K, np.zeros(5) if dist is None else dist)
        err = np.abs(ours - ref.reshape(-1, 2)).max()
        assert err < 1e-6, err


def test_project_rational_model_uses_cv2_and_matches_it():
    rng = np.random.default_rng(5)
    dist = np.array([-0.2, 0.05, 1e-3, -1e-3, 0.01, 0.02, -0.01, 0.003])
    cam = _random_camera(rng, dist)
    X = _points_in_front(cam, rng, 50)
    rvec, _ = cv2.Rodrigues(cam.R)
    ref, _ = cv2.projectPoints(X.reshape(-1, 1, 3), rvec, cam.t, cam.K, dist)
    assert np.abs(cam.project(X) - ref.reshape(-1, 2)).max() < 1e-6


def test_project_points_behind_the_camera_are_nan_and_distort_flag():
    rng = np.random.default_rng(2)
    dist = np.array([-0.3, 0.1, 0, 0, 0])
    cam = _random_camera(rng, dist)
    X = _points_in_front(cam, rng, 10)
    behind = cam.center - (X - cam.center)  # mirrored through the centre: z < 0
    uv = cam.project(np.concatenate([X, behind]))
    assert np.all(np.isfinite(uv[:10])) and np.all(np.isnan(uv[10:]))
    # distort=False is the pinhole projection K [R t] X
    P = cam.P
    h = np.c_[X, np.ones(len(X))] @ P.T
    assert np.allclose(cam.project(X, distort=False), h[:, :2] / h[:, 2:], atol=1e-9)
    assert np.abs(cam.project(X, distort=False) - uv[:10]).max() > 0.1


@pytest.mark.parametrize("new_hw", [(120, 160), (60, 80), (960, 1280), (240, 200)])
def test_resized_keeps_the_pixel_centre_convention(new_hw):
    rng = np.random.default_rng(3)
    cam = _random_camera(rng, np.array([-0.1, 0.02, 0, 0, 0]))
    X = _points_in_front(cam, rng, 100)
    uv = cam.project(X)
    H2, W2 = new_hw
    cam2 = cam.resized(H2, W2)
    assert (cam2.height, cam2.width) == (H2, W2)
    sx, sy = W2 / cam.width, H2 / cam.height
    expect = np.stack([(uv[:, 0] + 0.5) * sx - 0.5, (uv[:, 1] + 0.5) * sy - 0.5], 1)
    assert np.abs(cam2.project(X) - expect).max() < 1e-9
    # the image rectangle [-0.5, W-0.5] x [-0.5, H-0.5] maps onto the new one
    assert np.allclose(cam2.K[:2, 2], [(cam.K[0, 2] + 0.5) * sx - 0.5, (cam.K[1, 2] + 0.5) * sy - 0.5])
    # R, t, dist and name unchanged
    assert np.array_equal(cam2.R, cam.R) and np.array_equal(cam2.t, cam.t)
    assert np.array_equal(cam2.dist, cam.dist) and cam2.name == cam.name


def test_look_at_gives_a_rotation_and_centres_the_target():
    rng = np.random.default_rng(4)
    for _ in range(20):
        eye = rng.normal(size=3)
        target = rng.normal(scale=0.2, size=3)
        R, t = C.look_at(eye, target)
        assert np.abs(R @ R.T - np.eye(3)).max() < 1e-12
        assert abs(np.linalg.det(R) - 1.0) < 1e-12
        cam = C.Camera(C.intrinsics(800, 640, 480), R, t, 640, 480)
        assert np.allclose(cam.center, eye, atol=1e-12)
        assert np.allclose(cam.forward, (target - eye) / np.linalg.norm(target - eye), atol=1e-12)
        assert np.allclose(cam.project(target), [319.5, 239.5], atol=1e-9)
    # degenerate: looking straight down still gives a proper rotation
    R, t = C.look_at([0, 0, 1.0], [0, 0, 0])
    assert np.abs(R @ R.T - np.eye(3)).max() < 1e-12 and abs(np.linalg.det(R) - 1) < 1e-12


def test_look_at_puts_world_up_up_and_world_right_right():
    # a camera on the -y axis looking at the origin along +y: world +x is image right, world +z image up
    R, t = C.look_at([0.0, -1.0, 0.0], [0.0, 0.0, 0.0])
    cam = C.Camera(C.intrinsics(800, 640, 480), R, t, 640, 480)
    c = cam.project([0.0, 0.0, 0.0])
    assert cam.project([0.0, 0.0, 0.05])[1] < c[1]  # above -> smaller row
    assert cam.project([0.05, 0.0, 0.0])[0] > c[0]  # +x -> larger column


def test_lab18_images_are_upright():
    target = np.array([0.0, 0.0, 0.06])
    for cam in C.load_rig("lab18"):
        if abs(cam.forward[2]) > 0.9:  # the two top-down cameras have no "up"
            continue
        assert cam.project(target + [0, 0, 0.02])[1] < cam.project(target)[1], cam.name


# ------------------------------------------------------------------ camera files


def _two_cameras():
    rng = np.random.default_rng(9)
    a = _random_camera(rng, np.array([-0.1, 0.01, 1e-4, -2e-4, 0.003]))
    a.name = "left"
    b = _random_camera(rng)
    b.name = "right"
    return [a, b]


def test_cameras_json_round_trip(tmp_path):
    cams = _two_cameras()
    p = str(tmp_path / "cams.json")
    C.save_cameras(p, cams, extra={"note": "x"})
    back = C.load_cameras(p)
    assert [c.name for c in back] == ["left", "right"]
    for a, b in zip(cams, back):
        assert np.array_equal(a.K, b.K) and np.array_equal(a.R, b.R) and np.array_equal(a.t, b.t)
        assert np.array_equal(a.dist, b.dist)
        assert (a.width, a.height) == (b.width, b.height)
    with open(p) as f:
        d = json.load(f)
    assert "opencv" in d["convention"] and d["note"] == "x"


def _write(tmp_path, name, obj_or_text):
    p = tmp_path / name
    p.write_text(obj_or_text if isinstance(obj_or_text, str) else json.dumps(obj_or_text))
    return str(p)


def _cam_dicts():
    return {"cameras": [c.to_dict() for c in _two_cameras()]}


def _mutate(fn):
    d = _cam_dicts()
    fn(d["cameras"][1])
    return d


@pytest.mark.parametrize(
    "name,content,needle",
    [
        ("bad_json.json", '{"cameras": [', "not valid JSON"),
        ("not_rotation.json", _mutate(lambda c: c.update(R=(2 * np.eye(3)).tolist())), "not a rotation"),
        ("reflection.json", _mutate(lambda c: c.update(R=np.diag([1.0, 1.0, -1.0]).tolist())), "not a rotation"),
        ("neg_focal.json", _mutate(lambda c: c["K"][0].__setitem__(0, -500.0)), "focal"),
        ("bad_K_shape.json", _mutate(lambda c: c.update(K=[[1, 0, 0], [0, 1, 0]])), "3x3"),
        ("bad_t_shape.json", _mutate(lambda c: c.update(t=[0, 0])), "t 3"),
        ("missing_R.json", _mutate(lambda c: c.pop("R")), "lacks R"),
        ("non_numeric.json", _mutate(lambda c: c.update(t=["a", 0, 0])), "non-numeric"),
        ("no_list.json", {"cams": []}, "'cameras' list"),
        ("empty.json", {"cameras": []}, "empty"),
        ("dup_names.json", {"cameras": [_cam_dicts()["cameras"][0]] * 2}, "not unique"),
        ("zero_size.json", _mutate(lambda c: c.update(width=0)), "must be positive"),
    ],
)
def test_bad_camera_files_raise_naming_the_file(tmp_path, name, content, needle):
    p = _write(tmp_path, name, content)
    with pytest.raises(ClothFitError) as e:
        C.load_cameras(p)
    msg = str(e.value)
    assert p in msg, msg
    assert needle in msg, msg


def test_missing_camera_file(tmp_path):
    p = str(tmp_path / "nope.json")
    with pytest.raises(ClothFitError, match="not found") as e:
        C.load_cameras(p)
    assert p in str(e.value)
    with pytest.raises(ClothFitError, match="no_such_rig"):
        C.load_rig("no_such_rig")


# ----------------------------------------------------------------- lab18 rig


@pytest.fixture(scope="module")
def rig():
    return C.load_rig("lab18")


@pytest.fixture(scope="module")
def paper_motion():
    sc = paper_scenario()
    r = simulate(sc, [D.GT_PARAMS])
    assert not r.exploded[0]
    return sc, r.positions[0]


def test_lab18_rig_shape(rig):
    assert len(rig) == 18
    assert all((c.height, c.width) == (480, 640) for c in rig)
    assert len({c.name for c in rig}) == 18
    assert C.load_rig(C.rig_path("lab18")) is not None


def test_lab18_every_camera_sees_the_whole_motion(rig, paper_motion):
    sc, X = paper_motion
    assert X.shape == (30, 256, 3)
    margin = 10.0
    for cam in rig:
        uv = cam.project(X)
        assert np.all(np.isfinite(uv)), cam.name
        assert uv[..., 0].min() >= margin and uv[..., 0].max() <= cam.width - 1 - margin, cam.name
        assert uv[..., 1].min() >= margin and uv[..., 1].max() <= cam.height - 1 - margin, cam.name
        # and the cloth is not a speck: its silhouette covers a reasonable area at every frame
        for f in (0, 14, 29):
            assert raster.silhouette(cam, X[f], sc.grid.triangles).sum() > 500


def _dir(cams, i, target):
    v = cams[i].center - target
    return v / np.linalg.norm(v)


def test_spread_order_rule(rig):
    o1 = C.spread_order(rig)
    o2 = C.spread_order(list(rig))
    assert o1 == o2
    assert sorted(o1) == list(range(18)) and o1[0] == 0
    assert C.spread_order(rig, first=5)[0] == 5
    target = C._rig_target(rig)
    dirs = np.array([_dir(rig, i, target) for i in range(18)])
    # greedy farthest-point rule: each next camera maximises the minimum angle to those chosen
    for k in range(1, 18):
        chosen = o1[:k]
        ang = np.degrees(np.arccos(np.clip(dirs @ dirs[chosen].T, -1, 1))).min(1)
        rest = [i for i in range(18) if i not in chosen]
        assert ang[o1[k]] >= ang[rest].max() - 1e-6
    # for two cameras, the two viewing directions are more than 90 degrees apart
    a, b = o1[:2]
    assert np.degrees(np.arccos(dirs[a] @ dirs[b])) > 90.0
    assert np.degrees(np.arccos(rig[a].forward @ rig[b].forward)) > 90.0


def test_select_training_partitions_the_rig(rig):
    prev = []
    for n in range(1, 19):
        train, held = C.select_training(rig, n)
        assert (train, held) == C.select_training(rig, n)
        assert len(train) == n and train == sorted(train) and held == sorted(held)
        assert set(train).isdisjoint(held) and sorted(train + held) == list(range(18))
        assert set(prev) <= set(train)
        prev = train
    for bad in (0, 19):
        with pytest.raises(ClothFitError, match=str(bad)):
            C.select_training(rig, bad)


# ------------------------------------------------------------------ rasteriser


def _random_mesh(rng, H, W, n_tris=25):
    n = int(rng.integers(6, 40))
    pts = rng.uniform(-0.3 * W, 1.3 * W, size=(n, 2))
    pts[:, 1] = rng.uniform(-0.3 * H, 1.3 * H, size=n)
    tris = np.array([rng.choice(n, 3, replace=False) for _ in range(n_tris)])
    pts[0] = pts[1] + 0.37 * (pts[2] - pts[1])  # collinear (degenerate) triangles
    pts[3] = pts[4]  # two coincident vertices (degenerate)
    tris[0] = [0, 1, 2]
    tris[1] = [3, 4, 5]
    if rng.random() < 0.5:
        pts[int(rng.integers(6, n))] = np.nan  # NaN vertex: its triangles are skipped
    # some small triangles and some large overlapping / folded ones
    tris = np.concatenate([tris, tris[:5, ::-1]])
    return pts, tris


def test_rasterize_equals_reference_on_random_meshes():
    rng = np.random.default_rng(21)
    H, W = 23, 31
    total = 0
    for trial in range(60):
        pts, tris = _random_mesh(rng, H, W)
        a = raster.rasterize(pts, tris, H, W)
        b = raster.reference_fill(pts, tris, H, W)
        assert a.shape == (H, W) and a.dtype == bool
        assert np.array_equal(a, b), (trial, int((a ^ b).sum()))
        total += a.sum()
    assert 0 < total < 60 * H * W


def test_rasterize_window_agrees_with_rasterize():
    rng = np.random.default_rng(22)
    H, W = 40, 30
    for trial in range(60):
        pts, tris = _random_mesh(rng, H, W, n_tris=int(rng.integers(2, 8)))
        pts = pts * 0.5 + rng.uniform(-5, 20, size=2)
        full = raster.rasterize(pts, tris, H, W)
        r0, c0, win = raster.rasterize_window(pts, tris, H, W)
        emb = np.zeros((H, W), bool)
        if win.size:
            assert win.any(axis=1)[0] and win.any(axis=1)[-1] and win.any(axis=0)[0] and win.any(axis=0)[-1]
            emb[r0 : r0 + win.shape[0], c0 : c0 + win.shape[1]] = win
        assert np.array_equal(emb, full), trial
    # nothing visible -> empty window
    r0, c0, win = raster.rasterize_window(np.array([[-10.0, -10], [-5, -10], [-5, -3]]), np.array([[0, 1, 2]]), H, W)
    assert win.shape == (0, 0)


def test_rasterize_equals_reference_on_the_projected_cloth(rig, paper_motion):
    sc, X = paper_motion
    tris = sc.grid.triangles
    for ci, f in ((0, 0), (9, 12), (16, 29), (13, 20)):
        cam = rig[ci].resized(60, 80) if ci != 13 else rig[ci].resized(120, 160)
        uv = cam.project(X[f])
        a = raster.rasterize(uv, tris, cam.height, cam.width)
        b = raster.reference_fill(uv, tris, cam.height, cam.width)
        assert a.sum() > 50
        assert np.array_equal(a, b), (ci, f, int((a ^ b).sum()))
        assert np.array_equal(raster.silhouette(rig[ci], X[f], tris, cam.height, cam.width), a)


def test_reference_fill_on_a_point_triangle_agrees_with_rasterize():
    pts = np.array([[3.3, 4.7], [3.3, 4.7], [3.3, 4.7]])
    tris = np.array([[0, 1, 2]])
    assert np.array_equal(raster.reference_fill(pts, tris, 10, 12), raster.rasterize(pts, tris, 10, 12))


def test_axis_aligned_square_pixel_centre_count_and_cv2_is_fatter():
    """Square (1.5, 1.5)-(5.5, 5.5): pixel centres 2..5 in x and y are inside -> 16 pixels."""
    H, W = 12, 12
    pts = np.array([[1.5, 1.5], [5.5, 1.5], [5.5, 5.5], [1.5, 5.5]])
    tris = np.array([[0, 1, 2], [0, 2, 3]])
    m = raster.rasterize(pts, tris, H, W)
    expect = np.zeros((H, W), bool)
    expect[2:6, 2:6] = True
    assert np.array_equal(m, expect)
    assert m.sum() == 16
    # edges through pixel centres are inside: square (2,2)-(5,5) also gives rows/cols 2..5
    pts2 = np.array([[2.0, 2.0], [5.0, 2.0], [5.0, 5.0], [2.0, 5.0]])
    assert np.array_equal(raster.rasterize(pts2, tris, H, W), expect)
    # cv2.fillPoly (sub-pixel coordinates via shift) fills every pixel an edge touches: fatter
    img = np.zeros((H, W), np.uint8)
    cv2.fillPoly(img, [np.round(pts * 16).astype(np.int32)], 1, lineType=cv2.LINE_8, shift=4)
    assert img.sum() > 16
    assert np.all(img[expect] == 1)


def test_rasterize_clips_to_the_image():
    H, W = 8, 10
    pts = np.array([[-20.0, -20.0], [40.0, -20.0], [-20.0, 40.0]])
    m = raster.rasterize(pts, np.array([[0, 1, 2]]), H, W)
    assert m.all()  # a triangle containing the whole image covers all of it
    pts = np.array([[-5.0, -5.0], [-1.0, -5.0], [-1.0, -1.0]])
    assert not raster.rasterize(pts, np.array([[0, 1, 2]]), H, W).any()


# -------------------------------------------------------------------- metrics


def test_e_sil_on_hand_made_images():
    obs = np.zeros((10, 10), bool)
    obs[2:6, 2:6] = True  # 16 pixels
    mod = np.zeros((10, 10), bool)
    mod[2:6, 3:7] = True  # shifted by one column: 4 missing + 4 extra
    assert metrics.e_sil(obs, mod) == pytest.approx(8 / 16)
    assert metrics.e_sil(obs, obs) == 0.0
    assert metrics.e_sil(obs, np.zeros_like(obs)) == 1.0
    big = np.ones((10, 10), bool)
    assert metrics.e_sil(obs, big) == pytest.approx(84 / 16)  # normalised by the OBSERVED area
    assert metrics.e_sil(obs.astype(np.uint8) * 255, mod.astype(np.uint8)) == pytest.approx(0.5)


def test_e_sil_errors():
    obs = np.zeros((10, 10), bool)
    obs[1, 1] = True
    with pytest.raises(ClothFitError, match="10x10.*10x11"):
        metrics.e_sil(obs, np.zeros((10, 11), bool), name="cam3 frame 2")
    with pytest.raises(ClothFitError, match="empty") as e:
        metrics.e_sil(np.zeros((4, 4), bool), np.ones((4, 4), bool), name="cam3 frame 2")
    assert "cam3 frame 2" in str(e.value)


def test_e_all_is_the_sum_over_cameras_and_frames():
    o = np.zeros((6, 6), bool)
    o[1:3, 1:3] = True  # 4 pixels
    m1 = o.copy()
    m1[4, 4] = True  # 1 extra -> 0.25
    m2 = np.zeros_like(o)  # all missing -> 1.0
    obs = [[o, o], [o, o]]
    mod = [[o, m1], [m2, m1]]
    assert metrics.e_all(obs, mod) == pytest.approx(0 + 0.25 + 1.0 + 0.25)


def test_shape_error_mm():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(3, 20, 3))
    b = a.copy()
    b[0] += [0.003, 0, 0]  # 3 mm everywhere
    b[1, :10] += [0, 0.004, 0]  # 4 mm on half the vertices -> mean 2 mm
    e = metrics.shape_error_mm(b, a)
    assert np.allclose(e, [3.0, 2.0, 0.0])
    c = b.copy()
    c[2, 0, 0] = np.nan
    assert metrics.shape_error_mm(c, a)[2] == np.inf
    with pytest.raises(ClothFitError, match="differ"):
        metrics.shape_error_mm(a[:2], a)


def _disc(H=60, W=70, r=17.3):
    yy, xx = np.mgrid[0:H, 0:W]
    return (xx - 33.2) ** 2 + (yy - 29.6) ** 2 <= r * r


def test_boundary_noise_model():
    m = _disc()
    inner, outer = metrics.boundary_pixels(m)
    assert inner.any() and outer.any()
    assert np.all(m[inner]) and not np.any(m[outer])
    n_inner = int(inner.sum())
    expect = int(round(0.05 * n_inner))
    assert expect >= 3
    a = metrics.add_boundary_noise(m, 0.05, np.random.default_rng(7))
    flipped = a ^ m
    assert int(flipped.sum()) == expect
    assert np.all((inner | outer)[flipped])  # only in the boundary band
    assert np.array_equal(a[flipped & inner], np.zeros(int((flipped & inner).sum()), bool))  # missing
    assert np.all(a[flipped & outer])  # extra
    b = metrics.add_boundary_noise(m, 0.05, np.random.default_rng(7))
    assert np.array_equal(a, b)  # reproducible
    c = metrics.add_boundary_noise(m, 0.05, np.random.default_rng(8))
    assert not np.array_equal(a, c)  # another seed, another pattern
    assert int((c ^ m).sum()) == expect
    assert np.array_equal(metrics.add_boundary_noise(m, 0.0, np.random.default_rng(7)), m)
    big = metrics.add_boundary_noise(m, 0.5, np.random.default_rng(1))
    assert int((big ^ m).sum()) == int(round(0.5 * n_inner))
    assert np.array_equal(m, _disc())  # input untouched
    with pytest.raises(ClothFitError, match="1.5"):
        metrics.add_boundary_noise(m, 1.5, np.random.default_rng(0))
