# SPDX-License-Identifier: GPL-3.0-or-later
"""The whole Blender pipeline in one call, for headless use (``blender -b``, the ``bpy`` module,
``demo_blend/build_demo.py``, the ``python -m clothfit`` CLI).

Steps, each one ``clothfit`` operator: build the rig, build the cloth, simulate + bake,
render the silhouettes with Blender into ``<out>/capture``, load the capture, fit, apply the fit,
overlays; then save the .blend (paths stored relative to it).
"""

from __future__ import annotations

import argparse
import os
import sys
import time

STEPS_CAPTURE = ("build_rig", "build_cloth", "simulate", "render_silhouettes", "load_capture")


def script_argv(argv=None):
    """Arguments after ``--`` when present (Blender's convention), otherwise ``sys.argv[1:]``."""
    if argv is not None:
        return list(argv)
    return sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else sys.argv[1:]


def add_arguments(ap: argparse.ArgumentParser, blend_default=None):
    ap.add_argument(
        "--out",
        default=os.path.join("out", "demo"),
        help="output directory: capture, result, overlays (default: %(default)s)",
    )
    ap.add_argument(
        "--blend", default=blend_default or "", help="where to save the .blend; '' = do not save (default: %(default)r)"
    )
    ap.add_argument("--rig", default="lab18", help="rig preset (rigs/) or cameras JSON (default: %(default)s)")
    ap.add_argument(
        "--times", default=None, help="capture times [s] as start:stop:step (default: the paper's 0.05:1.5:0.05)"
    )
    ap.add_argument(
        "--noise",
        type=float,
        default=0.05,
        help="fraction of boundary pixels flipped in the rendered silhouettes (default: %(default)s)",
    )
    ap.add_argument("--no-fit", action="store_true", help="skip the fit (and apply)")
    ap.add_argument(
        "--train-cameras",
        type=int,
        default=8,
        help="cameras the fit trains on, chosen by the spread rule (default: %(default)s)",
    )
    ap.add_argument("--budget", type=int, default=1500, help="fit: maximum model evaluations (default: %(default)s)")
    ap.add_argument(
        "--resolution",
        default="120x160",
        choices=["FULL", "240x320", "120x160", "60x80"],
        help="fit resolution H x W [px]; FULL = the rig's (default: %(default)s)",
    )
    ap.add_argument(
        "--optimizer",
        default=None,
        choices=["auto", "spx-mgg", "cma-es", "cma-staged"],
        help="default: the project's default optimiser (core/defaults.py)",
    )
    ap.add_argument("--seed", type=int, default=0, help="random seed of the fit (default: %(default)s)")
    ap.add_argument(
        "--no-blender-model",
        action="store_true",
        help="skip the second fit with Blender's cloth model (and its Cloth modifier)",
    )
    ap.add_argument(
        "--blender-budget", type=int, default=1500, help="Blender-model fit: maximum evaluations (default: %(default)s)"
    )
    ap.add_argument(
        "--engine",
        default="WORKBENCH",
        choices=["WORKBENCH", "EEVEE"],
        help="silhouette renderer (default: %(default)s)",
    )
    ap.add_argument(
        "--post",
        action=argparse.BooleanOptionalAction,
        default=False,
        help="stand a post in front of the cloth (collection 'Occluders': rendered as a holdout, "
        "written as ignore masks)",
    )
    return ap


POST_LOCATION = (0.02, -0.01, 0.05)  # m: through the cloth's area, where the released corner falls
POST_RADIUS, POST_HEIGHT = 0.006, 0.3


def add_post(scene):
    """A thin vertical cylinder in the collection 'Occluders' (a post in front of / through the cloth)."""
    import bpy

    from .render import OCCLUDERS

    coll = bpy.data.collections.get(OCCLUDERS) or bpy.data.collections.new(OCCLUDERS)
    if coll.name not in {c.name for c in scene.collection.children_recursive}:
        scene.collection.children.link(coll)
    me = bpy.data.meshes.new("Post")
    import bmesh

    bm = bmesh.new()
    bmesh.ops.create_cone(bm, cap_ends=True, segments=24, radius1=POST_RADIUS, radius2=POST_RADIUS, depth=POST_HEIGHT)
    bm.to_mesh(me)
    bm.free()
    post = bpy.data.objects.new("Post", me)
    post.location = POST_LOCATION
    coll.objects.link(post)
    return post


