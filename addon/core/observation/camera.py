"""Pinhole cameras in the OpenCV convention, rigs, and the training-camera rule.

Convention (used by every file this project reads or writes):

* ``x_cam = R @ X_world + t``; camera looks along +Z, +X right, +Y down.
* ``K = [[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` (skew ``s`` is normally 0).
* Pixel ``(row i, col j)`` has its centre at continuous image coordinates
  ``(x=j, y=i)``: pixel centres sit at integers (OpenCV's convention), the image
  spans ``[-0.5, W-0.5] x [-0.5, H-0.5]``. A pixel belongs to a silhouette when
  its centre is inside the projected mesh (this is how Blender samples with
  anti-aliasing off).
* Optional lens distortion ``dist`` in OpenCV's order ``(k1, k2, p1, p2[, k3...])``.

World units are metres; the world is Z-up (as in Blender).
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ..errors import ClothFitError
from ..jsonio import read_json

MAX_IMAGE_SIDE = 16384  # pixels per side of a camera image


def check_camera_name(name: Any, where: str = "camera") -> str:
    """A camera name becomes a folder name (silhouettes, debug images): refuse anything that is not
    one plain path component."""
    if (
        not isinstance(name, str)
        or not name
        or name in (".", "..")
        or name != name.strip()
        or any(ch in name for ch in '/\\:*?"<>|')
        or any(ord(ch) < 32 for ch in name)
        or len(name) > 200
    ):
        raise ClothFitError(
            f"{where}: camera name {name!r} cannot be used in a file name "
            f"(no empty names, '.', '..', '/', '\\', ':', '*', '?', '\"', '<', '>', '|', control "
            f"characters or edge spaces)"
        )
    return name


def check_image_size(width: Any, height: Any, where: str = "camera") -> tuple[int, int]:
    """(width, height) as positive integers up to MAX_IMAGE_SIDE (numbers such as 640.0 accepted)."""
    out = []
    for nm, v in (("width", width), ("height", height)):
        try:
            ok = not isinstance(v, bool) and float(v) == int(float(v))
        except (TypeError, ValueError, OverflowError):
            ok = False
        if not ok or not 0 < int(float(v)) <= MAX_IMAGE_SIDE:
            raise ClothFitError(
                f"{where}: image {nm} {v!r} must be positive: a whole number of pixels in 1..{MAX_IMAGE_SIDE}"
            )
        out.append(int(float(v)))
    return out[0], out[1]


@dataclass
class Camera:
    K: np.ndarray
    R: np.ndarray
    t: np.ndarray
    width: int
    height: int
    name: str = "cam"
    dist: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def __post_init__(self):
        self.K = np.asarray(self.K, dtype=np.float64).reshape(3, 3)
        self.R = np.asarray(self.R, dtype=np.float64).reshape(3, 3)
        self.t = np.asarray(self.t, dtype=np.float64).reshape(3)
        self.dist = np.asarray(self.dist, dtype=np.float64).reshape(-1)
        self.width = int(self.width)
        self.height = int(self.height)
        self.validate()

    # ------------------------------------------------------------------ checks
    def validate(self, source: str = "camera") -> None:
        where = f"{source} '{self.name}'"
        for nm, arr in (("K", self.K), ("R", self.R), ("t", self.t), ("dist", self.dist)):
            if not np.all(np.isfinite(arr)):
                raise ClothFitError(f"{where}: {nm} has non-finite values")
        if self.width <= 0 or self.height <= 0:
            raise ClothFitError(f"{where}: image size {self.width}x{self.height} must be positive")
        if self.K[0, 0] <= 0 or self.K[1, 1] <= 0:
            raise ClothFitError(f"{where}: focal lengths fx={self.K[0, 0]}, fy={self.K[1, 1]} must be positive")
        if (
            abs(self.K[2, 2] - 1.0) > 1e-9
            or abs(self.K[1, 0]) > 1e-9
            or abs(self.K[2, 0]) > 1e-9
            or abs(self.K[2, 1]) > 1e-9
        ):
            raise ClothFitError(f"{where}: K must be upper triangular with K[2,2] = 1, got {self.K.tolist()}")
        with np.errstate(over="ignore", invalid="ignore"):  # absurd entries: caught just below
            err = np.abs(self.R @ self.R.T - np.eye(3)).max()
        if not err <= 1e-6 or np.linalg.det(self.R) < 0:
            raise ClothFitError(
                f"{where}: R is not a rotation (|R R^T - I| = {err:.2e}, det = {np.linalg.det(self.R):.3f})"
            )
        if self.dist.size not in (0, 4, 5, 8, 12, 14):
            raise ClothFitError(
                f"{where}: distortion must have 0, 4, 5, 8, 12 or 14 coefficients, got {self.dist.size}"
            )

    # ------------------------------------------------------------- geometry
    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates."""
        return -self.R.T @ self.t

    @property
    def forward(self) -> np.ndarray:
        """Viewing direction (+Z of the camera) in world coordinates."""
        return self.R[2].copy()

    @property
    def P(self) -> np.ndarray:
        return self.K @ np.hstack([self.R, self.t[:, None]])

    def to_camera(self, X: np.ndarray) -> np.ndarray:
        X = np.asarray(X, dtype=np.float64)
        return X @ self.R.T + self.t

    def project(self, X: np.ndarray, distort: bool = True) -> np.ndarray:
        """Project world points ``(..., 3)`` to pixel coordinates ``(..., 2)``.

        Points behind the camera (z <= 1e-9) get NaN. With ``distort`` and
        non-zero distortion coefficients, OpenCV's distortion model is applied
        (k1, k2, p1, p2, k3 are implemented in numpy; longer models use cv2).
        """
        X = np.asarray(X, dtype=np.float64)
        Xc = X @ self.R.T + self.t
        z = Xc[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            x = Xc[..., 0] / z
            y = Xc[..., 1] / z
        bad = z <= 1e-9
        if distort and self.dist.size and np.any(self.dist != 0):
            x, y = _distort(x, y, self.dist)
        u = self.K[0, 0] * x + self.K[0, 1] * y + self.K[0, 2]
        v = self.K[1, 1] * y + self.K[1, 2]
        out = np.stack([u, v], axis=-1)
        out[bad] = np.nan
        return out

    def resized(self, height: int, width: int) -> Camera:
        """The same camera imaging at another resolution (pixel-centre convention kept)."""
        sx = width / self.width
        sy = height / self.height
        K = self.K.copy()
        K[0, 0] *= sx
        K[0, 1] *= sx
        K[1, 1] *= sy
        K[0, 2] = (self.K[0, 2] + 0.5) * sx - 0.5
        K[1, 2] = (self.K[1, 2] + 0.5) * sy - 0.5
        return Camera(K, self.R, self.t, width, height, self.name, self.dist)

    # ------------------------------------------------------------------- io
    def to_dict(self) -> dict:
        d = {
            "name": self.name,
            "width": self.width,
            "height": self.height,
            "K": self.K.tolist(),
            "R": self.R.tolist(),
            "t": self.t.tolist(),
        }
        if self.dist.size:
            d["dist"] = self.dist.tolist()
        return d

    @classmethod
    def from_dict(cls, d: dict, source: str = "camera") -> Camera:
        if not isinstance(d, dict):
            raise ClothFitError(f"{source}: camera entry must be an object, got {type(d).__name__}")
        missing = [k for k in ("K", "R", "t", "width", "height") if k not in d]
        if missing:
            raise ClothFitError(f"{source}: camera '{d.get('name', '?')}' lacks {', '.join(missing)}")
        try:
            K = np.array(d["K"], dtype=np.float64)
            R = np.array(d["R"], dtype=np.float64)
            t = np.array(d["t"], dtype=np.float64)
            dist = np.array(d.get("dist", []), dtype=np.float64)
        except (TypeError, ValueError) as e:
            raise ClothFitError(f"{source}: camera '{d.get('name', '?')}' has non-numeric data ({e})") from None
        if K.shape != (3, 3) or R.shape != (3, 3) or t.size != 3:
            raise ClothFitError(
                f"{source}: camera '{d.get('name', '?')}' needs K 3x3, R 3x3, t 3; got {K.shape}, {R.shape}, {t.shape}"
            )
        name = d.get("name", "cam")
        check_camera_name(name, source)
        w, h = check_image_size(d["width"], d["height"], f"{source}: camera '{name}'")
        cam = cls.__new__(cls)
        cam.K, cam.R, cam.t, cam.dist = K, R, t.reshape(3), dist.reshape(-1)
        cam.width, cam.height, cam.name = w, h, name
        cam.validate(source)
        return cam


def _distort(x, y, dist):
    d = np.zeros(5)
    n = min(5, dist.size)
    d[:n] = dist[:n]
    if dist.size > 5 and np.any(dist[5:] != 0):
        import cv2  # rational / thin prism / tilted models: let OpenCV do it

        pts = np.stack([x, y, np.ones_like(x)], -1).reshape(-1, 1, 3)
        good = np.all(np.isfinite(pts), axis=-1).reshape(-1)
        out = np.full((pts.shape[0], 2), np.nan)
        if good.any():
            p, _ = cv2.projectPoints(pts[good], np.zeros(3), np.zeros(3), np.eye(3), dist)
            out[good] = p.reshape(-1, 2)
        out = out.reshape(x.shape + (2,))
        return out[..., 0], out[..., 1]
    k1, k2, p1, p2, k3 = d
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return xd, yd


# ---------------------------------------------------------------- construction


def look_at(eye: ArrayLike, target: ArrayLike, up: ArrayLike = (0.0, 0.0, 1.0)) -> tuple[np.ndarray, np.ndarray]:
    """R, t of an OpenCV camera at ``eye`` looking at ``target`` with world ``up`` up in the image."""
    eye = np.asarray(eye, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    z = target - eye
    z /= np.linalg.norm(z)
    upv = np.asarray(up, dtype=np.float64)
    if abs(np.dot(z, upv / np.linalg.norm(upv))) > 0.999:
        upv = np.array([0.0, 1.0, 0.0])
    x = np.cross(z, upv)  # x = y × z with y (image down) = -up, i.e. x = z × up
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    t = -R @ eye
    return R, t


def intrinsics(
    fx: float, width: float, height: float, fy: float | None = None, cx: float | None = None, cy: float | None = None
) -> np.ndarray:
    fy = fx if fy is None else fy
    cx = (width - 1) / 2.0 if cx is None else cx
    cy = (height - 1) / 2.0 if cy is None else cy
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def ring_rig(
    n_per_ring: Sequence[int] = (8, 8, 2),
    elevations_deg: Sequence[float] = (30.0, -10.0, 70.0),
    distance: float = 0.6,
    target: ArrayLike = (0.0, 0.0, 0.0),
    width: int = 640,
    height: int = 480,
    fx: float = 900.0,
    azimuth_offsets_deg: Sequence[float] | None = None,
) -> list[Camera]:
    """A parametric rig: rings of cameras at given elevations, all looking at ``target``."""
    cams = []
    target = np.asarray(target, dtype=np.float64)
    if azimuth_offsets_deg is None:
        azimuth_offsets_deg = [0.0 if i % 2 == 0 else 180.0 / max(n, 1) for i, n in enumerate(n_per_ring)]
    idx = 0
    for n, elev, off in zip(n_per_ring, elevations_deg, azimuth_offsets_deg):
        for j in range(n):
            az = math.radians(off + 360.0 * j / n)
            el = math.radians(elev)
            eye = target + distance * np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
            R, t = look_at(eye, target)
            cams.append(Camera(intrinsics(fx, width, height), R, t, width, height, name=f"cam{idx:02d}"))
            idx += 1
    return cams


# -------------------------------------------------------------------- rig io


def save_cameras(path: str, cameras: Iterable[Camera], extra: dict | None = None) -> None:
    d = {
        "convention": "opencv: x_cam = R X + t, +Z forward, +Y down, pixel centres at integers",
        "cameras": [c.to_dict() for c in cameras],
    }
    if extra:
        d.update(extra)
    from ..jsonio import write_json

    write_json(path, d)


def load_cameras(path: str) -> list[Camera]:
    """Read a cameras JSON (``{"cameras": [...]}``, a rig preset is the same format)."""
    d = read_json(path, "camera file", expect=None)
    if not isinstance(d, dict) or not isinstance(d.get("cameras"), list):
        raise ClothFitError(f"camera file {path}: expected an object with a 'cameras' list")
    if not d["cameras"]:
        raise ClothFitError(f"camera file {path}: the 'cameras' list is empty")
    cams = [Camera.from_dict(c, source=f"{path} camera #{i}") for i, c in enumerate(d["cameras"])]
    names = [c.name for c in cams]
    if len(set(names)) != len(names):
        raise ClothFitError(f"camera file {path}: camera names are not unique: {names}")
    return cams


# the rig presets: rigs/ beside addon/ (a checkout, the extension), or addon/rigs/ in a wheel (pyproject.toml)
_PACKAGED_RIGS = os.path.normpath(os.path.join(os.path.dirname(__file__), "..", "..", "rigs"))
RIGS_DIR = (
    _PACKAGED_RIGS
    if os.path.isdir(_PACKAGED_RIGS)
    else os.path.normpath(os.path.join(os.path.dirname(__file__), "..", "..", "..", "rigs"))
)


def rig_path(name_or_path: str) -> str:
    if os.path.isfile(name_or_path):
        return name_or_path
    p = os.path.join(RIGS_DIR, name_or_path if name_or_path.endswith(".json") else name_or_path + ".json")
    if not os.path.isfile(p):
        avail = sorted(f[:-5] for f in os.listdir(RIGS_DIR) if f.endswith(".json")) if os.path.isdir(RIGS_DIR) else []
        raise ClothFitError(f"rig '{name_or_path}' not found (looked for {p}; presets: {', '.join(avail) or 'none'})")
    return p


def load_rig(name_or_path: str) -> list[Camera]:
    return load_cameras(rig_path(name_or_path))


# ------------------------------------------------------- training-camera rule


def spread_order(cameras: Sequence[Camera], first: int = 0) -> list[int]:
    """Order camera indices so that every prefix is spread around the rig.

    Rule (documented in docs/cli.md, "Training cameras"): start with camera ``first``; then repeatedly
    add the camera whose viewing direction (unit vector from the rig's target
    towards the camera centre) has the largest minimum angle to the directions
    already chosen; ties go to the lower index. Training with ``n`` cameras uses
    the first ``n`` of this order; the cameras not used are the held-out ones.
    """
    centres = np.array([c.center for c in cameras])
    target = _rig_target(cameras)
    dirs = centres - target
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    order = [first]
    while len(order) < len(cameras):
        cos = dirs @ dirs[order].T  # (C, k)
        min_angle = np.arccos(np.clip(cos.max(axis=1), -1, 1))
        min_angle[order] = -1.0
        order.append(int(np.argmax(np.round(min_angle, 9))))
    return order


def select_training(cameras: Sequence[Camera], n: int, first: int = 0) -> tuple[list[int], list[int]]:
    if n < 1 or n > len(cameras):
        raise ClothFitError(f"number of training cameras {n} must be within 1..{len(cameras)}")
    order = spread_order(cameras, first)
    train = sorted(order[:n])
    held = sorted(order[n:])
    return train, held


def _rig_target(cameras):
    """Least-squares point closest to all optical axes."""
    A = np.zeros((3, 3))
    b = np.zeros(3)
    for c in cameras:
        d = c.forward
        M = np.eye(3) - np.outer(d, d)
        A += M
        b += M @ c.center
    try:
        return np.linalg.solve(A, b)
    except np.linalg.LinAlgError:
        return np.mean([c.center for c in cameras], axis=0)
