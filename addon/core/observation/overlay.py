"""Overlays of observed vs. model silhouettes, and contact sheets.

Colours (RGB; ``write_rgb`` converts to cv2's BGR when saving): agreement (both) white
(255, 255, 255), missing (observed only) red (230, 40, 40), extra (model only) blue (40, 140, 255),
background black; pixels of unknown truth (ignore masks: occluders) grey (110, 110, 110), darker
(70, 70, 70) where the model is not.
"""
from __future__ import annotations

import os

import numpy as np

from ..errors import ClothFitError

AGREE_RGB = (255, 255, 255)
MISSING_RGB = (230, 40, 40)
EXTRA_RGB = (40, 140, 255)
IGNORE_MODEL_RGB = (110, 110, 110)
IGNORE_RGB = (70, 70, 70)


def overlay_image(observed: np.ndarray, model: np.ndarray, ignore=None) -> np.ndarray:
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


def label(img: np.ndarray, text: str) -> np.ndarray:
    import cv2
    out = img.copy()
    s = max(0.35, img.shape[1] / 900)
    cv2.putText(out, text, (5, int(18 * s / 0.5)), cv2.FONT_HERSHEY_SIMPLEX, s, (255, 255, 0), 1, cv2.LINE_AA)
    return out


def contact_sheet(images, cols: int = 6, tile_width: int = 213) -> np.ndarray:
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
        row = tiles[i:i + cols]
        row = [np.pad(t, ((0, th - t.shape[0]), (0, 0), (0, 0))) for t in row]
        row += [np.zeros((th, tile_width, 3), np.uint8)] * (cols - len(row))
        rows.append(np.concatenate([np.pad(t, ((1, 1), (1, 1), (0, 0)), constant_values=60) for t in row], 1))
    return np.concatenate(rows, 0)


def write_rgb(path: str, rgb: np.ndarray):
    import cv2
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    if not cv2.imwrite(path, rgb[..., ::-1]):
        raise ClothFitError(f"could not write image {path}")


def capture_overlays(capture, params, out_dir, cameras=None, times=None, sheet_name="contact_sheet.png",
                     max_sheet=36):
    """Write one overlay PNG per camera and frame plus a contact sheet; returns the list of paths."""
    from ..physics.models import model_and_row
    from .raster import silhouette
    model, row = model_and_row(params, getattr(capture, "model", None))
    cams = list(range(len(capture.cameras))) if cameras is None else list(cameras)
    times = list(capture.frame_times) if times is None else list(times)
    fidx = [capture.frame_index(t) for t in times]
    sc = capture.scenario.with_frames([float(capture.frame_times[i]) for i in fidx])
    sim = model.simulate(sc, row[None])
    if sim.exploded[0]:
        raise ClothFitError(f"overlay: the {model.name} model with these parameters explodes ({sim.reason[0]})")
    X = sim.positions[0]
    paths, sheet = [], []
    for c in cams:
        cam = capture.cameras[c]
        for j, f in enumerate(fidx):
            obs, ign = capture.load_observation(c, f)
            mod = silhouette(cam, X[j], sc.grid.triangles)
            img = overlay_image(obs, mod, ign)
            xor = obs ^ mod if ign is None else (obs ^ mod) & ~ign
            e = np.count_nonzero(xor) / max(1, obs.sum())
            path = os.path.join(out_dir, cam.name, f"{f:03d}.png")
            write_rgb(path, img)
            paths.append(path)
            if len(sheet) < max_sheet:
                sheet.append(label(img, f"{cam.name} t={capture.frame_times[f]:.2f} E={100 * e:.2f}%"))
    if sheet:
        sp = os.path.join(out_dir, sheet_name)
        write_rgb(sp, contact_sheet(sheet))
        paths.append(sp)
    return paths
