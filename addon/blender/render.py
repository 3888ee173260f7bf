# SPDX-License-Identifier: GPL-3.0-or-later
"""Blender-rendered silhouettes: Workbench (or Eevee), flat, anti-aliasing off, colours kept 0/1.

Settings (applied for the duration of a ``silhouette_render`` block, then restored): engine
Workbench; lighting FLAT, colour SINGLE white; shadows, cavity, outline, specular, X-ray off;
``scene.display.render_aa = 'OFF'`` (one sample per pixel centre, as the core rasteriser does);
view transform Standard, look None, exposure 0, gamma 1; dither 0; film transparent (the
silhouette is the alpha channel, 0 or 255 with AA off); compositor and sequencer off; every
object but the cloth hidden from the render. In background mode the Render Result has no
pixels, so each render is written to a PNG and read back (PNG rows run top-down, as numpy's).

**Occluders** (the objects of the collection ``Occluders``: a post, a hand, a gripper) hide the cloth
and are written as ignore masks (pixels of unknown truth, ``docs/capture_format.md``):

* **Eevee** (``engine="EEVEE"``): real holdouts. Pass 1 renders the cloth with every occluder as a
  holdout (``Object.is_holdout``): the alpha is the visible cloth. Pass 2 renders the occluders with
  the cloth as a holdout: the alpha is the visible occluder = the ignore mask. Anti-aliasing off:
  one sample (``eevee.taa_render_samples = 1``) and a zero-width pixel filter
  (``render.filter_size = 0``), so alpha is 0 or 255.
* **Workbench** ignores holdout flags (measured in Blender 4.5: neither ``Object.is_holdout`` nor a
  holdout collection removes anything), so there the holdout is done by colour in one pass: object
  colours (``shading.color_type = 'OBJECT'``), the cloth white, the occluders black; visible cloth =
  opaque and white, visible occluder = opaque and black. Same result, half the renders.
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
    old = getattr(owner, attr)
    if not isinstance(old, str) and hasattr(old, "__len__"):
        old = tuple(old)  # a bpy_prop_array is a live view: keep the values, not the view
    saved.append((owner, attr, old))
    setattr(owner, attr, value)


OCCLUDERS = "Occluders"  # the collection whose objects are occluders
ENGINES = ("WORKBENCH", "EEVEE")


def occluder_objects(scene):
    """Renderable objects of the scene's ``Occluders`` collection (and its children)."""
    coll = bpy.data.collections.get(OCCLUDERS)
    if coll is None or coll.name not in {c.name for c in scene.collection.children_recursive}:
        return []
    return [o for o in coll.all_objects if o.type in RENDERABLE and not o.hide_render]


RENDERABLE = {"MESH", "CURVE", "SURFACE", "META", "FONT", "VOLUME", "GPENCIL", "GREASEPENCIL", "POINTCLOUD", "CURVES"}


def _eevee_engine():
    items = {i.identifier for i in bpy.types.RenderSettings.bl_rna.properties["engine"].enum_items}
    for e in ("BLENDER_EEVEE_NEXT", "BLENDER_EEVEE"):
        if e in items:
            return e
    raise ClothFitError("this Blender has no Eevee render engine")


@contextlib.contextmanager
def silhouette_render(scene, objects, engine="WORKBENCH", holdouts=()):
    """Configure ``scene`` for silhouette renders of ``objects`` only (``holdouts`` hide them where in
    front: Eevee holdouts, or black in Workbench); restore everything after."""
    if engine not in ENGINES:
        raise ClothFitError(f"render engine {engine!r} unknown (one of {', '.join(ENGINES)})")
    saved = []
    hidden = []
    keep = {o.name for o in objects} | {o.name for o in holdouts}
    try:
        r = scene.render
        if engine == "EEVEE":
            _set(saved, r, "engine", _eevee_engine())
            ev = scene.eevee
            _set(saved, ev, "taa_render_samples", 1)
            for attr in (
                "use_gtao",
                "use_bloom",
                "use_ssr",
                "use_motion_blur",
                "use_shadows",
                "use_volumetric_shadows",
                "use_raytracing",
            ):
                if hasattr(ev, attr):
                    _set(saved, ev, attr, False)
            _set(saved, r, "filter_size", 0.0)
            if hasattr(r, "use_motion_blur"):
                _set(saved, r, "use_motion_blur", False)
            for o in holdouts:
                _set(saved, o, "is_holdout", True)
            for o in objects:
                if o.is_holdout:
                    _set(saved, o, "is_holdout", False)
        else:
            _set(saved, r, "engine", "BLENDER_WORKBENCH")
        sh = scene.display.shading
        _set(saved, sh, "light", "FLAT")
        if engine == "WORKBENCH" and holdouts:
            _set(saved, sh, "color_type", "OBJECT")
            for o in objects:
                _set(saved, o, "color", (1.0, 1.0, 1.0, 1.0))
            for o in holdouts:
                _set(saved, o, "color", (0.0, 0.0, 0.0, 1.0))
        else:
            _set(saved, sh, "color_type", "SINGLE")
        _set(saved, sh, "single_color", (1.0, 1.0, 1.0))
        for attr in (
            "show_shadows",
            "show_cavity",
            "show_object_outline",
            "show_specular_highlight",
            "show_xray",
            "use_dof",
            "show_backface_culling",
        ):
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
            if o.name not in keep and o.type in RENDERABLE and not o.hide_render:
                o.hide_render = True
                hidden.append(o)
        for o in list(objects) + list(holdouts):
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


