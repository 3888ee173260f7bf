"""Silhouettes from camera footage into a capture: the footage folder or the videos, per camera the
images handed to ``silhouette.py`` (background difference in YUV, automatic threshold, clean-up,
checks, debug images: the method is told there), every problem gathered, then the capture written.

Footage layout read by :func:`extract_capture`::

    footage/
      footage.json        optional: {"cameras": "cameras.yml", "frame_times": [...],
                                     "scenario": {...Scenario.to_dict()...}, "cloth_mass": 0.0025,
                                     "uncertain": {"time_offset": 0.02, "handles": 0.002}}
      cameras.yml         calibration in any format calib_io.import_cameras reads
      cam00/background.png      one or more plates: files named background* or bg*
      cam00/000.png ...         foreground frames, in natural sort order (= frame_times order)
      cam01/...

The capture's ``uncertain`` block (``docs/capture_format.md``) is the one given (``--uncertain``), else
the ``--scenario`` file's (``clothfit handles`` writes one beside its scenario), else footage.json's;
frames read from videos at their timestamps otherwise declare one frame period for the time offset
(the frame taken is the one on display, up to a frame before the asked time) and nothing for the handles.

Camera folders are matched to the cameras by name. Distorted cameras are kept with their
distortion (the fitter projects with it) unless ``undistort=True``, which undistorts the
silhouettes (``calib_io.undistort_silhouette``) and writes the cameras without distortion.
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Callable, Sequence
from dataclasses import asdict
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import ClothFitError
from ..jsonio import write_json
from ..observation.camera import check_camera_name
from .silhouette import (  # noqa: F401
    MIN_AUTO_THRESHOLD,
    THRESHOLD_MODES,
    CameraResult,
    ExtractOptions,
    as_float_image,
    bgr_to_yuv,
    camera_thresholds,
    clean_mask,
    difference,
    extract_camera,
    fill_holes,
    noise_threshold,
    otsu_threshold,
    read_image,
    refine_boundary,  # re-exported: the extraction's API in one place
)

if TYPE_CHECKING:
    from ..observation.camera import Camera
    from ..observation.capture import Capture
    from ..physics.scenario import Scenario, Uncertainty

IMAGE_EXTS = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".webp", ".exr")
BACKGROUND_PREFIXES = ("background", "bg")
FOOTAGE_JSON = "footage.json"
REPORT_JSON = "extract_report.json"
MAX_LISTED_ERRORS = 25


# ================================================================== footage folders


def _natural_key(s: str):
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", s)]


def footage_images(capture: Capture) -> Callable[[int, int], np.ndarray]:
    """For a capture extracted from image footage (``python -m clothfit extract``, not ``--videos``):
    a function ``(camera index, frame index) -> RGB uint8`` frame the silhouette was extracted from
    (``capture_overlays(images=...)`` draws on it). Raises ClothFitError if the capture names no
    image footage, or if its silhouettes were undistorted (they no longer match the frames)."""
    import cv2

    from ..jsonio import read_json

    footage = (capture.meta or {}).get("footage")
    if not footage or not os.path.isdir(footage):
        raise ClothFitError(f"{capture.root}: not extracted from image footage (no camera images to draw on)")
    rep_path = os.path.join(capture.root, REPORT_JSON)
    if os.path.isfile(rep_path) and read_json(rep_path, "extraction report").get("options", {}).get("undistort"):
        raise ClothFitError(
            f"{capture.root}: the silhouettes were undistorted, so they no longer match the "
            f"camera images; draw the overlays without them"
        )
    cache = {}

    def image(ci, fi):
        name = capture.cameras[ci].name
        if name not in cache:
            cache[name] = list_camera_images(os.path.join(footage, name))[1]
        frames = cache[name]
        if fi >= len(frames):
            raise ClothFitError(f"camera '{name}': no frame {fi} in {os.path.join(footage, name)}")
        img = cv2.imread(frames[fi], cv2.IMREAD_COLOR)
        if img is None:
            raise ClothFitError(f"camera image {frames[fi]} is unreadable")
        return np.ascontiguousarray(img[..., ::-1])

    return image


def list_camera_images(folder: str) -> tuple[list[str], list[str]]:
    """(background paths, frame paths) of a camera folder; backgrounds are files named
    ``background*`` or ``bg*`` (case-insensitive), frames are the other images, natural order."""
    if not os.path.isdir(folder):
        raise ClothFitError(f"camera folder not found: {folder}")
    files = sorted(
        (
            f
            for f in os.listdir(folder)
            if not f.startswith(".")
            and os.path.splitext(f)[1].lower() in IMAGE_EXTS
            and os.path.isfile(os.path.join(folder, f))
        ),
        key=_natural_key,
    )
    bgs = [os.path.join(folder, f) for f in files if f.lower().startswith(BACKGROUND_PREFIXES)]
    frames = [os.path.join(folder, f) for f in files if not f.lower().startswith(BACKGROUND_PREFIXES)]
    return bgs, frames


def read_footage_json(footage_dir: str) -> tuple[dict, str | None]:
    p = os.path.join(footage_dir, FOOTAGE_JSON)
    if not os.path.isfile(p):
        return {}, p
    try:
        with open(p, encoding="utf-8-sig") as f:
            d = json.load(f)
    except (OSError, json.JSONDecodeError) as e:
        raise ClothFitError(f"{p}: not valid JSON ({e})") from None
    if not isinstance(d, dict):
        raise ClothFitError(f"{p}: expected a JSON object")
    return d, p


def find_calibration(footage_dir: str) -> str | None:
    for f in sorted(os.listdir(footage_dir)):
        stem, ext = os.path.splitext(f)
        if stem.lower() in ("cameras", "calibration", "calib") and ext.lower() in (".json", ".yml", ".yaml", ".xml"):
            return os.path.join(footage_dir, f)
    for sub in ("colmap", "sparse", os.path.join("sparse", "0")):
        p = os.path.join(footage_dir, sub)
        if os.path.isfile(os.path.join(p, "cameras.txt")):
            return p
    return None


def _resolve_scenario(scenario, frame_times, where):
    return _resolve_scenario_uncertain(scenario, frame_times, where)[:2]


def _resolve_scenario_uncertain(scenario, frame_times, where):
    """(Scenario, note or None, the scenario file's ``uncertain`` block or None)."""
    from ..physics.scenario import Scenario, paper_scenario

    unc = None
    if scenario is None:
        return (
            paper_scenario(frame_times=frame_times),
            (
                "no scenario given: the paper's manipulation is assumed "
                "(10 cm 16x16 cloth, 4 corners held at z = 0.1 m, corner 0 "
                "released at t = 0)"
            ),
            None,
        )
    if isinstance(scenario, Scenario):
        return scenario.with_frames(frame_times), None, None
    if isinstance(scenario, str):
        if not os.path.isfile(scenario):
            raise ClothFitError(f"scenario file not found: {scenario}")
        try:
            with open(scenario, encoding="utf-8-sig") as f:
                d = json.load(f)
        except (OSError, json.JSONDecodeError) as e:
            raise ClothFitError(f"scenario file {scenario}: not valid JSON ({e})") from None
        if isinstance(d, dict) and isinstance(d.get("scenario"), dict):
            unc = d.get("uncertain")  # a `clothfit handles` file or a capture.json: its bounds
            d = d["scenario"]
        where = scenario
        scenario = d
    if not isinstance(scenario, dict):
        raise ClothFitError(f"{where}: scenario must be an object (Scenario.to_dict())")
    d = dict(scenario)
    d["frame_times"] = list(frame_times)
    return Scenario.from_dict(d, source=f"{where} scenario"), None, unc


def _uncertain_for(scen, explicit, from_scenario, from_footage, frame_period=None):
    """The capture's ``uncertain`` block and where it came from: ``explicit`` (an Uncertainty, a dict or
    ``--uncertain`` text), else the scenario file's, else footage.json's, else, for frames read from
    videos at their timestamps, one frame period for the time (a frame is the one on display at the asked
    time, up to a frame earlier, and a flash sync is good to a frame) and nothing for the handles."""
    from ..physics.scenario import Uncertainty

    n = len(scen.handles)
    if explicit is not None:
        if isinstance(explicit, Uncertainty):
            return explicit, "given"
        if isinstance(explicit, str):
            u = Uncertainty.from_text(explicit, n, "--uncertain")
            return (None if not u.active else u), "--uncertain"
        return Uncertainty.parse(explicit, n, "uncertain"), "given"
    for value, src in ((from_scenario, "the scenario file"), (from_footage, FOOTAGE_JSON)):
        if value is not None:
            return Uncertainty.parse(value, n, f"{src} uncertain"), src
    if frame_period:
        return Uncertainty(round(float(frame_period), 6), (0.0,) * n), "one frame period of the videos"
    return None, None


def extract_capture(
    footage_dir: str,
    out_dir: str,
    cameras: str | os.PathLike | list[Camera] | None = None,
    frame_times: Sequence[float] | None = None,
    scenario: Scenario | dict[str, Any] | str | os.PathLike | None = None,
    cloth_mass: float | None = None,
    options: ExtractOptions | None = None,
    camera_names: Sequence[str] | None = None,
    progress: Callable[[int, int, str], Any] | None = None,
    should_stop: Callable[[], bool] | None = None,
    uncertain: Uncertainty | dict[str, Any] | str | None = None,
    **option_overrides: Any,
) -> dict:
    """Extract every camera's silhouettes from a footage folder and write a capture.

    ``cameras``: a calibration path (anything ``calib_io.import_cameras`` reads) or a list of
    Camera; default: ``footage.json``'s ``cameras`` or a ``cameras.*``/``calibration.*`` file or a
    COLMAP folder in ``footage_dir``. ``frame_times``: the capture times (default:
    ``footage.json``). ``scenario``: a Scenario, its dict, or a path to a JSON holding one (a
    capture.json works); default ``footage.json``'s, else the paper's scenario (with a warning).
    ``cloth_mass`` [kg]: default ``footage.json``'s. ``camera_names``: extract only these.
    ``uncertain``: the capture's ``uncertain`` block (an Uncertainty, its dict or ``--uncertain`` text);
    default: the scenario file's (``clothfit handles`` writes one), else ``footage.json``'s, else none.
    ``options`` or keyword overrides of :class:`ExtractOptions` fields. ``progress(i, n, name)``
    is called per camera. ``should_stop()`` is asked before each camera: True stops there, and the
    capture holds the cameras done so far (``report["stopped"]``, a warning; before the first
    camera it is a ClothFitError, nothing written).
    Returns the report (also written to ``out_dir/extract_report.json``):
    per camera threshold and statistics, per frame area, all warnings.
    Raises one ClothFitError listing every bad file when anything is wrong; nothing is written then.
    """
    from . import calib_io

    opts = _options(options, option_overrides)
    if not os.path.isdir(footage_dir):
        raise ClothFitError(f"footage folder not found: {footage_dir}")
    meta, meta_path = read_footage_json(footage_dir)
    if cameras is None:
        cameras = _footage_calibration(footage_dir, meta, meta_path)
    inputs = [os.path.join(footage_dir, FOOTAGE_JSON)]
    if isinstance(cameras, str):
        inputs.append(cameras)
        cameras = calib_io.import_cameras(cameras)
    cameras = list(cameras)
    for c in cameras:  # names become folders (debug images, silhouettes): checked before any is used
        check_camera_name(c.name, "calibration")
    if isinstance(scenario, str):
        inputs.append(scenario)
    _refuse_overwriting(out_dir, inputs)
    cameras = _pick_cameras(cameras, camera_names)
    if frame_times is None:
        frame_times = meta.get("frame_times")
        if frame_times is None:
            raise ClothFitError(f"footage {footage_dir}: no frame times given (argument or {FOOTAGE_JSON})")
    try:
        frame_times = [float(t) for t in frame_times]
    except (TypeError, ValueError):
        raise ClothFitError(f"frame times must be numbers, got {frame_times!r}") from None
    if scenario is None and meta.get("scenario") is not None:
        scenario = meta["scenario"]
    scen, scen_note, scen_unc = _resolve_scenario_uncertain(scenario, frame_times, meta_path)
    unc, unc_src = _uncertain_for(scen, uncertain, scen_unc, meta.get("uncertain"))
    if cloth_mass is None:
        cloth_mass = meta.get("cloth_mass")

    errors, warnings = [], []
    if scen_note:
        warnings.append(scen_note)
    report = {
        "footage": os.path.abspath(footage_dir),
        "out": os.path.abspath(out_dir),
        "options": asdict(opts),
        "frame_times": frame_times,
        "cameras": {},
    }
    extra = _uncalibrated_folders(footage_dir, {c.name for c in cameras})
    if extra and not camera_names:
        warnings.append(f"folders with images that are not calibrated cameras were ignored: {', '.join(extra)}")
    all_masks = []
    out_cameras = []
    for ci, cam in enumerate(cameras):
        if _stop(should_stop, ci, len(cameras), report, warnings):
            break
        if progress:
            progress(ci, len(cameras), cam.name)
        got = _camera_images(cam, os.path.join(footage_dir, cam.name), frame_times, errors)
        if got is None:
            all_masks.append(None)
            continue
        bg_paths, bgs, frames, names = got
        masks, out_cam = _extract_one(cam, bgs, frames, names, opts, report, errors, warnings)
        report["cameras"][cam.name]["background_files"] = bg_paths
        all_masks.append(masks)
        out_cameras.append(out_cam)
    cap_meta = {"generator": "addon.core.extract", "footage": os.path.abspath(footage_dir)}
    if isinstance(meta.get("meta"), dict):
        cap_meta["footage_meta"] = meta["meta"]
    return _write_result(
        out_dir,
        footage_dir,
        out_cameras,
        scen,
        all_masks,
        cloth_mass,
        cap_meta,
        opts,
        report,
        errors,
        warnings,
        unc,
        unc_src,
    )


def _uncalibrated_folders(footage_dir, known) -> list:
    """The footage's sub-folders holding images that are not among the ``known`` camera names, sorted."""
    return sorted(
        d
        for d in os.listdir(footage_dir)
        if os.path.isdir(os.path.join(footage_dir, d))
        and d not in known
        and not d.startswith(".")
        and any(os.path.splitext(f)[1].lower() in IMAGE_EXTS for f in os.listdir(os.path.join(footage_dir, d)))
    )


def _options(options, overrides) -> ExtractOptions:
    """``options`` (default ExtractOptions()) with the keyword ``overrides`` that are not None, checked."""
    opts = options or ExtractOptions()
    for k, v in overrides.items():
        if not hasattr(opts, k):
            raise ClothFitError(f"unknown extraction option {k!r}")
        if v is not None:
            setattr(opts, k, v)
    opts.check()
    return opts


def _footage_calibration(footage_dir, meta, meta_path):
    """The calibration of a footage folder given no cameras: footage.json's, else a cameras.* /
    calibration.* file or a COLMAP folder in it."""
    cameras = meta.get("cameras")
    if isinstance(cameras, str):
        cameras = os.path.join(footage_dir, cameras)
    elif cameras is not None:
        raise ClothFitError(f"{meta_path}: 'cameras' must be a path relative to the footage folder")
    else:
        cameras = find_calibration(footage_dir)
    if cameras is None:
        raise ClothFitError(
            f"footage {footage_dir}: no cameras given and no {FOOTAGE_JSON}, cameras.* / "
            "calibration.* file or COLMAP folder found"
        )
    return cameras


def _pick_cameras(cameras, camera_names):
    """Only the cameras named (in that order); all of them when none is named."""
    if not camera_names:
        return cameras
    byname = {c.name: c for c in cameras}
    missing = [n for n in camera_names if n not in byname]
    if missing:
        raise ClothFitError(f"cameras {', '.join(missing)} are not in the calibration ({', '.join(byname)})")
    return [byname[n] for n in camera_names]


def _camera_images(cam, folder, frame_times, errors):
    """(background paths, backgrounds, frames, frame names) of one camera's folder, every image read and
    its size checked; None when anything is wrong (the problems go to ``errors``)."""
    if not os.path.isdir(folder):
        errors.append(f"camera '{cam.name}': folder {folder} not found")
        return None
    bg_paths, fr_paths = list_camera_images(folder)
    if not bg_paths:
        errors.append(
            f"camera '{cam.name}': no background image in {folder} (name it background.png; "
            f"files named background* or bg* are background plates)"
        )
    if len(fr_paths) != len(frame_times):
        errors.append(
            f"camera '{cam.name}': {len(fr_paths)} foreground images in {folder} but {len(frame_times)} frame times"
        )
    if not bg_paths or not fr_paths:
        return None
    bgs, frames, names, bad = [], [], [], False
    for p in bg_paths + fr_paths:
        try:
            img = read_image(p)
        except ClothFitError as e:
            errors.append(f"camera '{cam.name}': {e}")
            bad = True
            continue
        if img.shape[:2] != (cam.height, cam.width):
            errors.append(
                f"camera '{cam.name}': image {p} is {img.shape[0]}x{img.shape[1]} (HxW) but the "
                f"calibrated camera images {cam.height}x{cam.width}"
            )
            bad = True
            continue
        if p in bg_paths:
            bgs.append(img)
        else:
            frames.append(img)
            names.append(p)
    if bad or len(frames) != len(frame_times):
        return None
    return bg_paths, bgs, frames, names


def _stop(should_stop, ci, n, report, warnings) -> bool:
    """Asked before camera ``ci``: stop here? Then the capture holds cameras 0..ci-1 (none: an error,
    nothing written)."""
    if should_stop is None or not should_stop():
        return False
    if ci == 0:
        raise ClothFitError("extraction stopped before the first camera finished: nothing written")
    report["stopped"] = {"cameras_done": ci, "cameras": n}
    warnings.append(f"stopped after {ci} of {n} cameras: the capture holds only those")
    return True


def _extract_one(cam, bgs, frames, names, opts, report, errors, warnings):
    """Silhouettes of one camera from its loaded images (+ undistortion); problems go to ``errors``."""
    from . import calib_io

    res = extract_camera(bgs, frames, opts, cam.name, names, (cam.height, cam.width))
    report["cameras"][cam.name] = res.report
    errors.extend(res.errors)
    warnings.extend(res.warnings)
    masks = res.masks
    out_cam = cam
    if opts.undistort and cam.dist.size and np.any(cam.dist != 0) and not res.errors:
        maps = calib_io.undistort_maps(cam)
        masks = [calib_io.undistort_silhouette(m, cam, maps) for m in masks]
        out_cam = calib_io.undistorted_camera(cam)
    return masks, out_cam


def _write_result(
    out_dir,
    source,
    out_cameras,
    scen,
    all_masks,
    cloth_mass,
    cap_meta,
    opts,
    report,
    errors,
    warnings,
    uncertain=None,
    uncertain_source=None,
):
    """All cameras done: one error listing every problem (nothing written), else the capture + report."""
    from ..observation.capture import write_capture

    report["warnings"] = warnings
    if errors:
        listed = errors[:MAX_LISTED_ERRORS]
        more = f"\n  ... and {len(errors) - len(listed)} more" if len(errors) > len(listed) else ""
        raise ClothFitError(
            f"extraction from {source} failed, nothing written ({len(errors)} problem"
            f"{'s' if len(errors) > 1 else ''}):\n  " + "\n  ".join(listed) + more
        )
    cap_meta["extraction"] = {
        "options": {k: v for k, v in asdict(opts).items() if k != "debug_dir"},
        "thresholds": {n: r["threshold"] for n, r in report["cameras"].items()},
    }
    if "stopped" in report:
        cap_meta["extraction"]["stopped"] = report["stopped"]
    if uncertain is not None:
        report["uncertain"] = dict(uncertain.to_dict(), source=uncertain_source)
    write_capture(
        out_dir,
        out_cameras,
        scen,
        all_masks,
        cloth_mass=cloth_mass,
        meta=cap_meta,
        allow_empty=opts.allow_empty,
        uncertain=uncertain,
    )
    write_json(os.path.join(out_dir, REPORT_JSON), report)
    return report


def extract_videos(
    videos_dir: str,
    plates_dir: str,
    sync: str | os.PathLike | dict[str, float],
    out_dir: str,
    cameras: str | os.PathLike | list[Camera],
    frame_times: Sequence[float],
    scenario: Scenario | dict[str, Any] | str | os.PathLike | None = None,
    cloth_mass: float | None = None,
    options: ExtractOptions | None = None,
    camera_names: Sequence[str] | None = None,
    progress: Callable[[int, int, str], Any] | None = None,
    should_stop: Callable[[], bool] | None = None,
    uncertain: Uncertainty | dict[str, Any] | str | None = None,
    **option_overrides: Any,
) -> dict:
    """Silhouettes from one video per camera (``footage/video.py``: layout, timing rule) -> a capture.

    ``sync``: a sync file path or ``{camera: video time at t = 0}``; ``cameras``: a calibration path or
    Camera list; ``frame_times``: the capture times; ``progress(camera_index, n_cameras, text)``;
    ``should_stop`` and ``uncertain`` as in :func:`extract_capture`, except that without one the capture
    declares one frame period of the videos (the slowest) as its time offset bound.
    Video problems (no video, unreadable, sync or frame time outside it, wrong size) raise at once,
    one line naming the file; extraction problems of all cameras are reported together as in
    :func:`extract_capture`. Returns the report (also ``out_dir/extract_report.json``).
    """
    from . import calib_io, video

    opts = _options(options, option_overrides)
    if cameras is None:
        raise ClothFitError("extract --videos needs the calibrated cameras (--cameras)")
    inputs = [sync] if isinstance(sync, str) else []
    if isinstance(cameras, str):
        inputs.append(cameras)
        cameras = calib_io.import_cameras(cameras)
    cameras = list(cameras)
    for c in cameras:  # names become folders (debug images, silhouettes): checked before any is used
        check_camera_name(c.name, "calibration")
    if isinstance(scenario, str):
        inputs.append(scenario)
    _refuse_overwriting(out_dir, inputs)
    cameras = _pick_cameras(cameras, camera_names)
    if frame_times is None:
        raise ClothFitError("extract --videos needs the capture times (--times)")
    try:
        frame_times = [float(t) for t in frame_times]
    except (TypeError, ValueError):
        raise ClothFitError(f"frame times must be numbers, got {frame_times!r}") from None
    if not frame_times or any(t < 0 for t in frame_times) or np.any(np.diff(frame_times) <= 0):
        raise ClothFitError(f"capture times {frame_times} must be >= 0 and strictly increasing")
    sync_path = sync if isinstance(sync, str) else "sync"
    sync = video.read_sync(sync, [c.name for c in cameras]) if isinstance(sync, str) else dict(sync)
    scen, scen_note, scen_unc = _resolve_scenario_uncertain(scenario, frame_times, "extract --videos")
    _uncertain_for(scen, uncertain, scen_unc, None)  # a bad block fails before the videos are read
    errors, warnings = [], []
    if scen_note:
        warnings.append(scen_note)
    report = {
        "videos": os.path.abspath(videos_dir),
        "plates": os.path.abspath(plates_dir),
        "out": os.path.abspath(out_dir),
        "options": asdict(opts),
        "frame_times": frame_times,
        "sync": sync,
        "cameras": {},
        "video": {},
    }
    all_masks, out_cameras = [], []
    for ci, cam in enumerate(cameras):
        if _stop(should_stop, ci, len(cameras), report, warnings):
            break
        if cam.name not in sync:
            raise ClothFitError(f"{sync_path}: no time for camera '{cam.name}'")
        if progress:
            progress(ci, len(cameras), f"{cam.name}: plate")
        plate, plate_src = video.read_plate(plates_dir, cam)
        step = (
            (lambda k, n, ci=ci, cam=cam: progress(ci + k / max(n, 1), len(cameras), f"{cam.name}: frame {k}/{n}"))
            if progress
            else None
        )
        frames, vrep = video.camera_frames(videos_dir, cam, sync[cam.name], frame_times, sync_path, step)
        vrep["plate"] = plate_src
        report["video"][cam.name] = vrep
        names = [f"{os.path.basename(vrep['video'])} at {u:.4f} s" for u in vrep["frame_timestamps"]]
        masks, out_cam = _extract_one(cam, [plate], frames, names, opts, report, errors, warnings)
        all_masks.append(masks)
        out_cameras.append(out_cam)
    if progress:
        progress(len(cameras), len(cameras), "done")
    cap_meta = {
        "generator": "addon.core.extract (videos)",
        "videos": os.path.abspath(videos_dir),
        "sync": sync,
        "frame_timestamps": {n: r["frame_timestamps"] for n, r in report["video"].items()},
    }
    fps = [r["mean_fps"] for r in report["video"].values() if r.get("mean_fps")]
    unc, unc_src = _uncertain_for(scen, uncertain, scen_unc, None, 1.0 / min(fps) if fps else None)
    return _write_result(
        out_dir,
        videos_dir,
        out_cameras,
        scen,
        all_masks,
        cloth_mass,
        cap_meta,
        opts,
        report,
        errors,
        warnings,
        unc,
        unc_src,
    )


def _refuse_overwriting(out_dir, inputs):
    """The capture written to ``out_dir`` must not replace the extraction's own input files."""
    from ..observation.capture import CAMERAS_JSON, CAPTURE_JSON, SHAPES_NPZ

    outs = {
        os.path.realpath(os.path.join(out_dir, n)): n for n in (CAPTURE_JSON, CAMERAS_JSON, SHAPES_NPZ, REPORT_JSON)
    }
    for p in inputs:
        if not os.path.exists(p):
            continue
        real = os.path.realpath(p)
        hit = [outs[real]] if real in outs else []
        if hit:
            raise ClothFitError(
                f"extract: writing the capture to {out_dir} would overwrite its input {p} "
                f"({', '.join(hit)}): choose another -o folder"
            )


def format_report(report: dict) -> str:
    """A short human-readable summary of an extraction report."""
    lines = [f"{'camera':<10} {'threshold':>9} {'mode':>10} {'otsu':>7} {'noise':>7} {'area min..max [px]':>20}"]
    for name, r in report["cameras"].items():
        areas = [f["area"] for f in r["frames"]]
        lines.append(
            f"{name:<10} {r['threshold']:9.2f} {r['mode']:>10} {r['otsu']:7.2f} {r['noise']:7.2f} "
            f"{min(areas):>9}..{max(areas):<9}"
        )
    for w in report.get("warnings", []):
        lines.append("warning: " + w)
    return "\n".join(lines)
