"""Captures from point clouds: a folder of calibrated point clouds (one ``N x 3`` .npy per frame) made into
a capture (``observation/capture.py``) the fit reads like any other (docs/point_clouds.md).

What a conversion is told, in a setup JSON (``read_setup``): the clouds' unit (metres per unit) and the
interval between frames; the cloth (a flat square of a given side, lying in the horizontal plane through
its grasped corner, its diagonal pointing ``across`` from that corner); the grasped corner's path (the
robot's waypoints, keyed one ``interval`` apart); optionally a crop plane (the part of the scene the
clouds left out, e.g. within 2 cm of a table) and the virtual cameras. Every length is in metres in the
clouds' own frame (z up) scaled by the unit; waypoints read from a file may carry their own frame.

What it writes: a ring of virtual cameras looking at the points (and any calibrated real ones,
``real_cameras``); per camera and frame a silhouette made by drawing every point above the crop as a disc
of ``splat_radius`` metres facing the camera (``splat``); the scenario (the cloth flat at rest at t = 0, its grasped corner the handle moving along the waypoints,
the frame times, the crop, which the model's silhouettes then honour: ``physics/crop.py``).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Any

import numpy as np

from .. import defaults as D
from ..errors import ClothFitError
from ..jsonio import read_json
from ..observation.camera import Camera, ring_rig
from ..observation.capture import Capture, write_capture
from ..observation.points import frame_scatter_mm, read_point_cloud
from ..observation.raster import silhouette
from ..physics import blender_settings as BS
from ..physics.colliders import Collisions
from ..physics.crop import CropPlane
from ..physics.models import model_and_row
from ..physics.scenario import ClothGrid, Handle, Scenario

SETUP_KEYS = (
    "unit_scale",
    "frame_interval",
    "splat_radius",
    "cloth",
    "path",
    "crop",
    "cameras",
    "uncertain",
    "settle_time",
    "colliders",
    "collision_settings",
    "first_frame",
    "erode_radius",
)
MAX_SPLAT_PX = 64  # a disc wider than this many pixels is a wrong radius or a camera inside the cloud


# ============================================================================ reading


def point_cloud_files(folder: str) -> list[str]:
    """The .npy files of a folder in name order (one per frame)."""
    if not os.path.isdir(folder):
        raise ClothFitError(f"point clouds {folder}: not a folder")
    names = sorted(n for n in os.listdir(folder) if n.lower().endswith(".npy"))
    if not names:
        raise ClothFitError(f"point clouds {folder}: no .npy files")
    return [os.path.join(folder, n) for n in names]


def _number(v: Any, what: str, lo: float = 0.0, positive: bool = True) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise ClothFitError(f"{what}: {v!r} is not a number")
    v = float(v)
    if not math.isfinite(v) or v < lo or (positive and v <= 0):
        raise ClothFitError(f"{what}: {v!r} must be a finite number {'>' if positive else '>='} {lo:g}")
    return v


def _vector(v: Any, what: str, n: int = 3) -> np.ndarray:
    try:
        a = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        raise ClothFitError(f"{what}: {v!r:.80} is not {n} numbers") from None
    if a.shape != (n,) or not np.all(np.isfinite(a)):
        raise ClothFitError(f"{what}: {v!r:.80} must be {n} finite numbers")
    return a


def frame_transform(waypoints: np.ndarray, frame: dict[str, Any], where: str) -> np.ndarray:
    """Waypoints in a robot's frame into the clouds' units: ``((w - translation) / scale) @ Rz(z_rotation_deg)``
    (row vectors; the convention of DiffCloud's ``lift_real2sim.yaml``)."""
    if not isinstance(frame, dict) or set(frame) - {"translation", "scale", "z_rotation_deg"}:
        raise ClothFitError(f"{where}: 'frame' must be {{'translation': [x, y, z], 'scale': s, 'z_rotation_deg': a}}")
    t = _vector(frame.get("translation", [0.0, 0.0, 0.0]), f"{where} frame translation")
    s = _number(frame.get("scale", 1.0), f"{where} frame scale")
    a = math.radians(_number(frame.get("z_rotation_deg", 0.0), f"{where} frame z_rotation_deg", -360.0, False))
    rz = np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])
    return ((waypoints - t) / s) @ rz


