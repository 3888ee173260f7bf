"""Calibrated cameras in and out: OpenCV FileStorage (YAML/JSON/XML), EasyMocap, COLMAP text and binary models.

Our :class:`~.camera.Camera` is OpenCV's pinhole: ``x_cam = R X + t``, +Z forward, +Y down, pixel
centres at integer coordinates, distortion in OpenCV's order ``(k1, k2, p1, p2[, k3, ...])``.

OpenCV FileStorage files (``.yml``/``.yaml``/``.json``/``.xml``)
    Read: one camera at the top level, or several cameras as a ``cameras`` sequence of maps, or
    as top-level maps (the key is the camera's name). Per camera we accept the spellings people
    actually write: ``camera_matrix`` / ``cameraMatrix`` / ``K`` / ``intrinsic`` /
    ``intrinsic_matrix`` / ``M``; ``distortion_coefficients`` / ``dist_coeffs`` / ``distCoeffs``
    / ``dist`` / ``D``; extrinsics ``R`` (3x3) and ``t`` / ``T`` / ``tvec``, or ``rvec``
    (Rodrigues) and ``tvec``; image size ``image_width`` + ``image_height`` / ``width`` +
    ``height`` / ``image_size`` or ``imageSize`` ([w, h]). Matrices may be ``!!opencv-matrix``
    nodes or plain (nested) lists. A YAML file without OpenCV's ``%YAML:1.0`` header is read
    too. A camera without extrinsics is an error (we need calibrated poses); a file without an
    image size needs ``width``/``height`` from the caller.
    Write: one file with a ``cameras`` sequence (``write_opencv``) or one file per camera
    (``write_opencv_dir``), each camera with ``name``, ``image_width``, ``image_height``,
    ``camera_matrix``, ``distortion_coefficients``, ``R``, ``rvec`` and ``tvec``. When a file
    holds both ``R`` and ``rvec`` they must agree (1e-6) or we refuse it.

EasyMocap (a folder with ``intri.yml`` and ``extri.yml``, OpenCV FileStorage)
    ``names`` lists the cameras; per camera ``K_<name>`` (3x3), ``dist_<name>`` (1x5 or 1x4, OpenCV
    order), ``Rot_<name>`` (3x3; else ``R_<name>``, a Rodrigues vector) and ``T_<name>`` (3x1, metres):
    ``x_cam = R X + T``, the same convention as ours, pixel centres at integers (OpenCV). EasyMocap
    stores no image size: it is taken from ``H_<name>``/``W_<name>`` when present (EasyVolcap writes
    them), else from the caller (``sizes`` per camera, e.g. the videos' frame size, or
    ``width``/``height``).

COLMAP text and binary models: ``colmap.py`` (read and written there; ``import_cameras`` and
``export_cameras`` here reach them by format).

Distortion: :meth:`Camera.project` applies the OpenCV distortion model, so a capture can keep
distorted silhouettes with distorted cameras (the fitter projects vertices with distortion;
triangle edges stay straight between projected vertices, which is accurate for small triangles).
Or undistort the silhouettes with :func:`undistort_silhouette` and use the camera without
distortion.
"""

from __future__ import annotations

import os
import re
from typing import TYPE_CHECKING

import numpy as np

from ..errors import ClothFitError
from ..observation.camera import Camera, check_image_size, load_cameras, save_cameras
from .colmap import check_unique, colmap_folder, read_colmap, read_colmap_bin, write_colmap

if TYPE_CHECKING:
    from collections.abc import Sequence

_K_KEYS = ("camera_matrix", "cameraMatrix", "K", "intrinsic", "intrinsic_matrix", "intrinsics", "M")
_D_KEYS = ("distortion_coefficients", "dist_coeffs", "distCoeffs", "distortion", "dist", "D")
_R_KEYS = ("R", "rotation_matrix", "rotation")
_T_KEYS = ("t", "T", "tvec", "translation")
_RVEC_KEYS = ("rvec", "rvecs", "rotation_vector")

OPENCV_EXTS = (".yml", ".yaml", ".json", ".xml")


# ============================================================== OpenCV FileStorage: read


