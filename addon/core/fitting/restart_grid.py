"""Runs again from a grid (``StagedCMA``'s ``first_restart_grid``): the checks of its settings and of its saved
state, and a saved first-stage run's end (docs/search.md, "Runs again from a grid")."""

from __future__ import annotations

from typing import Any

import numpy as np

from .. import defaults as D
from ..errors import ClothFitError
from .space import checked_flag, checked_integer, checked_number, saved_array, saved_bool, saved_value


def is_run_end(e: object, k: int) -> bool:
    """A saved first-stage run's end: [best value, its point in the strong settings' cube (k numbers)]."""
    return (
        isinstance(e, list)
        and len(e) == 2
        and isinstance(e[0], (int, float, str))
        and not isinstance(e[0], bool)
        and isinstance(e[1], list)
        and len(e[1]) == k
        and all(isinstance(v, (int, float)) and not isinstance(v, bool) and 0.0 <= v <= 1.0 for v in e[1])
    )


def grid_names(names: object, first: list, w: str) -> list | None:
    """``first_restart_grid``: None, or two distinct coordinates of the first stage."""
    if names is None:
        return None
    if (
        not isinstance(names, (list, tuple))
        or len(names) != 2
        or len(set(names)) != 2
        or any(n not in first for n in names)
    ):
        raise ClothFitError(
            f"{w}: 'first_restart_grid' must name two coordinates of the first stage ({', '.join(first)})"
        )
    return [str(n) for n in names]


def grid_shape(points: object, w: str) -> tuple[int, int]:
    """``first_restart_grid_points``: an n x n grid (one count, 2 to 64), or the points along each of the two named
    coordinates ([rows, columns], 1 to 64 each, rows at least 2): a count of 1 holds that coordinate at the run's own
    value (a line through the run's end, not a grid)."""
    pair = [points, points] if isinstance(points, int) and not isinstance(points, bool) else points
    if (
        not isinstance(pair, (list, tuple))
        or len(pair) != 2
        or not all(isinstance(v, int) and not isinstance(v, bool) and 1 <= v <= 64 for v in pair)
        or pair[0] < 2
    ):
        raise ClothFitError(
            f"{w}: first_restart_grid_points must be a count from 2 to 64 or [rows, columns] of 1 to 64 (rows at "
            f"least 2), got {points!r}"
        )
    return int(pair[0]), int(pair[1])


def grid_near(near: object, first: list, names: list | None, w: str) -> dict:
    """``first_restart_grid_near``: first-stage coordinates other than the grid's own -> a step (unit cube, above 0
    and at most 0.25); the grid is tried again with each of them moved by -step and by +step, one at a time (None or
    {}: at the run's own values only)."""
    near = {} if near is None else near
    if (
        not isinstance(near, dict)
        or any(n not in first or n in (names or ()) for n in near)
        or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and 0.0 < v <= 0.25 for v in near.values())
    ):
        raise ClothFitError(
            f"{w}: first_restart_grid_near must map first-stage coordinates other than the grid's own to a step in "
            f"(0, 0.25] of the unit cube, got {near!r}"
        )
    return {str(n): float(v) for n, v in near.items()}


def near_offsets(near: dict, first: list) -> np.ndarray:
    """The grid's offsets from the run's end (``grid_near``): (1 + 2 len(near), len(first)), the run's own first,
    then each named coordinate moved by -step and +step, one at a time."""
    offsets = np.zeros((1 + 2 * len(near), len(first)))
    for i, (n, step) in enumerate(near.items()):
        offsets[1 + 2 * i : 3 + 2 * i, first.index(n)] = (-step, step)
    return offsets


def grid_batch(u: np.ndarray, a: int, b: int, shape: tuple, offsets: np.ndarray) -> np.ndarray:
    """The grid's points (unit cube, clipped): ``u`` (a run's end) with coordinates ``a`` and ``b`` at the centres of a
    rows x columns grid across their ranges (one column: ``b`` held at the run's own value), once at each of
    ``offsets`` (``near_offsets``)."""
    na, nb = shape
    U = np.repeat(u[None], na * nb, 0)
    A, B = np.meshgrid(centres(na), centres(nb) if nb > 1 else u[b : b + 1], indexing="ij")
    U[:, a], U[:, b] = A.ravel(), B.ravel()
    return np.clip(np.concatenate([U + o for o in offsets]), 0.0, 1.0)


def starts_left(starts: list, ends: list, first: list, names: list, points: tuple) -> list:
    """The grid's cells (``starts``, best first) that no first-stage run has ended in (``ends``: [value, point]):
    not within one cell of a run's end, nor within ``STAGED_FIRST_RESTART_GRID_APART`` (a basin, not a fine grid's
    cell), along both of the grid's coordinates (``names``, ``points`` along each)."""
    a, b = (first.index(x) for x in names)
    da, db = (max(1.0 / n, D.STAGED_FIRST_RESTART_GRID_APART) for n in points)
    return [s for s in starts if not any(abs(s[a] - e[1][a]) <= da and abs(s[b] - e[1][b]) <= db for e in ends)]


