"""Calibration of the noise-floor estimate (``addon/core/observation/floor.py``) against true floors.

The true floor of an image is the ``E_sil`` of the true shape, rasterised at the fit resolution, against
the observed silhouette as the fitter sees it (resampled when the fit resolution differs). Cases:

* synthetic captures (``synth_capture``, the function behind ``python -m clothfit synth --noise``) of both
  models (the paper's sheet and Blender's cloth), 18 ``lab18`` cameras x 10 frames (t = 0.15 .. 1.5 s),
  noise 0, 1, 2, 5, 10 % of the boundary pixels, at 60x80 .. 480x640, fitted at their own resolution;
* the same 480 x 640 captures (paper model) fitted at 240x320, 120x160, 60x80 (the paper's Table 2);
* photoreal footage (``tools/render_footage.py render``, extracted by ``python -m clothfit extract``)
  against its true masks (``--footage`` and ``--capture``; skipped when not given);
* where the residual lies (``residual_profile``: rim share, balance, outline shift in px) for the
  perfect model on that footage, and for a timing error (the true shape one frame, 0.15 s, late) on a
  synthetic capture.

Per case: the capture's true floor (mean over images), the estimate (``capture_floor``: mean over
images), their ratio, and the per-image ratios (median, 10th and 90th percentiles).

    python tools/floor_calibration.py --json out/floor_cal/calibration.json [--footage DIR --capture DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)

from clothfit.core.observation.capture import load_capture  # noqa: E402
from clothfit.core.observation.floor import capture_floor, resample_silhouette, residual_profile  # noqa: E402
from clothfit.core.observation.raster import silhouette  # noqa: E402
from clothfit.core.observation.silhouette_files import read_silhouette  # noqa: E402
from clothfit.core.observation.synth import synth_capture  # noqa: E402
from clothfit.core.physics.scenario import paper_scenario  # noqa: E402

RESOLUTIONS = [(60, 80), (120, 160), (240, 320), (480, 640)]
NOISES = [0.0, 0.01, 0.02, 0.05, 0.10]
FIT_RESOLUTIONS = [(240, 320), (120, 160), (60, 80)]
RESAMPLED_NOISES = [0.0, 0.05, 0.10]
TIMES = [round(0.15 * i, 2) for i in range(1, 11)]
REUSE = False  # --reuse: keep synthetic captures a previous run wrote
RESOLUTIONS_RUN = RESOLUTIONS  # the resolutions this run made (their paper captures serve the other cases)


def make_capture(root, noise, resolution, model="paper"):
    """The synthetic capture of a case (written again unless --reuse and it exists)."""
    if REUSE and os.path.isfile(os.path.join(root, "capture.json")):
        return load_capture(root)
    if os.path.isdir(root):
        shutil.rmtree(root)
    synth_capture(
        root,
        None,
        noise=noise,
        resolution=resolution,
        scenario=paper_scenario(frame_times=TIMES),
        model=None if model == "paper" else "blender",
    )
    return load_capture(root)


def true_floors(cap, positions, fit_res=None):
    """(C, F) E_sil of the true shapes (``positions`` (F, V, 3)) against the capture's silhouettes at ``fit_res``."""
    tris = cap.scenario.grid.triangles
    out = np.zeros((len(cap.cameras), cap.n_frames))
    for c, cam in enumerate(cap.cameras):
        h, w = (cam.height, cam.width) if fit_res is None else fit_res
        for f in range(cap.n_frames):
            o = resample_silhouette(cap.load_silhouette(c, f), h, w)
            t = silhouette(cam, positions[f], tris, h, w)
            out[c, f] = np.count_nonzero(o ^ t) / np.count_nonzero(o)
    return out