def _read_rgba(path, shape=None):
    import cv2

    img = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    if img is None or img.ndim != 3 or img.shape[2] != 4:
        raise ClothFitError(f"render {path}: expected an RGBA PNG, got {None if img is None else img.shape}")
    if shape is not None and img.shape[:2] != tuple(shape):
        raise ClothFitError(f"render {path}: {img.shape[0]}x{img.shape[1]} but {shape[0]}x{shape[1]} expected")
    return img


def read_alpha_mask(path, shape=None):
    return _read_rgba(path, shape)[..., 3] > 127


def read_object_colour_masks(path, shape=None):
    """Workbench object-colour render: (white = cloth, black = occluder) among the opaque pixels."""
    img = _read_rgba(path, shape)
    opaque = img[..., 3] > 127
    white = img[..., 2] > 127  # BGR(A): red channel
    return opaque & white, opaque & ~white


def render_masks(scene, cloth_obj, camera_objs, tmpdir=None, engine="WORKBENCH", occluders=None):
    """Bool (H, W) silhouettes of ``cloth_obj`` from each camera, at the scene's current frame.

    With ``occluders`` (a list, e.g. ``occluder_objects(scene)``) the result is a list of ``(mask,
    ignore)``: the visible cloth and the visible occluders (the module text says how per engine)."""
    from .scene import render_size

    W, H = render_size(scene)
    own = tmpdir is None
    tmpdir = tmpdir or tempfile.mkdtemp(prefix="clothfit_render_")
    out = []
    occ = list(occluders or [])

    def shoot(i, tag):
        p = os.path.join(tmpdir, f"{tag}_{i:03d}.png")
        render_to_file(scene, camera_objs[i], p)
        return p

    def done(p):
        if own:
            os.remove(p)

    try:
        if occluders is None or (engine == "WORKBENCH" and not occ):
            with silhouette_render(scene, [cloth_obj], engine):
                for i in range(len(camera_objs)):
                    p = shoot(i, "sil")
                    m = read_alpha_mask(p, (H, W))
                    out.append(m if occluders is None else (m, np.zeros_like(m)))
                    done(p)
        elif engine == "WORKBENCH":
            with silhouette_render(scene, [cloth_obj], engine, holdouts=occ):
                for i in range(len(camera_objs)):
                    p = shoot(i, "sil")
                    out.append(read_object_colour_masks(p, (H, W)))
                    done(p)
        else:
            with silhouette_render(scene, [cloth_obj], engine, holdouts=occ):
                for i in range(len(camera_objs)):
                    p = shoot(i, "sil")
                    out.append(read_alpha_mask(p, (H, W)))
                    done(p)
            if occluders is not None:
                ign = []
                if occ:
                    with silhouette_render(scene, occ, engine, holdouts=[cloth_obj]):
                        for i in range(len(camera_objs)):
                            p = shoot(i, "occ")
                            ign.append(read_alpha_mask(p, (H, W)))
                            done(p)
                else:
                    ign = [np.zeros_like(m) for m in out]
                out = list(zip(out, ign))
    finally:
        if own:
            try:
                os.rmdir(tmpdir)
            except OSError:
                pass
    return out


def render_mask(scene, cloth_obj, camera_obj, engine="WORKBENCH"):
    return render_masks(scene, cloth_obj, [camera_obj], engine=engine)[0]


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
