"""Command line: ``clothfit <command> ...`` (the console script; ``python -m addon`` is the same).

No Blender needed except for ``blender`` and ``blender-agreement`` (the bpy module). The habits of
every command (``EPILOG``, also at the end of ``--help``): stdout carries one JSON document, the
command's result, and nothing else; messages for people (progress, tables, "wrote ...") go to
stderr. Exit codes: 0 done, 1 an unexpected failure, 2 bad data (a ClothFitError: one line naming
the file or value, never a traceback), 64 a command line the parser rejects, 130 Ctrl-C (a fit
keeps and reports its best result first).
"""
from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import signal
import sys
import threading
import time

import numpy as np

from .core import defaults as D
from .core.errors import ClothFitError


def _floats(s, what="--times"):
    if not s:
        return None
    try:
        return [float(x) for x in s.split(",") if x.strip()]
    except ValueError:
        raise ClothFitError(f"{what} {s!r} must be a comma-separated list of numbers") from None


def _res(s):
    if not s:
        return None
    from .core.fitting.job import check_resolution
    try:
        h, w = (int(x) for x in s.lower().split("x"))
    except ValueError:
        raise ClothFitError(f"resolution {s!r} must look like HxW, e.g. 120x160") from None
    return check_resolution([h, w], f"resolution {s!r}")


def _params(args, default=None):
    if getattr(args, "params", None):
        d = _json_arg(args.params, "--params")
        if "params" in d and not d.get("params") and not d.get("blender_cloth"):
            raise ClothFitError(f"--params {args.params}: 'params' is empty (a fit that never evaluated?)")
        return d
    if default is not None:
        return default
    return dict(D.GT_PARAMS)


def _model_spec(a):
    """--model/--fps/--quality/--bending-model -> a model dict (None: not asked for)."""
    name = getattr(a, "model", None)
    given = lambda k: getattr(a, k, None) is not None and not (k == "quality" and getattr(a, k) == "auto")  # noqa: E731
    if name is None:
        if any(given(k) for k in ("fps", "quality", "bending_model")):
            name = "blender"
        else:
            return None
    spec = {"name": name}
    if name == "blender":
        for k in ("fps", "quality", "bending_model"):
            if given(k):
                spec[k] = getattr(a, k)
    elif any(given(k) for k in ("fps", "quality", "bending_model")):
        raise ClothFitError("--fps, --quality and --bending-model belong to --model blender")
    return spec


def _capture_truth(cap):
    """The parameters a synthetic capture was made with (for evaluate/overlay without --params)."""
    meta = cap.meta or {}
    if meta.get("true_blender_cloth"):
        return {"model": meta.get("true_model") or "blender", "blender_cloth": meta["true_blender_cloth"],
                "blender_scene": {"fps": (meta.get("true_model") or {}).get("fps", D.BLENDER_FPS)}}
    return None


def _cams(capture, spec):
    """Camera selection: None = all; "n:4" = 4 spread cameras; "0,3,5" indices; names allowed."""
    from .core.observation.camera import select_training
    if not spec:
        return None
    if spec.startswith(("n:", "spread:", "heldout:")):
        try:
            n = int(spec.split(":")[1])
        except ValueError:
            raise ClothFitError(f"--cameras {spec!r}: the count after ':' must be an integer") from None
        train, held = select_training(capture.cameras, n)
        return held if spec.startswith("heldout:") else train
    out = []
    for tok in spec.split(","):
        tok = tok.strip()
        if tok.isdigit():
            c = int(tok)
            if not 0 <= c < len(capture.cameras):
                raise ClothFitError(f"--cameras: index {c} outside 0..{len(capture.cameras) - 1}")
            out.append(c)
        else:
            out.append(capture.camera_index(tok))
    return out


def _times(spec):
    if not spec:
        return None
    if spec == "train":
        return list(D.TRAIN_TIMES)
    if spec == "test":
        return list(D.TEST_TIMES)
    return _floats(spec)


class Progress:
    """A one-line text progress bar on stderr."""

    def __init__(self, enabled=True, width=30):
        self.enabled = enabled and sys.stderr.isatty() or os.environ.get("CLOTHFIT_PROGRESS") == "1"
        self.width = width
        self.t0 = time.time()
        self.last = 0

    def __call__(self, job):
        if not self.enabled:
            return False
        now = time.time()
        if now - self.last < 0.2 and not job.finished:
            return False
        self.last = now
        n = int(self.width * job.progress)
        bp = job.best_params or {}
        err = job.best_error / job.objective.n_images * 100 if job.best_params else float("nan")
        sys.stderr.write(f"\r[{'#' * n}{'.' * (self.width - n)}] gen {job.generation} evals {job.evaluations} "
                         f"E_sil {err:.3f}% k {bp.get('k', 0):.4g} l {bp.get('l', 0):.4g} d {bp.get('d', 0):.4g} "
                         f"{now - self.t0:.0f}s ")
        sys.stderr.flush()
        return False

    def done(self):
        if self.enabled:
            sys.stderr.write("\n")


def cmd_synth(a):
    from .core.observation.synth import synth_capture
    kw = {} if a.truth_dt_safety is None else {"truth_dt_safety": a.truth_dt_safety}
    spec = _model_spec(a)
    params = _params(a, {} if spec and spec["name"] == "blender" else None)
    if spec and spec["name"] == "blender":
        params = params.get("blender_cloth", params)
    cap = synth_capture(a.out, params, rig=a.rig, noise=a.noise, resolution=_res(a.resolution), seed=a.seed,
                        model=spec, **kw)
    print(f"wrote capture {a.out}: {len(cap.cameras)} cameras x {len(cap.frame_times)} frames")
    return {"capture": a.out, "cameras": [c.name for c in cap.cameras], "frame_times": list(cap.frame_times),
            "resolution": [cap.cameras[0].height, cap.cameras[0].width]}


def _scene_evaluator(cfg):
    """The workers of a ``--backend blender`` fit (Blender's own solver on ``cfg.blend``)."""
    from .farm.scene import BlendSceneEvaluator
    return BlendSceneEvaluator(cfg.blend, cfg.blend_object, cfg.frame_zero, cfg.workers, cfg.address, cfg.executor)


def _backend_args(a):
    """--backend core|blender (and the compute backends auto|numba|numpy) -> FitConfig fields."""
    scene = {k: getattr(a, k, None) for k in ("blend", "object", "frame_zero", "workers", "address")}
    if a.backend != "blender":
        given = [f"--{k.replace('_', '-')}" for k, v in scene.items() if v is not None]
        if given:
            raise ClothFitError(f"{', '.join(given)} belong to --backend blender")
        return {"backend": "auto" if a.backend == "core" else a.backend}
    if not a.blend:
        raise ClothFitError("--backend blender needs --blend SCENE.blend")
    if any(getattr(a, k, None) is not None for k in ("fps", "bending_model")) or a.model == "paper" or \
            getattr(a, "quality", None) not in (None, "auto"):
        raise ClothFitError("with --backend blender the scene's Cloth modifier and frame rate define the model: "
                            "drop --model/--fps/--quality N/--bending-model (--quality auto lets the fit choose)")
    if a.workers is not None and a.workers < 1:
        raise ClothFitError(f"--workers {a.workers}: must be at least 1")
    return {"backend": "auto", "evaluator": "blender", "blend": a.blend, "blend_object": a.object,
            "frame_zero": a.frame_zero, "workers": a.workers, "address": a.address, "executor": a.executor}


def _refuse_overwriting_inputs(out, capture, what):
    """An output must not replace the capture's own files."""
    real = os.path.realpath(out)
    root = os.path.realpath(capture.root)
    inputs = {os.path.realpath(os.path.join(root, n)) for n in ("capture.json", "cameras.json", "shapes.npz")}
    if real in inputs or real == root:
        raise ClothFitError(f"{what} {out} would overwrite the capture's own {os.path.basename(real)}: choose another path")


