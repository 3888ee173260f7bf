"""The on-disk capture format (SPEC 6): cameras, frame times, handles, silhouettes, shapes.

One capture is one directory (full description: ``docs/capture_format.md``)::

    capture.json          format tag, version, scenario, frame times, file names, meta
    cameras.json          camera.save_cameras format (OpenCV convention)
    sil/{camera}/{frame:03d}.png   one 8-bit single-channel PNG per camera and frame,
                          0 = background, 255 = object
    shapes.npz            optional ground truth: positions (F, V, 3) [m], frame_times (F,)

The same format is written by the Blender renderer, by the synthetic generator and by the
real-footage extractor, and read by the fitter. Everything here is pure (numpy + cv2).
Every problem is a ``ClothFitError`` whose message names the file or the value at fault.
"""
from __future__ import annotations

import io
import json
import math
import os
import re
import string

import numpy as np

from ..errors import ClothFitError
from ..safeio import atomic_write
from ..physics.scenario import Scenario, Uncertainty
from .camera import Camera, check_camera_name, load_cameras, save_cameras

FORMAT = "silhouette-cloth-fit/capture"
VERSION = 1
CAPTURE_JSON = "capture.json"
CAMERAS_JSON = "cameras.json"
SHAPES_NPZ = "shapes.npz"
DEFAULT_PATTERN = "sil/{camera}/{frame:03d}.png"
PATTERN_FIELDS = ("camera", "frame", "time")
TIME_FORMAT = ".3f"          # how a bare {time} is formatted: 0.05 -> "0.050"
REQUIRED_KEYS = ("format", "version", "cameras", "scenario", "frame_times", "silhouettes")
MAX_FIELD_WIDTH = 32        # largest width / precision of a pattern field ({frame:03d})
FRAME_TIME_TOL = 1e-9        # top-level vs scenario vs shapes.npz frame times
DEFAULT_IGNORE_PATTERN = "ignore/{camera}/{frame:03d}.png"
MASK_KEYS = ("silhouette_ids", "ignore_ids", "matte_threshold", "ignore")   # how silhouettes are stored


# =============================================================== silhouette files

def _short_values(values, limit=8):
    vals = [int(v) if float(v).is_integer() else float(v) for v in values[:limit]]
    s = ", ".join(str(v) for v in vals)
    return s + (", ..." if len(values) > limit else "")


def _mask_from_array(mask, where: str) -> np.ndarray:
    """A 2D boolean array from bool / 0-1 / 0-255 numeric input (anything else is an error)."""
    m = np.asarray(mask)
    if m.ndim != 2:
        raise ClothFitError(f"{where}: a silhouette must be a 2D (H, W) array, got shape {m.shape}")
    if m.dtype == bool:
        return m
    if not np.issubdtype(m.dtype, np.number):
        raise ClothFitError(f"{where}: a silhouette must be boolean or numeric, got dtype {m.dtype}")
    vals = np.unique(m)
    if not np.all(np.isfinite(vals)):
        raise ClothFitError(f"{where}: the silhouette has non-finite values")
    if np.all(np.isin(vals, (0, 1))) or np.all(np.isin(vals, (0, 255))):
        return m > 0
    raise ClothFitError(f"{where}: the silhouette is not binary: values {_short_values(vals)} "
                        f"(expected bool, 0/1 or 0/255)")


def save_silhouette(path: str, mask) -> None:
    """Write ``mask`` (bool, 0/1 or 0/255; shape (H, W)) as an 8-bit single-channel PNG 0/255.

    Parent directories are created; the file is written to a temporary name and renamed, so a
    reader never sees half a PNG.
    """
    m = _mask_from_array(mask, f"silhouette {path}")
    if os.path.splitext(path)[1].lower() != ".png":
        raise ClothFitError(f"silhouette {path}: silhouettes are written as PNG (lossless); "
                            f"the file name must end with .png")
    img = np.where(m, 255, 0).astype(np.uint8)
    ok, buf = _imencode(".png", img)
    if not ok:
        raise ClothFitError(f"silhouette {path}: PNG encoding failed")
    d = os.path.dirname(path)
    try:
        if d:
            os.makedirs(d, exist_ok=True)
        _write_bytes_atomic(path, buf.tobytes())
    except OSError as e:
        raise ClothFitError(f"silhouette {path}: cannot write ({e})") from None


def _imencode(ext, img):
    import cv2
    return cv2.imencode(ext, img)


def _write_bytes_atomic(path: str, data: bytes):
    atomic_write(path, data)


