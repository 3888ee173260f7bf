"""The manipulation measured from footage: clips and fingertips marked once, tracked, triangulated.

``clothfit handles`` (``docs/phone_rig.md``, step 6). The user marks every held point of the cloth (a clip,
a fingertip: a *handle*) in at least two cameras at one frame (a marks JSON, below). This module
(the steps: ``handle_triangulate.py``, ``handle_tracking.py``, ``handle_release.py``,
``handle_placement.py``; the marks: ``handle_marks.py``)

1. **triangulates** each mark (linear DLT on the undistorted rays, then Gauss-Newton on the pixel
   reprojection error with the cameras' distortion); the residual is reported per camera in pixels
   and converted to millimetres at the point's depth (``residual_px * depth / f``);
2. **tracks** each mark through every frame of every camera that marked it (pyramidal Lucas-Kanade,
   frame to frame, with a forward-backward check, then refined against the marked frame's own patch
   so that a still clip does not drift) and triangulates it per frame; a camera that disagrees with
   the others by more than ``HANDLE_MAX_RESIDUAL_PX`` (a drifted track) is dropped from that frame on;
3. **finds the release** of a released handle: the *departure frame* is the first frame where its
   3-D track is further from its pin than ``max(HANDLE_DEPARTURE_MIN_M, HANDLE_DEPARTURE_K x the held
   jitter)``; the release *instant* is extrapolated back from the first frames of the fall (a
   parabola from rest, ``X = p + A s^2 / 2, s = t - t_release``, least squares over the last held
   and the first free frames); the *release frame* is the first frame after that instant (the frame
   the scenario's ``release_time`` makes the first free one);
4. **places the cloth**: a flat rectangle of the measured size, a grid of the chosen resolution,
   moved rigidly so that the points the user says the clips hold (``at``) sit on the triangulated
   pins (Kabsch; with the ``at`` points on one line the cloth hangs below that line); each handle
   gets the grid vertex nearest its ``at`` (or, without ``at``, the vertex of the placed cloth
   nearest its pin);
5. writes the **scenario** (``Scenario.to_dict()``: the placed grid, one ``Handle`` per mark: fixed =
   its mean position, moving = its smoothed track, released = its pin and release time) and its
   ``uncertain`` block, which ``clothfit extract --scenario`` copies into the capture.

Marks JSON::

    {"frame": 0,                                     # the frame the marks are made at (default 0)
     "handles": [
       {"name": "left clip", "at": "top-left", "marks": {"cam0": [412.5, 230.0], "cam1": [300.2, 198.7]}},
       {"name": "middle", "at": [0.15, 0.0], "marks": {...}},
       {"name": "hand", "motion": "moving", "marks": {...}},
       {"name": "corner", "at": "top-right", "released": true, "marks": {...}}]}

``marks``: camera name -> ``[x, y]`` pixel of the (distorted) frame, OpenCV's convention (x = column,
y = row, pixel centres at integers). ``at``: where the handle holds the cloth, ``[u, v]`` metres from
the cloth's top-left corner (u along its width = grid columns, v down its height = grid rows) or a
corner name (``top-left``, ``top-right``, ``bottom-left``, ``bottom-right``). ``motion``: ``fixed``
(default) or ``moving``. ``released``: the handle lets go of the cloth during the footage. ``frame``
per handle overrides the top-level one. Unknown keys are refused (a typo must not pass silently).

Bad input is one line naming the file, handle, camera or frame, and nothing is written: unreadable
media, a mark outside its image or in fewer than two cameras, marks that do not meet in 3-D, a track
lost while it is needed (the camera and frame named), a released handle that never leaves its pin, a
clip far from every vertex of the cloth, two clips on one vertex.
"""

from __future__ import annotations

import math
import os
from typing import TYPE_CHECKING, Any

import numpy as np

from .. import defaults as D
from ..errors import ClothFitError
from ..physics.scenario import MAX_HANDLE_OFFSET_M, Handle, Scenario, Uncertainty
from .handle_marks import (
    HandleOptions,
    finite_number,
    parse_marks,  # noqa: E402,F401  (handles.parse_marks: tests/test_handles.py)
    read_marks,
)
from .handle_placement import assign_vertices, grid_resolution
from .handle_release import detect_release, smooth_track
from .handle_tracking import track_camera, window_for
from .handle_triangulate import triangulate, triangulate_track

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable, Sequence

    from ..observation.camera import Camera
    from .handle_marks import HandleMarks

