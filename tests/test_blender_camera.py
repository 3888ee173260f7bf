"""Blender camera <-> OpenCV camera: exact round trips, and rendered pixels where OpenCV projects."""

import numpy as np
import pytest
from blender_support import bpy, factory  # noqa: F401

cv2 = pytest.importorskip("cv2")

from clothfit.blender import render as R  # noqa: E402
from clothfit.blender import scene as S  # noqa: E402
from clothfit.core.observation.camera import Camera, look_at  # noqa: E402
from clothfit.core.observation.raster import rasterize, silhouette  # noqa: E402

pytestmark = pytest.mark.usefixtures("factory")

# lens, sensor w, sensor h, fit, res x, res y, percentage, pixel aspect x, y, shift x, y
CASES = [
    (50.0, 36.0, 24.0, "AUTO", 640, 480, 100, 1.0, 1.0, 0.0, 0.0),
    (35.0, 32.0, 24.0, "VERTICAL", 1000, 700, 50, 1.0, 1.2, 0.1, -0.05),
    (80.0, 36.0, 24.0, "HORIZONTAL", 480, 640, 100, 2.0, 1.0, -0.2, 0.15),
    (28.0, 36.0, 20.0, "AUTO", 360, 640, 100, 1.0, 1.0, 0.07, 0.11),  # AUTO resolves vertical
    (60.0, 23.5, 15.6, "AUTO", 517, 333, 75, 1.0, 1.5, -0.03, -0.12),  # AUTO, par makes it vertical
    (120.0, 30.0, 40.0, "VERTICAL", 333, 517, 100, 1.3, 1.0, 0.2, 0.0),
]


def make_camera(scene, case, name="cam"):
    lens, sw, sh, fit, rx, ry, pct, ax, ay, shx, shy = case
    r = scene.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = rx, ry, pct
    r.pixel_aspect_x, r.pixel_aspect_y = ax, ay
    data = bpy.data.cameras.new(name)
    data.lens, data.sensor_width, data.sensor_height, data.sensor_fit = lens, sw, sh, fit
    data.shift_x, data.shift_y = shx, shy
    obj = bpy.data.objects.new(name, data)
    scene.collection.objects.link(obj)
    obj.location = (0.3, -0.45, 0.25)
    obj.rotation_euler = (1.1, 0.05, 0.6)
    bpy.context.view_layer.update()
    return obj


def blender_settings(scene, obj):
    d, r = obj.data, scene.render
    return dict(
        lens=d.lens,
        sensor_width=d.sensor_width,
        sensor_height=d.sensor_height,
        fit=d.sensor_fit,
        shift=(d.shift_x, d.shift_y),
        size=S.render_size(scene),
        par=r.pixel_aspect_y / r.pixel_aspect_x,
        matrix=np.array(obj.matrix_world),
    )


@pytest.mark.parametrize("case", CASES)
def test_blender_to_opencv_to_blender_same_camera(case):
    scene = bpy.context.scene
    obj = make_camera(scene, case)
    before = blender_settings(scene, obj)
    cam = S.camera_from_blender(obj, scene)
    assert (cam.width, cam.height) == before["size"]
    # scramble what the conversion must recover, then convert back into the same camera
    obj.data.lens, obj.data.shift_x, obj.data.shift_y = 17.0, 0.0, 0.0
    obj.matrix_world = obj.matrix_world.Identity(4)
    S.camera_to_blender(cam, obj, scene)
    bpy.context.view_layer.update()
    after = blender_settings(scene, obj)
    assert after["fit"] == before["fit"] and after["size"] == before["size"]
    assert scene.render.resolution_percentage == case[6]
    assert after["lens"] == pytest.approx(before["lens"], rel=1e-6)
    assert after["sensor_width"] == before["sensor_width"] and after["sensor_height"] == before["sensor_height"]
    assert after["shift"][0] == pytest.approx(before["shift"][0], abs=1e-6)
    assert after["shift"][1] == pytest.approx(before["shift"][1], abs=1e-6)
    assert after["par"] == pytest.approx(before["par"], rel=1e-7)
    np.testing.assert_allclose(after["matrix"], before["matrix"], atol=1e-6)


@pytest.mark.parametrize("case", CASES)
def test_blender_camera_into_fresh_scene_gives_same_projection(case):
    scene = bpy.context.scene
    obj = make_camera(scene, case)
    cam = S.camera_from_blender(obj, scene)
    # a fresh scene (default 1920x1080) and a default camera (sensor 36 mm, AUTO)
    other = bpy.data.scenes.new("other")
    data = bpy.data.cameras.new("fresh")
    fresh = bpy.data.objects.new("fresh", data)
    other.collection.objects.link(fresh)
    S.camera_to_blender(cam, fresh, other)
    back = S.camera_from_blender(fresh, other)
    assert (back.width, back.height) == (cam.width, cam.height)
    np.testing.assert_allclose(back.K, cam.K, rtol=1e-6, atol=1e-4)
    np.testing.assert_allclose(back.R, cam.R, atol=1e-6)
    np.testing.assert_allclose(back.t, cam.t, atol=1e-6)


def random_opencv_camera(rng, W, H):
    fx = rng.uniform(300, 2000)
    fy = fx / rng.choice([1.0, 1.25, 0.8])
    cx = (W - 1) / 2 + rng.uniform(-0.1, 0.1) * W
    cy = (H - 1) / 2 + rng.uniform(-0.1, 0.1) * H
    eye = rng.normal(size=3)
    eye = 0.6 * eye / np.linalg.norm(eye)
    R, t = look_at(eye, rng.normal(scale=0.02, size=3))
    K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    return Camera(K, R, t, W, H, "cv")


