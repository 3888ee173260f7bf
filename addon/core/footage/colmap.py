"""Calibrated cameras in and out, COLMAP's models (``calib_io.py`` holds the other formats and the
one entry point each way, ``import_cameras`` / ``export_cameras``).

COLMAP text models (a folder with ``cameras.txt`` and ``images.txt``)
    Camera models SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV and FULL_OPENCV; COLMAP's
    distortion of these models is OpenCV's with the same coefficients (SIMPLE_RADIAL ``k`` = k1;
    RADIAL ``k1, k2``; OPENCV ``k1, k2, p1, p2``; FULL_OPENCV ``k1, k2, p1, p2, k3, k4, k5, k6``,
    the rational model). Every line of ``images.txt`` ``IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID
    NAME`` (followed by its 2D-points line) becomes one Camera: COLMAP's pose is world-to-camera,
    the same as ours. The camera's name is the image name's stem (``cam03.png`` -> ``cam03``); if
    stems collide (``cam03/0001.png``, ``cam04/0001.png``) the path without extension with ``/``
    turned into ``_`` is used.

    **Pixel convention.** COLMAP puts the centre of the top-left pixel at (0.5, 0.5); we (and
    OpenCV) put it at (0, 0). So ``cx_ours = cx_colmap - 0.5`` and ``cy_ours = cy_colmap - 0.5``
    on import, and ``+ 0.5`` on export. Focal lengths and distortion are unchanged.
    Export writes PINHOLE (no distortion), OPENCV (up to 4 coefficients or k3 = 0) or
    FULL_OPENCV, ``images.txt`` with ``<name>.png`` image names and an empty ``points3D.txt``.

COLMAP binary models (``cameras.bin`` + ``images.bin``)
    Read with our own struct reader (COLMAP's documented little-endian layout): cameras.bin =
    uint64 count, then per camera int32 id, int32 model id, uint64 width, uint64 height, float64
    params; images.bin = uint64 count, then per image int32 id, float64 qw qx qy qz tx ty tz, int32
    camera id, a NUL-terminated name, uint64 number of 2D points and 24 bytes per point (x, y
    float64, point3D id int64). Then exactly as the text model.
"""

from __future__ import annotations

import math
import os
from typing import TYPE_CHECKING

import numpy as np

from ..errors import ClothFitError
from ..observation.camera import Camera, check_camera_name

if TYPE_CHECKING:
    from collections.abc import Iterable, Sequence


def check_unique(cams: Sequence, where: str) -> None:
    """Names are checked (one plain path component each, unique) before any of them is used."""
    names = [c.name for c in cams]
    for n in names:
        check_camera_name(n, where)
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ClothFitError(f"{where}: camera names are not unique: {', '.join(dup)}")


# ======================================================================== COLMAP

# model name -> (number of params, how they map to fx, fy, cx, cy, dist)
COLMAP_MODELS = {
    "SIMPLE_PINHOLE": 3,  # f, cx, cy
    "PINHOLE": 4,  # fx, fy, cx, cy
    "SIMPLE_RADIAL": 4,  # f, cx, cy, k
    "RADIAL": 5,  # f, cx, cy, k1, k2
    "OPENCV": 8,  # fx, fy, cx, cy, k1, k2, p1, p2
    "FULL_OPENCV": 12,  # fx, fy, cx, cy, k1, k2, p1, p2, k3, k4, k5, k6
}
COLMAP_PIXEL_OFFSET = 0.5  # COLMAP's pixel centres are at +0.5: cx_ours = cx_colmap - 0.5


def _colmap_lines(path):
    if not os.path.isfile(path):
        raise ClothFitError(f"COLMAP model file not found: {path}")
    try:
        with open(path, encoding="utf-8") as f:
            raw = f.read().splitlines()
    except (OSError, UnicodeDecodeError) as e:
        raise ClothFitError(f"COLMAP model file {path} is unreadable: {e}") from None
    return [(i + 1, ln) for i, ln in enumerate(raw)]


