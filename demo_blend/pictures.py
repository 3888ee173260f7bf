"""The demo's pictures that tell its story (no bpy here: numpy + OpenCV on the capture and the fit).

* ``fit_on_images``: the camera images with the comparison drawn on them, first guess (the
  optimiser's starting point) against the fitted cloth, for a training camera and held-out ones;
* ``error_curve``: the best training E_sil against the evaluations spent;
* ``parameter_table``: true, first-guess and fitted parameters with their errors;
* ``first_guess_params``: where the fit starts (the centre of the search box, as CMA-ES starts).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

FONT = cv2.FONT_HERSHEY_SIMPLEX
BG = (32, 34, 38)
FG = (235, 235, 235)
DIM = (150, 150, 150)
ACCENT = (255, 200, 60)


def first_guess_params(capture):
    """The paper model's parameters at the centre of the default search box: CMA-ES's first mean."""
    from clothfit.core.fitting.job import FitConfig
    from clothfit.core.fitting.parameters import make_parameters

    par = make_parameters(capture, FitConfig())
    return par.params(par.space.decode(np.full(par.space.n, 0.5)))


def model_silhouettes(capture, params, cams, t):
    """Core-rasterised silhouettes of ``params`` at capture time ``t`` for camera indices ``cams``."""
    from clothfit.core.observation.raster import silhouette
    from clothfit.core.physics.models import model_and_row

    model, row = model_and_row(params, getattr(capture, "model", None))
    fi = capture.frame_index(t)
    sc = capture.scenario.with_frames([float(capture.frame_times[fi])])
    sim = model.simulate(sc, row[None])
    X = sim.positions[0][0]
    return [silhouette(capture.cameras[c], X, sc.grid.triangles) for c in cams]


def e_sil_pct(observed, model, ignore=None):
    xor = observed ^ model
    if ignore is not None:
        xor &= ~ignore
    return 100.0 * np.count_nonzero(xor) / max(1, np.count_nonzero(observed))


def _text(img, s, org, scale=0.5, color=FG, thick=1):
    cv2.putText(img, s, org, FONT, scale, color, thick, cv2.LINE_AA)


def _text_width(s, scale=0.5, thick=1):
    return cv2.getTextSize(s, FONT, scale, thick)[0][0]


def fit_on_images(capture, images, rows, cams, t, roles, tile=300):
    """One picture: a row per parameter set (``rows``: [(title, params)]), a column per camera
    (``cams`` indices, ``images`` their RGB pictures at time ``t``, ``roles`` e.g. "training");
    each tile the camera image cropped around the cloth with ``overlay_on_image``. Returns
    (RGB image, {row title: [E_sil % per camera]})."""
    from clothfit.core.observation.overlay import overlay_on_image, silhouette_box

    fi = capture.frame_index(t)
    obs = [capture.load_observation(c, fi) for c in cams]
    mods = {title: model_silhouettes(capture, p, cams, t) for title, p in rows}
    boxes = [silhouette_box([o] + [mods[title][j] for title, _ in rows], margin=0.12) for j, (o, _) in enumerate(obs)]
    head, gap, tit = 34, 6, 28
    W = len(cams) * (tile + gap) + gap
    H = head + len(rows) * (tile + tit + gap) + 44
    out = np.full((H, W, 3), BG, np.uint8)
    errors = {}
    for j, c in enumerate(cams):
        name = capture.cameras[c].name
        _text(out, f"{name} ({roles[j]})", (gap + j * (tile + gap) + 4, 22), 0.55)
    y = head
    for title, _ in rows:
        _text(out, title, (gap + 2, y + 19), 0.52, ACCENT)
        y += tit
        errors[title] = []
        for j in range(len(cams)):
            o, ign = obs[j]
            m = mods[title][j]
            e = e_sil_pct(o, m, ign)
            errors[title].append(e)
            im = overlay_on_image(images[j], o, m, ign, box=boxes[j], size=tile)
            x = gap + j * (tile + gap)
            out[y : y + im.shape[0], x : x + im.shape[1]] = im
            _text(out, f"E_sil {e:.1f} %", (x + 6, y + tile - 8), 0.5, (255, 255, 255))
        y += tile + gap
    legend = [
        ("observed only (missing)", (255, 40, 40)),
        ("model only (extra)", (40, 150, 255)),
        ("model outline", (255, 230, 0)),
    ]
    x = gap + 2
    for s, rgb in legend:
        cv2.rectangle(out, (x, H - 30), (x + 14, H - 16), rgb, -1)
        _text(out, s, (x + 20, H - 18), 0.45)
        x += 20 + _text_width(s, 0.45) + 22
    _text(out, f"t = {t:.2f} s", (W - 90, H - 18), 0.45, DIM)
    return out, errors


def error_curve(history, n_images, floor_pct=None, width=760, height=380, title="training E_sil"):
    """Best-so-far mean training E_sil [%] (log scale) against evaluations: ``history`` is the
    result's [[evaluations, best E_all], ...]; ``n_images`` the training images (E_all / n = mean
    E_sil); ``floor_pct``: the true parameters' own error on the same images (dashed)."""
    ev = np.array([h[0] for h in history], float)
    e = np.array([100.0 * h[1] / n_images for h in history], float)
    img = np.full((height, width, 3), BG, np.uint8)
    L, R, T, B = 70, 20, 36, 50
    lo = min(e.min(), floor_pct if floor_pct else e.min()) * 0.7
    hi = e.max() * 1.4
    d0, d1 = math.floor(math.log10(lo)), math.ceil(math.log10(hi))
    xmax = ev.max() * 1.04

    def X(v):
        return round(L + (width - L - R) * v / xmax)

    def Y(v):
        return round(T + (height - T - B) * (d1 - math.log10(max(v, 10.0**d0))) / (d1 - d0))

    for d in range(d0, d1 + 1):
        for k in (1, 2, 5):
            v = k * 10.0**d
            if 10.0**d0 <= v <= 10.0**d1:
                cv2.line(img, (L, Y(v)), (width - R, Y(v)), (58, 60, 66) if k > 1 else (80, 82, 90), 1)
                if k in (1, 5) or d1 - d0 <= 2:
                    _text(img, f"{v:g}", (L - 8 - _text_width(f"{v:g}", 0.42), Y(v) + 5), 0.42, DIM)
    step = 10 ** math.floor(math.log10(xmax / 2))
    step = step * (5 if xmax / step > 20 else 2 if xmax / step > 8 else 1)
    for v in np.arange(0, xmax, step):
        cv2.line(img, (X(v), height - B), (X(v), height - B + 5), DIM, 1)
        _text(img, f"{v:g}", (X(v) - _text_width(f"{v:g}", 0.42) // 2, height - B + 20), 0.42, DIM)
    cv2.rectangle(img, (L, T), (width - R, height - B), (100, 100, 100), 1)
    if floor_pct:
        for x0 in range(L, width - R, 12):
            cv2.line(img, (x0, Y(floor_pct)), (min(x0 + 6, width - R), Y(floor_pct)), (120, 220, 120), 1)
        s = f"true parameters: {floor_pct:.2f} %"
        _text(img, s, (width - R - _text_width(s, 0.45) - 6, Y(floor_pct) - 7), 0.45, (120, 220, 120))
    pts = []
    for i in range(len(ev)):
        pts.append((X(ev[i]), Y(e[i])))
        if i + 1 < len(ev):
            pts.append((X(ev[i + 1]), Y(e[i])))
    cv2.polylines(img, [np.array(pts, np.int32)], False, ACCENT, 2, cv2.LINE_AA)
    _text(img, f"first guess: {e[0]:.1f} %", (X(ev[0]) + 8, Y(e[0]) - 10), 0.45, ACCENT)
    s = f"{e[-1]:.2f} % after {int(ev[-1])} evaluations"
    _text(
        img,
        s,
        (
            width - R - _text_width(s, 0.45) - 6,
            Y(e[-1]) - 8 if not floor_pct or abs(Y(e[-1]) - Y(floor_pct)) > 18 else Y(e[-1]) + 20,
        ),
        0.45,
        ACCENT,
    )
    _text(img, title + " [%], best so far (log scale)", (L, 22), 0.5)
    _text(img, "model evaluations", (width // 2 - 60, height - 10), 0.45, DIM)
    return img


def parameter_table(rows, header, width=760, row_h=30, note=None):
    """A table picture: ``header`` = column titles, ``rows`` = lists of cell strings."""
    cols = len(header)
    first = 230
    cw = (width - first - 10) // (cols - 1)
    H = 40 + row_h * (len(rows) + 1) + (30 if note else 10)
    img = np.full((H, width, 3), BG, np.uint8)
    y = 40

    def xcell(i):
        return 10 if i == 0 else first + (i - 1) * cw

    for i, h in enumerate(header):
        _text(img, h, (xcell(i), y), 0.5, ACCENT)
    cv2.line(img, (10, y + 10), (width - 10, y + 10), (100, 100, 100), 1)
    for r in rows:
        y += row_h
        for i, cell in enumerate(r):
            _text(img, cell, (xcell(i), y), 0.5, FG if i else DIM)
    if note:
        _text(img, note, (10, H - 12), 0.42, DIM)
    return img


def write(path, rgb):
    from clothfit.core.observation.overlay import write_rgb

    write_rgb(path, rgb)
    return path