FORMAT = "silhouette-cloth-fit/scenario"
G = 9.81


# ===================================================================== footage


class FootageSource:
    """Frames of every camera as grey uint8 images, and their capture times: image folders
    (``footage/<camera>/`` frames in natural order, background plates skipped, as ``extract`` reads
    them) or one video per camera at the capture times (``footage/video.py``)."""

    def __init__(self, cameras, times, folder=None, videos=None, sync=None):
        self.cameras = {c.name: c for c in cameras}
        self.times = [float(t) for t in times]
        self.folder, self.videos, self.sync = folder, videos, sync
        self.used = {}

    def frames(self, name: str) -> list[np.ndarray]:
        import cv2

        cam = self.cameras[name]
        if self.videos:
            from . import video

            if name not in self.sync:
                raise ClothFitError(f"sync: no time for camera '{name}'")
            frames, rep = video.camera_frames(self.videos, cam, self.sync[name], self.times)
            self.used[name] = rep["video"]
            return [cv2.cvtColor(f, cv2.COLOR_BGR2GRAY) for f in frames]
        from .extract import list_camera_images

        _, paths = list_camera_images(os.path.join(self.folder, name))
        if len(paths) != len(self.times):
            raise ClothFitError(
                f"camera '{name}': {len(paths)} frames in {os.path.join(self.folder, name)} but "
                f"{len(self.times)} frame times"
            )
        out = []
        for p in paths:
            if os.path.getsize(p) == 0:
                raise ClothFitError(f"image {p} is an empty (zero-byte) file")
            img = cv2.imread(p, cv2.IMREAD_GRAYSCALE)
            if img is None:
                raise ClothFitError(f"image {p} is unreadable (not an image, corrupt or truncated)")
            if img.shape[:2] != (cam.height, cam.width):
                raise ClothFitError(
                    f"image {p} is {img.shape[0]}x{img.shape[1]} (HxW) but camera '{name}' images "
                    f"{cam.height}x{cam.width}"
                )
            out.append(img)
        self.used[name] = os.path.join(self.folder, name)
        return out


# ================================================================== the whole job


