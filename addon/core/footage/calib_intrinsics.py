"""Camera geometry and the first estimates of ``clothfit calibrate``: rotations, the projection
with distortion, the calibration options, per camera ``cv2.calibrateCamera`` on its own views
(:func:`initial_intrinsics`) and the cameras joined through the moments they share
(:func:`initial_extrinsics`). The steps of a calibration: ``calibrate.py``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from .. import defaults as D
from ..errors import ClothFitError
from .calib_board import Board, natural_key

if TYPE_CHECKING:
    from .calib_detect import View

DISTORTION_MODELS = {  # name -> which of (k1, k2, p1, p2, k3) are estimated
    "none": (),
    "k1": ("k1",),
    "k1k2": ("k1", "k2"),
    "k1k2p1p2": ("k1", "k2", "p1", "p2"),
    "k1k2p1p2k3": ("k1", "k2", "p1", "p2", "k3"),
}
DIST_ORDER = ("k1", "k2", "p1", "p2", "k3")


# ================================================================= camera geometry


def rodrigues(r: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(N, 3, 3)`` of rotation vectors ``(N, 3)`` (Rodrigues' formula, vectorised;
    first order below 1e-12 rad)."""
    r = np.asarray(r, dtype=np.float64).reshape(-1, 3)
    th = np.linalg.norm(r, axis=1)
    small = th < 1e-12
    k = r / np.where(small, 1.0, th)[:, None]
    z = np.zeros(len(r))
    Kx = np.stack(
        [
            np.stack([z, -k[:, 2], k[:, 1]], -1),
            np.stack([k[:, 2], z, -k[:, 0]], -1),
            np.stack([-k[:, 1], k[:, 0], z], -1),
        ],
        1,
    )
    s, c = np.sin(th)[:, None, None], (1 - np.cos(th))[:, None, None]
    R = np.eye(3)[None] + s * Kx + c * (Kx @ Kx)
    rx = np.stack(
        [
            np.stack([z, -r[:, 2], r[:, 1]], -1),
            np.stack([r[:, 2], z, -r[:, 0]], -1),
            np.stack([-r[:, 1], r[:, 0], z], -1),
        ],
        1,
    )
    return np.where(small[:, None, None], np.eye(3)[None] + rx, R)


def rotvec(R: np.ndarray) -> np.ndarray:
    import cv2

    return cv2.Rodrigues(np.asarray(R, dtype=np.float64))[0].reshape(3)


def project_points(
    X_cam: np.ndarray,
    fx: np.ndarray | float,
    fy: np.ndarray | float,
    cx: np.ndarray | float,
    cy: np.ndarray | float,
    dist: np.ndarray,
) -> np.ndarray:
    """Pixels of camera-frame points with OpenCV's (k1, k2, p1, p2, k3) distortion; all arrays
    broadcast per point."""
    z = X_cam[:, 2]
    x = X_cam[:, 0] / z
    y = X_cam[:, 1] / z
    k1, k2, p1, p2, k3 = (dist[:, i] for i in range(5))
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([fx * xd + cx, fy * yd + cy], -1)


def _mean_rotation(Rs) -> np.ndarray:
    """Robust mean of rotations: the medoid, then the chordal mean of those within 5 degrees of it."""
    Rs = np.asarray(Rs)
    if len(Rs) == 1:
        return Rs[0]
    tr = np.einsum("aij,bij->ab", Rs, Rs)
    ang = np.arccos(np.clip((tr - 1) / 2, -1, 1))
    med = int(np.argmin(ang.sum(1)))
    keep = ang[med] < math.radians(5.0)
    U, _, Vt = np.linalg.svd(Rs[keep].sum(0))
    R = U @ Vt
    if np.linalg.det(R) < 0:
        U[:, -1] *= -1
        R = U @ Vt
    return R


def rotation_angle_deg(R: np.ndarray) -> float:
    return math.degrees(math.acos(max(-1.0, min(1.0, (float(np.trace(R)) - 1) / 2))))


# ========================================================================= options


