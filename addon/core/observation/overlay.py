"""Overlays of observed vs. model silhouettes, and contact sheets.

Colours (RGB; ``write_rgb`` converts to cv2's BGR when saving): agreement (both) white
(255, 255, 255), missing (observed only) red (230, 40, 40), extra (model only) blue (40, 140, 255),
background black; pixels of unknown truth (ignore masks: occluders) grey (110, 110, 110), darker
(70, 70, 70) where the model is not. ``overlay_on_image`` draws the same comparison on the camera's
own picture (a footage frame, a render): red and blue tints and the model's outline in yellow.

Against the noise floor (``floor.py``): ``mark_floor`` frames an overlay in the colour of its
image's ``E_sil / floor`` ratio (green at most ``FLOOR_NEAR`` x, amber up to ``far``, red beyond: far
above its own floor) and labels it; ``floor_sheet`` draws every camera x frame as a grid of such cells
(the overlays as thumbnails when given) with a summary line. ``capture_overlays(..., floors=...)``
adds both to its contact sheet and writes ``floor_sheet.png``; without floors its outputs are as before.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from ..errors import ClothFitError
from .floor import FAR_ABOVE, floor_ratios

if TYPE_CHECKING:
    from .capture import Capture

AGREE_RGB = (255, 255, 255)
MISSING_RGB = (230, 40, 40)
EXTRA_RGB = (40, 140, 255)
IGNORE_MODEL_RGB = (110, 110, 110)
IGNORE_RGB = (70, 70, 70)


def overlay_image(observed: np.ndarray, model: np.ndarray, ignore: np.ndarray | None = None) -> np.ndarray:
    """RGB uint8 image: white = both, red = observed only (missing), blue = model only (extra);
    ``ignore`` pixels (truth unknown) grey: light where the model covers them, dark elsewhere."""
    o = np.asarray(observed, dtype=bool)
    m = np.asarray(model, dtype=bool)
    if o.shape != m.shape:
        raise ClothFitError(f"overlay: observed {o.shape} and model {m.shape} silhouettes differ in size")
    img = np.zeros(o.shape + (3,), dtype=np.uint8)
    img[o & m] = AGREE_RGB
    img[o & ~m] = MISSING_RGB
    img[~o & m] = EXTRA_RGB
    if ignore is not None:
        g = np.asarray(ignore, dtype=bool)
        if g.shape != o.shape:
            raise ClothFitError(f"overlay: ignore mask {g.shape} and silhouettes {o.shape} differ in size")
        img[g & m] = IGNORE_MODEL_RGB
        img[g & ~m] = IGNORE_RGB
    return img


ON_IMAGE_MISSING_RGB = (255, 40, 40)  # tint where the cloth was observed but the model has none
ON_IMAGE_EXTRA_RGB = (40, 150, 255)  # tint where the model has cloth the camera did not see
ON_IMAGE_OUTLINE_RGB = (255, 230, 0)  # the model silhouette's outline


def silhouette_box(
    masks: Iterable[np.ndarray], margin: float = 0.15, shape: tuple[int, int] | None = None
) -> tuple[int, int, int, int]:
    """(y0, y1, x0, x1): the box around every mask's pixels, grown by ``margin`` of its size on
    each side, square where the image allows; the whole image if every mask is empty."""
    masks = [np.asarray(m, dtype=bool) for m in masks]
    h, w = shape or masks[0].shape
    ys, xs = [], []
    for m in masks:
        yy, xx = np.nonzero(m)
        ys += [yy.min(), yy.max()] if yy.size else []
        xs += [xx.min(), xx.max()] if xx.size else []
    if not ys:
        return 0, h, 0, w
    cy, cx = (min(ys) + max(ys)) / 2, (min(xs) + max(xs)) / 2
    half = (1 + 2 * margin) * max(max(ys) - min(ys), max(xs) - min(xs), 8) / 2
    half = min(half, h / 2, w / 2)
    y0 = round(min(max(cy - half, 0), h - 2 * half))
    x0 = round(min(max(cx - half, 0), w - 2 * half))
    return y0, y0 + round(2 * half), x0, x0 + round(2 * half)


def overlay_on_image(
    image: np.ndarray,
    observed: np.ndarray,
    model: np.ndarray,
    ignore: np.ndarray | None = None,
    box: tuple[int, int, int, int] | None = None,
    size: int | None = None,
    alpha: float = 0.55,
) -> np.ndarray:
    """The camera's own picture (RGB uint8, e.g. a footage frame or a render) with the comparison
    drawn on it: red tint where the cloth was observed but the model has none (missing), blue tint
    where the model has cloth the observation does not (extra), the model silhouette's outline in
    yellow; pixels of unknown truth (``ignore``) are left untinted. ``box`` (y0, y1, x0, x1) crops
    (see ``silhouette_box``), ``size`` scales the crop's longer side to that many pixels (the
    outline is drawn after scaling, so it stays one pixel wide)."""
    import cv2

    img = np.asarray(image)
    o = np.asarray(observed, dtype=bool)
    m = np.asarray(model, dtype=bool)
    if img.ndim != 3 or img.shape[2] != 3 or img.shape[:2] != o.shape or o.shape != m.shape:
        raise ClothFitError(
            f"overlay on image: image {img.shape}, observed {o.shape} and model {m.shape} "
            f"do not match (RGB image and silhouettes of one camera)"
        )
    g = np.zeros_like(o) if ignore is None else np.asarray(ignore, dtype=bool)
    y0, y1, x0, x1 = box or (0, o.shape[0], 0, o.shape[1])
    img, o, m, g = img[y0:y1, x0:x1], o[y0:y1, x0:x1], m[y0:y1, x0:x1], g[y0:y1, x0:x1]
    if size:
        f = size / max(img.shape[:2])
        dsize = (max(1, round(img.shape[1] * f)), max(1, round(img.shape[0] * f)))
        img = cv2.resize(img, dsize, interpolation=cv2.INTER_AREA if f < 1 else cv2.INTER_LINEAR)
        o, m, g = (
            cv2.resize(x.astype(np.uint8), dsize, interpolation=cv2.INTER_NEAREST).astype(bool) for x in (o, m, g)
        )
    out = img.astype(np.float32)
    for sel, rgb in ((o & ~m & ~g, ON_IMAGE_MISSING_RGB), (~o & m & ~g, ON_IMAGE_EXTRA_RGB)):
        out[sel] = (1 - alpha) * out[sel] + alpha * np.array(rgb, np.float32)
    out = np.clip(out, 0, 255).astype(np.uint8)
    contours, _ = cv2.findContours(m.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    out = np.ascontiguousarray(out)
    cv2.drawContours(out, contours, -1, ON_IMAGE_OUTLINE_RGB, 1, cv2.LINE_AA)
    return out


def label(img: np.ndarray, text: str) -> np.ndarray:
    import cv2

    out = img.copy()
    s = max(0.35, img.shape[1] / 900)
    cv2.putText(out, text, (5, int(18 * s / 0.5)), cv2.FONT_HERSHEY_SIMPLEX, s, (255, 255, 0), 1, cv2.LINE_AA)
    return out


def contact_sheet(images: Sequence[np.ndarray], cols: int = 6, tile_width: int = 213) -> np.ndarray:
    """Tile RGB images (resized to ``tile_width``) into one image."""
    import cv2

    if not images:
        raise ClothFitError("contact sheet: no images")
    tiles = []
    for im in images:
        h, w = im.shape[:2]
        th = int(round(h * tile_width / w))
        tiles.append(cv2.resize(im, (tile_width, th), interpolation=cv2.INTER_AREA))
    th = max(t.shape[0] for t in tiles)
    rows = []
    for i in range(0, len(tiles), cols):
        row = tiles[i : i + cols]
        row = [np.pad(t, ((0, th - t.shape[0]), (0, 0), (0, 0))) for t in row]
        row += [np.zeros((th, tile_width, 3), np.uint8)] * (cols - len(row))
        rows.append(np.concatenate([np.pad(t, ((1, 1), (1, 1), (0, 0)), constant_values=60) for t in row], 1))
    return np.concatenate(rows, 0)


def legend_strip(lines: Sequence[str], width: int) -> np.ndarray:
    """Text lines on a dark strip ``width`` px wide (RGB uint8): the contact sheet's legend."""
    import cv2

    h = 18 * len(lines) + 8
    out = np.full((h, width, 3), 24, np.uint8)
    for k, text in enumerate(lines):
        colour = (255, 140, 60) if "UNDETERMINED" in text else (230, 230, 230)
        cv2.putText(out, text, (6, 18 * k + 18), cv2.FONT_HERSHEY_SIMPLEX, 0.45, colour, 1, cv2.LINE_AA)
    return out


