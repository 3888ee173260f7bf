"""Build the demo scene: rig, cloth, simulate + bake, Blender-rendered silhouettes, fit, overlays,
and the pictures that tell the story.

Runs the same under Blender and under Python with the ``bpy`` module::

    blender -b --factory-startup --python-exit-code 1 -P demo_blend/build_demo.py -- --out out/demo
    python demo_blend/build_demo.py --out out/demo

Writes the capture to ``<out>/capture`` (silhouettes rendered by Blender's Workbench, 5 % boundary
noise; a post in the collection 'Occluders' stands in front of the cloth and is written as ignore
masks, ``--no-post`` removes it), the fit result and overlays there, saves ``demo_blend/demo.blend``
(``--blend``), and writes into ``<out>/pictures`` (``--pictures DIR``; ``--no-pictures`` skips them):

* ``fit_on_images.png``: camera images (Blender renders of the true cloth) with the comparison drawn
  on them, the optimiser's first guess against the fitted cloth, a training and two held-out cameras;
* ``error_curve.png``: the best training E_sil against the evaluations spent;
* ``parameters.png``: true, first-guess and fitted parameters;
* ``blender_rig.png``, ``blender_silhouettes.png``, ``blender_overlays_first_guess.png``,
  ``blender_overlays.png``: the rig, the rendered silhouettes and the overlay sheets of the walkthrough;

and every figure of the run to ``<out>/summary.json`` (what ``tools/figures.py record demo`` records
for the docs; ``make docs-images`` copies the pictures to docs/img).
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
SHOW_TIME = 0.45  # s: a test time (not among the training times 0.1, 0.2, ...)
SHOW_CAMERAS = ("cam00", "cam05", "cam14")


def main(argv=None):
    for d in (ROOT, HERE):
        if d not in sys.path:
            sys.path.insert(0, d)
    from clothfit.blender import pipeline

    ap = pipeline.add_arguments(
        argparse.ArgumentParser(description="Build the Silhouette Cloth Fit demo scene"),
        blend_default=os.path.join(HERE, "demo.blend"),
    )
    ap.add_argument("--pictures", default=None, help="where the pictures go (default <out>/pictures)")
    ap.add_argument("--no-pictures", action="store_true", help="skip the pictures")
    ap.set_defaults(post=True)  # the demo has a post in front of the cloth (an occluder: ignore masks)
    a = ap.parse_args(pipeline.script_argv(argv))
    out = os.path.abspath(a.out)
    pics = None if a.no_pictures else os.path.abspath(a.pictures or os.path.join(out, "pictures"))
    print(
        "note: Blender's first render may print 'EGL Error (0x3009)' lines: its headless OpenGL start-up asking "
        "for a newer OpenGL than the driver offers (harmless; docs/demo.md).",
        flush=True,
    )
    t0 = time.perf_counter()
    state = {}
    summary = pipeline.run(
        a,
        after_capture=(lambda scene: capture_pictures(scene, pics, state)) if pics else None,
        after_overlays=(lambda scene: overlay_pictures(scene, pics)) if pics else None,
    )
    if pics and not a.no_fit:
        summary.update(story_pictures(summary, pics, state))
    summary["seconds"] = time.perf_counter() - t0
    write_summary(os.path.join(out, "summary.json"), summary, a)
    return 0


def write_summary(path, summary, a):
    from clothfit.core.jsonio import write_json

    keep = {k: v for k, v in summary.items() if k not in ("capture", "result", "blend")}
    keep["settings"] = {
        "rig": a.rig,
        "train_cameras": a.train_cameras,
        "budget": a.budget,
        "resolution": a.resolution,
        "noise": a.noise,
        "seed": a.seed,
        "post": a.post,
        "blender_budget": a.blender_budget,
    }
    if "blender_model" in keep:
        keep["blender_model"] = {k: v for k, v in keep["blender_model"].items() if k not in ("result", "overlays")}
    write_json(path, keep)
    print(f"summary {path}")


# ======================================================= the story: first guess, fit, error curve, parameters


def shown(scene):
    """(time, camera names) the pictures show: SHOW_TIME and SHOW_CAMERAS on the demo's rig and
    times; otherwise the middle capture time, the first training camera and two held-out ones."""
    from clothfit.blender import api
    from clothfit.core.observation.camera import select_training
    from clothfit.core.observation.capture import load_capture

    cap = load_capture(api.capture_dir(scene))
    times = [float(t) for t in cap.frame_times]
    t = SHOW_TIME if any(abs(x - SHOW_TIME) < 1e-9 for x in times) else times[len(times) // 2]
    names = [c.name for c in cap.cameras]
    if all(n in names for n in SHOW_CAMERAS):
        return t, list(SHOW_CAMERAS)
    train, held = select_training(cap.cameras, min(scene.clothfit.train_cameras, len(names)))
    return t, [names[i] for i in ([train[0]] + held[:2])]


def capture_pictures(scene, pics, state):
    """Right after the capture (the true cloth is baked): camera images of the shown cameras, the rig
    picture and the silhouettes sheet, and the first guess's overlay sheet."""
    from clothfit.blender import api
    from clothfit.blender import render as R

    os.makedirs(pics, exist_ok=True)
    t, names = state["time"], state["cameras"] = shown(scene)
    scene.frame_set(api.S.frame_of_time(scene, t))
    cams = {o.name: o for o in api.S.rig_objects(scene)}
    state["images"] = {}
    with studio_look(scene, api.cloth_object(scene)):
        for name in names:
            path = os.path.join(pics, "camera", f"{name}.png")
            os.makedirs(os.path.dirname(path), exist_ok=True)
            R.render_view(scene, cams[name], path)
            state["images"][name] = path
    write_rig_image(scene, pics, t)
    write_silhouettes_sheet(scene, pics, t)
    state["first_guess_sheet"] = first_guess_overlays(scene, pics, t)