def read_path(spec: Any, unit_scale: float, frame_interval: float, where: str, base: str = ".") -> Handle:
    """The grasped corner's path (vertex 0: the grid's corner at the first waypoint) from the setup's ``path``:
    ``waypoints`` [[x, y, z], ...] in metres, or ``file`` (a K x 3 .npy in the clouds' units, or in a robot's
    frame given by ``frame``); waypoint k at ``start + k * interval`` seconds (default 0 and the frame interval)."""
    if not isinstance(spec, dict) or ("waypoints" in spec) == ("file" in spec):
        raise ClothFitError(f"{where}: give 'waypoints' [[x, y, z], ...] or a 'file' of them")
    bad = sorted(set(spec) - {"waypoints", "file", "frame", "interval", "start"})
    if bad:
        raise ClothFitError(f"{where}: unknown key {bad[0]!r}")
    if "file" in spec:
        path = spec["file"] if os.path.isabs(str(spec["file"])) else os.path.join(base, str(spec["file"]))
        w = read_point_cloud(path)
        w = (frame_transform(w, spec["frame"], where) if "frame" in spec else w) * unit_scale
        src = path
    else:
        if "frame" in spec:
            raise ClothFitError(f"{where}: 'frame' goes with a 'file' of waypoints, not with 'waypoints' in metres")
        try:
            w = np.asarray(spec["waypoints"], dtype=np.float64)
        except (TypeError, ValueError):
            raise ClothFitError(f"{where} waypoints: not a list of [x, y, z] numbers") from None
        src = f"{where} waypoints"
        if w.ndim != 2 or w.shape[1] != 3 or not np.all(np.isfinite(w)):
            raise ClothFitError(f"{src}: shape {w.shape}, expected K x 3 finite numbers")
    if w.shape[0] < 2:
        raise ClothFitError(f"{src}: {w.shape[0]} waypoint(s): a path needs at least two")
    interval = _number(spec.get("interval", frame_interval), f"{where} interval")
    start = _number(spec.get("start", 0.0), f"{where} start", -1e3, False)
    return Handle(0, start + interval * np.arange(w.shape[0]), w)


@dataclass
class PointsSetup:
    """A conversion's settings (``read_setup``), lengths in metres and times in seconds."""

    unit_scale: float
    frame_interval: float
    splat_radius: float
    side: float
    grid_n: int
    across: np.ndarray
    handle: Handle
    crop: CropPlane | None
    cameras: dict[str, Any]
    uncertain: Any
    settle_time: float
    colliders: Collisions | None = None
    first_frame: int = 0  # frames of the folder before this one are left out (their times kept)
    erode_radius: float = (
        0.0  # [m] each splatted silhouette eroded by this much (a closing: holes filled, outline kept)
    )


