"""Captures from point clouds: splatted silhouettes match the cloth the points were sampled from, the
handle follows the waypoints, the crop is declared, and bad input is one line naming the file or value."""

import json
import math

import cv2
import numpy as np
import pytest
from clothfit import cli
from clothfit.core.errors import ClothFitError
from clothfit.core.footage.point_clouds import flat_square, points_to_capture, read_setup
from clothfit.core.observation.camera import ring_rig
from clothfit.core.observation.capture import load_capture
from clothfit.core.observation.points import read_point_cloud
from clothfit.core.observation.raster import silhouette
from clothfit.core.physics.scenario import ClothGrid

UNIT = 0.5  # metres per unit of the test clouds: the converter must scale them


def _sample(X, tris, n, rng):
    """``n`` points spread uniformly over the triangles (area-weighted)."""
    a, b, c = X[tris[:, 0]], X[tris[:, 1]], X[tris[:, 2]]
    area = np.linalg.norm(np.cross(b - a, c - a), axis=1) / 2
    pick = rng.choice(len(tris), n, p=area / area.sum())
    u, v = rng.random(n), rng.random(n)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    return a[pick] + u[:, None] * (b[pick] - a[pick]) + v[:, None] * (c[pick] - a[pick])


def _sheets():
    """Two poses of a 0.2 m square standing at different tilts (seen face-on by none of the cameras),
    partly below z = 0.1 m."""
    axis = np.array([1.0, 1.0, 0.0]) / math.sqrt(2.0)
    return [ClothGrid(9, side=0.2, origin=(0.0, 0.0, 0.15), rotation=math.radians(a) * axis) for a in (90.0, 60.0)]


def _setup(tmp_path, **change):
    d = {
        "unit_scale": UNIT,
        "frame_interval": 0.1,
        "splat_radius": 0.002,
        "cloth": {"side": 0.2, "grid": 5, "across": [1, 0, 0]},
        "path": {"waypoints": [[0.0, 0.0, 0.05], [0.0, 0.0, 0.15], [0.0, -0.05, 0.25]]},
        "crop": {"point": [0, 0, 0.1], "normal": [0, 0, 1]},
        "cameras": {"count": 4, "resolution": [192, 256]},
    }
    d.update(change)
    p = tmp_path / "setup.json"
    p.write_text(json.dumps(d))
    return p


@pytest.fixture
def clouds(tmp_path):
    folder = tmp_path / "clouds"
    folder.mkdir()
    rng = np.random.default_rng(3)
    for k, g in enumerate(_sheets()):
        np.save(folder / f"{k:03d}.npy", _sample(g.rest, g.triangles, 60000, rng) / UNIT)
    return folder


def test_splatted_silhouettes_match_the_cropped_cloth_the_points_came_from(tmp_path, clouds):
    cap, report = points_to_capture(str(clouds), read_setup(str(_setup(tmp_path))), str(tmp_path / "cap"))
    cap = load_capture(tmp_path / "cap", validate=True)
    assert cap.scenario.crop.to_dict() == {"point": [0.0, 0.0, 0.1], "normal": [0.0, 0.0, 1.0]}
    assert cap.meta["splat_radius_m"] == 0.002 and report["left_out"] == []
    for f, g in enumerate(_sheets()):
        for c, cam in enumerate(cap.cameras):
            obs = cap.load_silhouette(c, f)
            truth = silhouette(cam, g.rest, g.triangles, crop=cap.scenario.crop)
            whole = silhouette(cam, g.rest, g.triangles)
            # a disc reaches past the cloth's outline by its radius at most, and no cloth pixel is missed
            reach = int(np.ceil(cam.K[0, 0] * 0.002 / cam.to_camera(g.rest)[:, 2].min()))
            band = cv2.dilate(truth.astype(np.uint8), np.ones((2 * reach + 1,) * 2, np.uint8)) > 0
            assert not np.any(obs & ~band), (cam.name, f)
            assert np.count_nonzero(truth & ~obs) / truth.sum() < 0.01, (cam.name, f)
            assert np.count_nonzero(obs ^ truth) / truth.sum() < 0.1, (cam.name, f)
            assert np.count_nonzero(obs ^ whole) / whole.sum() > 0.15  # the crop removed a real part


