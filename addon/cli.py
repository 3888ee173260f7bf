"""Command line: ``python -m addon <command> ...`` (no Blender needed except for ``blender-*``).

Commands: synth, fit, evaluate, overlay, paper, tables, bench, occlusion, rig, extract, import-cameras, export-cameras,
blender (the whole pipeline through Blender: needs the bpy module).
Every error from bad input is one line naming the file or value (exit code 2), never a traceback.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

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
    if name is None:
        if any(getattr(a, k, None) is not None for k in ("fps", "quality", "bending_model")):
            name = "blender"
        else:
            return None
    spec = {"name": name}
    if name == "blender":
        for k in ("fps", "quality", "bending_model"):
            if getattr(a, k, None) is not None:
                spec[k] = getattr(a, k)
    elif any(getattr(a, k, None) is not None for k in ("fps", "quality", "bending_model")):
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
    if any(getattr(a, k, None) is not None for k in ("fps", "quality", "bending_model")) or a.model == "paper":
        raise ClothFitError("with --backend blender the scene's Cloth modifier and frame rate define the model: "
                            "drop --model/--fps/--quality/--bending-model")
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
                    restarts=a.restarts)
    for k, v in _backend_args(a).items():
        setattr(cfg, k, v)
    cfg = cfg.checked()
    evaluator = None
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
            job.cancel()
            print("\ncancelled: keeping the best result so far", file=sys.stderr)
        except ClothFitError as e:            # e.g. a worker that died for good: the best so far is kept
            job.error = str(e)
            job.cancel()
        finally:
            bar.done()
            job.save_result(a.out)
            if evaluator is not None:
                evaluator.close()
    r = job.result()
    if job.error:
        raise ClothFitError(f"fit failed: {job.error} (the result so far is in {a.out})")
    keys = ("params", "identifiable") if r.get("params") else ("blender_cloth", "blender_scene")
    print(json.dumps({k: r[k] for k in keys + ("best_E_sil_mean_pct", "evaluations", "stop_reason", "elapsed_s",
                                               "cancelled") if k in r}, indent=1))
    if "identifiable_error_pct" in r:
        print("recovery error [%]:", json.dumps(r["identifiable_error_pct"]))
    if "true_params_ignored" in r:
        print(f"note: {r['true_params_ignored']}", file=sys.stderr)
    print(f"wrote {a.out}")


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
                        model=_model_spec(a))
        configs.append(asdict(cfg))
    os.makedirs(a.out_dir, exist_ok=True)
    t0 = time.time()
    from .farm.tasks import fit_many
    results, kind, workers = fit_many(a.captures, configs, a.workers, a.address, a.executor)
    wall = time.time() - t0
    from .core.fitting.job import _atomic_json
    for i, (c, r) in enumerate(zip(a.captures, results)):
        name = f"{i:03d}_{os.path.basename(os.path.normpath(c))}.json"
        _atomic_json(os.path.join(a.out_dir, name), r)
        print(f"{c}: E_sil {r['best_E_sil_mean_pct']:.3f} % after {r['evaluations']} evaluations -> "
              f"{os.path.join(a.out_dir, name)}")
    print(f"{len(results)} fits on {workers} {kind} worker(s) in {wall:.1f} s")


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
    if a.python:
        print(f"# Blender {model.fps:g} fps scene: set scene.render.fps / fps_base to match")
        print("cloth = bpy.context.object.modifiers['Cloth'].settings")
        for k in ("quality", "bending_model") + B.FLOAT_SETTINGS:
            print(f"cloth.{k} = {s[k]!r}")
    else:
        print(json.dumps(out, indent=1))


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


def cmd_overlay(a):
    from .core.observation.capture import load_capture
    from .core.observation.overlay import capture_overlays
    cap = load_capture(a.capture)
    images = None
    if a.on_images:
        from .core.footage.extract import footage_images
        images = footage_images(cap)
    paths = capture_overlays(cap, _params(a, _capture_truth(cap)), a.out, cameras=_cams(cap, a.cameras),
                             times=_times(a.times), images=images)
    print(f"wrote {len(paths)} images under {a.out} (contact sheet: {paths[-1]})")


def cmd_paper(a):
    from .core.studies.experiment import run_paper
    if a.workers is not None or a.address is not None:
        return _paper_parallel(a)
    run_paper(a.json, quick=a.quick, out_dir=a.out, seed=a.seed, optimizer=a.optimizer,
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


def cmd_tables(a):
    from .core.studies.experiment import format_tables
    try:
        with open(a.json) as f:
            d = json.load(f)
    except (OSError, json.JSONDecodeError) as e:
        raise ClothFitError(f"cannot read {a.json}: {e}") from None
    print(format_tables(d))


def cmd_bench(a):
    from .core.studies.bench import run_bench
    run_bench(a.json, quick=a.quick, only_blender_workers=a.blender_workers)


def cmd_identifiability(a):
    from .core.studies.identifiability import MATERIALS, run
    mats = _names(a.materials)
    bad = [m for m in mats or [] if m not in MATERIALS]
    if bad:
        raise ClothFitError(f"--materials: unknown {', '.join(bad)} (known: {', '.join(MATERIALS)})")
    run(a.json, mats)


def cmd_occlusion(a):
    from .core.studies.occlusion import run_occlusion
    run_occlusion(a.json, out_dir=a.out, quick=a.quick, n_train=a.train_cameras, evaluations=a.max_evaluations,
                  seed=a.seed, resolution=_res(a.resolution), scales=_floats(a.scales, "--scales"),
                  truth_dt_safety=a.truth_dt_safety)


def cmd_rig(a):
    from .core.observation.camera import load_rig, spread_order
    cams = load_rig(a.rig)
    order = spread_order(cams)
    print(f"{len(cams)} cameras; training order (spread rule): {[cams[i].name for i in order]}")


def _model_args(s):
    s.add_argument("--model", choices=["paper", "blender"], default=None,
                   help="cloth model: the paper's sheet or Blender's cloth solver (default: the capture's, else paper)")
    s.add_argument("--fps", type=float, default=None, help="blender: scene frame rate the settings are for (24)")
    s.add_argument("--quality", type=int, default=None, help="blender: solver steps per frame (5)")
    s.add_argument("--bending-model", choices=["ANGULAR", "LINEAR"], default=None, help="blender: bending model")


def build_parser():
    p = argparse.ArgumentParser(prog="python -m addon", description="Silhouette Cloth Fit: cloth parameters from multi-view silhouettes")
    sub = p.add_subparsers(dest="cmd", required=True)

    s = sub.add_parser("synth", help="make a synthetic capture from ground-truth parameters")
    s.add_argument("--out", required=True)
    s.add_argument("--rig", default=D.DEFAULT_RIG)
    s.add_argument("--params", help="JSON or a JSON file with m, k, l, d (default: the built-in ground truth)")
    s.add_argument("--noise", type=float, default=D.NOISE_FRACTION, help="fraction of boundary pixels flipped")
    s.add_argument("--resolution", help="HxW, default: the rig's")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--truth-dt-safety", type=float, default=None, help="time-step factor of the truth (default: the model's)")
    _model_args(s)
    s.set_defaults(fn=cmd_synth)

    s = sub.add_parser("fit", help="fit the model to a capture")
    s.add_argument("capture")
    s.add_argument("--out", default="out/fit.json")
    s.add_argument("--cameras", help="'n:16' (spread rule), indices or names, default all")
    s.add_argument("--times", help="'train', 'test' or comma list of times; default all")
    s.add_argument("--optimizer", default=D.DEFAULT_OPTIMIZER, help="cma-es (default) or spx-mgg (the paper's GA)")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--max-evaluations", type=int, default=None)
    s.add_argument("--population", type=int, default=None, help="optimiser population (GA default 7n = 21, CMA-ES 4 + 3 ln n = 7)")
    s.add_argument("--children", type=int, default=None, help="GA: SPX children per family (default 5n = 15)")
    s.add_argument("--target", type=float, default=None, help="stop when mean E_sil per image falls below this fraction")
    s.add_argument("--resolution", help="fit at HxW (silhouettes area-resampled)")
    s.add_argument("--cloth-mass", type=float, default=None, help="total cloth mass [kg] (fixes m)")
    s.add_argument("--restarts", type=int, default=None,
                   help=f"cma-es: IPOP restarts after convergence, each with twice the population (default: paper "
                        f"{D.FIT_RESTARTS}, blender {D.BLENDER_FIT_RESTARTS})")
    s.add_argument("--checkpoint", help="default: OUT.checkpoint.json; written every few seconds and at the end")
    s.add_argument("--resume", action="store_true",
                   help="continue the checkpoint; refused if it is of another fit (capture, cameras, times, "
                        "resolution, optimiser, population, seed, bounds...); --max-evaluations may grow")
    s.add_argument("--force", action="store_true", help="replace an existing checkpoint instead of refusing")
    s.add_argument("--backend", default="auto", choices=["auto", "numba", "numpy", "core", "blender"],
                   help="where candidates are simulated: the core (auto, numba, numpy; core = auto) or blender "
                        "(Blender's own solver on --blend, in worker processes)")
    s.add_argument("--blend", help="blender backend: the .blend holding the cloth object (colliders and all)")
    s.add_argument("--object", help="blender backend: the cloth object (default: the scene's only mesh with a "
                                    "Cloth modifier)")
    s.add_argument("--frame-zero", type=float, default=None,
                   help="blender backend: scene frame of capture time 0 (default: the scene's frame_start)")
    s.add_argument("--workers", type=int, default=None, help="blender backend: worker processes (default: the cores)")
    s.add_argument("--address", default=None, help="blender backend: a running Ray cluster (auto, ray://host:port); "
                                                   "default: a local Ray instance started for the fit")
    s.add_argument("--executor", default="auto", choices=["auto", "ray", "process"],
                   help="blender backend: Ray actors or spawned processes (auto: Ray when installed)")
    s.add_argument("--quiet", action="store_true")
    _model_args(s)
    s.add_argument("--free", help="blender: comma list of ClothSettings to search (default: see README, "
                                  "Identifiability)")
    s.add_argument("--fixed", help="blender: JSON (or file) of ClothSettings held fixed")
    s.add_argument("--bounds", help="JSON (or file) {name: [low, high]} search ranges (blender: Blender units at "
                                    "the fixed vertex mass)")
    s.add_argument("--init", help="warm start from this result JSON (a blender or paper fit)")
    s.set_defaults(fn=cmd_fit)

    s = sub.add_parser("fit-many", help="fit many captures in parallel (Ray actors, or processes without Ray)")
    s.add_argument("captures", nargs="+")
    s.add_argument("--out-dir", default="out/fits")
    s.add_argument("--cameras")
    s.add_argument("--times")
    s.add_argument("--optimizer", default=D.DEFAULT_OPTIMIZER)
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--max-evaluations", type=int, default=None)
    s.add_argument("--population", type=int, default=None)
    s.add_argument("--resolution")
    s.add_argument("--cloth-mass", type=float, default=None)
    s.add_argument("--workers", type=int, default=None, help="worker processes (default: the cores)")
    s.add_argument("--address", default=None, help="a running Ray cluster (auto, ray://host:port)")
    s.add_argument("--executor", default="auto", choices=["auto", "ray", "process"])
    _model_args(s)
    s.set_defaults(fn=cmd_fit_many)

    s = sub.add_parser("export-blender-cloth", help="the Cloth modifier settings of a blender-model fit result")
    s.add_argument("result")
    s.add_argument("--python", action="store_true", help="print bpy assignments instead of JSON")
    s.set_defaults(fn=cmd_export_blender_cloth)

    s = sub.add_parser("evaluate", help="silhouette and shape error of parameters on a capture")
    s.add_argument("capture")
    s.add_argument("--params", help="result JSON file, or JSON with m, k, l, d (default ground truth)")
    s.add_argument("--cameras")
    s.add_argument("--times")
    s.add_argument("--resolution")
    s.add_argument("--json")
    s.set_defaults(fn=cmd_evaluate)

    s = sub.add_parser("overlay", help="observed vs model silhouette images and a contact sheet")
    s.add_argument("capture")
    s.add_argument("--params")
    s.add_argument("--out", default="out/overlays")
    s.add_argument("--cameras")
    s.add_argument("--times")
    s.add_argument("--on-images", action="store_true",
                   help="draw on the camera images the silhouettes were extracted from (image footage)")
    s.set_defaults(fn=cmd_overlay)

    s = sub.add_parser("paper", help="the paper's Table 1, Fig. 8 and Table 2 protocol")
    s.add_argument("--json", required=True)
    s.add_argument("--out", default="out/paper")
    s.add_argument("--quick", action="store_true")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--optimizer", default=None)
    s.add_argument("--max-evaluations", type=int, default=None)
    s.add_argument("--only", default=None, help="comma list of parts: table1, fig8, table2, optimizers")
    s.add_argument("--population", type=int, default=None, help="optimiser population (GA: MGG population)")
    s.add_argument("--children", type=int, default=None, help="GA: SPX children per family")
    s.add_argument("--rig", default=None, help="camera rig preset (default lab18)")
    s.add_argument("--workers", type=int, default=None,
                   help="run the parts (table1, fig8, table2, optimizers) in parallel on this many workers")
    s.add_argument("--address", default=None, help="run the parts on a running Ray cluster (auto, ray://host:port)")
    s.add_argument("--executor", default="auto", choices=["auto", "ray", "process"])
    s.add_argument("--truth-dt-safety", type=float, default=None,
                   help="time-step factor of the ground truth (default: the model's own; 0.125 = 4x finer truth, "
                        "i.e. a model mismatch the fit cannot remove)")
    s.set_defaults(fn=cmd_paper)

    s = sub.add_parser("tables", help="print the tables of a `paper` JSON again")
    s.add_argument("json")
    s.set_defaults(fn=cmd_tables)

    s = sub.add_parser("bench", help="speed figures")
    s.add_argument("--json", required=True)
    s.add_argument("--quick", action="store_true")
    s.add_argument("--blender-workers", action="store_true",
                   help="only Blender's solver as the fit's evaluator: evaluations/s with 1 and 2 Ray workers, "
                        "Ray's start-up cost (needs bpy and ray)")
    s.set_defaults(fn=cmd_bench)

    s = sub.add_parser("identifiability", help="which Blender cloth settings silhouettes can identify "
                                               "(sensitivity and Cramer-Rao table)")
    s.add_argument("--materials", help="comma list: default, silk, denim (default: all)")
    s.add_argument("--json", help="write the tables to this file")
    s.set_defaults(fn=cmd_identifiability)

    s = sub.add_parser("occlusion", help="study: a post and a hand hiding the cloth, as ignore masks vs as background")
    s.add_argument("--json", required=True)
    s.add_argument("--out", default="out/occlusion", help="where the three captures are written")
    s.add_argument("--quick", action="store_true", help="240x320, 700 evaluations")
    s.add_argument("--train-cameras", type=int, default=4)
    s.add_argument("--scales", default="1,1.33,1.67", help="occluder sizes (x post 15 %% of the cloth width, hand 12 %%)")
    s.add_argument("--truth-dt-safety", type=float, default=None,
                   help="time-step factor of the truth (0.125 = 4x finer than the fitter: a model mismatch)")
    s.add_argument("--max-evaluations", type=int, default=None)
    s.add_argument("--resolution", help="HxW (default: the rig's 480x640; --quick 240x320)")
    s.add_argument("--seed", type=int, default=0)
    s.set_defaults(fn=cmd_occlusion)

    s = sub.add_parser("rig", help="show a rig preset and its training-camera order")
    s.add_argument("rig", nargs="?", default=D.DEFAULT_RIG)
    s.set_defaults(fn=cmd_rig)

    # listed for --help only: main() hands these their whole argv before this parser runs
    for nm, hlp in SUBTOOLS.items():
        sub.add_parser(nm, help=hlp, add_help=False)
    return p


SUBTOOLS = {"extract": "silhouettes from camera images (see `extract --help`)",
            "import-cameras": "camera calibration files in (OpenCV YAML/JSON/XML, COLMAP)",
            "export-cameras": "camera calibration files out (OpenCV YAML/JSON/XML, COLMAP)",
            "blender": "the whole pipeline through Blender (bpy module): see `blender --help`",
            "blender-agreement": "the core's blender cloth model vs Blender's own solver, vertex by vertex (bpy module)"}


def run_subtool(argv):
    """Sub-tools with parsers of their own get everything after the command name."""
    if argv[0] == "blender":
        # build rig and cloth, simulate, render silhouettes with Blender, fit, overlays, save a .blend
        from .blender import pipeline
        return int(pipeline.main(argv[1:]) or 0)
    if argv[0] == "blender-agreement":
        from .blender import agreement
        return int(agreement.main(argv[1:]) or 0)
    if argv[0] == "extract":
        from .core.footage import extract
        extract.main(argv[1:])
    else:
        from .core.footage import calib_io
        calib_io.main(argv)
    return 0


DEBUG_ENV = "CLOTHFIT_DEBUG"


def _one_line(text, limit=1500):
    text = " ".join(str(text).split())
    return text if len(text) <= limit else text[:limit - 3] + "..."


def main(argv=None):
    """Run a command. Bad input: one line ``error: ...`` and exit code 2; any other failure: one
    line naming it and exit code 1 (the traceback only with the environment variable
    CLOTHFIT_DEBUG=1); Ctrl-C: exit code 130."""
    argv = sys.argv[1:] if argv is None else list(argv)
    try:
        if argv and argv[0] in SUBTOOLS:
            return run_subtool(argv)
        args = build_parser().parse_args(argv)
        args.fn(args)
    except ClothFitError as e:
        print(f"error: {_one_line(e)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("\ninterrupted", file=sys.stderr)
        return 130
    except Exception as e:  # noqa: BLE001 - the last line of defence: never a traceback for the user
        if os.environ.get(DEBUG_ENV):
            raise
        cmd = argv[0] if argv else "?"
        print(f"error: {cmd} failed: {type(e).__name__}: {_one_line(e) or 'no message'} "
              f"(set {DEBUG_ENV}=1 for the traceback)", file=sys.stderr)
        return 1
    return 0