def colmap_to_intrinsics(
    model: str, params: Iterable[float], where: str = "COLMAP camera"
) -> tuple[np.ndarray, np.ndarray]:
    """``K`` (our pixel convention) and OpenCV ``dist`` from a COLMAP camera model."""
    if model not in COLMAP_MODELS:
        raise ClothFitError(f"{where}: camera model {model} is not supported (supported: {', '.join(COLMAP_MODELS)})")
    p = [float(v) for v in params]
    if len(p) != COLMAP_MODELS[model]:
        raise ClothFitError(f"{where}: model {model} needs {COLMAP_MODELS[model]} parameters, got {len(p)}")
    if model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL"):
        fx = fy = p[0]
        cx, cy = p[1], p[2]
        rest = p[3:]
    else:
        fx, fy, cx, cy = p[:4]
        rest = p[4:]
    if model == "SIMPLE_RADIAL":
        dist = [rest[0], 0.0, 0.0, 0.0]
    elif model == "RADIAL":
        dist = [rest[0], rest[1], 0.0, 0.0]
    elif model == "OPENCV":
        dist = rest[:4]
    elif model == "FULL_OPENCV":
        dist = rest[:8]
    else:
        dist = []
    K = np.array([[fx, 0.0, cx - COLMAP_PIXEL_OFFSET], [0.0, fy, cy - COLMAP_PIXEL_OFFSET], [0.0, 0.0, 1.0]])
    return K, np.array(dist, dtype=np.float64)


def intrinsics_to_colmap(cam: Camera) -> tuple[str, list[float]]:
    """(model, params) of a Camera in COLMAP's convention (the model that represents it exactly)."""
    if abs(cam.K[0, 1]) > 1e-12:
        raise ClothFitError(f"camera '{cam.name}': COLMAP models have no skew, K[0,1] = {cam.K[0, 1]}")
    fx, fy = cam.K[0, 0], cam.K[1, 1]
    cx, cy = cam.K[0, 2] + COLMAP_PIXEL_OFFSET, cam.K[1, 2] + COLMAP_PIXEL_OFFSET
    d = cam.dist
    if d.size == 0 or not np.any(d != 0):
        return "PINHOLE", [fx, fy, cx, cy]
    if d.size > 8 and np.any(d[8:] != 0):
        raise ClothFitError(
            f"camera '{cam.name}': distortion with {d.size} coefficients (thin prism / tilt) has no COLMAP model"
        )
    if d.size <= 4 or (d.size >= 5 and not np.any(d[4:] != 0)):
        dd = np.zeros(4)
        dd[: min(4, d.size)] = d[:4]
        return "OPENCV", [fx, fy, cx, cy, *dd.tolist()]
    dd = np.zeros(8)
    dd[: min(8, d.size)] = d[:8]
    return "FULL_OPENCV", [fx, fy, cx, cy, *dd.tolist()]