def test_the_handle_follows_the_waypoints_at_the_declared_interval_from_a_flat_turned_square(tmp_path, clouds):
    cap, _ = points_to_capture(str(clouds), read_setup(str(_setup(tmp_path)), frame_interval=0.25), str(tmp_path / "c"))
    sc = cap.scenario
    assert np.allclose(sc.frame_times, [0.0, 0.25])
    (h,) = sc.handles
    assert np.allclose(h.times, [0.0, 0.25, 0.5])  # the path's interval follows the frames' by default
    assert np.allclose(h.positions[0], sc.grid.rest[h.vertex])  # the grasped corner starts under the gripper
    rest = sc.grid.rest
    assert np.ptp(rest[:, 2]) < 1e-12 and abs(rest[0, 2] - 0.05) < 1e-12  # flat, at the first waypoint's height
    far = rest[np.argmax(np.linalg.norm(rest - rest[h.vertex], axis=1))]
    assert np.allclose(far - rest[h.vertex], [0.2 * math.sqrt(2), 0.0, 0.0])  # the diagonal points 'across'


def test_a_square_turned_onto_any_direction_puts_its_opposite_corner_there():
    for ang in (0.0, 45.0, 200.0):
        a = np.array([math.cos(math.radians(ang)), math.sin(math.radians(ang)), 0.0])
        g = flat_square(np.array([0.1, 0.2, 0.3]), a, 0.3, 4)
        assert np.allclose(g.rest[0], [0.1, 0.2, 0.3])
        assert np.allclose(g.rest[-1], np.array([0.1, 0.2, 0.3]) + a * 0.3 * math.sqrt(2))


def test_waypoints_from_a_robot_frame_are_moved_into_the_clouds_frame(tmp_path):
    robot = np.array([[1.0, 2.0, 0.1], [1.0, 2.5, 0.4]])
    np.save(tmp_path / "traj.npy", robot)
    path = {"file": "traj.npy", "frame": {"translation": [1.0, 2.0, 0.0], "scale": 0.5, "z_rotation_deg": 90}}
    s = read_setup(str(_setup(tmp_path, path=path)))
    # ((w - t) / s) @ Rz(90) in units, times the unit scale: (0, 0.5, 0.3) -> (0.5, 0, 0.3) units x 0.5
    assert np.allclose(s.handle.positions, [[0.0, 0.0, 0.1], [0.5, 0.0, 0.4]])


def test_the_command_writes_the_capture_and_reports_it_as_json(tmp_path, clouds, capsys):
    setup = str(_setup(tmp_path))
    code = cli.main(
        ["points-to-capture", str(clouds), setup, "--out", str(tmp_path / "cap"), "--splat-radius", "0.004"]
    )
    got = capsys.readouterr()
    out = json.loads(got.out)
    assert code == 0 and out["splat_radius_m"] == 0.004 and out["frames"] == 2
    assert f"the splatting's own error: {out['splat_floor_pct']:.1f} %" in got.err
    assert load_capture(tmp_path / "cap").meta["splat_radius_m"] == 0.004


@pytest.mark.parametrize(
    "array, says",
    [
        (np.zeros((5, 2)), "shape (5, 2)"),
        (np.array([[0.0, 0.0, np.nan]]), "not finite"),
        (np.array([["a", "b", "c"]]), "not an array of numbers"),
        (np.zeros((0, 3)), "shape (0, 3)"),
    ],
)
def test_a_point_cloud_that_is_not_n_by_3_finite_numbers_is_one_line_naming_the_file(tmp_path, array, says):
    p = tmp_path / "bad.npy"
    np.save(p, array)
    with pytest.raises(ClothFitError) as e:
        read_point_cloud(str(p))
    assert str(p) in str(e.value) and says in str(e.value) and "\n" not in str(e.value)


def test_a_file_that_is_no_npy_array_is_one_line_naming_it(tmp_path):
    p = tmp_path / "000.npy"
    p.write_text("not numpy")
    with pytest.raises(ClothFitError) as e:
        read_point_cloud(str(p))
    assert str(p) in str(e.value) and "\n" not in str(e.value)


