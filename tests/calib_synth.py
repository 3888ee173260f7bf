"""Synthetic ChArUco views for the calibration tests: the board's printed image seen through known
cameras (OpenCV distortion included), no Blender.

Every pixel of the distorted image is traced back exactly: ``cv2.undistortPoints`` gives its
normalised ray, the ray meets the board plane, and the printed image is sampled there. Rendered at
``SUPERSAMPLE`` x the size and area-averaged down (anti-aliasing), then Gaussian sensor noise.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from clothfit.core.observation.camera import Camera, intrinsics, look_at

SUPERSAMPLE = 3
PX_PER_SQUARE = 120  # resolution of the printed image the views sample


def board_print(board, margin_squares=0.5):
    """The printed sheet: (image, metres per pixel, margin [m]); board coordinates (x, y) map to
    pixel ((x + margin) / mpp - 0.5, (y + margin) / mpp - 0.5)."""
    sx, sy = board.squares_x, board.squares_y
    margin_px = int(round(margin_squares * PX_PER_SQUARE))
    img = board.cv_board().generateImage(
        (sx * PX_PER_SQUARE + 2 * margin_px, sy * PX_PER_SQUARE + 2 * margin_px), marginSize=margin_px, borderBits=1
    )
    mpp = board.square_m / PX_PER_SQUARE
    return img, mpp, margin_px * mpp


_RAYS: dict = {}


def camera_rays(cam: Camera) -> np.ndarray:
    """Unit-depth rays ``(H*s*W*s, 3)`` of the supersampled pixel centres of ``cam`` (cached: they
    depend on the intrinsics only)."""
    key = (cam.K.tobytes(), cam.dist.tobytes(), cam.width, cam.height)
    if key not in _RAYS:
        s = SUPERSAMPLE
        H, W = cam.height * s, cam.width * s
        yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
        u = (xx + 0.5) / s - 0.5
        v = (yy + 0.5) / s - 0.5
        pts = np.stack([u.ravel(), v.ravel()], -1).reshape(-1, 1, 2)
        if cam.dist.size and np.any(cam.dist != 0):
            n = cv2.undistortPointsIter(
                pts, cam.K, cam.dist, None, None, (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-10)
            ).reshape(-1, 2)
        else:
            n = cv2.undistortPoints(pts, cam.K, None).reshape(-1, 2)
        _RAYS.clear()  # one camera at a time: memory
        _RAYS[key] = np.concatenate([n, np.ones((n.shape[0], 1))], 1)
    return _RAYS[key]


def render_view(cam: Camera, board, pose, printed=None, noise=1.5, rng=None, background=110):
    """Grey uint8 image of ``board`` at ``pose`` = (R, t) board -> world, seen by ``cam``."""
    img, mpp, margin = printed if printed is not None else board_print(board)
    s = SUPERSAMPLE
    H, W = cam.height * s, cam.width * s
    rays = camera_rays(cam)
    Rb, tb = pose
    # board -> camera: X_c = R_c (Rb X + tb) + t_c; a ray point lam * d in board coordinates is
    # Rbc^T (lam d - tbc), on the board where its z is 0
    Rbc = cam.R @ Rb
    tbc = cam.R @ tb + cam.t
    nz = Rbc[:, 2]
    denom = rays @ nz
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = (nz @ tbc) / denom
    Xb = (lam[:, None] * rays - tbc) @ Rbc
    mx = (Xb[:, 0] + margin) / mpp - 0.5
    my = (Xb[:, 1] + margin) / mpp - 0.5
    bad = ~(lam > 0)
    mx[bad] = -1e6
    my[bad] = -1e6
    out = cv2.remap(
        img,
        mx.reshape(H, W).astype(np.float32),
        my.reshape(H, W).astype(np.float32),
        interpolation=cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=background,
    )
    out = cv2.resize(out.astype(np.float32), (cam.width, cam.height), interpolation=cv2.INTER_AREA)
    out = 30 + out * (200 / 255)  # paper is not pure white, ink not black
    if noise:
        rng = rng or np.random.default_rng(0)
        out = out + rng.normal(0, noise, out.shape)
    return np.clip(np.round(out), 0, 255).astype(np.uint8)


def facing(cam: Camera, board, pose, min_cos=0.25) -> bool:
    """The printed face turned towards the camera (its normal within acos(min_cos) of the view
    direction) and every corner of the board inside the image."""
    Rb, tb = pose
    centre = Rb @ np.array([board.squares_x * board.square_m / 2, board.squares_y * board.square_m / 2, 0]) + tb
    face = -Rb[:, 2]  # out of the printed face
    to_cam = cam.center - centre
    if face @ to_cam / np.linalg.norm(to_cam) < min_cos:
        return False
    w, h = board.size_m
    uv = cam.project(np.array([[0, 0, 0], [w, 0, 0], [w, h, 0], [0, h, 0]]) @ Rb.T + tb)
    return bool(
        np.all(np.isfinite(uv))
        and np.all(uv >= 2)
        and np.all(uv[:, 0] <= cam.width - 3)
        and np.all(uv[:, 1] <= cam.height - 3)
    )


def write_dataset(folder, board, cams, poses, seed=0, noise=1.5, ext=".png"):
    """One folder per camera, one image per moment where the board faces it and is in view;
    moments named m000, m001 ... Returns {camera: [moments written]}."""
    import os

    rng = np.random.default_rng(seed)
    printed = board_print(board)
    out = {}
    for cam in cams:
        os.makedirs(os.path.join(folder, cam.name), exist_ok=True)
        out[cam.name] = []
        for k, pose in enumerate(poses):
            if not facing(cam, board, pose):
                continue
            img = render_view(cam, board, pose, printed, noise, rng)
            cv2.imwrite(os.path.join(folder, cam.name, f"m{k:03d}{ext}"), img)
            out[cam.name].append(f"m{k:03d}")
    return out


def wave_poses(board, cams, n=24, seed=0, height=0.18):
    """The board flat on the table (moment 0), then ``n`` poses held up round the middle, each
    turned towards a random pair of neighbouring cameras, tilted and rolled a little."""
    rng = np.random.default_rng(seed)
    poses = [board_pose_flat(board, yaw_deg=rng.uniform(-20, 20))]
    for k in range(n):
        i = k % len(cams)
        j = (i + 1) % len(cams)
        a = rng.uniform(0.2, 0.8)
        towards = a * cams[i].center + (1 - a) * cams[j].center
        centre = np.array([rng.uniform(-0.06, 0.06), rng.uniform(-0.06, 0.06), height + rng.uniform(-0.05, 0.05)])
        poses.append(board_pose_facing(board, centre, towards, rng.uniform(-25, 25), rng.uniform(-30, 30)))
    return poses


def rot(axis, deg):
    return cv2.Rodrigues(np.asarray(axis, float) / np.linalg.norm(axis) * math.radians(deg))[0]


FLIP = np.diag([1.0, -1.0, -1.0])  # board frame (x right, y down the print, z into it) <-> Z-up world


def board_pose_flat(board, centre=(0.0, 0.0, 0.0), yaw_deg=0.0):
    """The board lying face up, its centre at ``centre``: the calibration's world frame when centre = 0, yaw = 0."""
    c = np.array([board.squares_x * board.square_m / 2, board.squares_y * board.square_m / 2, 0.0])
    R = rot([0, 0, 1], yaw_deg) @ FLIP
    return R, np.asarray(centre, float) - R @ c