def measure_handles(
    cameras: Iterable[Camera],
    source: FootageSource,
    marks: Sequence[HandleMarks],
    cloth_size: Iterable[float],
    grid_n: int | None = None,
    grid_nx: int | None = None,
    grid_ny: int | None = None,
    options: HandleOptions | None = None,
    progress: Callable[[int, int, str], object] | None = None,
) -> dict[str, Any]:
    """Triangulate, track, find releases, place the cloth: returns ``{"scenario": Scenario, "uncertain":
    Uncertainty, "report": dict}``. ``marks``: HandleMarks list (``parse_marks``); ``cloth_size``
    ``(width, height)`` [m]."""
    opts = (options or HandleOptions()).check()
    width, height = check_size(cloth_size)
    nx, ny = grid_resolution(width, height, grid_n, grid_nx, grid_ny, [h.at for h in marks])
    times = np.asarray(source.times, dtype=np.float64)
    F = times.size
    if F < 1:
        raise ClothFitError("no frames")
    if np.any(np.diff(times) <= 0):
        raise ClothFitError(f"frame times must increase, got {times.tolist()[:8]}...")
    cams = [c for c in cameras if any(c.name in h.marks for h in marks)]
    warnings = []
    tri0s = _triangulate_marks(cams, marks, opts)
    tracks = _track_cameras(cams, source, marks, tri0s, opts, progress)
    rows, keys, rel_info = [], [], []
    for k, h in enumerate(marks):
        row, key, rel = _measure_handle(k, h, cams, tracks, tri0s, times, opts, warnings)
        rows.append(row)
        keys.append(key)
        rel_info.append(rel)
    # ---------------------------------------------------------------- the cloth
    place, vertices = assign_vertices(marks, keys, width, height, nx, ny, rows, opts, warnings)
    grid = place.grid
    # ---------------------------------------------------------------- scenario
    handles = []
    for k in range(len(marks)):
        kt, kx = keys[k]
        rel = rel_info[k]
        handles.append(Handle(vertices[k], kt, kx, rel.release_time if rel is not None else None))
    scen = Scenario(grid, handles, times, opts.settle_time)
    bounds = []
    for k, row in enumerate(rows):
        u = D.HANDLE_BOUND_K * row["sd_mm"] / 1000.0
        if u > MAX_HANDLE_OFFSET_M:
            raise ClothFitError(
                f"handle '{marks[k].name}': its position is uncertain by {u * 1000:.0f} mm ({D.HANDLE_BOUND_K:g} sigma), "
                f"more than the {MAX_HANDLE_OFFSET_M * 1000:g} mm a capture may declare: mark it in "
                f"cameras seeing it from more different directions"
            )
        b = D.HANDLE_FIT_BOX_M  # the fit's box (defaults: wider ones overfit the clips)
        bounds.append(round(b, 6))
        row["uncertain_mm"] = u * 1000.0  # what the triangulation leaves (3 sigma)
        row["fit_box_mm"] = b * 1000.0
    rels = [r for r in rel_info if r is not None]
    period = float(np.median(np.diff(times))) if F > 1 else 0.0
    t_off = period if rels else 0.0  # the release frame is exact: the instant is within its frame interval
    unc = Uncertainty.parse({"time_offset": round(t_off, 6), "handles": bounds}, len(handles), "handles")
    report = {
        "cloth": {
            "width": width,
            "height": height,
            "nx": nx,
            "ny": ny,
            "spacing_mm": 1000.0 * grid.spacing,
            "spacing_y_mm": 1000.0 * grid.side_y / (ny - 1),
            "origin": grid.origin.tolist(),
            "rotation": grid.rotation.tolist(),
            "normal": grid.R[:, 2].tolist(),
            "placement": place.method,
            "placement_residual_mm": {
                marks[k].name: float(r) * 1000.0 for k, r in zip(place.with_at, place.residuals_m)
            },
            "placement_rms_mm": float(1000.0 * np.sqrt(np.mean(place.residuals_m**2))),
        },
        "frames": F,
        "frame_period_s": period,
        "cameras": [c.name for c in cams],
        "handles": rows,
        "uncertain": unc.to_dict(),
        "uncertain_rule": (
            f"handles: {D.HANDLE_FIT_BOX_M * 1000:g} mm each (the fit's box: wider ones let it bend the "
            f"clips to what the cloth model cannot draw; docs/phone_rig.md), whatever the triangulation "
            f"leaves ({D.HANDLE_BOUND_K:g} x the largest standard deviation of the triangulated pin, pixel "
            f"noise = the residual's estimate, at least {opts.mark_sigma:g} px: uncertain_mm); an offset "
            f"against its box is reported by the fit; time_offset: one frame period when a "
            f"handle is released (its release time lies in the release frame's interval), else "
            f"0 (the handles are measured on the frames' own clock)"
        ),
        "warnings": warnings,
    }
    return {"scenario": scen, "uncertain": unc, "report": report}


def _triangulate_marks(cams, marks, opts: HandleOptions) -> list:
    """Each handle's marks in 3-D (``Triangulation``), or a one-line error when they do not meet."""
    tri0s = []
    for h in marks:
        mc = [c for c in cams if c.name in h.marks]
        tri0 = triangulate(mc, [h.marks[c.name] for c in mc], opts.mark_sigma)
        worst = int(np.argmax(tri0.residuals))
        if tri0.residuals[worst] > opts.max_residual:
            raise ClothFitError(
                f"handle '{h.name}': its marks do not meet in 3-D (camera {mc[worst].name} misses "
                f"by {tri0.residuals[worst]:.1f} px at frame {h.frame}): a mark on another point, or "
                f"the wrong calibration"
            )
        tri0s.append(tri0)
    return tri0s


def _track_cameras(cams, source: FootageSource, marks, tri0s, opts: HandleOptions, progress=None) -> list:
    """Every marked handle tracked through every frame of every camera that marked it (``CameraTrack``)."""
    tracks = []
    for i, cam in enumerate(cams):
        if progress:
            progress(i, len(cams), f"tracking in {cam.name}")
        frames = source.frames(cam.name)
        mk = [
            (
                h.frame,
                h.marks[cam.name],
                window_for(
                    h.size or opts.clip_size, float(cam.to_camera(tri0s[k].X)[2]), 0.5 * (cam.K[0, 0] + cam.K[1, 1])
                ),
            )
            if cam.name in h.marks
            else None
            for k, h in enumerate(marks)
        ]
        tracks.append(track_camera(cam.name, frames, mk, opts))
        del frames
    if progress:
        progress(len(cams), len(cams), "triangulating")
    return tracks


