"""The world frame of ``clothfit calibrate``: the board at the world moment, turned to up by a
level board or a gravity vector (see :func:`world_frame`; the steps of a calibration:
``calibrate.py``).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..errors import ClothFitError
from .calib_board import Board
from .calib_intrinsics import Options

FLIP = np.diag([1.0, -1.0, -1.0])  # board axes (x right, y down the print, z into it) -> world (z out of the face)


# ====================================================================== world frame


def world_frame(
    board: Board,
    ref_cam_pose: dict[str, tuple[np.ndarray, np.ndarray]],
    board_pose: dict[str, tuple[np.ndarray, np.ndarray]],
    world: str,
    opts: Options,
) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """The transform reference frame -> world ``(R, t)`` (see the module text) and how up was set."""
    if world not in board_pose:
        raise ClothFitError(
            f"--world {world}: no camera saw the board at that moment (moments seen: "
            f"{', '.join(list(board_pose)[:8])}{' ...' if len(board_pose) > 8 else ''})"
        )
    Rw, tw = board_pose[world]
    # board -> world: X_w = FLIP (X_b - centre); ref -> board: X_b = Rw^T (X_r - tw)
    R = FLIP @ Rw.T
    t = -FLIP @ Rw.T @ tw - FLIP @ board.centre()
    up_source = f"the board at the world moment {world}"
    up = None
    if opts.level is not None:
        if opts.level not in board_pose:
            raise ClothFitError(f"--level {opts.level}: no camera saw the board at that moment")
        Rl, _ = board_pose[opts.level]
        up = R @ (Rl @ np.array([0.0, 0.0, -1.0]))  # the level board's face normal, in the world
        up_source = f"the level board at moment {opts.level}"
    elif opts.gravity is not None:
        cam, g = opts.gravity
        if cam not in ref_cam_pose:
            raise ClothFitError(f"--gravity {cam}:...: no camera '{cam}' (cameras: {', '.join(ref_cam_pose)})")
        Rc, _ = ref_cam_pose[cam]
        g = np.asarray(g, float) / np.linalg.norm(g)
        up = -(R @ (Rc.T @ g))
        up_source = f"gravity measured in camera {cam}"
    tilt = 0.0
    if up is not None:
        up /= np.linalg.norm(up)
        tilt = math.degrees(math.acos(max(-1.0, min(1.0, float(up[2])))))
        xb = np.array([1.0, 0.0, 0.0])
        x = xb - up * (xb @ up)
        if np.linalg.norm(x) < 1e-6:
            raise ClothFitError(
                f"{up_source}: up lies along the board's X axis; the board at the world moment cannot set the heading"
            )
        x /= np.linalg.norm(x)
        y = np.cross(up, x)
        Q = np.stack([x, y, up])  # old world -> new world
        R, t = Q @ R, Q @ t
    return R, t, {"moment": world, "up": up_source, "board_tilt_deg": tilt}