def _checkpoint_summary(ck):
    from .core.fitting.job import read_checkpoint
    try:
        d = read_checkpoint(ck)
    except ClothFitError as e:
        return f"an unreadable checkpoint ({e})"
    r = d.get("result") if isinstance(d.get("result"), dict) else {}
    state = "a finished" if d.get("finished") else "an unfinished"
    return f"the checkpoint of {state} fit ({r.get('evaluations', '?')} evaluations)"


def cmd_fit(a):
    from .core.fitting.job import FitConfig, FitJob, exclusive_lock, read_checkpoint
    from .core.observation.capture import load_capture
    ck = a.checkpoint or (a.out + ".checkpoint.json")
    if a.resume and a.force:
        raise ClothFitError("--resume continues the checkpoint and --force replaces it: give one of them")
    if os.path.realpath(ck) == os.path.realpath(a.out):
        raise ClothFitError(f"--checkpoint and --out are the same file {a.out}")
    for path, what in ((a.out, "--out"), (ck, "checkpoint")):
        if os.path.isdir(path):
            raise ClothFitError(f"{what} {path} is a directory: give a file name")
    cap = load_capture(a.capture)
    _refuse_overwriting_inputs(a.out, cap, "--out")
    _refuse_overwriting_inputs(ck, cap, "--checkpoint")
    cfg = FitConfig(train_cameras=_cams(cap, a.cameras), train_times=_times(a.times), optimizer=a.optimizer,
                    seed=a.seed, max_evaluations=D.FIT_EVALUATIONS if a.max_evaluations is None else a.max_evaluations,
                    resolution=_res(a.resolution), cloth_mass=a.cloth_mass, backend=a.backend,
                    population=a.population, children=a.children, target_error=a.target,
                    model=None if a.backend == "blender" else _model_spec(a), free=_names(a.free),
                    fixed=_json_arg(a.fixed, "--fixed"), init=a.init, bounds=_json_arg(a.bounds, "--bounds"),
                    restarts=a.restarts, quality="auto" if a.quality == "auto" else None, uncertain=a.uncertain)
    for k, v in _backend_args(a).items():
        setattr(cfg, k, v)
    cfg = cfg.checked()
    evaluator = None
    interrupted = False
    with exclusive_lock(ck):
        if a.resume and not os.path.lexists(ck):
            raise ClothFitError(f"--resume: there is no checkpoint {ck} to continue (run without --resume to start)")
        if not a.resume and os.path.lexists(ck) and not a.force:
            raise ClothFitError(f"{ck} holds {_checkpoint_summary(ck)}: continue it with --resume, replace it "
                                f"with --force, or choose another --out")
        if cfg.evaluator == "blender":
            evaluator = _scene_evaluator(cfg)
        try:
            if a.resume:
                if a.max_evaluations is None:       # the budget the checkpointed fit was given
                    saved = read_checkpoint(ck)["config"].get("max_evaluations")
                    if isinstance(saved, int) and not isinstance(saved, bool) and saved >= 1:
                        cfg.max_evaluations = saved
                job = FitJob.resume(ck, capture=cap, config=cfg, checkpoint_interval=D.CHECKPOINT_INTERVAL_S,
                                    evaluator=evaluator)
                print(f"resumed {ck} at {job.evaluations} evaluations", file=sys.stderr)
            else:
                job = FitJob(cap, cfg, checkpoint=ck, checkpoint_interval=D.CHECKPOINT_INTERVAL_S,
                             evaluator=evaluator)
        except BaseException:
            if evaluator is not None:
                evaluator.close()
            raise
        bar = Progress(not a.quiet)
        try:
            job.run(callback=bar)
        except KeyboardInterrupt:
            interrupted = True
            with _sigint_deferred():          # a second Ctrl-C must not lose the result being written
                job.cancel()
        except ClothFitError as e:            # e.g. a worker that died for good: the best so far is kept
            job.error = str(e)
            job.cancel()
        finally:
            bar.done()
            with _sigint_deferred():
                job.save_result(a.out)
            if evaluator is not None:
                evaluator.close()
    r = job.result()
    if job.error:
        raise ClothFitError(f"fit failed: {job.error} (the result so far is in {a.out})")
    keys = ("params", "identifiable") if r.get("params") else ("blender_cloth", "blender_scene")
    summary = {k: r[k] for k in keys + ("identifiable_error_pct", "best_E_sil_mean_pct", "evaluations",
                                        "stop_reason", "elapsed_s", "cancelled", "quality_choice", "time_offset_s",
                                        "floor") if k in r}
    summary.update(out=a.out, checkpoint=ck)
    _fit_report(r)
    if "identifiable_error_pct" in r:
        print("recovery error [%]: " + ", ".join(f"{k} {v:.3g}" for k, v in r["identifiable_error_pct"].items()
                                                  if v is not None))
    if "true_params_ignored" in r:
        print(f"note: {r['true_params_ignored']}")
    if interrupted:
        raise Interrupted(f"the best result so far ({r['evaluations']} evaluations) is in {a.out}", summary)
    print(f"wrote {a.out}")
    return summary


def _fit_report(r):
    """The result's lines for people (stderr): quality chosen, manipulation, the floor and its warning."""
    qc = r.get("quality_choice")
    if qc:
        tried = ", ".join(f"{t['quality']}: {t['train_E_sil_pct']:.3f} %" for t in qc["tried"])
        print(f"quality {qc['chosen']} ({qc['rule']}; tried {tried})", file=sys.stderr)
        if qc.get("advice"):
            print(f"note: {qc['advice']}", file=sys.stderr)
    if "time_offset_s" in r or r.get("manipulation_note"):
        t = r.get("time_offset_s")
        u = r.get("time_offset_uncertainty_s")
        if t is not None:
            print(f"time offset {1000 * t:+.1f} ms" + (f" (+-{1000 * u:.1f} ms)" if u else ""), file=sys.stderr)
        for k, h in enumerate(r.get("handles") or []):
            if h.get("offset_bound_m"):
                print(f"handle {k} (vertex {h['vertex']}) moved by "
                      f"{', '.join(f'{1000 * v:+.2f}' for v in h['offset_m'])} mm", file=sys.stderr)
        if r.get("manipulation_note"):
            print(f"note: {r['manipulation_note']}", file=sys.stderr)
    fl = r.get("floor") or {}
    if fl.get("train_floor_pct") is not None:
        line = f"training E_sil {fl['train_E_sil_pct']:.3f} % (floor {fl['train_floor_pct']:.3f} %)"
        if fl.get("heldout_E_sil_pct") is not None:
            line += f"; held-out {fl['heldout_E_sil_pct']:.3f} % (floor {fl['heldout_floor_pct']:.3f} %)"
        print(line, file=sys.stderr)
    if fl.get("warning"):
        print(f"warning: {fl['warning']}", file=sys.stderr)


def cmd_fit_many(a):
    from dataclasses import asdict
    from .core.fitting.job import FitConfig
    from .core.observation.capture import load_capture
    if a.workers is not None and a.workers < 1:
        raise ClothFitError(f"--workers {a.workers}: must be at least 1")
    configs = []
    for c in a.captures:
        cap = load_capture(c)                     # bad captures fail here, before any worker starts
        cfg = FitConfig(train_cameras=_cams(cap, a.cameras), train_times=_times(a.times), optimizer=a.optimizer,
                        seed=a.seed, max_evaluations=a.max_evaluations or D.FIT_EVALUATIONS,
                        resolution=_res(a.resolution), cloth_mass=a.cloth_mass, population=a.population,
                        model=_model_spec(a), quality="auto" if a.quality == "auto" else None,
                        uncertain=a.uncertain)
        configs.append(asdict(cfg))
    os.makedirs(a.out_dir, exist_ok=True)
    t0 = time.time()
    from .farm.tasks import fit_many
    results, kind, workers = fit_many(a.captures, configs, a.workers, a.address, a.executor)
    wall = time.time() - t0
    from .core.fitting.job import _atomic_json
    fits = []
    for i, (c, r) in enumerate(zip(a.captures, results)):
        path = os.path.join(a.out_dir, f"{i:03d}_{os.path.basename(os.path.normpath(c))}.json")
        _atomic_json(path, r)
        print(f"{c}: E_sil {r['best_E_sil_mean_pct']:.3f} % after {r['evaluations']} evaluations -> {path}")
        fits.append({"capture": c, "out": path, "best_E_sil_mean_pct": r["best_E_sil_mean_pct"],
                     "evaluations": r["evaluations"], "stop_reason": r.get("stop_reason")})
    print(f"{len(results)} fits on {workers} {kind} worker(s) in {wall:.1f} s")
    return {"fits": fits, "workers": workers, "executor": kind, "wall_s": wall}


