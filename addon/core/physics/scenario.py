"""The cloth and its manipulation, shared by every cloth model: grid, handles, scenario.

Grid: ``ny x nx`` point masses, vertex ``(i, j)`` (row i, column j) has index ``i * nx + j``.
Every quad ``(i, j)..(i+1, j+1)`` is split along the diagonal ``(i, j)-(i+1, j+1)`` into two
triangles; springs lie on every triangle edge: ``ny (nx-1)`` horizontal, ``(ny-1) nx`` vertical and
``(ny-1)(nx-1)`` diagonal. For 16 x 16: 450 triangles, 240 + 240 + 225 = 705 springs.

"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .. import defaults as D
from ..errors import ClothFitError
from .colliders import Collisions
from .crop import CropPlane
from .rotation import rotation_matrix

# plausibility limits of a scenario read from a file: beyond them a value is a typo or an attack
# (memory exhaustion, a simulation that never ends), not a cloth
MAX_GRID_SIDE = 1000
MAX_GRID_VERTICES = 250_000
MAX_SIZE_M = 1000.0  # lengths and positions [m]
MAX_TIME_S = 3600.0  # frame and key times [s]
MAX_SETTLE_S = 60.0  # settling before t = 0 [s]
MAX_GRAVITY = 1000.0  # [m/s^2]
MAX_FRAMES = 100_000
# the manipulation's unknowns a capture may declare (``Uncertainty``): bounds beyond these are not an
# uncertain measurement but a wrong one (a release misread by more than a second, a pin 5 cm away)
UNCERTAIN_KEYS = ("time_offset", "handles", "time_scale")
MAX_TIME_OFFSET_S = 1.0
MAX_HANDLE_OFFSET_M = 0.05
MAX_TIME_SCALE = 2.0  # a frame interval known to within a factor 2 either way


class ClothGrid:
    """Topology and rest geometry of the sheet.

    The flat sheet in its own (local) frame: column ``j`` at ``x = -side/2 + j * side/(nx-1)``, row
    ``i`` at ``y = -side_y/2 + i * side_y/(ny-1)``, ``z = 0``. It is *placed* in the world by
    ``rest = origin + R(rotation) @ local``: ``origin`` is the world position of the sheet's centre
    (default ``(0, 0, height)``: the paper's horizontal sheet centred on the z axis) and ``rotation``
    a rotation vector (axis times angle [rad], default 0: local axes = world axes). A real cloth
    hangs somewhere else, in some orientation (``footage/handles.py`` fits the placement to the
    clips). ``height`` is the z of ``origin``.
    """

    def __init__(
        self,
        nx: int = D.GRID_N,
        ny: int | None = None,
        side: float = D.CLOTH_SIDE,
        height: float | None = None,
        side_y: float | None = None,
        origin=None,
        rotation=None,
    ):
        ny = nx if ny is None else ny
        for v in (nx, ny):
            if isinstance(v, bool) or not isinstance(v, (int, np.integer, float)) or v != int(v):
                raise ClothFitError(f"cloth grid size must be whole numbers, got {nx} x {ny}")
        if nx < 2 or ny < 2:
            raise ClothFitError(f"cloth grid must be at least 2 x 2, got {nx} x {ny}")
        if nx > MAX_GRID_SIDE or ny > MAX_GRID_SIDE or nx * ny > MAX_GRID_VERTICES:
            raise ClothFitError(
                f"cloth grid {nx} x {ny} is too large (at most {MAX_GRID_SIDE} per side and "
                f"{MAX_GRID_VERTICES} vertices)"
            )
        for nm, v in (("side", side), ("side_y", side if side_y is None else side_y)):
            if not (isinstance(v, (int, float, np.floating)) and math.isfinite(v) and 0 < v <= MAX_SIZE_M):
                raise ClothFitError(f"cloth {nm} must be a positive finite length up to {MAX_SIZE_M:g} m, got {v}")
        if origin is not None:
            origin = _vector3(origin, "cloth origin", MAX_SIZE_M)
            if height is not None and abs(float(height) - origin[2]) > 1e-9:
                raise ClothFitError(
                    f"cloth height {height} differs from the z of its origin {origin[2]} (give one of them)"
                )
            height = float(origin[2])
        height = D.CLOTH_HEIGHT if height is None else height
        if not (isinstance(height, (int, float, np.floating)) and math.isfinite(height) and abs(height) <= MAX_SIZE_M):
            raise ClothFitError(f"cloth height must be a finite number within +-{MAX_SIZE_M:g} m, got {height}")
        self.nx, self.ny = int(nx), int(ny)
        self.side = float(side)
        self.side_y = float(side if side_y is None else side_y)
        self.height = float(height)
        self.origin = np.array([0.0, 0.0, self.height]) if origin is None else origin
        self.rotation = np.zeros(3) if rotation is None else _vector3(rotation, "cloth rotation", 1e3)
        self.R = rotation_matrix(self.rotation)
        self.spacing = self.side / (self.nx - 1)
        xs = np.linspace(-self.side / 2, self.side / 2, self.nx)
        ys = np.linspace(-self.side_y / 2, self.side_y / 2, self.ny)
        X, Y = np.meshgrid(xs, ys)  # (ny, nx)
        self.local = np.stack([X, Y, np.zeros_like(X)], -1).reshape(-1, 3)
        if self.placed:
            self.rest = self.origin + self.local @ self.R.T
        else:  # the paper's sheet, exactly as it always was (no rounding from a product with I)
            self.rest = np.stack([X, Y, np.full_like(X, self.height)], -1).reshape(-1, 3)
        idx = np.arange(self.nx * self.ny).reshape(self.ny, self.nx)
        a = idx[:-1, :-1].ravel()
        b = idx[:-1, 1:].ravel()
        c = idx[1:, :-1].ravel()
        dd = idx[1:, 1:].ravel()
        # two triangles per quad, split along (i,j)-(i+1,j+1), counter-clockwise seen from +z
        self.triangles = np.concatenate([np.stack([a, b, dd], 1), np.stack([a, dd, c], 1)]).astype(np.int32)
        h = np.stack([idx[:, :-1].ravel(), idx[:, 1:].ravel()], 1)
        v = np.stack([idx[:-1, :].ravel(), idx[1:, :].ravel()], 1)
        g = np.stack([a, dd], 1)
        self.springs = np.concatenate([h, v, g]).astype(np.int32)
        # rest length of each spring in units of l
        self.rest_factor = np.concatenate([np.ones(len(h)), np.ones(len(v)), np.full(len(g), math.sqrt(2.0))])
        # the same sheet as a polygon mesh (what Blender's cloth is built from): one quad per cell,
        # corners (i, j), (i, j+1), (i+1, j+1), (i+1, j), counter-clockwise seen from +z; the two
        # triangles above are its corners (0, 1, 2) and (0, 2, 3), as Blender tessellates a quad
        self.quads = np.stack([a, b, dd, c], 1).astype(np.int64)

    @property
    def n_vertices(self) -> int:
        return self.nx * self.ny

    def corners(self) -> list[int]:
        """Indices of the four corners: (0,0), (0,nx-1), (ny-1,0), (ny-1,nx-1)."""
        nx, ny = self.nx, self.ny
        return [0, nx - 1, (ny - 1) * nx, ny * nx - 1]

    @property
    def placed(self) -> bool:
        """True when the sheet is moved off the paper's placement (centre off the z axis or rotated)."""
        return bool(self.origin[0] != 0.0 or self.origin[1] != 0.0 or np.any(self.rotation != 0.0))

    def to_dict(self) -> dict[str, Any]:
        d = {"nx": self.nx, "ny": self.ny, "side": self.side, "side_y": self.side_y, "height": self.height}
        if self.placed:  # written only when used: older readers see the same keys as before
            d["origin"] = self.origin.tolist()
            d["rotation"] = self.rotation.tolist()
        return d

    @classmethod
    def from_dict(cls, d: Any, source: str = "cloth") -> ClothGrid:
        if not isinstance(d, dict):
            raise ClothFitError(f"{source}: the cloth must be an object, got {d!r}")
        try:
            origin = d.get("origin")
            return cls(
                int(d.get("nx", D.GRID_N)),
                int(d.get("ny", d.get("nx", D.GRID_N))),
                float(d.get("side", D.CLOTH_SIDE)),
                None if d.get("height") is None else float(d["height"]),
                None if d.get("side_y") is None else float(d["side_y"]),
                origin=origin,
                rotation=d.get("rotation"),
            )
        except ClothFitError as e:
            raise ClothFitError(f"{source}: {e}") from None
        except (TypeError, ValueError, AttributeError) as e:
            raise ClothFitError(f"{source}: bad cloth description {d!r} ({e})") from None


def _vector3(v, what, limit):
    try:
        a = np.asarray(v, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise ClothFitError(f"{what} must be 3 numbers, got {v!r}") from None
    if a.size != 3 or not np.all(np.isfinite(a)) or np.abs(a).max() > limit:
        raise ClothFitError(f"{what} must be 3 finite numbers within +-{limit:g}, got {v!r}")
    return a


@dataclass
class Handle:
    """A grid vertex whose position is prescribed.

    ``times``/``positions`` give a piecewise-linear trajectory (held at the first position
    before ``times[0]`` and at the last after ``times[-1]``); a single key = a fixed point.
    After ``release_time`` (if given) the vertex is free.
    """

    vertex: int
    times: np.ndarray
    positions: np.ndarray
    release_time: float | None = None

    def __post_init__(self):
        self.times = np.asarray(self.times, dtype=np.float64).reshape(-1)
        self.positions = np.asarray(self.positions, dtype=np.float64).reshape(-1, 3)
        if self.times.size != self.positions.shape[0] or self.times.size == 0:
            raise ClothFitError(
                f"handle on vertex {self.vertex}: {self.times.size} times but {self.positions.shape[0]} positions"
            )
        if np.any(np.diff(self.times) <= 0):
            raise ClothFitError(f"handle on vertex {self.vertex}: key times must increase, got {self.times.tolist()}")
        if not np.all(np.isfinite(self.positions)) or not np.all(np.isfinite(self.times)):
            raise ClothFitError(f"handle on vertex {self.vertex}: non-finite key")
        if np.abs(self.positions).max() > MAX_SIZE_M or np.abs(self.times).max() > MAX_TIME_S:
            raise ClothFitError(f"handle on vertex {self.vertex}: keys beyond {MAX_SIZE_M:g} m or {MAX_TIME_S:g} s")
        if self.release_time is not None and not (
            math.isfinite(self.release_time) and abs(self.release_time) <= MAX_TIME_S
        ):
            raise ClothFitError(
                f"handle on vertex {self.vertex}: release_time {self.release_time} must be finite "
                f"and within {MAX_TIME_S:g} s"
            )

    def position(self, t: ArrayLike) -> np.ndarray:
        """Positions at times ``t`` (array) -> ``t.shape + (3,)``."""
        t = np.asarray(t, dtype=np.float64)
        if self.times.size == 1:
            return np.broadcast_to(self.positions[0], t.shape + (3,)).copy()
        return np.stack([np.interp(t, self.times, self.positions[:, a]) for a in range(3)], -1)

    def velocity(self, t: ArrayLike) -> np.ndarray:
        t = np.asarray(t, dtype=np.float64)
        out = np.zeros(t.shape + (3,))
        if self.times.size == 1:
            return out
        seg = np.clip(np.searchsorted(self.times, t, side="right") - 1, 0, self.times.size - 2)
        vel = np.diff(self.positions, axis=0) / np.diff(self.times)[:, None]
        inside = (t >= self.times[0]) & (t < self.times[-1])
        out[inside] = vel[seg[inside]]
        return out

    def held(self, t: ArrayLike) -> np.ndarray | np.bool_:
        t = np.asarray(t, dtype=np.float64)
        if self.release_time is None:
            return np.ones(t.shape, dtype=bool)
        return t <= self.release_time  # held up to and including the release instant

    def to_dict(self) -> dict[str, Any]:
        d = {"vertex": int(self.vertex), "times": self.times.tolist(), "positions": self.positions.tolist()}
        if self.release_time is not None:
            d["release_time"] = float(self.release_time)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any], n_vertices: int | None = None, source: str = "handle") -> Handle:
        try:
            v = int(d["vertex"])
            h = cls(
                v,
                d.get("times", [0.0]),
                d["positions"],
                None if d.get("release_time") is None else float(d["release_time"]),
            )
        except KeyError as e:
            raise ClothFitError(f"{source}: missing {e.args[0]!r}") from None
        except (TypeError, ValueError) as e:
            raise ClothFitError(f"{source}: bad handle {d!r} ({e})") from None
        if n_vertices is not None and not (0 <= v < n_vertices):
            raise ClothFitError(f"{source}: vertex {v} outside the grid (0..{n_vertices - 1})")
        return h