def read_silhouette(path: str, expected_shape=None, binarize_threshold=None, allow_empty: bool = False,
                    source: str | None = None) -> np.ndarray:
    """Read a silhouette image -> bool array (H, W), True = object.

    Accepted: 8-bit (or 16-bit) images with values {0, max} or {0, 1}; single channel, or 3/4
    channels whose colour channels are equal (an alpha channel must be fully opaque). Anything
    else is "not binary" and an error, unless ``binarize_threshold`` (in 0..255, 8-bit scale) is
    given: then grey images (colour ones converted to grey) are thresholded, object = value >
    threshold. ``expected_shape`` = (H, W) checks the size; ``allow_empty=False`` rejects a
    silhouette without any object pixel. ``source`` (e.g. "camera 'cam00' frame 3") is added to
    messages.
    """
    import cv2
    where = f"silhouette {path}" + (f" ({source})" if source else "")
    if not os.path.isfile(path):
        raise ClothFitError(f"{where}: file not found" if os.path.exists(path) is False
                            else f"{where}: not a file")
    try:
        data = np.fromfile(path, dtype=np.uint8)
    except OSError as e:
        raise ClothFitError(f"{where}: cannot read ({e})") from None
    if data.size == 0:
        raise ClothFitError(f"{where}: the file is empty (0 bytes), not an image")
    try:
        img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    except cv2.error:  # pragma: no cover - depends on the OpenCV build
        img = None
    if img is None or img.size == 0:
        raise ClothFitError(f"{where}: corrupt or unreadable image ({data.size} bytes that OpenCV cannot decode)")

    if img.dtype == np.uint8:
        maxval = 255
    elif img.dtype == np.uint16:
        maxval = 65535
    else:
        raise ClothFitError(f"{where}: unsupported pixel type {img.dtype} (use an 8-bit PNG)")

    # ---- size first: a wrong-size image is wrong whatever its values
    h, w = img.shape[:2]
    if expected_shape is not None:
        eh, ew = int(expected_shape[0]), int(expected_shape[1])
        if (h, w) != (eh, ew):
            raise ClothFitError(f"{where}: image is {h} x {w} (H x W) but {eh} x {ew} was expected")

    # ---- channels -> one grey plane
    if img.ndim == 3:
        c = img.shape[2]
        if c in (2, 4):
            alpha = img[..., -1]
            n_transp = int(np.count_nonzero(alpha != maxval))
            if n_transp:
                raise ClothFitError(
                    f"{where}: has an alpha channel with {n_transp} non-opaque pixels; the silhouette must be "
                    f"in the grey value (0 background, 255 object), not in the alpha channel")
            img = img[..., :-1]
            c -= 1
        if c == 1:
            img = img[..., 0]
        elif c == 3:
            b, g, r = img[..., 0], img[..., 1], img[..., 2]
            differ = (b != g) | (g != r)
            n_diff = int(np.count_nonzero(differ))
            if n_diff:
                if binarize_threshold is None:
                    raise ClothFitError(
                        f"{where}: colour image whose channels differ in {n_diff} pixels; a silhouette must be "
                        f"grey (pass binarize_threshold to convert to grey and threshold)")
                img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
            else:
                img = b
        else:
            raise ClothFitError(f"{where}: unsupported number of channels {c}")
    grey = img

    # ---- values
    if binarize_threshold is not None:
        try:
            thr = float(binarize_threshold)
        except (TypeError, ValueError):
            raise ClothFitError(f"binarize_threshold must be a number in 0..255, got {binarize_threshold!r}") from None
        if not (0.0 <= thr < 255.0):
            raise ClothFitError(f"binarize_threshold must be in 0..255 (8-bit scale), got {binarize_threshold!r}")
        scaled = grey.astype(np.float64) * (255.0 / maxval) if maxval != 255 else grey
        mask = scaled > thr
    else:
        if grey.max(initial=0) <= 1:
            mask = grey > 0                      # 0/1 image
        else:
            bad = (grey != 0) & (grey != maxval)
            n_bad = int(np.count_nonzero(bad))
            if n_bad:
                vals = np.unique(grey[bad])
                raise ClothFitError(
                    f"{where}: not binary: {n_bad} pixels have values other than 0 and {maxval} "
                    f"({len(vals)} distinct offending values: {_short_values(vals)}); "
                    f"pass binarize_threshold to threshold grey images")
            mask = grey > 0
    if not allow_empty and not mask.any():
        raise ClothFitError(f"{where}: empty silhouette (no object pixel)")
    return mask


def _where(path, source):
    return f"silhouette {path}" + (f" ({source})" if source else "")


def _check_size(img, expected_shape, where):
    if expected_shape is not None:
        h, w = img.shape[:2]
        eh, ew = int(expected_shape[0]), int(expected_shape[1])
        if (h, w) != (eh, ew):
            raise ClothFitError(f"{where}: image is {h} x {w} (H x W) but {eh} x {ew} was expected")


def read_label_silhouette(path: str, silhouette_ids, ignore_ids=(), expected_shape=None, allow_empty: bool = False,
                          source: str | None = None):
    """A label image (palette or greyscale PNG, e.g. a SAM 2 / XMem / DAVIS mask) -> ``(mask, ignore)``.

    ``mask`` = pixels whose label is one of ``silhouette_ids`` (the cloth), ``ignore`` = pixels whose
    label is one of ``ignore_ids`` (occluders: truth unknown there) or None without ignore ids.
    The stored values are used as they are (palette indices, grey levels), never converted.
    """
    from .png import read_label_png
    where = _where(path, source)
    if not os.path.isfile(path):
        raise ClothFitError(f"{where}: file not found")
    labels = read_label_png(path, where)
    _check_size(labels, expected_shape, where)
    mask = np.isin(labels, np.asarray(silhouette_ids))
    ignore = np.isin(labels, np.asarray(ignore_ids)) if len(ignore_ids) else None
    if not allow_empty and not mask.any():
        present = np.unique(labels)
        raise ClothFitError(f"{where}: no cloth label: the image holds labels {_short_values(present, 12)} but "
                            f"silhouette_ids are {list(silhouette_ids)}")
    return mask, ignore


def read_matte(path: str, threshold: float, expected_shape=None, allow_empty: bool = False,
               source: str | None = None) -> np.ndarray:
    """An alpha matte (PNG; grey, or the alpha channel of grey + alpha / RGBA) -> object = value >
    ``threshold`` (0..1 of full scale, so 8- and 16-bit mattes take the same threshold)."""
    import cv2
    where = _where(path, source)
    if not os.path.isfile(path):
        raise ClothFitError(f"{where}: file not found")
    data = np.fromfile(path, dtype=np.uint8)
    if data.size == 0:
        raise ClothFitError(f"{where}: the file is empty (0 bytes), not an image")
    img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    if img is None or img.size == 0:
        raise ClothFitError(f"{where}: corrupt or unreadable image ({data.size} bytes that OpenCV cannot decode)")
    if img.dtype not in (np.uint8, np.uint16):
        raise ClothFitError(f"{where}: unsupported pixel type {img.dtype} for an alpha matte (8- or 16-bit)")
    _check_size(img, expected_shape, where)
    if img.ndim == 3:
        if img.shape[2] in (2, 4):
            img = img[..., -1]             # the alpha channel
        elif np.any(img[..., 0] != img[..., 1]) or np.any(img[..., 1] != img[..., 2]):
            raise ClothFitError(f"{where}: a colour image is not an alpha matte (use grey, grey + alpha or RGBA)")
        else:
            img = img[..., 0]
    scale = 255.0 if img.dtype == np.uint8 else 65535.0
    mask = img.astype(np.float64) > float(threshold) * scale
    if not allow_empty and not mask.any():
        raise ClothFitError(f"{where}: empty silhouette (no matte value above {threshold:g})")
    return mask