def parse_setup(d: Any, where: str, base: str = ".", **override: Any) -> PointsSetup:
    """The setup from its JSON object; ``override``: frame_interval, splat_radius given on the command line."""
    if not isinstance(d, dict):
        raise ClothFitError(f"{where}: expected a JSON object")
    bad = sorted(set(d) - set(SETUP_KEYS))
    if bad:
        raise ClothFitError(f"{where}: unknown key {bad[0]!r} (known: {', '.join(SETUP_KEYS)})")
    d = dict(d, **{k: v for k, v in override.items() if v is not None})
    if "frame_interval" not in d:
        raise ClothFitError(f"{where}: no 'frame_interval' (seconds between frames)")
    unit = _number(d.get("unit_scale", 1.0), f"{where} unit_scale")
    interval = _number(d["frame_interval"], f"{where} frame_interval")
    radius = _number(d.get("splat_radius", D.POINTS_SPLAT_RADIUS), f"{where} splat_radius")
    cloth = d.get("cloth")
    if not isinstance(cloth, dict) or "side" not in cloth or "across" not in cloth:
        raise ClothFitError(f"{where}: 'cloth' must give 'side' [m] and 'across' (the diagonal's direction)")
    n = cloth.get("grid", D.GRID_N)
    if isinstance(n, bool) or not isinstance(n, int) or n < 2:
        raise ClothFitError(f"{where} cloth grid: {n!r} must be a whole number of vertices per side >= 2")
    across = _vector(cloth["across"], f"{where} cloth across")
    across[2] = 0.0
    if not np.linalg.norm(across) > 1e-12:
        raise ClothFitError(f"{where} cloth across: {cloth['across']} has no horizontal direction")
    if "path" not in d:
        raise ClothFitError(f"{where}: no 'path' (the grasped corner's waypoints)")
    cams = d.get("cameras", {})
    if not isinstance(cams, dict) or set(cams) - {"count", "elevation_deg", "fov_deg", "resolution", "real"}:
        raise ClothFitError(f"{where} cameras: expected {{count, elevation_deg, fov_deg, resolution: [H, W], real}}")
    if "real" in cams:
        cams = dict(cams, real=real_cameras(cams["real"], unit, f"{where} cameras real", base))
    return PointsSetup(
        unit,
        interval,
        radius,
        _number(cloth["side"], f"{where} cloth side"),
        n,
        across / np.linalg.norm(across),
        read_path(d["path"], unit, interval, f"{where} path", base),
        CropPlane.parse(d.get("crop"), f"{where} crop"),
        cams,
        d.get("uncertain"),
        _number(d.get("settle_time", D.POINTS_SETTLE_TIME), f"{where} settle_time", 0.0, False),
        _colliders(d, where),
        _first_frame(d.get("first_frame", 0), where),
        _erode(d, radius, where),
    )


def _erode(d: dict, radius: float, where: str) -> float:
    e = _number(d.get("erode_radius", 0.0), f"{where} erode_radius", 0.0, False)
    if e >= radius:
        raise ClothFitError(f"{where} erode_radius: {e:g} m must be below the splat radius {radius:g} m")
    return e


def _first_frame(v: Any, where: str) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or v < 0:
        raise ClothFitError(f"{where} first_frame: {v!r} must be a whole number of frames >= 0")
    return v


def _colliders(d: dict, where: str) -> Collisions | None:
    """The setup's colliders (a table the cloth lies on: ``physics/colliders.py``, lengths in metres in the
    clouds' frame), or None."""
    if d.get("colliders") is None:
        if d.get("collision_settings") is not None:
            raise ClothFitError(f"{where}: 'collision_settings' without 'colliders'")
        return None
    return Collisions.from_dicts(d["colliders"], d.get("collision_settings"), where)


def read_setup(path: str, **override: Any) -> PointsSetup:
    """``parse_setup`` of a setup JSON file (relative file names in it are relative to its folder)."""
    d = read_json(path, "points setup")
    return parse_setup(d, f"setup {path}", os.path.dirname(os.path.abspath(path)), **override)


# ============================================================================ geometry


def flat_square(corner: np.ndarray, across: np.ndarray, side: float, n: int) -> ClothGrid:
    """An ``n x n`` grid of a square of ``side`` lying flat (z = corner's z) with its corner vertex 0 at
    ``corner`` and the opposite corner ``side * sqrt(2)`` away along the horizontal unit vector ``across``."""
    centre = np.asarray(corner, dtype=np.float64) + across * side / math.sqrt(2.0)
    theta = math.atan2(-across[1], -across[0]) - math.atan2(-1.0, -1.0)  # local (-1, -1) turned onto -across
    return ClothGrid(n, side=side, origin=centre, rotation=(0.0, 0.0, theta))


