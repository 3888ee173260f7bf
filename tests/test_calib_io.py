"""Camera import/export (addon/core/footage/calib_io.py): OpenCV FileStorage, COLMAP, distortion."""

import json

import cv2
import numpy as np
import pytest
from clothfit.core.errors import ClothFitError
from clothfit.core.footage import calib_io as CI
from clothfit.core.footage import colmap as CM
from clothfit.core.observation.camera import Camera, intrinsics, load_rig, look_at
from clothfit.core.observation.raster import rasterize


def rig(n=3, dist=None, skewless=True):
    cams = []
    for i in range(n):
        R, t = look_at([0.5 * np.cos(1.3 * i), 0.5 * np.sin(1.3 * i), 0.2 + 0.1 * i], [0, 0, 0.06])
        K = intrinsics(900.0 + 10 * i, 640, 480, fy=905.0 + 10 * i, cx=321.25 - i, cy=238.75 + i)
        d = np.zeros(0) if dist is None else np.asarray(dist[i % len(dist)], float)
        cams.append(Camera(K, R, t, 640, 480, name=f"cam{i:02d}", dist=d))
    return cams


def same(a, b, tol=1e-9):
    assert len(a) == len(b)
    for x, y in zip(a, b):
        assert x.name == y.name and (x.width, x.height) == (y.width, y.height)
        assert np.allclose(x.K, y.K, atol=tol) and np.allclose(x.R, y.R, atol=tol) and np.allclose(x.t, y.t, atol=tol)
        dx = np.zeros(8)
        dy = np.zeros(8)
        dx[: min(8, x.dist.size)] = x.dist[:8]
        dy[: min(8, y.dist.size)] = y.dist[:8]
        assert np.allclose(dx, dy, atol=tol)


DISTS = [[-0.21, 0.05, 0.001, -0.002, 0.01], [0.1, -0.02, 0.0, 0.0, 0.0], []]


# --------------------------------------------------------------------- OpenCV


@pytest.mark.parametrize("ext", [".yml", ".yaml", ".json", ".xml"])
def test_opencv_multi_file_round_trip(tmp_path, ext):
    cams = rig(3, DISTS)
    p = str(tmp_path / ("cams" + ext))
    CI.export_cameras(cams, p)
    back = CI.import_cameras(p)
    same(cams, back)


def test_opencv_per_camera_files_round_trip(tmp_path):
    cams = rig(3, DISTS)
    files = CI.write_opencv_dir(str(tmp_path / "calib"), cams)
    assert len(files) == 3
    same(cams, CI.import_cameras(str(tmp_path / "calib")))
    same(cams[1:2], CI.import_cameras(files[1]))


def test_lab18_round_trips_through_every_format(tmp_path):
    cams = load_rig("lab18")
    for fmt, p in (("opencv", "a.yml"), ("opencv-dir", "b"), ("colmap", "c"), ("json", "d.json")):
        CI.export_cameras(cams, str(tmp_path / p), fmt)
        same(cams, CI.import_cameras(str(tmp_path / p)), tol=1e-9)


