"""Core rasteriser vs. Blender's Workbench (or Eevee) render of the same deformed cloth, and their speeds.

    python lab/raster_agreement.py [--rig lab18] [--times 0.05:1.5:0.05] [--engine workbench|eevee] [--json out/agreement.json]
    blender -b --factory-startup --python-exit-code 1 -P lab/raster_agreement.py -- [same options]

Simulates the paper scenario with the ground-truth parameters, bakes it into the Blender cloth,
and for every rig camera and capture time compares Blender's silhouette (Workbench, AA off) with
``core.observation.raster.silhouette`` of the same vertices: XOR pixels / silhouette area. Prints a table per
camera and per time, the overall figures, and the time per silhouette of each (the Blender figure
includes writing and reading the PNG, as a capture render does).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description="Core rasteriser vs. Blender silhouettes")
    ap.add_argument("--rig", default="lab18")
    ap.add_argument("--times", default=None, help="start:stop:step or a comma list (default: the paper's 30 times)")
    ap.add_argument("--per-image", action="store_true", help="print every (camera, time) row")
    ap.add_argument(
        "--engine",
        default="workbench",
        choices=["workbench", "eevee"],
        help="Blender renderer (eevee: one sample, zero pixel filter)",
    )
    ap.add_argument("--json", default=None, help="write all figures to this JSON file")
    return ap.parse_args(argv)


def main(argv=None):
    if ROOT not in sys.path:
        sys.path.insert(0, ROOT)
    from clothfit.blender.pipeline import script_argv

    a = parse_args(script_argv(argv))
    import bpy
    import clothfit
    import numpy as np
    from clothfit.blender import api, registration
    from clothfit.blender import render as R
    from clothfit.blender import scene as S
    from clothfit.core.observation.raster import silhouette

    if not registration.is_registered():
        clothfit.register()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    p = scene.clothfit
    p.rig_source, p.rig_preset = "PRESET", a.rig
    if a.times:
        p.frame_times = a.times
    api.build_rig(scene)
    cloth = api.build_cloth(scene)
    api.simulate(scene)
    objs = S.rig_objects(scene)
    cams = S.rig_cameras(scene)
    tris = S.grid_from_object(cloth).triangles
    times = api.parse_times(p.frame_times)
    W, H = S.render_size(scene)
    rows = []
    t_blender = t_core = 0.0
    n_blender = n_core = 0
    tmp = tempfile.mkdtemp(prefix="clothfit_agree_")
    engine = a.engine.upper()
    R.render_masks(scene, cloth, objs[:1], tmpdir=tmp, engine=engine)  # warm-up (first render builds shaders)
    for t in times:
        scene.frame_set(S.frame_of_time(scene, t))
        X = S.evaluated_positions(cloth)
        t0 = time.perf_counter()
        masks = R.render_masks(scene, cloth, objs, tmpdir=tmp, engine=engine)
        t_blender += time.perf_counter() - t0
        n_blender += len(objs)
        t0 = time.perf_counter()
        core = [silhouette(c, X, tris) for c in cams]
        t_core += time.perf_counter() - t0
        n_core += len(cams)
        for c, m, k in zip(cams, masks, core):
            area = int(k.sum())
            xor = int(np.count_nonzero(m ^ k))
            rows.append(
                {
                    "camera": c.name,
                    "time": t,
                    "area_px": area,
                    "blender_area_px": int(m.sum()),
                    "xor_px": xor,
                    "xor_pct": 100.0 * xor / max(area, 1),
                }
            )
            if a.per_image:
                print(f"{c.name} t={t:.2f}  area {area:6d}  xor {xor:4d} px  {rows[-1]['xor_pct']:.4f} %")
    shutil.rmtree(tmp, ignore_errors=True)
    pct = np.array([r["xor_pct"] for r in rows])
    xor = np.array([r["xor_px"] for r in rows])
    area = np.array([r["area_px"] for r in rows])
    print(
        f"rig {a.rig}: {len(cams)} cameras x {len(times)} times at {H} x {W} (H x W), "
        f"Blender {bpy.app.version_string} {engine.title()} AA off"
    )
    print("per camera: mean / max XOR % of the silhouette area, mean area px")
    for c in cams:
        sel = [r for r in rows if r["camera"] == c.name]
        v = np.array([r["xor_pct"] for r in sel])
        print(f"  {c.name}: {v.mean():.4f} / {v.max():.4f} %  ({np.mean([r['area_px'] for r in sel]):.0f} px)")
    print("per time: mean / max XOR %")
    for t in times:
        v = np.array([r["xor_pct"] for r in rows if r["time"] == t])
        print(f"  t={t:.2f}: {v.mean():.4f} / {v.max():.4f} %")
    summary = {
        "images": len(rows),
        "width": W,
        "height": H,
        "rig": a.rig,
        "blender": bpy.app.version_string,
        "engine": engine,
        "xor_pct_mean": float(pct.mean()),
        "xor_pct_max": float(pct.max()),
        "xor_px_total": int(xor.sum()),
        "area_px_total": int(area.sum()),
        "xor_pct_overall": float(100.0 * xor.sum() / area.sum()),
        "images_with_zero_xor": int((xor == 0).sum()),
        "xor_px_max": int(xor.max()),
        "blender_ms_per_silhouette": 1000 * t_blender / n_blender,
        "core_ms_per_silhouette": 1000 * t_core / n_core,
    }
    print(
        f"overall: XOR {summary['xor_px_total']} px of {summary['area_px_total']} px = "
        f"{summary['xor_pct_overall']:.4f} %; per image mean {summary['xor_pct_mean']:.4f} %, "
        f"max {summary['xor_pct_max']:.4f} % (max {summary['xor_px_max']} px); "
        f"{summary['images_with_zero_xor']}/{len(rows)} images identical"
    )
    print(
        f"time per silhouette: Blender {summary['blender_ms_per_silhouette']:.1f} ms (render + PNG write/read), "
        f"core {summary['core_ms_per_silhouette']:.2f} ms "
        f"({summary['blender_ms_per_silhouette'] / summary['core_ms_per_silhouette']:.0f}x)"
    )
    if a.json:
        os.makedirs(os.path.dirname(os.path.abspath(a.json)), exist_ok=True)
        with open(a.json, "w") as f:
            json.dump({"summary": summary, "rows": rows}, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