def _names(spec):
    return [x.strip() for x in spec.split(",") if x.strip()] if spec else None


def _json_arg(text, what):
    """An option that takes JSON or a JSON file."""
    if not text:
        return None
    from .core.jsonio import read_json
    if os.path.isfile(text):
        d = read_json(text, what)
    else:
        try:
            d = json.loads(text)
        except json.JSONDecodeError:
            raise ClothFitError(f"{what} {text!r} is neither a file nor JSON") from None
    if not isinstance(d, dict):
        raise ClothFitError(f"{what} must be a JSON object")
    return d


def cmd_export_blender_cloth(a):
    from .core.jsonio import read_json
    from .core.physics import blender as B
    from .core.physics.models import BlenderModel, model_and_row
    res = read_json(a.result, "result")
    model, row = model_and_row(res)
    if not isinstance(model, BlenderModel):
        raise ClothFitError(f"result {a.result}: a {model.name}-model fit has no Blender cloth settings "
                            "(fit with --model blender, or warm-start one from it with --init)")
    s = model.settings(row)
    out = {"blender_cloth": s, "blender_scene": {"fps": model.fps}}
    manip = {k: res[k] for k in ("time_offset_s", "handles") if res.get(k) is not None}
    if manip:                                 # the manipulation the fit estimated: where the pins go, when it lets go
        out["manipulation"] = manip
    if a.python:                              # the one command whose stdout is not JSON: Python, by request
        lines = [f"# Blender {model.fps:g} fps scene: set scene.render.fps / fps_base to match",
                 "cloth = bpy.context.object.modifiers['Cloth'].settings"]
        lines += [f"cloth.{k} = {s[k]!r}" for k in ("quality", "bending_model") + B.FLOAT_SETTINGS]
        if manip.get("time_offset_s") is not None:
            lines.append(f"# the fit read the footage {1000 * manip['time_offset_s']:+.1f} ms off: the release "
                         f"happened at capture time + time_offset_s")
        for h in manip.get("handles") or []:
            if any(h.get("offset_m") or []):
                lines.append(f"# pin at vertex {h['vertex']}: moved by {[round(v * 1000, 2) for v in h['offset_m']]} mm "
                             f"from the capture's measurement")
        return Text("\n".join(lines))
    return out


def cmd_evaluate(a):
    from .core.fitting.evaluate import evaluate
    from .core.observation.capture import load_capture
    cap = load_capture(a.capture)
    params = _params(a, _capture_truth(cap))
    r = evaluate(cap, params, cameras=_cams(cap, a.cameras), times=_times(a.times), resolution=_res(a.resolution))
    if r["exploded"]:
        raise ClothFitError(f"the {r['model']['name']} model with these parameters explodes: no silhouette to score")
    s = f"silhouette error {r['silhouette_error_pct']:.3f} % over {len(r['cameras'])} cameras x {len(r['times'])} frames"
    if "shape_error_mm" in r:
        s += f"; shape error {r['shape_error_mm']:.3f} mm"
    print(s)
    if a.json:
        from .core.safeio import atomic_json
        atomic_json(a.json, r)
    return r


def _capture_floor(cap, cams, times, resolution):
    from .core.observation.floor import capture_floor
    fidx = None if times is None else [cap.frame_index(t) for t in times]
    return capture_floor(cap, cams, fidx, resolution)


def cmd_floor(a):
    from .core.observation.capture import load_capture
    cap = load_capture(a.capture)
    cf = _capture_floor(cap, _cams(cap, a.cameras), _times(a.times), _res(a.resolution))
    d = cf.to_dict()
    print(f"noise floor {100 * d['floor']:.3f} % E_sil per image (median {100 * d['floor_median']:.3f} %; "
          f"resampling {100 * d['resampling']:.3f} %) over {d['n_images']} images; a 1-pixel shift of the outline "
          f"costs {100 * d['rim']:.2f} %; {cf.limits}")
    if a.json:
        from .core.safeio import atomic_json
        atomic_json(a.json, d)
    return d


def cmd_overlay(a):
    from .core.observation.capture import load_capture
    from .core.observation.overlay import capture_overlays
    cap = load_capture(a.capture)
    images = None
    if a.on_images:
        from .core.footage.extract import footage_images
        images = footage_images(cap)
    cams, times = _cams(cap, a.cameras), _times(a.times)
    floors = None
    if a.floor:
        floors = _capture_floor(cap, cams, times, None).per_image()
    paths = capture_overlays(cap, _params(a, _capture_truth(cap)), a.out, cameras=cams, times=times, images=images,
                             floors=floors)
    print(f"wrote {len(paths)} images under {a.out} (contact sheet: {paths[-1]})")
    out = {"out": a.out, "images": paths[:-1], "contact_sheet": paths[-1]}
    if a.floor:
        out["images"], out["floor_sheet"] = paths[:-2], paths[-2]
    return out


def cmd_paper(a):
    from .core.studies.experiment import run_paper
    if a.workers is not None or a.address is not None:
        return _paper_parallel(a)
    return run_paper(a.json, quick=a.quick, out_dir=a.out, seed=a.seed, optimizer=a.optimizer,
                     max_evaluations=a.max_evaluations, only=a.only, truth_dt_safety=a.truth_dt_safety,
                     population=a.population, children=a.children, rig=a.rig)


def _paper_parallel(a):
    """``paper --workers N / --address``: the protocol's parts as tasks on Ray (or spawned processes)."""
    from .core.fitting.job import _atomic_json
    from .core.studies.experiment import format_tables
    from .farm.tasks import PAPER_PARTS, paper_parts
    parts = [p for p in (a.only or ",".join(PAPER_PARTS)).split(",") if p]
    bad = [p for p in parts if p not in PAPER_PARTS]
    if bad:
        raise ClothFitError(f"--only: unknown part(s) {', '.join(bad)} (parts: {', '.join(PAPER_PARTS)})")
    if a.workers is not None and a.workers < 1:
        raise ClothFitError(f"--workers {a.workers}: must be at least 1")
    kw = {"quick": a.quick, "seed": a.seed, "optimizer": a.optimizer, "max_evaluations": a.max_evaluations,
          "truth_dt_safety": a.truth_dt_safety, "population": a.population, "children": a.children, "rig": a.rig}
    out = paper_parts(parts, a.out, kw, a.workers, a.address, a.executor)
    _atomic_json(a.json, out)
    print(format_tables(out))
    print(f"{len(parts)} part(s) on {out['workers']} {out['executor']} worker(s) in {out['total_seconds']:.1f} s; wrote {a.json}")
    return out


def cmd_tables(a):
    from .core.jsonio import read_json
    from .core.studies.experiment import format_tables
    return Text(format_tables(read_json(a.json, "paper JSON")))           # text tables by design (the JSON is the file itself)


def cmd_bench(a):
    from .core.studies.bench import run_bench
    from .farm.bench import bench_blender_workers
    return run_bench(a.json, quick=a.quick, only_blender_workers=a.blender_workers, only_default_fit=a.default_fit,
                     blender_workers=bench_blender_workers)


def cmd_identifiability(a):
    from .core.studies.identifiability import MATERIALS, run
    mats = _names(a.materials)
    bad = [m for m in mats or [] if m not in MATERIALS]
    if bad:
        raise ClothFitError(f"--materials: unknown {', '.join(bad)} (known: {', '.join(MATERIALS)})")
    return run(a.json, mats)


def cmd_occlusion(a):
    from .core.studies.occlusion import run_occlusion
    return run_occlusion(a.json, out_dir=a.out, quick=a.quick, n_train=a.train_cameras, evaluations=a.max_evaluations,
                  seed=a.seed, resolution=_res(a.resolution), scales=_floats(a.scales, "--scales"),
                  truth_dt_safety=a.truth_dt_safety)


