# SPDX-License-Identifier: GPL-3.0-or-later
"""Footage and captures in the scene: silhouettes extracted from camera footage into a capture,
a capture loaded (its cameras become the rig, its scenario the settings), and the observed
silhouettes (or overlays) shown as camera background images."""

from __future__ import annotations

import math
import os
import queue
import threading

import bpy

from ...core.errors import ClothFitError
from .. import scene as S
from .cameras import set_rig
from .reading import (
    abspath,
    cameras_from_json,
    capture_dir,
    empties_scenario,
    parse_times,
    props,
    refuse_foreign_capture,
    scene_grid,
)
from .steps import Steps

EXTRACT_GENERATOR = "addon.core.extract"
THRESHOLD_MODES = {"AUTO": "auto", "OTSU": "otsu", "NOISE": "noise"}
OVERLAY_DIR = "overlays"  # <capture>/overlays/<camera>/<frame>.png (Overlays writes them)


def parse_camera_thresholds(spec: str, camera_names=None) -> dict:
    """``"cam03=9.5, cam07=12"`` -> {"cam03": 9.5, "cam07": 12.0}; names checked against the cameras."""
    out = {}
    for item in (spec or "").replace(";", ",").split(","):
        item = item.strip()
        if not item:
            continue
        if "=" not in item:
            raise ClothFitError(f"per-camera threshold {item!r}: expected CAMERA=VALUE (e.g. cam03=9.5)")
        name, val = (x.strip() for x in item.split("=", 1))
        try:
            v = float(val)
        except ValueError:
            raise ClothFitError(f"per-camera threshold {item!r}: {val!r} is not a number") from None
        if not (math.isfinite(v) and v > 0):
            raise ClothFitError(f"per-camera threshold {item!r}: the threshold must be a positive number")
        if name in out:
            raise ClothFitError(f"per-camera threshold: camera '{name}' is given twice")
        if camera_names is not None and name not in camera_names:
            raise ClothFitError(
                f"per-camera threshold {item!r}: no camera '{name}' in the calibration (cameras: "
                f"{', '.join(list(camera_names)[:20])})"
            )
        out[name] = v
    return out


def _footage_cameras(scene, footage, sizes=None):
    """The calibration for an extraction: the Calibration property, else the footage's own
    (footage.json's, cameras.* / calibration.*, a COLMAP folder), else the rig's exact cameras
    (imported or loaded). Returns (cameras, where they came from)."""
    from ...core.footage import calib_io
    from ...core.footage import extract as X

    p = props(scene)
    if p.extract_calibration.strip():
        path = abspath(p.extract_calibration, "calibration")
        return calib_io.import_cameras(path, sizes=sizes), path
    meta, meta_path = X.read_footage_json(footage)
    if isinstance(meta.get("cameras"), str):
        path = os.path.join(footage, meta["cameras"])
        return calib_io.import_cameras(path), path
    path = X.find_calibration(footage)
    if path is not None:
        return calib_io.import_cameras(path, sizes=sizes), path
    if p.rig_cameras_json.strip():
        return cameras_from_json(p.rig_cameras_json), "the scene's imported cameras"
    raise ClothFitError(
        f"footage {footage}: no calibration: set Calibration, put a cameras.yml (or footage.json, "
        f"or a COLMAP folder) in the footage folder, or import cameras into the rig first"
    )


def extract_silhouettes(scene, progress=None):
    """Silhouettes from the footage folder (``core.footage.extract.extract_capture``) into a capture,
    then load it (cameras become the rig, observed silhouettes the camera backgrounds).

    With the Empties manipulation the capture's scenario is the empties' (sampled at the
    footage's frame times); otherwise footage.json's, else the paper's (with a warning).
    ``progress(fraction)`` is called per camera. Returns (Capture, report); ``report["warnings"]``
    lists every warning of the extraction, ``report["notes"]`` what the scene changed (frame rate).
    Errors (every bad file in one message) write nothing."""
    return extract_steps(scene).run(progress)


def extract_steps(scene) -> Steps:
    """``extract_silhouettes`` in steps for the modal operator. The first step reads the settings
    and checks them; the extraction (pure core: numpy, OpenCV) then runs in a worker thread and
    each step reports its progress; the capture is loaded into the scene at the end. Cancelled,
    the cameras extracted so far are written as a capture (not loaded); stopped before the first
    camera is done, nothing is written."""
    return Steps(_extract_work, scene)


