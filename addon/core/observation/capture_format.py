"""The capture format's names and checks (``docs/capture_format.md``; the capture itself:
``capture.py``): the file names and keys, the silhouette file-name pattern (``{camera}``,
``{frame}``, ``{time}`` fields) and the checks of the values ``capture.json`` holds (model, shapes,
cloth mass, frame times).
"""

from __future__ import annotations

import math
import os
import re
import string
from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import ClothFitError

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

FORMAT = "silhouette-cloth-fit/capture"
VERSION = 1
CAPTURE_JSON = "capture.json"
CAMERAS_JSON = "cameras.json"
SHAPES_NPZ = "shapes.npz"
DEFAULT_PATTERN = "sil/{camera}/{frame:03d}.png"
PATTERN_FIELDS = ("camera", "frame", "time")
TIME_FORMAT = ".3f"  # how a bare {time} is formatted: 0.05 -> "0.050"
REQUIRED_KEYS = ("format", "version", "cameras", "scenario", "frame_times", "silhouettes")
MAX_FIELD_WIDTH = 32  # largest width / precision of a pattern field ({frame:03d})
FRAME_TIME_TOL = 1e-9  # top-level vs scenario vs shapes.npz frame times
DEFAULT_IGNORE_PATTERN = "ignore/{camera}/{frame:03d}.png"
MASK_KEYS = ("silhouette_ids", "ignore_ids", "matte_threshold", "ignore")  # how silhouettes are stored


# =========================================================================== pattern


class Time(float):
    """A frame time that formats as ``0.050`` under a bare ``{time}``."""

    def __format__(self, spec):
        return format(float(self), spec or TIME_FORMAT)


def check_pattern(pattern: Any, where: str = "silhouettes pattern") -> str:
    """Validate a silhouette file-name pattern and return it."""
    if not isinstance(pattern, str) or not pattern.strip():
        raise ClothFitError(f"{where}: must be a non-empty string, got {pattern!r}")
    try:
        parsed = list(string.Formatter().parse(pattern))
    except ValueError as e:
        raise ClothFitError(f"{where} {pattern!r}: bad braces ({e})") from None
    fields = set()
    for _, name, spec, conv in parsed:
        if name is None:
            continue
        if name not in PATTERN_FIELDS:
            raise ClothFitError(
                f"{where} {pattern!r}: unknown field {{{name}}} "
                f"(allowed: {', '.join('{' + f + '}' for f in PATTERN_FIELDS)})"
            )
        if conv:
            raise ClothFitError(f"{where} {pattern!r}: conversions (!{conv}) are not allowed")
        if spec and "{" in spec:
            raise ClothFitError(f"{where} {pattern!r}: nested fields are not allowed")
        if spec and any(int(n) > MAX_FIELD_WIDTH for n in re.findall(r"\d+", spec)):
            raise ClothFitError(
                f"{where} {pattern!r}: field width or precision in {{{name}:{spec}}} above {MAX_FIELD_WIDTH}"
            )
        fields.add(name)
    if "camera" not in fields:
        raise ClothFitError(f"{where} {pattern!r}: must contain {{camera}}")
    if "frame" not in fields and "time" not in fields:
        raise ClothFitError(f"{where} {pattern!r}: must contain {{frame}} or {{time}}")
    norm = pattern.replace("\\", "/")
    if os.path.isabs(pattern) or norm.startswith("/") or re.match(r"^[A-Za-z]:", norm):
        raise ClothFitError(f"{where} {pattern!r}: must be relative to the capture directory")
    if ".." in norm.split("/"):
        raise ClothFitError(f"{where} {pattern!r}: must not leave the capture directory ('..')")
    try:
        pattern.format(camera="cam", frame=0, time=Time(0.0))
    except (ValueError, TypeError, KeyError, IndexError) as e:
        raise ClothFitError(f"{where} {pattern!r}: cannot be formatted ({e})") from None
    return pattern


