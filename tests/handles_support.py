"""Synthetic footage for the handles tests: known 3-D clip trajectories seen by a few cameras.

Each clip is drawn as a round marker (dark rim, bright centre: its intensity an analytic function of
the distance to the projected point, so its position is exact to any sub-pixel) of a fixed physical
size over a static textured background; frames are 8-bit with a little sensor noise.
"""

from __future__ import annotations

import math
import os

import numpy as np
from clothfit.core.observation.camera import Camera, intrinsics, look_at

CLOTH_W, CLOTH_H = 0.30, 0.24
TOP_Z = 0.55
CLIP_RADIUS_M = 0.008


def rig(n=4, width=640, height=480, fx=800.0, distance=1.0, distort=True):
    cams = []
    target = np.array([0.0, 0.0, TOP_Z - 0.1])
    for i, az in enumerate(np.linspace(-65, 65, n)):
        a = math.radians(az - 90.0)
        el = math.radians(12.0 + 6 * (i % 2))
        eye = target + distance * np.array([math.cos(el) * math.cos(a), math.cos(el) * math.sin(a), math.sin(el)])
        R, t = look_at(eye, target)
        dist = np.array([-0.08 + 0.02 * i, 0.02, 0.0005, -0.0004, 0.0]) if distort else np.zeros(0)
        cams.append(Camera(intrinsics(fx, width, height), R, t, width, height, f"cam{i}", dist))
    return cams


def clip_tracks(times, release_time=0.21, moving=True):
    """name -> (F, 3) world positions: 'left' fixed at the top-left corner, 'right' released at
    ``release_time`` (falls: 0.5 a s^2 + j s^3 / 6), 'middle' on the top edge (moved sideways and up
    if ``moving``)."""
    t = np.asarray(times, dtype=np.float64)
    left = np.tile([-CLOTH_W / 2, 0.0, TOP_Z], (t.size, 1))
    pin = np.array([CLOTH_W / 2, 0.0, TOP_Z])
    s = np.maximum(t - release_time, 0.0)[:, None]
    a = np.array([-2.0, 0.5, -11.0])
    j = np.array([15.0, 0.0, 30.0])
    right = pin + 0.5 * a * s**2 + j * s**3 / 6.0
    mid = np.tile([0.0, 0.0, TOP_Z], (t.size, 1))
    if moving:
        mid = mid + np.stack([0.03 * np.sin(2.0 * t), 0.01 * t, 0.02 * (1 - np.cos(3.0 * t))], 1)
    return {"left": left, "right": right, "middle": mid}


def background(cam, seed):
    import cv2

    rng = np.random.default_rng(seed)
    small = rng.uniform(60, 200, (cam.height // 8 + 1, cam.width // 8 + 1)).astype(np.float32)
    big = cv2.resize(small, (cam.width, cam.height), interpolation=cv2.INTER_CUBIC)
    return np.clip(big + rng.normal(0, 8, big.shape), 0, 255).astype(np.float32)


def render(cam, bg, points, rng, noise=1.5):
    """An 8-bit grey frame: ``bg`` with a marker at each world point."""
    img = bg.copy()
    for X in points:
        uv = cam.project(X)
        if not np.all(np.isfinite(uv)):
            continue
        z = float(cam.to_camera(X)[2])
        R = cam.K[0, 0] * CLIP_RADIUS_M / z
        x0, x1 = int(max(0, uv[0] - R - 3)), int(min(cam.width, uv[0] + R + 4))
        y0, y1 = int(max(0, uv[1] - R - 3)), int(min(cam.height, uv[1] + R + 4))
        if x0 >= x1 or y0 >= y1:
            continue
        yy, xx = np.mgrid[y0:y1, x0:x1].astype(np.float64)
        r = np.hypot(xx - uv[0], yy - uv[1])
        cover = np.clip(R + 0.5 - r, 0.0, 1.0)  # 1 px soft edge
        ang = np.arctan2(yy - uv[1], xx - uv[0])
        val = 25.0 + 200.0 * np.exp(-((r / (0.3 * R)) ** 2)) + 40.0 * (np.cos(2 * ang) > 0) * (r > 0.5 * R)
        img[y0:y1, x0:x1] = img[y0:y1, x0:x1] * (1 - cover) + val * cover
    return np.clip(np.round(img + rng.normal(0, noise, img.shape)), 0, 255).astype(np.uint8)


def write_footage(folder, cams, times, tracks, seed=0, noise=1.5):
    """footage/<camera>/000.png ... with the markers of ``tracks`` (name -> (F, 3))."""
    import cv2

    rng = np.random.default_rng(seed)
    for ci, cam in enumerate(cams):
        d = os.path.join(folder, cam.name)
        os.makedirs(d, exist_ok=True)
        bg = background(cam, seed * 100 + ci)
        for f in range(len(times)):
            img = render(cam, bg, [tr[f] for tr in tracks.values()], rng, noise)
            cv2.imwrite(os.path.join(d, f"{f:03d}.png"), img)


def marks_for(cams, tracks, frame=0, sigma=0.5, seed=0, which=None, extra=None):
    """The marks JSON a user would click: the true projections at ``frame`` plus Gaussian click noise."""
    rng = np.random.default_rng(seed)
    hs = []
    for name, tr in tracks.items():
        cams_h = which.get(name, cams) if which else cams
        m = {c.name: (c.project(tr[frame]) + rng.normal(0, sigma, 2)).tolist() for c in cams_h}
        h = {"name": name, "marks": m}
        h.update((extra or {}).get(name, {}))
        hs.append(h)
    return {"frame": frame, "handles": hs}
