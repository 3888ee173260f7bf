"""The noise floor of a capture's silhouettes, estimated from the silhouettes themselves (no truth).

The floor of an image is the ``E_sil`` (eq. 6) that a perfect model (the true shape, rasterised at
pixel centres at the fit resolution) would score against the observed silhouette as the fitter sees
it: it comes from the observation's own errors and from resampling the images to the fit resolution.
A fit whose error ends far above its images' floor is limited by something else (the model, the time
scale, the manipulation) or by errors this estimate cannot see (below). ``docs/noise_floor.md`` has
the calibration (``lab/floor_calibration.py``).

The estimate has two parts:

* **noise** (random, pixel-scale boundary errors: flipped boundary pixels, ragged segmentation). A
  3 x 3 majority vote (median) flips every isolated wrong pixel on a straight edge and leaves a clean
  digitised straight edge, whatever its slope, unchanged (its staircase is not noise). So on the
  *straight* stretches of the outline (curvature radius above ``STRAIGHT_RADIUS`` px, where a clean
  outline gives no votes) the votes per boundary pixel measure the noise rate; the floor is that rate
  times the boundary length over the area. Corners and pixel-sized details (where a clean outline
  gets votes too) only enter through the boundary length. A capture pools the rate over its images
  (``capture_floor``), so an image with little straight outline borrows its capture's rate.
  That image-only count fails on small images of a curved or folded cloth: the staircase of an outline
  a few pixels across votes like noise (Blender's cloth at 120 x 160 with 1 % noise: 5.6x its floor).
  **With a model** (``capture_floor(..., model=...)``: a fit's best candidate rasterised by the fitter,
  as ``fitting/diagnose.report`` passes it) the votes a clean raster of that shape casts (staircase,
  corners, folds) are the baseline: only the observed image's votes on pixels that differ from the
  model, where the model casts none, count,
  and the votes one flipped pixel casts on this shape are measured on noisy copies of the model
  (``MODEL_FLIP_RATE``). Near a large model-image disagreement nothing counts, and a model that
  agrees with too little of the outline (``MODEL_AGREEMENT``) is not used. A wrong model can only
  raise the estimate this way (a fold it lacks votes as noise), never lower it. ``basis`` says which.
* **resampling** (the fit runs at a lower resolution than the images): the fitter area-averages each
  image and thresholds at one half (``resample_silhouette``, the one the fitter uses), the model is rasterised at the low-resolution pixel centres; the two
  disagree along the outline even for a perfect observation (ties of a 2 x 2 block count as cloth:
  about 1 % at half resolution). Estimated by running both paths on a smooth sub-pixel version of the
  observed shape (a Gaussian blur, ``PROXY_SIGMA`` image pixels) at ``len(PROXY_SHIFTS)`` sub-pixel
  offsets, plus the noise that survives the resampling (the image against its median, resampled).

What it cannot see (say so wherever the number is shown): errors that look like shape. A segmenter
that is biased (loses or adds a rim along the whole outline: the usual case of real extraction), or
that drops a low-contrast part of the cloth, produces a clean, smooth silhouette, and no check of an
image against itself can tell it from the true one. On the photoreal footage (``docs/noise_floor.md``)
the estimate is about a tenth of the true floor there, while 80 % of that floor lies within one pixel of
the observed outline. So the estimate is a lower bound for real footage; ``rim`` (the ``E_sil`` of a
one-pixel shift of the whole outline) is the scale of such a bias, and ``residual_profile`` says
where a fit's residual lies (on that rim or in the bulk, one-sided or not, and the outline shift in
pixels that would explain it). Clean silhouettes with real pixel-scale detail (a cloth edge that
zig-zags at one pixel at low resolution) read as noise and raise the estimate.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from .. import defaults as D
from ..errors import ClothFitError

if TYPE_CHECKING:
    from .capture import Capture

# --- calibration (lab/floor_calibration.py, docs/noise_floor.md)
STRAIGHT_RADIUS = 20.0  # px: outline with a larger curvature radius counts as straight (a 3 x 3 median never
# changes a clean digitised edge there: measured baseline < 0.01 % at 240 x 320)
CURVATURE_SIGMA = 2.0  # px: blur of the silhouette for its curvature (isolated flipped pixels barely move it)
POOL_STRENGTH = 200.0  # straight boundary pixels: an image's rate is shrunk to its capture's pooled rate with
# this weight (an image with 200 straight boundary pixels gets half its own rate)
MIN_STRAIGHT = 50  # fewer straight boundary pixels in the whole capture: use every boundary pixel's votes
# (corners vote too: an over-estimate, flagged by ``basis``)
PROXY_SIGMA = 2.0  # image px: blur of the smooth shape used for the resampling part (1: the staircase
# ripple adds disagreements; 3: rounds pixel-sized features away at 8x downsampling)
PROXY_SHIFTS = (
    (0.0, 0.0),
    (0.5, 0.0),
    (0.0, 0.5),
    (0.5, 0.5),
    (-0.25, -0.25),
    (0.25, -0.25),
    (-0.25, 0.25),
    (0.25, 0.25),
)  # sub-pixel offsets of the shape (image px) the resampling part is averaged over
MODEL_FLIP_RATE = 0.05  # the model's clean silhouette is flipped at this fraction of its boundary pixels to
# measure how many votes one flipped pixel casts on this shape (about 1 on a straight edge, 0-2 at a staircase)
MODEL_DRAWS = 2  # noisy copies of each model silhouette for that measurement
MODEL_CLUSTER = 3  # px: a model-image disagreement (8-connected) larger than this is shape, not noise: the votes
# within 2 px of it are left out (a wrong model must not lower the floor)
MODEL_AGREEMENT = 0.8  # the share of the observed outline (away from such disagreements) below which the model
# is too far from the images to serve as the baseline: the image-only estimate is used instead
FAR_ABOVE = D.FLOOR_FAR_ABOVE  # a fit error more than this times its floor is "far above" it

LIMITS = (
    "lower bound for real footage: a segmenter's bias (a rim lost or added along the whole outline) and "
    "dropped low-contrast parts look like shape and are invisible to any check of an image against itself"
)


# ============================================================================ helpers


def _mask(m, where: str) -> np.ndarray:
    from .silhouette_files import mask_from_array

    return mask_from_array(m, where)


def _fit_shape(fit_shape, native, where):
    if fit_shape is None:
        return tuple(native)
    try:
        h, w = fit_shape
        ok = all(isinstance(x, (int, np.integer)) and not isinstance(x, bool) for x in (h, w)) and h > 0 and w > 0
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise ClothFitError(f"{where}: fit resolution {fit_shape!r} must be two positive integers (height, width)")
    return int(h), int(w)


def resample_silhouette(mask: np.ndarray, height: int, width: int) -> np.ndarray:
    """Silhouette at another resolution as the fitter makes it (``fitting/job.load_observed`` calls this):
    area average, object where it is at least one half."""
    import cv2

    if mask.shape == (height, width):
        return mask.astype(bool)
    img = cv2.resize(mask.astype(np.float32), (width, height), interpolation=cv2.INTER_AREA)
    return img >= 0.5


def resample_ignore(mask: np.ndarray | None, height: int, width: int) -> np.ndarray | None:
    """An ignore mask at another resolution as the fitter makes it (unknown where any part was unknown)."""
    import cv2

    if mask is None or mask.shape == (height, width):
        return mask
    img = cv2.resize(mask.astype(np.float32), (width, height), interpolation=cv2.INTER_AREA)
    return img > 0


def inner_boundary(mask: np.ndarray) -> np.ndarray:
    """Object pixels with a 4-neighbour outside (the image border counts as outside)."""
    p = np.pad(mask, 1, mode="constant")
    return mask & (~p[:-2, 1:-1] | ~p[2:, 1:-1] | ~p[1:-1, :-2] | ~p[1:-1, 2:])


def majority3(mask: np.ndarray) -> np.ndarray:
    """3 x 3 median (majority of 9) of a binary image; outside the image counts as background."""
    import cv2

    p = np.pad(mask.astype(np.uint8), 1, mode="constant")
    s = cv2.boxFilter(p, cv2.CV_16U, (3, 3), normalize=False, borderType=cv2.BORDER_CONSTANT)
    return (s >= 5)[1:-1, 1:-1]


def curvature(mask: np.ndarray, sigma: float = CURVATURE_SIGMA) -> np.ndarray:
    """|curvature| [1/px] of the level lines of the blurred silhouette (div of the unit gradient)."""
    import cv2

    u = cv2.GaussianBlur(mask.astype(np.float64), (0, 0), sigma, borderType=cv2.BORDER_CONSTANT)
    uy, ux = np.gradient(u)
    uyy, uyx = np.gradient(uy)
    uxy, uxx = np.gradient(ux)
    g2 = ux * ux + uy * uy
    with np.errstate(divide="ignore", invalid="ignore"):
        k = (uxx * uy * uy - 2.0 * ux * uy * uxy + uyy * ux * ux) / g2**1.5
    return np.where(g2 > 1e-12, np.abs(k), np.inf)


def _grid_sample(u, xs, ys):
    import cv2

    mx, my = np.meshgrid(np.asarray(xs, np.float32), np.asarray(ys, np.float32))
    return cv2.remap(u, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


# ============================================================================ one image


@dataclass
class FloorEstimate:
    """The floor of one image at the fit resolution. Fractions like ``E_sil`` (x 100 for %)."""

    floor: float  # estimated E_sil of a perfect model = noise + resampling
    noise: float  # part from random pixel-scale boundary errors
    resampling: float  # part from resampling to the fit resolution (0 at the images' own)
    rim: float  # inner-boundary pixels / area at the fit resolution: E_sil of a 1-pixel shift of
    # the whole outline (the scale of a segmenter's bias, which ``floor`` cannot see)
    votes: int  # pixels the 3 x 3 majority flips on straight outline (image resolution)
    straight: int  # inner-boundary pixels on straight outline (image resolution)
    boundary: int  # inner-boundary pixels (image resolution, outside the ignore mask and image border)
    area: int  # observed area outside the ignore mask (image resolution)
    fit_area: int  # the same at the fit resolution (eq. 6's normaliser)
    shape: tuple  # image (H, W)
    fit_shape: tuple  # fit (h, w)
    basis: str = "straight outline"  # where the noise rate came from
    splat: float = 0.0  # E_sil of a perfect model against silhouettes splatted from points (a capture converted
    # from point clouds, its meta's ``splat_floor``); ``floor`` is the larger of it and noise + resampling

    @property
    def rate(self) -> float:
        """Majority votes per straight boundary pixel (this image alone)."""
        return self.votes / self.straight if self.straight else float("nan")

    def to_dict(self) -> dict:
        d = asdict(self)
        d["shape"], d["fit_shape"] = list(self.shape), list(self.fit_shape)
        return d


def _prepare(observed, ignore, where):
    o = _mask(observed, where)
    g = None
    if ignore is not None:
        g = _mask(ignore, f"{where} ignore mask")
        if g.shape != o.shape:
            raise ClothFitError(
                f"{where}: ignore mask is {g.shape[0]}x{g.shape[1]} but the silhouette is {o.shape[0]}x{o.shape[1]}"
            )
        g = g if g.any() else None
    if g is not None:
        o = o & ~g
    if not o.any():
        raise ClothFitError(
            f"{where}: the observed silhouette is empty"
            + (" outside the ignore mask" if g is not None else "")
            + ", its floor is undefined"
        )
    return o, g


def _known(o, g):
    """Pixels whose 3 x 3 surroundings are known: away from the image border and the ignore mask."""
    import cv2

    valid = np.ones(o.shape, bool)
    valid[0, :] = valid[-1, :] = valid[:, 0] = valid[:, -1] = False
    if g is not None:
        r = int(math.ceil(1.5 * CURVATURE_SIGMA))
        valid &= ~(cv2.dilate(g.astype(np.uint8), np.ones((2 * r + 1, 2 * r + 1), np.uint8)) > 0)
    return valid


def _counts(o, g):
    """(votes on straight outline, straight boundary, boundary, all votes on the boundary band) at the image's
    own resolution, over pixels whose surroundings are known (away from the ignore mask and the image border)."""
    valid = _known(o, g)
    # work in the silhouette's box (plus a margin for the blur): same result, far less work
    ys, xs = np.nonzero(o)
    m = int(math.ceil(4 * CURVATURE_SIGMA)) + 2
    y0, y1 = max(0, ys.min() - m), min(o.shape[0], ys.max() + m + 1)
    x0, x1 = max(0, xs.min() - m), min(o.shape[1], xs.max() + m + 1)
    oc, vc = o[y0:y1, x0:x1], valid[y0:y1, x0:x1]
    med = majority3(oc)
    votes = (oc ^ med) & vc
    straight = curvature(oc) < 1.0 / STRAIGHT_RADIUS
    inner = inner_boundary(med) & vc
    return (
        int(np.count_nonzero(votes & straight)),
        int(np.count_nonzero(inner & straight)),
        int(np.count_nonzero(inner)),
        int(np.count_nonzero(votes)),
    )


def _resampling_part(o, g, fit_shape):
    """(resampling part, noise surviving the resampling, fit-resolution observation) as counts."""
    H, W = o.shape
    h, w = fit_shape
    import cv2

    r = resample_silhouette(o, h, w)
    gl = resample_ignore(g, h, w)
    known = np.ones((h, w), bool) if gl is None else ~gl
    r = r & known
    u = cv2.GaussianBlur(o.astype(np.float32), (0, 0), PROXY_SIGMA, borderType=cv2.BORDER_CONSTANT)
    sx, sy = W / w, H / h
    xs_lo, ys_lo = (np.arange(w) + 0.5) * sx - 0.5, (np.arange(h) + 0.5) * sy - 0.5
    total = 0
    for dx, dy in PROXY_SHIFTS:
        hi = _grid_sample(u, np.arange(W) + dx, np.arange(H) + dy) >= 0.5
        lo = _grid_sample(u, xs_lo + dx, ys_lo + dy) >= 0.5
        total += int(np.count_nonzero((resample_silhouette(hi, h, w) ^ lo) & known))
    resamp = total / len(PROXY_SHIFTS)
    noise = int(np.count_nonzero((r ^ resample_silhouette(majority3(o), h, w)) & known))
    return resamp, noise, r


def estimate_floor(
    observed: np.ndarray,
    ignore: np.ndarray | None = None,
    fit_shape: Sequence[int] | None = None,
    rate: float | None = None,
    name: str = "silhouette",
) -> FloorEstimate:
    """The floor of one observed silhouette (bool / 0-1 / 0-255 (H, W)), ``E_sil`` units.

    ``ignore``: pixels of unknown truth (as in the fit: they leave eq. 6); ``fit_shape`` (h, w): the
    fit's resolution (default: the image's own); ``rate``: a noise rate (votes per straight boundary
    pixel) to use instead of this image's own (``capture_floor`` passes the capture's pooled one).
    Bad input (not a 2D binary image, an ignore mask of another size, nothing observed outside the
    ignore mask, a bad fit resolution): a one-line ``ClothFitError`` naming ``name``. See the module
    docstring for what the estimate can and cannot see."""
    o, g = _prepare(observed, ignore, name)
    return _estimate(o, g, _fit_shape(fit_shape, o.shape, name), _counts(o, g), rate, name)


def _estimate(o, g, fs, counts, rate, name) -> FloorEstimate:
    votes, straight, boundary, all_votes = counts
    area = int(np.count_nonzero(o))
    basis = "straight outline"
    if rate is None:
        if straight >= MIN_STRAIGHT:
            rate = votes / straight
        else:
            rate, basis = (all_votes / boundary if boundary else 0.0), "whole outline (upper bound)"
    if fs == o.shape:
        noise = rate * boundary / area
        resamp = 0.0
        r, fit_area, gl = o, area, g
    else:
        resamp_n, noise_n, r = _resampling_part(o, g, fs)
        fit_area = int(np.count_nonzero(r))
        if fit_area == 0:
            raise ClothFitError(f"{name}: the observed silhouette vanishes at the fit resolution {fs[0]}x{fs[1]}")
        resamp, noise = resamp_n / fit_area, noise_n / fit_area
        basis = "resampled image against its median"
        gl = resample_ignore(g, *fs)
    ib = inner_boundary(r)
    ib[0, :] = ib[-1, :] = ib[:, 0] = ib[:, -1] = False
    if gl is not None:
        ib &= ~gl
    rim = int(np.count_nonzero(ib)) / fit_area
    return FloorEstimate(
        float(noise + resamp),
        float(noise),
        float(resamp),
        float(rim),
        votes,
        straight,
        boundary,
        area,
        fit_area,
        tuple(o.shape),
        tuple(fs),
        basis,
    )


# ============================================================================ with a model's silhouette


def _model_counts(r, gl, m, rng):
    """At the fit resolution, observed ``r`` (ignore ``gl``) against a model's clean silhouette ``m``:
    (the observed image's 3 x 3 majority votes minus the model's, the votes the model's noisy copies gain
    and the pixels they flip, the observed outline where model and image agree, all the observed outline).
    Votes near a large disagreement (``MODEL_CLUSTER``: shape, not noise) are left out."""
    import cv2

    from .metrics import add_boundary_noise

    known = _known(r, gl)
    ys, xs = np.nonzero(r | m)
    y0, y1 = max(0, ys.min() - 4), min(r.shape[0], ys.max() + 5)
    x0, x1 = max(0, xs.min() - 4), min(r.shape[1], xs.max() + 5)
    r, m, known = r[y0:y1, x0:x1], m[y0:y1, x0:x1], known[y0:y1, x0:x1]
    valid = known.copy()
    _, lab, st, _ = cv2.connectedComponentsWithStats(((r ^ m) & known).astype(np.uint8), connectivity=8)
    big = np.nonzero(st[:, cv2.CC_STAT_AREA] > MODEL_CLUSTER)[0]
    big = big[big > 0]
    if big.size:
        valid &= ~(cv2.dilate(np.isin(lab, big).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0)

    base = (m ^ majority3(m)) & valid

    def new_votes(x):  # votes on pixels that differ from the model, where the clean model casts none: a
        # model's own features (folds the image lacks) do not subtract, so a wrong model raises the floor
        # rather than lowering it
        return int(np.count_nonzero((x ^ majority3(x)) & valid & ~base & (x ^ m)))

    gain = flips = 0
    for _ in range(MODEL_DRAWS):
        mn = add_boundary_noise(m, MODEL_FLIP_RATE, rng)
        gain += new_votes(mn)
        flips += int(np.count_nonzero((mn ^ m) & valid))
    inner = inner_boundary(majority3(r))
    return new_votes(r), gain, flips, int(np.count_nonzero(inner & valid)), int(np.count_nonzero(inner & known))


def _model_pooled(prepared, model, fs, names, seed):
    """``pooled_floors`` with model silhouettes ``model[c][f]`` (fit resolution ``fs``) as the baseline:
    ``((estimates, rate, basis), share of the outline that agrees)``, or ``(None, share)`` when too little
    agrees."""
    low = []
    for c, row in enumerate(prepared):
        lrow = []
        for f, (o, g) in enumerate(row):
            m = _mask(model[c][f], f"{names[c][f]} model")
            if m.shape != tuple(fs):
                raise ClothFitError(
                    f"{names[c][f]}: model silhouette is {m.shape[0]}x{m.shape[1]}, the fit resolution {fs[0]}x{fs[1]}"
                )
            gl = resample_ignore(g, *fs)
            r = resample_silhouette(o, *fs) if o.shape != tuple(fs) else o
            r = r if gl is None else r & ~gl
            if not r.any():
                raise ClothFitError(
                    f"{names[c][f]}: the observed silhouette vanishes at the fit resolution {fs[0]}x{fs[1]}"
                )
            mc = _model_counts(r, gl, m, np.random.default_rng([int(seed), c, f]))
            lrow.append((r, gl, m, mc))
        low.append(lrow)
    k = np.array([[x[3] for x in row] for row in low], dtype=np.float64)  # (C, F, 5)
    agree, total = k[..., 3].sum(), k[..., 4].sum()
    share = agree / total if total else 0.0
    if share < MODEL_AGREEMENT:
        return None, share
    per_flip = k[..., 1].sum() / k[..., 2].sum() if k[..., 2].sum() > 0 else 1.0
    per_flip = max(per_flip, 0.25)
    rate = max(k[..., 0].sum() / per_flip, 0.0) / agree if agree else 0.0
    basis = f"model baseline ({100 * share:.0f} % of the outline agrees with the model)"
    images = []
    for c, row in enumerate(prepared):
        erow = []
        for f, (o, g) in enumerate(row):
            r, gl, m, (net, _, _, ag, tot) = low[c][f]
            rate_i = max(0.0, (net / per_flip + POOL_STRENGTH * rate) / (ag + POOL_STRENGTH))
            fit_area = int(np.count_nonzero(r))
            noise, resamp = rate_i * tot / fit_area, 0.0
            if o.shape != tuple(fs):  # the resampling's own part: the smooth proxy of the observed shape
                resamp = _resampling_part(o, g, fs)[0] / fit_area
            ib = inner_boundary(r) & _known(r, gl)
            erow.append(
                FloorEstimate(
                    float(noise + resamp),
                    float(noise),
                    float(resamp),
                    int(np.count_nonzero(ib)) / fit_area,
                    int(net),
                    int(ag),
                    int(tot),
                    int(np.count_nonzero(o)),
                    fit_area,
                    tuple(o.shape),
                    tuple(fs),
                    basis,
                )
            )
        images.append(erow)
    return (images, float(rate), basis), share


# ============================================================================ a capture


@dataclass
class CaptureFloor:
    """The floors of a capture's chosen images at the fit resolution."""

    images: list  # [cam][frame] FloorEstimate
    camera_names: list
    frame_times: list
    fit_resolution: list | None  # (h, w), None = the images' own
    rate: float  # pooled votes per straight boundary pixel (all chosen images)
    basis: str
    limits: str = LIMITS
    method: dict = field(
        default_factory=lambda: {
            "straight_radius_px": STRAIGHT_RADIUS,
            "pool_strength": POOL_STRENGTH,
            "proxy_sigma_px": PROXY_SIGMA,
            "model_flip_rate": MODEL_FLIP_RATE,
            "model_agreement": MODEL_AGREEMENT,
        }
    )

    def per_image(self) -> np.ndarray:
        """(C, F) floors."""
        return np.array([[e.floor for e in row] for row in self.images], dtype=np.float64)

    @property
    def floor(self) -> float:
        """The capture's floor: the mean of its images' floors (compare with the mean E_sil per image)."""
        return float(self.per_image().mean())

    def to_dict(self, per_image: bool = True) -> dict:
        P = self.per_image()
        parts = {
            k: float(np.mean([[getattr(e, k) for e in row] for row in self.images]))
            for k in ("noise", "resampling", "rim", "splat")
        }
        d = {
            "floor": float(P.mean()),
            "floor_median": float(np.median(P)),
            **parts,
            "rate": self.rate,
            "basis": self.basis,
            "n_images": int(P.size),
            "fit_resolution": self.fit_resolution,
            "limits": self.limits,
            "method": self.method,
        }
        if per_image:
            d["cameras"] = self.camera_names
            d["frame_times"] = self.frame_times
            d["per_image"] = [[round(float(x), 7) for x in row] for row in P]
        return d


