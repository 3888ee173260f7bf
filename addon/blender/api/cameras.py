# SPDX-License-Identifier: GPL-3.0-or-later
"""Cameras in and out of the scene: the rig from the settings or from core cameras, calibrated
cameras imported (OpenCV, COLMAP, our JSON) and exported. Cameras that still show their imported
camera are exported exactly (``reading.exact_rig_cameras``)."""

from __future__ import annotations

import os

from ...core.errors import ClothFitError
from ...core.jsonio import read_json
from .. import scene as S
from .reading import (
    abspath,
    blender_view_cameras,
    cameras_to_json,
    exact_rig_cameras,
    props,
    rig_from_props,
)


def build_rig(scene, cameras=None):
    """Cameras (core ``Camera`` list, default: the rig the properties describe) into the scene."""
    return set_rig(scene, cameras if cameras is not None else rig_from_props(scene))[0]


def set_rig(scene, cameras):
    """Build the rig from ``cameras`` and keep them exactly in ``rig_cameras_json``.
    Returns (camera objects, notes)."""
    cameras = list(cameras)
    shown, notes = blender_view_cameras(cameras)
    objs = S.build_rig(scene, shown)
    props(scene).rig_cameras_json = cameras_to_json(cameras)
    return objs, notes


def import_cameras(scene, path=None):
    """Calibrated cameras (OpenCV FileStorage YAML/JSON/XML file or folder, COLMAP text model,
    our cameras JSON) -> the rig. Returns (cameras, notes)."""
    from ...core.footage import calib_io

    p = props(scene)
    src = abspath(path if path else p.cameras_file, "camera file")
    cams = calib_io.import_cameras(src)
    _, notes = set_rig(scene, cams)
    if path:
        p.cameras_file = path
    return cams, notes


EXPORT_FORMATS = {"OPENCV": "opencv", "OPENCV_DIR": "opencv-dir", "COLMAP": "colmap", "JSON": "json"}


def _refuse_capture_files(dst, fmt):
    """A camera export must not replace a capture's own cameras.json / capture.json (the capture's
    silhouettes belong to those cameras)."""
    from ...core.observation.capture import CAMERAS_JSON, CAPTURE_JSON

    if fmt in ("OPENCV", "JSON"):
        folder, names = os.path.dirname(dst), [os.path.basename(dst)]
    else:
        folder, names = dst, []
    if not os.path.isfile(os.path.join(folder, CAPTURE_JSON)):
        return
    cap_files = {CAMERAS_JSON, CAPTURE_JSON}
    try:
        ref = read_json(os.path.join(folder, CAPTURE_JSON), "capture").get("cameras")
        if isinstance(ref, str):
            cap_files.add(os.path.basename(ref))
    except ClothFitError:
        pass
    hit = [n for n in names if n in cap_files]
    if hit:
        raise ClothFitError(
            f"camera export path {dst} is the camera file of the capture in {folder}: exporting "
            f"there would replace the cameras its silhouettes were taken with; choose another path"
        )


def export_cameras(scene, path=None, fmt=None):
    """The rig's cameras -> an OpenCV file/folder, a COLMAP model or our JSON. Cameras that
    still show their imported/loaded camera are written exactly (float64, distortion); moved
    ones as Blender shows them. Returns (path, cameras, names of cameras written from Blender)."""
    from ...core.footage import calib_io

    p = props(scene)
    fmt = fmt or p.cameras_export_format
    if fmt not in EXPORT_FORMATS:
        raise ClothFitError(f"camera export format {fmt!r} unknown ({', '.join(EXPORT_FORMATS)})")
    dst = abspath(path if path else p.cameras_export_path, "camera export path")
    if fmt in ("OPENCV", "JSON"):
        ext = os.path.splitext(dst)[1].lower()
        if os.path.isdir(dst) or not ext:
            dst = os.path.join(dst, "cameras.json" if fmt == "JSON" else "calibration.yml")
        elif fmt == "JSON" and ext != ".json":
            raise ClothFitError(f"camera export path {dst}: a Cloth Fit cameras JSON must end with .json")
    elif os.path.isfile(dst):
        raise ClothFitError(f"camera export path {dst} is a file: the {fmt} format writes a folder")
    _refuse_capture_files(dst, fmt)
    rows = exact_rig_cameras(scene)
    cams = [ex if ex is not None else b for b, ex, _ in rows]
    from_blender = [b.name for b, ex, _ in rows if ex is None]
    os.makedirs(os.path.dirname(dst) if fmt in ("OPENCV", "JSON") else dst, exist_ok=True)
    calib_io.export_cameras(cams, dst, EXPORT_FORMATS[fmt])
    if path:
        p.cameras_export_path = path
    return dst, cams, from_blender
