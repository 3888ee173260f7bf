"""Release detection for ``clothfit handles``: the departure frame of a released handle, the release
instant extrapolated back from the first frames of the fall (a parabola from rest), and the
smoothing of a moving handle's track.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .. import defaults as D
from ..errors import ClothFitError
from .handle_marks import HandleOptions

# ===================================================================== release


@dataclass
class Release:
    departure_frame: int  # first frame further from the pin than the threshold
    release_frame: int  # first frame after the release instant: the departure frame or the one before
    release_time: float  # the release instant written to the scenario, inside the release frame's interval
    extrapolated_time: float | None  # where the fall's parabola puts the instant (None: no parabola fits)
    threshold_m: float
    held_jitter_m: float  # RMS distance of the held frames from the pin
    pin: np.ndarray  # (3,)
    back: bool  # the release frame is the one before the departure (a slow start)


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


def detect_release(times: np.ndarray, X: np.ndarray, marked: int, opts: HandleOptions, name: str = "handle") -> Release:
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
        raise ClothFitError(
            f"handle '{name}' is declared released but stays within {opts.departure_min * 1000:g} mm of "
            f"its pin through frame {last} (t = {times[last]:g} s): not released in the footage, or "
            f"its track stopped early"
        )
    held = [f for f in range(0, first_off) if ok[f]]
    pin = np.median(X[held], axis=0)
    quiet = held[:-2] if len(held) >= 5 else held  # the last held frames may already carry the start of the fall
    jitter = float(np.sqrt(np.mean(np.sum((X[quiet] - pin) ** 2, axis=1))))
    thr = max(opts.departure_min, opts.departure_k * jitter)
    d = np.linalg.norm(X - pin, axis=1)
    early = [f for f in range(0, marked) if ok[f] and d[f] > thr]
    if early:
        raise ClothFitError(
            f"handle '{name}' moves {d[early[0]] * 1000:.1f} mm off its pin at frame {early[0]}, before "
            f"its marked frame {marked}: mark it at a frame where it is held"
        )
    dep = next(
        (f for f in range(marked + 1, F) if ok[f] and d[f] > thr and (f + 1 >= F or not ok[f + 1] or d[f + 1] > thr)),
        None,
    )
    if dep is None:
        raise ClothFitError(
            f"handle '{name}' is declared released but never stays off its pin by more than {thr * 1000:.2f} mm"
        )
    free = [f for f in range(dep, min(F, dep + D.HANDLE_RELEASE_FREE_FRAMES)) if ok[f]]
    period = float(times[dep] - times[dep - 1]) if dep > 0 else (float(np.median(np.diff(times))) if F > 1 else 1.0)
    t_ext, back = None, False
    if len(free) >= 3 and dep > 0:
        _, _, rms = _parabola(times[free], X[free], pin, times[dep] - 4 * period, times[dep])
        if rms <= max(D.HANDLE_PARABOLA_TOL * d[free[-1]], 3.0 * jitter):  # a fall from rest, not a snap
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
    return Release(
        int(dep), int(rel), float(t_r), None if t_ext is None else float(t_ext), float(thr), jitter, pin, bool(back)
    )


# ================================================================== smoothing


def smooth_track(times: np.ndarray, X: np.ndarray, half: int) -> np.ndarray:
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