def virtual_ring(points: np.ndarray, spec: dict[str, Any]) -> list[Camera]:
    """A ring of cameras at one elevation around the points, far enough that each sees all of them."""
    count = spec.get("count", 0 if spec.get("real") else D.POINTS_CAMERAS)
    if isinstance(count, bool) or not isinstance(count, int) or not (0 if spec.get("real") else 1) <= count <= 64:
        raise ClothFitError(f"cameras count: {count!r} must be a whole number 1..64 (0 with real cameras)")
    if count == 0:
        return []
    elev = _number(spec.get("elevation_deg", D.POINTS_ELEVATION_DEG), "cameras elevation_deg", -89.0, False)
    fov = _number(spec.get("fov_deg", D.POINTS_FOV_DEG), "cameras fov_deg")
    res = spec.get("resolution", D.POINTS_RESOLUTION)
    if not isinstance(res, (list, tuple)) or len(res) != 2:
        raise ClothFitError(f"cameras resolution: {res!r} must be [H, W]")
    h, w = res
    if not all(isinstance(x, int) and not isinstance(x, bool) and 8 <= x <= D.MAX_IMAGE_SIDE for x in (h, w)):
        raise ClothFitError(f"cameras resolution: {[h, w]} must be [H, W] whole numbers of pixels, at least 8")
    if not (fov < 170 and elev <= 89):
        raise ClothFitError(
            f"cameras: field of view {fov:g} deg (< 170) or elevation {elev:g} deg (<= 89) out of range"
        )
    lo, hi = points.min(0), points.max(0)
    target = (lo + hi) / 2.0
    radius = max(float(np.linalg.norm(points - target, axis=1).max()), 1e-3)
    half = math.atan(math.tan(math.radians(fov) / 2.0) * min(h, w) / w)  # the narrower half-angle
    distance = radius * D.POINTS_MARGIN / math.sin(half)
    fx = (w / 2.0) / math.tan(math.radians(fov) / 2.0)
    return ring_rig((count,), (elev,), distance, target, w, h, fx, (0.0,))


def _array(v: Any, shape: tuple, what: str, base: str) -> np.ndarray:
    """Numbers of a given shape, written in the setup or in a .npy file named there."""
    if isinstance(v, str):
        path = v if os.path.isabs(v) else os.path.join(base, v)
        try:
            v = np.load(path, allow_pickle=False)
        except (OSError, ValueError, EOFError) as e:
            raise ClothFitError(f"{what} {path}: not a readable .npy array ({type(e).__name__})") from None
        what = f"{what} {path}"
    try:
        a = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        raise ClothFitError(f"{what}: not numbers") from None
    if a.shape != shape or not np.all(np.isfinite(a)):
        raise ClothFitError(f"{what}: shape {a.shape}, expected {shape} finite numbers")
    return a