def _open_storage(path: str):
    import cv2

    if not os.path.isfile(path):
        raise ClothFitError(f"calibration file not found: {path}")
    try:
        with open(path, encoding="utf-8", errors="replace") as f:
            text = f.read()
    except OSError as e:
        raise ClothFitError(f"calibration file {path} is unreadable: {e}") from None
    if not text.strip():
        raise ClothFitError(f"calibration file {path} is empty")
    ext = os.path.splitext(path)[1].lower()
    if ext in (".yml", ".yaml") and not text.lstrip().startswith("%YAML"):
        text = "%YAML:1.0\n---\n" + text  # OpenCV insists on its header; plain YAML is common
    try:
        fs = cv2.FileStorage(
            text,
            cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY | (cv2.FILE_STORAGE_FORMAT_JSON if ext == ".json" else 0),
        )
        ok = fs.isOpened()
    except cv2.error as e:
        raise ClothFitError(
            f"calibration file {path} could not be parsed by OpenCV FileStorage: {str(e).strip().splitlines()[-1]}"
        ) from None
    except Exception as e:  # cv2 raises SystemError on some syntax errors
        raise ClothFitError(f"calibration file {path} could not be parsed by OpenCV FileStorage ({e})") from None
    if not ok:
        raise ClothFitError(f"calibration file {path} could not be opened by OpenCV FileStorage")
    return fs


def _node_to_py(node):
    """A FileNode as Python data: maps -> dict, seqs -> list, opencv-matrix -> ndarray."""
    if node.isMap():
        keys = list(node.keys())
        if {"rows", "cols", "data"} <= set(keys):
            rows, cols = int(node.getNode("rows").real()), int(node.getNode("cols").real())
            data = np.array(_node_to_py(node.getNode("data")), dtype=np.float64).reshape(-1)
            if data.size != rows * cols:
                raise ValueError(f"matrix of {rows}x{cols} has {data.size} values")
            return data.reshape(rows, cols)
        return {k: _node_to_py(node.getNode(k)) for k in keys}
    if node.isSeq():
        return [_node_to_py(node.at(i)) for i in range(node.size())]
    if node.isInt():
        return int(node.real())
    if node.isReal():
        return float(node.real())
    if node.isString():
        return node.string()
    return None


def _first(d: dict, keys):
    for k in keys:
        if k in d and d[k] is not None:
            return k, d[k]
    return None, None


def _looks_like_camera(d) -> bool:
    return isinstance(d, dict) and _first(d, _K_KEYS)[0] is not None


def _array(value, what, where, sizes=None, shape=None):
    try:
        a = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ClothFitError(f"{where}: {what} is not numeric: {value!r}") from None
    if shape is not None:
        if a.size != int(np.prod(shape)):
            raise ClothFitError(
                f"{where}: {what} must have {int(np.prod(shape))} values ({shape}), got shape {a.shape}"
            )
        a = a.reshape(shape)
    else:
        a = a.reshape(-1)
        if sizes is not None and a.size not in sizes:
            raise ClothFitError(f"{where}: {what} must have {' or '.join(map(str, sizes))} values, got {a.size}")
    if not np.all(np.isfinite(a)):
        raise ClothFitError(f"{where}: {what} has non-finite values: {a.tolist()}")
    return a


def _image_size(d, where, width, height):
    w = h = None
    for kw, kh in (("image_width", "image_height"), ("width", "height"), ("imageWidth", "imageHeight")):
        if kw in d and kh in d:
            w, h = d[kw], d[kh]
            break
    if w is None:
        _, size = _first(d, ("image_size", "imageSize", "img_size", "resolution"))
        if size is not None:
            s = _array(size, "image_size", where, sizes=(2,))
            w, h = s[0], s[1]  # OpenCV's cv::Size order: width, height
    if w is None:
        w, h = width, height
    if w is None or h is None:
        raise ClothFitError(f"{where}: no image size (image_width/image_height or image_size); give width and height")
    try:
        w, h = int(round(float(w))), int(round(float(h)))
    except (TypeError, ValueError, OverflowError):
        raise ClothFitError(f"{where}: image size {w!r} x {h!r} is not a finite number") from None
    return check_image_size(w, h, where)


