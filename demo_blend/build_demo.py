"""Build the demo scene: rig, cloth, simulate + bake, Blender-rendered silhouettes, fit, overlays.

Runs the same under Blender and under Python with the ``bpy`` module::

    blender -b --factory-startup --python-exit-code 1 -P demo_blend/build_demo.py -- --out out/demo
    python demo_blend/build_demo.py --out out/demo

Writes the capture to ``<out>/capture`` (silhouettes rendered by Blender's Workbench, 5 % boundary
noise; a post in the collection 'Occluders' stands in front of the cloth and is written as ignore
masks, ``--no-post`` removes it), the fit result and overlays there, and saves ``demo_blend/demo.blend`` (``--blend``).
``--images DIR`` also writes the walkthrough pictures (docs/img): a Blender render of the rig and
the cloth, a sheet of rendered silhouettes and the overlay contact sheet.
"""
from __future__ import annotations

import argparse
import os
import shutil
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)


def main(argv=None):
    if ROOT not in sys.path:
        sys.path.insert(0, ROOT)
    from addon.blender import pipeline
    ap = pipeline.add_arguments(argparse.ArgumentParser(description="Build the Silhouette Cloth Fit demo scene"),
                                blend_default=os.path.join(HERE, "demo.blend"))
    ap.add_argument("--images", default=None, help="also write the walkthrough images into this directory")
    ap.set_defaults(post=True)     # the demo has a post in front of the cloth (an occluder: ignore masks)
    a = ap.parse_args(pipeline.script_argv(argv))
    images = os.path.abspath(a.images) if a.images else None
    pipeline.run(a, after_capture=(lambda scene: first_guess_overlays(scene, images)) if images else None,
                 after_overlays=(lambda scene: write_walkthrough_images(scene, images)) if images else None)
    return 0


# ======================================================= walkthrough images

def _camera_proxies(scene, cam_objs, size=0.03):
    """Small pyramids where the rig's cameras are (cameras themselves do not render)."""
    import bpy
    import numpy as np
    coll = bpy.data.collections.new("ClothFit Docs")
    scene.collection.children.link(coll)
    verts = np.array([[0, 0, 0], [-1, -0.75, -1.6], [1, -0.75, -1.6], [1, 0.75, -1.6], [-1, 0.75, -1.6]]) * size
    faces = [(0, 1, 2), (0, 2, 3), (0, 3, 4), (0, 4, 1), (1, 4, 3, 2)]
    me = bpy.data.meshes.new("camera proxy")
    me.from_pydata(verts.tolist(), [], faces)
    objs = []
    for c in cam_objs:
        o = bpy.data.objects.new(f"proxy {c.name}", me)
        o.matrix_world = c.matrix_world.copy()
        o.color = (0.9, 0.5, 0.1, 1.0)
        coll.objects.link(o)
        objs.append(o)
    return coll, objs


FIRST_GUESS = {"k": 4.0, "l": 0.0075, "d": 4.0e-5}


def first_guess_overlays(scene, img_dir, t_show=0.5):
    """docs/img: overlays of a poor first guess (before fitting), to show the colours."""

    from addon.blender import api
    from addon.core.observation.capture import load_capture
    os.makedirs(img_dir, exist_ok=True)
    p = scene.clothfit
    saved = api.params_from_scene(scene).as_dict()
    try:
        api.params_to_scene(scene, dict(saved, **FIRST_GUESS))
        cap = load_capture(api.capture_dir(scene))
        fi = cap.frame_index(t_show) if abs(cap.frame_times - t_show).min() < 1e-6 else cap.n_frames // 2
        s = api.make_overlays(scene, source="CORE", frame_indices=[fi])
        dst = os.path.join(img_dir, "blender_overlays_first_guess.png")
        shutil.copyfile(s["contact_sheet"], dst)
        _shrink(dst, 960)
        print(f"  image {dst}: first guess {FIRST_GUESS}, mean E_sil {s['mean_E_sil_pct']:.2f} %")
    finally:
        api.params_to_scene(scene, saved)
        p.overlay_dir = ""


def _shrink(path, width):
    import cv2
    img = cv2.imread(path)
    if img.shape[1] > width:
        img = cv2.resize(img, (width, int(img.shape[0] * width / img.shape[1])), interpolation=cv2.INTER_AREA)
    cv2.imwrite(path, img, [cv2.IMWRITE_PNG_COMPRESSION, 9])