def pooled_floors(
    observed: Sequence[Sequence[np.ndarray]],
    ignore: Sequence[Sequence[np.ndarray | None] | None] | None = None,
    fit_shape: Sequence[int] | None = None,
    names: Sequence[Sequence[str]] | None = None,
    model: Sequence[Sequence[np.ndarray]] | None = None,
    seed: int = 0,
) -> tuple[list[list[FloorEstimate]], float, str]:
    """``(estimates, rate, basis)`` for silhouettes ``observed[c][f]`` (and ``ignore[c][f]``, None or
    entries None) at their own resolution, for a fit at ``fit_shape`` (h, w; default their own):
    ``estimates[c][f]`` are ``FloorEstimate``; the noise rate is pooled over all of them (``rate``) and
    each image's own rate shrunk towards it with weight ``POOL_STRENGTH``; ``basis`` says where the
    rate came from. ``names[c][f]`` name the images in error messages.

    ``model[c][f]``: a model's clean silhouettes at the fit resolution (a fit's best candidate,
    rasterised as the fitter does). Then the votes such a clean raster casts (its staircase, corners and
    folds) are the baseline subtracted from the observed image's votes, and the votes one flipped pixel
    casts on this shape are measured on noisy copies of it (``seed``): the noise part no longer counts a
    curved outline's staircase as noise. Votes near a large model-image disagreement are left out, so a
    wrong model's shape does not lower the floor; when less than ``MODEL_AGREEMENT`` of the outline is
    left, the image-only estimate is used and ``basis`` says why. A model that lacks folds the images
    have raises its estimate (up to 2.2x at 1 % noise in the calibration) rather than lowering it. For a fit at a lower resolution than
    the images, the resampling part stays that of the smooth proxy of the observed shape (the model's own
    resampling disagreement depends on its sub-pixel position: a wrong model lowered it by a third at
    60 x 80)."""
    C = len(observed)
    if C == 0 or any(len(row) == 0 for row in observed):
        raise ClothFitError("floor: no silhouettes given")
    if names is None:
        names = [[f"silhouette [{c}][{f}]" for f in range(len(observed[c]))] for c in range(C)]
    prepared = [
        [
            _prepare(observed[c][f], None if ignore is None or ignore[c] is None else ignore[c][f], names[c][f])
            for f in range(len(observed[c]))
        ]
        for c in range(C)
    ]
    fs = None if fit_shape is None else _fit_shape(fit_shape, (1, 1), "floor: fit resolution")
    note = ""
    if model is not None:
        if len(model) != C or any(len(model[c]) != len(observed[c]) for c in range(C)):
            raise ClothFitError(
                "floor: the model silhouettes do not match the observed ones camera by camera, frame by frame"
            )
        out, share = _model_pooled(prepared, model, fs or prepared[0][0][0].shape, names, seed)
        if out is not None:
            return out
        note = (
            f" (the model's silhouettes agree with {100 * share:.0f} % of the outline, too little to serve as "
            "the baseline)"
        )
    return _image_only(prepared, fs, names, note)