def story_pictures(summary, pics, state):
    """After the fit: first guess vs fit on the camera images, the error curve, the parameter table,
    and the figures they show (returned for summary.json)."""
    import cv2
    import pictures as P
    from clothfit.core.fitting.evaluate import evaluate
    from clothfit.core.jsonio import read_json
    from clothfit.core.observation.camera import select_training
    from clothfit.core.observation.capture import load_capture
    from clothfit.core.physics.paper import identifiable

    cap = load_capture(summary["capture"])
    res = read_json(summary["result"], "fit result")
    truth = dict(summary["true_params"])
    first = P.first_guess_params(cap)
    names = [c.name for c in cap.cameras]
    t_show = state["time"]
    cams = [names.index(n) for n in state["cameras"]]
    train, held = select_training(cap.cameras, len(res["train_cameras"]))
    roles = ["training" if c in train else "held out" for c in cams]
    images = [cv2.imread(state["images"][n])[..., ::-1] for n in state["cameras"]]
    sets = {"first_guess": first, "fitted": res["params"], "truth": truth}
    rows = [("first guess (where the optimiser starts)", first), ("fitted", res)]
    img, errs = P.fit_on_images(cap, images, rows, cams, t_show, roles)
    paths = {"fit_on_images": P.write(os.path.join(pics, "fit_on_images.png"), img)}
    # the figures: training error at the fit's resolution, held-out cameras at the test times (full size)
    test_times = [float(t) for t in cap.frame_times if not any(abs(t - u) < 1e-9 for u in res["train_times"])]
    test_times = test_times or [float(t) for t in cap.frame_times]  # every time trained on: score them all
    fig = {
        "first_guess": first,
        "fitted": res["params"],
        "true": truth,
        "identifiable": {k: identifiable(v) for k, v in sets.items()},
        "identifiable_error_pct": {},
        "train_E_sil_pct": {},
        "heldout_E_sil_pct": {},
        "shape_error_mm": {},
        "shown": {
            "time": t_show,
            "cameras": list(state["cameras"]),
            "roles": roles,
            "E_sil_pct": {"first_guess": errs[rows[0][0]], "fitted": errs[rows[1][0]]},
        },
        "evaluations": res["evaluations"],
        "stop_reason": res["stop_reason"],
        "fit_seconds": res["elapsed_s"],
        "train_cameras": res["train_cameras"],
        "train_times": res["train_times"],
        "fit_resolution": res["resolution"],
        "heldout_cameras": [names[c] for c in held],
        "test_times": test_times,
        "image_size": [cap.cameras[0].height, cap.cameras[0].width],
    }
    for key, p in sets.items():
        k = key
        tr = evaluate(
            cap, p, cameras=res["train_camera_indices"], times=res["train_times"], resolution=res["resolution"]
        )
        ho = evaluate(cap, p, cameras=held, times=test_times)
        fig["train_E_sil_pct"][k] = tr["silhouette_error_pct"]
        fig["heldout_E_sil_pct"][k] = ho["silhouette_error_pct"]
        fig["shape_error_mm"][k] = ho.get("shape_error_mm")
        if key != "truth":
            fig["identifiable_error_pct"][k] = {
                q: 100 * abs(v / fig["identifiable"]["truth"][q] - 1) for q, v in fig["identifiable"][k].items()
            }
    curve = [[0, fig["train_E_sil_pct"]["first_guess"] * res["n_train_images"] / 100]] + res["history"]
    paths["error_curve"] = P.write(
        os.path.join(pics, "error_curve.png"),
        P.error_curve(
            curve,
            res["n_train_images"],
            floor_pct=fig["train_E_sil_pct"]["truth"],
            title=f"training E_sil ({len(res['train_cameras'])} cameras x {len(res['train_times'])} times, "
            f"{res['resolution'][0]} x {res['resolution'][1]})",
        ),
    )
    idt, idf, idg = (fig["identifiable"][k] for k in ("truth", "fitted", "first_guess"))
    ef = fig["identifiable_error_pct"]["fitted"]
    table = [
        [
            "k/m [1/s^2]",
            f"{idt['k_over_m']:,.0f}",
            f"{idg['k_over_m']:,.0f}",
            f"{idf['k_over_m']:,.0f}",
            f"{ef['k_over_m']:.2f} %",
        ],
        [
            "d/m [1/s]",
            f"{idt['d_over_m']:.4g}",
            f"{idg['d_over_m']:.4g}",
            f"{idf['d_over_m']:.5g}",
            f"{ef['d_over_m']:.2f} %",
        ],
        ["l [mm]", f"{1000 * idt['l']:.4f}", f"{1000 * idg['l']:.4f}", f"{1000 * idf['l']:.4f}", f"{ef['l']:.2f} %"],
        [
            "training E_sil",
            f"{fig['train_E_sil_pct']['truth']:.2f} %",
            f"{fig['train_E_sil_pct']['first_guess']:.1f} %",
            f"{fig['train_E_sil_pct']['fitted']:.2f} %",
            "",
        ],
        [
            "held-out E_sil",
            f"{fig['heldout_E_sil_pct']['truth']:.2f} %",
            f"{fig['heldout_E_sil_pct']['first_guess']:.1f} %",
            f"{fig['heldout_E_sil_pct']['fitted']:.2f} %",
            "",
        ],
        [
            "shape error [mm]",
            "0",
            f"{fig['shape_error_mm']['first_guess']:.2f}",
            f"{fig['shape_error_mm']['fitted']:.3f}",
            "",
        ],
    ]
    paths["parameters"] = P.write(
        os.path.join(pics, "parameters.png"),
        P.parameter_table(
            table,
            ["", "truth", "first guess", "fitted", "error"],
            note=f"m fixed at {1e6 * truth['m']:.0f} mg per point (the cloth's weighed mass): silhouettes identify "
            f"k/m, d/m and l; {res['evaluations']} evaluations",
        ),
    )
    fig["pictures"] = picture_hashes(pics)
    if state.get("first_guess_sheet"):
        fig["first_guess_sheet_mean_E_sil_pct"] = state["first_guess_sheet"]
    for v in paths.values():
        print(f"  picture {v}")
    return {"story": fig}


