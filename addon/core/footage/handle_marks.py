"""The marks of ``clothfit handles``: the options and the marks JSON (its format: ``handles.py``),
parsed and checked (a handle marked in at least two cameras, inside their images, unknown keys
refused).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from .. import defaults as D
from ..errors import ClothFitError
from ..jsonio import read_json

if TYPE_CHECKING:
    from collections.abc import Iterable

    from ..observation.camera import Camera

CORNERS = ("top-left", "top-right", "bottom-left", "bottom-right")
MOTIONS = ("fixed", "moving")
MARKS_KEYS = ("frame", "handles")
HANDLE_KEYS = ("name", "marks", "at", "motion", "released", "frame", "size")


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
    settle_time: float = D.FOOTAGE_SETTLE_TIME

    def check(self) -> HandleOptions:
        for nm in (
            "mark_sigma",
            "max_residual",
            "fb_max",
            "ref_max",
            "departure_min",
            "departure_k",
            "max_pin_offset",
            "clip_size",
        ):
            v = getattr(self, nm)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ClothFitError(f"handles option {nm} = {v!r} must be a positive number")
        if not (finite_number(self.clip_size) and 0 < self.clip_size <= 1.0):
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
    marks: dict  # camera name -> (x, y)
    frame: int
    at: tuple | None = None  # (u, v) metres on the cloth from its top-left corner
    at_text: str | None = None
    motion: str = "fixed"
    released: bool = False
    size: float | None = None  # the clip's size [m] (sets the tracking window); None = the option's


def finite_number(v: Any) -> bool:
    return not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v)


def parse_marks(
    d: Any,
    cameras: Iterable[Camera],
    n_frames: int,
    cloth_size: tuple[float, float] | None = None,
    source: str = "marks",
) -> list[HandleMarks]:
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
            if not (isinstance(p, (list, tuple)) and len(p) == 2 and all(finite_number(v) for v in p)):
                raise ClothFitError(f"{where}: the mark in camera '{cn}' must be [x, y] pixels, got {p!r}")
            c = cams[cn]
            x, y = float(p[0]), float(p[1])
            if not (-0.5 <= x <= c.width - 0.5 and -0.5 <= y <= c.height - 0.5):
                raise ClothFitError(
                    f"{where}: the mark ({x:g}, {y:g}) in camera '{cn}' is outside its {c.width}x{c.height} image"
                )
            pts[cn] = (x, y)
        if len(pts) < 2:
            raise ClothFitError(
                f"{where}: marked in {len(pts)} camera{'s' if len(pts) != 1 else ''}; a point "
                f"needs marks in at least 2 cameras to be triangulated"
            )
        motion = h.get("motion", "fixed")
        if motion not in MOTIONS:
            raise ClothFitError(f"{where}: motion {motion!r} must be one of {', '.join(MOTIONS)}")
        released = h.get("released", False)
        if not isinstance(released, bool):
            raise ClothFitError(f"{where}: 'released' must be true or false, got {released!r}")
        at, at_text = _parse_at(h.get("at"), cloth_size, where)
        size = h.get("size")
        if size is not None and not (finite_number(size) and 0 < size <= 1.0):
            raise ClothFitError(f"{where}: 'size' {size!r} must be the clip's size in metres (at most 1)")
        out.append(
            HandleMarks(
                name,
                pts,
                _frame(h.get("frame", frame0), n_frames, where),
                at,
                at_text,
                motion,
                released,
                None if size is None else float(size),
            )
        )
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
    if not (isinstance(v, (list, tuple)) and len(v) == 2 and all(finite_number(x) for x in v)):
        raise ClothFitError(
            f"{where}: 'at' must be [u, v] metres from the cloth's top-left corner or a corner name, got {v!r}"
        )
    u, vv = float(v[0]), float(v[1])
    if size is not None:
        w, h = size
        tol = 1e-6
        if not (-tol <= u <= w + tol and -tol <= vv <= h + tol):
            raise ClothFitError(f"{where}: 'at' [{u:g}, {vv:g}] is off the {w:g} x {h:g} m cloth")
    return (u, vv), None


def read_marks(
    path: str, cameras: Iterable[Camera], n_frames: int, cloth_size: tuple[float, float] | None = None
) -> list[HandleMarks]:
    return parse_marks(read_json(path, "marks file"), cameras, n_frames, cloth_size, f"marks file {path}")