def test_handwritten_opencv_files(tmp_path):
    R, t = look_at([0.4, 0.1, 0.3], [0, 0, 0])
    rvec = cv2.Rodrigues(R)[0].ravel()
    # plain YAML (no %YAML header), rvec/tvec, image_size [w, h], camelCase
    y = tmp_path / "plain.yaml"
    y.write_text(
        "cameraMatrix: [[800, 0, 319.5], [0, 800, 239.5], [0, 0, 1]]\n"
        "distCoeffs: [-0.1, 0.01, 0, 0]\n"
        f"rvec: [{rvec[0]!r}, {rvec[1]!r}, {rvec[2]!r}]\n"
        f"tvec: [{t[0]!r}, {t[1]!r}, {t[2]!r}]\n"
        "imageSize: [640, 480]\n"
    )
    c = CI.import_cameras(str(y))[0]
    assert c.name == "plain" and (c.width, c.height) == (640, 480)
    assert np.allclose(c.R, R, atol=1e-12) and np.allclose(c.dist, [-0.1, 0.01, 0, 0])
    # OpenCV JSON with opencv-matrix nodes, two cameras as top-level maps, K and R/T
    j = tmp_path / "stereo.json"
    mat = lambda a: {
        "type_id": "opencv-matrix",
        "rows": a.shape[0],
        "cols": a.shape[1],
        "dt": "d",
        "data": a.ravel().tolist(),
    }
    import json

    j.write_text(
        json.dumps(
            {
                "left": {
                    "K": mat(np.array([[700.0, 0, 300], [0, 700, 200], [0, 0, 1]])),
                    "R": mat(np.eye(3)),
                    "T": mat(np.zeros((3, 1))),
                    "width": 600,
                    "height": 400,
                },
                "right": {
                    "K": mat(np.array([[700.0, 0, 300], [0, 700, 200], [0, 0, 1]])),
                    "R": mat(R),
                    "T": mat(t.reshape(3, 1)),
                    "width": 600,
                    "height": 400,
                },
                "baseline_note": "not a camera",
            }
        )
    )
    cams = CI.import_cameras(str(j))
    assert [c.name for c in cams] == ["left", "right"] and np.allclose(cams[1].t, t)
    # no image size in the file: taken from the caller
    n = tmp_path / "nosize.yml"
    n.write_text(
        "%YAML:1.0\n---\nK: [800, 0, 320, 0, 800, 240, 0, 0, 1]\nR: [1, 0, 0, 0, 1, 0, 0, 0, 1]\nt: [0, 0, 1]\n"
    )
    with pytest.raises(ClothFitError, match="no image size"):
        CI.import_cameras(str(n))
    assert CI.import_cameras(str(n), width=640, height=480)[0].width == 640


@pytest.mark.parametrize(
    "content, needle",
    [
        ("", "empty"),
        ("K: [[1, 0, 0], [0, 1, 0]\n  oops: [", "could not be parsed"),
        ("foo: 1\nbar: [1, 2]\n", "no camera found"),
        ("K: [800, 0, 320, 0, 800, 240, 0, 0, 1]\nt: [0, 0, 1]\nimage_width: 64\nimage_height: 48\n", "no extrinsics"),
        (
            "K: [800, 0, 320, 0, 800, 240, 0, 0, 1]\nR: [1, 0, 0, 0, 1, 0, 0, 0, 1]\nimage_width: 64\nimage_height: 48\n",
            "no translation",
        ),
        (
            "K: [800, 0, 320, 0, 800]\nR: [1, 0, 0, 0, 1, 0, 0, 0, 1]\nt: [0, 0, 1]\nimage_width: 64\nimage_height: 48\n",
            "must have 9 values",
        ),
        (
            "K: [800, 0, 320, 0, 800, 240, 0, 0, 1]\nR: [1, 0, 0, 0, 1, 0, 0, 0, 1]\nrvec: [0.5, 0, 0]\nt: [0, 0, 1]\n"
            "image_width: 64\nimage_height: 48\n",
            "disagree",
        ),
        (
            "K: [800, 0, 320, 0, 800, 240, 0, 0, 1]\nR: [1, 0, 0, 0, 1, 0, 0, 0, -1]\nt: [0, 0, 1]\n"
            "image_width: 64\nimage_height: 48\n",
            "not a rotation",
        ),
        (
            "K: [800, 0, 320, 0, 800, 240, 0, 0, 1]\nR: [1, 0, 0, 0, 1, 0, 0, 0, 1]\nt: [0, 0, 1]\nD: [0.1, 0.2, 0.3]\n"
            "image_width: 64\nimage_height: 48\n",
            "4 or 5",
        ),
    ],
)
def test_opencv_bad_files(tmp_path, content, needle):
    p = tmp_path / "bad.yml"
    p.write_text(content)
    with pytest.raises(ClothFitError) as ei:
        CI.import_cameras(str(p))
    assert needle in str(ei.value) and "bad.yml" in str(ei.value)


def test_missing_and_unknown(tmp_path):
    with pytest.raises(ClothFitError, match="not found"):
        CI.import_cameras(str(tmp_path / "nope.yml"))
    (tmp_path / "x.abc").write_text("1")
    with pytest.raises(ClothFitError, match="cannot tell"):
        CI.import_cameras(str(tmp_path / "x.abc"))
    with pytest.raises(ClothFitError, match="format"):
        CI.import_cameras(str(tmp_path / "x.abc"), fmt="bogus")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ClothFitError, match="no OpenCV calibration files"):
        CI.import_cameras(str(tmp_path / "empty"))
    with pytest.raises(ClothFitError, match="no cameras"):
        CI.export_cameras([], str(tmp_path / "a.yml"))