def picture_hashes(pics):
    """sha256 of every picture in ``pics`` (not the camera renders): docs/img copies must match."""
    import hashlib

    out = {}
    for f in sorted(os.listdir(pics)):
        if f.endswith(".png"):
            with open(os.path.join(pics, f), "rb") as fh:
                out[f] = hashlib.sha256(fh.read()).hexdigest()
    return out


class studio_look:
    """Workbench studio light, object colours, a grey world: how the camera images are rendered."""

    def __init__(self, scene, cloth):
        self.scene, self.cloth = scene, cloth

    def __enter__(self):
        import bpy

        sc = self.scene
        sh = sc.display.shading
        self.saved = (sh.light, sh.color_type, sc.world, self.cloth.color[:])
        sh.light, sh.color_type = "STUDIO", "OBJECT"
        world = bpy.data.worlds.get("ClothFit Docs World") or bpy.data.worlds.new("ClothFit Docs World")
        world.color = (0.32, 0.34, 0.38)
        sc.world = world
        self.cloth.color = (0.86, 0.80, 0.68, 1.0)
        return self

    def __exit__(self, *exc):
        sh = self.scene.display.shading
        sh.light, sh.color_type, self.scene.world, self.cloth.color = self.saved
        return False


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


def first_guess_overlays(scene, pics, t_show):
    """Overlays of the first guess (where the optimiser starts) for every camera at ``t_show``, core
    rasteriser: what the fit has to correct. Returns their mean E_sil [%]."""
    import pictures as P
    from clothfit.blender import api
    from clothfit.core.observation.capture import load_capture

    p = scene.clothfit
    saved = api.params_from_scene(scene).as_dict()
    try:
        cap = load_capture(api.capture_dir(scene))
        api.params_to_scene(scene, P.first_guess_params(cap))
        s = api.make_overlays(scene, source="CORE", frame_indices=[cap.frame_index(t_show)])
        dst = os.path.join(pics, "blender_overlays_first_guess.png")
        shutil.copyfile(s["contact_sheet"], dst)
        _shrink(dst, 960)
        print(f"  picture {dst}: first guess, mean E_sil {s['mean_E_sil_pct']:.2f} %")
        return s["mean_E_sil_pct"]
    finally:
        api.params_to_scene(scene, saved)
        p.overlay_dir = ""