FLOOR_NEAR = 1.5  # E_sil / floor up to this: the image is at its floor (green)
FLOOR_AT_RGB = (60, 190, 90)  # at its floor
FLOOR_ABOVE_RGB = (240, 170, 30)  # above it, up to ``far`` x
FLOOR_FAR_RGB = (235, 50, 50)  # far above it (more than ``far`` x): the model, time scale or manipulation, or
# an observation error the floor cannot see (floor.py)


FLOOR_SHEET_CELL = 96  # px per camera x frame cell of floor_sheet.png


def _thumb(img, size):
    import cv2

    k = size / max(img.shape[:2])
    if k >= 1:
        return img
    return cv2.resize(
        img, (max(1, round(img.shape[1] * k)), max(1, round(img.shape[0] * k))), interpolation=cv2.INTER_AREA
    )


def floor_colour(ratio: float, far: float = FAR_ABOVE) -> tuple[int, int, int]:
    """RGB of an ``E_sil / floor`` ratio: green (<= FLOOR_NEAR), amber (<= far), red (> far, or not finite)."""
    if not np.isfinite(ratio) or ratio > far:
        return FLOOR_FAR_RGB
    return FLOOR_AT_RGB if ratio <= FLOOR_NEAR else FLOOR_ABOVE_RGB


