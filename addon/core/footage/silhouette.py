"""Silhouettes from camera images: background difference in YUV, automatic threshold, clean-up.

Paper section 4: per camera a background image (no object) and foreground images; the difference
in YUV colour space is thresholded into a silhouette (object 1, background 0). The paper picks the
threshold by hand; we add what real footage needs (all pure numpy + cv2, no bpy):

1. **Difference** ``D = sqrt((w_Y dY)^2 + dU^2 + dV^2)`` per pixel between the frame and the
   background (the mean of the background plates when there are several), with
   ``Y = 0.299 R + 0.587 G + 0.114 B``, ``U = 0.492 (B - Y)``, ``V = 0.877 (R - Y)`` on the 0..255
   scale; both images are smoothed by a Gaussian of ``blur`` px first (sensor noise; default 1).
   **Chroma weighting against shadows**: a shadow or a change of exposure mostly changes
   brightness, so ``w_Y`` (``luma_weight``, default 0.35) weighs luma down against chroma.
   **Shadow model** (``shadow_min``, default 0.6; 1 = off): a shadow scales the background's
   Y, U and V by the same factor (YUV is linear in RGB), so the frame is also compared with the
   background dimmed by a factor ``a`` in ``[shadow_min, 1]``, and ``D`` is the smaller of the two
   differences. Shadows are smooth, so ``a`` is one least-squares factor per ``shadow_window`` px
   window centred on the pixel (default 9): a uniform cloth over a textured table does not pass
   for a shadow, because the table's texture would have to persist under a shadow. (At a hard
   shadow edge the window straddles lit and shadowed background: a thin line of difference
   remains there; ``shadow_window=1``, one factor per pixel, suits hard-edged shadows better.) Grey images have no chroma: there
   ``D = |dY|`` and no shadow model (a shadow cannot be told from a darker object).
2. **Threshold, one per camera** (cameras differ in exposure and noise; a fixed camera's noise
   does not change over the frames):
   * ``noise``: a noise model of the background difference. With two or more background plates
     the plate-to-plate difference (scaled to the frame-to-mean-background noise) is pure noise;
     with one plate the difference images of the camera's frames are used (mostly background).
     Threshold = ``median + noise_k * 1.4826 * MAD`` of that noise difference (``noise_k`` 6).
   * ``otsu``: Otsu's threshold on the histogram of all difference images of the camera.
   * ``auto`` (default): the noise threshold, never below ``MIN_AUTO_THRESHOLD`` (2 levels).
     Measured on the photoreal footage (``docs/footage_measured.md``) it beats Otsu clearly: Otsu
     lands between the bright parts of the cloth and the background and loses the low-contrast
     parts (cloth in its own shade); the noise threshold detects everything that is not noise and
     the boundary refinement (step 3) puts the edge back where it belongs.
   * a number: that threshold (difference units, 0..255 scale); ``thresholds={camera: value}``
     overrides it per camera.
3. **Clean-up**: morphological opening (``open_radius`` px: removes specks) then closing
   (``close_radius`` px: bridges small gaps), keep the largest 8-connected component, fill holes,
   then **boundary refinement** (``refine_radius`` px, default 2): within that distance of the
   boundary a pixel is object when its difference exceeds half the local object level (the mean
   difference of the nearby interior). A low threshold on a blurred difference makes silhouettes
   fat by about a pixel at high-contrast edges; the half-level point of a blurred edge is the edge
   itself, whatever the threshold and the blur.
4. **Checks** per file, never a silent empty silhouette: unreadable/corrupt image, image size
   different from the camera's (or from its background), missing background, missing camera
   folder, frame count different from the frame times are errors; a frame where nothing
   (``< min_area`` px) is found is an error (with ``allow_empty`` a warning and an empty
   silhouette); a silhouette touching the image border, a large second component that was dropped,
   or an area far from the camera's median are warnings. All errors of all files are gathered and
   reported together, before anything is written.
5. **Debug images** (``debug_dir``): per camera and frame the difference image (scaled so the
   threshold is mid-grey), the raw threshold, after opening, after closing, the largest component,
   after refinement, the final silhouette, and an overlay of its outline on the frame; per camera
   a histogram of the difference with the noise, Otsu and chosen thresholds.

The footage folders and videos these images come from, and the capture written: ``extract.py``.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import ClothFitError

THRESHOLD_MODES = ("auto", "otsu", "noise")
MIN_AUTO_THRESHOLD = 2.0  # "auto" never goes below this difference (0..255 scale): noise-free renders


@dataclass
class ExtractOptions:
    threshold: object = "auto"  # "auto" | "otsu" | "noise" | a number (difference units)
    thresholds: dict = field(default_factory=dict)  # per camera name -> number (overrides)
    luma_weight: float = 0.35  # weight of dY against dU, dV (chroma weighting vs shadows)
    shadow_min: float = 0.6  # background dimmed down to this ratio counts as shadow (1 = off)
    shadow_window: int = 9  # px: one dimming ratio per window (shadows are smooth; 1 = per pixel)
    noise_k: float = 6.0  # noise threshold = median + noise_k * robust sigma
    blur: float = 1.0  # Gaussian sigma [px] on both images before differencing (0 = off)
    open_radius: int = 1  # morphological opening radius [px] (0 = off)
    close_radius: int = 2  # morphological closing radius [px] (0 = off)
    keep_largest: bool = True
    fill_holes: bool = True
    refine_radius: int = 2  # boundary refinement to half the local contrast, px (0 = off)
    min_area: int = 50  # a silhouette smaller than this = nothing found
    allow_empty: bool = False  # nothing found: warning + empty silhouette instead of an error
    undistort: bool = False  # undistort silhouettes, write cameras without distortion
    debug_dir: str | None = None

    def check(self) -> ExtractOptions:
        t = self.threshold
        if isinstance(t, str):
            if t not in THRESHOLD_MODES:
                try:
                    self.threshold = float(t)
                except ValueError:
                    raise ClothFitError(
                        f"extraction threshold {t!r} must be one of {', '.join(THRESHOLD_MODES)} or a number"
                    ) from None
        t = self.threshold
        if not isinstance(t, str) and not (isinstance(t, (int, float)) and math.isfinite(t) and t > 0):
            raise ClothFitError(f"extraction threshold {t!r} must be a positive number")
        for k, v in (self.thresholds or {}).items():
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ClothFitError(f"extraction threshold of camera {k!r} = {v!r} must be a positive number")
        if not (0.0 <= self.luma_weight <= 10.0):
            raise ClothFitError(f"luma weight {self.luma_weight} must be within 0..10")
        if not (0.0 < self.shadow_min <= 1.0):
            raise ClothFitError(f"shadow ratio {self.shadow_min} must be within (0, 1] (1 = no shadow model)")
        if not (self.noise_k > 0):
            raise ClothFitError(f"noise factor {self.noise_k} must be positive")
        if self.blur < 0 or min(self.open_radius, self.close_radius, self.refine_radius, self.min_area) < 0:
            raise ClothFitError(
                f"blur {self.blur}, open radius {self.open_radius}, close radius "
                f"{self.close_radius} and min area {self.min_area} must be >= 0"
            )
        return self


# ================================================================ images and colour


def read_image(path: str) -> np.ndarray:
    """An image file as float32 ``(H, W, 3)`` BGR or ``(H, W)`` grey on the 0..255 scale."""
    import cv2

    if not os.path.isfile(path):
        raise ClothFitError(f"image not found: {path}")
    if os.path.getsize(path) == 0:
        raise ClothFitError(f"image {path} is an empty (zero-byte) file")
    img = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ClothFitError(f"image {path} is unreadable (not an image, corrupt or truncated)")
    return as_float_image(img, path)


def as_float_image(img: np.ndarray, source: str = "image") -> np.ndarray:
    img = np.asarray(img)
    if img.dtype == np.uint8:
        f = img.astype(np.float32)
    elif img.dtype == np.uint16:
        f = img.astype(np.float32) / 257.0
    elif img.dtype in (np.float32, np.float64):
        f = np.asarray(img, dtype=np.float32)
        f = f * 255.0 if np.nanmax(f) <= 1.0 + 1e-6 else f  # EXR / float images in 0..1
    elif img.dtype == bool:
        f = img.astype(np.float32) * 255.0
    else:
        raise ClothFitError(f"{source}: unsupported pixel type {img.dtype}")
    if f.ndim == 3 and f.shape[2] == 1:
        f = f[:, :, 0]
    elif f.ndim == 3 and f.shape[2] == 4:
        f = f[:, :, :3]
    elif f.ndim == 3 and f.shape[2] == 2:
        f = f[:, :, 0]
    if f.ndim not in (2, 3) or (f.ndim == 3 and f.shape[2] != 3):
        raise ClothFitError(f"{source}: unsupported image layout {img.shape}")
    if not np.all(np.isfinite(f)):
        raise ClothFitError(f"{source}: image has non-finite pixel values")
    return f


def bgr_to_yuv(img: np.ndarray) -> np.ndarray:
    """BGR (0..255) -> YUV (analogue YUV, BT.601 luma), float32 ``(H, W, 3)``; grey -> ``(H, W, 1)``."""
    if img.ndim == 2:
        return img[:, :, None].astype(np.float32)
    b, g, r = img[:, :, 0], img[:, :, 1], img[:, :, 2]
    y = 0.299 * r + 0.587 * g + 0.114 * b
    return np.stack([y, 0.492 * (b - y), 0.877 * (r - y)], -1).astype(np.float32)


def difference(
    frame_yuv: np.ndarray,
    bg_yuv: np.ndarray,
    luma_weight: float,
    blur: float,
    shadow_min: float = 1.0,
    shadow_window: int = 1,
) -> np.ndarray:
    """The weighted YUV difference image ``D`` (float32 ``(H, W)``).

    With ``shadow_min < 1`` the frame is compared with the background dimmed by the best ratio
    ``a`` in ``[shadow_min, 1]`` (a shadow scales Y, U and V alike): ``D = min_a |f - a b|_w``.
    Grey images (one channel): ``D = |dY|`` without shadow model.
    """
    import cv2

    f = frame_yuv
    b = bg_yuv
    if blur > 0:
        f = cv2.GaussianBlur(f, (0, 0), blur)
        b = cv2.GaussianBlur(b, (0, 0), blur)
        if f.ndim == 2:
            f, b = f[:, :, None], b[:, :, None]
    if f.shape[2] == 1:  # grey: no chroma, so a shadow cannot be told from a darker object
        return np.abs(f[:, :, 0] - b[:, :, 0])
    w = np.array([luma_weight, 1.0, 1.0], np.float32)
    fw, bw = f * w, b * w
    d0 = fw - bw
    plain = np.sqrt((d0 * d0).sum(-1))
    if shadow_min >= 1.0:
        return plain
    fb = (fw * bw).sum(-1)
    bb = (bw * bw).sum(-1)
    if shadow_window <= 1:
        a = np.clip(fb / np.maximum(bb, 1e-6), shadow_min, 1.0)[:, :, None]
        d = fw - a * bw
        return np.minimum(plain, np.sqrt((d * d).sum(-1)))
    # a shadow dims smoothly: one least-squares ratio per window
    w = int(shadow_window)
    a = np.clip(cv2.boxFilter(fb, -1, (w, w)) / np.maximum(cv2.boxFilter(bb, -1, (w, w)), 1e-6), shadow_min, 1.0)
    d = fw - a[:, :, None] * bw
    return np.minimum(plain, np.sqrt((d * d).sum(-1)))


# ====================================================================== thresholds


def otsu_threshold(values: np.ndarray, bins: int = 512) -> float:
    """Otsu's threshold of a set of non-negative values (maximises the between-class variance)."""
    v = np.asarray(values, dtype=np.float64).ravel()
    v = v[np.isfinite(v)]
    if v.size == 0:
        return float("nan")
    hi = float(np.percentile(v, 99.95))
    if hi <= 0:
        return float("nan")
    hist, edges = np.histogram(np.minimum(v, hi), bins=bins, range=(0.0, hi))
    centres = 0.5 * (edges[:-1] + edges[1:])
    w0 = np.cumsum(hist).astype(np.float64)
    w1 = w0[-1] - w0
    s0 = np.cumsum(hist * centres)
    m0 = s0 / np.maximum(w0, 1e-12)
    m1 = (s0[-1] - s0) / np.maximum(w1, 1e-12)
    between = w0 * w1 * (m0 - m1) ** 2
    between[(w0 == 0) | (w1 == 0)] = -1
    i = int(np.argmax(between))
    return float(edges[i + 1])