def check_mask_spec(d, where: str) -> dict:
    """The capture keys saying how silhouettes are stored (``MASK_KEYS``), checked; absent = binary PNGs.

    ``silhouette_ids``: silhouettes are label images (palette or greyscale PNGs) and these labels
    are the cloth; ``ignore_ids``: labels of occluders (needs ``silhouette_ids``); ``matte_threshold``
    (0 <= T < 1): silhouettes are alpha mattes, object = alpha > T; ``ignore``: a file pattern (the
    silhouette pattern's fields) of binary masks of pixels whose truth is unknown.
    """
    d = d or {}
    out = {}

    def ids(key):
        v = d.get(key)
        if v is None:
            return None
        if isinstance(v, (int, np.integer)) and not isinstance(v, bool):
            v = [v]
        if not isinstance(v, (list, tuple)) or not v or any(
                isinstance(x, bool) or not isinstance(x, (int, np.integer)) or not 0 <= x <= 65535 for x in v):
            raise ClothFitError(f"{where}: '{key}' must be a non-empty list of label values (integers 0..65535), "
                                f"got {v!r:.80}")
        return [int(x) for x in v]

    sil, ign = ids("silhouette_ids"), ids("ignore_ids")
    if sil is not None:
        out["silhouette_ids"] = sil
    if ign is not None:
        if sil is None:
            raise ClothFitError(f"{where}: 'ignore_ids' needs 'silhouette_ids' (label images)")
        both = sorted(set(sil) & set(ign))
        if both:
            raise ClothFitError(f"{where}: labels {both} are both in 'silhouette_ids' and in 'ignore_ids'")
        out["ignore_ids"] = ign
    t = d.get("matte_threshold")
    if t is not None:
        if sil is not None:
            raise ClothFitError(f"{where}: 'matte_threshold' (alpha mattes) and 'silhouette_ids' (label images) "
                                f"exclude each other")
        if isinstance(t, bool) or not isinstance(t, (int, float)) or not (0.0 <= float(t) < 1.0):
            raise ClothFitError(f"{where}: 'matte_threshold' must be a number in [0, 1) (fraction of full alpha), "
                                f"got {t!r}")
        out["matte_threshold"] = float(t)
    if d.get("ignore") is not None:
        out["ignore"] = check_pattern(d["ignore"], f"{where}: 'ignore' pattern")
    return out


# =========================================================================== pattern

class _Time(float):
    """A frame time that formats as ``0.050`` under a bare ``{time}``."""

    def __format__(self, spec):
        return format(float(self), spec or TIME_FORMAT)


def check_pattern(pattern, where: str = "silhouettes pattern") -> str:
    """Validate a silhouette file-name pattern and return it."""
    if not isinstance(pattern, str) or not pattern.strip():
        raise ClothFitError(f"{where}: must be a non-empty string, got {pattern!r}")
    try:
        parsed = list(string.Formatter().parse(pattern))
    except ValueError as e:
        raise ClothFitError(f"{where} {pattern!r}: bad braces ({e})") from None
    fields = set()
    for _, name, spec, conv in parsed:
        if name is None:
            continue
        if name not in PATTERN_FIELDS:
            raise ClothFitError(f"{where} {pattern!r}: unknown field {{{name}}} "
                                f"(allowed: {', '.join('{' + f + '}' for f in PATTERN_FIELDS)})")
        if conv:
            raise ClothFitError(f"{where} {pattern!r}: conversions (!{conv}) are not allowed")
        if spec and "{" in spec:
            raise ClothFitError(f"{where} {pattern!r}: nested fields are not allowed")
        if spec and any(int(n) > MAX_FIELD_WIDTH for n in re.findall(r"\d+", spec)):
            raise ClothFitError(f"{where} {pattern!r}: field width or precision in {{{name}:{spec}}} above "
                                f"{MAX_FIELD_WIDTH}")
        fields.add(name)
    if "camera" not in fields:
        raise ClothFitError(f"{where} {pattern!r}: must contain {{camera}}")
    if "frame" not in fields and "time" not in fields:
        raise ClothFitError(f"{where} {pattern!r}: must contain {{frame}} or {{time}}")
    norm = pattern.replace("\\", "/")
    if os.path.isabs(pattern) or norm.startswith("/") or re.match(r"^[A-Za-z]:", norm):
        raise ClothFitError(f"{where} {pattern!r}: must be relative to the capture directory")
    if ".." in norm.split("/"):
        raise ClothFitError(f"{where} {pattern!r}: must not leave the capture directory ('..')")
    try:
        pattern.format(camera="cam", frame=0, time=_Time(0.0))
    except (ValueError, TypeError, KeyError, IndexError) as e:
        raise ClothFitError(f"{where} {pattern!r}: cannot be formatted ({e})") from None
    return pattern


def _check_camera_name(name: str, where: str):
    check_camera_name(name, where)


def _field_regex(component: str, camera: str | None = None) -> re.Pattern:
    """Regex of one path component of the pattern: {camera} captured (or the literal ``camera``),
    {frame} digits, {time} a number."""
    out = []
    seen_camera = False
    for lit, name, spec, _ in string.Formatter().parse(component):
        out.append(re.escape(lit))
        if name == "camera":
            if camera is not None:
                out.append(re.escape(camera))
            else:
                out.append(r"(?P=camera)" if seen_camera else r"(?P<camera>[^/\\]+)")
            seen_camera = True
        elif name == "frame":
            out.append(r"[ +-]*\d+")
        elif name == "time":
            out.append(r"[ +\-0-9.eE]+")
    return re.compile("^" + "".join(out) + "$")


# =========================================================================== capture