def real_cameras(specs: Any, unit_scale: float, where: str, base: str = ".") -> list[Camera]:
    """Cameras calibrated in a robot's frame, moved into the clouds' frame: each ``{"name", "intrinsics":
    [fx, fy, cx, cy], "camera_to_frame": 3 x 4 [R | t] (camera -> robot, metres), "resolution": [H, W],
    "frame": the path's kind of frame}`` (arrays inline or in .npy files). The frame's scale must equal
    ``unit_scale`` (metres stay metres: a camera cannot be scaled)."""
    if not isinstance(specs, list) or not specs:
        raise ClothFitError(f"{where}: expected a list of cameras")
    out = []
    for i, c in enumerate(specs):
        w = f"{where}[{i}]"
        if not isinstance(c, dict) or set(c) - {"name", "intrinsics", "camera_to_frame", "resolution", "frame"}:
            raise ClothFitError(f"{w}: expected {{name, intrinsics, camera_to_frame, resolution, frame}}")
        fx, fy, cx, cy = _array(c.get("intrinsics"), (4,), f"{w} intrinsics", base)
        T = _array(c.get("camera_to_frame"), (3, 4), f"{w} camera_to_frame", base)
        frame = c.get("frame", {})
        if abs(float(frame.get("scale", 1.0)) - unit_scale) > 1e-9 * unit_scale:
            raise ClothFitError(f"{w} frame scale: {frame.get('scale', 1.0)!r} must equal unit_scale {unit_scale:g}")
        res = c.get("resolution")
        if not isinstance(res, list) or len(res) != 2 or not all(isinstance(x, int) and x >= 8 for x in res):
            raise ClothFitError(f"{w} resolution: {res!r} must be [H, W] whole numbers of pixels")
        # world (clouds' metres) -> robot: X_r = rz X_w + t (frame_transform inverted); robot -> camera
        origin = frame_transform(np.zeros((1, 3)), frame, w)[0] * unit_scale  # where the robot's origin lands
        rz = frame_transform(np.eye(3), dict(frame, translation=[0.0, 0.0, 0.0]), w) * unit_scale  # rows: axes
        R_rc = T[:, :3].T  # robot -> camera rotation
        R = R_rc @ rz
        t = R_rc @ (rz @ -origin - T[:, 3])
        K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        name = str(c.get("name", f"real{i}"))
        out.append(Camera(K, R, t, int(res[1]), int(res[0]), name=name))
    return out


def splat(camera: Camera, points: np.ndarray, radius: float, erode: float = 0.0) -> np.ndarray:
    """The silhouette (bool H x W) of ``points`` drawn as discs of ``radius`` metres facing the camera: a pixel
    is in when its centre lies within a disc's projected radius ``fx * radius / depth`` of a point; then, with
    ``erode`` > 0, eroded by a disc of ``fx * erode / depth`` pixels at the points' median depth (discs large
    enough to close the gaps of a sparse cloud, the outline drawn back towards the surface's)."""
    out = _discs(camera, points, radius)
    if erode > 0.0 and out.any():
        z = float(np.median(camera.to_camera(points)[:, 2]))
        rp = int(round(float(camera.K[0, 0]) * erode / z)) if z > 1e-9 else 0
        if rp > 0:
            import cv2  # as the silhouette readers do: the add-on loads without it

            d = np.arange(-rp, rp + 1)
            disc = (d[:, None] ** 2 + d[None, :] ** 2 <= rp * rp).astype(np.uint8)
            out = cv2.erode(out.astype(np.uint8), disc, borderValue=0) > 0
    return out


def _discs(camera: Camera, points: np.ndarray, radius: float) -> np.ndarray:
    depth = camera.to_camera(points)[:, 2]
    uv = camera.project(points)
    ok = np.isfinite(uv).all(1) & (depth > 1e-9)
    uv, depth = uv[ok], depth[ok]
    out = np.zeros((camera.height, camera.width), dtype=bool)
    if not uv.size:
        return out
    r = float(camera.K[0, 0]) * radius / depth
    big = float(r.max())
    if big > MAX_SPLAT_PX:
        raise ClothFitError(
            f"camera '{camera.name}': a splat of {radius:g} m is {big:.0f} px wide (at most {MAX_SPLAT_PX}): "
            f"the radius is too large or the camera sits inside the cloud"
        )
    R = int(math.ceil(big))
    d = np.arange(-R, R + 1)
    dy, dx = (a.reshape(-1) for a in np.meshgrid(d, d, indexing="ij"))
    for s in range(0, uv.shape[0], 4096):
        u, v, rr = uv[s : s + 4096, 0:1], uv[s : s + 4096, 1:2], r[s : s + 4096, None]
        cols = np.rint(u).astype(np.int64) + dx
        rows = np.rint(v).astype(np.int64) + dy
        hit = (cols - u) ** 2 + (rows - v) ** 2 <= rr**2
        hit &= (rows >= 0) & (rows < camera.height) & (cols >= 0) & (cols < camera.width)
        out[rows[hit], cols[hit]] = True
    return out


