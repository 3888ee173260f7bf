"""Blender cloth settings: ``bpy.types.ClothSettings`` names, Blender's ranges, defaults and presets,
the solver's constants, their validation and the frame's step loop (``blender.py``'s model reads
them; ``blender.py`` re-exports every name)."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from .. import defaults as D
from ..errors import ClothFitError

FLOAT_SETTINGS = (
    "mass",
    "air_damping",
    "tension_stiffness",
    "compression_stiffness",
    "shear_stiffness",
    "bending_stiffness",
    "tension_damping",
    "compression_damping",
    "shear_damping",
    "bending_damping",
    "pin_stiffness",
    "time_scale",
)
BENDING_MODELS = ("ANGULAR", "LINEAR")
# Blender's own limits (hard_min, hard_max) of bpy.types.ClothSettings (4.2 - 4.5; a Blender test
# reads them back from bpy and compares); mass and time_scale must also be > 0 here.
RANGES = {
    "mass": (0.0, 3.4028234663852886e38),
    "air_damping": (0.0, 10.0),
    "tension_stiffness": (0.0, 10000.0),
    "compression_stiffness": (0.0, 10000.0),
    "shear_stiffness": (0.0, 10000.0),
    "bending_stiffness": (0.0, 10000.0),
    "tension_damping": (0.0, 50.0),
    "compression_damping": (0.0, 50.0),
    "shear_damping": (0.0, 50.0),
    "bending_damping": (0.0, 1000.0),
    "pin_stiffness": (0.0, 50.0),
    "time_scale": (0.0, 3.4028234663852886e38),
    "quality": (1, 2147483647),
}
POSITIVE = ("mass", "time_scale")
# A new Cloth modifier's values (Blender 4.2 - 4.5)
DEFAULTS = {
    "quality": 5,
    "bending_model": "ANGULAR",
    "mass": 0.3,
    "air_damping": 1.0,
    "tension_stiffness": 15.0,
    "compression_stiffness": 15.0,
    "shear_stiffness": 5.0,
    "bending_stiffness": 0.5,
    "tension_damping": 5.0,
    "compression_damping": 5.0,
    "shear_damping": 5.0,
    "bending_damping": 0.5,
    "pin_stiffness": 1.0,
    "time_scale": 1.0,
}
# the settings that scale with the mass (the symmetry of the equations of motion)
MASS_SCALED = (
    "mass",
    "air_damping",
    "tension_stiffness",
    "compression_stiffness",
    "shear_stiffness",
    "bending_stiffness",
    "tension_damping",
    "compression_damping",
    "shear_damping",
    "pin_stiffness",
)
# Blender 4.5's cloth presets (scripts/presets/cloth/*.py), as ClothSettings values
PRESETS = {
    "cotton": {
        "quality": 5,
        "mass": 0.3,
        "tension_stiffness": 15,
        "compression_stiffness": 15,
        "shear_stiffness": 15,
        "bending_stiffness": 0.5,
        "tension_damping": 5,
        "compression_damping": 5,
        "shear_damping": 5,
        "air_damping": 1,
        "bending_damping": 0.5,
    },
    "silk": {
        "quality": 5,
        "mass": 0.15,
        "tension_stiffness": 5,
        "compression_stiffness": 5,
        "shear_stiffness": 5,
        "bending_stiffness": 0.05,
        "tension_damping": 0,
        "compression_damping": 0,
        "shear_damping": 0,
        "air_damping": 1,
        "bending_damping": 0.5,
    },
    "denim": {
        "quality": 12,
        "mass": 1,
        "tension_stiffness": 40,
        "compression_stiffness": 40,
        "shear_stiffness": 40,
        "bending_stiffness": 10,
        "tension_damping": 25,
        "compression_damping": 25,
        "shear_damping": 25,
        "air_damping": 1,
        "bending_damping": 0.5,
    },
    "leather": {
        "quality": 15,
        "mass": 0.4,
        "tension_stiffness": 80,
        "compression_stiffness": 80,
        "shear_stiffness": 80,
        "bending_stiffness": 150,
        "tension_damping": 25,
        "compression_damping": 25,
        "shear_damping": 25,
        "air_damping": 1,
        "bending_damping": 0.5,
    },
    "rubber": {
        "quality": 7,
        "mass": 3,
        "tension_stiffness": 15,
        "compression_stiffness": 15,
        "shear_stiffness": 15,
        "bending_stiffness": 25,
        "tension_damping": 25,
        "compression_damping": 25,
        "shear_damping": 25,
        "air_damping": 1,
        "bending_damping": 0.5,
    },
}
GRAVITY_SCALE = 0.001  # Blender scales the scene gravity by 1/1000 for cloth
AIR_SCALE = 0.01  # drag = AIR_SCALE * air_damping
SOFTGOALSNAP = 0.999  # goal weight (w^4) from which a vertex is pinned
CG_TOLERANCE = 0.01  # relative residual at which Blender's CG stops
CG_MAX_ITERATIONS = 100
ALMOST_ZERO = 1.1920928955078125e-07  # FLT_EPSILON: shorter springs have no direction
MAX_STEPS_PER_FRAME = 1000  # a (time_scale, quality) pair needing more is refused
MAX_STRAIN = D.MAX_STRAIN  # a structural spring longer than (1 + MAX_STRAIN) rest = exploded
EXPLODE_FACTOR = D.EXPLODE_FACTOR


def mass_scaled(bending_model: str = "ANGULAR") -> tuple:
    """Settings multiplied together by a change of mass that leaves the motion unchanged."""
    return MASS_SCALED + (("bending_damping",) if bending_model == "ANGULAR" else ())


def physical_time_scale(fps: float, gravity: ArrayLike = D.GRAVITY) -> float:
    """Speed Multiplier that makes Blender's cloth move in real time at ``fps`` frames per second.

    Blender's solver advances ``time_scale`` time units per frame with gravity ``0.001 g`` per unit
    squared; one unit is then ``1 / (fps * time_scale)`` seconds, and gravity in m/s^2 is
    ``0.001 g (fps time_scale)^2``: equal to ``g`` when ``time_scale = sqrt(1000) / fps``. With the
    default time_scale = 1 a cloth at 24 fps falls as if under 0.58 g."""
    if not (fps > 0 and math.isfinite(fps)):
        raise ClothFitError(f"frame rate {fps} must be a positive number")
    return math.sqrt(1.0 / GRAVITY_SCALE) / float(fps)


def rate_factor(own_fps: float, fps: float) -> float:
    """The factor on a cloth's Speed Multiplier (``time_scale``) that keeps it in physical time when its
    scene's frame rate goes from ``own_fps`` to ``fps`` (``physical_time_scale``: time_scale x fps is what
    matters); 1 for the same rate."""
    own, new = float(own_fps), float(fps)
    return 1.0 if abs(own - new) <= 1e-9 * new else own / new


def check_settings(s: dict, source: str = "Blender cloth settings") -> dict:
    """Validate settings against Blender's ranges; returns a complete dict (defaults filled in)."""
    if not isinstance(s, dict):
        raise ClothFitError(f"{source}: expected an object of ClothSettings values, got {type(s).__name__}")
    known = set(FLOAT_SETTINGS) | {"quality", "bending_model"}
    bad = sorted(set(s) - known)
    if bad:
        raise ClothFitError(
            f"{source}: unknown or unsupported setting(s) {', '.join(bad)} "
            f"(supported: quality, bending_model, {', '.join(FLOAT_SETTINGS)})"
        )
    out = dict(DEFAULTS)
    out.update(s)
    bm = out["bending_model"]
    if bm not in BENDING_MODELS:
        raise ClothFitError(f"{source}: bending_model {bm!r} must be one of {', '.join(BENDING_MODELS)}")
    q = out["quality"]
    if isinstance(q, bool) or not isinstance(q, (int, np.integer)) and not (isinstance(q, float) and q.is_integer()):
        raise ClothFitError(f"{source}: quality {q!r} must be a whole number")
    q = int(q)
    if q < RANGES["quality"][0]:
        raise ClothFitError(f"{source}: quality {q} must be >= 1 (steps per frame)")
    out["quality"] = q
    for n in FLOAT_SETTINGS:
        v = out[n]
        try:
            v = float(v)
        except (TypeError, ValueError):
            raise ClothFitError(f"{source}: {n} = {out[n]!r} is not a number") from None
        lo, hi = RANGES[n]
        if not math.isfinite(v) or v < lo or v > hi or (n in POSITIVE and v <= 0):
            rng = f"> {lo:g}" if n in POSITIVE else f"in [{lo:g}, {hi:g}]"
            raise ClothFitError(f"{source}: {n} = {v!r} is outside Blender's range ({rng})")
        out[n] = v
    return out