def noise_threshold(noise_values: np.ndarray, k: float) -> tuple:
    """``median + k * 1.4826 * MAD`` of a noise difference sample; returns (threshold, median, sigma)."""
    v = np.asarray(noise_values, dtype=np.float64).ravel()
    med = float(np.median(v))
    sigma = 1.4826 * float(np.median(np.abs(v - med)))
    sigma = max(sigma, 1e-3)
    return med + k * sigma, med, sigma


def _sample(a: np.ndarray, n: int = 400_000, seed: int = 0) -> np.ndarray:
    a = a.ravel()
    if a.size <= n:
        return a
    return a[np.random.default_rng(seed).choice(a.size, n, replace=False)]


# ======================================================================= clean-up


def _disk(r: int):
    import cv2

    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))


def fill_holes(mask: np.ndarray) -> np.ndarray:
    """Fill background regions not connected to the image border (4-connected)."""
    import cv2

    m = mask.astype(np.uint8)
    h, w = m.shape
    pad = np.zeros((h + 2, w + 2), np.uint8)
    pad[1:-1, 1:-1] = m
    ff = pad.copy()
    cv2.floodFill(ff, np.zeros((h + 4, w + 4), np.uint8), (0, 0), 1)
    holes = ff[1:-1, 1:-1] == 0
    return mask | holes