def _ratio_text(e: float, floor: float) -> str:
    r = floor_ratios([e], [floor])[0][0]
    return "inf" if not np.isfinite(r) else f"{r:.1f}"


def mark_floor(
    img: np.ndarray, e_sil: float, floor: float, far: float = FAR_ABOVE, text: str | None = None
) -> np.ndarray:
    """A copy of ``img`` (RGB uint8) framed in ``floor_colour`` of ``e_sil / floor`` and labelled at the
    bottom ``E 4.20% floor 0.36% x11.7`` (``text`` is put in front of it)."""
    import cv2

    if img.ndim != 3 or img.shape[2] != 3:
        raise ClothFitError(f"mark floor: expected an RGB image, got shape {img.shape}")
    ratio = floor_ratios([e_sil], [floor])[0][0]
    rgb = floor_colour(ratio, far)
    out = img.copy()
    h, w = out.shape[:2]
    b = max(2, round(min(h, w) / 60))
    out[:b], out[-b:], out[:, :b], out[:, -b:] = rgb, rgb, rgb, rgb
    s = max(0.35, w / 900)
    msg = (text + " " if text else "") + f"E {100 * e_sil:.2f}% floor {100 * floor:.2f}% x{_ratio_text(e_sil, floor)}"
    y = h - b - max(4, int(6 * s / 0.5))
    cv2.putText(out, msg, (b + 3, y), cv2.FONT_HERSHEY_SIMPLEX, s, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(out, msg, (b + 3, y), cv2.FONT_HERSHEY_SIMPLEX, s, rgb, 1, cv2.LINE_AA)
    return out


def floor_sheet(
    e_sil: ArrayLike,
    floors: ArrayLike,
    cameras: Sequence[str],
    times: Sequence[float],
    far: float = FAR_ABOVE,
    tiles: Sequence[Sequence[np.ndarray]] | None = None,
    cell: int = 96,
) -> np.ndarray:
    """One RGB image: a grid of cameras (rows) x frames (columns), each cell coloured by its image's
    ``E_sil / floor`` (``floor_colour``) and showing the ratio; ``tiles[c][f]`` (RGB images, e.g. the
    overlays) are drawn as thumbnails inside the coloured frame. A header names the frame times, the
    left column the cameras, and a last line sums up: mean E_sil, mean floor, their ratio and how many
    images are far above their floor. ``e_sil`` and ``floors``: (C, F) fractions."""
    import cv2

    e = np.asarray(e_sil, dtype=np.float64)
    f = np.asarray(floors, dtype=np.float64)
    if e.ndim != 2:
        raise ClothFitError(f"floor sheet: errors must be (cameras, frames), got shape {e.shape}")
    ratio, far_mask = floor_ratios(e, f, far)
    C, F = e.shape
    if len(cameras) != C or len(times) != F:
        raise ClothFitError(f"floor sheet: {C} x {F} errors but {len(cameras)} cameras and {len(times)} times")
    if tiles is not None and (len(tiles) != C or any(len(row) != F for row in tiles)):
        raise ClothFitError(f"floor sheet: tiles must be {C} x {F} images")
    cell = max(int(cell), 24)
    lw, hh, fh = max(60, cell // 2 + 20), 22, 26
    font, s = cv2.FONT_HERSHEY_SIMPLEX, 0.4
    em, fm = float(e.mean()), float(f.mean())
    summary = (
        f"mean E {100 * em:.2f}%  mean floor {100 * fm:.2f}%  x{_ratio_text(em, fm)}  "
        f"{int(far_mask.sum())}/{e.size} images > {far:g}x their floor"
    )
    width = max(lw + F * cell, cv2.getTextSize(summary, font, s, 1)[0][0] + 8)
    img = np.full((hh + C * cell + fh, width, 3), 30, np.uint8)
    for j, t in enumerate(times):
        cv2.putText(img, f"t={float(t):.2f}", (lw + j * cell + 4, 15), font, s, (230, 230, 230), 1, cv2.LINE_AA)
    for i, name in enumerate(cameras):
        y0 = hh + i * cell
        cv2.putText(img, str(name)[:10], (4, y0 + cell // 2 + 4), font, s, (230, 230, 230), 1, cv2.LINE_AA)
        for j in range(F):
            x0 = lw + j * cell
            rgb = floor_colour(ratio[i, j], far)
            img[y0 + 1 : y0 + cell - 1, x0 + 1 : x0 + cell - 1] = rgb
            b = max(3, cell // 16)
            if tiles is not None:
                t = np.asarray(tiles[i][j])
                inner = cell - 2 - 2 * b
                k = inner / max(t.shape[:2])
                th, tw = max(1, round(t.shape[0] * k)), max(1, round(t.shape[1] * k))
                thumb = cv2.resize(t, (tw, th), interpolation=cv2.INTER_AREA)
                yy, xx = y0 + 1 + b + (inner - th) // 2, x0 + 1 + b + (inner - tw) // 2
                img[y0 + 1 + b : y0 + cell - 1 - b, x0 + 1 + b : x0 + cell - 1 - b] = 0
                img[yy : yy + th, xx : xx + tw] = thumb
            else:
                img[y0 + 1 + b : y0 + cell - 1 - b, x0 + 1 + b : x0 + cell - 1 - b] = (20, 20, 20)
            txt = "x" + ("inf" if not np.isfinite(ratio[i, j]) else f"{ratio[i, j]:.1f}")
            cv2.putText(img, txt, (x0 + b + 3, y0 + cell - b - 5), font, s, (0, 0, 0), 3, cv2.LINE_AA)
            cv2.putText(img, txt, (x0 + b + 3, y0 + cell - b - 5), font, s, rgb, 1, cv2.LINE_AA)
    cv2.putText(
        img,
        summary,
        (4, hh + C * cell + 18),
        font,
        s,
        floor_colour(floor_ratios([em], [fm])[0][0], far),
        1,
        cv2.LINE_AA,
    )
    return img


def write_rgb(path: str, rgb: np.ndarray) -> None:
    import cv2

    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    if not cv2.imwrite(path, rgb[..., ::-1]):
        raise ClothFitError(f"could not write image {path}")


def capture_overlays(
    capture: Capture,
    params: dict[str, Any],
    out_dir: str | os.PathLike,
    cameras: Iterable[int] | None = None,
    times: Iterable[float] | None = None,
    sheet_name: str = "contact_sheet.png",
    max_sheet: int = 36,
    images: Callable[[int, int], np.ndarray | None] | None = None,
    floors: ArrayLike | None = None,
    far: float = FAR_ABOVE,
    legend: Sequence[str] | None = None,
) -> list[str]:
    """Write one overlay PNG per camera and frame plus a contact sheet; returns the list of paths.
    ``images(camera index, frame index)``: the camera's own picture of that frame (RGB uint8, e.g.
    ``footage.extract.footage_images``); where it gives one, the comparison is drawn on it
    (``overlay_on_image``) instead of on black. ``floors``: the images' noise floors, (cameras, times)
    in the order drawn (``floor.capture_floor(...).per_image()``): then the contact sheet's tiles are
    framed and labelled by ``mark_floor`` and ``floor_sheet.png`` (``floor_sheet``) is written too,
    second to last in the list (the per-image PNGs are unchanged). ``legend``: text lines drawn under the contact
    sheet (a fit's settings with their intervals: ``fitting.result.interval_lines``)."""
    from ..physics.models import model_and_row
    from ..physics.scenario import fitted_scenario
    from .raster import silhouette

    model, row = model_and_row(params, getattr(capture, "model", None))
    cams = list(range(len(capture.cameras))) if cameras is None else list(cameras)
    times = list(capture.frame_times) if times is None else list(times)
    fidx = [capture.frame_index(t) for t in times]
    sc = capture.scenario.with_frames([float(capture.frame_times[i]) for i in fidx])
    sc = fitted_scenario(sc, params)  # a fit result's estimated manipulation (time offset, handles)
    sim = model.simulate(sc, row[None])
    if sim.exploded[0]:
        raise ClothFitError(f"overlay: the {model.name} model with these parameters explodes ({sim.reason[0]})")
    X = sim.positions[0]
    if floors is not None:
        floors = np.asarray(floors, dtype=np.float64)
        if floors.shape != (len(cams), len(fidx)):
            raise ClothFitError(
                f"overlay: floors are {floors.shape} but {len(cams)} cameras x {len(fidx)} frames are drawn"
            )
    paths, sheet = [], []
    errs = np.zeros((len(cams), len(fidx)))
    thumbs = [[None] * len(fidx) for _ in cams]
    for ci, c in enumerate(cams):
        cam = capture.cameras[c]
        for j, f in enumerate(fidx):
            obs, ign = capture.load_observation(c, f)
            mod = silhouette(cam, X[j], sc.grid.triangles, crop=sc.crop)
            photo = images(c, f) if images is not None else None
            img = overlay_on_image(photo, obs, mod, ign) if photo is not None else overlay_image(obs, mod, ign)
            xor = obs ^ mod if ign is None else (obs ^ mod) & ~ign
            e = np.count_nonzero(xor) / max(1, obs.sum())
            errs[ci, j] = e
            path = os.path.join(out_dir, cam.name, f"{f:03d}.png")
            write_rgb(path, img)
            paths.append(path)
            if floors is not None:
                y0, y1, x0, x1 = silhouette_box([obs, mod])
                thumbs[ci][j] = _thumb(img[y0:y1, x0:x1], FLOOR_SHEET_CELL)
            if len(sheet) < max_sheet:
                if floors is None:
                    sheet.append(label(img, f"{cam.name} t={capture.frame_times[f]:.2f} E={100 * e:.2f}%"))
                else:
                    sheet.append(
                        mark_floor(label(img, f"{cam.name} t={capture.frame_times[f]:.2f}"), e, floors[ci, j], far)
                    )
    if floors is not None:
        fp = os.path.join(out_dir, "floor_sheet.png")
        write_rgb(
            fp,
            floor_sheet(
                errs,
                floors,
                [capture.cameras[c].name for c in cams],
                [capture.frame_times[f] for f in fidx],
                far,
                tiles=thumbs,
                cell=FLOOR_SHEET_CELL,
            ),
        )
        paths.append(fp)
    if sheet:
        sp = os.path.join(out_dir, sheet_name)
        img = contact_sheet(sheet)
        if legend:
            img = np.concatenate([img, legend_strip(legend, img.shape[1])], 0)
        write_rgb(sp, img)
        paths.append(sp)
    return paths