def _image_only(prepared, fs, names, note):
    """``pooled_floors`` from the images alone (``note`` appended to the basis)."""
    C = len(prepared)
    counts = [[_counts(o, g) for o, g in row] for row in prepared]
    V = sum(k[0] for row in counts for k in row)
    S = sum(k[1] for row in counts for k in row)
    if S >= MIN_STRAIGHT:
        pooled, basis = V / S, "straight outline"
    else:
        B = sum(k[2] for row in counts for k in row)
        pooled, basis = (sum(k[3] for row in counts for k in row) / B if B else 0.0), "whole outline (upper bound)"
    images = []
    for c in range(C):
        row = []
        for f, (o, g) in enumerate(prepared[c]):
            v, st = counts[c][f][:2]
            rate = (v + POOL_STRENGTH * pooled) / (st + POOL_STRENGTH) if basis == "straight outline" else pooled
            est = _estimate(o, g, o.shape if fs is None else fs, counts[c][f], rate, names[c][f])
            if est.basis == "straight outline":
                est.basis = basis
            est.basis += note
            row.append(est)
        images.append(row)
    return images, float(pooled), basis + note


def capture_floor(
    capture: Capture,
    cams: Iterable[int] | None = None,
    fidx: Iterable[int] | None = None,
    resolution: Sequence[int] | None = None,
    model: Sequence[Sequence[np.ndarray]] | None = None,
) -> CaptureFloor:
    """Floors of ``capture``'s cameras ``cams`` (indices, default all) at frames ``fidx`` (indices,
    default all), for a fit at ``resolution`` (h, w; default the images' own), as ``fitting/job.
    load_observed`` would feed them to the fitter (``pooled_floors`` on the images as stored).
    ``model[i][j]``: a model's clean silhouettes of camera ``cams[i]`` at frame ``fidx[j]`` at the fit
    resolution (a fit's best candidate), the baseline of the noise votes (``pooled_floors``)."""
    cams = list(range(len(capture.cameras))) if cams is None else [int(c) for c in cams]
    fidx = list(range(capture.n_frames)) if fidx is None else [int(f) for f in fidx]
    if not cams or not fidx:
        raise ClothFitError(f"floor of capture {getattr(capture, 'root', '')}: no cameras or no frames chosen")
    observed, ignore = capture.load_observations(cams, fidx)
    names = [[f"camera '{capture.cameras[c].name}' frame {f}" for f in fidx] for c in cams]
    images, rate, basis = pooled_floors(observed, ignore, resolution, names, model)
    basis = _with_splat(capture, images, cams, fidx, basis)
    return CaptureFloor(
        images,
        [capture.cameras[c].name for c in cams],
        [float(capture.frame_times[f]) for f in fidx],
        None if resolution is None else [int(x) for x in resolution],
        rate,
        basis,
    )