def end_run_share(share: object, at_end: bool, names: list | None, w: str) -> float:
    """``first_restart_grid_end_run``: a share of the budget in [0, 1], more than 0 only with a grid at the first
    stage's end."""
    share = checked_number(share, f"{w}: first_restart_grid_end_run", 0.0, 1.0)
    if share > 0 and not (at_end and names):
        raise ClothFitError(f"{w}: first_restart_grid_end_run needs the grid at the first stage's end")
    return share


def window_frames(frames: object, share: object, at_end: bool, w: str) -> tuple[int, float]:
    """``first_restart_grid_frames`` (the first K training frames the grid at the stage's end is scored on; 0: all
    of them) and ``first_restart_grid_window_share`` (what one such evaluation costs in evaluations on every frame,
    in (0, 1]; the fit measures it from the frame times)."""
    k = checked_integer(frames, f"{w}: first_restart_grid_frames", 0, 10**6)
    share = checked_number(share, f"{w}: first_restart_grid_window_share", 0.0, 1.0, lo_open=True)
    if k and not at_end:
        raise ClothFitError(f"{w}: first_restart_grid_frames needs the grid at the first stage's end")
    return k, share


def window_best(pending: np.ndarray, f: np.ndarray, n: int) -> np.ndarray | None:
    """The ``n`` cells of the grid (``pending``) with the lowest values on the first frames (``f``), best first, to
    be scored again on every frame; None if none was finite."""
    order = [i for i in np.argsort(f, kind="stable") if np.isfinite(f[i])][:n]
    return pending[order] if order else None


def grid_settings(opt: Any, w: str, **kw: Any) -> dict:
    """The grid's settings of a new ``StagedCMA`` (``kw``: its ``first_restart_grid*`` arguments),
    checked, as its attributes, and the grid's state before it has run."""
    names = grid_names(kw["first_restart_grid"], opt.first, w)
    at_end = checked_flag(kw["first_restart_grid_at_end"], f"{w}: first_restart_grid_at_end")
    frames, share = window_frames(kw["first_restart_grid_frames"], kw["first_restart_grid_window_share"], at_end, w)
    return {
        "first_restart_grid": names,
        "grid_points": grid_shape(kw["first_restart_grid_points"], w),
        "grid_near": grid_near(kw["first_restart_grid_near"], opt.first, names, w),
        "grid_at_end": at_end,
        "grid_end_run": end_run_share(kw["first_restart_grid_end_run"], at_end, names, w),
        "grid_sigma": checked_number(
            kw["first_restart_grid_sigma"], f"{w}: first_restart_grid_sigma", 0.0, 1.0, lo_open=True
        ),
        "grid_frames": frames,
        "grid_window_share": share,
        # the grid's points (strong settings' cube) while they wait to be evaluated, on the first frames or on all;
        # where the runs after it start, best cell first; whether it has run; the evaluation at which the run from
        # its best point (at the end) ends
        "grid_pending": None,
        "grid_windowed": False,
        "grid_starts": [],
        "grid_done": False,
        "grid_end_until": None,
    }


GRID_KEYS = (
    "first_restart_grid",
    "grid_points",
    "grid_near",
    "grid_at_end",
    "grid_end_run",
    "grid_end_until",
    "grid_sigma",
    "grid_frames",
    "grid_window_share",
    "grid_pending",
    "grid_windowed",
    "grid_starts",
    "grid_done",
)


def grid_state(opt: Any) -> dict:
    """The grid's part of a saved ``StagedCMA`` (``GRID_KEYS``; ``restore_grid`` reads it back)."""
    return {
        "first_restart_grid": opt.first_restart_grid,
        "grid_points": list(opt.grid_points),
        "grid_near": dict(opt.grid_near),
        "grid_at_end": opt.grid_at_end,
        "grid_end_run": opt.grid_end_run,
        "grid_end_until": opt.grid_end_until,
        "grid_sigma": opt.grid_sigma,
        "grid_frames": opt.grid_frames,
        "grid_window_share": opt.grid_window_share,
        "grid_pending": None if opt.grid_pending is None else opt.grid_pending.tolist(),
        "grid_windowed": opt.grid_windowed,
        "grid_starts": [list(s) for s in opt.grid_starts],
        "grid_done": opt.grid_done,
    }


