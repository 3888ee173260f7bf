# SPDX-License-Identifier: GPL-3.0-or-later
"""Fallback overlay drawing, used only if ``core/overlay.py`` is not importable.

Colours (BGR): agreement white, missing (observed only) red, extra (model only) blue, black
elsewhere: the same convention as the core module.
"""
from __future__ import annotations

import numpy as np


def overlay_image(observed, model):
    o = np.asarray(observed, bool)
    m = np.asarray(model, bool)
    img = np.zeros(o.shape + (3,), np.uint8)
    img[o & m] = (255, 255, 255)
    img[o & ~m] = (0, 0, 255)
    img[~o & m] = (255, 0, 0)
    return img


def contact_sheet(images, cols=6, tile_width=None):
    import cv2
    imgs = [np.asarray(i) for i in images]
    if not imgs:
        raise ValueError("no images")
    h, w = imgs[0].shape[:2]
    if tile_width:
        h, w = int(round(h * tile_width / w)), int(tile_width)
        imgs = [cv2.resize(i, (w, h), interpolation=cv2.INTER_AREA) for i in imgs]
    rows = (len(imgs) + cols - 1) // cols
    sheet = np.full((rows * h, cols * w, 3), 64, np.uint8)
    for k, i in enumerate(imgs):
        r, c = divmod(k, cols)
        sheet[r * h:(r + 1) * h, c * w:(c + 1) * w] = i if i.ndim == 3 else i[..., None]
    return sheet