def field_regex(component: str, camera: str | None = None) -> re.Pattern:
    """Regex of one path component of the pattern: {camera} captured (or the literal ``camera``),
    {frame} digits, {time} a number."""
    out = []
    seen_camera = False
    for lit, name, _spec, _ in string.Formatter().parse(component):
        out.append(re.escape(lit))
        if name == "camera":
            if camera is not None:
                out.append(re.escape(camera))
            else:
                out.append(r"(?P=camera)" if seen_camera else r"(?P<camera>[^/\\]+)")
            seen_camera = True
        elif name == "frame":
            out.append(r"[ +-]*\d+")
        elif name == "time":
            out.append(r"[ +\-0-9.eE]+")
    return re.compile("^" + "".join(out) + "$")


# ================================================================= value checks


def check_model(model: Any, where: str) -> dict:
    """The capture's optional ``model`` (the model a fit uses unless told otherwise), as a dict of what it
    declares, checked and in canonical form: a key it leaves out stays out, so a capture that names no
    quality leaves the fit to choose one (its ladder) rather than reading the default quality as declared."""
    if model is None:
        return None
    from ..physics.models import get_model

    try:
        full = get_model(model).to_dict()
    except ClothFitError as e:
        raise ClothFitError(f"{where}: 'model': {e}") from None
    if not isinstance(model, (dict, str)):
        return full  # a model object declares all of itself
    declared = {"name"} | (set(model) if isinstance(model, dict) else set())
    return {k: v for k, v in full.items() if k in declared}


def check_shapes(shapes: ArrayLike, n_frames: int, n_vertices: int, where: str) -> np.ndarray:
    try:
        s = np.asarray(shapes, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise ClothFitError(f"{where}: shapes are not numeric ({e})") from None
    if s.ndim != 3 or s.shape[2] != 3:
        raise ClothFitError(f"{where}: shapes must be (F, V, 3) vertex positions, got shape {s.shape}")
    if s.shape[0] != n_frames:
        raise ClothFitError(f"{where}: shapes have {s.shape[0]} frames but the capture has {n_frames} frame times")
    if s.shape[1] != n_vertices:
        raise ClothFitError(
            f"{where}: shapes have {s.shape[1]} vertices per frame but the cloth grid has "
            f"{n_vertices} vertices (shape {s.shape}, expected ({n_frames}, {n_vertices}, 3))"
        )
    if not np.all(np.isfinite(s)):
        raise ClothFitError(f"{where}: shapes contain {int(np.count_nonzero(~np.isfinite(s)))} non-finite values")
    return s


def check_cloth_mass(cloth_mass: Any, where: str) -> float | None:
    if cloth_mass is None:
        return None
    if isinstance(cloth_mass, bool):
        raise ClothFitError(f"{where}: cloth_mass must be a number in kg, got {cloth_mass!r}")
    try:
        v = float(cloth_mass)
    except (TypeError, ValueError):
        raise ClothFitError(f"{where}: cloth_mass must be a number in kg, got {cloth_mass!r}") from None
    if not math.isfinite(v) or v <= 0:
        raise ClothFitError(f"{where}: cloth_mass must be a positive finite mass in kg, got {cloth_mass!r}")
    return v


def check_frame_times(value: Any, where: str, name: str) -> np.ndarray:
    if not isinstance(value, (list, tuple)) or not value:
        raise ClothFitError(f"{where}: {name} must be a non-empty list of times in seconds, got {value!r:.80}")
    try:
        t = np.array([float(x) for x in value if not isinstance(x, bool)], dtype=np.float64)
    except (TypeError, ValueError):
        raise ClothFitError(f"{where}: {name} must contain numbers only, got {value!r:.80}") from None
    if t.size != len(value) or not np.all(np.isfinite(t)):
        raise ClothFitError(f"{where}: {name} must contain finite numbers only, got {value!r:.80}")
    return t


def names_str(names: Iterable[str], limit: int = 20) -> str:
    names = list(names)
    return ", ".join(names[:limit]) + (f", ... ({len(names)} in all)" if len(names) > limit else "")


def times_str(t: Sequence[float], limit: int = 8) -> str:
    s = ", ".join(f"{x:g}" for x in t[:limit])
    return f"[{s}{', ...' if len(t) > limit else ''}] ({len(t)} times)"