def _measure_handle(k, h, cams, tracks, tri0s, times, opts: HandleOptions, warnings: list):
    """Handle ``k``'s 3-D track, release and motion: ``(report row, (key times, key positions), Release
    or None)``; warnings appended to ``warnings``."""
    F = times.size
    tri0 = tri0s[k]
    marked_cams = [c.name for c in cams if c.name in h.marks]
    traj = triangulate_track(cams, tracks, k, opts)
    for cn, f, r in traj.dropped:
        warnings.append(
            f"handle '{h.name}': camera {cn} dropped from frame {f} on (its track misses the others' "
            f"point by {r:.1f} px)"
        )
    ok = np.all(np.isfinite(traj.X), axis=1)
    rel = None
    if h.released:
        rel = detect_release(times, traj.X, h.frame, opts, h.name)
        need = range(0, min(F, rel.departure_frame + 1))
    else:
        need = range(0, F)
    missing = [f for f in need if not ok[f]]
    if missing:
        f = missing[0]
        raise ClothFitError(
            f"handle '{h.name}': no 3-D point at frame {f} (t = {times[f]:g} s): "
            f"{traj.problems.get(f, 'fewer than 2 cameras')}"
        )
    track_len = {tr.name: int(np.sum(np.all(np.isfinite(tr.points[:, k]), axis=1))) for tr in tracks if k in tr.marked}
    row = {
        "name": h.name,
        "motion": h.motion,
        "released": h.released,
        "marked_frame": h.frame,
        "cameras": marked_cams,
        "residual_px": {cn: float(r) for cn, r in zip(marked_cams, tri0.residuals)},
        "residual_rms_px": tri0.rms,
        "residual_mm": {cn: float(r) for cn, r in zip(marked_cams, tri0.residuals_mm)},
        "residual_rms_mm": float(np.sqrt(np.mean(tri0.residuals_mm**2))),
        "sd_mm": 1000.0 * tri0.sd_max,
        "sigma_px": tri0.sigma,
        "marked_position": tri0.X.tolist(),
        "track_frames": track_len,
        "tracked_3d_frames": int(ok.sum()),
        "track_rms_px": float(np.nanmean(traj.rms_px)) if ok.any() else None,
    }
    if rel is not None:
        row.update(
            departure_frame=rel.departure_frame,
            release_frame=rel.release_frame,
            release_time=rel.release_time,
            release_extrapolated_time=rel.extrapolated_time,
            release_before_departure=rel.back,
            release_threshold_mm=rel.threshold_m * 1000.0,
            held_jitter_mm=rel.held_jitter_m * 1000.0,
        )
    if h.motion == "moving":
        end = rel.departure_frame if rel is not None else F
        sm = smooth_track(times[:end], traj.X[:end], opts.smooth)
        key_t, key_x = times[:end], sm
        row["travel_mm"] = float(1000.0 * np.max(np.linalg.norm(sm - sm[0], axis=1)))
    else:
        held = np.nonzero(ok[: (rel.departure_frame if rel is not None else F)])[0]
        pos = rel.pin if rel is not None else np.mean(traj.X[held], axis=0)
        key_t, key_x = times[:1], pos[None]
        dist = np.linalg.norm(traj.X[held] - pos, axis=1)
        drift = float(dist.max())
        row["drift_mm"] = 1000.0 * drift
        # the tracking jitter from second differences (a smooth motion hardly has any, noise has sqrt(6) sigma)
        d2 = np.linalg.norm(np.diff(traj.X[held], 2, axis=0), axis=1) if held.size > 2 else np.zeros(1)
        thr = max(opts.departure_min, opts.departure_k * float(np.median(d2)) / math.sqrt(6.0))
        if not h.released and drift > thr:
            fmax = int(held[np.argmax(dist)])
            warnings.append(
                f"handle '{h.name}' is declared fixed but moves {drift * 1000:.1f} mm from its mean "
                f'position (frame {fmax}): declare it "motion": "moving"?'
            )
    return row, (key_t, key_x), rel


