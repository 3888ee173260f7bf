"""The frame rate a capture was filmed at, read from its frame times.

The frames of a capture are a camera's frames, some perhaps left out (a capture keeps every other one, or
drops a blurred one): every gap between consecutive frame times is then a whole number of the camera's
frame periods. ``frame_rate_from_times`` finds the longest period that divides every gap (within
``FPS_TOLERANCE`` of a period: float noise, timestamps rounded to the millisecond), trying the shortest
gap split into 1 to ``FPS_MAX_GAP_FRAMES`` periods, and refines it by least squares over all gaps. Too few
frames (``FPS_MIN_FRAMES``) or irregular times give no rate and say why.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from .. import defaults as D

SNAP = 5e-4  # a rate within this share of a whole number (or of an NTSC one, n / 1.001) is that number


def _snap(fps: float) -> float:
    for exact in (round(fps), round(fps * 1.001) / 1.001):
        if exact > 0 and abs(fps - exact) <= SNAP * fps:
            return float(exact)
    return float(round(fps, 4))


def frame_rate_from_times(times: ArrayLike) -> tuple[float | None, str]:
    """``(fps, why)``: the frame rate whose period divides every gap of ``times`` [s] (see the module's
    text) and how it was read, or ``(None, why not)``."""
    t = np.sort(np.asarray(times, dtype=np.float64).reshape(-1))
    if t.size < D.FPS_MIN_FRAMES:
        return None, f"{t.size} frame time(s) are too few to read a frame rate from (at least {D.FPS_MIN_FRAMES})"
    if not np.all(np.isfinite(t)):
        return None, "the frame times are not all finite"
    gaps = np.diff(t)
    if np.any(gaps <= 0):
        return None, "two frames share a time"
    for k in range(1, D.FPS_MAX_GAP_FRAMES + 1):
        n = np.round(gaps / (gaps.min() / k))
        period = float(gaps.sum() / n.sum())
        if n.max() <= D.FPS_MAX_GAP_FRAMES and np.all(np.abs(gaps - n * period) <= D.FPS_TOLERANCE * period):
            skipped = int(np.sum(n - 1))
            return _snap(1.0 / period), (
                f"{t.size} frames {1000 * period:.2f} ms apart"
                + (f", {skipped} frame(s) missing between them" if skipped else "")
            )
    return None, (
        f"the frame times are irregular (gaps of {1000 * gaps.min():.2f} to {1000 * gaps.max():.2f} ms that no "
        f"common frame period divides)"
    )
