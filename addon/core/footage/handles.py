"""The manipulation measured from footage: clips and fingertips marked once, tracked, triangulated.

``clothfit handles`` (``docs/phone_rig.md``, step 6). The user marks every held point of the cloth (a clip,
a fingertip: a *handle*) in at least two cameras at one frame (a marks JSON, below). This module

1. **triangulates** each mark (linear DLT on the undistorted rays, then Gauss-Newton on the pixel
   reprojection error with the cameras' distortion); the residual is reported per camera in pixels
   and converted to millimetres at the point's depth (``residual_px * depth / f``);
2. **tracks** each mark through every frame of every camera that marked it (pyramidal Lucas-Kanade,
   frame to frame, with a forward-backward check, then refined against the marked frame's own patch
   so that a still clip does not drift) and triangulates it per frame; a camera that disagrees with
   the others by more than ``HANDLE_MAX_RESIDUAL_PX`` (a drifted track) is dropped from that frame on;
3. **finds the release** of a released handle: the *departure frame* is the first frame where its
   3-D track is further from its pin than ``max(HANDLE_DEPARTURE_MIN_M, HANDLE_DEPARTURE_K x the held
   jitter)``; the release *instant* is extrapolated back from the first frames of the fall (a
   parabola from rest, ``X = p + A s^2 / 2, s = t - t_release``, least squares over the last held
   and the first free frames); the *release frame* is the first frame after that instant (the frame
   the scenario's ``release_time`` makes the first free one);
4. **places the cloth**: a flat rectangle of the measured size, a grid of the chosen resolution,
   moved rigidly so that the points the user says the clips hold (``at``) sit on the triangulated
   pins (Kabsch; with the ``at`` points on one line the cloth hangs below that line); each handle
   gets the grid vertex nearest its ``at`` (or, without ``at``, the vertex of the placed cloth
   nearest its pin);
5. writes the **scenario** (``Scenario.to_dict()``: the placed grid, one ``Handle`` per mark: fixed =
   its mean position, moving = its smoothed track, released = its pin and release time) and its
   ``uncertain`` block, which ``clothfit extract --scenario`` copies into the capture.

Marks JSON::

    {"frame": 0,                                     # the frame the marks are made at (default 0)
     "handles": [
       {"name": "left clip", "at": "top-left", "marks": {"cam0": [412.5, 230.0], "cam1": [300.2, 198.7]}},
       {"name": "middle", "at": [0.15, 0.0], "marks": {...}},
       {"name": "hand", "motion": "moving", "marks": {...}},
       {"name": "corner", "at": "top-right", "released": true, "marks": {...}}]}

``marks``: camera name -> ``[x, y]`` pixel of the (distorted) frame, OpenCV's convention (x = column,
y = row, pixel centres at integers). ``at``: where the handle holds the cloth, ``[u, v]`` metres from
the cloth's top-left corner (u along its width = grid columns, v down its height = grid rows) or a
corner name (``top-left``, ``top-right``, ``bottom-left``, ``bottom-right``). ``motion``: ``fixed``
(default) or ``moving``. ``released``: the handle lets go of the cloth during the footage. ``frame``
per handle overrides the top-level one. Unknown keys are refused (a typo must not pass silently).

Bad input is one line naming the file, handle, camera or frame, and nothing is written: unreadable
media, a mark outside its image or in fewer than two cameras, marks that do not meet in 3-D, a track
lost while it is needed (the camera and frame named), a released handle that never leaves its pin, a
clip far from every vertex of the cloth, two clips on one vertex.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

import numpy as np

from .. import defaults as D
from ..errors import ClothFitError
from ..jsonio import read_json
from ..physics.scenario import (MAX_HANDLE_OFFSET_M, ClothGrid, Handle, Scenario, Uncertainty, rotation_matrix,
                                rotation_vector)

FORMAT = "silhouette-cloth-fit/scenario"
CORNERS = ("top-left", "top-right", "bottom-left", "bottom-right")
MOTIONS = ("fixed", "moving")
MARKS_KEYS = ("frame", "handles")
HANDLE_KEYS = ("name", "marks", "at", "motion", "released", "frame", "size")
G = 9.81
NCC_RETRY = 0.8          # a tracked patch less like the previous frame's than this: search for it (a slipped track)
NCC_ACCEPT = 0.5         # a searched match less alike than this is no match (the track is lost)
MAX_SEARCH_PX = 150      # radius of that search around the prediction


# ==================================================================== options

@dataclass
class HandleOptions:
    mark_sigma: float = D.HANDLE_MARK_SIGMA_PX
    max_residual: float = D.HANDLE_MAX_RESIDUAL_PX
    clip_size: float = D.HANDLE_CLIP_SIZE_M
    levels: int = D.HANDLE_LK_LEVELS
    fb_max: float = D.HANDLE_FB_MAX_PX
    ref_max: float = D.HANDLE_REF_MAX_PX
    departure_min: float = D.HANDLE_DEPARTURE_MIN_M
    departure_k: float = D.HANDLE_DEPARTURE_K
    max_pin_offset: float = D.HANDLE_MAX_PIN_OFFSET_M
    smooth: int = D.HANDLE_SMOOTH_FRAMES
    settle_time: float = D.SETTLE_TIME

    def check(self):
        for nm in ("mark_sigma", "max_residual", "fb_max", "ref_max", "departure_min", "departure_k", "max_pin_offset",
                   "clip_size"):
            v = getattr(self, nm)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ClothFitError(f"handles option {nm} = {v!r} must be a positive number")
        if not (_num(self.clip_size) and 0 < self.clip_size <= 1.0):
            raise ClothFitError(f"clip size {self.clip_size!r} must be a length in metres, at most 1 m")
        if not (isinstance(self.levels, int) and 0 <= self.levels <= 8):
            raise ClothFitError(f"pyramid levels {self.levels!r} must be 0..8")
        if not (isinstance(self.smooth, int) and 0 <= self.smooth <= 50):
            raise ClothFitError(f"smoothing half-width {self.smooth!r} must be 0..50 frames")
        return self


# ====================================================================== marks

@dataclass
class HandleMarks:
    name: str
    marks: dict                 # camera name -> (x, y)
    frame: int
    at: tuple | None = None     # (u, v) metres on the cloth from its top-left corner
    at_text: str | None = None
    motion: str = "fixed"
    released: bool = False
    size: float | None = None   # the clip's size [m] (sets the tracking window); None = the option's


def _num(v):
    return not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v)


def parse_marks(d, cameras, n_frames: int, cloth_size=None, source: str = "marks") -> list:
    """The handles of a marks JSON object, checked against the cameras (names, image sizes), the
    number of frames and the cloth size ``(width, height)`` (for ``at``)."""
    if not isinstance(d, dict):
        raise ClothFitError(f"{source}: expected an object {{'frame': F, 'handles': [...]}}")
    bad = sorted(set(d) - set(MARKS_KEYS))
    if bad:
        raise ClothFitError(f"{source}: unknown key {bad[0]!r} (known: {', '.join(MARKS_KEYS)})")
    frame0 = _frame(d.get("frame", 0), n_frames, source)
    hs = d.get("handles")
    if not isinstance(hs, list) or not hs:
        raise ClothFitError(f"{source}: 'handles' must be a non-empty list")
    cams = {c.name: c for c in cameras}
    out, names = [], set()
    for i, h in enumerate(hs):
        where = f"{source} handle #{i}"
        if not isinstance(h, dict):
            raise ClothFitError(f"{where}: expected an object with 'marks'")
        name = h.get("name", f"handle {i}")
        if not isinstance(name, str) or not name.strip():
            raise ClothFitError(f"{where}: 'name' must be a non-empty string, got {name!r}")
        where = f"{source} handle '{name}'"
        if name in names:
            raise ClothFitError(f"{where}: two handles have this name")
        names.add(name)
        bad = sorted(set(h) - set(HANDLE_KEYS))
        if bad:
            raise ClothFitError(f"{where}: unknown key {bad[0]!r} (known: {', '.join(HANDLE_KEYS)})")
        marks = h.get("marks")
        if not isinstance(marks, dict):
            raise ClothFitError(f"{where}: 'marks' must be an object {{camera: [x, y]}}")
        pts = {}
        for cn, p in marks.items():
            if cn not in cams:
                raise ClothFitError(f"{where}: camera '{cn}' is not in the calibration ({', '.join(list(cams)[:12])})")
            if not (isinstance(p, (list, tuple)) and len(p) == 2 and all(_num(v) for v in p)):
                raise ClothFitError(f"{where}: the mark in camera '{cn}' must be [x, y] pixels, got {p!r}")
            c = cams[cn]
            x, y = float(p[0]), float(p[1])
            if not (-0.5 <= x <= c.width - 0.5 and -0.5 <= y <= c.height - 0.5):
                raise ClothFitError(f"{where}: the mark ({x:g}, {y:g}) in camera '{cn}' is outside its "
                                    f"{c.width}x{c.height} image")
            pts[cn] = (x, y)
        if len(pts) < 2:
            raise ClothFitError(f"{where}: marked in {len(pts)} camera{'s' if len(pts) != 1 else ''}; a point "
                                f"needs marks in at least 2 cameras to be triangulated")
        motion = h.get("motion", "fixed")
        if motion not in MOTIONS:
            raise ClothFitError(f"{where}: motion {motion!r} must be one of {', '.join(MOTIONS)}")
        released = h.get("released", False)
        if not isinstance(released, bool):
            raise ClothFitError(f"{where}: 'released' must be true or false, got {released!r}")
        at, at_text = _parse_at(h.get("at"), cloth_size, where)
        size = h.get("size")
        if size is not None and not (_num(size) and 0 < size <= 1.0):
            raise ClothFitError(f"{where}: 'size' {size!r} must be the clip's size in metres (at most 1)")
        out.append(HandleMarks(name, pts, _frame(h.get("frame", frame0), n_frames, where), at, at_text, motion,
                               released, None if size is None else float(size)))
    return out


def _frame(v, n_frames, where):
    if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v < n_frames:
        raise ClothFitError(f"{where}: frame {v!r} must be a frame index 0..{n_frames - 1}")
    return v


def _parse_at(v, size, where):
    if v is None:
        return None, None
    if isinstance(v, str):
        if v not in CORNERS:
            raise ClothFitError(f"{where}: 'at' {v!r} must be [u, v] metres or a corner: {', '.join(CORNERS)}")
        if size is None:
            return None, v
        w, h = size
        return ((0.0 if "left" in v else w), (0.0 if "top" in v else h)), v
    if not (isinstance(v, (list, tuple)) and len(v) == 2 and all(_num(x) for x in v)):
        raise ClothFitError(f"{where}: 'at' must be [u, v] metres from the cloth's top-left corner or a corner "
                            f"name, got {v!r}")
    u, vv = float(v[0]), float(v[1])
    if size is not None:
        w, h = size
        tol = 1e-6
        if not (-tol <= u <= w + tol and -tol <= vv <= h + tol):
            raise ClothFitError(f"{where}: 'at' [{u:g}, {vv:g}] is off the {w:g} x {h:g} m cloth")
    return (u, vv), None


def read_marks(path, cameras, n_frames, cloth_size=None) -> list:
    return parse_marks(read_json(path, "marks file"), cameras, n_frames, cloth_size, f"marks file {path}")


# ============================================================== triangulation

@dataclass
class Triangulation:
    X: np.ndarray               # (3,) world point
    residuals: np.ndarray       # (C,) reprojection distance per camera [px]
    residuals_mm: np.ndarray    # (C,) the same at the point's depth [mm]
    cov: np.ndarray             # (3, 3) covariance [m^2] for the pixel noise ``sigma``
    sigma: float                # pixel noise used: the residual's estimate, floored at the mark noise

    @property
    def rms(self) -> float:
        return float(np.sqrt(np.mean(self.residuals ** 2)))

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


def triangulate(cams, pts, sigma_floor: float = D.HANDLE_MARK_SIGMA_PX) -> Triangulation:
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
    s_est = math.sqrt(float(np.sum(res ** 2)) / dof)
    sigma = max(s_est, sigma_floor)
    try:
        cov = np.linalg.inv(J.T @ J) * sigma ** 2
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


# =================================================================== tracking

@dataclass
class CameraTrack:
    """One camera's tracks: ``points (F, H, 2)`` pixels (NaN where not tracked or lost) and, per
    handle, the frame where the track was lost forwards / backwards (None = kept to the end)."""
    name: str
    points: np.ndarray
    lost_forward: list
    lost_backward: list
    lost_reason: list = field(default_factory=list)
    marked: dict = field(default_factory=dict)   # handle -> its marked frame (where tracking began)


def _lk_params(window, opts):
    import cv2
    return dict(winSize=(window, window), maxLevel=opts.levels,
                criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 0.001))


def window_for(size_m, depth_m, focal_px, lo=7, hi=41) -> int:
    """The LK window of a clip ``size_m`` wide at ``depth_m`` from a camera of focal length ``focal_px``:
    its apparent size in pixels, odd, within ``lo..hi``. A window much larger than the clip holds mostly
    background, which stays still when the clip moves and drags the track back."""
    w = int(round(focal_px * size_m / max(depth_m, 1e-9)))
    w = min(max(w, lo), hi)
    return w if w % 2 == 1 else w + 1


def _lk(a, b, p, guess, params, fb_max, shape):
    """Track points ``p`` (N, 2) from image a to b (optionally from ``guess``); returns (points, ok, fb error)."""
    import cv2
    p0 = np.ascontiguousarray(p, dtype=np.float32).reshape(-1, 1, 2)
    if guess is not None:
        p1 = np.ascontiguousarray(guess, dtype=np.float32).reshape(-1, 1, 2).copy()
        p1, st, _ = cv2.calcOpticalFlowPyrLK(a, b, p0, p1, flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **params)
    else:
        p1, st, _ = cv2.calcOpticalFlowPyrLK(a, b, p0, None, **params)
    pb, st2, _ = cv2.calcOpticalFlowPyrLK(b, a, p1, p0.copy(), flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **params)
    p1 = p1.reshape(-1, 2).astype(np.float64)
    fb = np.linalg.norm(pb.reshape(-1, 2) - p0.reshape(-1, 2), axis=1)
    h, w = shape
    inside = (p1[:, 0] >= 0) & (p1[:, 0] <= w - 1) & (p1[:, 1] >= 0) & (p1[:, 1] <= h - 1)
    ok = (st.reshape(-1) == 1) & (st2.reshape(-1) == 1) & (fb <= fb_max) & inside & np.all(np.isfinite(p1), axis=1)
    return p1, ok, fb


def _patch(img, p, w):
    import cv2
    return cv2.getRectSubPix(img, (w, w), (float(p[0]), float(p[1]))).astype(np.float64)


def _ncc(a, b) -> float:
    a = a - a.mean()
    b = b - b.mean()
    den = math.sqrt(float((a * a).sum() * (b * b).sum()))
    return float((a * b).sum() / den) if den > 0 else 0.0


def _step(prev, nxt, cur, guess, win, params, opts, shape):
    """One frame of a track: LK from the predicted position; when it fails or its patch no longer looks
    like the previous one (NCC < ``NCC_RETRY``: it slipped onto the still background), the previous
    patch is searched around the prediction (normalised cross-correlation inside a disc, sub-pixel peak)
    and refined by LK without pyramid (a coarse level, mostly background, would pull it back). Returns
    (point or None, forward-backward error)."""
    import cv2
    q, ok, fb = _lk(prev, nxt, cur[None], guess[None], params, opts.fb_max, shape)
    tmpl = _patch(prev, cur, win)
    score = _ncc(tmpl, _patch(nxt, q[0], win)) if ok[0] else -1.0
    if score >= NCC_RETRY:
        return q[0], float(fb[0])
    best = (q[0], float(fb[0])) if ok[0] else (None, float(fb[0]))
    c = _search(nxt, tmpl, guess, max(2 * win, 2 * float(np.linalg.norm(guess - cur)) + win), shape)
    if c is None:
        return best
    local = dict(params, maxLevel=0)
    q2, ok2, fb2 = _lk(prev, nxt, cur[None], c[None], local, opts.fb_max, shape)
    cands = [(c, _ncc(tmpl, _patch(nxt, c, win)), float(np.linalg.norm(q2[0] - c)) if ok2[0] else np.inf)]
    if ok2[0]:
        cands.append((q2[0], _ncc(tmpl, _patch(nxt, q2[0], win)), float(fb2[0])))
    pt, sc, err = max(cands, key=lambda x: x[1])
    if sc > score and sc >= NCC_ACCEPT:
        return pt, (float(fb2[0]) if ok2[0] else 0.0)
    return best


def _search(img, tmpl, centre, radius, shape):
    """Best match of ``tmpl`` (odd square, compared inside its inscribed disc) within ``radius`` px of
    ``centre``: its sub-pixel position (parabola through the peak's neighbours), or None."""
    import cv2
    win = tmpl.shape[0]
    r = int(min(radius, MAX_SEARCH_PX))
    h, w = shape
    x0, y0 = int(round(centre[0])) - r - win // 2, int(round(centre[1])) - r - win // 2
    X0, Y0 = max(x0, 0), max(y0, 0)
    X1, Y1 = min(x0 + 2 * r + win, w), min(y0 + 2 * r + win, h)
    if X1 - X0 <= win + 2 or Y1 - Y0 <= win + 2:
        return None
    yy, xx = np.mgrid[0:win, 0:win] - (win - 1) / 2.0
    mask = ((xx * xx + yy * yy) <= (win / 2.0) ** 2).astype(np.float32)
    res = cv2.matchTemplate(img[Y0:Y1, X0:X1].astype(np.float32), tmpl.astype(np.float32), cv2.TM_CCOEFF_NORMED,
                            mask=mask)
    res = np.nan_to_num(res, nan=-1.0, posinf=-1.0, neginf=-1.0)
    iy, ix = np.unravel_index(int(np.argmax(res)), res.shape)
    dx = dy = 0.0
    if 0 < ix < res.shape[1] - 1:
        a, b, c = res[iy, ix - 1], res[iy, ix], res[iy, ix + 1]
        den = a - 2 * b + c
        dx = 0.5 * (a - c) / den if den < 0 else 0.0
    if 0 < iy < res.shape[0] - 1:
        a, b, c = res[iy - 1, ix], res[iy, ix], res[iy + 1, ix]
        den = a - 2 * b + c
        dy = 0.5 * (a - c) / den if den < 0 else 0.0
    return np.array([X0 + ix + dx + (win - 1) / 2.0, Y0 + iy + dy + (win - 1) / 2.0])


def track_camera(name, frames, marks, opts: HandleOptions) -> CameraTrack:
    """Track the marked points of one camera through its grey frames.

    ``frames``: list of ``(H, W)`` uint8 images; ``marks``: list of ``(frame index, (x, y), window px)``
    or None per handle. Each point is followed frame to frame (forward from its marked frame, then
    backward; the guess: constant acceleration in the image, exact for a clip starting to fall), and each new position is
    refined by LK from the marked frame's patch (initial guess: the frame-to-frame point); the
    refinement is kept when its round trip agrees within ``fb_max`` and it lies within ``ref_max`` of
    the frame-to-frame point. A point is lost when LK fails, its forward-backward error exceeds
    ``fb_max`` or it leaves the image; it stays lost."""
    F = len(frames)
    H = len(marks)
    pts = np.full((F, H, 2), np.nan)
    lost_f, lost_b, why = [None] * H, [None] * H, [None] * H
    shape = frames[0].shape[:2]
    for k, m in enumerate(marks):
        if m is None:
            continue
        fm, p, win = m
        params = _lk_params(win, opts)
        pts[fm, k] = p
        for direction in (1, -1):
            cur = np.asarray(p, dtype=np.float64)
            vel = acc = np.zeros(2)
            f = fm + direction
            while 0 <= f < F:
                q, fb = _step(frames[f - direction], frames[f], cur, cur + vel + acc, win, params, opts, shape)
                if q is None:
                    if direction > 0:
                        lost_f[k] = f
                    else:
                        lost_b[k] = f
                    why[k] = f"forward-backward error {fb:.2f} px" if np.isfinite(fb) else "no match"
                    break
                r, ok_r, _ = _lk(frames[fm], frames[f], np.asarray(p, dtype=np.float64)[None], q[None], params,
                                 opts.fb_max, shape)
                if ok_r[0] and np.linalg.norm(r[0] - q) <= opts.ref_max:
                    q = r[0]
                acc = (q - cur) - vel
                vel = q - cur
                cur = q
                pts[f, k] = cur
                f += direction
    return CameraTrack(name, pts, lost_f, lost_b, why, {k: m[0] for k, m in enumerate(marks) if m is not None})


# ============================================================ 3-D trajectories

@dataclass
class Trajectory3D:
    X: np.ndarray               # (F, 3), NaN where fewer than 2 cameras
    cameras: list               # per frame: names of the cameras used
    rms_px: np.ndarray          # (F,)
    problems: dict              # frame -> reason it has no point (lost tracks, disagreement)
    dropped: list               # (camera, frame, residual px): cameras dropped as drifted


def triangulate_track(cams, tracks, k, opts: HandleOptions) -> Trajectory3D:
    """Handle ``k``'s 3-D trajectory from its per-camera tracks; a camera whose reprojection misses
    by more than ``max_residual`` is dropped from that frame on (in its direction of tracking) while
    at least 2 others remain."""
    F = tracks[0].points.shape[0]
    X = np.full((F, 3), np.nan)
    used = [[] for _ in range(F)]
    rms = np.full(F, np.nan)
    problems, dropped = {}, []
    banned = {}        # camera index -> set of frames excluded
    for f in range(F):
        idx = [ci for ci, tr in enumerate(tracks) if np.all(np.isfinite(tr.points[f, k]))
               and f not in banned.get(ci, ())]
        while len(idx) >= 2:
            tri = triangulate([cams[ci] for ci in idx], [tracks[ci].points[f, k] for ci in idx], opts.mark_sigma)
            worst = int(np.argmax(tri.residuals))
            if tri.residuals[worst] <= opts.max_residual:
                X[f] = tri.X
                used[f] = [cams[ci].name for ci in idx]
                rms[f] = tri.rms
                break
            if len(idx) == 2:
                problems[f] = (f"cameras {cams[idx[0]].name} and {cams[idx[1]].name} disagree by "
                               f"{tri.residuals.max():.1f} px (a track drifted off its point)")
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
                lost.append(f"camera {tr.name} at frame {at}" + (f" ({tr.lost_reason[k]})" if tr.lost_reason[k] else "")
                            if at is not None else f"camera {tr.name} (dropped as drifted)")
            problems[f] = ("its track is lost in " + ", ".join(lost)) if lost else "fewer than 2 cameras see it"
    return Trajectory3D(X, used, rms, problems, dropped)


# ===================================================================== release

@dataclass
class Release:
    departure_frame: int        # first frame further from the pin than the threshold
    release_frame: int          # first frame after the release instant: the departure frame or the one before
    release_time: float         # the release instant written to the scenario, inside the release frame's interval
    extrapolated_time: float | None   # where the fall's parabola puts the instant (None: no parabola fits)
    threshold_m: float
    held_jitter_m: float        # RMS distance of the held frames from the pin
    pin: np.ndarray             # (3,)
    back: bool                  # the release frame is the one before the departure (a slow start)


def _parabola(t, X, pin, lo, hi, n=801):
    """Least squares ``X = pin + A (t - t_r)^2 / 2`` over the given free frames, ``t_r`` searched in
    ``[lo, hi]``: returns (t_r, A, rms)."""
    best = (np.inf, None, None)
    for tr in np.linspace(lo, hi, n):
        s2 = 0.5 * np.maximum(t - tr, 0.0) ** 2
        den = float(s2 @ s2)
        if den <= 0:
            continue
        A = (s2 @ (X - pin)) / den
        r = float(np.sum((X - pin - s2[:, None] * A) ** 2))
        if r < best[0]:
            best = (r, tr, A)
    r, tr, A = best
    return tr, A, math.sqrt(r / max(X.size, 1))


def detect_release(times, X, marked: int, opts: HandleOptions, name="handle") -> Release:
    """Departure and release of a released handle from its 3-D track ``X (F, 3)`` (NaN = missing);
    the handle is held at frame ``marked``.

    *Departure frame*: the first frame further from the pin (the median of the held frames) than
    ``max(departure_min, departure_k x the held jitter)``, and still off at the next frame.
    *Release frame*: the departure frame, or the frame before it when the release came so shortly
    before that frame that its fall was still under the threshold there. The decision: the first
    ``HANDLE_RELEASE_FREE_FRAMES`` free frames are a fall from rest (a parabola ``X = pin + A s^2 / 2``,
    ``s = t - t_release``, fits them to ``HANDLE_PARABOLA_TOL`` of the fall), the parabola through the
    first two of them puts the instant before the previous frame, and its fall there agrees with the
    one measured (within the threshold). A corner that snaps away (a stretched cloth springs back
    within milliseconds) starts with a jump no parabola from rest fits: its departure frame stands.
    *Release time*: the extrapolated instant when it lies in the release frame's interval, else the
    interval's middle."""
    times = np.asarray(times, dtype=np.float64)
    F = len(times)
    ok = np.all(np.isfinite(X), axis=1)
    d0 = np.linalg.norm(X - X[marked], axis=1)
    first_off = next((f for f in range(marked + 1, F) if ok[f] and d0[f] > opts.departure_min), None)
    if first_off is None:
        last = int(np.nonzero(ok)[0].max())
        raise ClothFitError(f"handle '{name}' is declared released but stays within {opts.departure_min * 1000:g} mm of "
                            f"its pin through frame {last} (t = {times[last]:g} s): not released in the footage, or "
                            f"its track stopped early")
    held = [f for f in range(0, first_off) if ok[f]]
    pin = np.median(X[held], axis=0)
    quiet = held[:-2] if len(held) >= 5 else held          # the last held frames may already carry the start of the fall
    jitter = float(np.sqrt(np.mean(np.sum((X[quiet] - pin) ** 2, axis=1))))
    thr = max(opts.departure_min, opts.departure_k * jitter)
    d = np.linalg.norm(X - pin, axis=1)
    early = [f for f in range(0, marked) if ok[f] and d[f] > thr]
    if early:
        raise ClothFitError(f"handle '{name}' moves {d[early[0]] * 1000:.1f} mm off its pin at frame {early[0]}, before "
                            f"its marked frame {marked}: mark it at a frame where it is held")
    dep = next((f for f in range(marked + 1, F) if ok[f] and d[f] > thr
                and (f + 1 >= F or not ok[f + 1] or d[f + 1] > thr)), None)
    if dep is None:
        raise ClothFitError(f"handle '{name}' is declared released but never stays off its pin by more than "
                            f"{thr * 1000:.2f} mm")
    free = [f for f in range(dep, min(F, dep + D.HANDLE_RELEASE_FREE_FRAMES)) if ok[f]]
    period = float(times[dep] - times[dep - 1]) if dep > 0 else (float(np.median(np.diff(times))) if F > 1 else 1.0)
    t_ext, back = None, False
    if len(free) >= 3 and dep > 0:
        _, _, rms = _parabola(times[free], X[free], pin, times[dep] - 4 * period, times[dep])
        if rms <= max(D.HANDLE_PARABOLA_TOL * d[free[-1]], 3.0 * jitter):      # a fall from rest, not a snap
            # the instant from the first two free frames: the least bent by the fall's jerk
            tr, A, _ = _parabola(times[free[:2]], X[free[:2]], pin, times[dep] - 4 * period, times[dep])
            prev = dep - 1
            predicted = 0.5 * float(np.linalg.norm(A)) * max(times[prev] - tr, 0.0) ** 2
            t_ext = tr
            back = tr < times[prev] and (not ok[prev] or abs(d[prev] - predicted) < thr)
    rel = dep - 1 if back else dep
    lo = times[rel - 1] if rel > 0 else times[rel] - period
    hi = times[rel]
    t_r = t_ext if t_ext is not None and lo <= t_ext < hi else 0.5 * (lo + hi)
    return Release(int(dep), int(rel), float(t_r), None if t_ext is None else float(t_ext), float(thr), jitter, pin,
                   bool(back))


# ================================================================== smoothing

def smooth_track(times, X, half: int) -> np.ndarray:
    """Local quadratic regression over +-``half`` frames at every frame (Savitzky-Golay for uneven times;
    keeps a constant acceleration exactly); ``half`` 0 = unchanged."""
    if half <= 0 or len(times) < 3:
        return X.copy()
    out = X.copy()
    F = len(times)
    for f in range(F):
        a, b = max(0, f - half), min(F, f + half + 1)
        t = times[a:b] - times[f]
        if b - a < 3:
            continue
        V = np.stack([np.ones_like(t), t, t * t], 1)
        coef = np.linalg.lstsq(V, X[a:b], rcond=None)[0]
        out[f] = coef[0]
    return out


# ================================================================== placement

@dataclass
class Placement:
    grid: ClothGrid
    method: str
    residuals_m: np.ndarray     # per handle with 'at': |placed at-point - pin|
    with_at: list               # indices of those handles
    ats: list                   # per handle the (u, v) used (the given 'at', the top-edge rule's) or None


def cloth_local(at, width, height):
    """Local grid coordinates of a point ``(u, v)`` on the cloth (from its top-left corner)."""
    return np.array([at[0] - width / 2.0, at[1] - height / 2.0, 0.0])


def _kabsch(Q, P):
    """Rotation R and translation o minimising sum |o + R q - p|^2 (proper rotation)."""
    qc, pc = Q.mean(0), P.mean(0)
    Hm = (Q - qc).T @ (P - pc)
    U, _, Vt = np.linalg.svd(Hm)
    dfix = np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0
    R = Vt.T @ np.diag([1.0, 1.0, dfix]) @ U.T
    return R, pc - R @ qc


def _hanging(Q, P, width, height, gravity):
    """Placement from points on one line (two clips, or several along an edge): the line of the ``at``
    points onto the line of the pins, the cloth hanging below it (its centre as low as it can be)."""
    down = -np.asarray(gravity, dtype=np.float64)
    down = -down / np.linalg.norm(down)                  # unit vector along gravity
    qc, pc = Q.mean(0), P.mean(0)
    i0, i1 = _extremes(Q)
    uq = Q[i1] - Q[i0]
    up_ = P[i1] - P[i0]
    if np.linalg.norm(uq) < 1e-9 or np.linalg.norm(up_) < 1e-9:
        raise ClothFitError("the clips with 'at' sit on one point: give 'at' for clips at 2 different places")
    uq /= np.linalg.norm(uq)
    up_ /= np.linalg.norm(up_)
    # in the cloth: the in-plane direction from the line towards the cloth's centre (rows downward if on it)
    cq = -qc - np.dot(-qc, uq) * uq
    cq = np.array([0.0, 1.0, 0.0]) - np.dot([0.0, 1.0, 0.0], uq) * uq if np.linalg.norm(cq) < 1e-9 else cq
    cq /= np.linalg.norm(cq)
    # in the world: gravity's component across the pins' line
    cw = down - np.dot(down, up_) * up_
    if np.linalg.norm(cw) < 1e-6:
        raise ClothFitError("the clips with 'at' lie on a vertical line: the cloth's plane is unknown; give 'at' for "
                            "a clip off that line")
    cw /= np.linalg.norm(cw)
    A = np.stack([uq, cq, np.cross(uq, cq)], 1)
    B = np.stack([up_, cw, np.cross(up_, cw)], 1)
    R = B @ A.T
    o = pc - R @ qc
    return R, o


def _extremes(Q):
    n = len(Q)
    best, pair = -1.0, (0, min(1, n - 1))
    for i in range(n):
        for j in range(i + 1, n):
            d = float(np.linalg.norm(Q[i] - Q[j]))
            if d > best:
                best, pair = d, (i, j)
    return pair


def _collinear(Q, tol=1e-6):
    if len(Q) < 3:
        return True
    s = np.linalg.svd(Q - Q.mean(0), compute_uv=False)
    return s[1] <= tol * max(s[0], 1e-12)


def place_cloth(width, height, nx, ny, pins, ats, gravity=D.GRAVITY) -> Placement:
    """The rigid placement of the flat ``width x height`` cloth (grid ``nx x ny``) that puts the
    ``at`` points of the handles on their pins. ``pins (H, 3)``; ``ats``: per handle (u, v) or None.
    Without any ``at``: the cloth hangs by its top edge, the two pins furthest apart at its top
    corners and the others on the edge between them."""
    pins = np.asarray(pins, dtype=np.float64)
    with_at = [k for k, a in enumerate(ats) if a is not None]
    if not with_at:
        if len(pins) < 2:
            raise ClothFitError("one handle without 'at': say where it holds the cloth ('at': [u, v] or a corner)")
        i, j = _extremes(pins)
        e = pins[j] - pins[i]
        L = float(np.linalg.norm(e))
        method = "top edge (no 'at' given: the two clips furthest apart at the top corners)"
        ats = [None] * len(pins)
        for k in range(len(pins)):
            u = float(np.dot(pins[k] - pins[i], e / L)) if L > 0 else 0.0
            ats[k] = (min(max(u, 0.0), width), 0.0)
        ats[i], ats[j] = (0.0, 0.0), (width, 0.0)
        with_at = list(range(len(pins)))
    else:
        method = "the clips' 'at' onto their pins"
    if len(with_at) < 2:
        raise ClothFitError("only one handle says where it holds the cloth ('at'): give 'at' for at least 2 handles "
                            "(or for none: the cloth then hangs by its top edge)")
    Q = np.array([cloth_local(ats[k], width, height) for k in with_at])
    P = pins[with_at]
    if _collinear(Q) or _collinear(P, 1e-3):
        R, o = _hanging(Q, P, width, height, gravity)
        method += ", hanging below their line"
    else:
        R, o = _kabsch(Q, P)
        method += ", rigid fit (Kabsch)"
    grid = ClothGrid(nx, ny, width, side_y=height, origin=o, rotation=rotation_vector(R))
    res = np.linalg.norm(o + Q @ R.T - P, axis=1)
    return Placement(grid, method, res, with_at, list(ats))


def grid_resolution(width, height, n=None, nx=None, ny=None, ats=()):
    """(nx, ny): given; else ``n`` vertices along the longer side and the other side's count making the
    cells as square as possible; without ``n``, the count within HANDLE_GRID_N - 4 .. + 8 that puts the
    given ``at`` points (u, v) nearest to grid vertices (ties: nearest to HANDLE_GRID_N), so that the
    pins sit where the clips are."""
    if nx is not None or ny is not None:
        if nx is None or ny is None:
            raise ClothFitError("give both grid counts (columns x rows), or one count for the longer side")
        for v in (nx, ny):
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 2:
                raise ClothFitError(f"grid resolution {nx} x {ny} must be whole numbers >= 2")
        return int(nx), int(ny)

    def square(n):
        if width >= height:
            return n, max(2, int(round(height / (width / (n - 1)))) + 1)
        return max(2, int(round(width / (height / (n - 1)))) + 1), n
    if n is not None:
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 2:
            raise ClothFitError(f"grid resolution {n!r} must be a whole number >= 2")
        return square(int(n))
    pts = np.array([a for a in ats if a is not None], dtype=np.float64).reshape(-1, 2)
    if pts.size == 0:
        return square(D.HANDLE_GRID_N)

    def miss(n):
        cx, cy = square(n)
        gu = np.linspace(0, width, cx)
        gv = np.linspace(0, height, cy)
        return max(float(np.hypot(np.abs(gu - u).min(), np.abs(gv - v).min())) for u, v in pts)
    cands = range(max(2, D.HANDLE_GRID_N - 4), D.HANDLE_GRID_N + 9)
    return square(min(cands, key=lambda n: (round(miss(n), 4), abs(n - D.HANDLE_GRID_N))))


# ===================================================================== footage

class FootageSource:
    """Frames of every camera as grey uint8 images, and their capture times: image folders
    (``footage/<camera>/`` frames in natural order, background plates skipped, as ``extract`` reads
    them) or one video per camera at the capture times (``footage/video.py``)."""

    def __init__(self, cameras, times, folder=None, videos=None, sync=None):
        self.cameras = {c.name: c for c in cameras}
        self.times = [float(t) for t in times]
        self.folder, self.videos, self.sync = folder, videos, sync
        self.used = {}

    def frames(self, name):
        import cv2
        cam = self.cameras[name]
        if self.videos:
            from . import video
            if name not in self.sync:
                raise ClothFitError(f"sync: no time for camera '{name}'")
            frames, rep = video.camera_frames(self.videos, cam, self.sync[name], self.times)
            self.used[name] = rep["video"]
            return [cv2.cvtColor(f, cv2.COLOR_BGR2GRAY) for f in frames]
        from .extract import list_camera_images
        _, paths = list_camera_images(os.path.join(self.folder, name))
        if len(paths) != len(self.times):
            raise ClothFitError(f"camera '{name}': {len(paths)} frames in {os.path.join(self.folder, name)} but "
                                f"{len(self.times)} frame times")
        out = []
        for p in paths:
            if os.path.getsize(p) == 0:
                raise ClothFitError(f"image {p} is an empty (zero-byte) file")
            img = cv2.imread(p, cv2.IMREAD_GRAYSCALE)
            if img is None:
                raise ClothFitError(f"image {p} is unreadable (not an image, corrupt or truncated)")
            if img.shape[:2] != (cam.height, cam.width):
                raise ClothFitError(f"image {p} is {img.shape[0]}x{img.shape[1]} (HxW) but camera '{name}' images "
                                    f"{cam.height}x{cam.width}")
            out.append(img)
        self.used[name] = os.path.join(self.folder, name)
        return out


# ================================================================== the whole job

def measure_handles(cameras, source: FootageSource, marks, cloth_size, grid_n=None, grid_nx=None, grid_ny=None,
                    options: HandleOptions | None = None, progress=None) -> dict:
    """Triangulate, track, find releases, place the cloth: returns ``{"scenario": Scenario, "uncertain":
    Uncertainty, "report": dict}``. ``marks``: HandleMarks list (``parse_marks``); ``cloth_size``
    ``(width, height)`` [m]."""
    opts = (options or HandleOptions()).check()
    width, height = check_size(cloth_size)
    nx, ny = grid_resolution(width, height, grid_n, grid_nx, grid_ny, [h.at for h in marks])
    times = np.asarray(source.times, dtype=np.float64)
    F = times.size
    if F < 1:
        raise ClothFitError("no frames")
    if np.any(np.diff(times) <= 0):
        raise ClothFitError(f"frame times must increase, got {times.tolist()[:8]}...")
    cams = [c for c in cameras if any(c.name in h.marks for h in marks)]
    warnings = []
    # ---------------------------------------------------------------- the marks in 3-D
    tri0s = []
    for h in marks:
        mc = [c for c in cams if c.name in h.marks]
        tri0 = triangulate(mc, [h.marks[c.name] for c in mc], opts.mark_sigma)
        worst = int(np.argmax(tri0.residuals))
        if tri0.residuals[worst] > opts.max_residual:
            raise ClothFitError(f"handle '{h.name}': its marks do not meet in 3-D (camera {mc[worst].name} misses "
                                f"by {tri0.residuals[worst]:.1f} px at frame {h.frame}): a mark on another point, or "
                                f"the wrong calibration")
        tri0s.append(tri0)
    # ---------------------------------------------------------------- track per camera
    tracks = []
    for i, cam in enumerate(cams):
        if progress:
            progress(i, len(cams), f"tracking in {cam.name}")
        frames = source.frames(cam.name)
        mk = [(h.frame, h.marks[cam.name],
               window_for(h.size or opts.clip_size, float(cam.to_camera(tri0s[k].X)[2]), 0.5 * (cam.K[0, 0] + cam.K[1, 1])))
              if cam.name in h.marks else None for k, h in enumerate(marks)]
        tracks.append(track_camera(cam.name, frames, mk, opts))
        del frames
    if progress:
        progress(len(cams), len(cams), "triangulating")
    # ---------------------------------------------------------------- per handle
    rows, keys, rel_info = [], [], []
    for k, h in enumerate(marks):
        tri0 = tri0s[k]
        marked_cams = [c.name for c in cams if c.name in h.marks]
        traj = triangulate_track(cams, tracks, k, opts)
        for cn, f, r in traj.dropped:
            warnings.append(f"handle '{h.name}': camera {cn} dropped from frame {f} on (its track misses the others' "
                            f"point by {r:.1f} px)")
        ok = np.all(np.isfinite(traj.X), axis=1)
        rel = None
        if h.released:
            rel = detect_release(times, traj.X, h.frame, opts, h.name)
            need = range(0, min(F, rel.departure_frame + 1))
        else:
            need = range(0, F)
        missing = [f for f in need if not ok[f]]
        if missing:
            f = missing[0]
            raise ClothFitError(f"handle '{h.name}': no 3-D point at frame {f} (t = {times[f]:g} s): "
                                f"{traj.problems.get(f, 'fewer than 2 cameras')}")
        track_len = {tr.name: int(np.sum(np.all(np.isfinite(tr.points[:, k]), axis=1))) for tr in tracks
                     if k in tr.marked}
        row = {"name": h.name, "motion": h.motion, "released": h.released, "marked_frame": h.frame,
               "cameras": marked_cams,
               "residual_px": {cn: float(r) for cn, r in zip(marked_cams, tri0.residuals)},
               "residual_rms_px": tri0.rms,
               "residual_mm": {cn: float(r) for cn, r in zip(marked_cams, tri0.residuals_mm)},
               "residual_rms_mm": float(np.sqrt(np.mean(tri0.residuals_mm ** 2))),
               "sd_mm": 1000.0 * tri0.sd_max, "sigma_px": tri0.sigma,
               "marked_position": tri0.X.tolist(),
               "track_frames": track_len, "tracked_3d_frames": int(ok.sum()),
               "track_rms_px": float(np.nanmean(traj.rms_px)) if ok.any() else None}
        if rel is not None:
            row.update(departure_frame=rel.departure_frame, release_frame=rel.release_frame,
                       release_time=rel.release_time, release_extrapolated_time=rel.extrapolated_time,
                       release_before_departure=rel.back, release_threshold_mm=rel.threshold_m * 1000.0,
                       held_jitter_mm=rel.held_jitter_m * 1000.0)
        if h.motion == "moving":
            end = rel.departure_frame if rel is not None else F
            sm = smooth_track(times[:end], traj.X[:end], opts.smooth)
            key_t, key_x = times[:end], sm
            row["travel_mm"] = float(1000.0 * np.max(np.linalg.norm(sm - sm[0], axis=1)))
        else:
            held = np.nonzero(ok[: (rel.departure_frame if rel is not None else F)])[0]
            pos = rel.pin if rel is not None else np.mean(traj.X[held], axis=0)
            key_t, key_x = times[:1], pos[None]
            dist = np.linalg.norm(traj.X[held] - pos, axis=1)
            drift = float(dist.max())
            row["drift_mm"] = 1000.0 * drift
            # the tracking jitter from second differences (a smooth motion hardly has any, noise has sqrt(6) sigma)
            d2 = np.linalg.norm(np.diff(traj.X[held], 2, axis=0), axis=1) if held.size > 2 else np.zeros(1)
            thr = max(opts.departure_min, opts.departure_k * float(np.median(d2)) / math.sqrt(6.0))
            if not h.released and drift > thr:
                fmax = int(held[np.argmax(dist)])
                warnings.append(f"handle '{h.name}' is declared fixed but moves {drift * 1000:.1f} mm from its mean "
                                f"position (frame {fmax}): declare it \"motion\": \"moving\"?")
        rows.append(row)
        keys.append((key_t, key_x))
        rel_info.append(rel)
    # ---------------------------------------------------------------- the cloth
    pins = np.array([kx[0] for _, kx in keys])
    ats = [h.at for h in marks]
    place = place_cloth(width, height, nx, ny, pins, ats)
    grid = place.grid
    vertices = []
    for k, h in enumerate(marks):
        a = place.ats[k]
        if a is not None:
            v = int(np.argmin(np.linalg.norm(grid.local - cloth_local(a, width, height), axis=1)))
        else:
            v = int(np.argmin(np.linalg.norm(grid.rest - pins[k], axis=1)))
        for k2, v2 in enumerate(vertices):
            if v2 == v:
                raise ClothFitError(f"handles '{marks[k2].name}' and '{h.name}' fall on the same grid vertex (row "
                                    f"{v // nx}, column {v % nx}): they are closer than a grid cell "
                                    f"({grid.spacing * 1000:.1f} mm) on the cloth; use a finer grid or check their "
                                    f"'at' and marks")
        vertices.append(v)
    for k, h in enumerate(marks):
        v, a = vertices[k], place.ats[k]
        off = float(np.linalg.norm(grid.rest[v] - pins[k]))
        if off > opts.max_pin_offset:
            raise ClothFitError(f"handle '{h.name}' is {off * 1000:.0f} mm from its vertex (row {v // nx}, column "
                                f"{v % nx}) of the placed {width:g} x {height:g} m cloth (at most "
                                f"{opts.max_pin_offset * 1000:g} mm): check the cloth size, its 'at' and its marks")
        rows[k].update(vertex=v, row=v // nx, column=v % nx, pin_offset_mm=off * 1000.0,
                       at=list(a) if a is not None else None)
    if float(place.residuals_m.max(initial=0.0)) > 0.5 * grid.spacing:
        warnings.append(f"the placed cloth misses the clips by up to {place.residuals_m.max() * 1000:.1f} mm (more than "
                        f"half a grid cell): the rest lengths near them are distorted; check the cloth size and 'at'")
    # ---------------------------------------------------------------- scenario
    handles = []
    for k, h in enumerate(marks):
        kt, kx = keys[k]
        rel = rel_info[k]
        handles.append(Handle(vertices[k], kt, kx, rel.release_time if rel is not None else None))
    scen = Scenario(grid, handles, times, opts.settle_time)
    bounds = []
    for k, row in enumerate(rows):
        b = max(D.HANDLE_BOUND_K * row["sd_mm"] / 1000.0, D.HANDLE_BOUND_FLOOR_M)
        if b > MAX_HANDLE_OFFSET_M:
            raise ClothFitError(f"handle '{marks[k].name}': its position is uncertain by {b * 1000:.0f} mm (3 sigma), "
                                f"more than the {MAX_HANDLE_OFFSET_M * 1000:g} mm a capture may declare: mark it in "
                                f"cameras seeing it from more different directions")
        bounds.append(round(b, 6))
        row["uncertain_mm"] = b * 1000.0
    rels = [r for r in rel_info if r is not None]
    period = float(np.median(np.diff(times))) if F > 1 else 0.0
    t_off = period if rels else 0.0      # the release frame is exact: the instant is within its frame interval
    unc = Uncertainty.parse({"time_offset": round(t_off, 6), "handles": bounds}, len(handles), "handles")
    report = {"cloth": {"width": width, "height": height, "nx": nx, "ny": ny, "spacing_mm": 1000.0 * grid.spacing,
                        "spacing_y_mm": 1000.0 * grid.side_y / (ny - 1), "origin": grid.origin.tolist(),
                        "rotation": grid.rotation.tolist(), "normal": grid.R[:, 2].tolist(),
                        "placement": place.method,
                        "placement_residual_mm": {marks[k].name: float(r) * 1000.0
                                                  for k, r in zip(place.with_at, place.residuals_m)},
                        "placement_rms_mm": float(1000.0 * np.sqrt(np.mean(place.residuals_m ** 2)))},
              "frames": F, "frame_period_s": period, "cameras": [c.name for c in cams],
              "handles": rows, "uncertain": unc.to_dict(),
              "uncertain_rule": (f"handles: {D.HANDLE_BOUND_K:g} x the largest standard deviation of the triangulated "
                                 f"pin (pixel noise = the residual's estimate, at least {opts.mark_sigma:g} px), at "
                                 f"least {D.HANDLE_BOUND_FLOOR_M * 1000:g} mm; time_offset: one frame period when a "
                                 f"handle is released (its release time lies in the release frame's interval), else "
                                 f"0 (the handles are measured on the frames' own clock)"),
              "warnings": warnings}
    return {"scenario": scen, "uncertain": unc, "report": report}


def write_scenario(path, result, inputs=()) -> dict:
    """The scenario file ``clothfit extract --scenario`` reads: ``{"format", "version", "scenario",
    "uncertain", "report"}``, written atomically; refuses to overwrite one of ``inputs``."""
    from ..safeio import atomic_json
    real = os.path.realpath(path)
    for p in inputs:
        if p and os.path.exists(p) and os.path.realpath(p) == real:
            raise ClothFitError(f"handles: writing {path} would overwrite its input {p}: choose another --out")
    if os.path.isdir(path):
        raise ClothFitError(f"handles: --out {path} is a directory: give a file name")
    d = {"format": FORMAT, "version": 1, "scenario": result["scenario"].to_dict(),
         "uncertain": result["uncertain"].to_dict(), "report": result["report"]}
    atomic_json(path, d)
    return d


# ====================================================================== inputs

def check_size(size):
    """(width, height) [m] of the cloth, checked."""
    try:
        w, h = (float(v) for v in size)
    except (TypeError, ValueError):
        raise ClothFitError(f"cloth size {size!r} must be two lengths: width and height in metres") from None
    for nm, v in (("width", w), ("height", h)):
        if not (math.isfinite(v) and 0 < v <= 100):
            raise ClothFitError(f"cloth {nm} {v:g} m must be a positive length in metres (at most 100)")
    return w, h


def frame_times_for(count=None, times=None, fps=None, start=0.0, what="footage"):
    """The capture times: ``times`` as given, else ``count`` frames at ``fps`` from ``start``."""
    if times is not None:
        t = [float(x) for x in times]
        if not t:
            raise ClothFitError(f"{what}: no frame times")
        return t
    if fps is None:
        raise ClothFitError(f"{what}: no frame times: give --times, or --fps (and for videos --frames)")
    if not (_num(fps) and fps > 0):
        raise ClothFitError(f"--fps {fps!r} must be a positive number of frames per second")
    if count is None or count < 1:
        raise ClothFitError(f"{what}: the number of frames is unknown: give --frames")
    return [float(start) + i / float(fps) for i in range(int(count))]


def run(out, marks, size, footage=None, videos=None, sync=None, find_sync=False, flash_time=0.0, cameras=None,
        times=None, fps=None, start=0.0, frames=None, grid=None, options: HandleOptions | None = None,
        progress=None) -> dict:
    """``clothfit handles``: read the inputs, measure, write ``out`` (``write_scenario``); returns the
    written document. ``footage``: image folders per camera (``extract``'s layout, ``footage.json``
    optional) or ``videos`` + ``sync`` (a sync JSON path, or ``find_sync`` for a flash); ``cameras``:
    a calibration path (default: the footage's); ``times`` / ``fps`` (+ ``start``, ``frames``): the
    capture times (default: ``footage.json``'s); ``size`` (width, height) [m]; ``grid``: None, N (along
    the longer side) or (nx, ny)."""
    from . import calib_io, video
    from .extract import _find_calibration, _read_footage_json, list_camera_images
    opts = (options or HandleOptions()).check()
    inputs = [marks]
    if videos and footage:
        raise ClothFitError(f"handles: a footage folder ({footage}) and --videos exclude each other")
    if not videos and not footage:
        raise ClothFitError("handles: give a footage folder (image folders per camera) or --videos DIR")
    meta = {}
    if footage:
        if not os.path.isdir(footage):
            raise ClothFitError(f"footage folder not found: {footage}")
        meta, meta_path = _read_footage_json(footage)
        inputs.append(meta_path)
        if cameras is None:
            cameras = meta.get("cameras")
            cameras = os.path.join(footage, cameras) if isinstance(cameras, str) else _find_calibration(footage)
    if cameras is None:
        raise ClothFitError("handles: no calibration: give --cameras (or a footage folder with footage.json's "
                            "'cameras', a cameras.* / calibration.* file or a COLMAP folder)")
    if isinstance(cameras, str):
        inputs.append(cameras)
        sizes = video.video_sizes(videos) if videos and calib_io.detect_format(cameras) == "easymocap" else None
        cams = calib_io.import_cameras(cameras, sizes=sizes)
    else:
        cams = list(cameras)
    if footage:
        if times is None and fps is None and meta.get("frame_times") is not None:
            times = meta["frame_times"]
        if times is None:
            named = [c for c in cams if os.path.isdir(os.path.join(footage, c.name))]
            count = len(list_camera_images(os.path.join(footage, named[0].name))[1]) if named else None
            times = frame_times_for(count, None, fps, start, f"footage {footage}")
        else:
            times = frame_times_for(None, times, None, 0.0, f"footage {footage}")
    else:
        times = frame_times_for(frames, times, fps, start, f"videos {videos}")
    t = np.asarray(times, dtype=np.float64)
    if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        raise ClothFitError(f"frame times must be finite and strictly increasing, got {times[:6]}...")
    width, height = check_size(size)
    hmarks = read_marks(marks, cams, len(times), (width, height))
    sync_times = None
    if videos:
        names = sorted({n for h in hmarks for n in h.marks})
        if find_sync:
            sync_times = video.flash_sync(videos, names, flash_time, sync)
        elif sync:
            inputs.append(sync)
            sync_times = video.read_sync(sync, names)
        else:
            raise ClothFitError("handles --videos needs --sync SYNC.json (or --find-sync flash)")
    if os.path.isdir(out):
        raise ClothFitError(f"handles: --out {out} is a directory: give a file name")
    for p in inputs:
        if p and os.path.exists(p) and os.path.realpath(p) == os.path.realpath(out):
            raise ClothFitError(f"handles: writing {out} would overwrite its input {p}: choose another --out")
    gkw = {}
    if isinstance(grid, (tuple, list)):
        gkw = {"grid_nx": grid[0], "grid_ny": grid[1]}
    elif grid is not None:
        gkw = {"grid_n": grid}
    src = FootageSource(cams, times, folder=footage, videos=videos, sync=sync_times)
    result = measure_handles(cams, src, hmarks, (width, height), options=opts, progress=progress, **gkw)
    rep = result["report"]
    rep.update({"marks": os.path.abspath(marks), "footage": os.path.abspath(footage) if footage else None,
                "videos": os.path.abspath(videos) if videos else None, "sync": sync_times,
                "calibration": os.path.abspath(cameras) if isinstance(cameras, str) else None,
                "media": src.used})
    return write_scenario(out, result, inputs)


def format_report(rep: dict) -> str:
    """A table for people: one line per handle."""
    c = rep["cloth"]
    lines = [f"cloth {c['width']:g} x {c['height']:g} m as {c['nx']} x {c['ny']} vertices "
             f"({c['spacing_mm']:.1f} x {c['spacing_y_mm']:.1f} mm cells); placement: {c['placement']}; "
             f"its residual {c['placement_rms_mm']:.2f} mm RMS",
             f"{'handle':<14} {'vertex':>11} {'res px':>7} {'res mm':>7} {'sd mm':>6} {'bound mm':>8} {'track':>6} "
             f"{'release':>16}"]
    for h in rep["handles"]:
        rel = (f"frame {h['release_frame']} ({h['release_time']:.4f} s)" if h.get("released") else
               ("moving" if h["motion"] == "moving" else "fixed"))
        lines.append(f"{h['name'][:14]:<14} {'r%d c%d' % (h['row'], h['column']):>11} {h['residual_rms_px']:7.2f} "
                     f"{h['residual_rms_mm']:7.2f} {h['sd_mm']:6.2f} {h['uncertain_mm']:8.2f} "
                     f"{h['tracked_3d_frames']:>6} {rel:>16}")
    lines.append(f"uncertain: {rep['uncertain']}")
    for w in rep.get("warnings", []):
        lines.append("warning: " + w)
    return "\n".join(lines)