def write_scenario(path: str, result: dict[str, Any], inputs: Iterable[str | None] = ()) -> dict[str, Any]:
    """The scenario file ``clothfit extract --scenario`` reads: ``{"format", "version", "scenario",
    "uncertain", "report"}``, written atomically; refuses to overwrite one of ``inputs``."""
    from ..jsonio import write_json

    real = os.path.realpath(path)
    for p in inputs:
        if p and os.path.exists(p) and os.path.realpath(p) == real:
            raise ClothFitError(f"handles: writing {path} would overwrite its input {p}: choose another --out")
    if os.path.isdir(path):
        raise ClothFitError(f"handles: --out {path} is a directory: give a file name")
    d = {
        "format": FORMAT,
        "version": 1,
        "scenario": result["scenario"].to_dict(),
        "uncertain": result["uncertain"].to_dict(),
        "report": result["report"],
    }
    write_json(path, d)
    return d


# ====================================================================== inputs


def check_size(size: Iterable[float]) -> tuple[float, float]:
    """(width, height) [m] of the cloth, checked."""
    try:
        w, h = (float(v) for v in size)
    except (TypeError, ValueError):
        raise ClothFitError(f"cloth size {size!r} must be two lengths: width and height in metres") from None
    for nm, v in (("width", w), ("height", h)):
        if not (math.isfinite(v) and 0 < v <= 100):
            raise ClothFitError(f"cloth {nm} {v:g} m must be a positive length in metres (at most 100)")
    return w, h


def frame_times_for(
    count: int | None = None,
    times: Iterable[float] | None = None,
    fps: float | None = None,
    start: float = 0.0,
    what: str = "footage",
) -> list[float]:
    """The capture times: ``times`` as given, else ``count`` frames at ``fps`` from ``start``."""
    if times is not None:
        t = [float(x) for x in times]
        if not t:
            raise ClothFitError(f"{what}: no frame times")
        return t
    if fps is None:
        raise ClothFitError(f"{what}: no frame times: give --times, or --fps (and for videos --frames)")
    if not (finite_number(fps) and fps > 0):
        raise ClothFitError(f"--fps {fps!r} must be a positive number of frames per second")
    if count is None or count < 1:
        raise ClothFitError(f"{what}: the number of frames is unknown: give --frames")
    return [float(start) + i / float(fps) for i in range(int(count))]