def summarise(name, ident, true, est, extra=None):
    """A row of the table; ``ident`` a short key for the docs' tags (``paper_480x640_n5``)."""
    true, est = np.asarray(true, float), np.asarray(est, float)
    tm, em = float(true.mean()), float(est.mean())
    pos = true > 0
    r = est[pos] / true[pos]
    row = {
        "case": name,
        "id": ident,
        "n_images": int(true.size),
        "true_floor_pct": 100 * tm,
        "estimate_pct": 100 * em,
        "ratio": em / tm if tm > 0 else None,
        "image_ratio_median": float(np.median(r)) if r.size else None,
        "image_ratio_p10": float(np.percentile(r, 10)) if r.size else None,
        "image_ratio_p90": float(np.percentile(r, 90)) if r.size else None,
    }
    row.update(extra or {})
    return row


def synth_cases(out, models, resolutions, noises, log):
    rows = []
    for model in models:
        for res in resolutions:
            for noise in noises:
                root = os.path.join(out, f"{model}_{res[0]}x{res[1]}_n{noise:g}")
                cap = make_capture(root, noise, res, model)
                X = np.load(os.path.join(root, "shapes.npz"))["positions"]
                t0 = time.process_time()
                cf = capture_floor(cap)
                secs = time.process_time() - t0
                row = summarise(
                    f"{model} {res[0]}x{res[1]} noise {100 * noise:g} %",
                    f"{model}_{res[0]}x{res[1]}_n{100 * noise:g}",
                    true_floors(cap, X),
                    cf.per_image(),
                    {
                        "model": model,
                        "resolution": list(res),
                        "fit_resolution": list(res),
                        "noise": noise,
                        "rate": cf.rate,
                        "basis": cf.basis,
                        "rim_pct": 100 * cf.to_dict(False)["rim"],
                        "cpu_seconds_per_image": secs / cf.per_image().size,
                    },
                )
                log(row)
                rows.append(row)
    return rows


def resampled_cases(out, fit_resolutions, noises, log):
    rows = []
    for noise in noises:
        root = os.path.join(out, f"paper_480x640_n{noise:g}")
        cap = (
            load_capture(root)
            if os.path.isfile(os.path.join(root, "capture.json")) and (480, 640) in RESOLUTIONS_RUN
            else make_capture(root, noise, (480, 640))
        )
        X = np.load(os.path.join(root, "shapes.npz"))["positions"]
        for fr in fit_resolutions:
            cf = capture_floor(cap, resolution=fr)
            d = cf.to_dict(False)
            row = summarise(
                f"paper 480x640 noise {100 * noise:g} % fitted at {fr[0]}x{fr[1]}",
                f"paper_480x640_n{100 * noise:g}_at_{fr[0]}x{fr[1]}",
                true_floors(cap, X, fr),
                cf.per_image(),
                {
                    "model": "paper",
                    "resolution": [480, 640],
                    "fit_resolution": list(fr),
                    "noise": noise,
                    "resampling_pct": 100 * d["resampling"],
                    "noise_part_pct": 100 * d["noise"],
                },
            )
            log(row)
            rows.append(row)
    return rows


def footage_case(footage, capture_dir, log):
    cap = load_capture(capture_dir)
    cf = capture_floor(cap)
    true = np.zeros((len(cap.cameras), cap.n_frames))
    prof = []
    for c, cam in enumerate(cap.cameras):
        for f in range(cap.n_frames):
            o = cap.load_silhouette(c, f)
            t = read_silhouette(os.path.join(footage, "truth", "masks", cam.name, f"{f:03d}.png"))
            true[c, f] = np.count_nonzero(o ^ t) / np.count_nonzero(o)
            prof.append(residual_profile(o, t))
    d = cf.to_dict(False)
    row = summarise(
        "photoreal footage, extracted",
        "footage",
        true,
        cf.per_image(),
        {
            "resolution": [cap.cameras[0].height, cap.cameras[0].width],
            "cameras": cap.camera_names,
            "rim_pct": 100 * d["rim"],
            "rate": cf.rate,
            "perfect_model": {
                k: float(np.nanmedian([p[k] for p in prof])) for k in ("rim_share", "balance", "bias_px")
            },
        },
    )
    log(row)
    return row