def test_duplicate_names_refused(tmp_path):
    cams = rig(2)
    cams[1].name = "cam00"
    CI.write_opencv(str(tmp_path / "d.yml"), cams)
    with pytest.raises(ClothFitError, match="not unique"):
        CI.import_cameras(str(tmp_path / "d.yml"))


# ---------------------------------------------------------------------- COLMAP


def colmap_project(model, params, qvec, tvec, X):
    """COLMAP's own projection, written from its documentation (pixel centres at +0.5)."""
    R = CM._quat_to_R(np.asarray(qvec, float))
    Xc = X @ R.T + np.asarray(tvec)
    u, v = Xc[:, 0] / Xc[:, 2], Xc[:, 1] / Xc[:, 2]
    p = list(params)
    if model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL"):
        fx = fy = p[0]
        cx, cy = p[1], p[2]
    else:
        fx, fy, cx, cy = p[:4]
    k1 = k2 = p1 = p2 = 0.0
    if model == "SIMPLE_RADIAL":
        k1 = p[3]
    elif model == "RADIAL":
        k1, k2 = p[3], p[4]
    elif model == "OPENCV":
        k1, k2, p1, p2 = p[4:8]
    r2 = u * u + v * v
    radial = k1 * r2 + k2 * r2 * r2
    du = u * radial + 2 * p1 * u * v + p2 * (r2 + 2 * u * u)
    dv = v * radial + 2 * p2 * u * v + p1 * (r2 + 2 * v * v)
    return np.stack([fx * (u + du) + cx, fy * (v + dv) + cy], -1)


MODELS = [
    ("SIMPLE_PINHOLE", [850.0, 320.0, 240.0]),
    ("PINHOLE", [850.0, 860.0, 321.0, 239.0]),
    ("SIMPLE_RADIAL", [850.0, 320.0, 240.0, -0.08]),
    ("RADIAL", [850.0, 320.0, 240.0, -0.08, 0.02]),
    ("OPENCV", [850.0, 860.0, 321.0, 239.0, -0.1, 0.03, 0.001, -0.0015]),
]


@pytest.mark.parametrize("model, params", MODELS)
def test_colmap_models_and_half_pixel_convention(tmp_path, model, params):
    q = np.array([0.9, 0.1, -0.3, 0.2])
    q /= np.linalg.norm(q)
    tv = [0.01, -0.02, 0.5]
    (tmp_path / "cameras.txt").write_text(f"# comment\n7 {model} 640 480 {' '.join(map(str, params))}\n")
    (tmp_path / "images.txt").write_text(
        "# Image list\n"
        f"3 {' '.join(map(str, q))} {' '.join(map(str, tv))} 7 frames/cam05.jpg\n"
        "100.0 200.0 -1 101.5 20.25 4\n"
    )
    cam = CI.import_cameras(str(tmp_path))[0]
    assert cam.name == "cam05" and (cam.width, cam.height) == (640, 480)
    X = np.random.default_rng(0).uniform(-0.05, 0.05, (50, 3))
    ours = cam.project(X)
    theirs = colmap_project(model, params, q, tv, X)
    assert np.allclose(ours, theirs - 0.5, atol=1e-9)  # our pixel centres at integers
    # and back out: the same COLMAP parameters (model may be generalised to OPENCV)
    CI.export_cameras([cam], str(tmp_path / "out"), "colmap")
    again = CI.import_cameras(str(tmp_path / "out"))[0]
    assert np.allclose(again.project(X), ours, atol=1e-9)
    line = [ln for ln in (tmp_path / "out" / "cameras.txt").read_text().splitlines() if not ln.startswith("#")][0]
    vals = [float(v) for v in line.split()[4:]]
    assert vals[2] == pytest.approx(params[1] if model.startswith(("SIMPLE", "RADIAL")) else params[2])
    assert (tmp_path / "out" / "points3D.txt").is_file()


def test_colmap_export_models_and_round_trip(tmp_path):
    cams = rig(3, [[-0.2, 0.05, 0.001, -0.002], [0.1, -0.02, 0, 0, 0.003], []])
    CI.export_cameras(cams, str(tmp_path / "m"), "colmap")
    models = [
        ln.split()[1] for ln in (tmp_path / "m" / "cameras.txt").read_text().splitlines() if not ln.startswith("#")
    ]
    assert models == ["OPENCV", "FULL_OPENCV", "PINHOLE"]
    same(cams, CI.import_cameras(str(tmp_path / "m" / "images.txt")))