def _extract_paths(scene, p):
    """The footage folder and the output capture folder of an extraction, checked."""
    footage = abspath(p.footage_dir, "footage directory")
    if not os.path.isdir(footage):
        raise ClothFitError(f"footage folder not found: {footage}")
    out = (
        abspath(p.extract_capture_dir, "output capture directory")
        if p.extract_capture_dir.strip()
        else capture_dir(scene)
    )
    if os.path.normpath(out) == os.path.normpath(footage):
        raise ClothFitError(f"the output capture directory is the footage folder {footage}: choose another one")
    refuse_foreign_capture(out, EXTRACT_GENERATOR, "Extract Silhouettes", "extractions")
    return footage, out


def _extract_work(steps, scene):
    from ...core.footage import extract as X

    p = props(scene)
    footage, out = _extract_paths(scene, p)
    videos = getattr(p, "footage_kind", "IMAGES") == "VIDEOS"
    sizes = None
    if videos:
        from ...core.footage import video as V

        sizes = V.video_sizes(footage)
    cams, cam_source = _footage_cameras(scene, footage, sizes)
    times = parse_times(p.extract_times) if p.extract_times.strip() else None
    if videos and times is None:
        raise ClothFitError("extraction from videos needs the capture times (Times)")
    mode = p.extract_threshold_mode
    opts = X.ExtractOptions(
        threshold=THRESHOLD_MODES.get(mode, float(p.extract_threshold)),
        thresholds=parse_camera_thresholds(p.extract_camera_thresholds, [c.name for c in cams]),
        luma_weight=float(p.extract_luma_weight),
        shadow_min=float(p.extract_shadow_min),
        debug_dir=os.path.join(out, "debug") if p.extract_debug else None,
    ).check()
    scenario, notes = None, []
    if p.scenario_source == "EMPTIES":
        ft = times
        if ft is None:
            ft = X.read_footage_json(footage)[0].get("frame_times")
            if not isinstance(ft, list) or not ft:
                raise ClothFitError(f"footage {footage}: no frame times (set Times, or frame_times in footage.json)")
        scenario = empties_scenario(scene, scene_grid(scene), ft, notes)
    if videos:
        names = [c.name for c in cams]
        sync_path = abspath(p.footage_sync, "sync file") if p.footage_sync.strip() else None
        if not (p.footage_find_sync or sync_path):
            raise ClothFitError("extraction from videos needs a Sync file (or Sync from Flash)")
        if not p.footage_plates.strip():
            raise ClothFitError("extraction from videos needs the Plates folder")
        plates, find_sync, flash_time = (
            abspath(p.footage_plates, "plates folder"),
            p.footage_find_sync,
            p.footage_flash_time,
        )

    # from here on no bpy: the worker thread runs the core extraction
    events, stop, box = queue.Queue(), threading.Event(), {}

    def cb(i, n, name):
        events.put((i / max(n, 1), f"{name}"))

    def work():
        try:
            if videos:
                sync = sync_path
                if find_sync:
                    sync = V.flash_sync(footage, names, flash_time, sync_path)
                    notes.append("sync from the flash: " + ", ".join(f"{k} {v:.4f} s" for k, v in sync.items()))
                box["report"] = X.extract_videos(
                    footage,
                    plates,
                    sync,
                    out,
                    cams,
                    times,
                    scenario=scenario,
                    options=opts,
                    progress=cb,
                    should_stop=stop.is_set,
                )
            else:
                box["report"] = X.extract_capture(
                    footage,
                    out,
                    cameras=cams,
                    frame_times=times,
                    scenario=scenario,
                    options=opts,
                    progress=cb,
                    should_stop=stop.is_set,
                )
        except BaseException as e:  # noqa: BLE001 - handed to the main thread, raised there
            box["err"] = e

    worker = threading.Thread(target=work, name="clothfit-extract", daemon=True)
    worker.start()
    steps.kept = "nothing was written"
    fraction, text = 0.0, f"extracting {len(cams)} cameras"
    try:
        while worker.is_alive() or not events.empty():
            try:
                fraction, text = events.get(timeout=0.02)
            except queue.Empty:
                pass
            yield fraction, text
    except GeneratorExit:  # cancelled: the cameras done so far become the capture
        stop.set()
        worker.join()
        steps.kept = _kept_after_stop(box, out, len(cams))
        raise
    worker.join()
    if "err" in box:
        raise box["err"]
    report = box["report"]
    cap = load_capture(scene, out)
    thr = [r["threshold"] for r in report["cameras"].values()]
    nw = len(report.get("warnings", []))
    p.extract_status = (
        f"{cap.n_cameras} cameras x {cap.n_frames} frames, thresholds {min(thr):.2f}.."
        f"{max(thr):.2f}, {nw} warning{'s' if nw != 1 else ''}"
    )
    report["calibration"] = cam_source
    report["notes"] = notes
    return cap, report