def cmd_rig(a):
    from .core.observation.camera import load_rig, spread_order
    cams = load_rig(a.rig)
    order = spread_order(cams)
    print(f"{len(cams)} cameras; training order (spread rule): {[cams[i].name for i in order]}")
    return {"rig": a.rig, "cameras": [c.name for c in cams], "training_order": [cams[i].name for i in order],
            "resolution": [cams[0].height, cams[0].width] if cams else None}


def cmd_extract(a):
    from .core.footage import extract
    return extract.run_args(a)


def _pair(text, what, kind=float):
    """``AxB`` -> (a, b)."""
    try:
        a_, b_ = (kind(x) for x in text.lower().replace("×", "x").split("x"))
    except ValueError:
        raise ClothFitError(f"{what} {text!r} must look like {'0.30x0.40' if kind is float else '16x21'}") from None
    return a_, b_


def cmd_handles(a):
    from .core.footage import handles as H
    size = _pair(a.size, "--size")
    grid = None
    if a.grid:
        grid = _pair(a.grid, "--grid", int) if "x" in a.grid.lower() else None
        if grid is None:
            try:
                grid = int(a.grid)
            except ValueError:
                raise ClothFitError(f"--grid {a.grid!r} must be a count (vertices along the longer side) or "
                                    f"COLUMNSxROWS") from None
    opts = H.HandleOptions(clip_size=a.clip_size, mark_sigma=a.mark_sigma, max_residual=a.max_residual,
                           fb_max=a.fb_max, departure_min=a.departure_min / 1000.0,
                           max_pin_offset=a.max_pin_offset / 1000.0, smooth=a.smooth, levels=a.levels,
                           settle_time=a.settle)
    tty = sys.stderr.isatty() or os.environ.get("CLOTHFIT_PROGRESS") == "1"

    def progress(i, n, text):
        if tty:
            print(f"[{i}/{n}] {text}", file=sys.stderr)
    doc = H.run(a.out, a.marks, size, footage=a.footage, videos=a.videos, sync=a.sync,
                find_sync=a.find_sync == "flash", flash_time=a.flash_time, cameras=a.cameras,
                times=_floats(a.times), fps=a.fps, start=a.start, frames=a.frames, grid=grid, options=opts,
                progress=progress)
    print(H.format_report(doc["report"]))
    print(f"wrote {a.out}: the scenario for `clothfit extract --scenario {a.out}`")
    return dict(doc["report"], out=a.out, uncertain=doc["uncertain"])

def _gravity(text):
    """--gravity CAMERA:GX,GY,GZ -> (camera, (gx, gy, gz))."""
    if not text:
        return None
    cam, sep, vec = text.rpartition(":")
    if not sep or not cam:
        raise ClothFitError(f"--gravity {text!r}: expected CAMERA:GX,GY,GZ (gravity in that camera's axes)")
    v = _floats(vec, "--gravity")
    if not v or len(v) != 3:
        raise ClothFitError(f"--gravity {text!r}: expected three numbers after the camera name")
    return cam, tuple(v)


def cmd_calibrate(a):
    from .core.footage import calibrate as CB
    board = CB.parse_board(a.board, a.legacy_board)
    if a.make_board:
        if a.folder:
            raise ClothFitError("--make-board writes a board to print: give no FOLDER")
        stem = os.path.splitext(a.out)[0] if a.out.lower().endswith((".png", ".pdf")) else a.out
        r = CB.make_board(board, stem + ".png", stem + ".pdf", a.dpi, a.margin)
        print(f"wrote {r['png']} ({r['png_px'][0]} x {r['png_px'][1]} px at {r['png_dpi']:.1f} dpi) and {r['pdf']} "
              f"({r['pdf_page_mm'][0]:.1f} x {r['pdf_page_mm'][1]:.1f} mm): print at 100 %, then measure a square "
              f"({board.square_m * 1000:g} mm)")
        return r
    if not a.folder:
        raise ClothFitError("calibrate needs FOLDER (one folder of images or one video per camera), or --make-board")
    fixed = {}
    if a.intrinsics:
        from .core.footage.calib_io import import_cameras
        fixed = {c.name: c for c in import_cameras(a.intrinsics)}
    opts = CB.Options(distortion=a.distortion, square_pixels=not a.free_aspect, shared=a.shared_intrinsics,
                      fixed=fixed, world=a.world, level=a.level, gravity=_gravity(a.gravity), min_views=a.min_views,
                      min_corners=a.min_corners, blur_ratio=a.blur_ratio).check()
    sync = None
    if a.sync or a.find_sync:
        src = CB.find_source(a.folder)
        if src.kind != "videos":
            raise ClothFitError(f"--sync / --find-sync are for videos; {a.folder} holds camera folders of images")
        from .core.footage import video
        if a.find_sync:
            sync = video.flash_sync(a.folder, src.cameras, a.flash_time)
            print("sync from the flash: " + ", ".join(f"{k} {v:.4f} s" for k, v in sync.items()))
        else:
            sync = video.read_sync(a.sync, src.cameras)
    elif a.every is not None or a.times:
        raise ClothFitError("--every and --times sample videos: they need --sync FILE or --find-sync flash")
    res, det, src = CB.calibrate_folder(a.folder, board, opts, sync=sync, every=a.every,
                                        times=_floats(a.times) if a.times else None, debug_dir=a.debug,
                                        log=lambda s: print(s))
    written = CB.write_outputs(res, a.out, a.export, a.format, a.report)
    for c in res.report["cameras"]:
        print(f"{c['name']:<12} RMS {c['rms_px']:.3f} px  views {c['views_used']} ({c['views_shared']} shared)  "
              f"fx {c['fx']:.1f}  centre {[round(x, 3) for x in c['centre_m']]} m")
    print(f"overall RMS {res.report['rms_px']:.3f} px over {res.report['corners']} corners, "
          f"{res.report['moments']} moments; world: board at {res.report['world']['moment']}, up from "
          f"{res.report['world']['up']}")
    print("wrote " + ", ".join(written.values()))
    return dict(res.report, written=written)


def cmd_cameras(a):
    from .core.footage import calib_io
    return calib_io.run_args(a)


def cmd_blender(a):
    """The whole pipeline through Blender (build rig and cloth, simulate, render silhouettes, fit,
    overlays, save a .blend): needs the bpy module."""
    from .blender import pipeline
    return pipeline.run(a)


def cmd_blender_agreement(a):
    if a.grid < 2 or a.grid > 200:
        raise ClothFitError(f"--grid {a.grid}: must be 2..200")
    import bpy

    from .blender import agreement
    out = {"grid": a.grid, "settle_s": a.settle, "after_s": a.after, "fps": a.fps,
           "blender": bpy.app.version_string, "cases": agreement.run(a.grid, a.settle, a.after, a.fps)}
    if a.json:
        from .core.safeio import atomic_json
        atomic_json(a.json, out)
    return out


PROG = "clothfit"
EXIT_FAILURE = 1          # an unexpected failure (a bug or the machine): one line, CLOTHFIT_DEBUG=1 for the traceback
EXIT_BAD_DATA = 2         # a ClothFitError: a file or value the command cannot use
EXIT_USAGE = 64           # the parser rejected the command line (sysexits.h EX_USAGE)
EXIT_INTERRUPTED = 130    # Ctrl-C (128 + SIGINT, the shells' convention)

EPILOG = f"""\
output:
  stdout carries one JSON document, the command's result, and nothing else (clothfit fit ... | jq .params);
  progress, tables and every other message for people go to stderr. Not JSON: `tables` (text tables),
  `export-blender-cloth --python` (Python), --help and --version.
exit codes:
  0 done; {EXIT_FAILURE} an unexpected failure (set CLOTHFIT_DEBUG=1 for the traceback); {EXIT_BAD_DATA} bad data: a file or
  value the command cannot use, one line naming it; {EXIT_USAGE} a command line the parser rejects (unknown command or
  option, missing or mistyped value); {EXIT_INTERRUPTED} interrupted by Ctrl-C: `fit` first writes its best result
  so far to --out and reports it on stdout."""