def test_colmap_name_collisions_and_sparse_folder(tmp_path):
    d = tmp_path / "proj" / "sparse" / "0"
    d.mkdir(parents=True)
    (d / "cameras.txt").write_text("1 PINHOLE 64 48 50 50 32 24\n")
    (d / "images.txt").write_text("1 1 0 0 0 0 0 1 1 camA/0001.png\n\n2 1 0 0 0 0.1 0 1 1 camB/0001.png\n\n")
    cams = CI.import_cameras(str(tmp_path / "proj"))
    assert [c.name for c in cams] == ["camA_0001", "camB_0001"]
    assert cams[0].K[0, 2] == 31.5


@pytest.mark.parametrize(
    "cams_txt, imgs_txt, needle",
    [
        ("1 FISHEYE 64 48 50 32 24 0.1\n", "1 1 0 0 0 0 0 1 1 a.png\n", "not supported"),
        ("1 PINHOLE 64 48 50 32 24\n", "1 1 0 0 0 0 0 1 1 a.png\n", "needs 4 parameters"),
        ("1 PINHOLE 64 48 50 50 32 24\n", "1 1 0 0 0 0 0 1 2 a.png\n", "camera id 2"),
        ("1 PINHOLE 64 48 50 50 32 24\n", "1 0 0 0 0 0 0 1 1 a.png\n", "quaternion"),
        ("1 PINHOLE 64 48 50 50 32 24\n", "1 1 0 0 x 0 0 1 1 a.png\n", "non-numeric"),
        ("1 PINHOLE 64 48 50 50 32 24\n", "1 1 0 0 0 0 0 1\n", "expected"),
        ("# nothing\n", "1 1 0 0 0 0 0 1 1 a.png\n", "no cameras"),
        ("1 PINHOLE 64 48 50 50 32 24\n", "# none\n", "no images"),
        ("1 PINHOLE 64 48 -50 50 32 24\n", "1 1 0 0 0 0 0 1 1 a.png\n", "focal"),
    ],
)
def test_colmap_bad_files(tmp_path, cams_txt, imgs_txt, needle):
    (tmp_path / "cameras.txt").write_text(cams_txt)
    (tmp_path / "images.txt").write_text(imgs_txt)
    with pytest.raises(ClothFitError) as ei:
        CI.import_cameras(str(tmp_path), fmt="colmap")
    assert needle in str(ei.value)
    assert ".txt" in str(ei.value)


def test_colmap_missing_images_txt(tmp_path):
    (tmp_path / "cameras.txt").write_text("1 PINHOLE 64 48 50 50 32 24\n")
    with pytest.raises(ClothFitError, match="images.txt"):
        CI.import_cameras(str(tmp_path), fmt="colmap")


def test_quaternion_round_trip():
    rng = np.random.default_rng(1)
    Rs = [cv2.Rodrigues(rng.normal(size=3))[0] for _ in range(50)]
    Rs += [np.diag([1.0, -1.0, -1.0]), np.diag([-1.0, 1.0, -1.0]), np.diag([-1.0, -1.0, 1.0]), np.eye(3)]
    for R in Rs:
        q = CM._R_to_quat(R)
        assert q[0] >= 0 and np.allclose(CM._quat_to_R(q), R, atol=1e-12)


def test_colmap_refuses_what_it_cannot_hold():
    c = rig(1)[0]
    c.K[0, 1] = 1.0
    with pytest.raises(ClothFitError, match="skew"):
        CM.intrinsics_to_colmap(c)
    c = rig(1, [[0.1, 0, 0, 0, 0, 0, 0, 0, 0.01, 0, 0, 0]])[0]
    with pytest.raises(ClothFitError, match="no COLMAP model"):
        CM.intrinsics_to_colmap(c)


# ------------------------------------------------------------------- distortion