def refine_boundary(mask: np.ndarray, diff: np.ndarray, radius: int, floor: float = 0.0) -> np.ndarray:
    """Move the silhouette's boundary to where the difference falls to half the local object level.

    An edge in the image (anti-aliased, lens-blurred, and blurred by ``blur``) is a ramp between
    the background's difference (~0) and the object's; a global threshold puts the boundary on
    the ramp wherever it crosses the threshold: outside the true edge for high-contrast parts,
    inside it for low-contrast ones. Half the local object level is the edge itself (a symmetric
    blur keeps the half-way point of a step in place) and does not depend on the threshold.
    The local level is the mean difference of the object's interior (the mask eroded by 2 px)
    in a ``(4 radius + 5)`` px window; only pixels within ``radius`` px of the boundary change,
    and only where an interior is near. ``floor``: a pixel never becomes object below it.
    """
    import cv2

    if radius <= 0 or not mask.any():
        return mask
    m8 = mask.astype(np.uint8)
    inner = cv2.erode(m8, _disk(2)).astype(np.float32)
    if not inner.any():
        return mask
    win = 4 * radius + 5
    num = cv2.boxFilter(diff.astype(np.float32) * inner, -1, (win, win), normalize=False)
    den = cv2.boxFilter(inner, -1, (win, win), normalize=False)
    band = (cv2.dilate(m8, _disk(radius)) > 0) & ~(cv2.erode(m8, _disk(radius)) > 0) & (den > 0.5)
    level = num / np.maximum(den, 1e-6)
    out = mask.copy()
    out[band] = diff[band] > np.maximum(0.5 * level[band], floor)
    return out