def board_pose_facing(board, centre, towards, tilt_deg=0.0, roll_deg=0.0):
    """The board held up with its printed face towards the point ``towards``."""
    c = np.array([board.squares_x * board.square_m / 2, board.squares_y * board.square_m / 2, 0.0])
    # board z (into the print) points away from ``towards``
    Rc, _ = look_at(np.asarray(towards, float), np.asarray(centre, float))  # rows: x, y, z of a camera at towards
    R = Rc.T @ rot([1, 0, 0], tilt_deg) @ rot([0, 0, 1], roll_deg)
    return R, np.asarray(centre, float) - R @ c


def phone_rig(n=4, width=480, height=640, distance=0.75, seed=0):
    """``n`` phone-like portrait cameras round the origin, different focal lengths and distortion."""
    rng = np.random.default_rng(seed)
    cams = []
    for i in range(n):
        az = 2 * math.pi * i / n + rng.uniform(-0.2, 0.2)
        el = math.radians(rng.uniform(28, 40))
        eye = distance * np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
        R, t = look_at(eye, [0.0, 0.0, 0.08])
        fx = width * rng.uniform(0.85, 1.15)
        K = intrinsics(
            fx, width, height, cx=(width - 1) / 2 + rng.uniform(-6, 6), cy=(height - 1) / 2 + rng.uniform(-6, 6)
        )
        dist = np.array(
            [rng.uniform(-0.12, -0.02), rng.uniform(0.0, 0.06), rng.uniform(-1e-3, 1e-3), rng.uniform(-1e-3, 1e-3)]
        )
        cams.append(Camera(K, R, t, width, height, name=f"phone{i}", dist=dist))
    return cams


def cameras_in_world(cams, board, pose0):
    """The cameras in the calibration's world frame: the board at ``pose0`` (board -> scene), origin at
    its chessboard's centre, X along its squares_x direction, Z out of its printed face."""
    Rb, tb = pose0
    c = np.array([board.squares_x * board.square_m / 2, board.squares_y * board.square_m / 2, 0.0])
    out = []
    for cam in cams:
        R = cam.R @ Rb @ FLIP
        t = cam.R @ (Rb @ c + tb) + cam.t
        out.append(Camera(cam.K, R, t, cam.width, cam.height, cam.name, cam.dist))
    return out


def errors(truth, est):
    """Per camera: focal error [%], centre error [mm], rotation error [deg]."""
    out = {}
    for t, e in zip(truth, est):
        assert t.name == e.name
        dR = e.R @ t.R.T
        ang = math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(dR) - 1) / 2))))
        out[t.name] = {
            "focal_pct": 100 * abs(e.K[0, 0] / t.K[0, 0] - 1),
            "centre_mm": 1000 * float(np.linalg.norm(e.center - t.center)),
            "rotation_deg": ang,
        }
    return out