# ============================================================================ the splatting's own error


def splat_floor(
    cameras: list[Camera],
    vertices: np.ndarray,
    triangles: np.ndarray,
    crop: CropPlane | None,
    counts: list[int],
    radius: float,
    erode: float = 0.0,
    seed: int = 0,
) -> np.ndarray:
    """(C, F) ``E_sil`` fractions of a cloth's own points splatted as the converter splats real points, against
    the same cloth's silhouette: the error a perfect model keeps against splatted silhouettes, which the
    images' outline noise (``observation/floor.py``) cannot see. ``vertices`` (F, V, 3) the cloth per frame;
    frame f is sampled uniformly over its area with ``counts[f]`` points above the ``crop`` (as many as the
    real cloud keeps there) and splatted with ``radius`` and ``erode`` (``splat``). A frame where the cloth shows
    too little area above the crop to hold that many points (even sampled ``D.SPLAT_FLOOR_OVERSAMPLE`` times as
    densely) gets NaN: its error cannot be estimated with this cloth."""
    rng = np.random.default_rng(seed)
    out = np.zeros((len(cameras), len(counts)))
    for f, n in enumerate(counts):
        V = vertices[f]
        a, b, c = (V[triangles[:, i]] for i in range(3))
        area = np.linalg.norm(np.cross(b - a, c - a), axis=1) / 2.0
        m = D.SPLAT_FLOOR_OVERSAMPLE * int(n)
        pick = rng.choice(len(area), m, p=area / area.sum())
        u, v = rng.random(m), rng.random(m)
        flip = u + v > 1.0
        u[flip], v[flip] = 1.0 - u[flip], 1.0 - v[flip]
        S = a[pick] + u[:, None] * (b[pick] - a[pick]) + v[:, None] * (c[pick] - a[pick])
        if crop is not None:
            S = S[crop.height(S) >= 0.0]
        if S.shape[0] < int(n):  # too little of this cloth above the crop to hold the frame's points
            out[:, f] = np.nan
            continue
        S = S[: int(n)]
        for ci, cam in enumerate(cameras):
            model = silhouette(cam, V, triangles, crop=crop)
            o = splat(cam, S, radius, erode)
            out[ci, f] = np.count_nonzero(model ^ o) / max(int(o.sum()), 1)
    return out


def default_cloth_splat_floor(cameras: list[Camera], scenario: Scenario, counts: list[int], setup: PointsSetup) -> dict:
    """The capture's ``meta["splat_floor"]``: ``splat_floor`` of Blender's default cloth moved by the capture's
    handling (its settings are unknown before a fit; the splatting's error depends on the points' density, the
    disc radius and the cloth's outline far more than on its stiffness), per camera name and frame time; null for
    a frame where that cloth lies below the crop."""
    model, row = model_and_row({"blender_cloth": dict(BS.DEFAULTS)})
    X = model.simulate(scenario, row[None]).positions[0]
    P = splat_floor(cameras, X, scenario.grid.triangles, scenario.crop, counts, setup.splat_radius, setup.erode_radius)
    return {
        "cloth": "Blender's default cloth moved by the capture's handling, sampled with each frame's count of points",
        "resolution": [cameras[0].height, cameras[0].width],
        "cameras": [c.name for c in cameras],
        "frame_times": [float(t) for t in scenario.frame_times],
        "per_image": [[round(float(x), 6) if np.isfinite(x) else None for x in row] for row in P],
        "mean": round(float(np.nanmean(P)), 6) if np.isfinite(P).any() else None,
    }


# ============================================================================ conversion