def _camera_from_mapping(d: dict, name: str, where: str, width=None, height=None) -> Camera:
    import cv2

    kk, K = _first(d, _K_KEYS)
    if kk is None:
        raise ClothFitError(f"{where}: no camera matrix (looked for {', '.join(_K_KEYS)})")
    K = _array(K, kk, where, shape=(3, 3))
    dk, dist = _first(d, _D_KEYS)
    dist = np.zeros(0) if dk is None else _array(dist, dk, where, sizes=(0, 4, 5, 8, 12, 14))
    rk, R = _first(d, _R_KEYS)
    vk, rvec = _first(d, _RVEC_KEYS)
    tk, t = _first(d, _T_KEYS)
    if rk is None and vk is None:
        raise ClothFitError(f"{where}: no extrinsics (need R or rvec, and t/tvec); the camera pose must be calibrated")
    if tk is None:
        raise ClothFitError(f"{where}: no translation (looked for {', '.join(_T_KEYS)})")
    t = _array(t, tk, where, sizes=(3,))
    if rk is not None:
        R = _array(R, rk, where, shape=(3, 3))
        if vk is not None:
            Rv = cv2.Rodrigues(_array(rvec, vk, where, sizes=(3,)))[0]
            if np.abs(Rv - R).max() > 1e-6:
                raise ClothFitError(f"{where}: {rk} and {vk} disagree (max difference {np.abs(Rv - R).max():.2e})")
    else:
        R = cv2.Rodrigues(_array(rvec, vk, where, sizes=(3,)))[0]
    w, h = _image_size(d, where, width, height)
    cam_name = d.get("name") if isinstance(d.get("name"), str) and d.get("name") else name
    cam = Camera.__new__(Camera)
    cam.K, cam.R, cam.t, cam.dist, cam.width, cam.height, cam.name = K, R, t, dist, w, h, str(cam_name)
    cam.validate(where)
    return cam


def read_opencv(path: str, width: int | None = None, height: int | None = None) -> list:
    """Cameras of one OpenCV FileStorage file (one camera or several, see the module doc)."""
    fs = _open_storage(path)
    try:
        root = _node_to_py(fs.root())
    except (ValueError, TypeError) as e:
        raise ClothFitError(f"calibration file {path}: {e}") from None
    finally:
        fs.release()
    if not isinstance(root, dict) or not root:
        raise ClothFitError(f"calibration file {path}: expected a map of camera data at the top level")
    stem = os.path.splitext(os.path.basename(path))[0]
    if _looks_like_camera(root):
        return [_camera_from_mapping(root, stem, f"{path}", width, height)]
    entries = []
    if isinstance(root.get("cameras"), list):
        for i, c in enumerate(root["cameras"]):
            if not isinstance(c, dict):
                raise ClothFitError(f"calibration file {path}: cameras[{i}] is not a map")
            entries.append((f"cam{i:02d}", c, f"{path} cameras[{i}]"))
    else:
        for k, v in root.items():
            if _looks_like_camera(v):
                entries.append((k, v, f"{path} camera '{k}'"))
    if not entries:
        raise ClothFitError(
            f"calibration file {path}: no camera found (no camera matrix under any of "
            f"{', '.join(_K_KEYS)}, and no 'cameras' list)"
        )
    cams = [_camera_from_mapping(v, k, where, width, height) for k, v, where in entries]
    check_unique(cams, path)
    return cams


def read_opencv_dir(folder: str, width: int | None = None, height: int | None = None) -> list:
    """One camera per OpenCV file in ``folder`` (sorted by file name; the stem names the camera)."""
    files = sorted(f for f in os.listdir(folder) if os.path.splitext(f)[1].lower() in OPENCV_EXTS)
    if not files:
        raise ClothFitError(f"camera folder {folder}: no OpenCV calibration files ({', '.join(OPENCV_EXTS)})")
    cams = []
    for f in files:
        cams.extend(read_opencv(os.path.join(folder, f), width, height))
    check_unique(cams, folder)
    return cams


# ============================================================= OpenCV FileStorage: write


def _safe_key(name: str) -> str:
    k = re.sub(r"[^A-Za-z0-9_]", "_", name)
    return k if k and k[0].isalpha() else "cam_" + k


def _write_camera(fs, cam: Camera):
    import cv2

    fs.write("name", cam.name)
    fs.write("image_width", int(cam.width))
    fs.write("image_height", int(cam.height))
    fs.write("camera_matrix", cam.K)
    fs.write("distortion_coefficients", (cam.dist if cam.dist.size else np.zeros(5)).reshape(1, -1))
    fs.write("R", cam.R)
    fs.write("rvec", cv2.Rodrigues(cam.R)[0].reshape(3, 1))
    fs.write("tvec", cam.t.reshape(3, 1))