@dataclass
class Scenario:
    """A cloth, its handles, the settling phase and the capture times: one manipulation.

    ``crop`` (``crop.CropPlane``, None = none): the part of the scene the capture's data
    left out (points near a table); the model's silhouettes leave it out too. The simulation ignores it."""

    grid: ClothGrid
    handles: list
    frame_times: np.ndarray
    settle_time: float = D.SETTLE_TIME
    gravity: np.ndarray = field(default_factory=lambda: np.array(D.GRAVITY))
    colliders: Collisions | None = None  # what the cloth lands on (``colliders.py``); None: nothing
    crop: CropPlane | None = None  # the part of the scene the silhouettes leave out (``crop.py``); None: nothing

    def __post_init__(self):
        if self.colliders is not None and not isinstance(self.colliders, Collisions):
            raise ClothFitError(f"scenario: colliders must be a Collisions, got {type(self.colliders).__name__}")
        self.crop = CropPlane.parse(self.crop, "scenario crop")
        self.frame_times = np.asarray(self.frame_times, dtype=np.float64).reshape(-1)
        self.gravity = np.asarray(self.gravity, dtype=np.float64).reshape(3)
        if self.frame_times.size == 0:
            raise ClothFitError("scenario: no frame times")
        if not np.all(np.isfinite(self.frame_times)) or self.frame_times.max() > MAX_TIME_S:
            raise ClothFitError(f"scenario: frame times must be finite and at most {MAX_TIME_S:g} s")
        if self.frame_times.size > MAX_FRAMES:
            raise ClothFitError(f"scenario: {self.frame_times.size} frame times (at most {MAX_FRAMES})")
        try:
            self.settle_time = float(self.settle_time)
        except (TypeError, ValueError):
            raise ClothFitError(f"scenario: settle_time must be a number, got {self.settle_time!r}") from None
        if not (math.isfinite(self.settle_time) and 0 <= self.settle_time <= MAX_SETTLE_S):
            raise ClothFitError(
                f"scenario: settle_time {self.settle_time} must be a finite number of seconds in [0, {MAX_SETTLE_S:g}]"
            )
        if not np.all(np.isfinite(self.gravity)) or np.linalg.norm(self.gravity) > MAX_GRAVITY:
            raise ClothFitError(
                f"scenario: gravity {self.gravity.tolist()} must be finite and at most {MAX_GRAVITY:g} m/s^2"
            )
        if np.any(np.diff(self.frame_times) <= 0):
            raise ClothFitError(f"scenario: frame times must increase, got {self.frame_times.tolist()}")
        if self.frame_times[0] < -self.settle_time - 1e-12:
            raise ClothFitError(
                f"scenario: frame times must be >= -settle_time (the cloth settles from "
                f"t = -{self.settle_time:g} s to t = 0), got {self.frame_times[0]}"
            )
        seen = set()
        for h in self.handles:
            if not (0 <= h.vertex < self.grid.n_vertices):
                raise ClothFitError(
                    f"scenario: handle vertex {h.vertex} outside the grid (0..{self.grid.n_vertices - 1})"
                )
            if h.vertex in seen:
                raise ClothFitError(f"scenario: vertex {h.vertex} has two handles")
            seen.add(h.vertex)

    def to_dict(self) -> dict[str, Any]:
        d = {
            "cloth": self.grid.to_dict(),
            "handles": [h.to_dict() for h in self.handles],
            "frame_times": self.frame_times.tolist(),
            "settle_time": self.settle_time,
            "gravity": self.gravity.tolist(),
            **({} if self.crop is None else {"crop": self.crop.to_dict()}),
        }
        if self.colliders is not None:
            d["colliders"] = [c.to_dict() for c in self.colliders.colliders]
            d["collision_settings"] = self.colliders.settings_dict()
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any], source: str = "scenario") -> Scenario:
        grid = ClothGrid.from_dict(d.get("cloth", {}), source=f"{source} cloth")
        hs = d.get("handles")
        if not isinstance(hs, list):
            raise ClothFitError(f"{source}: 'handles' must be a list")
        handles = [Handle.from_dict(h, grid.n_vertices, f"{source} handle #{i}") for i, h in enumerate(hs)]
        if "frame_times" not in d:
            raise ClothFitError(f"{source}: missing 'frame_times'")
        cols = None
        if d.get("colliders") is not None:
            cols = Collisions.from_dicts(d["colliders"], d.get("collision_settings"), source)
        elif d.get("collision_settings") is not None:
            raise ClothFitError(f"{source}: 'collision_settings' without 'colliders'")
        crop = CropPlane.parse(d.get("crop"), f"{source} crop")
        return cls(
            grid,
            handles,
            d["frame_times"],
            float(d.get("settle_time", D.SETTLE_TIME)),
            d.get("gravity", D.GRAVITY),
            colliders=cols,
            crop=crop,
        )

    def with_frames(self, times: ArrayLike) -> Scenario:
        times = np.asarray(times, dtype=np.float64)
        return Scenario(
            self.grid, self.handles, times, self.settle_time, self.gravity, colliders=self.colliders, crop=self.crop
        )

    def moved(
        self, time_offset: float = 0.0, handle_offsets: ArrayLike | None = None, time_scale: float = 1.0
    ) -> Scenario:
        """The manipulation a fit estimated (``Uncertainty``): the frames read ``time_offset`` s earlier
        on the manipulation's clock (true time = time_scale x capture time - time_offset; a frame before
        the settle's start reads its start), every handle's trajectory moved by its offset (H, 3) [m]
        and, with a ``time_scale``, its key and release times stretched by it like the frames'."""
        hs = self.handles
        if handle_offsets is not None:
            off = np.asarray(handle_offsets, dtype=np.float64).reshape(len(hs), 3)
            hs = [Handle(h.vertex, h.times, h.positions + off[k], h.release_time) for k, h in enumerate(hs)]
        frames = self.frame_times
        if time_scale != 1.0:
            s = float(time_scale)
            hs = [
                Handle(h.vertex, h.times * s, h.positions, None if h.release_time is None else h.release_time * s)
                for h in hs
            ]
            frames = frames * s
        times = np.maximum(frames - float(time_offset), -self.settle_time)
        return Scenario(self.grid, hs, times, self.settle_time, self.gravity, colliders=self.colliders, crop=self.crop)