def kept_points(files: list[str], setup: PointsSetup) -> tuple[list[np.ndarray], list[int]]:
    """Every frame's points in metres above the crop, and the count each keeps; a crop above the cloud of
    every frame (no frame keeping ``D.POINTS_MIN_POINTS``) is refused, naming the plane."""
    frames, counts = [], []
    for f in files:
        X = read_point_cloud(f) * setup.unit_scale
        if setup.crop is not None:
            X = X[setup.crop.height(X) >= 0.0]
        frames.append(X)
        counts.append(int(X.shape[0]))
    if max(counts) < D.POINTS_MIN_POINTS:
        best = int(np.argmax(counts))
        raise ClothFitError(
            f"crop plane {setup.crop.to_dict() if setup.crop else None}: above the cloth: no frame keeps "
            f"{D.POINTS_MIN_POINTS} points above it (the most: {counts[best]} in {files[best]})"
        )
    return frames, counts


def points_to_capture(folder: str, setup: PointsSetup, out: str) -> tuple[Capture, dict[str, Any]]:
    """Convert a folder of point clouds (``point_cloud_files``) with ``setup`` into a capture at ``out``.
    Frame k of the folder is taken at ``k * frame_interval``; frames keeping fewer than
    ``D.POINTS_MIN_POINTS`` points above the crop are left out (listed in the report). Returns the capture
    and a report (frames kept and left out, points per frame, the cameras)."""
    files = point_cloud_files(folder)
    h = setup.handle
    if setup.crop is not None and not np.any(setup.crop.height(h.positions) > 0.0):
        raise ClothFitError(
            f"crop plane {setup.crop.to_dict()}: above the cloth: its grasped corner never rises above it "
            f"(waypoints {h.positions[0].round(4).tolist()} .. {h.positions[-1].round(4).tolist()} m)"
        )
    frames, counts = kept_points(files, setup)
    if setup.first_frame >= len(files):
        raise ClothFitError(f"first_frame {setup.first_frame}: the folder {folder} has only {len(files)} frames")
    keep = [k for k, c in enumerate(counts) if c >= D.POINTS_MIN_POINTS and k >= setup.first_frame]
    times = np.round(setup.frame_interval * np.asarray(keep, dtype=np.float64), 9)  # 0.6, not 0.6000000000000001
    grid = flat_square(h.positions[0], setup.across, setup.side, setup.grid_n)
    scenario = Scenario(grid, [h], times, setup.settle_time, colliders=setup.colliders, crop=setup.crop)
    every = np.concatenate([frames[k] for k in keep] + [h.positions, grid.rest])
    cams = virtual_ring(every, setup.cameras) + list(setup.cameras.get("real", []))
    sils = [[splat(c, frames[k], setup.splat_radius, setup.erode_radius) for k in keep] for c in cams]
    meta = {
        "generator": "points-to-capture (discs splatted from point clouds)",
        "points": os.path.abspath(folder),
        "point_files": [os.path.basename(files[k]) for k in keep],
        "unit_scale": setup.unit_scale,
        "frame_interval_s": setup.frame_interval,
        "splat_radius_m": setup.splat_radius,
        "erode_radius_m": setup.erode_radius,
        "points_per_frame": [counts[k] for k in keep],
        "left_out": [os.path.basename(files[k]) for k in range(len(files)) if k not in keep],
        "splat_floor": default_cloth_splat_floor(cams, scenario, [counts[k] for k in keep], setup),
        # each frame's points' own scatter about a smooth surface: what a perfect cloth still scores against them
        "points_scatter_mm": [round(frame_scatter_mm(frames[k]), 4) for k in keep],
    }
    cap = write_capture(out, cams, scenario, sils, meta=meta, uncertain=setup.uncertain)
    report = {
        "capture": os.path.abspath(out),
        "cameras": [c.name for c in cams],
        "resolution": [cams[0].height, cams[0].width],
        "frames": len(keep),
        "frame_times": times.tolist(),
        "left_out": meta["left_out"],
        "splat_radius_m": setup.splat_radius,
        "splat_floor_pct": None if meta["splat_floor"]["mean"] is None else round(100 * meta["splat_floor"]["mean"], 3),
        "crop": None if setup.crop is None else setup.crop.to_dict(),
    }
    return cap, report