def _shrink(path, width):
    import cv2

    img = cv2.imread(path)
    if img.shape[1] > width:
        img = cv2.resize(img, (width, int(img.shape[0] * width / img.shape[1])), interpolation=cv2.INTER_AREA)
    cv2.imwrite(path, img, [cv2.IMWRITE_PNG_COMPRESSION, 9])


def write_rig_image(scene, pics, t_show):
    """The rig and the cloth rendered by Blender from an overview camera (orange pyramids: the rig's
    cameras), inset: the cloth through cam00."""
    import bpy
    import cv2
    import numpy as np
    from clothfit.blender import api
    from clothfit.blender import render as R
    from clothfit.core.observation.camera import Camera, look_at

    cams = api.S.rig_objects(scene)
    coll, proxies = _camera_proxies(scene, cams)
    cloth = api.cloth_object(scene)
    data = bpy.data.cameras.new("overview")
    data.lens = 30
    over = bpy.data.objects.new("overview", data)
    scene.collection.objects.link(over)
    Rm, t = look_at((0.95, -0.75, 0.6), (0.0, 0.0, 0.08))
    K = np.array([[620.0, 0, 399.5], [0, 620.0, 299.5], [0, 0, 1]])
    saved = (scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage)
    api.S.camera_to_blender(Camera(K, Rm, t, 800, 600, "overview"), over, scene)
    rig_png = os.path.join(pics, "blender_rig.png")
    close_png = os.path.join(pics, ".cloth_close.png")
    with studio_look(scene, cloth):
        cloth.color = (0.3, 0.6, 1.0, 1.0)
        R.render_view(scene, over, rig_png)
        for o in proxies:
            o.hide_render = True
        R.render_view(scene, cams[0], close_png)  # inset: the cloth through rig camera 0
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = saved
    big = cv2.imread(rig_png)
    ys, xs = np.nonzero(R.render_mask(scene, cloth, cams[0]))
    half = int(0.65 * max(xs.max() - xs.min(), ys.max() - ys.min())) + 4
    cy, cx = (ys.max() + ys.min()) // 2, (xs.max() + xs.min()) // 2
    close = cv2.copyMakeBorder(cv2.imread(close_png), half, half, half, half, cv2.BORDER_REPLICATE)
    inset = close[cy : cy + 2 * half, cx : cx + 2 * half]
    inset = cv2.resize(inset, (240, 240), interpolation=cv2.INTER_AREA)
    big[12:252, 548:788] = inset
    cv2.rectangle(big, (547, 11), (788, 252), (255, 255, 255), 1)
    cv2.putText(
        big,
        f"{cams[0].name}, t = {t_show:.2f} s",
        (552, 246),
        cv2.FONT_HERSHEY_SIMPLEX,
        0.45,
        (255, 255, 255),
        1,
        cv2.LINE_AA,
    )
    cv2.imwrite(rig_png, big, [cv2.IMWRITE_PNG_COMPRESSION, 9])
    os.remove(close_png)
    for o in proxies:
        bpy.data.objects.remove(o)
    bpy.data.collections.remove(coll)
    bpy.data.objects.remove(over)
    print(f"  picture {rig_png}")
    return rig_png