def write_walkthrough_images(scene, img_dir):
    """docs/img: rig + cloth rendered by Blender, rendered silhouettes, the overlay sheet."""

    import bpy
    import cv2
    import numpy as np
    from addon.blender import api
    from addon.blender import render as R
    from addon.core.observation.capture import load_capture
    from addon.core.observation.overlay import contact_sheet, label
    os.makedirs(img_dir, exist_ok=True)
    p = scene.clothfit
    times = api.parse_times(p.frame_times)
    t_show = times[min(9, len(times) - 1)]
    scene.frame_set(api.S.frame_of_time(scene, t_show))
    # 1. the rig and the cloth, from an overview camera
    cams = api.S.rig_objects(scene)
    coll, proxies = _camera_proxies(scene, cams)
    cloth = api.cloth_object(scene)
    cloth.color = (0.3, 0.6, 1.0, 1.0)
    data = bpy.data.cameras.new("overview")
    data.lens = 30
    over = bpy.data.objects.new("overview", data)
    scene.collection.objects.link(over)
    from addon.core.observation.camera import Camera, look_at
    Rm, t = look_at((0.95, -0.75, 0.6), (0.0, 0.0, 0.08))
    K = np.array([[620.0, 0, 399.5], [0, 620.0, 299.5], [0, 0, 1]])
    saved = (scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage)
    api.S.camera_to_blender(Camera(K, Rm, t, 800, 600, "overview"), over, scene)
    sh = scene.display.shading
    old = (sh.light, sh.color_type)
    sh.light, sh.color_type = "STUDIO", "OBJECT"
    world = scene.world or bpy.data.worlds.new("ClothFit Docs World")
    old_world = scene.world
    scene.world = world
    world.color = (0.32, 0.34, 0.38)
    rig_png = os.path.join(img_dir, "blender_rig.png")
    R.render_view(scene, over, rig_png)
    for o in proxies:
        o.hide_render = True
    close_png = os.path.join(img_dir, ".cloth_close.png")
    R.render_view(scene, cams[0], close_png)  # inset: the cloth through rig camera 0
    sh.light, sh.color_type = old
    scene.world = old_world
    big = cv2.imread(rig_png)
    ys, xs = np.nonzero(R.render_mask(scene, cloth, cams[0]))
    half = int(0.65 * max(xs.max() - xs.min(), ys.max() - ys.min())) + 4
    cy, cx = (ys.max() + ys.min()) // 2, (xs.max() + xs.min()) // 2
    close = cv2.copyMakeBorder(cv2.imread(close_png), half, half, half, half, cv2.BORDER_REPLICATE)
    inset = close[cy:cy + 2 * half, cx:cx + 2 * half]
    inset = cv2.resize(inset, (240, 240), interpolation=cv2.INTER_AREA)
    big[12:252, 548:788] = inset
    cv2.rectangle(big, (547, 11), (788, 252), (255, 255, 255), 1)
    cv2.putText(big, f"{cams[0].name}, t = {t_show:.2f} s", (552, 246), cv2.FONT_HERSHEY_SIMPLEX, 0.45,
                (255, 255, 255), 1, cv2.LINE_AA)
    cv2.imwrite(rig_png, big, [cv2.IMWRITE_PNG_COMPRESSION, 9])
    os.remove(close_png)
    for o in proxies:
        bpy.data.objects.remove(o)
    bpy.data.collections.remove(coll)
    bpy.data.objects.remove(over)
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = saved
    # 2. silhouettes rendered by Blender (noisy observations as written), 6 cameras at one time
    cap = load_capture(api.capture_dir(scene))
    fi = cap.frame_index(t_show)
    tiles = []
    for ci in range(0, cap.n_cameras, 3):
        m = cap.load_silhouette(ci, fi)
        rgb = np.repeat(np.where(m, 255, 0).astype(np.uint8)[..., None], 3, axis=2)
        tiles.append(label(rgb, f"{cap.cameras[ci].name} t={t_show:.2f}s"))
    sil_png = os.path.join(img_dir, "blender_silhouettes.png")
    cv2.imwrite(sil_png, contact_sheet(tiles, cols=3, tile_width=240)[..., ::-1])
    # 3. the overlay contact sheet of the last overlays run
    sheet = os.path.join(api.abspath(p.overlay_dir, "overlays"), "contact_sheet.png")
    ov_png = os.path.join(img_dir, "blender_overlays.png")
    shutil.copyfile(sheet, ov_png)
    _shrink(ov_png, 960)
    for f in (rig_png, sil_png, ov_png):
        print(f"  image {f} ({os.path.getsize(f) / 1e3:.0f} kB)")
    return [rig_png, sil_png, ov_png]


if __name__ == "__main__":
    try:
        code = main()
    except Exception as e:  # noqa: BLE001 - a script's exit code must say it failed
        from addon.core.errors import ClothFitError  # noqa: E402
        if isinstance(e, ClothFitError):
            print(f"error: {e}", file=sys.stderr)
            sys.exit(2)
        raise
    sys.exit(code)
