"""Calibration of the noise-floor estimate (``addon/core/observation/floor.py``) against true floors.

The true floor of an image is the error of the TRUE settings as the fit sees it: the capture's true
settings simulated by the fitter's model, rasterised by the fitter at the fit resolution, against the
observed silhouette as the fitter sees it (resampled when the fit resolution differs): the
``SilhouetteObjective`` of those images at the true row, which is what ``python -m clothfit evaluate
--params`` reports. Cases:

* synthetic captures (``synth_capture``, the function behind ``python -m clothfit synth --noise``) of both
  models (the paper's sheet and Blender's cloth), on two rigs (``lab18``: 18 cameras, ``ring8``: 8),
  10 frames (t = 0.15 .. 1.5 s), noise 0, 1, 2, 5, 10 % of the boundary pixels, at 60x80 .. 480x640,
  fitted at their own resolution;
* the same 480 x 640 ``lab18`` captures (paper model) fitted at 240x320, 120x160, 60x80 (the paper's Table 2);
* photoreal footage (``lab/render_footage.py render``, extracted by ``python -m clothfit extract``)
  against its true masks (``--footage`` and ``--capture``; skipped when not given);
* where the residual lies (``residual_profile``: rim share, balance, outline shift in px) for the
  perfect model on that footage, and for a timing error (the true shape one frame, 0.15 s, late) on a
  synthetic capture.

Per case three estimates (``capture_floor``, mean over images): with a model's silhouettes as the
baseline, as a fit's result states it (the model: the true settings, rasterised by the fitter, standing
for a fit that found them: ``ratio``); with a wrong model's (``ratio_wrong_model``: settings of a wrong
basin, Blender's bending 200x low and compression 1.2x high, the paper's stiffness 0.85x: the floor must
not fall with them); and from the images alone, as the ``floor`` command states it (``ratio_image_only``).
Ratios are the capture's mean estimate over its mean true floor; per image: median and 10th-90th
percentiles of estimate / truth (the model-based estimate).

    python lab/floor_calibration.py --json out/floor_cal/calibration.json [--footage DIR --capture DIR]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)

from clothfit.core.fitting.job import load_observed  # noqa: E402
from clothfit.core.fitting.objective import SilhouetteObjective  # noqa: E402
from clothfit.core.observation.capture import load_capture  # noqa: E402
from clothfit.core.observation.floor import capture_floor, residual_profile  # noqa: E402
from clothfit.core.observation.raster import silhouette  # noqa: E402
from clothfit.core.observation.silhouette_files import read_silhouette  # noqa: E402
from clothfit.core.observation.synth import synth_capture  # noqa: E402
from clothfit.core.physics.models import model_and_row  # noqa: E402
from clothfit.core.physics.scenario import paper_scenario  # noqa: E402

RESOLUTIONS = [(60, 80), (120, 160), (240, 320), (480, 640)]
RIGS = ["lab18", "ring8"]
NOISES = [0.0, 0.01, 0.02, 0.05, 0.10]
FIT_RESOLUTIONS = [(240, 320), (120, 160), (60, 80)]
RESAMPLED_NOISES = [0.0, 0.05, 0.10]
TIMES = [round(0.15 * i, 2) for i in range(1, 11)]
REUSE = False  # --reuse: keep synthetic captures a previous run wrote
RESOLUTIONS_RUN = RESOLUTIONS  # the resolutions this run made (their paper captures serve the other cases)


def make_capture(root, noise, resolution, model="paper", rig="lab18"):
    """The synthetic capture of a case (written again unless --reuse and it exists)."""
    if REUSE and os.path.isfile(os.path.join(root, "capture.json")):
        return load_capture(root)
    if os.path.isdir(root):
        shutil.rmtree(root)
    synth_capture(
        root,
        None,
        rig=rig,
        noise=noise,
        resolution=resolution,
        scenario=paper_scenario(frame_times=TIMES),
        model=None if model == "paper" else "blender",
    )
    return load_capture(root)


def true_settings(cap):
    """The settings a synthetic capture was made with (ClothSettings values or m, k, l, d)."""
    return cap.meta.get("true_blender_cloth") or cap.meta["true_params"]


def wrong_settings(truth):
    """Settings of a wrong basin near the truth's silhouettes: Blender's bending 200x low and compression
    1.2x high (the Quick start's wrong fit), the paper's stiffness 0.85x."""
    if "bending_stiffness" in truth:
        return dict(
            truth,
            bending_stiffness=truth["bending_stiffness"] / 200,
            compression_stiffness=truth["compression_stiffness"] * 1.2,
        )
    return dict(truth, k=truth["k"] * 0.85)


def fit_view(cap, fit_res=None):
    """The capture's images as a fit at ``fit_res`` sees them: (objective, model row of the truth)."""
    model, row = model_and_row(true_settings(cap), getattr(cap, "model", None))
    n = range(len(cap.cameras))
    cameras, observed, ignore = load_observed(cap, n, range(cap.n_frames), fit_res)
    return SilhouetteObjective(cap.scenario, cameras, observed, model=model, ignore=ignore), model


def true_floors(obj, model, settings):
    """(C, F) E_sil of ``settings`` as the fit sees them (the fitter's simulation and rasteriser)."""
    return obj.per_image(model_and_row(settings, model)[1][None])[0][0]


def model_silhouettes(obj, model, settings):
    """The fitter's clean silhouettes [c][f] of ``settings`` at the fit resolution (a fit's best candidate
    stands here)."""
    return obj.silhouettes(model_and_row(settings, model)[1])


def estimates(cap, obj, model, fit_res=None):
    """(model-based CaptureFloor, wrong-model CaptureFloor, image-only CaptureFloor, cpu s per image)."""
    truth = true_settings(cap)
    t0 = time.process_time()
    cf = capture_floor(cap, resolution=fit_res, model=model_silhouettes(obj, model, truth))
    secs = (time.process_time() - t0) / cf.per_image().size
    wrong = capture_floor(cap, resolution=fit_res, model=model_silhouettes(obj, model, wrong_settings(truth)))
    return cf, wrong, capture_floor(cap, resolution=fit_res), secs


def with_estimates(row, true, wrong, image_only):
    tm = float(np.mean(true))
    row["ratio_wrong_model"] = wrong.floor / tm if tm > 0 else None
    row["wrong_model_basis"] = wrong.basis
    row["wrong_model_pct"] = 100 * wrong.floor
    row["ratio_image_only"] = image_only.floor / tm if tm > 0 else None
    row["image_only_pct"] = 100 * image_only.floor
    return row


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


def synth_cases(out, models, resolutions, noises, log, rigs=RIGS):
    rows = []
    for rig in rigs:
        for model in models:
            for res in resolutions:
                for noise in noises:
                    root = os.path.join(out, f"{rig}_{model}_{res[0]}x{res[1]}_n{noise:g}")
                    cap = make_capture(root, noise, res, model, rig)
                    obj, mdl = fit_view(cap)
                    true = true_floors(obj, mdl, true_settings(cap))
                    cf, wrong, image_only, secs = estimates(cap, obj, mdl)
                    row = summarise(
                        f"{rig} {model} {res[0]}x{res[1]} noise {100 * noise:g} %",
                        f"{rig}_{model}_{res[0]}x{res[1]}_n{100 * noise:g}",
                        true,
                        cf.per_image(),
                        {
                            "rig": rig,
                            "model": model,
                            "resolution": list(res),
                            "fit_resolution": list(res),
                            "noise": noise,
                            "rate": cf.rate,
                            "basis": cf.basis,
                            "rim_pct": 100 * cf.to_dict(False)["rim"],
                            "cpu_seconds_per_image": secs,
                        },
                    )
                    log(with_estimates(row, true, wrong, image_only))
                    rows.append(row)
    return rows


def resampled_cases(out, fit_resolutions, noises, log):
    rows = []
    for noise in noises:
        root = os.path.join(out, f"lab18_paper_480x640_n{noise:g}")
        cap = (
            load_capture(root)
            if os.path.isfile(os.path.join(root, "capture.json")) and (480, 640) in RESOLUTIONS_RUN
            else make_capture(root, noise, (480, 640))
        )
        for fr in fit_resolutions:
            obj, mdl = fit_view(cap, fr)
            true = true_floors(obj, mdl, true_settings(cap))
            cf, wrong, image_only, _ = estimates(cap, obj, mdl, fr)
            d = cf.to_dict(False)
            row = summarise(
                f"lab18 paper 480x640 noise {100 * noise:g} % fitted at {fr[0]}x{fr[1]}",
                f"lab18_paper_480x640_n{100 * noise:g}_at_{fr[0]}x{fr[1]}",
                true,
                cf.per_image(),
                {
                    "rig": "lab18",
                    "model": "paper",
                    "resolution": [480, 640],
                    "fit_resolution": list(fr),
                    "noise": noise,
                    "basis": cf.basis,
                    "resampling_pct": 100 * d["resampling"],
                    "noise_part_pct": 100 * d["noise"],
                },
            )
            log(with_estimates(row, true, wrong, image_only))
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
    root = os.path.join(out, "lab18_paper_240x320_n0.05")
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


def _r(x):
    return "-" if x is None else f"{x:.2f}"


def table(rows):
    lines = [
        "| case | images | true floor [%] | estimate [%] | ratio | wrong model | image only | per-image ratio median (p10-p90) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        im = (
            "-"
            if r["image_ratio_median"] is None
            else f"{r['image_ratio_median']:.2f} ({r['image_ratio_p10']:.2f}-{r['image_ratio_p90']:.2f})"
        )
        lines.append(
            f"| {r['case']} | {r['n_images']} | {r['true_floor_pct']:.3f} | {r['estimate_pct']:.3f} | {_r(r['ratio'])} "
            f"| {_r(r.get('ratio_wrong_model'))} | {_r(r.get('ratio_image_only'))} | {im} |"
        )
    return "\n".join(lines)


def worst(rows):
    """The worst ratio of each estimate over the rows with a true floor: {estimate: [ratio, case id]}."""
    out = {}
    for key in ("ratio", "ratio_wrong_model", "ratio_image_only"):
        vals = [(r[key], r["id"]) for r in rows if r.get(key) is not None]
        if vals:
            v, ident = max(vals, key=lambda t: abs(math.log(t[0])) if t[0] > 0 else math.inf)
            out[key] = [v, ident]
    return out


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--out", default="out/floor_cal", help="folder for the synthetic captures (default: %(default)s)")
    p.add_argument("--json", required=True, help="write the calibration table here")
    p.add_argument("--footage", help="photoreal footage folder (lab/render_footage.py render --out)")
    p.add_argument("--capture", help="its extracted capture (python -m clothfit extract FOOTAGE --out)")
    p.add_argument("--quick", action="store_true", help="paper model, lab18, at 120x160 and 480x640 only (a smoke run)")
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
        "synthetic": synth_cases(a.out, models, res, NOISES, log, ["lab18"] if a.quick else RIGS),
        "resampled": resampled_cases(a.out, FIT_RESOLUTIONS, RESAMPLED_NOISES, log),
        "timing_error": timing_error_case(a.out, log),
    }
    if a.footage and a.capture:
        out["footage"] = footage_case(a.footage, a.capture, log)
    rows = out["synthetic"] + out["resampled"] + ([out["footage"]] if "footage" in out else [])
    out["table"] = table(rows)
    out["worst"] = worst(rows)
    out["seconds"] = time.time() - t0
    os.makedirs(os.path.dirname(os.path.abspath(a.json)), exist_ok=True)
    with open(a.json, "w") as f:
        json.dump(out, f, indent=1)
    print(out["table"])


if __name__ == "__main__":
    main()