class Capture:
    """A capture in memory: cameras, scenario, frame times and where the silhouettes are.

    Silhouettes are read on demand (``load_silhouette``). Frame indices refer to
    ``frame_times`` of this object; a ``subset`` keeps pointing at the right files.
    """

    def __init__(self, root, cameras, scenario: Scenario, pattern: str = DEFAULT_PATTERN, shapes=None,
                 cloth_mass=None, meta=None, json_path=None, _file_frames=None, _all_camera_names=None, model=None,
                 masks=None, uncertain=None):
        self.root = os.path.abspath(str(root))
        self.json_path = json_path or os.path.join(self.root, CAPTURE_JSON)
        where = f"capture {self.json_path}"
        self.cameras = list(cameras)
        if not self.cameras:
            raise ClothFitError(f"{where}: no cameras")
        for i, c in enumerate(self.cameras):
            if not isinstance(c, Camera):
                raise ClothFitError(f"{where}: camera #{i} is a {type(c).__name__}, not a Camera")
            _check_camera_name(c.name, where)
        names = [c.name for c in self.cameras]
        if len(set(names)) != len(names):
            raise ClothFitError(f"{where}: camera names are not unique: {names}")
        if not isinstance(scenario, Scenario):
            raise ClothFitError(f"{where}: scenario must be a Scenario, got {type(scenario).__name__}")
        self.scenario = scenario
        self.frame_times = np.asarray(scenario.frame_times, dtype=np.float64).copy()
        self.pattern = check_pattern(pattern, f"{where}: silhouettes pattern")
        self._file_frames = (np.arange(self.frame_times.size) if _file_frames is None
                             else np.asarray(_file_frames, dtype=np.int64))
        self._all_camera_names = list(_all_camera_names) if _all_camera_names is not None else names
        self.shapes = None if shapes is None else check_shapes(shapes, self.frame_times.size,
                                                               scenario.grid.n_vertices, where)
        self.cloth_mass = check_cloth_mass(cloth_mass, where)
        if meta is None:
            meta = {}
        if not isinstance(meta, dict):
            raise ClothFitError(f"{where}: meta must be an object/dict, got {type(meta).__name__}")
        self.meta = meta
        self.model = _check_model(model, where)
        self.masks = check_mask_spec(masks, where)
        if uncertain is not None and not isinstance(uncertain, Uncertainty):
            uncertain = Uncertainty.parse(uncertain, len(scenario.handles), f"{where}: uncertain")
        self.uncertain = uncertain        # what the manipulation could not measure (None: all exact)
        self._check_unique_paths()

    # ------------------------------------------------------------------ basics
    @property
    def n_cameras(self) -> int:
        return len(self.cameras)

    @property
    def n_frames(self) -> int:
        return int(self.frame_times.size)

    @property
    def camera_names(self):
        return [c.name for c in self.cameras]

    @property
    def point_mass(self):
        """``cloth_mass / n_vertices`` [kg] (the fixed m of SPEC 2), or None."""
        return None if self.cloth_mass is None else self.cloth_mass / self.scenario.grid.n_vertices

    def __repr__(self):
        return (f"Capture({self.root!r}, {self.n_cameras} cameras, {self.n_frames} frames, "
                f"shapes={'yes' if self.shapes is not None else 'no'})")

    def camera_index(self, name: str) -> int:
        for i, c in enumerate(self.cameras):
            if c.name == name:
                return i
        raise ClothFitError(f"capture {self.json_path}: no camera named {name!r} "
                            f"(cameras: {', '.join(self.camera_names)})")

    def frame_index(self, time: float, tol: float = 1e-6) -> int:
        try:
            t = float(time)
        except (TypeError, ValueError):
            raise ClothFitError(f"capture {self.json_path}: frame time must be a number, got {time!r}") from None
        d = np.abs(self.frame_times - t)
        i = int(np.argmin(d))
        if not (d[i] <= tol):
            avail = ", ".join(f"{x:g}" for x in self.frame_times)
            raise ClothFitError(f"capture {self.json_path}: time {t:g} s is not a frame of the capture "
                                f"(tolerance {tol:g}); available times: {avail}")
        return i

    def frame_indices(self, times, tol: float = 1e-6):
        return [self.frame_index(t, tol) for t in times]

    def _check_cam(self, ci):
        if not isinstance(ci, (int, np.integer)) or not (0 <= ci < self.n_cameras):
            raise ClothFitError(f"capture {self.json_path}: camera index {ci!r} out of range 0..{self.n_cameras - 1}")
        return int(ci)

    def _check_frame(self, fi):
        if not isinstance(fi, (int, np.integer)) or not (0 <= fi < self.n_frames):
            raise ClothFitError(f"capture {self.json_path}: frame index {fi!r} out of range 0..{self.n_frames - 1}")
        return int(fi)

    # ------------------------------------------------------------- silhouettes
    def _relpath(self, name: str, file_frame: int, time: float) -> str:
        return self.pattern.format(camera=name, frame=int(file_frame), time=_Time(time))

    def silhouette_path(self, cam_index: int, frame_index: int) -> str:
        ci, fi = self._check_cam(cam_index), self._check_frame(frame_index)
        rel = self._relpath(self.cameras[ci].name, self._file_frames[fi], self.frame_times[fi])
        return os.path.join(self.root, *rel.replace("\\", "/").split("/"))

    def ignore_path(self, cam_index: int, frame_index: int):
        """The ignore mask file of a camera and frame (the capture's ``ignore`` pattern), or None."""
        if "ignore" not in self.masks:
            return None
        ci, fi = self._check_cam(cam_index), self._check_frame(frame_index)
        rel = self.masks["ignore"].format(camera=self.cameras[ci].name, frame=int(self._file_frames[fi]),
                                          time=_Time(self.frame_times[fi]))
        return os.path.join(self.root, *rel.replace("\\", "/").split("/"))

    @property
    def has_ignore(self) -> bool:
        """True when the capture marks pixels of unknown truth (``ignore_ids`` or an ``ignore`` pattern)."""
        return "ignore_ids" in self.masks or "ignore" in self.masks

    def load_observation(self, cam_index: int, frame_index: int, allow_empty: bool = False,
                         binarize_threshold=None):
        """``(mask, ignore)`` of a camera and frame: the cloth silhouette (bool (H, W)) and the pixels
        whose truth is unknown (bool (H, W), or None when the capture marks none). Cloth pixels under
        an ignore mask are not cloth (they count as unknown); the silhouette must keep some pixel
        outside the ignored ones (eq. 6 divides by that area) unless ``allow_empty``."""
        ci, fi = self._check_cam(cam_index), self._check_frame(frame_index)
        cam = self.cameras[ci]
        shape = (cam.height, cam.width)
        src = f"camera '{cam.name}', frame {fi}, t={self.frame_times[fi]:g} s"
        path = self.silhouette_path(ci, fi)
        ignore = None
        if "silhouette_ids" in self.masks:
            mask, ignore = read_label_silhouette(path, self.masks["silhouette_ids"], self.masks.get("ignore_ids", ()),
                                                 shape, allow_empty=allow_empty, source=src)
        elif "matte_threshold" in self.masks:
            mask = read_matte(path, self.masks["matte_threshold"], shape, allow_empty=allow_empty, source=src)
        else:
            mask = read_silhouette(path, shape, binarize_threshold=binarize_threshold, allow_empty=allow_empty,
                                   source=src)
        if "ignore" in self.masks:
            extra = read_silhouette(self.ignore_path(ci, fi), shape, allow_empty=True,
                                    source=f"ignore mask of {src}")
            ignore = extra if ignore is None else (ignore | extra)
        if ignore is not None:
            mask = mask & ~ignore
            if not allow_empty and not mask.any():
                raise ClothFitError(f"{_where(path, src)}: every cloth pixel is ignored (hidden by the ignore mask "
                                    f"or ignore labels): nothing left to compare")
        return mask, ignore

    def load_silhouette(self, cam_index: int, frame_index: int, allow_empty: bool = False,
                        binarize_threshold=None) -> np.ndarray:
        """bool (H, W) silhouette of camera ``cam_index`` at frame ``frame_index`` (validated); pixels
        of unknown truth (``load_observation``) are not part of it."""
        return self.load_observation(cam_index, frame_index, allow_empty, binarize_threshold)[0]

    def load_silhouettes(self, cam_indices=None, frame_indices=None, allow_empty: bool = False,
                         binarize_threshold=None):
        """``[[mask for frame in frame_indices] for cam in cam_indices]`` (None = all)."""
        cams = range(self.n_cameras) if cam_indices is None else cam_indices
        frames = range(self.n_frames) if frame_indices is None else list(frame_indices)
        return [[self.load_silhouette(ci, fi, allow_empty, binarize_threshold) for fi in frames] for ci in cams]

    def load_observations(self, cam_indices=None, frame_indices=None, allow_empty: bool = False):
        """``(masks, ignores)``, each ``[cam][frame]`` (an ignore entry is None where nothing is ignored)."""
        cams = range(self.n_cameras) if cam_indices is None else cam_indices
        frames = range(self.n_frames) if frame_indices is None else list(frame_indices)
        pairs = [[self.load_observation(ci, fi, allow_empty) for fi in frames] for ci in cams]
        return [[m for m, _ in row] for row in pairs], [[i for _, i in row] for row in pairs]

    def _check_unique_paths(self):
        seen = {}
        patterns = [("silhouettes", self.pattern)] + ([("ignore", self.masks["ignore"])] if "ignore" in self.masks else [])
        for kind, pat in patterns:
            for ci, c in enumerate(self.cameras):
                for fi in range(self.n_frames):
                    p = pat.format(camera=c.name, frame=int(self._file_frames[fi]), time=_Time(self.frame_times[fi]))
                    if p in seen:
                        raise ClothFitError(
                            f"capture {self.json_path}: {kind} pattern {pat!r} gives the same file {p} "
                            f"to {seen[p]} and to camera '{c.name}' frame {fi}{f' ({kind})' if kind != 'silhouettes' else ''}")
                    seen[p] = f"camera '{c.name}' frame {fi}" + (f" ({kind})" if kind != "silhouettes" else "")

    # ------------------------------------------------------------------ subset
    def subset(self, cam_indices=None, frame_indices=None) -> "Capture":
        """The same capture restricted to some cameras and frames (files are not touched)."""
        cams = list(range(self.n_cameras)) if cam_indices is None else [self._check_cam(c) for c in cam_indices]
        frames = list(range(self.n_frames)) if frame_indices is None else [self._check_frame(f) for f in frame_indices]
        if not cams or not frames:
            raise ClothFitError(f"capture {self.json_path}: a subset needs at least one camera and one frame")
        if np.any(np.diff(frames) <= 0):
            raise ClothFitError(f"capture {self.json_path}: subset frame indices must increase, got {frames}")
        if len(set(cams)) != len(cams):
            raise ClothFitError(f"capture {self.json_path}: subset camera indices repeat: {cams}")
        scen = self.scenario.with_frames(self.frame_times[frames])
        shapes = None if self.shapes is None else self.shapes[frames]
        return Capture(self.root, [self.cameras[c] for c in cams], scen, self.pattern, shapes, self.cloth_mass,
                       dict(self.meta), self.json_path, self._file_frames[frames], self._all_camera_names, model=self.model,
                       masks=self.masks, uncertain=self.uncertain)

    # ---------------------------------------------------------------- validate
    def validate(self, full: bool = True, allow_empty: bool = False, binarize_threshold=None) -> "Capture":
        """Check the capture against its files; raise one ClothFitError describing the problems.

        Always: the silhouette directory layout matches the cameras ("camera count mismatch"
        when the silhouette tree holds a camera that is not in cameras.json, or a camera of
        cameras.json has no silhouette at all), shapes are (F, V, 3). With ``full``, every
        silhouette of every camera and frame is also read and checked (exists, decodes, size,
        binary, not empty).
        """
        where = f"capture {self.json_path}"
        names = self.camera_names
        # ---- silhouette tree vs cameras
        found = self._scan_camera_names()
        unknown = [] if found is None else sorted(set(found) - set(self._all_camera_names))
        without = [c.name for ci, c in enumerate(self.cameras)
                   if not any(os.path.isfile(self.silhouette_path(ci, fi)) for fi in range(self.n_frames))]
        if unknown or without:
            all_names = self._all_camera_names
            msg = (f"{where}: camera count mismatch: cameras.json lists {len(all_names)} cameras "
                   f"({_names_str(all_names)})")
            if found is not None:
                msg += (f" but the silhouettes (pattern {self.pattern!r}) are for {len(set(found))} cameras "
                        f"({_names_str(sorted(set(found)))})")
            if unknown:
                msg += f"; silhouettes of cameras not in cameras.json: {', '.join(unknown)}"
            if without:
                msg += (f"; cameras without any silhouette: {', '.join(without)} (expected e.g. "
                        f"{self.silhouette_path(names.index(without[0]), 0)})")
            raise ClothFitError(msg)
        # ---- shapes
        if self.shapes is not None:
            check_shapes(self.shapes, self.n_frames, self.scenario.grid.n_vertices, where)
        # ---- every file
        if full:
            problems = []
            for ci in range(self.n_cameras):
                for fi in range(self.n_frames):
                    try:
                        self.load_observation(ci, fi, allow_empty=allow_empty, binarize_threshold=binarize_threshold)
                    except ClothFitError as e:
                        problems.append(str(e))
            if problems:
                head = "\n  ".join(problems[:10])
                more = f"\n  ... and {len(problems) - 10} more" if len(problems) > 10 else ""
                raise ClothFitError(f"{where}: {len(problems)} bad silhouette file(s) of "
                                    f"{self.n_cameras * self.n_frames}:\n  {head}{more}")
        return self

    def _scan_camera_names(self):
        """Camera names present in the silhouette tree, or None when the pattern cannot be scanned.

        The tree is scanned at the first path component holding {camera}; the components before
        it must be plain directories. If that component is a directory level (e.g. sil/{camera}/...)
        sub-directories are matched, else files.
        """
        parts = self.pattern.replace("\\", "/").split("/")
        k = next(i for i, p in enumerate(parts) if "{camera" in p)
        for p in parts[:k]:
            if any(name is not None for _, name, _, _ in string.Formatter().parse(p)):
                return None
        parent = os.path.join(self.root, *parts[:k]) if k else self.root
        if not os.path.isdir(parent):
            return []
        rx = _field_regex(parts[k])
        known = [(n, _field_regex(parts[k], n)) for n in self._all_camera_names]
        is_dir_level = k < len(parts) - 1
        names = []
        for entry in sorted(os.listdir(parent)):
            if entry.startswith(".") or entry.endswith(".tmp"):
                continue
            full = os.path.join(parent, entry)
            if is_dir_level != os.path.isdir(full):
                continue
            name = next((n for n, r in known if r.match(entry)), None)
            if name is None:
                m = rx.match(entry)
                name = m.group("camera") if m else None
            if name is not None:
                names.append(name)
        return names

    # ------------------------------------------------------------------ io
    def to_dict(self) -> dict:
        d = {"format": FORMAT, "version": VERSION, "cameras": CAMERAS_JSON,
             "scenario": self.scenario.to_dict(), "frame_times": self.frame_times.tolist(),
             "silhouettes": self.pattern}
        if self.shapes is not None:
            d["shapes"] = SHAPES_NPZ
        if self.cloth_mass is not None:
            d["cloth_mass"] = self.cloth_mass
        if self.model is not None:
            d["model"] = self.model
        d.update(self.masks)
        if self.uncertain is not None:
            d["uncertain"] = self.uncertain.to_dict()
        d["meta"] = self.meta
        return d