def ensure_wheels():
    """Make the bundled packages importable when running from a checkout under a Blender binary.

    Blender's Python has no OpenCV or numba; an installed extension gets them from the
    wheels its manifest lists. From a checkout (``blender -b -P demo_blend/build_demo.py``) the
    same wheels in ``wheels/`` (downloaded by ``tools/build_extension.py``) are unpacked once into
    ``out/.blender_site/<wheel>`` and put on sys.path, for each package that is not importable.
    Returns the directories added. Raises SystemExit if OpenCV is missing and no wheel is there.
    """
    import glob
    import importlib.util
    import platform
    import zipfile

    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    arch = platform.machine().lower()
    added = []
    for whl in sorted(glob.glob(os.path.join(root, "wheels", "*.whl"))):
        tags = os.path.basename(whl)[:-4].split("-")[-1]
        ok = (
            tags == "any"
            or (sys.platform.startswith("linux") and "linux" in tags and arch in tags)
            or (sys.platform == "darwin" and "macosx" in tags and arch in tags)
            or (sys.platform == "win32" and "win_amd64" in tags)
        )
        if not ok:
            continue
        with zipfile.ZipFile(whl) as z:
            tops = sorted({n.split("/")[0] for n in z.namelist() if n.count("/") == 1 and n.endswith("/__init__.py")})
            if not tops or all(_importable(t) for t in tops):
                continue
            site = os.path.join(root, "out", ".blender_site", os.path.basename(whl)[:-4])
            if not all(os.path.isdir(os.path.join(site, t)) for t in tops):
                z.extractall(site)
        sys.path.insert(0, site)
        added.append(site)
    importlib.invalidate_caches()
    if not _importable("cv2"):
        raise SystemExit(
            "OpenCV (cv2) is not importable and no matching wheel is in wheels/: run "
            "`python tools/build_extension.py` once (it downloads the wheels), or install the extension"
        )
    return added


def _importable(name):
    import importlib.util

    try:
        return importlib.util.find_spec(name) is not None
    except ImportError:
        return False


def ensure_registered():
    from .. import register
    from . import registration

    if not registration.is_registered():
        register()


def run_op(op, **kw):
    import bpy

    from ..core.errors import ClothFitError

    t = time.time()
    try:
        r = getattr(bpy.ops.clothfit, op)(**kw)
    except RuntimeError as e:  # the operator reported an error (bad input): pass its message on
        msg = str(e)
        if msg.startswith("Error: ") and "Traceback" not in msg:
            raise ClothFitError(f"clothfit.{op}: {msg[len('Error: ') :].strip()}") from None
        raise
    print(f"  clothfit.{op}: {r} in {time.time() - t:.1f} s", flush=True)
    if r != {"FINISHED"}:
        raise SystemExit(f"clothfit.{op} failed: {r}")