def clean_mask(
    raw: np.ndarray, opts: ExtractOptions, diff: np.ndarray | None = None, floor: float = 0.0
) -> tuple[np.ndarray, dict[str, np.ndarray], dict[str, Any]]:
    """Opening, closing, largest component, hole filling, boundary refinement (needs ``diff``).
    Returns (final, steps dict, info dict)."""
    import cv2

    steps = {"threshold": raw}
    m = raw.astype(np.uint8)
    if opts.open_radius > 0:
        m = cv2.morphologyEx(m, cv2.MORPH_OPEN, _disk(opts.open_radius))
    steps["open"] = m > 0
    if opts.close_radius > 0:
        # pad so that closing does not glue the silhouette to the image border
        r = opts.close_radius
        mp = cv2.copyMakeBorder(m, r, r, r, r, cv2.BORDER_CONSTANT, value=0)
        m = cv2.morphologyEx(mp, cv2.MORPH_CLOSE, _disk(r))[r:-r, r:-r]
    steps["close"] = m > 0
    info = {"components": 0, "dropped_area": 0, "second_area": 0}
    n, lab, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
    info["components"] = int(n - 1)
    if opts.keep_largest and n > 2:
        areas = stats[1:, cv2.CC_STAT_AREA]
        order = np.argsort(areas)[::-1]
        keep = int(order[0]) + 1
        info["dropped_area"] = int(areas.sum() - areas[order[0]])
        info["second_area"] = int(areas[order[1]])
        m = (lab == keep).astype(np.uint8)
    steps["largest"] = m > 0
    final = m > 0
    if opts.fill_holes and final.any():
        final = fill_holes(final)
    if diff is not None and opts.refine_radius > 0 and final.any():
        final = refine_boundary(final, diff, opts.refine_radius, floor)
        n, lab, stats, _ = cv2.connectedComponentsWithStats(final.astype(np.uint8), connectivity=8)
        if opts.keep_largest and n > 2:
            final = lab == (int(np.argmax(stats[1:, cv2.CC_STAT_AREA])) + 1)
        if opts.fill_holes and final.any():
            final = fill_holes(final)
    steps["refine"] = final
    steps["final"] = final
    return final, steps, info