def _kept_after_stop(box, out, n):
    if "err" in box:
        e = box["err"]
        first = (str(e).splitlines() or [""])[0]
        return "nothing was written" + ("" if "stopped before the first camera" in first else f" ({first})")
    done = box["report"].get("stopped", {}).get("cameras_done", n)
    if done < n:
        return (
            f"kept a capture of the {done} of {n} cameras extracted so far in {out} (not loaded: Load "
            f"Capture loads it; extract again for every camera)"
        )
    return f"kept the whole capture in {out} (it finished before the stop; not loaded: Load Capture loads it)"


def load_capture(scene, path=None):
    """Read and fully validate a capture; its cameras become the rig, its scenario the settings,
    and each camera shows its observed silhouette (frame ``view_frame``) as background image."""
    from ...core.observation.capture import load_capture as core_load

    p = props(scene)
    root = abspath(path, "capture directory") if path else capture_dir(scene)
    cap = core_load(root)
    cap.validate(full=True)
    set_rig(scene, cap.cameras)
    g = cap.scenario.grid
    p.cloth_nx, p.cloth_side, p.cloth_height = g.nx, g.side, g.height
    p.settle_time = cap.scenario.settle_time
    p.frame_times = ", ".join(f"{t:g}" for t in cap.frame_times)
    p.capture_releases = releases_text(cap.scenario)
    released = [h for h in cap.scenario.handles if h.release_time is not None]
    if len(released) == 1 and released[0].vertex in g.corners() and released[0].release_time == 0.0:
        p.released_corner = g.corners().index(released[0].vertex)  # the Paper manipulation can replay it
    p.capture_dir = cap.root  # the folder, also when ``path`` is its capture.json
    p.scenario_source = "CAPTURE"
    p["view_frame"] = min(p.view_frame, cap.n_frames - 1)
    show_observations(scene, p.view_frame, cap)
    return cap


def releases_text(scenario) -> str:
    """Every handle the capture lets go, with its time ("vertex 0 at 0 s, vertex 255 at 0.05 s"), and
    the handles that move along a path ("...; 4 held; corner 0 moving"); the capture's scenario, which
    Build Cloth, Simulate, Fit and Apply replay, keeps them all."""
    from ...core.physics.handling import moving_handles

    g = scenario.grid
    corners = g.corners()

    def name(v):
        return f"corner {corners.index(v)}" if v in corners else f"vertex {v}"

    parts = [
        f"{name(h.vertex)} at {h.release_time:g} s"
        for h in sorted(scenario.handles, key=lambda h: (h.release_time is None, h.release_time or 0.0, h.vertex))
        if h.release_time is not None
    ]
    held = sum(h.release_time is None for h in scenario.handles)
    moving = [name(v) for v in moving_handles(scenario)]
    return (
        (", ".join(parts) if parts else "nothing released")
        + f"; {held} held"
        + (f"; {', '.join(moving)} moving" if moving else "")
    )


def load_image(name, path):
    img = bpy.data.images.get(name)
    if img is None:
        img = bpy.data.images.load(path, check_existing=False)
        img.name = name
    elif bpy.path.abspath(img.filepath) != path:
        img.filepath = path
        img.reload()
    else:
        img.reload()
    return img


def show_background(cam_obj, image, alpha=0.6):
    cd = cam_obj.data
    bg = cd.background_images[0] if len(cd.background_images) else cd.background_images.new()
    bg.image = image
    bg.alpha = alpha
    bg.display_depth = "FRONT"
    cd.show_background_images = True
    return bg


def overlay_path(cap, ci, fi):
    """Where Overlays writes camera ``ci``'s overlay of capture frame ``fi``."""
    return os.path.join(cap.root, OVERLAY_DIR, cap.cameras[ci].name, f"{fi:03d}.png")


def show_observations(scene, frame_index, cap=None, kind="observed"):
    """Camera backgrounds: observed silhouettes (or overlays) of capture frame ``frame_index``."""
    from ...core.observation.capture import load_capture as core_load

    cap = cap or core_load(capture_dir(scene))
    fi = max(0, min(int(frame_index), cap.n_frames - 1))
    objs = {o.name: o for o in S.rig_objects(scene)}
    shown = 0
    for ci, c in enumerate(cap.cameras):
        obj = objs.get(c.name)
        if obj is None:
            continue
        if kind == "overlay":
            path = overlay_path(cap, ci, fi)
        else:
            path = cap.silhouette_path(ci, fi)
        if os.path.isfile(path):
            show_background(obj, load_image(f"clothfit {kind} {c.name}", path))
            shown += 1
    return shown