# ================================================================= value checks

def _check_model(model, where: str):
    """The capture's optional ``model`` (the model a fit uses unless told otherwise), as a dict."""
    if model is None:
        return None
    from ..physics.models import get_model
    try:
        return get_model(model).to_dict()
    except ClothFitError as e:
        raise ClothFitError(f"{where}: 'model': {e}") from None


def check_shapes(shapes, n_frames: int, n_vertices: int, where: str) -> np.ndarray:
    try:
        s = np.asarray(shapes, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise ClothFitError(f"{where}: shapes are not numeric ({e})") from None
    if s.ndim != 3 or s.shape[2] != 3:
        raise ClothFitError(f"{where}: shapes must be (F, V, 3) vertex positions, got shape {s.shape}")
    if s.shape[0] != n_frames:
        raise ClothFitError(f"{where}: shapes have {s.shape[0]} frames but the capture has {n_frames} frame times")
    if s.shape[1] != n_vertices:
        raise ClothFitError(f"{where}: shapes have {s.shape[1]} vertices per frame but the cloth grid has "
                            f"{n_vertices} vertices (shape {s.shape}, expected ({n_frames}, {n_vertices}, 3))")
    if not np.all(np.isfinite(s)):
        raise ClothFitError(f"{where}: shapes contain {int(np.count_nonzero(~np.isfinite(s)))} non-finite values")
    return s


def check_cloth_mass(cloth_mass, where: str):
    if cloth_mass is None:
        return None
    if isinstance(cloth_mass, bool):
        raise ClothFitError(f"{where}: cloth_mass must be a number in kg, got {cloth_mass!r}")
    try:
        v = float(cloth_mass)
    except (TypeError, ValueError):
        raise ClothFitError(f"{where}: cloth_mass must be a number in kg, got {cloth_mass!r}") from None
    if not math.isfinite(v) or v <= 0:
        raise ClothFitError(f"{where}: cloth_mass must be a positive finite mass in kg, got {cloth_mass!r}")
    return v


def _check_frame_times(value, where: str, name: str) -> np.ndarray:
    if not isinstance(value, (list, tuple)) or not value:
        raise ClothFitError(f"{where}: {name} must be a non-empty list of times in seconds, got {value!r:.80}")
    try:
        t = np.array([float(x) for x in value if not isinstance(x, bool)], dtype=np.float64)
    except (TypeError, ValueError):
        raise ClothFitError(f"{where}: {name} must contain numbers only, got {value!r:.80}") from None
    if t.size != len(value) or not np.all(np.isfinite(t)):
        raise ClothFitError(f"{where}: {name} must contain finite numbers only, got {value!r:.80}")
    return t


def _names_str(names, limit=20):
    names = list(names)
    return ", ".join(names[:limit]) + (f", ... ({len(names)} in all)" if len(names) > limit else "")


def _times_str(t, limit=8):
    s = ", ".join(f"{x:g}" for x in t[:limit])
    return f"[{s}{', ...' if len(t) > limit else ''}] ({len(t)} times)"


# ========================================================================= loading

def _resolve(root: str, rel, where: str, key: str) -> str:
    if not isinstance(rel, str) or not rel.strip():
        raise ClothFitError(f"{where}: '{key}' must be a file name, got {rel!r}")
    return rel if os.path.isabs(rel) else os.path.join(root, rel)


def load_capture(path, validate: bool = False) -> Capture:
    """Read a capture directory (or its capture.json). Silhouettes are not read here.

    The JSON structure, cameras.json and shapes.npz are checked with precise messages; with
    ``validate=True`` also ``Capture.validate(full=True)`` (every silhouette file).
    """
    path = os.fspath(path)
    if os.path.isdir(path):
        json_path = os.path.join(path, CAPTURE_JSON)
        if not os.path.isfile(json_path):
            if os.path.isfile(os.path.join(path, CAMERAS_JSON)):  # a writer started but did not finish
                raise ClothFitError(f"capture directory {path}: {CAPTURE_JSON} missing: the capture is incomplete "
                                    f"({CAMERAS_JSON} was written but the writer never finalised it, e.g. a "
                                    f"render or extraction stopped midway); write the capture again")
            raise ClothFitError(f"capture directory {path} has no {CAPTURE_JSON} ({CAPTURE_JSON} missing: "
                                f"{json_path})")
    elif os.path.isfile(path):
        json_path = path
    else:
        raise ClothFitError(f"capture not found: {path} (give a capture directory or its {CAPTURE_JSON})")
    root = os.path.dirname(os.path.abspath(json_path))
    where = json_path

    try:
        with open(json_path, "rb") as f:
            raw = f.read()
        text = raw.decode("utf-8-sig")
    except (OSError, UnicodeDecodeError) as e:
        raise ClothFitError(f"{where}: cannot read ({e})") from None
    try:
        d = json.loads(text)
    except json.JSONDecodeError as e:
        raise ClothFitError(f"{where}: invalid JSON at line {e.lineno}, column {e.colno}: {e.msg}") from None
    if not isinstance(d, dict):
        raise ClothFitError(f"{where}: expected a JSON object at the top level, got {type(d).__name__}")

    fmt = d.get("format")
    if fmt != FORMAT:
        raise ClothFitError(f"{where}: 'format' is {fmt!r}, expected {FORMAT!r} (is this a capture.json?)")
    missing = [k for k in REQUIRED_KEYS if k not in d]
    if missing:
        raise ClothFitError(f"{where}: missing key(s) {', '.join(repr(k) for k in missing)}")
    ver = d["version"]
    if isinstance(ver, bool) or not isinstance(ver, int):
        raise ClothFitError(f"{where}: 'version' must be an integer, got {ver!r}")
    if ver != VERSION:
        raise ClothFitError(f"{where}: capture format version {ver} is not supported (this reader knows version "
                            f"{VERSION})")

    # ---- scenario and frame times
    if not isinstance(d["scenario"], dict):
        raise ClothFitError(f"{where}: 'scenario' must be an object, got {type(d['scenario']).__name__}")
    try:
        scenario = Scenario.from_dict(d["scenario"], source=f"{where} scenario")
    except ClothFitError as e:
        msg = str(e)
        raise ClothFitError(msg if where in msg else f"{where}: {msg}") from None
    except (TypeError, ValueError, AttributeError, KeyError) as e:
        raise ClothFitError(f"{where}: bad 'scenario' ({type(e).__name__}: {e})") from None
    top = _check_frame_times(d["frame_times"], where, "'frame_times'")
    st = scenario.frame_times
    if top.shape != st.shape or np.max(np.abs(top - st)) > FRAME_TIME_TOL:
        raise ClothFitError(f"{where}: frame_times mismatch between the top level {_times_str(top)} and "
                            f"the scenario {_times_str(st)}")

    pattern = check_pattern(d["silhouettes"], f"{where}: 'silhouettes' pattern")

    # ---- cameras
    cam_path = _resolve(root, d["cameras"], where, "cameras")
    if not os.path.isfile(cam_path):
        raise ClothFitError(f"{where}: cameras file {cam_path} not found (named by 'cameras': {d['cameras']!r})")
    cameras = load_cameras(cam_path)

    # ---- optional parts
    shapes = None
    if d.get("shapes") is not None:
        shapes_path = _resolve(root, d["shapes"], where, "shapes")
        shapes = read_shapes(shapes_path, scenario.frame_times, scenario.grid.n_vertices)
    cloth_mass = check_cloth_mass(d.get("cloth_mass"), where)
    meta = d.get("meta", {})
    if meta is None:
        meta = {}
    if not isinstance(meta, dict):
        raise ClothFitError(f"{where}: 'meta' must be an object, got {type(meta).__name__}")

    masks = check_mask_spec({k: d.get(k) for k in MASK_KEYS}, where)
    cap = Capture(root, cameras, scenario, pattern, shapes, cloth_mass, meta, json_path=json_path,
                  model=d.get("model"), masks=masks, uncertain=d.get("uncertain"))
    if validate:
        cap.validate(full=True)
    return cap


def read_shapes(path: str, frame_times=None, n_vertices=None) -> np.ndarray:
    """``positions`` (F, V, 3) of a shapes.npz, checked against the capture's frames and grid."""
    where = f"shapes file {path}"
    if not os.path.isfile(path):
        raise ClothFitError(f"{where}: not found")
    try:
        with np.load(path, allow_pickle=False) as z:
            keys = list(z.files)
            if "positions" not in keys:
                raise ClothFitError(f"{where}: no 'positions' array (arrays present: {', '.join(keys) or 'none'})")
            pos = np.array(z["positions"])
            ft = np.array(z["frame_times"]) if "frame_times" in keys else None
    except ClothFitError:
        raise
    except Exception as e:  # zipfile.BadZipFile, ValueError, OSError, EOFError...
        raise ClothFitError(f"{where}: corrupt or unreadable .npz ({type(e).__name__}: {e})") from None
    if frame_times is not None and n_vertices is not None:
        pos = check_shapes(pos, len(frame_times), n_vertices, where)
    if ft is not None and frame_times is not None:
        ft = ft.reshape(-1).astype(np.float64)
        ref = np.asarray(frame_times, dtype=np.float64)
        if ft.shape != ref.shape or np.max(np.abs(ft - ref)) > FRAME_TIME_TOL:
            raise ClothFitError(f"{where}: frame_times {_times_str(ft)} differ from the capture's {_times_str(ref)}")
    return pos


# ========================================================================= writing

def _json_default(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    raise TypeError(f"{type(o).__name__} is not JSON serialisable")


def write_capture(root, cameras, scenario: Scenario, silhouettes, shapes=None, cloth_mass=None, meta=None,
                  pattern: str = DEFAULT_PATTERN, allow_empty: bool = False, finalize: bool = True, model=None,
                  ignore=None, ignore_pattern: str = DEFAULT_IGNORE_PATTERN, uncertain=None):
    """Write a capture directory and return it as a ``Capture`` (or a ``PendingCapture``).

    ``silhouettes[c][f]`` (bool / 0-1 / 0-255 arrays of camera c's height x width) for every
    camera and every frame of ``scenario.frame_times``; or None when the caller writes each PNG
    itself at ``capture.silhouette_path(c, f)`` with ``save_silhouette`` (a renderer).
    Order: an old capture.json is removed first, then cameras.json, shapes.npz and the PNGs, and
    capture.json is written last (temporary file + rename), so a directory with a capture.json
    is always complete.

    ``finalize=False`` (the two-step API for renderers): everything but capture.json is written
    and a :class:`PendingCapture` is returned; the caller writes the silhouettes, then calls
    :func:`finalize_capture` (which checks that every silhouette file exists) to write
    capture.json. A writer that fails midway thus leaves no capture.json, and loading the
    directory says "capture.json missing". ``finalize=True`` with ``silhouettes=None`` writes
    capture.json at once (a metadata-only capture, e.g. a cameras container): only for callers
    that do not need the PNGs to be there.

    ``ignore[c][f]`` (bool arrays or None = nothing ignored): pixels whose truth is unknown
    (occluders), written as binary PNGs under ``ignore_pattern`` and named by the capture's
    ``ignore`` key. ``ignore=True`` with ``silhouettes=None``: the renderer writes them too, at
    ``capture.ignore_path(c, f)``.
    """
    root = os.path.abspath(os.fspath(root))
    masks = {"ignore": ignore_pattern} if ignore is not None else None
    cap = Capture(root, cameras, scenario, pattern, shapes, cloth_mass, meta, model=model, masks=masks,
                  uncertain=uncertain)
    where = f"capture {cap.json_path}"
    if os.path.splitext(cap.pattern)[1].lower() != ".png":
        raise ClothFitError(f"{where}: silhouettes pattern {cap.pattern!r} must end with .png "
                            f"(silhouettes are written as lossless PNG)")
    try:
        text = json.dumps(cap.to_dict(), indent=1, default=_json_default, allow_nan=False)
    except (TypeError, ValueError) as e:
        raise ClothFitError(f"{where}: meta is not JSON serialisable ({e})") from None
    cap.meta = json.loads(text)["meta"]   # what a reader will get back

    ign_arrays = ignore if ignore is not None and ignore is not True else None
    if silhouettes is not None:
        _check_silhouettes(cap, silhouettes, allow_empty, where, ign_arrays)

    try:
        os.makedirs(root, exist_ok=True)
        if os.path.exists(cap.json_path):
            os.remove(cap.json_path)
        save_cameras(os.path.join(root, CAMERAS_JSON), cap.cameras)
        if cap.shapes is not None:
            buf = io.BytesIO()
            np.savez_compressed(buf, positions=cap.shapes, frame_times=cap.frame_times)
            atomic_write(os.path.join(root, SHAPES_NPZ), buf.getvalue())
    except OSError as e:
        raise ClothFitError(f"{where}: cannot write ({e})") from None

    if silhouettes is not None:
        for ci in range(cap.n_cameras):
            for fi in range(cap.n_frames):
                save_silhouette(cap.silhouette_path(ci, fi), silhouettes[ci][fi])
    else:
        for ci in range(cap.n_cameras):
            os.makedirs(os.path.dirname(cap.silhouette_path(ci, 0)), exist_ok=True)
            if cap.has_ignore:
                os.makedirs(os.path.dirname(cap.ignore_path(ci, 0)), exist_ok=True)
    if ign_arrays is not None:
        for ci, cam in enumerate(cap.cameras):
            for fi in range(cap.n_frames):
                m = ign_arrays[ci][fi]
                save_silhouette(cap.ignore_path(ci, fi), np.zeros((cam.height, cam.width), bool) if m is None else m)

    pending = PendingCapture(cap, text)
    if not finalize:
        return pending
    return pending.finalize(check_files=silhouettes is not None)


class PendingCapture:
    """A capture written except for its capture.json (``write_capture(..., finalize=False)``).

    ``capture`` is the ``Capture`` it will become (``silhouette_path`` etc. work already);
    :meth:`finalize` / :func:`finalize_capture` writes capture.json once every silhouette is there.
    Until then ``load_capture`` refuses the directory ("capture.json missing").
    """

    def __init__(self, capture: Capture, text: str):
        self.capture = capture
        self._text = text
        self.finalized = False

    @property
    def root(self):
        return self.capture.root

    @property
    def json_path(self):
        return self.capture.json_path

    def silhouette_path(self, cam_index: int, frame_index: int) -> str:
        return self.capture.silhouette_path(cam_index, frame_index)

    def ignore_path(self, cam_index: int, frame_index: int):
        return self.capture.ignore_path(cam_index, frame_index)

    def missing_silhouettes(self):
        """Paths of the silhouette (and ignore mask) files not written yet."""
        cap = self.capture
        paths = [cap.silhouette_path(ci, fi) for ci in range(cap.n_cameras) for fi in range(cap.n_frames)]
        if cap.has_ignore:
            paths += [cap.ignore_path(ci, fi) for ci in range(cap.n_cameras) for fi in range(cap.n_frames)]
        return [p for p in paths if not os.path.isfile(p)]

    def finalize(self, check_files: bool = True) -> Capture:
        """Write capture.json (temporary file + rename) and return the ``Capture``.

        ``check_files``: refuse (ClothFitError naming the missing files) unless every
        silhouette file exists. The files' contents are not read (``validate`` does that)."""
        where = f"capture {self.json_path}"
        if check_files:
            missing = self.missing_silhouettes()
            if missing:
                n = self.capture.n_cameras * self.capture.n_frames
                head = "\n  ".join(missing[:5])
                more = f"\n  ... and {len(missing) - 5} more" if len(missing) > 5 else ""
                raise ClothFitError(f"{where}: cannot finalise: {len(missing)} of {n} silhouette files are "
                                    f"missing:\n  {head}{more}")
        try:
            _write_bytes_atomic(self.json_path, self._text.encode("utf-8"))
        except OSError as e:
            raise ClothFitError(f"{where}: cannot write ({e})") from None
        self.finalized = True
        return self.capture

    def __repr__(self):
        return f"PendingCapture({self.root!r}, finalized={self.finalized})"


def finalize_capture(pending: PendingCapture, check_files: bool = True) -> Capture:
    """Second step of ``write_capture(..., finalize=False)``: write capture.json last."""
    if not isinstance(pending, PendingCapture):
        raise ClothFitError(f"finalize_capture needs the PendingCapture returned by write_capture(..., "
                            f"finalize=False), got {type(pending).__name__}")
    return pending.finalize(check_files)


def _check_silhouettes(cap: Capture, silhouettes, allow_empty: bool, where: str, ignore=None):
    try:
        n = len(silhouettes)
    except TypeError:
        raise ClothFitError(f"{where}: silhouettes must be indexable [camera][frame], "
                            f"got {type(silhouettes).__name__}") from None
    if n != cap.n_cameras:
        raise ClothFitError(f"{where}: silhouettes for {n} cameras but {cap.n_cameras} cameras given")
    for ci, cam in enumerate(cap.cameras):
        row = silhouettes[ci]
        if len(row) != cap.n_frames:
            raise ClothFitError(f"{where}: camera '{cam.name}' has {len(row)} silhouettes but the scenario has "
                                f"{cap.n_frames} frame times")
        for fi in range(cap.n_frames):
            w = f"{where}: silhouette of camera '{cam.name}' frame {fi} (t={cap.frame_times[fi]:g})"
            m = _mask_from_array(row[fi], w)
            if m.shape != (cam.height, cam.width):
                raise ClothFitError(f"{w}: shape {m.shape} but the camera is {cam.height} x {cam.width} (H x W)")
            if ignore is not None and ignore[ci][fi] is not None:
                g = _mask_from_array(ignore[ci][fi], w + " ignore mask")
                if g.shape != m.shape:
                    raise ClothFitError(f"{w}: ignore mask shape {g.shape} but the camera is {cam.height} x {cam.width}")
                m = m & ~g
            if not allow_empty and not m.any():
                raise ClothFitError(f"{w}: empty silhouette (no object pixel{' outside the ignore mask' if ignore else ''})")