def _with_splat(capture: Capture, images: list, cams: list[int], fidx: list[int], basis: str) -> str:
    """Raise each image's floor to its splatting error when the capture was made from point clouds (its meta's
    ``splat_floor``, per camera name and frame time, null where it could not be estimated:
    ``footage/point_clouds.default_cloth_splat_floor``); returns the basis, extended when it did."""
    sf = capture.meta.get("splat_floor")
    if sf is None:
        return basis
    where = f"{getattr(capture, 'root', 'capture')}/capture.json meta splat_floor"
    try:
        P = np.array([[np.nan if x is None else x for x in row] for row in sf["per_image"]], dtype=np.float64)
        cam_row = {str(n): i for i, n in enumerate(sf["cameras"])}
        times = np.asarray(sf["frame_times"], dtype=np.float64)
    except (KeyError, TypeError, ValueError):
        raise ClothFitError(f"{where}: expected cameras, frame_times and per_image (cameras x frames)") from None
    if P.shape != (len(cam_row), times.size) or np.any(np.isinf(P)) or np.any(P < 0):
        raise ClothFitError(f"{where}: per_image must be {len(cam_row)} x {times.size} fractions >= 0 (or null)")
    raised = False
    for i, c in enumerate(cams):
        row = cam_row.get(capture.cameras[c].name)
        for j, f in enumerate(fidx):
            k = np.flatnonzero(np.abs(times - capture.frame_times[f]) < 1e-6)
            if row is None or not k.size:
                raise ClothFitError(
                    f"{where}: no value for camera '{capture.cameras[c].name}' at t = {capture.frame_times[f]:g} s"
                )
            e = images[i][j]
            if np.isnan(P[row, k[0]]):  # not estimable there (the converter's cloth lay below the crop)
                continue
            e.splat = float(P[row, k[0]])
            if e.splat > e.floor:
                e.floor, raised = e.splat, True
    if not raised:
        return basis
    return f"{basis}; raised to the error of splatting a cloth's own points (the images were splatted from points)"