@dataclass
class Options:
    """How to calibrate (the CLI's options; every default in ``defaults.py``)."""

    distortion: str = D.CALIB_DISTORTION
    square_pixels: bool = True  # fx = fy
    shared: bool = False  # one set of intrinsics for every camera (same phone model)
    fixed: dict = field(default_factory=dict)  # {camera: Camera} whose intrinsics are held fixed
    world: str | None = None  # moment of the world board (default: the first moment)
    level: str | None = None  # a moment where the board lies level (its normal = up)
    gravity: tuple | None = None  # (camera, (gx, gy, gz)): gravity in that camera's frame
    min_views: int = D.CALIB_MIN_VIEWS
    min_corners: int = D.CALIB_MIN_CORNERS
    blur_ratio: float = D.CALIB_BLUR_RATIO
    loss: str = D.CALIB_LOSS
    loss_scale_px: float = D.CALIB_LOSS_SCALE_PX
    outlier_px: float = D.CALIB_OUTLIER_PX

    def check(self) -> Options:
        if self.distortion not in DISTORTION_MODELS:
            raise ClothFitError(f"--distortion {self.distortion!r}: one of {', '.join(DISTORTION_MODELS)}")
        if self.loss not in ("linear", "huber", "soft_l1", "cauchy"):
            raise ClothFitError(f"--loss {self.loss!r}: one of linear, huber, soft_l1, cauchy")
        for nm, v, lo in (("--min-views", self.min_views, 1), ("--min-corners", self.min_corners, 4)):
            if not isinstance(v, int) or v < lo:
                raise ClothFitError(f"{nm} {v!r}: must be a whole number >= {lo}")
        if not (0 <= self.blur_ratio < 1):
            raise ClothFitError(f"--blur-ratio {self.blur_ratio:g}: must be within 0..1 (0 = keep blurred frames)")
        if not (self.loss_scale_px > 0 and self.outlier_px > 0):
            raise ClothFitError("the loss scale and the outlier threshold must be positive pixels")
        if self.gravity is not None:
            g = np.asarray(self.gravity[1], float)
            if g.shape != (3,) or not np.all(np.isfinite(g)) or np.linalg.norm(g) < 1e-9:
                raise ClothFitError(f"--gravity {self.gravity[0]}:{self.gravity[1]}: needs three numbers, not all zero")
        if self.level is not None and self.gravity is not None:
            raise ClothFitError("--level and --gravity both say where up is: give one of them")
        return self


# ================================================================= initial estimates


@dataclass
class Intrinsics:
    K: np.ndarray
    dist: np.ndarray  # 5 coefficients k1, k2, p1, p2, k3
    fixed: bool = False


def _obj_img(board: Board, views):
    P = board.corners()
    obj = [P[v.ids].astype(np.float32) for v in views]
    img = [v.points.reshape(-1, 1, 2).astype(np.float32) for v in views]
    return obj, img


def _cv_flags(opts: Options) -> int:
    import cv2

    est = set(DISTORTION_MODELS[opts.distortion])
    f = 0
    if opts.square_pixels:
        f |= cv2.CALIB_FIX_ASPECT_RATIO
    if "k1" not in est:
        f |= cv2.CALIB_FIX_K1
    if "k2" not in est:
        f |= cv2.CALIB_FIX_K2
    if "k3" not in est:
        f |= cv2.CALIB_FIX_K3
    if "p1" not in est:
        f |= cv2.CALIB_ZERO_TANGENT_DIST
    return f


def initial_intrinsics(
    board: Board, views: dict[str, dict[str, View]], sizes: dict[str, tuple[int, int]], opts: Options
) -> tuple[dict[str, Intrinsics], dict[str, dict[str, tuple[np.ndarray, np.ndarray]]]]:
    """Per camera: (Intrinsics, {moment: (R, t) board -> camera}) from its own views; with
    ``opts.shared`` one calibrateCamera over every camera's views; fixed cameras: solvePnP."""
    import cv2

    intr, poses = {}, {}
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-10)
    free = [c for c in views if c not in opts.fixed]
    if opts.shared and free:
        sz = {sizes[c] for c in free}
        if len(sz) > 1:
            raise ClothFitError(
                "--shared-intrinsics: the cameras' images differ in size ("
                + ", ".join(f"{c} {sizes[c][0]}x{sizes[c][1]}" for c in free)
                + "): one lens, one size"
            )
    groups = [free] if opts.shared and free else [[c] for c in free]
    for group in groups:
        vs = [v for c in group for v in views[c].values()]
        obj, img = _obj_img(board, vs)
        w, h = sizes[group[0]]
        K0 = np.array([[1.0, 0, (w - 1) / 2], [0, 1.0, (h - 1) / 2], [0, 0, 1]])
        try:
            rms, K, dist, rv, tv = cv2.calibrateCamera(
                obj, img, (w, h), K0, np.zeros(5), flags=_cv_flags(opts), criteria=crit
            )
        except cv2.error as e:
            raise ClothFitError(
                f"camera(s) {', '.join(group)}: OpenCV's calibrateCamera failed on "
                f"{len(vs)} views ({str(e).strip().splitlines()[-1]})"
            ) from None
        if not (np.all(np.isfinite(K)) and K[0, 0] > 0):
            raise ClothFitError(
                f"camera(s) {', '.join(group)}: no finite intrinsics from {len(vs)} views "
                f"(more views at varied tilts needed)"
            )
        d5 = np.zeros(5)
        d5[: min(5, dist.size)] = np.asarray(dist).reshape(-1)[:5]
        for c in group:
            intr[c] = Intrinsics(K.copy(), d5.copy())
        for v, r, t in zip(vs, rv, tv):
            poses.setdefault(v.camera, {})[v.moment] = (cv2.Rodrigues(r)[0], np.asarray(t, float).reshape(3))
    for c in views:
        if c not in opts.fixed:
            continue
        cam = opts.fixed[c]
        if (cam.width, cam.height) != tuple(sizes[c]):
            raise ClothFitError(
                f"--intrinsics: camera '{c}' is {cam.width}x{cam.height} there but its images are "
                f"{sizes[c][0]}x{sizes[c][1]}"
            )
        if cam.dist.size > 5 and np.any(cam.dist[5:] != 0):
            raise ClothFitError(
                f"--intrinsics: camera '{c}' uses more than 5 distortion coefficients "
                f"(k1, k2, p1, p2, k3 are supported)"
            )
        d5 = np.zeros(5)
        d5[: min(5, cam.dist.size)] = cam.dist[:5]
        intr[c] = Intrinsics(cam.K.copy(), d5, fixed=True)
        for v in views[c].values():
            obj, img = _obj_img(board, [v])
            ok, r, t = cv2.solvePnP(obj[0], img[0], cam.K, d5, flags=cv2.SOLVEPNP_IPPE)
            if ok:
                poses.setdefault(c, {})[v.moment] = (cv2.Rodrigues(r)[0], np.asarray(t, float).reshape(3))
    return intr, poses


