"""Triangulation for ``clothfit handles``: a mark seen by several cameras to one 3-D point (linear
DLT on the undistorted rays, then Gauss-Newton on the reprojection error with the cameras'
distortion; residuals in pixels and millimetres), and a tracked handle to its 3-D trajectory, a
camera that disagrees with the others dropped from that frame on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .. import defaults as D
from ..errors import ClothFitError
from .handle_marks import HandleOptions

if TYPE_CHECKING:
    from collections.abc import Sequence

    from numpy.typing import ArrayLike

    from ..observation.camera import Camera
    from .handle_tracking import CameraTrack

# ============================================================== triangulation


@dataclass
class Triangulation:
    X: np.ndarray  # (3,) world point
    residuals: np.ndarray  # (C,) reprojection distance per camera [px]
    residuals_mm: np.ndarray  # (C,) the same at the point's depth [mm]
    cov: np.ndarray  # (3, 3) covariance [m^2] for the pixel noise ``sigma``
    sigma: float  # pixel noise used: the residual's estimate, floored at the mark noise

    @property
    def rms(self) -> float:
        return float(np.sqrt(np.mean(self.residuals**2)))

    @property
    def sd_max(self) -> float:
        return float(np.sqrt(max(np.linalg.eigvalsh(self.cov).max(), 0.0)))


def _normalised(cam, p):
    """Undistorted normalised image coordinates of pixel ``p`` of ``cam``."""
    p = np.asarray(p, dtype=np.float64).reshape(2)
    if cam.dist.size and np.any(cam.dist != 0):
        import cv2

        crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
        return cv2.undistortPointsIter(p.reshape(1, 1, 2), cam.K, cam.dist, None, None, crit).reshape(2)
    K = cam.K
    y = (p[1] - K[1, 2]) / K[1, 1]
    return np.array([(p[0] - K[0, 2] - K[0, 1] * y) / K[0, 0], y])


def triangulate(cams: Sequence[Camera], pts: ArrayLike, sigma_floor: float = D.HANDLE_MARK_SIGMA_PX) -> Triangulation:
    """The 3-D point seen at pixels ``pts`` (one (x, y) per camera, >= 2 cameras)."""
    pts = np.asarray(pts, dtype=np.float64).reshape(-1, 2)
    if len(cams) < 2:
        raise ClothFitError("triangulation needs at least 2 cameras")
    A = []
    for cam, p in zip(cams, pts):
        n = _normalised(cam, p)
        P = np.hstack([cam.R, cam.t[:, None]])
        A.append(n[0] * P[2] - P[0])
        A.append(n[1] * P[2] - P[1])
    A = np.asarray(A)
    X = np.linalg.lstsq(A[:, :3], -A[:, 3], rcond=None)[0]
    X, J = _refine(cams, pts, X)
    proj = np.array([c.project(X) for c in cams])
    res = np.linalg.norm(proj - pts, axis=1)
    depth = np.array([float(c.to_camera(X)[2]) for c in cams])
    if np.any(depth <= 0):
        bad = [c.name for c, z in zip(cams, depth) if z <= 0]
        raise ClothFitError(f"the marks meet behind camera {', '.join(bad)}: marks of different points?")
    f = np.array([0.5 * (c.K[0, 0] + c.K[1, 1]) for c in cams])
    dof = 2 * len(cams) - 3
    s_est = math.sqrt(float(np.sum(res**2)) / dof)
    sigma = max(s_est, sigma_floor)
    try:
        cov = np.linalg.inv(J.T @ J) * sigma**2
    except np.linalg.LinAlgError:
        cov = np.full((3, 3), np.inf)
    return Triangulation(X, res, res * depth / f * 1000.0, cov, sigma)


def _refine(cams, pts, X, iters=20):
    """Gauss-Newton on the pixel reprojection error (distortion included); returns (X, Jacobian)."""
    h = 1e-7
    J = None
    for _ in range(iters):
        r = np.concatenate([c.project(X) - p for c, p in zip(cams, pts)])
        J = np.empty((r.size, 3))
        for k in range(3):
            dX = np.zeros(3)
            dX[k] = h
            rp = np.concatenate([c.project(X + dX) - p for c, p in zip(cams, pts)])
            rm = np.concatenate([c.project(X - dX) - p for c, p in zip(cams, pts)])
            J[:, k] = (rp - rm) / (2 * h)
        if not np.all(np.isfinite(J)) or not np.all(np.isfinite(r)):
            break
        step = np.linalg.lstsq(J, -r, rcond=None)[0]
        X = X + step
        if np.linalg.norm(step) < 1e-12:
            break
    return X, J


# ============================================================ 3-D trajectories


@dataclass
class Trajectory3D:
    X: np.ndarray  # (F, 3), NaN where fewer than 2 cameras
    cameras: list  # per frame: names of the cameras used
    rms_px: np.ndarray  # (F,)
    problems: dict  # frame -> reason it has no point (lost tracks, disagreement)
    dropped: list  # (camera, frame, residual px): cameras dropped as drifted


def triangulate_track(
    cams: Sequence[Camera], tracks: Sequence[CameraTrack], k: int, opts: HandleOptions
) -> Trajectory3D:
    """Handle ``k``'s 3-D trajectory from its per-camera tracks; a camera whose reprojection misses
    by more than ``max_residual`` is dropped from that frame on (in its direction of tracking) while
    at least 2 others remain."""
    F = tracks[0].points.shape[0]
    X = np.full((F, 3), np.nan)
    used = [[] for _ in range(F)]
    rms = np.full(F, np.nan)
    problems, dropped = {}, []
    banned = {}  # camera index -> set of frames excluded
    for f in range(F):
        idx = [
            ci for ci, tr in enumerate(tracks) if np.all(np.isfinite(tr.points[f, k])) and f not in banned.get(ci, ())
        ]
        while len(idx) >= 2:
            tri = triangulate([cams[ci] for ci in idx], [tracks[ci].points[f, k] for ci in idx], opts.mark_sigma)
            worst = int(np.argmax(tri.residuals))
            if tri.residuals[worst] <= opts.max_residual:
                X[f] = tri.X
                used[f] = [cams[ci].name for ci in idx]
                rms[f] = tri.rms
                break
            if len(idx) == 2:
                problems[f] = (
                    f"cameras {cams[idx[0]].name} and {cams[idx[1]].name} disagree by "
                    f"{tri.residuals.max():.1f} px (a track drifted off its point)"
                )
                idx = []
                break
            ci = idx[worst]
            dropped.append((cams[ci].name, f, float(tri.residuals[worst])))
            rng = range(f, F) if f >= tracks[ci].marked[k] else range(0, f + 1)
            banned.setdefault(ci, set()).update(rng)
            idx = [c for c in idx if c != ci]
        if len(idx) < 2 and f not in problems:
            lost = []
            for tr in tracks:
                if k not in tr.marked or np.all(np.isfinite(tr.points[f, k])):
                    continue
                at = tr.lost_forward[k] if f > tr.marked[k] else tr.lost_backward[k]
                lost.append(
                    f"camera {tr.name} at frame {at}" + (f" ({tr.lost_reason[k]})" if tr.lost_reason[k] else "")
                    if at is not None
                    else f"camera {tr.name} (dropped as drifted)"
                )
            problems[f] = ("its track is lost in " + ", ".join(lost)) if lost else "fewer than 2 cameras see it"
    return Trajectory3D(X, used, rms, problems, dropped)
