# SPDX-License-Identifier: GPL-3.0-or-later
"""Overlays: observed against model silhouettes per camera and frame (the model's from the core
rasteriser or from Blender renders of the baked cloth), E_sil per image, a contact sheet; the
cameras then show their overlay as background."""

from __future__ import annotations

import os

import numpy as np

from ...core.errors import ClothFitError
from .. import render as R
from .. import scene as S
from .footage import OVERLAY_DIR, load_image, overlay_path, show_observations
from .reading import capture_dir, cloth_object, params_from_scene, props


def model_masks_core(scene, cap, frame_indices):
    """Model silhouettes [camera][frame] from the core simulation and rasteriser."""
    from ...core.observation.raster import silhouette
    from ...core.physics.models import simulate as core_simulate

    sc = cap.scenario.with_frames([float(cap.frame_times[i]) for i in frame_indices])
    res = core_simulate(sc, [params_from_scene(scene)])
    if res.exploded[0]:
        raise ClothFitError(f"the scene's parameters make the simulation unstable: {res.reason[0]}")
    X = res.positions[0]
    tris = sc.grid.triangles
    return [[silhouette(c, X[k], tris, crop=sc.crop) for k in range(len(frame_indices))] for c in cap.cameras]


def model_masks_blender(scene, cap, frame_indices):
    """Model silhouettes [camera][frame] rendered by Blender from the baked cloth."""
    distorted = [c.name for c in cap.cameras if c.dist.size and np.any(c.dist != 0)]
    if distorted:
        raise ClothFitError(
            f"the capture's cameras have lens distortion ({', '.join(distorted[:4])}"
            f"{', ...' if len(distorted) > 4 else ''}) but Blender renders pinhole images: "
            f"choose the Core model source for these overlays"
        )
    cloth = cloth_object(scene)
    baked = {round(t, 3) for t in S.baked_times(cloth)}
    times = [float(cap.frame_times[i]) for i in frame_indices]
    miss = [t for t in times if round(t, 3) not in baked]
    if miss:
        raise ClothFitError(f"the cloth is not baked at t = {miss[0]:.3f} s: simulate (or apply the fit) first")
    objs = {o.name: o for o in S.rig_objects(scene)}
    cam_objs = []
    for c in cap.cameras:
        if c.name not in objs:
            raise ClothFitError(f"the rig has no camera '{c.name}' of the capture: load the capture first")
        cam_objs.append(objs[c.name])
    out = [[None] * len(times) for _ in cap.cameras]
    frame0 = scene.frame_current
    try:
        for k, t in enumerate(times):
            scene.frame_set(S.frame_of_time(scene, t))
            for ci, m in enumerate(R.render_masks(scene, cloth, cam_objs)):
                out[ci][k] = m
    finally:
        scene.frame_set(frame0)
    return out


def make_overlays(scene, source=None, frame_indices=None, sheet_frame=None):
    """Observed vs. model silhouettes per camera and frame -> ``<capture>/overlays/<cam>/<f>.png``,
    a contact sheet of all cameras at one frame, E_sil per image in ``overlays/summary.json``;
    cameras show their overlay as background. Returns the summary dict."""
    from ...core.observation.capture import load_capture as core_load
    from ...core.observation.metrics import e_sil
    from ...core.observation.overlay import (
        contact_sheet,
        label,
        overlay_image,
        write_rgb,
    )

    p = props(scene)
    cap = core_load(capture_dir(scene))
    fidx = list(range(cap.n_frames)) if frame_indices is None else [int(i) for i in frame_indices]
    for i in fidx:
        if not 0 <= i < cap.n_frames:
            raise ClothFitError(f"overlay frame index {i} outside 0..{cap.n_frames - 1}")
    source = source or p.overlay_source
    model = (model_masks_blender if source == "BLENDER" else model_masks_core)(scene, cap, fidx)
    errs = np.zeros((cap.n_cameras, len(fidx)))
    sheet_fi = fidx[len(fidx) // 2] if sheet_frame is None else int(sheet_frame)
    tiles = []
    for ci, c in enumerate(cap.cameras):
        for k, fi in enumerate(fidx):
            obs, ign = cap.load_observation(ci, fi)
            mod = model[ci][k]
            if mod.shape != obs.shape:
                raise ClothFitError(
                    f"camera '{c.name}': model silhouette {mod.shape} and observed {obs.shape} differ in size"
                )
            # pixels of unknown truth (occluders) leave eq. 6: the model is not judged there
            errs[ci, k] = e_sil(obs, mod if ign is None else mod & ~ign, name=cap.silhouette_path(ci, fi))
            img = overlay_image(obs, mod, ign)
            write_rgb(overlay_path(cap, ci, fi), img)
            if fi == sheet_fi:
                tiles.append(label(img, f"{c.name} t={cap.frame_times[fi]:.2f} E={100 * errs[ci, k]:.2f}%"))
    out_dir = os.path.join(cap.root, OVERLAY_DIR)
    sheet_path = None
    if tiles:
        sheet = contact_sheet(tiles, cols=min(6, len(tiles)))
        sheet_path = os.path.join(out_dir, "contact_sheet.png")
        write_rgb(sheet_path, sheet)
        img = load_image("clothfit contact sheet", sheet_path)
        img.use_fake_user = False
    summary = {
        "source": source,
        "params": params_from_scene(scene).as_dict(),
        "frames": fidx,
        "times": [float(cap.frame_times[i]) for i in fidx],
        "cameras": cap.camera_names,
        "E_sil_pct": (100 * errs).tolist(),
        "mean_E_sil_pct": float(100 * errs.mean()),
        "contact_sheet": sheet_path,
        "contact_sheet_frame": sheet_fi,
    }
    from ...core.jsonio import write_json

    write_json(os.path.join(out_dir, "summary.json"), summary)
    p.overlay_dir = out_dir
    p.overlay_error = summary["mean_E_sil_pct"]
    show_observations(scene, p.view_frame if p.view_frame in fidx else fidx[0], cap, kind="overlay")
    return summary