@pytest.mark.parametrize("dist", DISTS[:2] + [[-0.2, 0.05, 0.001, -0.002, 0.01, 0.02, -0.01, 0.003]])
def test_project_with_distortion_matches_cv2(dist):
    cam = rig(1, [dist])[0]
    X = np.random.default_rng(2).uniform(-0.06, 0.06, (200, 3)) + [0, 0, 0.06]
    ours = cam.project(X)
    rvec = cv2.Rodrigues(cam.R)[0]
    ref, _ = cv2.projectPoints(X, rvec, cam.t, cam.K, cam.dist)
    assert np.allclose(ours, ref.reshape(-1, 2), atol=1e-7)
    # undistortPoints inverts the distortion: back to the distortion-free projection
    und = cv2.undistortPoints(ours.reshape(-1, 1, 2), cam.K, cam.dist, P=cam.K).reshape(-1, 2)
    assert np.allclose(und, cam.project(X, distort=False), atol=1e-3)


def test_undistort_silhouette_matches_undistorted_projection():
    cam = rig(1, [[-0.35, 0.12, 0.0, 0.0, 0.0]])[0]
    cam = cam.resized(240, 320)
    # a dense grid of triangles around the target, big in the image so distortion matters
    n = 40
    xs = np.linspace(-0.2, 0.2, n)
    gx, gy = np.meshgrid(xs, xs)
    V = np.stack([gx.ravel(), gy.ravel(), np.full(n * n, 0.06)], -1)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    T = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])
    distorted = rasterize(cam.project(V), T, cam.height, cam.width)
    undist_cam = CI.undistorted_camera(cam)
    expect = rasterize(undist_cam.project(V), T, cam.height, cam.width)
    got = CI.undistort_silhouette(distorted, cam)
    assert got.dtype == bool and got.shape == distorted.shape
    k = np.ones((3, 3), np.uint8)
    e8 = expect.astype(np.uint8)
    band = (cv2.dilate(e8, k) > 0) & ~(cv2.erode(e8, k) > 0)  # within 1 px of the true boundary
    assert ((distorted ^ expect) & ~band).sum() > 100  # distortion moves the boundary further
    assert ((got ^ expect) & ~band).sum() == 0  # undistorted: only boundary pixels differ
    assert (got ^ expect).sum() < 0.4 * (distorted ^ expect).sum()
    with pytest.raises(ClothFitError, match="camera"):
        CI.undistort_silhouette(distorted[:-1], cam)
    plain = rig(1)[0]
    m = np.zeros((480, 640), np.uint8)
    m[100:200, 100:300] = 1
    assert np.array_equal(CI.undistort_silhouette(m, plain), m > 0)  # no distortion: unchanged


# ------------------------------------------------------------------------- CLI


def test_cli_import_and_export_cameras(tmp_path, capsys):
    from clothfit.cli import main as cli

    cams = rig(3, DISTS)
    CI.export_cameras(cams, str(tmp_path / "colmap"), "colmap")
    assert cli(["import-cameras", str(tmp_path / "colmap"), "-o", str(tmp_path / "cams.json")]) == 0
    same(cams, CI.import_cameras(str(tmp_path / "cams.json")))
    io = capsys.readouterr()
    assert "imported 3 cameras" in io.err and "cam01" in io.err  # for people: stderr
    assert json.loads(io.out) == {
        "command": "import-cameras",
        "out": str(tmp_path / "cams.json"),
        "cameras": ["cam00", "cam01", "cam02"],
    }
    assert cli(["export-cameras", str(tmp_path / "cams.json"), "-o", str(tmp_path / "o.yml")]) == 0
    same(cams, CI.import_cameras(str(tmp_path / "o.yml")))
    assert (
        cli(["export-cameras", str(tmp_path / "cams.json"), "-o", str(tmp_path / "per"), "--format", "opencv-dir"]) == 0
    )
    same(cams, CI.import_cameras(str(tmp_path / "per")))
    # a capture as the source
    from clothfit.core.observation.capture import write_capture
    from clothfit.core.physics.scenario import paper_scenario

    cap = write_capture(str(tmp_path / "cap"), cams, paper_scenario(frame_times=[0.1]), None)
    assert cli(["export-cameras", cap.root, "-o", str(tmp_path / "fromcap")]) == 0
    same(cams, CI.import_cameras(str(tmp_path / "fromcap")))
    # errors: a message naming the file, exit code 2
    assert cli(["import-cameras", str(tmp_path / "missing.yml"), "-o", str(tmp_path / "x.json")]) == 2
    assert "missing.yml" in capsys.readouterr().err