# ============================================================================ a fit against its floor


def floor_ratios(e_sil: ArrayLike, floors: ArrayLike, far: float = FAR_ABOVE) -> tuple[np.ndarray, np.ndarray]:
    """``(ratio, far_mask)``: per image ``E_sil / floor`` (same shapes, e.g. (C, F)) and where it exceeds
    ``far``. A floor of 0 gives inf where E_sil > 0 (and 1 where both are 0)."""
    e = np.asarray(e_sil, dtype=np.float64)
    f = np.asarray(floors, dtype=np.float64)
    if e.shape != f.shape:
        raise ClothFitError(f"floor ratios: {e.shape} errors but {f.shape} floors")
    if not (np.all(np.isfinite(f)) and np.all(f >= 0)):
        raise ClothFitError("floor ratios: floors must be finite and non-negative")
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(f > 0, e / np.where(f > 0, f, 1.0), np.where(e > 0, np.inf, 1.0))
    return r, r > far


def residual_profile(
    observed: np.ndarray,
    model: np.ndarray,
    ignore: np.ndarray | None = None,
    width: float = 1.0,
    name: str = "silhouette",
) -> dict:
    """Where a fit's residual (``observed`` XOR ``model``, outside ``ignore``) lies, for naming its cause:

    * ``e_sil``: eq. 6;
    * ``rim_share``: the share of the XOR pixels within ``width`` px of the observed outline (NaN when
      they agree). Well below 1: much of the residual is in the bulk (shape, timing, manipulation,
      model). Near 1: a thin sliver along the outline, which is what a biased segmenter leaves, but
      also what any small misfit leaves (below about 1 % E_sil every residual is a rim), so it
      separates causes only for large residuals;
    * ``balance``: (model-only - observed-only) / XOR pixels, in -1..1 (NaN when they agree). A segmenter
      that loses (adds) a rim all round gives near +1 (-1); a shape in the wrong place gives near 0;
    * ``bias_px``: ``e_sil / rim``: the uniform shift of the whole outline, in pixels, that would cost
      this error (``rim``: inner-boundary pixels / area). "A segmentation bias of this many pixels would
      explain the residual" is a statement a user can check against their footage.

    Measured (docs/noise_floor.md): the perfect model on the photoreal footage has rim share 0.83 and
    bias 0.47 px; the true shape 0.15 s late on synthetic footage, rim share 0.16 at 36 % E_sil."""
    import cv2

    o = _mask(observed, name)
    m = _mask(model, f"{name} model")
    if o.shape != m.shape:
        raise ClothFitError(f"{name}: observed {o.shape} and model {m.shape} silhouettes differ in size")
    known = np.ones(o.shape, bool)
    if ignore is not None:
        g = _mask(ignore, f"{name} ignore mask")
        if g.shape != o.shape:
            raise ClothFitError(f"{name}: ignore mask {g.shape} and silhouettes {o.shape} differ in size")
        known = ~g
        o = o & known
    area = int(np.count_nonzero(o))
    if area == 0:
        raise ClothFitError(f"{name}: the observed silhouette is empty, E_sil is undefined")
    x = (o ^ m) & known
    n = int(np.count_nonzero(x))
    ib = inner_boundary(o) & known
    rim = int(np.count_nonzero(ib)) / area
    out = {
        "e_sil": n / area,
        "rim": rim,
        "bias_px": (n / area) / rim if rim else float("nan"),
        "rim_share": float("nan"),
        "balance": float("nan"),
    }
    if n:
        d_in = cv2.distanceTransform(np.pad(o, 1).astype(np.uint8), cv2.DIST_L2, 3)[1:-1, 1:-1]
        d_out = cv2.distanceTransform(np.pad(~o, 1, constant_values=True).astype(np.uint8), cv2.DIST_L2, 3)[1:-1, 1:-1]
        d = np.where(o, d_in, d_out)
        out["rim_share"] = int(np.count_nonzero(x & (d <= width))) / n
        out["balance"] = (int(np.count_nonzero(x & m)) - int(np.count_nonzero(x & o))) / n
    return out
