"""The bundle adjustment of ``clothfit calibrate``: every camera's intrinsics, distortion and pose
and every moment's board pose refined jointly (``scipy.optimize.least_squares``, a sparse Jacobian,
a robust loss). The steps of a calibration: ``calibrate.py``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .. import defaults as D
from ..errors import ClothFitError
from .calib_board import Board, natural_key
from .calib_intrinsics import DIST_ORDER, DISTORTION_MODELS, Intrinsics, Options, project_points, rodrigues, rotvec

if TYPE_CHECKING:
    from scipy.optimize import OptimizeResult

    from .calib_detect import View

# =================================================================== bundle adjustment


@dataclass
class Problem:
    """The observations and the parameter layout of the bundle adjustment."""

    cams: list
    moments: list
    ref: str
    obs_cam: np.ndarray  # (N,) camera index per corner observation
    obs_mom: np.ndarray  # (N,) moment index
    obs_X: np.ndarray  # (N, 3) board point
    obs_x: np.ndarray  # (N, 2) detected pixel
    intr_group: list  # per camera: index of its intrinsic group (-1: fixed)
    n_intr: int  # parameters per intrinsic group
    dist_idx: list  # which of the 5 distortion coefficients are free
    square_pixels: bool
    fixed_intr: dict  # camera index -> Intrinsics (fixed)


def _intr_layout(opts: Options):
    dist_idx = [DIST_ORDER.index(k) for k in DISTORTION_MODELS[opts.distortion]]
    return (3 if opts.square_pixels else 4) + len(dist_idx), dist_idx


def _pack(prob: Problem, intr: dict, cam_pose: dict, board_pose: dict) -> np.ndarray:
    x = []
    groups_done = set()
    for ci, c in enumerate(prob.cams):
        g = prob.intr_group[ci]
        if g < 0 or g in groups_done:
            continue
        groups_done.add(g)
        K, d = intr[c].K, intr[c].dist
        f = [0.5 * (K[0, 0] + K[1, 1])] if prob.square_pixels else [K[0, 0], K[1, 1]]
        x += f + [K[0, 2], K[1, 2]] + [d[i] for i in prob.dist_idx]
    for c in prob.cams:
        if c == prob.ref:
            continue
        R, t = cam_pose[c]
        x += list(rotvec(R)) + list(t)
    for m in prob.moments:
        R, t = board_pose[m]
        x += list(rotvec(R)) + list(t)
    return np.asarray(x, dtype=np.float64)


def _n_groups(prob: Problem) -> int:
    return max([g for g in prob.intr_group if g >= 0], default=-1) + 1


def _unpack(prob: Problem, x: np.ndarray):
    """(fx, fy, cx, cy, dist5) per camera, (rvec, t) per camera, (rvec, t) per moment."""
    ng = _n_groups(prob)
    C, M = len(prob.cams), len(prob.moments)
    intr = x[: ng * prob.n_intr].reshape(ng, prob.n_intr)
    o = ng * prob.n_intr
    ext = np.zeros((C, 6))
    others = [ci for ci, c in enumerate(prob.cams) if c != prob.ref]
    ext[others] = x[o : o + 6 * len(others)].reshape(-1, 6)
    o += 6 * len(others)
    brd = x[o : o + 6 * M].reshape(M, 6)
    fx, fy, cx, cy = np.zeros(C), np.zeros(C), np.zeros(C), np.zeros(C)
    dist = np.zeros((C, 5))
    nf = 1 if prob.square_pixels else 2
    for ci in range(C):
        g = prob.intr_group[ci]
        if g < 0:
            it = prob.fixed_intr[ci]
            fx[ci], fy[ci], cx[ci], cy[ci] = it.K[0, 0], it.K[1, 1], it.K[0, 2], it.K[1, 2]
            dist[ci] = it.dist
            continue
        p = intr[g]
        fx[ci] = p[0]
        fy[ci] = p[0] if prob.square_pixels else p[1]
        cx[ci], cy[ci] = p[nf], p[nf + 1]
        dist[ci, prob.dist_idx] = p[nf + 2 :]
    return fx, fy, cx, cy, dist, ext, brd


def _residuals(x: np.ndarray, prob: Problem) -> np.ndarray:
    fx, fy, cx, cy, dist, ext, brd = _unpack(prob, x)
    Rc, tc = rodrigues(ext[:, :3]), ext[:, 3:]
    Rm, tm = rodrigues(brd[:, :3]), brd[:, 3:]
    c, m = prob.obs_cam, prob.obs_mom
    Xr = np.einsum("nij,nj->ni", Rm[m], prob.obs_X) + tm[m]
    Xc = np.einsum("nij,nj->ni", Rc[c], Xr) + tc[c]
    uv = project_points(Xc, fx[c], fy[c], cx[c], cy[c], dist[c])
    return (uv - prob.obs_x).ravel()


def _sparsity(prob: Problem):
    from scipy.sparse import lil_matrix  # noqa: PLC0415  (scipy checked in bundle_adjust)

    ng = _n_groups(prob)
    N = prob.obs_cam.size
    others = [ci for ci, c in enumerate(prob.cams) if c != prob.ref]
    ext_col = {ci: ng * prob.n_intr + 6 * k for k, ci in enumerate(others)}
    mom0 = ng * prob.n_intr + 6 * len(others)
    n = mom0 + 6 * len(prob.moments)
    S = lil_matrix((2 * N, n), dtype=np.int8)
    rows = np.arange(N)
    for ci in range(len(prob.cams)):
        sel = rows[prob.obs_cam == ci]
        r = np.concatenate([2 * sel, 2 * sel + 1])
        g = prob.intr_group[ci]
        if g >= 0:
            for k in range(prob.n_intr):
                S[r, g * prob.n_intr + k] = 1
        if ci in ext_col:
            for k in range(6):
                S[r, ext_col[ci] + k] = 1
    for mi in range(len(prob.moments)):
        sel = rows[prob.obs_mom == mi]
        r = np.concatenate([2 * sel, 2 * sel + 1])
        for k in range(6):
            S[r, mom0 + 6 * mi + k] = 1
    return S.tocsr()


def _problem(board: Board, views: dict, intr: dict, ref: str, opts: Options) -> Problem:
    cams = list(views)
    moments = sorted({m for c in cams for m in views[c]}, key=natural_key)
    mi = {m: i for i, m in enumerate(moments)}
    P = board.corners()
    oc, om, oX, ox = [], [], [], []
    for ci, c in enumerate(cams):
        for m, v in views[c].items():
            oc.append(np.full(v.ids.size, ci))
            om.append(np.full(v.ids.size, mi[m]))
            oX.append(P[v.ids])
            ox.append(v.points)
    n_intr, dist_idx = _intr_layout(opts)
    group, fixed = [], {}
    free = [c for c in cams if not intr[c].fixed]
    for ci, c in enumerate(cams):
        if intr[c].fixed:
            group.append(-1)
            fixed[ci] = intr[c]
        else:
            group.append(0 if opts.shared else free.index(c))
    return Problem(
        cams,
        moments,
        ref,
        np.concatenate(oc),
        np.concatenate(om),
        np.concatenate(oX),
        np.concatenate(ox),
        group,
        n_intr,
        dist_idx,
        opts.square_pixels,
        fixed,
    )


def bundle_adjust(
    board: Board,
    views: dict[str, dict[str, View]],
    intr: dict[str, Intrinsics],
    ref: str,
    cam_pose: dict[str, tuple[np.ndarray, np.ndarray]],
    board_pose: dict[str, tuple[np.ndarray, np.ndarray]],
    opts: Options,
    max_nfev: int = D.CALIB_MAX_NFEV,
) -> tuple[
    dict[str, Intrinsics],
    dict[str, tuple[np.ndarray, np.ndarray]],
    dict[str, tuple[np.ndarray, np.ndarray]],
    np.ndarray,
    Problem,
    OptimizeResult,
]:
    """Refine everything jointly; returns (intrinsics, camera poses, board poses, per-observation
    residual vectors (N, 2), the problem, the optimiser's status)."""
    try:
        from scipy.optimize import least_squares
    except ImportError:
        raise ClothFitError(
            "calibrate needs scipy for its bundle adjustment: pip install scipy (see requirements.txt)"
        ) from None
    prob = _problem(board, views, intr, ref, opts)
    x0 = _pack(prob, intr, cam_pose, board_pose)
    r0 = _residuals(x0, prob)
    if not np.all(np.isfinite(r0)):
        raise ClothFitError(
            "calibration: the initial estimate puts the board behind a camera (the views are "
            "inconsistent: are the same moment's images really of the same moment?)"
        )
    # x_scale "jac" evens out pixels, metres and radians; lsmr's default tolerances stop its inner solves
    # too early on this ill-conditioned system (hundreds of tiny steps): 1e-10 converges in tens
    res = least_squares(
        _residuals,
        x0,
        jac_sparsity=_sparsity(prob),
        method="trf",
        loss=opts.loss,
        f_scale=opts.loss_scale_px,
        x_scale="jac",
        max_nfev=max_nfev,
        args=(prob,),
        xtol=1e-10,
        ftol=1e-10,
        gtol=1e-10,
        tr_solver="lsmr",
        tr_options={"atol": 1e-10, "btol": 1e-10},
    )
    fx, fy, cx, cy, dist, ext, brd = _unpack(prob, res.x)
    out_intr, out_cam, out_board = {}, {}, {}
    for ci, c in enumerate(prob.cams):
        K = np.array([[fx[ci], 0, cx[ci]], [0, fy[ci], cy[ci]], [0, 0, 1.0]])
        out_intr[c] = Intrinsics(K, dist[ci].copy(), intr[c].fixed)
        out_cam[c] = (rodrigues(ext[ci, :3])[0], ext[ci, 3:].copy())
    for k, m in enumerate(prob.moments):
        out_board[m] = (rodrigues(brd[k, :3])[0], brd[k, 3:].copy())
    return out_intr, out_cam, out_board, res.fun.reshape(-1, 2), prob, res


# ======================================================================= uncertainty


def _world_cameras(prob: Problem, x: np.ndarray, world_index: int, centre: np.ndarray) -> np.ndarray:
    """Per camera ``[R (9), centre (3), f, cx, cy]`` in the world of the board at ``world_index`` (no up
    correction): camera <- reference (``Rc, tc``), reference <- board (``Rb, tb``), board -> world (FLIP)."""
    fx, fy, cx, cy, _, ext, brd = _unpack(prob, x)
    Rc, tc = rodrigues(ext[:, :3]), ext[:, 3:]
    Rb, tb = rodrigues(brd[world_index, :3][None])[0], brd[world_index, 3:]
    flip = np.diag([1.0, -1.0, -1.0])
    out = []
    for ci in range(len(prob.cams)):
        R = Rc[ci] @ Rb @ flip
        c_ref = -Rc[ci].T @ tc[ci]
        c_w = flip @ (Rb.T @ (c_ref - tb) - centre)
        out.append(np.concatenate([R.ravel(), c_w, [0.5 * (fx[ci] + fy[ci]), cx[ci], cy[ci]]]))
    return np.asarray(out)


def camera_uncertainty(prob: Problem, res: OptimizeResult, world_index: int, board: Board) -> list[dict]:
    """Per camera the standard deviations its fit leaves (first order: the Gauss-Newton covariance
    ``s^2 (J^T J)^-1`` of the last adjustment, ``s`` the residuals' RMS per degree of freedom),
    carried to the world of the board at ``world_index`` (before any up correction): ``rotation_sd_deg``
    (RMS rotation angle), ``tilt_sd_deg`` (of the world's up seen from the camera: the gravity error),
    ``centre_sd_mm``, ``focal_sd_pct``, ``principal_point_sd_px``. What the views can pin down: a
    principal point the views leave loose turns the camera with it."""
    J = res.jac.toarray() if hasattr(res.jac, "toarray") else np.asarray(res.jac)
    m, n = J.shape
    s2 = float(np.sum(res.fun**2)) / max(m - n, 1)
    C = s2 * np.linalg.pinv(J.T @ J)
    x0 = res.x
    centre = board.centre()
    base = _world_cameras(prob, x0, world_index, centre)
    ncam = base.shape[0]
    G = np.zeros((ncam, 9, n))  # per camera: rotation (3), centre (3), f, cx, cy against x
    step = 1e-7 * np.maximum(np.abs(x0), 1.0)
    for i in range(n):
        xp = x0.copy()
        xp[i] += step[i]
        w = _world_cameras(prob, xp, world_index, centre)
        for ci in range(ncam):
            dR = w[ci, :9].reshape(3, 3) @ base[ci, :9].reshape(3, 3).T
            # the small rotation's vector (the skew part: Rodrigues rounds a 1e-7 rad turn to zero)
            G[ci, :3, i] = 0.5 * np.array([dR[2, 1] - dR[1, 2], dR[0, 2] - dR[2, 0], dR[1, 0] - dR[0, 1]]) / step[i]
            G[ci, 3:, i] = (w[ci, 9:] - base[ci, 9:]) / step[i]
    out = []
    for ci in range(ncam):
        S = G[ci] @ C @ G[ci].T
        up = base[ci, :9].reshape(3, 3)[:, 2]  # the world's Z in the camera's axes
        P = np.eye(3) - np.outer(up, up)
        f = base[ci, 12]
        out.append(
            {
                "rotation_sd_deg": float(np.degrees(np.sqrt(max(np.trace(S[:3, :3]), 0.0)))),
                "tilt_sd_deg": float(np.degrees(np.sqrt(max(np.trace(P @ S[:3, :3] @ P), 0.0)))),
                "centre_sd_mm": float(1000.0 * np.sqrt(max(np.trace(S[3:6, 3:6]), 0.0))),
                "focal_sd_pct": float(100.0 * np.sqrt(max(S[6, 6], 0.0)) / f),
                "principal_point_sd_px": float(np.sqrt(max(S[7, 7] + S[8, 8], 0.0))),
            }
        )
    return out