class Text(str):
    """A command result printed as text, not JSON (``tables``, ``export-blender-cloth --python``)."""


class Interrupted(Exception):
    """Ctrl-C after a command kept its work: ``result`` is still reported, then exit code 130."""

    def __init__(self, message, result=None):
        super().__init__(message)
        self.result = result


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Descriptions and epilogs keep their line breaks; option help is wrapped as usual."""


class ArgumentParser(argparse.ArgumentParser):
    """argparse with the CLI's habits: a usage error exits with EXIT_USAGE (64), not argparse's 2,
    which is the code of bad data here."""

    def __init__(self, *args, **kw):
        kw.setdefault("formatter_class", HelpFormatter)
        super().__init__(*args, **kw)

    def error(self, message):
        self.print_usage(sys.stderr)
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message}\n")


def _quality_arg(text):
    if str(text).strip().lower() == "auto":
        return "auto"
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number of steps per frame or 'auto'") from None


def _model_args(s, default_text="the capture's, else paper"):
    from .core.physics import blender as B
    s.add_argument("--model", choices=["paper", "blender"], default=None,
                   help=f"cloth model: the paper's mass-spring sheet or Blender's cloth solver (default: {default_text})")
    s.add_argument("--fps", type=float, default=None,
                   help=f"blender model: scene frame rate [frames/s] the settings are for (default: {D.BLENDER_FPS})")
    s.add_argument("--quality", type=_quality_arg, default=None,
                   help="blender model: solver steps per frame, or 'auto' (default: the capture's, else the fit "
                        f"chooses from {', '.join(map(str, D.QUALITY_LADDER))} starting at {B.DEFAULTS['quality']}, "
                        "Blender's; --backend blender: the scene's, one rung above it tried)")
    s.add_argument("--bending-model", choices=list(B.BENDING_MODELS), default=None,
                   help=f"blender model: Blender's bending model (default: {B.DEFAULTS['bending_model']})")


def _selection_args(s, what="fit"):
    """--cameras / --times: which cameras and frames a command uses."""
    s.add_argument("--cameras", help=f"cameras to {what}: 'n:16' (16 spread round the cloth by the spread rule), "
                                     "'heldout:16' (the others), indices or names, comma separated (default: all)")
    s.add_argument("--times", help=f"frame times to {what}: 'train' (0.1, 0.2 ... 1.5 s), 'test' (0.05, 0.15 ... "
                                   "1.45 s) or a comma list of times [s] (default: every frame of the capture)")


def _search_args(s):
    """Options of fit and fit-many: the optimiser and the fit's budget and scale."""
    s.add_argument("--optimizer", default=D.DEFAULT_OPTIMIZER,
                   help="cma-es or spx-mgg, the paper's real-coded GA (default: %(default)s)")
    s.add_argument("--seed", type=int, default=0, help="random seed of the optimiser (default: %(default)s)")
    s.add_argument("--max-evaluations", type=int, default=None,
                   help=f"budget: at most this many simulated candidates (default: {D.FIT_EVALUATIONS}; with "
                        f"--resume the checkpoint's)")
    s.add_argument("--population", type=int, default=None,
                   help="optimiser population (default: GA 7n = 21, CMA-ES 4 + 3 ln n = 7)")
    s.add_argument("--uncertain", default=None,
                   help="what the manipulation could not measure, estimated with the cloth: 'time_offset=S,handles=M' "
                        "(bounds in seconds and metres; true time = capture time - time_offset_s), or 'none' "
                        "(default: the capture's 'uncertain' block)")
    s.add_argument("--resolution", help="fit at HxW [px], e.g. 120x160; silhouettes area-resampled "
                                        "(default: the capture's)")
    s.add_argument("--cloth-mass", type=float, default=None,
                   help="total cloth mass [kg]: fixes m, which silhouettes cannot identify (default: the "
                        "capture's cloth_mass, else a vertex mass flagged in the result: paper 1e-5 kg, blender "
                        "Blender's 0.3 kg, --backend blender the scene's)")


def _farm_args(s, what):
    s.add_argument("--workers", type=int, default=None, help=f"{what}: worker processes (default: the cores)")
    s.add_argument("--address", default=None, help=f"{what}: a running Ray cluster (auto, ray://host:port); "
                                                   "default: a local Ray instance started for the run")
    s.add_argument("--executor", default="auto", choices=["auto", "ray", "process"],
                   help=f"{what}: Ray actors or spawned processes; auto = Ray when installed (default: %(default)s)")


def _command(sub, name, fn, help, output):
    """One subcommand: ``help`` in the command list and as its description, ``output`` in its epilog."""
    s = sub.add_parser(name, help=help, description=help[0].upper() + help[1:] + ".",
                       epilog=f"output: {output}; messages for people on stderr.\nexit codes: 0 done, "
                              f"{EXIT_BAD_DATA} bad data, {EXIT_USAGE} usage, {EXIT_INTERRUPTED} Ctrl-C "
                              f"(see {PROG} --help).")
    s.set_defaults(fn=fn)
    return s


def _calibrate_args(s):
    from .core.footage import calibrate as CB
    from .core.footage.calib_io import FORMATS
    s.add_argument("folder", nargs="?",
                   help="one folder per camera (named after it) of images named by moment, the same name in every "
                        "camera = the same moment; or one video per camera, <camera>.<mp4|mov|mkv|avi>")
    s.add_argument("--board", required=True,
                   help="SQUARES_X,SQUARES_Y,SQUARE_M,MARKER_M,DICTIONARY in OpenCV's CharucoBoard layout, e.g. "
                        "9,7,0.04,0.03,DICT_5X5_100 (sizes in metres: measure the print)")
    s.add_argument("--legacy-board", action="store_true",
                   help="the board was made by OpenCV before 4.6 (differs only for an even number of rows)")
    s.add_argument("--out", required=True,
                   help="cameras JSON to write (our format); with --make-board: the board's file name, .png and "
                        ".pdf are written")
    s.add_argument("--make-board", action="store_true",
                   help="write a printable board (PNG and vector PDF at the stated square size) instead")
    s.add_argument("--dpi", type=float, default=D.CALIB_BOARD_DPI,
                   help="--make-board: PNG resolution [pixels per inch] (default: %(default)s)")
    s.add_argument("--margin", type=float, default=D.CALIB_BOARD_MARGIN_M,
                   help="--make-board: white margin round the board [m] (default: %(default)s)")
    s.add_argument("--world", metavar="MOMENT",
                   help="the moment whose board pose is the world: origin at the chessboard's centre, X along "
                        "its squares_x side, Z up out of the face (default: the first moment seen)")
    up = s.add_mutually_exclusive_group()
    up.add_argument("--level", metavar="MOMENT",
                    help="a moment where the board lies level: its normal is up (when the world board is not level)")
    up.add_argument("--gravity", metavar="CAMERA:GX,GY,GZ",
                    help="the direction gravity pulls, in that camera's axes (x right, y down, z forward in its "
                         "images), e.g. from the phone's accelerometer (default: the world board's normal is up)")
    s.add_argument("--distortion", default=D.CALIB_DISTORTION, choices=list(CB.DISTORTION_MODELS),
                   help="the distortion coefficients estimated (OpenCV's k1, k2, p1, p2, k3) (default: %(default)s)")
    s.add_argument("--free-aspect", action="store_true",
                   help="estimate fx and fy separately (default: square pixels, fx = fy)")
    s.add_argument("--intrinsics", metavar="FILE",
                   help="hold these cameras' intrinsics and distortion fixed (matched by name; any file "
                        "import-cameras reads); only their poses are estimated")
    s.add_argument("--shared-intrinsics", action="store_true",
                   help="one set of intrinsics for every estimated camera (the same phone model and zoom)")
    s.add_argument("--min-views", type=int, default=D.CALIB_MIN_VIEWS,
                   help="usable views a camera needs for its own intrinsics (default: %(default)s)")
    s.add_argument("--min-corners", type=int, default=D.CALIB_MIN_CORNERS,
                   help="ChArUco corners a view needs (default: %(default)s)")
    s.add_argument("--blur-ratio", type=float, default=D.CALIB_BLUR_RATIO,
                   help="skip a frame whose board sharpness is below this fraction of its camera's median, "
                        "0 = keep all (default: %(default)s)")
    s.add_argument("--sync", help="videos: JSON {camera: video time [s] at capture time 0}")
    s.add_argument("--find-sync", choices=["flash"], help="videos: the sync from a flash every camera saw")
    s.add_argument("--flash-time", type=float, default=0.0,
                   help="videos: capture time [s] of the flash (default: %(default)s)")
    s.add_argument("--every", type=float, default=None,
                   help=f"videos: one moment every this many seconds over the span all videos cover "
                        f"(default: {D.CALIB_VIDEO_EVERY_S})")
    s.add_argument("--times", help="videos: the capture times [s] to use, comma separated (default: --every)")
    s.add_argument("--debug", metavar="DIR",
                   help="draw the detected markers and corners (and the calibration's reprojections) per camera "
                        "and moment into DIR/<camera>/<moment>.jpg, also when the calibration fails")
    s.add_argument("--export", metavar="PATH", help="also write the cameras in another format (see --format)")
    s.add_argument("--format", default="auto", choices=[f for f in FORMATS if f != "easymocap"],
                   help="format of --export; auto: by its extension, .json ours, .yml/.yaml/.xml OpenCV, "
                        "anything else a COLMAP folder (default: %(default)s)")
    s.add_argument("--report", metavar="FILE", help="also write the full report (stdout's JSON) to this file")
    return s