def paper_scenario(
    grid: ClothGrid | None = None, frame_times: ArrayLike | None = None, released_corner: int = D.RELEASED_CORNER
) -> Scenario:
    """docs/method.md#spec-5: all four corners held at the flat square, settle, release one corner at t = 0."""
    grid = grid or ClothGrid()
    handles = []
    for _ci, v in enumerate(grid.corners()):
        handles.append(Handle(v, [0.0], grid.rest[v][None], 0.0 if v == grid.corners()[released_corner] else None))
    return Scenario(grid, handles, D.FRAME_TIMES if frame_times is None else frame_times)


@dataclass(frozen=True)
class Uncertainty:
    """What a capture could not measure exactly about its manipulation, as bounds the fit searches
    within (capture.json key ``"uncertain"``, ``fit --uncertain``).

    * ``time_offset`` [s]: the capture's clock against the manipulation's. The fit estimates
      ``time_offset_s`` in ``[-time_offset, time_offset]``, defined by *true time = capture time -
      time_offset_s*: the model is read at ``t - time_offset_s`` for a frame taken at capture time
      ``t`` (the settle, the keys and the release shift with it against the frames).
    * ``handles`` [m]: per handle (in the scenario's order) the bound of a 3-D offset of its whole
      trajectory, each coordinate in ``[-b, b]``; one number = the same for every handle; 0 = exact.
    * ``time_scale`` (a factor S >= 1): the capture's frame interval is known only to within a factor S:
      the fit estimates ``time_scale`` in ``[1/S, S]``, which stretches the frame times and the handles'
      key and release times alike (true time = time_scale x capture time - time_offset_s); 1 = exact.
    """

    time_offset: float = 0.0
    handles: tuple = ()
    time_scale: float = 1.0

    @property
    def active(self) -> bool:
        return self.time_offset > 0 or any(b > 0 for b in self.handles) or self.time_scale > 1.0

    def to_dict(self) -> dict:
        h = list(self.handles)
        d = {"time_offset": self.time_offset, "handles": h[0] if h and all(b == h[0] for b in h) else h}
        if self.time_scale > 1.0:  # written only when declared: older readers see the same keys as before
            d["time_scale"] = self.time_scale
        return d

    @classmethod
    def parse(cls, value: Any, n_handles: int, source: str = "uncertain") -> Uncertainty | None:
        """From a capture's ``"uncertain"`` object (None/absent = nothing uncertain). Bounds must be
        numbers >= 0 and at most ``MAX_TIME_OFFSET_S`` / ``MAX_HANDLE_OFFSET_M``; ``handles`` is one
        bound or a list with one per handle."""
        if value is None:
            return None
        if not isinstance(value, dict):
            raise ClothFitError(f"{source}: expected an object {{'time_offset': s, 'handles': m}}, got {value!r}")
        bad = sorted(set(value) - set(UNCERTAIN_KEYS))
        if bad:
            raise ClothFitError(f"{source}: unknown key {bad[0]!r} (known: {', '.join(UNCERTAIN_KEYS)})")
        t = _bound(value.get("time_offset", 0.0), f"{source} time_offset", MAX_TIME_OFFSET_S, "s")
        hv = value.get("handles", 0.0)
        if isinstance(hv, (list, tuple)):
            if len(hv) != n_handles:
                raise ClothFitError(
                    f"{source} handles: {len(hv)} bounds for {n_handles} handles (give one number or one per handle)"
                )
            hs = tuple(_bound(b, f"{source} handles[{i}]", MAX_HANDLE_OFFSET_M, "m") for i, b in enumerate(hv))
        else:
            hs = (_bound(hv, f"{source} handles", MAX_HANDLE_OFFSET_M, "m"),) * n_handles
        ts = _bound(value.get("time_scale", 1.0), f"{source} time_scale", MAX_TIME_SCALE, "x")
        if ts < 1.0:
            raise ClothFitError(
                f"{source} time_scale: {ts:g} must be a factor >= 1 (the scale is searched in [1/S, S])"
            )
        return cls(t, hs, ts)

    @classmethod
    def from_text(cls, text: str, n_handles: int, source: str = "--uncertain") -> Uncertainty | None:
        """``time_offset=0.05,handles=0.005`` (seconds, metres) or ``none``."""
        text = str(text).strip()
        if text.lower() == "none":
            return cls(0.0, (0.0,) * n_handles)
        d = {}
        for part in filter(None, (p.strip() for p in text.split(","))):
            key, eq, val = part.partition("=")
            key = key.strip()
            if not eq:
                raise ClothFitError(
                    f"{source}: {part!r} must be KEY=VALUE (keys: {', '.join(UNCERTAIN_KEYS)}), or 'none'"
                )
            if key in d:
                raise ClothFitError(f"{source}: {key!r} given twice")
            try:
                d[key] = float(val)
            except ValueError:
                raise ClothFitError(f"{source}: {key} = {val.strip()!r} is not a number") from None
        if not d:
            raise ClothFitError(f"{source}: empty (give e.g. time_offset=0.05,handles=0.005, or none)")
        return cls.parse(d, n_handles, source)