def run(
    out: str,
    marks: str,
    size: Iterable[float],
    footage: str | None = None,
    videos: str | None = None,
    sync: str | None = None,
    find_sync: bool = False,
    flash_time: float = 0.0,
    cameras: str | Iterable[Camera] | None = None,
    times: Sequence[float] | None = None,
    fps: float | None = None,
    start: float = 0.0,
    frames: int | None = None,
    grid: int | tuple[int, int] | list[int] | None = None,
    options: HandleOptions | None = None,
    progress: Callable[[int, int, str], object] | None = None,
) -> dict[str, Any]:
    """``clothfit handles``: read the inputs, measure, write ``out`` (``write_scenario``); returns the
    written document. ``footage``: image folders per camera (``extract``'s layout, ``footage.json``
    optional) or ``videos`` + ``sync`` (a sync JSON path, or ``find_sync`` for a flash); ``cameras``:
    a calibration path (default: the footage's); ``times`` / ``fps`` (+ ``start``, ``frames``): the
    capture times (default: ``footage.json``'s); ``size`` (width, height) [m]; ``grid``: None, N (along
    the longer side) or (nx, ny)."""
    from . import calib_io, video
    from .extract import find_calibration, list_camera_images, read_footage_json

    opts = (options or HandleOptions()).check()
    inputs = [marks]
    if videos and footage:
        raise ClothFitError(f"handles: a footage folder ({footage}) and --videos exclude each other")
    if not videos and not footage:
        raise ClothFitError("handles: give a footage folder (image folders per camera) or --videos DIR")
    meta = {}
    if footage:
        if not os.path.isdir(footage):
            raise ClothFitError(f"footage folder not found: {footage}")
        meta, meta_path = read_footage_json(footage)
        inputs.append(meta_path)
        if cameras is None:
            cameras = meta.get("cameras")
            cameras = os.path.join(footage, cameras) if isinstance(cameras, str) else find_calibration(footage)
    if cameras is None:
        raise ClothFitError(
            "handles: no calibration: give --cameras (or a footage folder with footage.json's "
            "'cameras', a cameras.* / calibration.* file or a COLMAP folder)"
        )
    if isinstance(cameras, str):
        inputs.append(cameras)
        sizes = video.video_sizes(videos) if videos and calib_io.detect_format(cameras) == "easymocap" else None
        cams = calib_io.import_cameras(cameras, sizes=sizes)
    else:
        cams = list(cameras)
    if footage:
        if times is None and fps is None and meta.get("frame_times") is not None:
            times = meta["frame_times"]
        if times is None:
            named = [c for c in cams if os.path.isdir(os.path.join(footage, c.name))]
            count = len(list_camera_images(os.path.join(footage, named[0].name))[1]) if named else None
            times = frame_times_for(count, None, fps, start, f"footage {footage}")
        else:
            times = frame_times_for(None, times, None, 0.0, f"footage {footage}")
    else:
        times = frame_times_for(frames, times, fps, start, f"videos {videos}")
    t = np.asarray(times, dtype=np.float64)
    if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        raise ClothFitError(f"frame times must be finite and strictly increasing, got {times[:6]}...")
    width, height = check_size(size)
    hmarks = read_marks(marks, cams, len(times), (width, height))
    sync_times = None
    if videos:
        names = sorted({n for h in hmarks for n in h.marks})
        if find_sync:
            sync_times = video.flash_sync(videos, names, flash_time, sync)
        elif sync:
            inputs.append(sync)
            sync_times = video.read_sync(sync, names)
        else:
            raise ClothFitError("handles --videos needs --sync SYNC.json (or --find-sync flash)")
    if os.path.isdir(out):
        raise ClothFitError(f"handles: --out {out} is a directory: give a file name")
    for p in inputs:
        if p and os.path.exists(p) and os.path.realpath(p) == os.path.realpath(out):
            raise ClothFitError(f"handles: writing {out} would overwrite its input {p}: choose another --out")
    gkw = {}
    if isinstance(grid, (tuple, list)):
        gkw = {"grid_nx": grid[0], "grid_ny": grid[1]}
    elif grid is not None:
        gkw = {"grid_n": grid}
    src = FootageSource(cams, times, folder=footage, videos=videos, sync=sync_times)
    result = measure_handles(cams, src, hmarks, (width, height), options=opts, progress=progress, **gkw)
    rep = result["report"]
    rep.update(
        {
            "marks": os.path.abspath(marks),
            "footage": os.path.abspath(footage) if footage else None,
            "videos": os.path.abspath(videos) if videos else None,
            "sync": sync_times,
            "calibration": os.path.abspath(cameras) if isinstance(cameras, str) else None,
            "media": src.used,
        }
    )
    return write_scenario(out, result, inputs)


def format_report(rep: dict) -> str:
    """A table for people: one line per handle."""
    c = rep["cloth"]
    lines = [
        f"cloth {c['width']:g} x {c['height']:g} m as {c['nx']} x {c['ny']} vertices "
        f"({c['spacing_mm']:.1f} x {c['spacing_y_mm']:.1f} mm cells); placement: {c['placement']}; "
        f"its residual {c['placement_rms_mm']:.2f} mm RMS",
        f"{'handle':<14} {'vertex':>11} {'res px':>7} {'res mm':>7} {'sd mm':>6} {'3sd mm':>7} {'box mm':>6} {'track':>6} "
        f"{'release':>16}",
    ]
    for h in rep["handles"]:
        rel = (
            f"frame {h['release_frame']} ({h['release_time']:.4f} s)"
            if h.get("released")
            else ("moving" if h["motion"] == "moving" else "fixed")
        )
        lines.append(
            f"{h['name'][:14]:<14} {'r' + str(h['row']) + ' c' + str(h['column']):>11} {h['residual_rms_px']:7.2f} "
            f"{h['residual_rms_mm']:7.2f} {h['sd_mm']:6.2f} {h['uncertain_mm']:7.2f} {h['fit_box_mm']:6.2f} "
            f"{h['tracked_3d_frames']:>6} {rel:>16}"
        )
    lines.append(f"uncertain: {rep['uncertain']}")
    for w in rep.get("warnings", []):
        lines.append("warning: " + w)
    return "\n".join(lines)