def build_parser():
    from . import version
    from .blender import pipeline
    from .core.footage import calib_io, extract
    p = ArgumentParser(prog=PROG, description="Silhouette Cloth Fit: cloth parameters from multi-view silhouettes.",
                       epilog=EPILOG)
    p.add_argument("--version", action="version", version=f"%(prog)s {version()}")
    sub = p.add_subparsers(dest="cmd", required=True, metavar="COMMAND")

    s = _command(sub, "synth", cmd_synth, "make a synthetic capture from ground-truth parameters",
                 "the capture's cameras, frame times and image size as JSON")
    s.add_argument("--out", required=True, help="capture folder to write")
    s.add_argument("--rig", default=D.DEFAULT_RIG,
                   help="camera rig: a preset of rigs/ (lab18, lab18_far, ring8) or a cameras JSON (default: %(default)s)")
    s.add_argument("--params", help="JSON or a JSON file: the paper model's m [kg per point mass], k [N/m], l [m], "
                                    "d [N s/m], or Blender cloth settings with --model blender (default: the built-in "
                                    "ground truth)")
    s.add_argument("--noise", type=float, default=D.NOISE_FRACTION,
                   help="fraction of the silhouettes' boundary pixels flipped (default: %(default)s)")
    s.add_argument("--resolution", help="image size HxW [px], e.g. 120x160 (default: the rig's)")
    s.add_argument("--seed", type=int, default=0, help="random seed of the boundary noise (default: %(default)s)")
    s.add_argument("--truth-dt-safety", type=float, default=None,
                   help="time step of the truth as a factor of sqrt(m/k); 0.125 = 4x finer than the fitter's "
                        "(default: the model's own)")
    _model_args(s, "paper")

    s = _command(sub, "fit", cmd_fit, "fit the model to a capture",
                 "a summary of the fit as JSON (params, errors, evaluations, stop_reason, out); the whole "
                 "result is in --out")
    s.add_argument("capture", help="capture folder (capture.json, cameras.json, silhouettes)")
    s.add_argument("--out", default="out/fit.json", help="result JSON to write (default: %(default)s)")
    _selection_args(s, "fit")
    _search_args(s)
    s.add_argument("--children", type=int, default=None, help="GA: SPX children per family (default: 5n = 15)")
    s.add_argument("--target", type=float, default=None,
                   help="stop when the mean E_sil per training image falls below this fraction, e.g. 0.005 = "
                        "0.5 %% (default: no target)")
    s.add_argument("--restarts", type=int, default=None,
                   help=f"cma-es: IPOP restarts after convergence, each with twice the population (default: paper "
                        f"{D.FIT_RESTARTS}, blender {D.BLENDER_FIT_RESTARTS})")
    s.add_argument("--checkpoint", help=f"checkpoint file, written every {D.CHECKPOINT_INTERVAL_S:g} s and at the end "
                                        f"(default: OUT.checkpoint.json)")
    again = s.add_mutually_exclusive_group()
    again.add_argument("--resume", action="store_true",
                       help="continue the checkpoint; refused if it is of another fit (capture, cameras, times, "
                            "resolution, optimiser, population, seed, bounds...); --max-evaluations may grow")
    again.add_argument("--force", action="store_true", help="replace an existing checkpoint instead of refusing")
    s.add_argument("--backend", default="auto", choices=["auto", "numba", "numpy", "core", "blender"],
                   help="where candidates are simulated: the core (auto, numba, numpy; core = auto) or blender "
                        "(Blender's own solver on --blend, in worker processes) (default: %(default)s)")
    s.add_argument("--blend", help="blender backend: the .blend holding the cloth object (colliders and all)")
    s.add_argument("--object", help="blender backend: the cloth object (default: the scene's only mesh with a "
                                    "Cloth modifier)")
    s.add_argument("--frame-zero", type=float, default=None,
                   help="blender backend: scene frame of capture time 0 (default: the scene's frame_start)")
    _farm_args(s, "blender backend")
    s.add_argument("--quiet", action="store_true",
                   help="no progress bar on stderr (shown on a terminal, or with CLOTHFIT_PROGRESS=1)")
    _model_args(s)
    s.add_argument("--free", help="blender model: comma list of ClothSettings to search (default: see README, "
                                  "Identifiability)")
    s.add_argument("--fixed", help="blender model: JSON (or file) of ClothSettings held fixed (default: Blender's "
                                   "defaults for the settings not searched)")
    s.add_argument("--bounds", help="JSON (or file) {name: [low, high]} search ranges; blender: Blender units at "
                                    "the fixed vertex mass (default: the model's ranges)")
    s.add_argument("--init", help="warm start from this result JSON, a blender or paper fit (default: a cold start)")

    s = _command(sub, "fit-many", cmd_fit_many, "fit many captures in parallel (Ray actors, or processes without Ray)",
                 "one summary per fit (capture, out, E_sil, evaluations) and the workers used, as JSON")
    s.add_argument("captures", nargs="+", help="capture folders")
    s.add_argument("--out-dir", default="out/fits",
                   help="folder for one result JSON per capture, NNN_<capture>.json (default: %(default)s)")
    _selection_args(s, "fit")
    _search_args(s)
    _farm_args(s, "the fits")
    _model_args(s)

    s = _command(sub, "export-blender-cloth", cmd_export_blender_cloth,
                 "the Cloth modifier settings of a blender-model fit result",
                 "the settings as JSON (blender_cloth, blender_scene), or Python with --python")
    s.add_argument("result", help="result JSON of a fit with --model blender")
    s.add_argument("--python", action="store_true", help="print bpy assignments (Python) instead of JSON")

    s = _command(sub, "evaluate", cmd_evaluate, "silhouette and shape error of parameters on a capture",
                 "the errors as JSON: mean, per camera and per time (silhouette [%], shape [mm] when the "
                 "capture has its true shapes)")
    s.add_argument("capture", help="capture folder")
    s.add_argument("--params", help="a result JSON file, or JSON with m, k, l, d (default: a synthetic capture's "
                                    "truth, else the built-in ground truth)")
    _selection_args(s, "score")
    s.add_argument("--resolution", help="score at HxW [px] (default: the capture's)")
    s.add_argument("--json", help="also write the result to this file")

    s = _command(sub, "overlay", cmd_overlay, "observed vs model silhouette images and a contact sheet",
                 "the image paths as JSON")
    s.add_argument("capture", help="capture folder")
    s.add_argument("--params", help="a result JSON file, or JSON with m, k, l, d (default: a synthetic capture's "
                                    "truth, else the built-in ground truth)")
    s.add_argument("--out", default="out/overlays",
                   help="folder for the images, <camera>/<frame>.png and contact_sheet.png (default: %(default)s)")
    _selection_args(s, "draw")
    s.add_argument("--on-images", action="store_true",
                   help="draw on the camera images the silhouettes were extracted from (image footage)")
    s.add_argument("--floor", action="store_true",
                   help="estimate each image's noise floor (see the floor command), frame the contact sheet's tiles "
                        "by E_sil / floor (green at it, amber above, red more than 3x) and write floor_sheet.png")

    s = _command(sub, "floor", cmd_floor, "estimate the noise floor of a capture's silhouettes from the silhouettes",
                 "the capture's floor, its parts and the per-image floors as JSON")
    s.add_argument("capture", help="capture folder")
    _selection_args(s, "estimate")
    s.add_argument("--resolution", help="for a fit at HxW [px]: the silhouettes area-resampled as the fitter does "
                                        "(default: the capture's)")
    s.add_argument("--json", help="also write the result to this file")

    s = _command(sub, "paper", cmd_paper, "the paper's Table 1, Fig. 8 and Table 2 protocol",
                 "every table and figure as JSON (the same as --json)")
    s.add_argument("--json", required=True, help="write the tables and every figure to this JSON file")
    s.add_argument("--out", default="out/paper", help="folder for the captures, fits and overlays (default: %(default)s)")
    s.add_argument("--quick", action="store_true",
                   help="a smaller protocol: 700 evaluations per fit, fewer cameras and seeds")
    s.add_argument("--seed", type=int, default=0, help="random seed of the captures and fits (default: %(default)s)")
    s.add_argument("--optimizer", default=None, help=f"cma-es or spx-mgg (default: {D.DEFAULT_OPTIMIZER})")
    s.add_argument("--max-evaluations", type=int, default=None,
                   help="budget of each fit (default: 2500, --quick 700)")
    s.add_argument("--only", default=None, help="comma list of parts: table1, fig8, table2, optimizers (default: all)")
    s.add_argument("--population", type=int, default=None,
                   help="optimiser population; GA: the MGG population (default: the optimiser's, see fit --help)")
    s.add_argument("--children", type=int, default=None, help="GA: SPX children per family (default: 5n = 15)")
    s.add_argument("--rig", default=None, help=f"camera rig preset (default: {D.DEFAULT_RIG})")
    s.add_argument("--workers", type=int, default=None,
                   help="run the parts (table1, fig8, table2, optimizers) in parallel on this many workers "
                        "(default: one after the other in this process)")
    s.add_argument("--address", default=None, help="run the parts on a running Ray cluster (auto, ray://host:port)")
    s.add_argument("--executor", default="auto", choices=["auto", "ray", "process"],
                   help="with --workers / --address: Ray actors or spawned processes; auto = Ray when installed "
                        "(default: %(default)s)")
    s.add_argument("--truth-dt-safety", type=float, default=None,
                   help="time-step factor of the ground truth (default: the model's own; 0.125 = 4x finer truth, "
                        "i.e. a model mismatch the fit cannot remove)")

    s = _command(sub, "tables", cmd_tables, "print the tables of a `paper` JSON again",
                 "text tables (the one text command: the JSON is the file itself)")
    s.add_argument("json", help="a JSON written by `paper --json`")

    s = _command(sub, "bench", cmd_bench, "speed figures", "every figure as JSON (the same as --json)")
    s.add_argument("--json", required=True, help="write every figure to this JSON file")
    s.add_argument("--quick", action="store_true", help="shorter fits: 700 evaluations instead of 2500 (the blender model's fit 600 instead of 3000)")
    s.add_argument("--blender-workers", action="store_true",
                   help="only Blender's solver as the fit's evaluator: evaluations/s with 1 and 2 Ray workers, "
                        "Ray's start-up cost (needs bpy and ray)")
    s.add_argument("--default-fit", action="store_true",
                   help="only the time to answer: the default fit of a 21 x 21 cloth, 4 cameras x 15 frames at "
                        "480 x 640, quality chosen and the manipulation's unknowns estimated (target 3 minutes)")

    s = _command(sub, "identifiability", cmd_identifiability,
                 "which Blender cloth settings silhouettes can identify (sensitivity and Cramer-Rao table)",
                 "the tables as JSON")
    s.add_argument("--materials", help="comma list: default, silk, denim (default: all)")
    s.add_argument("--json", help="also write the tables to this file")

    s = _command(sub, "occlusion", cmd_occlusion,
                 "study: a post and a hand hiding the cloth, as ignore masks vs as background",
                 "the study's table as JSON (the same as --json)")
    s.add_argument("--json", required=True, help="write the study to this JSON file")
    s.add_argument("--out", default="out/occlusion", help="where the three captures are written (default: %(default)s)")
    s.add_argument("--quick", action="store_true", help="240x320, 700 evaluations")
    s.add_argument("--train-cameras", type=int, default=4,
                   help="cameras each fit trains on, by the spread rule (default: %(default)s)")
    s.add_argument("--scales", default="1,1.33,1.67",
                   help="occluder sizes, x (post 15 %% of the cloth width, hand 12 %%) (default: %(default)s)")
    s.add_argument("--truth-dt-safety", type=float, default=None,
                   help="time-step factor of the truth; 0.125 = 4x finer than the fitter: a model mismatch "
                        "(default: the fitter's own)")
    s.add_argument("--max-evaluations", type=int, default=None, help="budget of each fit (default: 2000, --quick 700)")
    s.add_argument("--resolution", help="HxW [px] (default: the rig's 480x640; --quick 240x320)")
    s.add_argument("--seed", type=int, default=0, help="random seed of the captures and fits (default: %(default)s)")

    s = _command(sub, "rig", cmd_rig, "show a rig preset and its training-camera order",
                 "the camera names and their training order as JSON")
    s.add_argument("rig", nargs="?", default=D.DEFAULT_RIG,
                   help="a preset of rigs/ (lab18, lab18_far, ring8) or a cameras JSON (default: %(default)s)")

    extract.add_arguments(_command(sub, "extract", cmd_extract,
                                   "silhouettes from camera images or videos: background difference, automatic "
                                   "threshold, clean-up; writes a capture", "the extraction report as JSON"))
    _calibrate_args(_command(sub, "calibrate", cmd_calibrate,
                             "calibrate cameras from a ChArUco board: intrinsics, distortion and poses, "
                             "world = the board on the table, Z up", "the calibration report as JSON (per camera the "
                             "reprojection RMS, the views used, every view's RMS), or the board written with "
                             "--make-board"))
    calib_io.add_arguments(_command(sub, "import-cameras", cmd_cameras,
                                    "read a calibration (OpenCV YAML/JSON/XML, COLMAP, EasyMocap) into our cameras JSON",
                                    "the command, --out and the camera names as JSON"), "import-cameras")
    calib_io.add_arguments(_command(sub, "export-cameras", cmd_cameras,
                                    "write cameras (ours, a capture's or any calibration) as OpenCV YAML/JSON/XML, "
                                    "OpenCV files per camera or a COLMAP text model",
                                    "the command, --out and the camera names as JSON"), "export-cameras")
    s = _command(sub, "handles", cmd_handles,
                 "the manipulation from footage: marked clips triangulated, tracked, their release found, the "
                 "cloth placed; writes the scenario for extract --scenario",
                 "the report as JSON (per handle: vertex, residual px and mm, track length, release frame; the "
                 "cloth's placement; the uncertain block)")
    s.add_argument("footage", nargs="?", help="footage folder: <camera>/ frames (background* files skipped), optional "
                                              "footage.json (or --videos)")
    s.add_argument("--marks", required=True, help="marks JSON: per handle its pixel in >= 2 cameras at one frame, "
                                                  "'at' on the cloth, motion, released (docs/phone_rig.md, step 6)")
    s.add_argument("--size", required=True, help="the cloth's measured size WIDTHxHEIGHT [m], e.g. 0.30x0.40 (width "
                                                 "= along grid columns, 'at' u; height = rows, 'at' v)")
    s.add_argument("-o", "--out", required=True, help="scenario JSON to write (scenario + uncertain + report)")
    s.add_argument("--grid", help="vertices along the longer side (the other side's makes square cells), or "
                                  "COLUMNSxROWS (default: about 16, chosen so the clips' 'at' fall on vertices)")
    s.add_argument("--cameras", help="calibration: our cameras JSON, OpenCV, COLMAP or EasyMocap (default: the "
                                     "footage's footage.json / cameras.* / calibration.* / COLMAP folder)")
    s.add_argument("--videos", help="folder of videos, one per camera: <camera>.<mp4|mov|mkv|avi>")
    s.add_argument("--sync", help="with --videos: JSON {camera: video time [s] at t = 0} (written with --find-sync)")
    s.add_argument("--find-sync", choices=["flash"], help="with --videos: sync times from a flash every camera sees")
    s.add_argument("--flash-time", type=float, default=0.0, help="capture time [s] of the flash (default: %(default)s)")
    s.add_argument("--times", help="frame times [s], comma separated (default: footage.json's, else --fps)")
    s.add_argument("--fps", type=float, help="frames per second: frame k at START + k / FPS (every image of a folder; "
                                             "with --videos, --frames of them)")
    s.add_argument("--start", type=float, default=0.0, help="with --fps: time [s] of the first frame "
                                                            "(default: %(default)s)")
    s.add_argument("--frames", type=int, help="with --videos --fps: how many frames")
    s.add_argument("--clip-size", type=float, default=D.HANDLE_CLIP_SIZE_M,
                   help="a clip's size [m]: the tracking window is its size in each camera (default: %(default)s; "
                        "'size' per handle in the marks)")
    s.add_argument("--mark-sigma", type=float, default=D.HANDLE_MARK_SIGMA_PX,
                   help="pixel noise of a mark (a click), the floor of each handle's uncertainty (default: %(default)s)")
    s.add_argument("--max-residual", type=float, default=D.HANDLE_MAX_RESIDUAL_PX,
                   help="a camera missing the triangulated point by more [px] is a wrong mark or a drifted track "
                        "(default: %(default)s)")
    s.add_argument("--fb-max", type=float, default=D.HANDLE_FB_MAX_PX,
                   help="forward-backward tracking error [px] beyond which a track is lost (default: %(default)s)")
    s.add_argument("--levels", type=int, default=D.HANDLE_LK_LEVELS,
                   help="Lucas-Kanade pyramid levels (default: %(default)s)")
    s.add_argument("--departure-min", type=float, default=1000.0 * D.HANDLE_DEPARTURE_MIN_M,
                   help="a released handle has left its pin when further than this [mm] (and 6x its held jitter) "
                        "(default: %(default)s)")
    s.add_argument("--max-pin-offset", type=float, default=1000.0 * D.HANDLE_MAX_PIN_OFFSET_M,
                   help="a clip further than this [mm] from its vertex of the placed cloth is an error "
                        "(default: %(default)s)")
    s.add_argument("--smooth", type=int, default=D.HANDLE_SMOOTH_FRAMES,
                   help="moving handles: local quadratic over +-this many frames, 0 = raw (default: %(default)s)")
    s.add_argument("--settle", type=float, default=D.SETTLE_TIME,
                   help="seconds of settling before t = 0 written into the scenario (default: %(default)s)")

    pipeline.add_arguments(_command(sub, "blender", cmd_blender,
                                    "the whole pipeline through Blender (bpy module): rig, cloth, simulate, render "
                                    "silhouettes, fit, overlays, .blend", "a summary of the run as JSON"))
    s = _command(sub, "blender-agreement", cmd_blender_agreement,
                 "the core's blender cloth model vs Blender's own solver, vertex by vertex (bpy module)",
                 "every case's distances as JSON")
    s.add_argument("--grid", type=int, default=21,
                   help="vertices per side of the 10 cm sheet, 2..200 (default: %(default)s)")
    s.add_argument("--settle", type=float, default=1.0,
                   help="seconds hung by four corners before the release (default: %(default)s)")
    s.add_argument("--after", type=float, default=1.5, help="seconds simulated after the release (default: %(default)s)")
    s.add_argument("--fps", type=float, default=24.0, help="scene frame rate [frames/s] (default: %(default)s)")
    s.add_argument("--json", help="also write every figure to this file")
    return p