@pytest.mark.parametrize("top, says", [(0.7, "no frame keeps"), (0.5, "grasped corner never rises")])
def test_a_crop_plane_above_the_cloth_is_one_line_naming_the_plane(tmp_path, clouds, top, says):
    path = {"waypoints": [[0.0, 0.0, 0.05], [0.0, 0.0, top]]}  # the clouds reach 0.25 m
    setup = read_setup(str(_setup(tmp_path, crop={"point": [0, 0, 0.6], "normal": [0, 0, 1]}, path=path)))
    with pytest.raises(ClothFitError) as e:
        points_to_capture(str(clouds), setup, str(tmp_path / "cap"))
    msg = str(e.value)
    assert "crop plane" in msg and "0.6" in msg and "above the cloth" in msg and says in msg and "\n" not in msg


def test_a_path_of_fewer_than_two_waypoints_is_one_line_naming_it(tmp_path):
    with pytest.raises(ClothFitError) as e:
        read_setup(str(_setup(tmp_path, path={"waypoints": [[0.0, 0.0, 0.05]]})))
    msg = str(e.value)
    assert "waypoints" in msg and "at least two" in msg and "setup.json" in msg and "\n" not in msg


@pytest.mark.parametrize(
    "change, says",
    [
        ({"cameras": {"resolution": 120}}, "resolution"),
        ({"cameras": {"count": 0}}, "count"),
        ({"splat_radius": -1}, "splat_radius"),
        ({"cloth": {"side": 0.2}}, "cloth"),
        ({"frame_interval": "fast"}, "frame_interval"),
        ({"colour": 1}, "colour"),
    ],
)
def test_a_bad_setup_value_is_one_line_naming_it(tmp_path, clouds, change, says):
    with pytest.raises(ClothFitError) as e:
        points_to_capture(str(clouds), read_setup(str(_setup(tmp_path, **change))), str(tmp_path / "cap"))
    assert says in str(e.value) and "\n" not in str(e.value)


def test_a_camera_calibrated_in_a_robot_frame_sees_the_clouds_as_it_saw_the_robots_world(tmp_path, clouds):
    """A camera's calibration against a robot (camera -> robot, metres) and the robot's frame relative to the
    clouds (the path's convention) give a camera that projects the clouds' points where the real one would."""
    truth = ring_rig((1,), (35.0,), 0.8, (0.0, 0.0, 0.15), 64, 48, 70.0, (20.0,))[0]
    a = math.radians(30.0)
    rz = np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])
    move = np.array([0.3, -0.1, 0.05])  # robot = rz @ world + move, the inverse of ((w - move) / s) @ rz
    cam_to_robot = np.hstack([rz @ truth.R.T, (move - rz @ truth.R.T @ truth.t)[:, None]])
    np.save(tmp_path / "tcr.npy", cam_to_robot)
    real = {
        "name": "side",
        "intrinsics": [70.0, 70.0, 31.5, 23.5],
        "camera_to_frame": "tcr.npy",
        "resolution": [48, 64],
        "frame": {"translation": move.tolist(), "scale": UNIT, "z_rotation_deg": 30.0},
    }
    setup = read_setup(str(_setup(tmp_path, cameras={"real": [real]})))
    cap, report = points_to_capture(str(clouds), setup, str(tmp_path / "cap"))
    assert report["cameras"] == ["side"]
    X = np.random.default_rng(0).uniform(-0.1, 0.2, (50, 3))
    assert np.allclose(cap.cameras[0].project(X), truth.project(X), atol=1e-9)
    wrong = dict(real, frame=dict(real["frame"], scale=1.0))
    with pytest.raises(ClothFitError) as e:
        read_setup(str(_setup(tmp_path, cameras={"real": [wrong]})))
    assert "scale" in str(e.value) and "\n" not in str(e.value)


