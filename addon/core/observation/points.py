"""Point clouds beside a capture: the reader of one cloud (an ``N x 3`` .npy file) and the clouds a capture made
by ``points-to-capture`` was converted from (``capture_points``), in metres and cropped as its silhouettes were,
so a fitted cloth can be measured against the real points themselves (``metrics.points_to_cloth_m``)."""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

import numpy as np

from ..errors import ClothFitError

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