@pytest.mark.parametrize("fit", ["AUTO", "HORIZONTAL", "VERTICAL"])
@pytest.mark.parametrize("size", [(640, 480), (480, 640), (333, 517)])
def test_opencv_to_blender_to_opencv(fit, size):
    rng = np.random.default_rng(hash((fit, size)) % 2**32)
    scene = bpy.context.scene
    for i in range(4):
        cam = random_opencv_camera(rng, *size)
        data = bpy.data.cameras.new(f"c{i}")
        data.sensor_fit = fit
        obj = bpy.data.objects.new(f"c{i}", data)
        scene.collection.objects.link(obj)
        S.camera_to_blender(cam, obj, scene)
        bpy.context.view_layer.update()
        back = S.camera_from_blender(obj, scene, depsgraph=bpy.context.evaluated_depsgraph_get())
        assert (back.width, back.height) == size
        np.testing.assert_allclose(back.K, cam.K, rtol=1e-6, atol=2e-4)
        np.testing.assert_allclose(back.R, cam.R, atol=1e-6)
        np.testing.assert_allclose(back.t, cam.t, atol=1e-6)


def _facing_quad(cam, pixel, depth, half):
    """A square of side 2*half [m], facing the camera, centred on the ray of ``pixel`` at ``depth``."""
    Kinv = np.linalg.inv(cam.K)
    ray = Kinv @ np.array([pixel[0], pixel[1], 1.0])
    c_cam = ray / ray[2] * depth
    offs = np.array([[-half, -half, 0], [half, -half, 0], [half, half, 0], [-half, half, 0]])
    pts_cam = c_cam + offs
    world = (pts_cam - cam.t) @ cam.R  # R^T (x - t)
    centre = (c_cam - cam.t) @ cam.R
    return world, centre


def _polygon_centroid(P):
    x, y = P[:, 0], P[:, 1]
    x1, y1 = np.roll(x, -1), np.roll(y, -1)
    cr = x * y1 - x1 * y
    a = cr.sum() / 2
    return np.array([((x + x1) * cr).sum() / (6 * a), ((y + y1) * cr).sum() / (6 * a)])


@pytest.mark.parametrize("case", [CASES[1], CASES[2], CASES[4]])
def test_rendered_pixel_lands_where_opencv_projects(case):
    """Small quads at chosen pixels: Blender's rendered centroid = cv2.projectPoints (< 0.1 px)."""
    scene = bpy.context.scene
    obj = make_camera(scene, case)
    cam = S.camera_from_blender(obj, scene)
    W, H = cam.width, cam.height
    targets = [(0.2 * W, 0.25 * H), (0.75 * W, 0.7 * H), (0.5 * W + 3.3, 0.5 * H - 7.7), (0.85 * W, 0.15 * H)]
    verts, faces = [], []
    expected = []
    for px in targets:
        world, centre = _facing_quad(cam, px, 0.5, 0.006)
        n = len(verts)
        verts += world.tolist()
        faces.append((n, n + 1, n + 2, n + 3))
        proj, _ = cv2.projectPoints(world.reshape(-1, 1, 3), cv2.Rodrigues(cam.R)[0], cam.t, cam.K, None)
        expected.append(_polygon_centroid(proj.reshape(-1, 2)))
        c, _ = cv2.projectPoints(centre.reshape(1, 1, 3), cv2.Rodrigues(cam.R)[0], cam.t, cam.K, None)
        assert np.allclose(c.ravel(), px, atol=1e-6)
    me = bpy.data.meshes.new("quads")
    me.from_pydata(verts, [], faces)
    quads = bpy.data.objects.new("quads", me)
    scene.collection.objects.link(quads)
    mask = R.render_mask(scene, quads, obj)
    assert mask.shape == (H, W)
    # expected pixels: the cv2-projected quads sampled at pixel centres (integer coordinates)
    tris = np.array([(f[0], f[1], f[2]) for f in faces] + [(f[0], f[2], f[3]) for f in faces])
    proj, _ = cv2.projectPoints(np.array(verts).reshape(-1, 1, 3), cv2.Rodrigues(cam.R)[0], cam.t, cam.K, None)
    want = rasterize(proj.reshape(-1, 2), tris, H, W)
    n, lab = cv2.connectedComponents(mask.astype(np.uint8))
    assert n - 1 == len(targets)
    nw, labw = cv2.connectedComponents(want.astype(np.uint8))
    assert nw == n
    got = [np.array(np.nonzero(lab == k)[::-1]).mean(1) for k in range(1, n)]
    exp = [np.array(np.nonzero(labw == k)[::-1]).mean(1) for k in range(1, nw)]
    for e, poly_c in zip(sorted(exp, key=tuple), sorted(expected, key=tuple)):
        assert np.linalg.norm(e - poly_c) < 0.5  # sampling a ~15 px square moves its centroid < 0.5 px
    for e in exp:
        d = min(np.linalg.norm(g - e) for g in got)
        assert d < 0.05, (case, e, d)
    assert np.count_nonzero(want ^ mask) <= 2, np.count_nonzero(want ^ mask)
    # and the core rasteriser (core projection) agrees as well
    core = silhouette(cam, np.array(verts), tris)
    assert np.count_nonzero(core ^ mask) <= 2, np.count_nonzero(core ^ mask)