def _storage_for_write(path: str):
    import cv2

    ext = os.path.splitext(path)[1].lower()
    if ext not in OPENCV_EXTS:
        raise ClothFitError(f"OpenCV calibration file {path}: extension must be one of {', '.join(OPENCV_EXTS)}")
    d = os.path.dirname(os.path.abspath(path))
    os.makedirs(d, exist_ok=True)
    fs = cv2.FileStorage(path, cv2.FILE_STORAGE_WRITE)
    if not fs.isOpened():
        raise ClothFitError(f"cannot write OpenCV calibration file {path}")
    return fs


def write_opencv(path: str, cameras: Sequence[Camera]) -> str:
    """All cameras in one FileStorage file (format from the extension: .yml/.yaml/.json/.xml)."""
    import cv2

    fs = _storage_for_write(path)
    fs.write("camera_count", len(cameras))
    fs.write("convention", "x_cam = R X + t; +Z forward, +Y down; pixel centres at integers (OpenCV)")
    fs.startWriteStruct("cameras", cv2.FileNode_SEQ)
    for c in cameras:
        fs.startWriteStruct("", cv2.FileNode_MAP)
        _write_camera(fs, c)
        fs.endWriteStruct()
    fs.endWriteStruct()
    fs.release()
    return path


def write_opencv_dir(folder: str, cameras: Sequence[Camera], ext: str = ".yml") -> list[str]:
    """One FileStorage file per camera, ``<folder>/<name>.yml`` (name made file-safe)."""
    os.makedirs(folder, exist_ok=True)
    out = []
    for c in cameras:
        p = os.path.join(folder, _safe_key(c.name) + ext)
        fs = _storage_for_write(p)
        _write_camera(fs, c)
        fs.release()
        out.append(p)
    return out


# ===================================================================== EasyMocap

EASYMOCAP_FILES = ("intri.yml", "extri.yml")


def _is_easymocap(folder: str) -> bool:
    return os.path.isdir(folder) and all(os.path.isfile(os.path.join(folder, f)) for f in EASYMOCAP_FILES)


def read_easymocap(
    folder: str,
    width: int | None = None,
    height: int | None = None,
    sizes: dict[str, tuple[int, int]] | None = None,
) -> list[Camera]:
    """Cameras of an EasyMocap calibration folder (``intri.yml`` + ``extri.yml``); see the module text.
    ``sizes``: ``{name: (height, width)}`` for files without ``H_``/``W_``."""
    import cv2

    if os.path.isfile(folder):
        folder = os.path.dirname(folder) or "."
    data = {}
    for fname in EASYMOCAP_FILES:
        path = os.path.join(folder, fname)
        if not os.path.isfile(path):
            raise ClothFitError(f"EasyMocap calibration {folder}: {fname} not found (needs intri.yml and extri.yml)")
        fs = _open_storage(path)
        try:
            d = _node_to_py(fs.root())
        except (ValueError, TypeError) as e:
            raise ClothFitError(f"EasyMocap file {path}: {e}") from None
        finally:
            fs.release()
        if not isinstance(d, dict) or not isinstance(d.get("names"), list) or not d["names"]:
            raise ClothFitError(f"EasyMocap file {path}: no 'names' list of cameras")
        data[fname] = (d, path)
    (intri, ipath), (extri, epath) = data["intri.yml"], data["extri.yml"]
    names = [str(int(n)) if isinstance(n, (int, float)) else str(n) for n in intri["names"]]
    enames = {str(int(n)) if isinstance(n, (int, float)) else str(n) for n in extri["names"]}
    missing = [n for n in names if n not in enames]
    if missing:
        raise ClothFitError(f"EasyMocap file {epath}: no extrinsics for camera(s) {', '.join(missing)} of {ipath}")
    cams = []
    for n in names:
        where = f"EasyMocap camera '{n}' ({folder})"
        if f"K_{n}" not in intri:
            raise ClothFitError(f"EasyMocap file {ipath}: K_{n} missing")
        K = _array(intri[f"K_{n}"], f"K_{n}", where, shape=(3, 3))
        dist = _array(intri.get(f"dist_{n}", []), f"dist_{n}", where, sizes=(0, 4, 5, 8))
        if f"Rot_{n}" in extri:
            R = _array(extri[f"Rot_{n}"], f"Rot_{n}", where, shape=(3, 3))
        elif f"R_{n}" in extri:
            R = cv2.Rodrigues(_array(extri[f"R_{n}"], f"R_{n}", where, shape=(3, 1)))[0]
        else:
            raise ClothFitError(f"EasyMocap file {epath}: neither Rot_{n} nor R_{n} for camera '{n}'")
        if f"T_{n}" not in extri:
            raise ClothFitError(f"EasyMocap file {epath}: T_{n} missing")
        t = _array(extri[f"T_{n}"], f"T_{n}", where, shape=(3,))
        if f"H_{n}" in intri and f"W_{n}" in intri:
            w, h = check_image_size(intri[f"W_{n}"], intri[f"H_{n}"], where)
        elif sizes and n in sizes:
            h, w = (int(v) for v in sizes[n])
        elif width and height:
            h, w = int(height), int(width)
        elif sizes is not None:
            raise ClothFitError(
                f"camera '{n}': no video {n}.<mp4|mov|mkv|avi> in {getattr(sizes, 'source', 'the videos')} "
                f"(its image size comes from the video: EasyMocap's {folder} stores none)"
            )
        else:
            raise ClothFitError(
                f"EasyMocap calibration {folder}: camera '{n}' has no image size (EasyMocap files "
                f"store none): pass --width/--height, or extract from its video"
            )
        cam = Camera.__new__(Camera)
        cam.K, cam.R, cam.t, cam.dist, cam.width, cam.height, cam.name = K, R, t, dist, w, h, n
        cam.validate(where)
        cams.append(cam)
    check_unique(cams, ipath)
    return cams