def test_a_capture_from_point_clouds_reads_its_real_points_back_in_metres_above_its_crop(tmp_path, clouds):
    from clothfit.core.fitting.evaluate import evaluate
    from clothfit.core.observation.metrics import points_to_cloth_m
    from clothfit.core.observation.points import capture_points

    points_to_capture(str(clouds), read_setup(str(_setup(tmp_path))), str(tmp_path / "cap"))
    cap = load_capture(tmp_path / "cap")
    got = capture_points(cap, [0, 1])
    for P, g in zip(got, _sheets()):
        assert len(P) > 1000 and P[:, 2].min() >= 0.1  # scaled to metres, cropped as the silhouettes were
        assert points_to_cloth_m(P, g.rest, g.triangles).max() < 1e-9  # on the sheet they were sampled from
    r = evaluate(cap, {"tension_stiffness": 15.0})
    assert len(r["points_mm_per_time"]) == 2 and np.isfinite(r["points_mm"]) and r["points_mm"] > 0
    clouds.rename(tmp_path / "moved")
    with pytest.raises(ClothFitError, match=r"point cloud .*000.npy is not there"):
        capture_points(cap, [0])


def test_the_converter_states_each_frames_scatter_and_evaluate_reads_it_as_it_would_measure_it(tmp_path, clouds):
    import json

    from clothfit.core.fitting.evaluate import evaluate
    from clothfit.core.observation.metrics import points_scatter_m
    from clothfit.core.observation.points import capture_points

    points_to_capture(str(clouds), read_setup(str(_setup(tmp_path))), str(tmp_path / "cap"))
    cap = load_capture(tmp_path / "cap")
    stated = cap.meta["points_scatter_mm"]
    measured = [1000.0 * points_scatter_m(P).mean() for P in capture_points(cap, [0, 1])]
    assert len(stated) == 2 and np.allclose(stated, measured, atol=1e-4)
    r = evaluate(cap, {"tension_stiffness": 15.0})
    assert r["points_scatter_mm"] == pytest.approx(np.mean(measured), abs=1e-4)
    path = tmp_path / "cap" / "capture.json"
    d = json.loads(path.read_text())
    del d["meta"]["points_scatter_mm"]  # a capture converted before the converter stated it: measured instead
    path.write_text(json.dumps(d))
    assert evaluate(load_capture(tmp_path / "cap"), {"tension_stiffness": 15.0})["points_scatter_mm"] == (
        pytest.approx(np.mean(measured), rel=1e-12)
    )
    d["meta"]["points_scatter_mm"] = [0.1]
    path.write_text(json.dumps(d))
    with pytest.raises(ClothFitError) as e:
        evaluate(load_capture(tmp_path / "cap"), {"tension_stiffness": 15.0})
    assert "points_scatter_mm" in str(e.value) and "\n" not in str(e.value)


def test_frames_before_the_first_frame_are_left_out_keeping_their_times(tmp_path, clouds):
    cap, report = points_to_capture(str(clouds), read_setup(str(_setup(tmp_path, first_frame=1))), str(tmp_path / "c"))
    assert report["frame_times"] == [0.1] and report["left_out"] == ["000.npy"]
    with pytest.raises(ClothFitError, match=r"first_frame 2: the folder .* has only 2 frames"):
        points_to_capture(str(clouds), read_setup(str(_setup(tmp_path, first_frame=2))), str(tmp_path / "d"))
    with pytest.raises(ClothFitError, match=r"first_frame: -1 must be a whole number"):
        read_setup(str(_setup(tmp_path, first_frame=-1)))


def test_a_sparse_cloud_splatted_with_large_discs_and_eroded_back_keeps_the_outline_and_fills_the_holes(tmp_path):
    from clothfit.core.footage.point_clouds import splat

    g = _sheets()[0]
    cam = ring_rig((1,), (20.0,), 0.8, g.rest.mean(0), 256, 192, 250.0, (0.0,))[0]
    truth = silhouette(cam, g.rest, g.triangles)
    sparse = _sample(g.rest, g.triangles, 1500, np.random.default_rng(5))

    def err(o):
        return np.count_nonzero(o ^ truth) / truth.sum()

    plain, closed = splat(cam, sparse, 0.004), splat(cam, sparse, 0.008, erode=0.005)
    assert err(closed) < 0.6 * err(plain)  # holes filled, the outline not pushed out by the large discs
    assert np.count_nonzero(truth & ~closed) < np.count_nonzero(truth & ~plain)
    with pytest.raises(ClothFitError, match=r"erode_radius: 0.01 m must be below the splat radius 0.008 m"):
        read_setup(str(_setup(tmp_path, splat_radius=0.008, erode_radius=0.01)))