def _quat_to_R(q):
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def _R_to_quat(R):
    """Unit quaternion (w, x, y, z), w >= 0, of a rotation matrix (Shepperd's method)."""
    tr = np.trace(R)
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        q = [0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = math.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2]) * 2
        q = [(R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s]
    elif R[1, 1] > R[2, 2]:
        s = math.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2]) * 2
        q = [(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s]
    else:
        s = math.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1]) * 2
        q = [(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s]
    q = np.array(q)
    q /= np.linalg.norm(q)
    return -q if q[0] < 0 else q


def _is_points_line(s: str) -> bool:
    toks = s.split()
    if len(toks) % 3:
        return False
    try:
        [float(v) for v in toks]
    except ValueError:
        return False
    return True


def read_colmap(folder: str) -> list:
    """Cameras of a COLMAP text model folder (``cameras.txt`` + ``images.txt``), one per image."""
    cpath = os.path.join(folder, "cameras.txt")
    ipath = os.path.join(folder, "images.txt")
    intr = {}
    for ln, line in _colmap_lines(cpath):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        parts = s.split()
        where = f"{cpath} line {ln}"
        if len(parts) < 4:
            raise ClothFitError(f"{where}: expected 'CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]', got {s!r}")
        try:
            cid, w, h = int(parts[0]), int(parts[2]), int(parts[3])
            params = [float(v) for v in parts[4:]]
        except ValueError:
            raise ClothFitError(f"{where}: non-numeric camera entry {s!r}") from None
        K, dist = colmap_to_intrinsics(parts[1], params, where)
        if cid in intr:
            raise ClothFitError(f"{where}: camera id {cid} defined twice")
        intr[cid] = (K, dist, w, h, where)
    if not intr:
        raise ClothFitError(f"{cpath}: no cameras")
    images = []
    lines = [(ln, l.strip()) for ln, l in _colmap_lines(ipath)]
    lines = [(ln, s) for ln, s in lines if not s.startswith("#")]
    i = 0
    while i < len(lines):
        ln, s = lines[i]
        if not s:
            i += 1
            continue
        parts = s.split(maxsplit=9)
        where = f"{ipath} line {ln}"
        if len(parts) < 10:
            raise ClothFitError(f"{where}: expected 'IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME', got {s!r}")
        try:
            q = np.array([float(v) for v in parts[1:5]])
            t = np.array([float(v) for v in parts[5:8]])
            cid = int(parts[8])
        except ValueError:
            raise ClothFitError(f"{where}: non-numeric image entry {s!r}") from None
        if not np.all(np.isfinite(q)) or np.linalg.norm(q) < 1e-12:
            raise ClothFitError(f"{where}: quaternion {q.tolist()} is not a rotation")
        if cid not in intr:
            raise ClothFitError(f"{where}: camera id {cid} is not in {cpath}")
        images.append((parts[9].strip(), _quat_to_R(q), t, cid, where))
        i += 1
        if i < len(lines) and _is_points_line(lines[i][1]):
            i += 1  # the POINTS2D line that follows an image line (often empty)
    if not images:
        raise ClothFitError(f"{ipath}: no images")
    return _colmap_cameras(images, intr, ipath)


def write_colmap(folder: str, cameras: Sequence[Camera], image_ext: str = ".png") -> str:
    """A COLMAP text model: one COLMAP camera and one image (``<name><image_ext>``) per Camera."""
    from ..safeio import atomic_write

    os.makedirs(folder, exist_ok=True)
    for c in cameras:
        check_camera_name(c.name, f"COLMAP export to {folder}")
    files = {}
    with _Text(files, "cameras.txt") as f:
        f.write("# Camera list with one line of data per camera:\n")
        f.write("#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n")
        f.write(f"# Number of cameras: {len(cameras)}\n")
        f.write("# Written by Silhouette Cloth Fit: principal point in COLMAP's convention (pixel centres at +0.5)\n")
        for i, c in enumerate(cameras):
            model, params = intrinsics_to_colmap(c)
            f.write(f"{i + 1} {model} {c.width} {c.height} " + " ".join(repr(float(p)) for p in params) + "\n")
    with _Text(files, "images.txt") as f:
        f.write("# Image list with two lines of data per image:\n")
        f.write("#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n")
        f.write("#   POINTS2D[] as (X, Y, POINT3D_ID)\n")
        f.write(f"# Number of images: {len(cameras)}, mean observations per image: 0\n")
        for i, c in enumerate(cameras):
            q = _R_to_quat(c.R)
            vals = " ".join(repr(float(v)) for v in (*q, *c.t))
            f.write(f"{i + 1} {vals} {i + 1} {c.name}{image_ext}\n\n")
    with _Text(files, "points3D.txt") as f:
        f.write("# 3D point list with one line of data per point:\n")
        f.write("#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n")
        f.write("# Number of points: 0, mean track length: 0\n")
    for name, text in files.items():  # each file whole, never through a planted symlink
        atomic_write(os.path.join(folder, name), text.encode("utf-8"))
    return folder


# ================================================================ COLMAP binary

COLMAP_MODEL_IDS = {
    0: "SIMPLE_PINHOLE",
    1: "PINHOLE",
    2: "SIMPLE_RADIAL",
    3: "RADIAL",
    4: "OPENCV",
    5: "OPENCV_FISHEYE",
    6: "FULL_OPENCV",
    7: "FOV",
    8: "SIMPLE_RADIAL_FISHEYE",
    9: "RADIAL_FISHEYE",
    10: "THIN_PRISM_FISHEYE",
}
COLMAP_MODEL_NPARAMS = {0: 3, 1: 4, 2: 4, 3: 5, 4: 8, 5: 8, 6: 12, 7: 5, 8: 4, 9: 5, 10: 12}


class _Bin:
    def __init__(self, path):
        if not os.path.isfile(path):
            raise ClothFitError(f"COLMAP model file not found: {path}")
        with open(path, "rb") as f:
            self.data = f.read()
        self.pos, self.path = 0, path

    def read(self, fmt):
        import struct

        n = struct.calcsize("<" + fmt)
        if self.pos + n > len(self.data):
            raise ClothFitError(
                f"COLMAP binary file {self.path}: truncated at byte {self.pos} (file has {len(self.data)} bytes)"
            )
        v = struct.unpack_from("<" + fmt, self.data, self.pos)
        self.pos += n
        return v

    def name(self):
        end = self.data.find(b"\0", self.pos)
        if end < 0:
            raise ClothFitError(f"COLMAP binary file {self.path}: truncated image name at byte {self.pos}")
        s = self.data[self.pos : end].decode("utf-8", errors="replace")
        self.pos = end + 1
        return s


def read_colmap_bin(folder: str) -> list:
    """Cameras of a COLMAP binary model folder (``cameras.bin`` + ``images.bin``), one per image."""
    cpath, ipath = os.path.join(folder, "cameras.bin"), os.path.join(folder, "images.bin")
    b = _Bin(cpath)
    intr = {}
    (n,) = b.read("Q")
    for k in range(n):
        cid, mid, w, h = b.read("iiQQ")
        where = f"{cpath} camera #{k} (id {cid})"
        if mid not in COLMAP_MODEL_IDS:
            raise ClothFitError(f"{where}: unknown camera model id {mid} (a corrupt file?)")
        params = b.read("d" * COLMAP_MODEL_NPARAMS[mid])
        K, dist = colmap_to_intrinsics(COLMAP_MODEL_IDS[mid], params, where)
        if cid in intr:
            raise ClothFitError(f"{where}: camera id {cid} defined twice")
        intr[cid] = (K, dist, int(w), int(h))
    if b.pos != len(b.data):
        raise ClothFitError(
            f"COLMAP binary file {cpath}: {len(b.data) - b.pos} bytes left after {n} cameras (not a cameras.bin?)"
        )
    if not intr:
        raise ClothFitError(f"{cpath}: no cameras")
    b = _Bin(ipath)
    (n,) = b.read("Q")
    images = []
    for k in range(n):
        iid, qw, qx, qy, qz, tx, ty, tz, cid = b.read("idddddddi")
        name = b.name()
        (npts,) = b.read("Q")
        if b.pos + 24 * npts > len(b.data):
            raise ClothFitError(f"COLMAP binary file {ipath}: truncated in the 2D points of image {name!r}")
        b.pos += 24 * npts
        where = f"{ipath} image #{k} ({name})"
        q = np.array([qw, qx, qy, qz])
        if not np.all(np.isfinite(q)) or np.linalg.norm(q) < 1e-12:
            raise ClothFitError(f"{where}: quaternion {q.tolist()} is not a rotation")
        if cid not in intr:
            raise ClothFitError(f"{where}: camera id {cid} is not in {cpath}")
        images.append((name, _quat_to_R(q), np.array([tx, ty, tz]), cid, where))
    if not images:
        raise ClothFitError(f"{ipath}: no images")
    return _colmap_cameras(images, intr, ipath)


def _colmap_cameras(images, intr, where_all):
    stems = [os.path.splitext(os.path.basename(n))[0] for n, *_ in images]
    if len(set(stems)) != len(stems):
        stems = [os.path.splitext(n)[0].replace("\\", "/").replace("/", "_") for n, *_ in images]
    cams = []
    for name, (_, R, t, cid, where) in zip(stems, images):
        K, dist, w, h = intr[cid][:4]
        cam = Camera.__new__(Camera)
        cam.K, cam.R, cam.t, cam.dist, cam.width, cam.height, cam.name = K.copy(), R, t, dist.copy(), w, h, name
        cam.validate(where)
        cams.append(cam)
    check_unique(cams, where_all)
    return cams


def colmap_folder(path: str) -> tuple[str, str]:
    """(folder, 'bin' | 'txt') of a COLMAP model given as a folder (or sparse/0 under it) or one of its files."""
    folder = path if os.path.isdir(path) else os.path.dirname(path)
    for f in (folder, os.path.join(folder, "sparse", "0"), os.path.join(folder, "sparse")):
        if os.path.isfile(os.path.join(f, "cameras.txt")) and os.path.isfile(os.path.join(f, "images.txt")):
            if os.path.isfile(path) and path.endswith(".bin"):
                return f, "bin"
            return f, "txt"
        if os.path.isfile(os.path.join(f, "cameras.bin")) and os.path.isfile(os.path.join(f, "images.bin")):
            return f, "bin"
    return folder, "txt"


class _Text:
    """``with _Text(files, name) as f: f.write(...)`` collects a text file into ``files[name]``."""

    def __init__(self, files, name):
        import io

        self.files, self.name, self.buf = files, name, io.StringIO()

    def __enter__(self):
        return self.buf

    def __exit__(self, *exc):
        self.files[self.name] = self.buf.getvalue()
        return False