def restore_grid(d: dict, first: list, w: str) -> dict:
    """The grid's part of a saved ``StagedCMA`` (checked), as its attributes (``grid_settings``). Checkpoints from
    before a field restore it as: no grid; one count of points (before rows and columns); no ``near``; the grid at
    each run's end (before ``at_end``); no run from its best point (before ``end_run``); every frame (before the first
    frames' window). ``grid_pending`` holds the points waiting to be evaluated (on the first frames if
    ``grid_windowed``; after them, their best cells again on every frame), ``grid_starts`` the later runs' starts
    left, best cell first."""
    names = grid_names(d.get("first_restart_grid"), first, f"checkpoint: {w}")
    points = grid_shape(d.get("grid_points", D.STAGED_FIRST_RESTART_GRID_POINTS), f"checkpoint: {w}")
    near = grid_near(d.get("grid_near"), first, names, f"checkpoint: {w}")
    sigma = saved_value(d, "grid_sigma", w, float, 0.0, 1.0) if "grid_sigma" in d else D.STAGED_FIRST_RESTART_GRID_SIGMA
    done = saved_bool(d, "grid_done", w) if "grid_done" in d else False
    at_end = saved_bool(d, "grid_at_end", w) if "grid_at_end" in d else False
    end_run = end_run_share(d.get("grid_end_run", 0.0), at_end, names, f"checkpoint: {w}")
    end_until = saved_value(d, "grid_end_until", w, int, 0, 10**9, allow_none=True) if "grid_end_until" in d else None
    if end_until is not None and not (end_run > 0 and done):
        raise ClothFitError(f"checkpoint: {w} 'grid_end_until' needs first_restart_grid_end_run and the grid run")
    frames, share = window_frames(d.get("grid_frames", 0), d.get("grid_window_share", 1.0), at_end, f"checkpoint: {w}")
    windowed = saved_bool(d, "grid_windowed", w) if "grid_windowed" in d else False
    n2, k = points[0] * points[1] * (1 + 2 * len(near)), len(first)
    pending = saved_array(d, "grid_pending", w, (None, k), allow_none=True) if "grid_pending" in d else None
    rescoring = pending is not None and frames > 0 and not windowed  # the best cells again, on every frame
    # the grid's points, or after the first frames the best of them (fewer where some exploded there)
    most = min(n2, D.STAGED_FIRST_RESTART_GRID_RESCORE) if rescoring else n2
    if pending is not None and not (1 <= len(pending) <= most if rescoring else len(pending) == n2):
        raise ClothFitError(f"checkpoint: {w} 'grid_pending' holds {len(pending)} points, not the grid's")
    if windowed and (pending is None or not frames):
        raise ClothFitError(f"checkpoint: {w} 'grid_windowed' needs first_restart_grid_frames and a grid waiting")
    starts = d.get("grid_starts", [])
    if (
        not isinstance(starts, list)
        or len(starts) > n2
        or not all(is_run_end([0.0, s], k) for s in starts)
        or (pending is not None and (not done or starts))
        or ((pending is not None or starts) and names is None)
    ):
        raise ClothFitError(f"checkpoint: {w} 'grid_starts' must list points of {k} numbers in [0, 1] after the grid")
    if pending is not None and (np.any(pending < 0.0) or np.any(pending > 1.0)):
        raise ClothFitError(f"checkpoint: {w} 'grid_pending' must lie in the unit cube")
    return {
        "first_restart_grid": names,
        "grid_points": points,
        "grid_near": near,
        "grid_at_end": at_end,
        "grid_end_run": end_run,
        "grid_end_until": end_until,
        "grid_sigma": sigma,
        "grid_frames": frames,
        "grid_window_share": share,
        "grid_pending": pending,
        "grid_windowed": windowed,
        "grid_starts": [[float(v) for v in s] for s in starts],
        "grid_done": done,
    }


def restart_levels(name: object, levels: object, first: list, w: str) -> tuple:
    """(coordinate, levels) of ``first_restart_vary``: None, or a first-stage coordinate, with one or more
    levels in the unit cube; anything else is a one-line error."""
    if name is None:
        return None, tuple(D.STAGED_FIRST_RESTART_LEVELS)
    if not isinstance(name, str) or name not in first:
        raise ClothFitError(
            f"{w}: first_restart_vary must name a first-stage coordinate ({', '.join(first)}), got {name!r}"
        )
    try:
        lv = tuple(float(v) for v in levels)
    except (TypeError, ValueError):
        lv = ()
    if not lv or not all(0.0 <= v <= 1.0 for v in lv):
        raise ClothFitError(f"{w}: first_restart_levels must be one or more numbers in [0, 1], got {levels!r}")
    return name, lv


def centres(n: int) -> np.ndarray:
    """The centres of n equal cells across the unit interval (the scan's values, the grid's rows)."""
    return (np.arange(n) + 0.5) / n