def write_silhouettes_sheet(scene, pics, t_show):
    """Silhouettes as Render Silhouettes wrote them (noisy observations), 6 cameras at ``t_show``."""
    import cv2
    import numpy as np
    from clothfit.blender import api
    from clothfit.core.observation.capture import load_capture
    from clothfit.core.observation.overlay import contact_sheet, label

    cap = load_capture(api.capture_dir(scene))
    fi = cap.frame_index(t_show)
    tiles = []
    for ci in range(0, cap.n_cameras, 3):
        m = cap.load_silhouette(ci, fi)
        rgb = np.repeat(np.where(m, 255, 0).astype(np.uint8)[..., None], 3, axis=2)
        tiles.append(label(rgb, f"{cap.cameras[ci].name} t={t_show:.2f}s"))
    sil_png = os.path.join(pics, "blender_silhouettes.png")
    cv2.imwrite(sil_png, contact_sheet(tiles, cols=3, tile_width=240)[..., ::-1])
    print(f"  picture {sil_png}")
    return sil_png


def overlay_pictures(scene, pics):
    """The overlay contact sheet after the fit (every camera, Blender-rendered model silhouettes)."""
    from clothfit.blender import api

    sheet = os.path.join(api.abspath(scene.clothfit.overlay_dir, "overlays"), "contact_sheet.png")
    ov_png = os.path.join(pics, "blender_overlays.png")
    shutil.copyfile(sheet, ov_png)
    _shrink(ov_png, 960)
    print(f"  picture {ov_png}")
    return ov_png


if __name__ == "__main__":
    try:
        code = main()
    except Exception as e:
        from clothfit.core.errors import ClothFitError

        if isinstance(e, ClothFitError):
            print(f"error: {e}", file=sys.stderr)
            sys.exit(2)
        raise
    sys.exit(code)
