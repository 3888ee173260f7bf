"""Handlings: how hands move a cloth after it settles, as keyed handle paths (``scenario.Handle``).

Every handling holds corners of the sheet through the settle (t < 0) and moves them from t = 0 on;
a path is piecewise linear between keys ``D.HANDLING_KEY_STEP`` apart, held at its first key before
it and at its last after it (the ``Handle`` rule). The names (``D.HANDLINGS``, ``synth --handling``):

* ``release``: the paper's: four corners held still, one let go at t = 0 (``paper_scenario``);
* ``wave``: four corners held, one of them waved along ``direction`` (default up and down) by
  ``amplitude * sin(2 pi frequency t)`` until the last frame time, the other three still;
* ``lift``: the cloth hangs from two hands at the corners of one edge (the other corners free);
  both hands go up by ``height`` and down again over ``duration`` (a raised cosine);
* ``apart``: the same two hands start ``hold`` of the edge's length apart (the edge slack), move
  apart to ``spread`` of it and back over ``duration`` (a raised cosine);
* ``drag``: a table (a plane ``drop`` below the sheet, ``colliders.py``); the sheet is held flat by its
  four corners, at t = 0 three of them let go (it drops onto the table) and the fourth is lowered
  onto the table and dragged along it by ``distance`` over ``duration`` (smoothly), away from the
  cloth's middle (the cloth follows it).

Every default is in ``defaults.py``; the builders take the grid and frame times of any scenario.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .. import defaults as D
from ..errors import ClothFitError
from .colliders import Collider, Collisions
from .scenario import ClothGrid, Handle, Scenario, paper_scenario

OPTIONS = {
    "release": {"released_corner": D.RELEASED_CORNER},
    "wave": {
        "corner": D.WAVE_CORNER,
        "amplitude": D.WAVE_AMPLITUDE,
        "frequency": D.WAVE_FREQUENCY,
        "direction": D.WAVE_DIRECTION,
    },
    "lift": {"height": D.LIFT_HEIGHT, "duration": D.LIFT_DURATION},
    "apart": {"hold": D.APART_HOLD, "spread": D.APART_SPREAD, "duration": D.APART_DURATION},
    "drag": {
        "corner": D.DRAG_CORNER,
        "drop": D.DRAG_TABLE_DROP,
        "distance": D.DRAG_DISTANCE,
        "duration": D.DRAG_DURATION,
    },
}
assert tuple(OPTIONS) == tuple(D.HANDLINGS)


def key_times(end: float, step: float = D.HANDLING_KEY_STEP) -> np.ndarray:
    """Keys from t = 0 to ``end`` (both included), at most ``step`` apart, evenly spaced."""
    if not (math.isfinite(end) and end > 0):
        return np.zeros(1)
    n = max(int(math.ceil(end / step - 1e-9)), 1)
    return np.linspace(0.0, end, n + 1)


def raised_cosine(t: ArrayLike, duration: float) -> np.ndarray:
    """0 at t <= 0, rising smoothly to 1 at ``duration / 2`` and back to 0 at ``duration`` and after."""
    t = np.clip(np.asarray(t, dtype=np.float64), 0.0, duration)
    return (1.0 - np.cos(2.0 * math.pi * t / duration)) / 2.0


def wave_path(
    start: ArrayLike,
    end: float,
    amplitude: float = D.WAVE_AMPLITUDE,
    frequency: float = D.WAVE_FREQUENCY,
    direction: ArrayLike = D.WAVE_DIRECTION,
    step: float = D.HANDLING_KEY_STEP,
) -> tuple[np.ndarray, np.ndarray]:
    """(key times, positions (K, 3)) of a point waved from ``start`` along ``direction`` by
    ``amplitude * sin(2 pi frequency t)`` from t = 0 to ``end``."""
    d = np.asarray(direction, dtype=np.float64).reshape(3)
    norm = float(np.linalg.norm(d))
    if not (math.isfinite(norm) and norm > 0):
        raise ClothFitError(f"wave direction {d.tolist()} must be a non-zero vector")
    t = key_times(end, step)
    s = amplitude * np.sin(2.0 * math.pi * frequency * t)
    return t, np.asarray(start, dtype=np.float64).reshape(1, 3) + s[:, None] * (d / norm)


def bump_path(
    start: ArrayLike, displacement: ArrayLike, duration: float, step: float = D.HANDLING_KEY_STEP
) -> tuple[np.ndarray, np.ndarray]:
    """(key times, positions (K, 3)) of a point moved from ``start`` by ``displacement`` and back
    over ``duration`` from t = 0, smoothly (``raised_cosine``)."""
    t = key_times(duration, step)
    s = raised_cosine(t, duration)
    return t, np.asarray(start, dtype=np.float64).reshape(1, 3) + s[:, None] * np.asarray(
        displacement, dtype=np.float64
    ).reshape(1, 3)


def _options(name: str, given: dict[str, Any]) -> dict[str, Any]:
    if name not in OPTIONS:
        raise ClothFitError(f"handling {name!r} is not one of {', '.join(D.HANDLINGS)}")
    bad = sorted(set(given) - set(OPTIONS[name]))
    if bad:
        raise ClothFitError(f"handling {name!r} has no option {bad[0]!r} (options: {', '.join(OPTIONS[name])})")
    opts = dict(OPTIONS[name], **given)
    for k, v in opts.items():
        if k in ("corner", "released_corner"):
            if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or not 0 <= v <= 3:
                raise ClothFitError(f"handling {name!r}: {k} must be a corner index 0..3, got {v!r}")
        elif k != "direction" and not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
            raise ClothFitError(f"handling {name!r}: {k} must be a number >= 0, got {v!r}")
    for k in ("frequency", "duration", "hold", "spread", "drop"):
        if k in opts and opts[k] <= 0:
            raise ClothFitError(f"handling {name!r}: {k} must be positive, got {opts[k]!r}")
    return opts


def two_hands(grid: ClothGrid) -> tuple[int, int]:
    """The vertices the two hands of ``lift`` and ``apart`` hold: the corners of one edge."""
    c = grid.corners()
    return c[D.TWO_HAND_CORNERS[0]], c[D.TWO_HAND_CORNERS[1]]


def handling_scenario(
    name: str = D.HANDLING, grid: ClothGrid | None = None, frame_times: ArrayLike | None = None, **options: Any
) -> Scenario:
    """The scenario of handling ``name`` (one of ``D.HANDLINGS``) on ``grid`` (default the paper's)
    at ``frame_times`` (default ``D.FRAME_TIMES``); ``options`` override the handling's defaults
    (``OPTIONS[name]``). ``release`` with its defaults is exactly ``paper_scenario()``."""
    opts = _options(name, options)
    grid = grid or ClothGrid()
    times = np.asarray(D.FRAME_TIMES if frame_times is None else frame_times, dtype=np.float64).reshape(-1)
    if name == "release":
        return paper_scenario(grid, times, opts["released_corner"])
    rest = grid.rest
    corners = grid.corners()
    if name == "wave":
        waved = corners[opts["corner"]]
        t, p = wave_path(
            rest[waved], float(times.max(initial=0.0)), opts["amplitude"], opts["frequency"], opts["direction"]
        )
        handles = [Handle(v, t, p) if v == waved else Handle(v, [0.0], rest[v][None]) for v in corners]
        return Scenario(grid, handles, times)
    if name == "drag":
        return drag_scenario(grid, times, opts)
    a, b = two_hands(grid)
    if name == "lift":
        up = np.array([0.0, 0.0, opts["height"]])
        handles = [Handle(v, *bump_path(rest[v], up, opts["duration"])) for v in (a, b)]
    else:  # apart: the hands on the edge's line, symmetric about its middle
        mid, edge = (rest[a] + rest[b]) / 2.0, rest[b] - rest[a]
        t = key_times(opts["duration"])
        share = opts["hold"] + (opts["spread"] - opts["hold"]) * raised_cosine(t, opts["duration"])
        handles = [
            Handle(a, t, mid - share[:, None] * edge / 2.0),
            Handle(b, t, mid + share[:, None] * edge / 2.0),
        ]
    return Scenario(grid, handles, times, settle_time=D.TWO_HAND_SETTLE_TIME)


def moving_handles(scenario: Scenario, tol: float = 1e-12) -> list[int]:
    """The vertices of the handles whose keyed positions change (a path, not a point held still)."""
    return [h.vertex for h in scenario.handles if np.ptp(h.positions, axis=0).max(initial=0.0) > tol]


def smoothstep(t: ArrayLike, duration: float) -> np.ndarray:
    """0 at t <= 0, rising smoothly to 1 at ``duration`` and after."""
    s = np.clip(np.asarray(t, dtype=np.float64) / duration, 0.0, 1.0)
    return s * s * (3.0 - 2.0 * s)


def drag_scenario(grid: ClothGrid, times: np.ndarray, opts: dict[str, Any]) -> Scenario:
    """``drag`` (see the module): the table, the three corners let go at t = 0, the dragged corner's path
    (down onto the table over ``D.DRAG_LOWER_DURATION``, then ``distance`` away from the cloth's middle over
    ``duration``)."""
    rest = grid.rest
    corners = grid.corners()
    dragged = corners[opts["corner"]]
    top = float(rest[:, 2].min()) - opts["drop"]
    table = Collisions(
        [
            Collider.from_dict(
                {
                    "type": "plane",
                    "point": [0.0, 0.0, top],
                    "normal": [0.0, 0.0, 1.0],
                    "distance": D.DRAG_TABLE_DISTANCE,
                    "friction": D.COLLIDER_FRICTION,
                }
            )
        ],
        D.DRAG_CLOTH_DISTANCE,
        D.COLLISION_QUALITY,
    )
    rest_gap = (D.DRAG_TABLE_DISTANCE + D.DRAG_CLOTH_DISTANCE) * 8.0 / 9.0  # where Blender's cloth rests on it
    down = D.DRAG_LOWER_DURATION
    t = np.concatenate([key_times(down), down + key_times(opts["duration"])[1:]])
    lowered = smoothstep(t, down)
    along = smoothstep(t - down, opts["duration"])
    p = np.repeat(rest[dragged][None], t.size, axis=0)
    p[:, 2] += lowered * (top + rest_gap - rest[dragged, 2])
    out = rest[dragged] - rest.mean(axis=0)  # away from the cloth's middle, along the table: the cloth follows
    out[2] = 0.0
    out /= max(float(np.linalg.norm(out)), 1e-12)
    p += (along * opts["distance"])[:, None] * out
    handles = [Handle(dragged, t, p)] + [Handle(v, [0.0], rest[v][None], 0.0) for v in corners if v != dragged]
    return Scenario(grid, handles, times, colliders=table)