# ============================================================ one entry point each way

FORMATS = ("auto", "json", "opencv", "opencv-dir", "colmap", "easymocap")


def detect_format(path: str) -> str:
    if os.path.isdir(path):
        if _is_easymocap(path):
            return "easymocap"
        for sub in ("", os.path.join("sparse", "0"), "sparse"):
            for ext in (".txt", ".bin"):
                if all(os.path.isfile(os.path.join(path, sub, f + ext)) for f in ("cameras", "images")):
                    return "colmap"
        return "opencv-dir"
    ext = os.path.splitext(path)[1].lower()
    if os.path.basename(path) in EASYMOCAP_FILES and _is_easymocap(os.path.dirname(path) or "."):
        return "easymocap"
    if ext in (".txt", ".bin"):
        return "colmap"
    if ext == ".json":
        # our own cameras JSON has a "cameras" list of objects with K/R/t; OpenCV JSON otherwise
        try:
            import json

            with open(path) as f:
                d = json.load(f)
            cams = d.get("cameras") if isinstance(d, dict) else None
            if isinstance(cams, list) and cams and isinstance(cams[0], dict) and "K" in cams[0] and "width" in cams[0]:
                return "json"
        except (OSError, ValueError):
            pass
        return "opencv"
    if ext in OPENCV_EXTS:
        return "opencv"
    raise ClothFitError(
        f"cannot tell the camera file format of {path} (use a .yml/.yaml/.json/.xml file, "
        "a COLMAP model folder or name the format)"
    )


def import_cameras(
    path: str,
    fmt: str = "auto",
    width: int | None = None,
    height: int | None = None,
    sizes: dict[str, tuple[int, int]] | None = None,
) -> list[Camera]:
    """Cameras from any supported file or folder.

    ``fmt``: ``auto`` (by extension/content), ``json`` (our cameras JSON, see ``camera.py``),
    ``opencv`` (one FileStorage file), ``opencv-dir`` (a folder of FileStorage files, one camera
    each), ``colmap`` (a text model folder, or its ``cameras.txt``/``images.txt``).
    ``width``/``height`` are only used when an OpenCV file gives no image size.
    """
    if fmt not in FORMATS:
        raise ClothFitError(f"camera format {fmt!r} unknown (one of {', '.join(FORMATS)})")
    if not os.path.exists(path):
        raise ClothFitError(f"camera file or folder not found: {path}")
    if fmt == "auto":
        fmt = detect_format(path)
    if fmt == "json":
        return load_cameras(path)
    if fmt == "opencv":
        return read_opencv(path, width, height)
    if fmt == "opencv-dir":
        if not os.path.isdir(path):
            raise ClothFitError(f"{path} is not a folder (format opencv-dir)")
        return read_opencv_dir(path, width, height)
    if fmt == "easymocap":
        return read_easymocap(path, width, height, sizes)
    folder, kind = colmap_folder(path)
    return read_colmap_bin(folder) if kind == "bin" else read_colmap(folder)