def initial_extrinsics(
    poses: dict[str, dict[str, tuple[np.ndarray, np.ndarray]]], reference: str | None = None
) -> tuple[str, dict[str, tuple[np.ndarray, np.ndarray]], dict[str, tuple[np.ndarray, np.ndarray]]]:
    """Camera poses ``{camera: (R, t)}`` in the reference camera's frame, and board poses
    ``{moment: (R, t)}`` (board -> reference frame), from per-view board poses, along the spanning
    tree of most shared moments. Cameras not connected: one-line error naming the groups."""
    cams = list(poses)
    shared = {(a, b): sorted(set(poses[a]) & set(poses[b])) for i, a in enumerate(cams) for b in cams[i + 1 :]}
    groups = components(cams, [(a, b) for (a, b), s in shared.items() if s])
    if len(groups) > 1:
        desc = "; ".join("{" + ", ".join(g) + "}" for g in groups)
        raise ClothFitError(
            f"the cameras are not connected by shared views: {desc} share no moment where both "
            f"see the board (show the board to neighbouring cameras at once, e.g. lying on the "
            f"table between them)"
        )
    ref = reference or max(
        cams, key=lambda c: (sum(len(s) for (a, b), s in shared.items() if c in (a, b)), len(poses[c]))
    )
    cam_pose = {ref: (np.eye(3), np.zeros(3))}
    while len(cam_pose) < len(cams):  # Prim: the edge with most shared moments to a new camera
        best = None
        for (a, b), s in shared.items():
            if (a in cam_pose) != (b in cam_pose) and s and (best is None or len(s) > len(best[2])):
                best = (a, b, s) if a in cam_pose else (b, a, s)
        a, b, s = best
        # relative a -> b from every shared moment: R_ab = R_bm R_am^T, t_ab = t_bm - R_ab t_am
        Rab = [poses[b][m][0] @ poses[a][m][0].T for m in s]
        R = _mean_rotation(Rab)
        t = np.median([poses[b][m][1] - R @ poses[a][m][1] for m in s], axis=0)
        Ra, ta = cam_pose[a]
        cam_pose[b] = (R @ Ra, R @ ta + t)
    board_pose = {}
    moments = sorted({m for c in cams for m in poses[c]}, key=natural_key)
    for m in moments:
        Rs, ts = [], []
        for c in cams:
            if m in poses[c]:
                Rc, tc = cam_pose[c]
                Rcm, tcm = poses[c][m]
                Rs.append(Rc.T @ Rcm)
                ts.append(Rc.T @ (tcm - tc))
        board_pose[m] = (_mean_rotation(Rs), np.median(ts, axis=0))
    return ref, cam_pose, board_pose


def components(nodes: Iterable, edges: Iterable) -> list:
    parent = {n: n for n in nodes}

    def find(x):
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    for a, b in edges:
        parent[find(a)] = find(b)
    groups = {}
    for n in nodes:
        groups.setdefault(find(n), []).append(n)
    return sorted(groups.values(), key=lambda g: (-len(g), g))