def _bound(v, what: str, limit: float, unit: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
        raise ClothFitError(f"{what}: {v!r} is not a number ({unit})")
    v = float(v)
    if not math.isfinite(v) or v < 0:
        raise ClothFitError(f"{what}: {v!r} must be a bound >= 0 ({unit})")
    if v > limit:
        raise ClothFitError(f"{what}: {v:g} {unit} is absurd for an uncertain measurement (at most {limit:g} {unit})")
    return v


@dataclass
class Offsets:
    """Per-candidate estimates of a manipulation's unknowns (a fit's ``Uncertainty``): ``time`` (P,)
    [s] (``time_offset_s``: the model is read at capture time - time), ``handles`` (P, H, 3) [m]
    (each handle's trajectory moved by it) and ``scale`` (P,) (``time_scale``: frame times and handle
    key times stretched by it; None = 1 for all)."""

    time: np.ndarray
    handles: np.ndarray
    scale: np.ndarray | None = None

    def __post_init__(self):
        self.time = np.asarray(self.time, dtype=np.float64).reshape(-1)
        self.handles = np.asarray(self.handles, dtype=np.float64)
        self.scale = np.ones(self.time.size) if self.scale is None else np.asarray(self.scale, np.float64).reshape(-1)
        if self.scale.size != self.time.size:
            raise ClothFitError(f"offsets: {self.time.size} time offsets but {self.scale.size} time scales")
        if self.handles.ndim != 3 or self.handles.shape[0] != self.time.size or self.handles.shape[2] != 3:
            raise ClothFitError(
                f"offsets: {self.time.size} time offsets but handle offsets of shape "
                f"{self.handles.shape} (expected (P, H, 3))"
            )

    def __len__(self):
        return self.time.size

    def take(self, idx: np.ndarray | list[int] | slice) -> Offsets:
        return Offsets(self.time[idx], self.handles[idx], self.scale[idx])

    @property
    def stretches(self) -> bool:
        """True when some candidate's time scale is not 1 (its frames and keys stretched)."""
        return bool(np.any(self.scale != 1.0))

    @property
    def moves_handles(self) -> bool:
        return bool(np.any(self.handles != 0))

    @property
    def span(self) -> float:
        """The largest |time offset|."""
        return float(np.abs(self.time).max(initial=0.0))


def fitted_scenario(scenario: Scenario, result: dict[str, Any]) -> Scenario:
    """A scenario as a fit result estimated its manipulation: handles from the result's ``handles``
    (same vertices, in the same order) and its frames read ``time_offset_s`` earlier; a result
    without them leaves the scenario as it is."""
    hs = result.get("handles")
    t = result.get("time_offset_s") or 0.0
    scale = result.get("time_scale") or 1.0
    if not hs and not t and scale == 1.0:
        return scenario
    offsets = None
    if hs:
        if not isinstance(hs, list) or len(hs) != len(scenario.handles):
            raise ClothFitError(
                f"result: {len(hs) if isinstance(hs, list) else 'bad'} fitted handles for a scenario "
                f"with {len(scenario.handles)}"
            )
        offsets = np.zeros((len(hs), 3))
        for k, (d, h) in enumerate(zip(hs, scenario.handles)):
            if not isinstance(d, dict) or int(d.get("vertex", -1)) != h.vertex:
                raise ClothFitError(f"result: fitted handle #{k} is not on vertex {h.vertex} (the capture's)")
            try:
                offsets[k] = np.asarray(d.get("offset_m", [0.0, 0.0, 0.0]), dtype=np.float64).reshape(3)
            except (TypeError, ValueError):
                raise ClothFitError(f"result: fitted handle #{k} has a bad 'offset_m'") from None
    if not (isinstance(t, (int, float)) and math.isfinite(t)):
        raise ClothFitError(f"result: time_offset_s {t!r} is not a number")
    if isinstance(scale, bool) or not (isinstance(scale, (int, float)) and math.isfinite(scale) and scale > 0):
        raise ClothFitError(f"result: time_scale {scale!r} is not a positive number")
    return scenario.moved(float(t), offsets, float(scale))
