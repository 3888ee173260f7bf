"""Point clouds beside a capture: the reader of one cloud (an ``N x 3`` .npy file) and the clouds a capture made
by ``points-to-capture`` was converted from (``capture_points``), in metres and cropped as its silhouettes were,
so a fitted cloth can be measured against the real points themselves (``metrics.points_to_cloth_m``)."""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

import numpy as np

from ..errors import ClothFitError
from .metrics import points_scatter_m

if TYPE_CHECKING:
    from .capture import Capture


def read_point_cloud(path: str) -> np.ndarray:
    """The points ``(N, 3)`` of one .npy file: a numeric N x 3 array of finite numbers, N >= 1."""
    try:
        a = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as e:
        raise ClothFitError(f"point cloud {path}: not a readable .npy array ({type(e).__name__}: {e})") from None
    if not isinstance(a, np.ndarray) or a.dtype.kind not in "iuf":
        raise ClothFitError(f"point cloud {path}: not an array of numbers (dtype {getattr(a, 'dtype', type(a))})")
    if a.ndim != 2 or a.shape[1] != 3 or a.shape[0] == 0:
        raise ClothFitError(f"point cloud {path}: shape {a.shape}, expected N x 3 points (N >= 1)")
    bad = int(np.count_nonzero(~np.isfinite(a).all(axis=1)))
    if bad:
        raise ClothFitError(f"point cloud {path}: {bad} of {a.shape[0]} points are not finite")
    return a.astype(np.float64)


def capture_points(capture: Capture, fidx: list[int]) -> list[np.ndarray] | None:
    """The real points [m] of the capture's frames ``fidx`` (those above its crop), read from the folder its
    ``meta`` names (``points``, ``point_files``, ``unit_scale``); None for a capture not made from point
    clouds. A folder that has gone is one line naming it."""
    meta = getattr(capture, "meta", None) or {}
    folder, files = meta.get("points"), meta.get("point_files")
    if not folder or not isinstance(files, list) or len(files) != capture.n_frames:
        return None
    unit = float(meta.get("unit_scale", 1.0))
    crop = getattr(capture.scenario, "crop", None)
    out = []
    for k in fidx:
        path = os.path.join(folder, files[k])
        if not os.path.isfile(path):
            raise ClothFitError(f"capture {capture.root}: its point cloud {path} is not there (moved or deleted)")
        X = read_point_cloud(path) * unit
        out.append(X if crop is None else X[crop.height(X) >= 0.0])
    return out


def frame_scatter_mm(points: np.ndarray) -> float:
    """One frame's points' own scatter about a smooth surface [mm] (``metrics.points_scatter_m``, averaged):
    what a perfect cloth would still score against them."""
    return 1000.0 * float(points_scatter_m(points).mean())


def points_scatter_mm(capture: Capture, fidx: list[int], points: list[np.ndarray]) -> float:
    """The mean scatter [mm] of the real points of frames ``fidx``: as the converter stated it per frame
    (``meta.points_scatter_mm``), else measured on ``points`` (those frames' clouds; a capture converted before
    the converter stated it). A stated list that is not one finite number per frame is one line naming the
    capture."""
    stated = (getattr(capture, "meta", None) or {}).get("points_scatter_mm")
    if stated is None:
        return float(np.mean([frame_scatter_mm(P) for P in points if len(P)]))
    ok = (
        isinstance(stated, list)
        and len(stated) == capture.n_frames
        and all(isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) and v >= 0 for v in stated)
    )
    if not ok:
        raise ClothFitError(
            f"capture {capture.root}: meta.points_scatter_mm must hold one number >= 0 per frame "
            f"({capture.n_frames}), got {str(stated)[:80]}"
        )
    return float(np.mean([stated[k] for k in fidx]))