def run(args, after_capture=None, after_overlays=None):
    """Run the pipeline for parsed ``args`` (see ``add_arguments``) on a fresh empty scene.

    ``after_capture(scene)`` / ``after_overlays(scene)`` are optional hooks. Returns a summary dict.
    """
    import bpy

    ensure_wheels()
    ensure_registered()
    from . import api

    out = os.path.abspath(args.out)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    p = scene.clothfit
    p.rig_source, p.rig_preset = "PRESET", args.rig
    if args.times:
        p.frame_times = args.times
    p.noise = args.noise
    p.capture_dir = os.path.join(out, "capture")
    p.train_cameras = args.train_cameras
    p.max_evaluations = args.budget
    p.fit_resolution = args.resolution
    if args.optimizer:
        p.optimizer = args.optimizer
    p.seed = args.seed
    p.render_engine = getattr(args, "engine", "WORKBENCH")
    if getattr(args, "post", False):
        add_post(scene)
    print(f"Silhouette Cloth Fit (Blender pipeline) -> {out}", flush=True)
    for op in STEPS_CAPTURE:
        run_op(op)
    summary = {"capture": api.capture_dir(scene), "true_params": api.params_from_scene(scene).as_dict()}
    if after_capture:
        after_capture(scene)
    if not args.no_fit:
        run_op("fit")
        run_op("apply_fit")
        res = api.load_result(scene)
        summary.update(
            fitted_params=res["params"], identifiable_error_pct=res.get("identifiable_error_pct"), result=p.result_path
        )
        print("  true   ", {k: f"{v:.4g}" for k, v in summary["true_params"].items()})
        print("  fitted ", {k: f"{v:.4g}" for k, v in res["params"].items()})
        if res.get("identifiable_error_pct"):
            print("  identifiable error %", {k: f"{v:.2f}" for k, v in res["identifiable_error_pct"].items()})
    run_op("overlays")
    summary["overlay_mean_E_sil_pct"] = p.overlay_error
    print(f"  overlays: mean E_sil {p.overlay_error:.3f} % ({p.overlay_dir})")
    if after_overlays:
        after_overlays(scene)
    if not args.no_fit and not getattr(args, "no_blender_model", False):
        summary["blender_model"] = fit_blender_model(scene, args.blender_budget)
    times = api.parse_times(p.frame_times)
    p["view_frame"] = min(14, len(times) - 1)
    scene.frame_set(api.S.frame_of_time(scene, times[p.view_frame]))
    if args.blend:
        summary["blend"] = save_blend(scene, args.blend)
    return summary


def fit_blender_model(scene, budget):
    """The same capture fitted with Blender's own cloth model; Apply Blender Cloth builds a cloth
    with a Cloth modifier beside the paper model's; overlays of that fit under
    ``<capture>/overlays_blender_model``."""
    from ..core.fitting.evaluate import evaluate
    from ..core.observation.capture import load_capture
    from ..core.observation.overlay import capture_overlays
    from . import api

    p = scene.clothfit
    p.fit_model = "BLENDER"
    p.max_evaluations = budget
    run_op("fit")
    run_op("apply_blender_cloth")
    res = api.load_result(scene)
    cap = load_capture(api.capture_dir(scene))
    ev = evaluate(cap, res)
    out_dir = os.path.join(cap.root, "overlays_blender_model")
    paths = capture_overlays(cap, res, out_dir, times=[float(t) for t in cap.frame_times[::3]])
    bc = res["blender_cloth"]
    print("  Blender cloth fitted:", {k: (f"{v:.4g}" if isinstance(v, float) else v) for k, v in bc.items()})
    print(
        f"  Blender cloth model: mean E_sil {ev['silhouette_error_pct']:.3f} % over every camera and frame, "
        f"shape error {ev.get('shape_error_mm', float('nan')):.3f} mm; overlays {out_dir}"
    )
    return {
        "blender_cloth": bc,
        "blender_scene": res["blender_scene"],
        "result": p.result_path,
        "E_sil_pct": ev["silhouette_error_pct"],
        "shape_error_mm": ev.get("shape_error_mm"),
        "overlays": paths[-1],
    }


def save_blend(scene, path):
    """Save with the capture/result/overlay paths relative to the .blend (portable checkout)."""
    import bpy

    blend = os.path.abspath(path)
    os.makedirs(os.path.dirname(blend), exist_ok=True)
    p = scene.clothfit

    def rel(x):
        return bpy.path.relpath(x, start=os.path.dirname(blend)) if x and not x.startswith("//") else x

    p.capture_dir, p.result_path, p.overlay_dir = rel(p.capture_dir), rel(p.result_path), rel(p.overlay_dir)
    bpy.ops.wm.save_as_mainfile(filepath=blend, compress=True, relative_remap=True)
    print(f"saved {blend} ({os.path.getsize(blend) / 1e3:.0f} kB)")
    return blend


def main(argv=None):
    """``python -m clothfit``-style entry: parse ``argv`` and run the pipeline. Exit code 2 on bad input."""
    from ..core.errors import ClothFitError

    ap = add_arguments(argparse.ArgumentParser(description="Silhouette Cloth Fit: the Blender pipeline"))
    args = ap.parse_args(script_argv(argv))
    try:
        run(args)
    except ClothFitError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0