# ================================================================== one camera


@dataclass
class CameraResult:
    name: str
    masks: list
    report: dict
    errors: list
    warnings: list


def camera_thresholds(
    diffs: Sequence[np.ndarray], noise_sample: np.ndarray | None, opts: ExtractOptions, name: str
) -> dict[str, Any]:
    """The camera's threshold and the statistics behind it (a dict)."""
    pooled = np.concatenate([_sample(d, 200_000 // max(1, len(diffs)) + 1, i) for i, d in enumerate(diffs)])
    otsu = otsu_threshold(pooled)
    noise_src = noise_sample if noise_sample is not None else pooled
    thr_noise, med, sigma = noise_threshold(noise_src, opts.noise_k)
    if name in (opts.thresholds or {}):
        thr, mode = float(opts.thresholds[name]), "per-camera"
    elif not isinstance(opts.threshold, str):
        thr, mode = float(opts.threshold), "fixed"
    elif opts.threshold == "otsu":
        thr, mode = otsu, "otsu"
    elif opts.threshold == "noise":
        thr, mode = thr_noise, "noise"
    else:
        thr, mode = max(thr_noise, MIN_AUTO_THRESHOLD), "auto"
    if not math.isfinite(thr):
        thr = thr_noise
    return {
        "threshold": float(thr),
        "mode": mode,
        "otsu": float(otsu),
        "noise": float(thr_noise),
        "noise_median": med,
        "noise_sigma": sigma,
        "noise_source": "background plates" if noise_sample is not None else "frames (robust)",
    }


def extract_camera(
    backgrounds: np.ndarray | Sequence[np.ndarray],
    frames: Sequence[np.ndarray],
    options: ExtractOptions | None = None,
    name: str = "cam",
    frame_names: Sequence[str] | None = None,
    shape: tuple[int, int] | None = None,
    debug_dir: str | None = None,
) -> CameraResult:
    """Silhouettes of one camera from in-memory images (what the Blender operator can call).

    ``backgrounds``: one or more background plates, ``frames``: the foreground images (uint8 /
    uint16 / float BGR or grey arrays, or already ``as_float_image`` ones); ``shape``: the
    camera's (H, W) if known. Problems of this camera are returned in ``errors``/``warnings``
    (strings naming the frame), not raised, so that a caller can report all cameras at once.
    """
    opts = (options or ExtractOptions()).check()
    frame_names = list(frame_names) if frame_names is not None else [f"frame {i}" for i in range(len(frames))]
    errors, warnings = [], []
    report = {"name": name, "background_plates": len(backgrounds), "frames": []}
    if not backgrounds:
        return CameraResult(name, [], report, [f"camera '{name}': no background image"], [])
    bgs = [as_float_image(b, f"camera '{name}' background {i}") for i, b in enumerate(backgrounds)]
    size = shape or bgs[0].shape[:2]
    for i, b in enumerate(bgs):
        if b.shape[:2] != tuple(size):
            errors.append(
                f"camera '{name}' background {i}: size {b.shape[0]}x{b.shape[1]} (HxW) but the camera "
                f"images {size[0]}x{size[1]}"
            )
        if b.ndim != bgs[0].ndim:
            errors.append(f"camera '{name}' background {i}: colour and grey background plates mixed")
    if errors:
        return CameraResult(name, [], report, errors, warnings)
    yuv_bgs = [bgr_to_yuv(b) for b in bgs]
    bg = np.mean(yuv_bgs, axis=0) if len(yuv_bgs) > 1 else yuv_bgs[0]
    noise_sample = None
    if len(yuv_bgs) >= 2:
        scale = math.sqrt((1.0 + 1.0 / len(yuv_bgs)) / 2.0)
        noise_sample = _sample(
            difference(yuv_bgs[0], yuv_bgs[1], opts.luma_weight, opts.blur, opts.shadow_min, opts.shadow_window) * scale
        )
    diffs = []
    for fname, fr in zip(frame_names, frames):
        f = as_float_image(fr, f"camera '{name}' {fname}")
        if f.shape[:2] != tuple(size):
            errors.append(
                f"camera '{name}' {fname}: size {f.shape[0]}x{f.shape[1]} (HxW) but the camera/background "
                f"is {size[0]}x{size[1]}"
            )
            diffs.append(None)
            continue
        if f.ndim != bgs[0].ndim:
            errors.append(
                f"camera '{name}' {fname}: {'grey' if f.ndim == 2 else 'colour'} image but the background "
                f"is {'grey' if bgs[0].ndim == 2 else 'colour'}"
            )
            diffs.append(None)
            continue
        diffs.append(difference(bgr_to_yuv(f), bg, opts.luma_weight, opts.blur, opts.shadow_min, opts.shadow_window))
    good = [d for d in diffs if d is not None]
    if not good:
        return CameraResult(name, [], report, errors or [f"camera '{name}': no foreground frames"], warnings)
    stats = camera_thresholds(good, noise_sample, opts, name)
    thr = stats["threshold"]
    report.update(stats)
    if stats["mode"] == "otsu" and stats["otsu"] < stats["noise"]:
        warnings.append(
            f"camera '{name}': Otsu's threshold {stats['otsu']:.2f} is below the noise threshold "
            f"{stats['noise']:.2f}; the object is weak against the background noise"
        )
    masks = []
    debug = debug_dir or (os.path.join(opts.debug_dir, name) if opts.debug_dir else None)
    for fi, (fname, d) in enumerate(zip(frame_names, diffs)):
        if d is None:
            masks.append(None)
            continue
        raw = d > thr
        final, steps, info = clean_mask(raw, opts, d, stats["noise"])
        area = int(final.sum())
        fr_rep = {
            "frame": fname,
            "area": area,
            "raw_area": int(raw.sum()),
            "components": info["components"],
            "dropped_area": info["dropped_area"],
            "max_difference": float(d.max()),
        }
        report["frames"].append(fr_rep)
        if area < max(1, opts.min_area):
            msg = (
                f"camera '{name}' {fname}: nothing found (silhouette of {area} px < min area {opts.min_area}; "
                f"{int(raw.sum())} px above threshold {thr:.2f}, largest difference {float(d.max()):.2f})"
            )
            if opts.allow_empty:
                warnings.append(msg + "; written as an empty silhouette")
                final = np.zeros_like(final)
            else:
                errors.append(msg)
        else:
            if final[0, :].any() or final[-1, :].any() or final[:, 0].any() or final[:, -1].any():
                warnings.append(
                    f"camera '{name}' {fname}: the silhouette touches the image border (object cut off by the frame?)"
                )
            if info["second_area"] > 0.1 * area:
                warnings.append(
                    f"camera '{name}' {fname}: dropped a second region of {info['second_area']} px "
                    f"(the silhouette has {area} px): shadow, reflection or a second object?"
                )
        masks.append(final)
        if debug:
            _write_debug(debug, fi, fname, d, thr, steps, frames[fi])
    _area_outlier_warnings(report, name, warnings)
    if debug:
        _write_histogram(os.path.join(debug, "histogram.png"), good, stats)
    return CameraResult(name, masks, report, errors, warnings)


def _area_outlier_warnings(report, name, warnings):
    """A warning (appended to ``warnings``) per frame whose silhouette area is far from the camera's median."""
    areas = [r["area"] for r in report["frames"] if r["area"] > 0]
    if len(areas) >= 3:
        med = float(np.median(areas))
        for r in report["frames"]:
            if r["area"] > 0 and (r["area"] > 2.5 * med or r["area"] < med / 2.5):
                warnings.append(
                    f"camera '{name}' {r['frame']}: area {r['area']} px is far from the camera's median {med:.0f} px"
                )


# ==================================================================== debug output


def _write_png(path, img):
    import cv2

    os.makedirs(os.path.dirname(path), exist_ok=True)
    if not cv2.imwrite(path, img):
        raise ClothFitError(f"cannot write debug image {path}")


def _write_debug(folder, fi, fname, d, thr, steps, frame):
    import cv2

    stem = f"{fi:03d}"
    scaled = np.clip(d * (128.0 / max(thr, 1e-6)), 0, 255).astype(np.uint8)
    _write_png(os.path.join(folder, f"{stem}_1_difference.png"), scaled)
    for k, key in enumerate(("threshold", "open", "close", "largest", "refine", "final")):
        _write_png(os.path.join(folder, f"{stem}_{k + 2}_{key}.png"), steps[key].astype(np.uint8) * 255)
    f = as_float_image(frame)
    f = np.clip(f, 0, 255).astype(np.uint8)
    if f.ndim == 2:
        f = cv2.cvtColor(f, cv2.COLOR_GRAY2BGR)
    contours, _ = cv2.findContours(steps["final"].astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    cv2.drawContours(f, contours, -1, (0, 0, 255), 1)
    _write_png(os.path.join(folder, f"{stem}_8_overlay.png"), f)


def _write_histogram(path, diffs, stats, w=512, h=200):
    import cv2

    v = np.concatenate([_sample(x, 100_000) for x in diffs])
    hi = max(float(np.percentile(v, 99.9)), stats["threshold"] * 1.5, 1.0)
    hist, _ = np.histogram(np.minimum(v, hi), bins=w, range=(0, hi))
    logh = np.log1p(hist)
    logh = (logh / max(logh.max(), 1e-9) * (h - 20)).astype(int)
    img = np.full((h, w, 3), 255, np.uint8)
    for x, y in enumerate(logh):
        cv2.line(img, (x, h - 1), (x, h - 1 - int(y)), (90, 90, 90), 1)
    for key, col in (("noise", (255, 0, 0)), ("otsu", (0, 160, 0)), ("threshold", (0, 0, 255))):
        val = stats.get(key)
        if val is not None and math.isfinite(val):
            x = int(min(w - 1, val / hi * w))
            cv2.line(img, (x, 0), (x, h - 1), col, 1)
            cv2.putText(
                img,
                f"{key} {val:.1f}",
                (min(x + 3, w - 110), 12 + 14 * ("noise", "otsu", "threshold").index(key)),
                cv2.FONT_HERSHEY_SIMPLEX,
                0.4,
                col,
                1,
            )
    _write_png(path, img)