DEBUG_ENV = "CLOTHFIT_DEBUG"


def _one_line(text, limit=1500):
    text = " ".join(str(text).split())
    return text if len(text) <= limit else text[:limit - 3] + "..."


@contextlib.contextmanager
def _sigint_deferred():
    """Ctrl-C inside waits until the block is done (a result being written is not cut short)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    got = []
    old = signal.signal(signal.SIGINT, lambda *_: got.append(True))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)
    if got and callable(old):
        old(signal.SIGINT, None)


@contextlib.contextmanager
def messages_to_stderr():
    """Inside: whatever the command writes to stdout goes to stderr, at the file-descriptor level too
    (Blender, Ray and other libraries print from C or from threads); the result goes to the real
    stdout afterwards. Without file descriptors (stdout replaced in-process) ``sys.stdout`` alone
    is redirected."""
    try:
        out_fd, err_fd = sys.stdout.fileno(), sys.stderr.fileno()
    except (AttributeError, OSError, ValueError):
        with contextlib.redirect_stdout(sys.stderr):
            yield
        return
    sys.stdout.flush()
    saved = os.dup(out_fd)
    line_buffering = getattr(sys.stdout, "line_buffering", None)
    os.dup2(err_fd, out_fd)
    if line_buffering is False and hasattr(sys.stdout, "reconfigure"):
        sys.stdout.reconfigure(line_buffering=True)      # in order with stderr's lines
    try:
        yield
    finally:
        with contextlib.suppress(OSError, ValueError):
            sys.stdout.flush()
        os.dup2(saved, out_fd)
        os.close(saved)
        if line_buffering is False and hasattr(sys.stdout, "reconfigure"):
            sys.stdout.reconfigure(line_buffering=False)


def _finite(o):
    """NaN and infinities as null: stdout is strict JSON (jq and other parsers refuse NaN)."""
    if isinstance(o, float) and not math.isfinite(o):
        return None
    if isinstance(o, dict):
        return {k: _finite(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_finite(v) for v in o]
    return o


def emit(result):
    """Write a command's result to stdout: text as it is, anything else as one JSON document."""
    if result is None:
        return
    from .core.safeio import json_text
    text = result if isinstance(result, Text) else json_text(_finite(json.loads(json_text(result))), strict=True)
    sys.stdout.write(text.rstrip("\n") + "\n")
    sys.stdout.flush()


