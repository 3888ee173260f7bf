"""Silhouette images of a capture (``docs/capture_format.md``): one 8-bit single-channel PNG per
camera and frame (0 = background, 255 = object), or a label image / a matte read through the
capture's mask keys; read and checked (size, values, emptiness) and written atomically. Every
problem is a ``ClothFitError`` naming the file.
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import ClothFitError
from ..safeio import atomic_write
from .capture_format import check_pattern

if TYPE_CHECKING:
    from collections.abc import Sequence

    from numpy.typing import ArrayLike

# =============================================================== silhouette files


def _short_values(values, limit=8):
    vals = [int(v) if float(v).is_integer() else float(v) for v in values[:limit]]
    s = ", ".join(str(v) for v in vals)
    return s + (", ..." if len(values) > limit else "")


def mask_from_array(mask: Any, where: str) -> np.ndarray:
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
    raise ClothFitError(
        f"{where}: the silhouette is not binary: values {_short_values(vals)} (expected bool, 0/1 or 0/255)"
    )


def save_silhouette(path: str, mask: ArrayLike) -> None:
    """Write ``mask`` (bool, 0/1 or 0/255; shape (H, W)) as an 8-bit single-channel PNG 0/255.

    Parent directories are created; the file is written to a temporary name and renamed, so a
    reader never sees half a PNG.
    """
    m = mask_from_array(mask, f"silhouette {path}")
    if os.path.splitext(path)[1].lower() != ".png":
        raise ClothFitError(
            f"silhouette {path}: silhouettes are written as PNG (lossless); the file name must end with .png"
        )
    img = np.where(m, 255, 0).astype(np.uint8)
    ok, buf = _imencode(".png", img)
    if not ok:
        raise ClothFitError(f"silhouette {path}: PNG encoding failed")
    d = os.path.dirname(path)
    try:
        if d:
            os.makedirs(d, exist_ok=True)
        write_bytes_atomic(path, buf.tobytes())
    except OSError as e:
        raise ClothFitError(f"silhouette {path}: cannot write ({e})") from None


def _imencode(ext, img):
    import cv2

    return cv2.imencode(ext, img)


def write_bytes_atomic(path: str, data: bytes) -> None:
    atomic_write(path, data)


def read_silhouette(
    path: str,
    expected_shape: tuple[int, int] | None = None,
    binarize_threshold: float | None = None,
    allow_empty: bool = False,
    source: str | None = None,
) -> np.ndarray:
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
        raise ClothFitError(f"{where}: file not found" if os.path.exists(path) is False else f"{where}: not a file")
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
                    f"in the grey value (0 background, 255 object), not in the alpha channel"
                )
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
                        f"grey (pass binarize_threshold to convert to grey and threshold)"
                    )
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
            mask = grey > 0  # 0/1 image
        else:
            bad = (grey != 0) & (grey != maxval)
            n_bad = int(np.count_nonzero(bad))
            if n_bad:
                vals = np.unique(grey[bad])
                raise ClothFitError(
                    f"{where}: not binary: {n_bad} pixels have values other than 0 and {maxval} "
                    f"({len(vals)} distinct offending values: {_short_values(vals)}); "
                    f"pass binarize_threshold to threshold grey images"
                )
            mask = grey > 0
    if not allow_empty and not mask.any():
        raise ClothFitError(f"{where}: empty silhouette (no object pixel)")
    return mask


def silhouette_where(path: str, source: str | None) -> str:
    return f"silhouette {path}" + (f" ({source})" if source else "")


def _check_size(img, expected_shape, where):
    if expected_shape is not None:
        h, w = img.shape[:2]
        eh, ew = int(expected_shape[0]), int(expected_shape[1])
        if (h, w) != (eh, ew):
            raise ClothFitError(f"{where}: image is {h} x {w} (H x W) but {eh} x {ew} was expected")


def read_label_silhouette(
    path: str,
    silhouette_ids: Sequence[int],
    ignore_ids: Sequence[int] = (),
    expected_shape: tuple[int, int] | None = None,
    allow_empty: bool = False,
    source: str | None = None,
) -> tuple[np.ndarray, np.ndarray | None]:
    """A label image (palette or greyscale PNG, e.g. a SAM 2 / XMem / DAVIS mask) -> ``(mask, ignore)``.

    ``mask`` = pixels whose label is one of ``silhouette_ids`` (the cloth), ``ignore`` = pixels whose
    label is one of ``ignore_ids`` (occluders: truth unknown there) or None without ignore ids.
    The stored values are used as they are (palette indices, grey levels), never converted.
    """
    from .png import read_label_png

    where = silhouette_where(path, source)
    if not os.path.isfile(path):
        raise ClothFitError(f"{where}: file not found")
    labels = read_label_png(path, where)
    _check_size(labels, expected_shape, where)
    mask = np.isin(labels, np.asarray(silhouette_ids))
    ignore = np.isin(labels, np.asarray(ignore_ids)) if len(ignore_ids) else None
    if not allow_empty and not mask.any():
        present = np.unique(labels)
        raise ClothFitError(
            f"{where}: no cloth label: the image holds labels {_short_values(present, 12)} but "
            f"silhouette_ids are {list(silhouette_ids)}"
        )
    return mask, ignore


def read_matte(
    path: str,
    threshold: float,
    expected_shape: tuple[int, int] | None = None,
    allow_empty: bool = False,
    source: str | None = None,
) -> np.ndarray:
    """An alpha matte (PNG; grey, or the alpha channel of grey + alpha / RGBA) -> object = value >
    ``threshold`` (0..1 of full scale, so 8- and 16-bit mattes take the same threshold)."""
    import cv2

    where = silhouette_where(path, source)
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
            img = img[..., -1]  # the alpha channel
        elif np.any(img[..., 0] != img[..., 1]) or np.any(img[..., 1] != img[..., 2]):
            raise ClothFitError(f"{where}: a colour image is not an alpha matte (use grey, grey + alpha or RGBA)")
        else:
            img = img[..., 0]
    scale = 255.0 if img.dtype == np.uint8 else 65535.0
    mask = img.astype(np.float64) > float(threshold) * scale
    if not allow_empty and not mask.any():
        raise ClothFitError(f"{where}: empty silhouette (no matte value above {threshold:g})")
    return mask


def check_mask_spec(d: dict[str, Any] | None, where: str) -> dict[str, Any]:
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
        if (
            not isinstance(v, (list, tuple))
            or not v
            or any(isinstance(x, bool) or not isinstance(x, (int, np.integer)) or not 0 <= x <= 65535 for x in v)
        ):
            raise ClothFitError(
                f"{where}: '{key}' must be a non-empty list of label values (integers 0..65535), got {v!r:.80}"
            )
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
            raise ClothFitError(
                f"{where}: 'matte_threshold' (alpha mattes) and 'silhouette_ids' (label images) exclude each other"
            )
        if isinstance(t, bool) or not isinstance(t, (int, float)) or not (0.0 <= float(t) < 1.0):
            raise ClothFitError(
                f"{where}: 'matte_threshold' must be a number in [0, 1) (fraction of full alpha), got {t!r}"
            )
        out["matte_threshold"] = float(t)
    if d.get("ignore") is not None:
        out["ignore"] = check_pattern(d["ignore"], f"{where}: 'ignore' pattern")
    return out