def timing_error_case(out, log):
    """The true shape one frame (0.15 s) late against a 5 % noise capture: where its residual lies, per frame."""
    root = os.path.join(out, "paper_240x320_n0.05")
    cap = (
        load_capture(root)
        if os.path.isfile(os.path.join(root, "capture.json")) and (240, 320) in RESOLUTIONS_RUN
        else make_capture(root, 0.05, (240, 320))
    )
    X = np.load(os.path.join(root, "shapes.npz"))["positions"]
    tris = cap.scenario.grid.triangles
    rows = []
    for f in range(cap.n_frames - 1):
        prof = [
            residual_profile(cap.load_silhouette(c, f + 1), silhouette(cam, X[f], tris))
            for c, cam in enumerate(cap.cameras)
        ]
        rows.append(
            {
                "time": float(cap.frame_times[f + 1]),
                **{k: float(np.nanmedian([p[k] for p in prof])) for k in ("e_sil", "rim_share", "balance", "bias_px")},
            }
        )
    row = {"case": "paper 240x320 noise 5 %: the true shape 0.15 s late (medians over cameras)", "frames": rows}
    log(row)
    return row


def table(rows):
    lines = [
        "| case | images | true floor [%] | estimate [%] | ratio | per-image ratio median (p10-p90) |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        ratio = "-" if r["ratio"] is None else f"{r['ratio']:.2f}"
        im = (
            "-"
            if r["image_ratio_median"] is None
            else f"{r['image_ratio_median']:.2f} ({r['image_ratio_p10']:.2f}-{r['image_ratio_p90']:.2f})"
        )
        lines.append(
            f"| {r['case']} | {r['n_images']} | {r['true_floor_pct']:.3f} | {r['estimate_pct']:.3f} | {ratio} | {im} |"
        )
    return "\n".join(lines)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--out", default="out/floor_cal", help="folder for the synthetic captures (default: %(default)s)")
    p.add_argument("--json", required=True, help="write the calibration table here")
    p.add_argument("--footage", help="photoreal footage folder (tools/render_footage.py render --out)")
    p.add_argument("--capture", help="its extracted capture (python -m clothfit extract FOOTAGE --out)")
    p.add_argument("--quick", action="store_true", help="paper model at 120x160 and 480x640 only (a smoke run)")
    p.add_argument("--reuse", action="store_true", help="keep the synthetic captures a previous run wrote to --out")
    a = p.parse_args(argv)
    global REUSE, RESOLUTIONS_RUN
    REUSE = a.reuse
    t0 = time.time()

    def log(row):
        print(
            json.dumps(
                {
                    k: (round(v, 4) if isinstance(v, float) else v)
                    for k, v in row.items()
                    if not isinstance(v, list) or k in ("resolution", "fit_resolution")
                }
            ),
            file=sys.stderr,
            flush=True,
        )

    models = ["paper"] if a.quick else ["paper", "blender"]
    res = [(120, 160), (480, 640)] if a.quick else RESOLUTIONS
    RESOLUTIONS_RUN = res
    out = {
        "synthetic": synth_cases(a.out, models, res, NOISES, log),
        "resampled": resampled_cases(a.out, FIT_RESOLUTIONS, RESAMPLED_NOISES, log),
        "timing_error": timing_error_case(a.out, log),
    }
    if a.footage and a.capture:
        out["footage"] = footage_case(a.footage, a.capture, log)
    rows = out["synthetic"] + out["resampled"] + ([out["footage"]] if "footage" in out else [])
    out["table"] = table(rows)
    out["seconds"] = time.time() - t0
    os.makedirs(os.path.dirname(os.path.abspath(a.json)), exist_ok=True)
    with open(a.json, "w") as f:
        json.dump(out, f, indent=1)
    print(out["table"])


if __name__ == "__main__":
    main()