def main(argv=None):
    """Run a command (see ``EPILOG`` for stdout and the exit codes). Bad input: one line
    ``error: ...`` and exit code 2; a command line the parser rejects: its usage and exit code 64;
    any other failure: one line naming it and exit code 1 (the traceback only with the environment
    variable CLOTHFIT_DEBUG=1); Ctrl-C: one line and exit code 130."""
    argv = sys.argv[1:] if argv is None else [str(x) for x in argv]
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as e:                    # --help / --version (0) or a usage error (64)
        return e.code if isinstance(e.code, int) else EXIT_USAGE
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    result, code = None, 0
    try:
        with messages_to_stderr():
            result = args.fn(args)
    except Interrupted as e:
        print(f"interrupted: {_one_line(e)}", file=sys.stderr)
        result, code = e.result, EXIT_INTERRUPTED
    except KeyboardInterrupt:
        print(f"interrupted: {args.cmd} stopped", file=sys.stderr)
        return EXIT_INTERRUPTED
    except ClothFitError as e:
        print(f"error: {_one_line(e)}", file=sys.stderr)
        return EXIT_BAD_DATA
    except Exception as e:  # noqa: BLE001 - the last line of defence: never a traceback for the user
        if os.environ.get(DEBUG_ENV):
            raise
        print(f"error: {args.cmd} failed: {type(e).__name__}: {_one_line(e) or 'no message'} "
              f"(set {DEBUG_ENV}=1 for the traceback)", file=sys.stderr)
        return EXIT_FAILURE
    try:
        emit(result)
    except BrokenPipeError:                    # the reader went away (| head): nothing more to say
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    return code