def export_cameras(cameras: Sequence[Camera], path: str, fmt: str = "auto") -> str:
    """Write cameras: ``json`` (ours), ``opencv`` (one file), ``opencv-dir`` (a file per camera),
    ``colmap`` (a text model folder). ``auto``: a path ending in .json -> json, .yml/.yaml/.xml
    -> opencv, anything else (a folder) -> colmap."""
    if fmt not in FORMATS:
        raise ClothFitError(f"camera format {fmt!r} unknown (one of {', '.join(FORMATS)})")
    if not cameras:
        raise ClothFitError("no cameras to export")
    if fmt == "auto":
        ext = os.path.splitext(path)[1].lower()
        fmt = "json" if ext == ".json" else "opencv" if ext in OPENCV_EXTS else "colmap"
    if fmt == "json":
        save_cameras(path, cameras)
    elif fmt == "opencv":
        write_opencv(path, cameras)
    elif fmt == "opencv-dir":
        write_opencv_dir(path, cameras)
    else:
        write_colmap(path, cameras)
    return path


# ==================================================================== distortion


def undistort_maps(camera: Camera) -> tuple[np.ndarray, np.ndarray] | None:
    """cv2.remap maps from the undistorted image (same K, no distortion) into the distorted one."""
    import cv2

    if camera.dist.size == 0 or not np.any(camera.dist != 0):
        return None
    return cv2.initUndistortRectifyMap(
        camera.K, camera.dist, None, camera.K, (camera.width, camera.height), cv2.CV_32FC1
    )


def undistort_silhouette(
    mask: np.ndarray, camera: Camera, maps: tuple[np.ndarray, np.ndarray] | None = None
) -> np.ndarray:
    """The silhouette the same camera would see without lens distortion (nearest-neighbour remap).

    Returns a boolean ``(H, W)`` mask for ``undistorted_camera(camera)``. Pixels that map outside
    the distorted image are background. ``maps`` may be passed from :func:`undistort_maps` to
    undistort many masks of one camera quickly.
    """
    import cv2

    m = np.asarray(mask)
    if m.shape[:2] != (camera.height, camera.width):
        raise ClothFitError(
            f"undistort: silhouette is {m.shape[0]}x{m.shape[1]} but camera '{camera.name}' "
            f"images {camera.height}x{camera.width}"
        )
    maps = undistort_maps(camera) if maps is None else maps
    if maps is None:
        return m.astype(bool)
    out = cv2.remap(
        m.astype(np.uint8),
        maps[0],
        maps[1],
        interpolation=cv2.INTER_NEAREST,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=0,
    )
    return out > 0


def undistorted_camera(camera: Camera) -> Camera:
    """The same camera without distortion (what :func:`undistort_silhouette` images)."""
    return Camera(
        camera.K.copy(), camera.R.copy(), camera.t.copy(), camera.width, camera.height, camera.name, np.zeros(0)
    )


def undistort_image(image: np.ndarray, camera: Camera, interpolation: int | None = None) -> np.ndarray:
    """Undistort a colour/grey image (bilinear by default), e.g. for overlays."""
    import cv2

    maps = undistort_maps(camera)
    if maps is None:
        return image
    return cv2.remap(
        image,
        maps[0],
        maps[1],
        interpolation=cv2.INTER_LINEAR if interpolation is None else interpolation,
        borderMode=cv2.BORDER_CONSTANT,
    )


# ================================================================ cameras of anything


def cameras_from_any(path: str, fmt: str = "auto", width: int | None = None, height: int | None = None) -> list:
    """Cameras of a calibration file/folder, or of a capture (its folder or capture.json)."""
    cj = path if os.path.basename(path) == "capture.json" else os.path.join(path, "capture.json")
    if os.path.isfile(cj) and fmt == "auto":
        from ..observation.capture import load_capture

        return load_capture(cj).cameras
    return import_cameras(path, fmt, width, height)


def describe(cameras: Sequence[Camera]) -> str:
    lines = []
    for c in cameras:
        d = "none" if c.dist.size == 0 or not np.any(c.dist != 0) else " ".join(f"{v:.4g}" for v in c.dist)
        lines.append(
            f"{c.name:<12} {c.width}x{c.height}  fx {c.K[0, 0]:.2f} fy {c.K[1, 1]:.2f} "
            f"cx {c.K[0, 2]:.2f} cy {c.K[1, 2]:.2f}  centre {np.round(c.center, 4).tolist()}  dist {d}"
        )
    return "\n".join(lines)