def settings_row(s: dict) -> np.ndarray:
    """Settings dict -> row of FLOAT_SETTINGS values."""
    return np.array([float(s[n]) for n in FLOAT_SETTINGS], dtype=np.float64)


def row_settings(row: ArrayLike, quality: int, bending_model: str) -> dict:
    """Row of FLOAT_SETTINGS values -> complete settings dict (ClothSettings names)."""
    d = {"quality": int(quality), "bending_model": bending_model}
    d.update({n: float(v) for n, v in zip(FLOAT_SETTINGS, np.asarray(row, dtype=np.float64).reshape(-1))})
    return d


def steps_per_frame(time_scale: float, quality: int) -> tuple[float, np.ndarray]:
    """Blender's step loop for one frame, in float32 as Blender runs it.

    Returns ``(dt, step_starts)``: the step length and the start time of every step in solver
    time units (the loop ``while step < time_scale: step += dt``); the number of steps is
    ``quality`` or, for some pairs, ``quality + 1``."""
    f32 = np.float32
    tf = f32(time_scale)
    dt = f32(f32(1.0) / f32(quality)) * tf
    if not (dt > 0):
        raise ClothFitError(f"time_scale {time_scale} and quality {quality} give no time step")
    step = f32(0.0)
    starts = []
    while step < tf:
        starts.append(float(step))
        step = f32(step + dt)
        if len(starts) > MAX_STEPS_PER_FRAME:
            raise ClothFitError(f"quality {quality} means more than {MAX_STEPS_PER_FRAME} steps per frame")
    return float(dt), np.array(starts)
