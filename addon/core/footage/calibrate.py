"""Multi-camera calibration from a ChArUco board (``clothfit calibrate``), no Blender.

Input: a folder with one folder of images per camera (``FOLDER/<camera>/<moment>.<png|jpg|...>``;
the same file name in two cameras is the same moment), or one video per camera
(``FOLDER/<camera>.<mp4|mov|mkv|avi>``, sampled at common capture times through the videos' sync,
see ``video.py``).

The steps, each its own function (the board: ``calib_board.py``; detection: ``calib_detect.py``;
the first estimates: ``calib_intrinsics.py``; the bundle adjustment: ``calib_bundle.py``; the
world frame: ``calib_world.py``; this module runs them):

1. :func:`parse_board`: the board (``SQUARES_X,SQUARES_Y,SQUARE_M,MARKER_M,DICTIONARY``, OpenCV's
   ``CharucoBoard`` layout) checked;
2. :func:`detect_views`: ChArUco corners per image (``cv2.aruco.CharucoDetector``), a view kept
   when it has at least ``CALIB_MIN_CORNERS`` corners, not all on one line, and is not blurred
   (:func:`sharpness`: below ``CALIB_BLUR_RATIO`` x the camera's median sharpness = blurred);
3. :func:`initial_intrinsics`: per camera ``cv2.calibrateCamera`` on its own views (or the
   intrinsics given in a file, then the board poses by ``cv2.solvePnP``);
4. :func:`initial_extrinsics`: the cameras joined through the moments they share: relative poses
   averaged over the shared moments, along the spanning tree of most shared moments;
5. :func:`bundle_adjust`: every camera's intrinsics, distortion and pose and every moment's board
   pose refined jointly (``scipy.optimize.least_squares``, a sparse Jacobian, a robust loss), then
   corners and views far off their fit dropped and refined again;
6. :func:`world_frame`: the world is the board at the world moment (default: the first moment,
   by natural order of the names): origin at the centre of its chessboard, X along its squares_x
   direction, Y towards the top edge of the print, Z up out of the printed face, metres. Up is that
   board's normal unless a level board (``level``) or a gravity vector measured in one camera's
   frame (``gravity``) says otherwise; then Z is turned to up and X kept as close as possible to
   the board's X (its horizontal projection).

:func:`calibrate_folder` runs them all and returns the cameras and a report (per camera the
reprojection RMS, the views used and every view's RMS). Bad input is one ClothFitError line; this
module writes only what the caller asks, through :func:`write_outputs`, after everything
succeeded.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from .. import defaults as D
from ..errors import ClothFitError
from ..observation.camera import Camera

# calibrate.X names that addon/cli.py, tests/test_calibrate.py and lab/phone_rig.py use
from .calib_board import Board, make_board, natural_key, parse_board  # noqa: E402,F401
from .calib_bundle import bundle_adjust, camera_uncertainty
from .calib_detect import (
    Detections,
    Detector,  # noqa: E402,F401
    View,
    check_detections,
    detect_views,
    find_source,
    video_times,
)
from .calib_intrinsics import (  # noqa: E402,F401
    DIST_ORDER,
    DISTORTION_MODELS,
    Options,
    components,
    initial_extrinsics,
    initial_intrinsics,
    rotation_angle_deg,
)
from .calib_world import world_frame

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

    from .calib_detect import Source

# ========================================================================== the run


@dataclass
class Result:
    cameras: list  # Camera objects (world frame)
    report: dict
    board_poses: dict = field(default_factory=dict)  # {moment: (R, t)} board -> world


def calibrate_views(board: Board, det: Detections, opts: Options, log: Callable[[str], object] | None = None) -> Result:
    """Calibrate from detected views (see the module text); ``log(text)`` for progress messages."""
    opts.check()
    say = log or (lambda s: None)
    views = {c: dict(sorted(v.items(), key=lambda kv: natural_key(kv[0]))) for c, v in det.views.items()}
    if opts.shared and not [c for c in views if c not in opts.fixed]:
        opts.shared = False
    # too few views: per camera (estimated intrinsics), per group for shared intrinsics, 1 for fixed
    few = []
    for c, v in views.items():
        need = 1 if c in opts.fixed else opts.min_views
        if opts.shared and c not in opts.fixed:
            need = 1
        if len(v) < need:
            few.append((c, len(v), need))
    if opts.shared:
        total = sum(len(v) for c, v in views.items() if c not in opts.fixed)
        if total < opts.min_views:
            few.append(("(shared intrinsics)", total, opts.min_views))
    if few:
        c, n, need = few[0]
        st = det.stats.get(c, {})
        why = f"; of its {st.get('frames', 0)} frames, {st.get('found', 0)} show the board" if st else ""
        dropped = ", ".join(
            f"{st[k]} {k.replace('_', ' ')}" for k in ("few_corners", "collinear", "blurred") if st.get(k)
        )
        raise ClothFitError(
            f"camera '{c}' sees the board in {n} usable view(s), at least {need} needed{why}"
            f"{' (dropped: ' + dropped + ')' if dropped else ''}"
            f"{'; other cameras short too: ' + ', '.join(f[0] for f in few[1:]) if len(few) > 1 else ''}"
        )
    intr, poses = initial_intrinsics(board, views, det.sizes, opts)
    for c in views:  # views whose pose failed (solvePnP) are dropped
        views[c] = {m: v for m, v in views[c].items() if m in poses.get(c, {})}
    ref, cam_pose, board_pose = initial_extrinsics(poses)
    say(f"initial estimate: reference camera {ref}, {len(board_pose)} moments")
    dropped_views = []
    rejected = 0
    for rnd in range(D.CALIB_ROUNDS):
        intr, cam_pose, board_pose, resid, prob, status = bundle_adjust(
            board, views, intr, ref, cam_pose, board_pose, opts
        )
        err = np.linalg.norm(resid, axis=1)
        say(
            f"bundle adjustment round {rnd + 1}: RMS {math.sqrt(np.mean(err**2)):.3f} px over {err.size} corners "
            f"({status.nfev} evaluations)"
        )
        if rnd == D.CALIB_ROUNDS - 1:
            break
        views, n_rej, n_drop = _drop_outliers(views, prob, err, opts, dropped_views)
        rejected += n_rej
        if not n_rej and not n_drop:
            break
        board_pose = {m: p for m, p in board_pose.items() if any(m in views[c] for c in views)}
        _components_check(views, "after dropping the views far off the joint fit, ")
    # world frame
    moments = prob.moments
    world = opts.world
    if world is None:
        # the world is the board flat on the table at the first moment filmed: never silently another one
        world = det.moments[0] if det.moments else moments[0]
        if world not in board_pose:
            seen = [c for c in views if world in det.views.get(c, {})]
            raise ClothFitError(
                f"the board at the first moment {world} (the world frame: the board flat on the "
                f"table) is in no usable view{' (its views were dropped: ' + ', '.join(seen) + ')' if seen else ''}"
                f": retake it where every phone sees it, or give --world MOMENT of another flat view"
            )
    R_w, t_w, frame = world_frame(board, cam_pose, board_pose, world, opts)
    cams_out = []
    for c in prob.cams:
        Rc, tc = cam_pose[c]
        R = Rc @ R_w.T
        t = tc - R @ t_w
        w, h = det.sizes[c]
        it = intr[c]
        dist = it.dist[: len(DIST_ORDER)].copy()
        cams_out.append(Camera(it.K, _orthonormal(R), t, w, h, name=c, dist=dist))
    board_world = {}
    for m, (Rb, tb) in board_pose.items():  # board -> world
        board_world[m] = (R_w @ Rb, R_w @ tb + t_w)
    report = _report(board, det, views, prob, resid, cams_out, frame, dropped_views, rejected, opts, status)
    # what the views leave loose, per camera (first order, the last adjustment's covariance)
    for row, unc in zip(report["cameras"], camera_uncertainty(prob, status, prob.moments.index(world), board)):
        row.update(unc)
    return Result(cams_out, report, board_world)


def _components_check(views, prefix=""):
    cams = list(views)
    edges = [(a, b) for i, a in enumerate(cams) for b in cams[i + 1 :] if set(views[a]) & set(views[b])]
    groups = components(cams, edges)
    if len(groups) > 1:
        raise ClothFitError(
            f"{prefix}the cameras are not connected by shared views: "
            + "; ".join("{" + ", ".join(g) + "}" for g in groups)
        )


def _view_errors(views, prob, err):
    """(camera, moment, View, its corners' errors) in the order of the problem's observations."""
    k = 0
    for c in prob.cams:
        for m, v in views[c].items():
            yield c, m, v, err[k : k + v.ids.size]
            k += v.ids.size


def _drop_outliers(views, prob, err, opts: Options, dropped_views: list):
    """Corners further than max(outlier_px, CALIB_OUTLIER_SIGMAS robust sigmas) from the fit are
    dropped; a view left with fewer than min_corners is dropped whole, unless its camera would fall
    below its minimum of views. Returns (views, corners dropped, views dropped)."""
    thr = max(opts.outlier_px, D.CALIB_OUTLIER_SIGMAS * 1.4826 * float(np.median(err)))
    out = {c: {} for c in views}
    n_rej, gone = 0, []
    for c, m, v, e in _view_errors(views, prob, err):
        keep = e <= thr
        if keep.sum() < opts.min_corners:
            gone.append(
                {
                    "camera": c,
                    "moment": m,
                    "rms_px": float(np.sqrt(np.mean(e**2))),
                    "why": f"fewer than {opts.min_corners} corners within {thr:.2f} px of the joint fit",
                }
            )
            continue
        n_rej += int((~keep).sum())
        out[c][m] = v if keep.all() else View(c, m, v.ids[keep], v.points[keep], v.markers, v.sharpness)
    for c in views:
        need = 1 if (c in opts.fixed or opts.shared) else opts.min_views
        if len(out[c]) < need:  # never below the minimum: that camera keeps every view
            out[c] = dict(views[c])
            gone = [g for g in gone if g["camera"] != c]
    dropped_views += gone
    return out, n_rej, len(gone)


def _orthonormal(R):
    U, _, Vt = np.linalg.svd(R)
    return U @ Vt


def _report(board, det, views, prob, resid, cams_out, frame, dropped_views, rejected, opts, status) -> dict:
    err = np.linalg.norm(resid, axis=1)
    cams = []
    k = 0
    per_view = {}
    for c in prob.cams:
        for m, v in views[c].items():
            e = err[k : k + v.ids.size]
            k += v.ids.size
            per_view.setdefault(c, {})[m] = {"rms_px": float(np.sqrt(np.mean(e**2))), "corners": int(v.ids.size)}
    for ci, (c, cam) in enumerate(zip(prob.cams, cams_out)):
        e = err[prob.obs_cam == ci]
        shared = sorted({m for m in views[c] if sum(m in views[o] for o in views) > 1}, key=natural_key)
        cams.append(
            {
                "name": c,
                "width": cam.width,
                "height": cam.height,
                "rms_px": float(np.sqrt(np.mean(e**2))),
                "max_px": float(e.max()),
                "views_used": len(views[c]),
                "views_shared": len(shared),
                "corners": int(e.size),
                "fx": float(cam.K[0, 0]),
                "fy": float(cam.K[1, 1]),
                "cx": float(cam.K[0, 2]),
                "cy": float(cam.K[1, 2]),
                "dist": cam.dist.tolist(),
                "centre_m": cam.center.tolist(),
                "intrinsics": "fixed" if c in opts.fixed else ("shared" if opts.shared else "estimated"),
                "frames": det.stats.get(c, {}),
                "views": per_view.get(c, {}),
            }
        )
    return {
        "board": board.to_dict(),
        "rms_px": float(np.sqrt(np.mean(err**2))),
        "corners": int(err.size),
        "moments": len(prob.moments),
        "cameras": cams,
        "world": frame,
        "options": {
            "distortion": opts.distortion,
            "square_pixels": opts.square_pixels,
            "shared": opts.shared,
            "fixed": sorted(opts.fixed),
            "min_views": opts.min_views,
            "min_corners": opts.min_corners,
            "blur_ratio": opts.blur_ratio,
            "loss": opts.loss,
            "loss_scale_px": opts.loss_scale_px,
            "outlier_px": opts.outlier_px,
        },
        "rejected_corners": rejected,
        "dropped_views": dropped_views,
        "optimizer": {"nfev": int(status.nfev), "status": int(status.status), "message": str(status.message)},
    }


# ====================================================================== whole command


def calibrate_folder(
    folder: str,
    board: Board,
    opts: Options,
    sync: dict[str, float] | None = None,
    every: float | None = None,
    times: Sequence[float] | None = None,
    debug_dir: str | None = None,
    log: Callable[[str], object] | None = None,
) -> tuple[Result, Detections, Source]:
    """Detect and calibrate: (Result, Detections, Source). Videos need ``sync`` ({camera: video time
    at capture time 0}); they are sampled every ``every`` s (or at ``times``). ``debug_dir``: the
    detections drawn per camera and moment (see :func:`write_debug`), also when the calibration
    fails after the detection (that is when they are needed)."""
    opts.check()
    say = log or (lambda s: None)
    src = find_source(folder)
    t = None
    if src.kind == "videos":
        if sync is None:
            raise ClothFitError(
                f"calibration folder {folder} holds videos: give their sync (--sync FILE or --find-sync flash)"
            )
        missing = [c for c in src.cameras if c not in sync]
        if missing:
            raise ClothFitError(f"the sync has no time for camera(s) {', '.join(missing)}")
        t = video_times(src.videos, sync, D.CALIB_VIDEO_EVERY_S if every is None else every, times)
        say(f"{len(src.cameras)} videos, {len(t)} moments from {t[0]:.2f} to {t[-1]:.2f} s")
    else:
        say(f"{len(src.cameras)} cameras, {sum(len(v) for v in src.images.values())} images")
    unknown = [c for c in opts.fixed if c not in src.cameras]
    if unknown and not any(c in src.cameras for c in opts.fixed):
        raise ClothFitError(
            f"--intrinsics: none of its cameras ({', '.join(unknown[:5])}) is a camera of {folder} "
            f"({', '.join(src.cameras)})"
        )
    opts.fixed = {c: cam for c, cam in opts.fixed.items() if c in src.cameras}  # the others: another rig's
    det = detect_views(src, board, opts.min_corners, opts.blur_ratio, sync, t, keep_frames=bool(debug_dir))
    for c in src.cameras:
        st = det.stats[c]
        say(
            f"  {c}: {st['frames']} frames, board in {st['found']}, {st['views']} views kept"
            + "".join(f", {st[k]} {k.replace('_', ' ')}" for k in ("few_corners", "collinear", "blurred") if st[k])
        )
    result = None
    try:
        check_detections(det, board, src)
        if opts.world is not None:
            seen = {m for v in det.views.values() for m in v}
            if opts.world not in seen:
                raise ClothFitError(f"--world {opts.world}: no camera has a usable view of the board at that moment")
        result = calibrate_views(board, det, opts, log)
    finally:
        if debug_dir:
            n = write_debug(debug_dir, det, result, board)
            say(f"wrote {n} debug images under {debug_dir}")
    return result, det, src


def write_outputs(
    result: Result, out: str, export: str | None = None, fmt: str = "auto", report_path: str | None = None
) -> dict:
    """Write the cameras JSON (ours, with the calibration's summary), and optionally an export
    (``calib_io.export_cameras``) and the full report. Every destination is checked before the first
    file is written; each file is written atomically."""
    from ..jsonio import write_json
    from .calib_io import FORMATS, export_cameras

    dests = [p for p in (out, export, report_path) if p]
    real = [os.path.realpath(p) for p in dests]
    if len(set(real)) < len(real):
        raise ClothFitError(f"--out, --export and --report must be different files ({', '.join(dests)})")
    for p in (out, report_path):
        if p and os.path.isdir(p):
            raise ClothFitError(f"cannot write {p}: it is a directory")
    if export and fmt not in FORMATS:
        raise ClothFitError(f"--format {fmt!r}: one of {', '.join(FORMATS)}")
    summary = {k: result.report[k] for k in ("board", "rms_px", "world", "moments")}
    summary["cameras"] = {
        c["name"]: {"rms_px": c["rms_px"], "views_used": c["views_used"]} for c in result.report["cameras"]
    }
    from ..observation.camera import save_cameras

    save_cameras(out, result.cameras, extra={"calibration": summary})
    written = {"out": out}
    if export:
        export_cameras(result.cameras, export, fmt)
        written["export"] = export
    if report_path:
        write_json(report_path, result.report)
        written["report"] = report_path
    return written


def write_debug(folder: str, det: Detections, result: Result | None, board: Board) -> int:
    """Per camera and moment a JPEG: detected markers (blue), ChArUco corners (green) and, after a
    calibration, where the cameras reproject them (red crosses)."""
    import cv2

    from ..safeio import atomic_write

    P = board.corners()
    cams = {c.name: c for c in (result.cameras if result else [])}
    written = 0
    for (cam, moment), (jpg, _mids, mcorners) in det.debug_frames.items():
        grey = cv2.imdecode(np.frombuffer(jpg, np.uint8), cv2.IMREAD_GRAYSCALE)
        img = cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR)
        for c in mcorners or ():
            cv2.polylines(
                img, [np.round(np.asarray(c).reshape(-1, 2)).astype(np.int32)], True, (255, 128, 0), 1, cv2.LINE_AA
            )
        v = det.views.get(cam, {}).get(moment)
        if v is not None:
            for p in v.points:
                cv2.circle(img, (int(round(p[0])), int(round(p[1]))), 4, (0, 200, 0), 1, cv2.LINE_AA)
        if result is not None and cam in cams and moment in result.board_poses:
            Rb, tb = result.board_poses[moment]
            uv = cams[cam].project(P @ Rb.T + tb)
            for q in uv:
                if np.all(np.isfinite(q)):
                    x, y = int(round(q[0])), int(round(q[1]))
                    cv2.line(img, (x - 3, y), (x + 3, y), (0, 0, 255), 1)
                    cv2.line(img, (x, y - 3), (x, y + 3), (0, 0, 255), 1)
        text = "blue: markers, green: corners" + (", red: reprojected" if result is not None else "")
        if v is None:
            text = "board not used here: " + ("markers only" if mcorners else "nothing found")
        elif result is not None:
            info = next((c["views"].get(moment) for c in result.report["cameras"] if c["name"] == cam), None)
            if info:
                text += f", view RMS {info['rms_px']:.2f} px"
        cv2.putText(img, text, (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(img, text, (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
        ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 90])
        atomic_write(os.path.join(folder, cam, f"{moment}.jpg"), buf.tobytes())
        written += 1
    return written
