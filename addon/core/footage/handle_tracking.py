"""Tracking for ``clothfit handles``: each mark followed through every frame of a camera (pyramidal
Lucas-Kanade frame to frame with a forward-backward check, refined against the marked frame's own
patch; a slipped track searched for by normalised cross-correlation).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from .handle_marks import HandleOptions

if TYPE_CHECKING:
    from collections.abc import Sequence

NCC_RETRY = 0.8  # a tracked patch less like the previous frame's than this: search for it (a slipped track)
NCC_ACCEPT = 0.5  # a searched match less alike than this is no match (the track is lost)
MAX_SEARCH_PX = 150  # radius of that search around the prediction


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
    marked: dict = field(default_factory=dict)  # handle -> its marked frame (where tracking began)


def _lk_params(window, opts):
    import cv2

    return dict(
        winSize=(window, window),
        maxLevel=opts.levels,
        criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 0.001),
    )


def window_for(size_m: float, depth_m: float, focal_px: float, lo: int = 7, hi: int = 41) -> int:
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
    res = cv2.matchTemplate(
        img[Y0:Y1, X0:X1].astype(np.float32), tmpl.astype(np.float32), cv2.TM_CCOEFF_NORMED, mask=mask
    )
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


def track_camera(
    name: str,
    frames: Sequence[np.ndarray],
    marks: Sequence[tuple[int, Sequence[float], int] | None],
    opts: HandleOptions,
) -> CameraTrack:
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
                r, ok_r, _ = _lk(
                    frames[fm], frames[f], np.asarray(p, dtype=np.float64)[None], q[None], params, opts.fb_max, shape
                )
                if ok_r[0] and np.linalg.norm(r[0] - q) <= opts.ref_max:
                    q = r[0]
                acc = (q - cur) - vel
                vel = q - cur
                cur = q
                pts[f, k] = cur
                f += direction
    return CameraTrack(name, pts, lost_f, lost_b, why, {k: m[0] for k, m in enumerate(marks) if m is not None})