def test_the_stated_splat_floor_is_the_error_the_cloth_the_points_came_from_scores_against_them(tmp_path):
    """The splatting's own error (a perfect model against silhouettes splatted from its own sparse points): what
    ``splat_floor`` states for a cloth must match what the true cloth scores against a capture made from points
    sampled on it, image by image on average."""
    from clothfit.core.footage.point_clouds import splat_floor

    folder = tmp_path / "sparse"
    folder.mkdir()
    rng = np.random.default_rng(11)
    sheets = _sheets()
    for k, g in enumerate(sheets):
        np.save(folder / f"{k:03d}.npy", _sample(g.rest, g.triangles, 2500, rng) / UNIT)
    points_to_capture(str(folder), read_setup(str(_setup(tmp_path, splat_radius=0.004))), str(tmp_path / "cap"))
    cap = load_capture(tmp_path / "cap")
    crop = cap.scenario.crop
    truth = np.array(
        [
            [
                np.count_nonzero(silhouette(cam, g.rest, g.triangles, crop=crop) ^ cap.load_silhouette(c, f))
                / cap.load_silhouette(c, f).sum()
                for f, g in enumerate(sheets)
            ]
            for c, cam in enumerate(cap.cameras)
        ]
    )
    V = np.stack([g.rest for g in sheets])
    stated = splat_floor(cap.cameras, V, sheets[0].triangles, crop, cap.meta["points_per_frame"], 0.004)
    assert truth.mean() > 0.03  # sparse enough for the splatting to matter
    assert abs(stated.mean() / truth.mean() - 1.0) < 0.15, (stated.mean(), truth.mean())
    assert np.corrcoef(stated.ravel(), truth.ravel())[0, 1] > 0.7  # and image by image, not only on average


def test_a_capture_from_points_states_its_splat_floor_and_every_floor_of_its_images_honours_it(tmp_path, clouds):
    from clothfit.core.observation.floor import capture_floor

    points_to_capture(str(clouds), read_setup(str(_setup(tmp_path, splat_radius=0.004))), str(tmp_path / "cap"))
    cap = load_capture(tmp_path / "cap")
    sf = cap.meta["splat_floor"]
    assert sf["cameras"] == cap.camera_names and sf["frame_times"] == [0.0, 0.1]
    # at t = 0 the default cloth lies flat below the crop (the real points stand above it): not estimable there
    assert [row[0] for row in sf["per_image"]] == [None] * 4
    P = np.array([row[1] for row in sf["per_image"]])
    assert P.min() > 0.05
    cf = capture_floor(cap)
    assert np.all(cf.per_image()[:, 1] >= P - 1e-12) and [e.splat for e in cf.images[0]] == [0.0, P[0]]
    assert "splatting" in cf.basis
    one = capture_floor(cap, [2], [1])  # a subset finds its own images' values by camera name and time
    assert one.images[0][0].splat == P[2]
    sf["per_image"] = [[0.1]]
    with pytest.raises(ClothFitError, match=r"capture.json meta splat_floor: per_image must be 4 x 2"):
        capture_floor(cap)


def test_a_floor_raised_by_splatting_leaves_the_intervals_pixel_noise_as_it_was(tmp_path, clouds):
    """The intervals' pixel-noise threshold reads an image's noise, not the splatting's error (which is not a
    random flip of boundary pixels): the same with and without the capture's splat floor."""
    from clothfit.core.fitting.intervals import pixel_threshold
    from clothfit.core.observation.floor import capture_floor

    points_to_capture(str(clouds), read_setup(str(_setup(tmp_path, splat_radius=0.004))), str(tmp_path / "cap"))
    cap = load_capture(tmp_path / "cap")
    with_splat = [e for row in capture_floor(cap).images for e in row]
    del cap.meta["splat_floor"]
    without = [e for row in capture_floor(cap).images for e in row]
    assert any(a.floor > 2 * b.floor for a, b in zip(with_splat, without))

    def thr(ims):
        return pixel_threshold([e.noise + e.resampling for e in ims], [e.rim * e.fit_area for e in ims])

    assert (
        thr(with_splat)
        == thr(without)
        == pixel_threshold([e.floor for e in without], [e.rim * e.fit_area for e in without])
    )
