# SPDX-License-Identifier: GPL-3.0-or-later
"""Blender-rendered silhouettes: Workbench, flat white, anti-aliasing off, colours kept 0/1.

Settings (applied for the duration of a ``silhouette_render`` block, then restored): engine
Workbench; lighting FLAT, colour SINGLE white; shadows, cavity, outline, specular, X-ray off;
``scene.display.render_aa = 'OFF'`` (one sample per pixel centre, as the core rasteriser does);
view transform Standard, look None, exposure 0, gamma 1; dither 0; film transparent (the
silhouette is the alpha channel, 0 or 255 with AA off); compositor and sequencer off; every
object but the cloth hidden from the render. In background mode the Render Result has no
pixels, so each render is written to a PNG and read back (PNG rows run top-down, as numpy's).
"""
from __future__ import annotations

import contextlib
import ctypes
import os
import sys
import tempfile

import bpy
import numpy as np

from ..core.errors import ClothFitError


def _set(saved, owner, attr, value):
    saved.append((owner, attr, getattr(owner, attr)))
    setattr(owner, attr, value)


@contextlib.contextmanager
def silhouette_render(scene, objects):
    """Configure ``scene`` for silhouette renders of ``objects`` only; restore everything after."""
    saved = []
    hidden = []
    keep = {o.name for o in objects}
    try:
        r = scene.render
        _set(saved, r, "engine", "BLENDER_WORKBENCH")
        sh = scene.display.shading
        _set(saved, sh, "light", "FLAT")
        _set(saved, sh, "color_type", "SINGLE")
        _set(saved, sh, "single_color", (1.0, 1.0, 1.0))
        for attr in ("show_shadows", "show_cavity", "show_object_outline", "show_specular_highlight",
                     "show_xray", "use_dof", "show_backface_culling"):
            if hasattr(sh, attr):
                _set(saved, sh, attr, False)
        _set(saved, scene.display, "render_aa", "OFF")
        vs = scene.view_settings
        _set(saved, vs, "view_transform", "Standard")
        _set(saved, vs, "look", "None")
        _set(saved, vs, "exposure", 0.0)
        _set(saved, vs, "gamma", 1.0)
        _set(saved, vs, "use_curve_mapping", False)
        _set(saved, r, "dither_intensity", 0.0)
        _set(saved, r, "film_transparent", True)
        _set(saved, r, "use_compositing", False)
        _set(saved, r, "use_sequencer", False)
        _set(saved, r, "use_border", False)
        _set(saved, r, "use_stamp", False)
        im = r.image_settings
        _set(saved, im, "file_format", "PNG")
        _set(saved, im, "color_mode", "RGBA")
        _set(saved, im, "color_depth", "8")
        _set(saved, im, "compression", 0)
        _set(saved, r, "filepath", r.filepath)
        saved.append((scene, "camera", scene.camera))
        for o in scene.objects:
            if o.name not in keep and o.type in {"MESH", "CURVE", "SURFACE", "META", "FONT", "VOLUME",
                                                   "GPENCIL", "GREASEPENCIL", "POINTCLOUD", "CURVES"} \
                    and not o.hide_render:
                o.hide_render = True
                hidden.append(o)
        for o in objects:
            if o.hide_render:
                _set(saved, o, "hide_render", False)
        yield
    finally:
        for o in hidden:
            o.hide_render = False
        for owner, attr, value in reversed(saved):
            try:
                setattr(owner, attr, value)
            except (AttributeError, TypeError, ReferenceError):
                pass


@contextlib.contextmanager
def quiet_stdout():
    """Silence Blender's per-render "Fra:... / Saved: ..." lines (C-level stdout).

    Set CLOTHFIT_RENDER_VERBOSE=1 to keep them. Does nothing when stdout has no file descriptor."""
    if os.environ.get("CLOTHFIT_RENDER_VERBOSE"):
        yield
        return
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):
        yield
        return
    libc = None
    try:
        libc = ctypes.CDLL(None)
    except OSError:
        pass
    sys.stdout.flush()
    if libc is not None:
        libc.fflush(None)
    saved = os.dup(fd)
    null = os.open(os.devnull, os.O_WRONLY)
    os.dup2(null, fd)
    try:
        yield
    finally:
        if libc is not None:
            libc.fflush(None)
        os.dup2(saved, fd)
        os.close(saved)
        os.close(null)


def render_to_file(scene, camera_obj, path):
    """Render the scene through ``camera_obj`` to ``path`` (PNG). The caller sets the format."""
    scene.camera = camera_obj
    scene.render.filepath = path
    with quiet_stdout():
        bpy.ops.render.render(write_still=True, scene=scene.name)
    if not os.path.isfile(path):
        raise ClothFitError(f"Blender did not write the render {path}")
    return path


def read_alpha_mask(path, shape=None):
    import cv2
    img = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    if img is None or img.ndim != 3 or img.shape[2] != 4:
        raise ClothFitError(f"render {path}: expected an RGBA PNG, got {None if img is None else img.shape}")
    if shape is not None and img.shape[:2] != tuple(shape):
        raise ClothFitError(f"render {path}: {img.shape[0]}x{img.shape[1]} but {shape[0]}x{shape[1]} expected")
    return img[..., 3] > 127


def render_masks(scene, cloth_obj, camera_objs, tmpdir=None):
    """Bool (H, W) silhouettes of ``cloth_obj`` from each camera, at the scene's current frame."""
    from .scene import render_size
    W, H = render_size(scene)
    own = tmpdir is None
    tmpdir = tmpdir or tempfile.mkdtemp(prefix="clothfit_render_")
    out = []
    try:
        with silhouette_render(scene, [cloth_obj]):
            for i, cam in enumerate(camera_objs):
                p = os.path.join(tmpdir, f"sil_{i:03d}.png")
                render_to_file(scene, cam, p)
                out.append(read_alpha_mask(p, (H, W)))
                if own:
                    os.remove(p)
    finally:
        if own:
            try:
                os.rmdir(tmpdir)
            except OSError:
                pass
    return out


def render_mask(scene, cloth_obj, camera_obj):
    return render_masks(scene, cloth_obj, [camera_obj])[0]


def render_view(scene, camera_obj, path, resolution=None):
    """A plain Workbench (studio light) picture of the scene through ``camera_obj`` (for docs)."""
    saved = []
    try:
        r = scene.render
        _set(saved, r, "engine", "BLENDER_WORKBENCH")
        _set(saved, scene.display, "render_aa", "8")
        _set(saved, scene.view_settings, "view_transform", "Standard")
        _set(saved, r, "film_transparent", False)
        _set(saved, r.image_settings, "file_format", "PNG")
        _set(saved, r.image_settings, "color_mode", "RGB")
        _set(saved, r, "filepath", r.filepath)
        if resolution:
            _set(saved, r, "resolution_x", int(resolution[0]))
            _set(saved, r, "resolution_y", int(resolution[1]))
            _set(saved, r, "resolution_percentage", 100)
        saved.append((scene, "camera", scene.camera))
        render_to_file(scene, camera_obj, path)
    finally:
        for owner, attr, value in reversed(saved):
            setattr(owner, attr, value)
    return path


def mask_image(mask):
    return np.where(np.asarray(mask, bool), 255, 0).astype(np.uint8)
