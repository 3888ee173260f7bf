"""The fitting commands: synth, fit, fit-many, export-blender-cloth, evaluate, overlay, floor."""

from __future__ import annotations

import os
import sys
import time

from ..core import defaults as D
from ..core.errors import ClothFitError
from ..core.fitting.result import interval_lines
from .common import (
    Interrupted,
    add_command,
    camera_selection,
    capture_truth,
    farm_args,
    force_arg,
    json_arg,
    model_args,
    model_spec,
    name_list,
    params_arg,
    refuse_existing,
    refuse_filled_folder,
    res,
    search_args,
    selection_args,
    sigint_deferred,
    time_selection,
)
from .export import add_export
from .progress import fit_progress, progress_interval
from .synth import add_synth


def _scene_evaluator(cfg):
    """The workers of a ``--backend blender`` fit (Blender's own solver on ``cfg.blend``)."""
    from ..farm.scene import BlendSceneEvaluator

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
    if (
        any(getattr(a, k, None) is not None for k in ("fps", "bending_model"))
        or a.model == "paper"
        or getattr(a, "quality", None) not in (None, "auto")
    ):
        raise ClothFitError(
            "with --backend blender the scene's Cloth modifier and frame rate define the model: "
            "drop --model/--fps/--quality N/--bending-model (--quality auto lets the fit choose)"
        )
    if a.workers is not None and a.workers < 1:
        raise ClothFitError(f"--workers {a.workers}: must be at least 1")
    return {
        "backend": "auto",
        "evaluator": "blender",
        "blend": a.blend,
        "blend_object": a.object,
        "frame_zero": a.frame_zero,
        "workers": a.workers,
        "address": a.address,
        "executor": a.executor,
    }


def _refuse_overwriting_inputs(out, capture, what):
    """An output must not replace the capture's own files."""
    real = os.path.realpath(out)
    root = os.path.realpath(capture.root)
    inputs = {os.path.realpath(os.path.join(root, n)) for n in ("capture.json", "cameras.json", "shapes.npz")}
    if real in inputs or real == root:
        raise ClothFitError(
            f"{what} {out} would overwrite the capture's own {os.path.basename(real)}: choose another path"
        )


def _checkpoint_summary(ck):
    from ..core.fitting.job import read_checkpoint

    try:
        d = read_checkpoint(ck)
    except ClothFitError as e:
        return f"an unreadable checkpoint ({e})"
    r = d.get("result") if isinstance(d.get("result"), dict) else {}
    state = "a finished" if d.get("finished") else "an unfinished"
    return f"the checkpoint of {state} fit ({r.get('evaluations', '?')} evaluations)"


def fit_config(a, cap):
    """The FitConfig of ``fit`` and ``fit-many`` (``cap``: a capture, or the takes of a fit of several: each
    take's cameras and times chosen in it)."""
    if isinstance(cap, (list, tuple)):
        cfg = _fit_config(a, cap[0])
        cams, times = [camera_selection(c, a.cameras) for c in cap], [time_selection(a.times, c) for c in cap]
        cfg.train_cameras = None if all(c is None for c in cams) else cams
        cfg.train_times = None if all(t is None for t in times) else times
        return cfg
    return _fit_config(a, cap)


def _fit_config(a, cap):
    """The FitConfig of ``fit`` and ``fit-many`` from their parsed options (one rule for both; not yet
    checked: ``fit`` adds its backend first). An option the command does not declare keeps FitConfig's
    default. ``--max-evaluations``: not given = D.FIT_EVALUATIONS; any number given is the budget as it
    is, so 0 is refused by ``FitConfig.checked`` (bad data, exit 2), in ``fit`` and ``fit-many`` alike."""
    from ..core.fitting.job import FitConfig

    kw = dict(
        train_cameras=camera_selection(cap, a.cameras),
        train_times=time_selection(a.times, cap),
        optimizer=a.optimizer,
        seed=a.seed,
        max_evaluations=D.FIT_EVALUATIONS if a.max_evaluations is None else a.max_evaluations,
        resolution=res(a.resolution),
        cloth_mass=a.cloth_mass,
        population=a.population,
        searches=getattr(a, "searches", None),
    )
    backend = getattr(a, "backend", None)
    if backend is not None:
        kw["backend"] = backend
    kw["model"] = None if backend == "blender" else model_spec(a)
    if hasattr(a, "free"):  # fit's own options (fit-many keeps FitConfig's defaults)
        kw.update(
            children=a.children,
            target_error=a.target,
            free=name_list(a.free),
            fixed=json_arg(a.fixed, "--fixed"),
            init=a.init,
            bounds=json_arg(a.bounds, "--bounds"),
            restarts=a.restarts,
        )
    kw.update(quality="auto" if a.quality == "auto" else None, uncertain=a.uncertain)
    kw.update(intervals=getattr(a, "intervals", True))
    kw.update(search_options(getattr(a, "search", None) or []))
    return FitConfig(**kw)


def search_options(items):
    """``--search NAME=VALUE`` (repeatable) -> FitConfig's search options; values are numbers or
    true/false (checked with the config: ``FitConfig.checked``)."""
    from ..core.fitting.config import SEARCH_OPTIONS

    out = {}
    for item in items:
        name, sep, text = item.partition("=")
        name = name.strip()
        if not sep or name not in SEARCH_OPTIONS:
            raise ClothFitError(f"--search {item}: give NAME=VALUE with NAME one of {', '.join(SEARCH_OPTIONS)}")
        text = text.strip().lower()
        if text in ("true", "on", "yes", "false", "off", "no"):
            out[name] = text in ("true", "on", "yes")
            continue
        try:
            value = float(text)
        except ValueError:
            raise ClothFitError(f"--search {item}: the value must be a number or true/false") from None
        out[name] = int(value) if value.is_integer() and "." not in text and "e" not in text else value
    return out


def cmd_fit(a):
    from ..core.fitting.job import FitJob, exclusive_lock, read_checkpoint
    from ..core.observation.capture import load_capture

    ck = a.checkpoint or (a.out + ".checkpoint.json")
    if a.resume and a.force:
        raise ClothFitError("--resume continues the checkpoint and --force replaces it: give one of them")
    if os.path.realpath(ck) == os.path.realpath(a.out):
        raise ClothFitError(f"--checkpoint and --out are the same file {a.out}")
    for path, what in ((a.out, "--out"), (ck, "checkpoint")):
        if os.path.isdir(path):
            raise ClothFitError(f"{what} {path} is a directory: give a file name")
    if not a.resume and not a.force and os.path.lexists(a.out) and not os.path.lexists(ck):
        raise ClothFitError(f"--out {a.out} exists (its checkpoint {ck} is gone): --force overwrites it")
    caps = [load_capture(c) for c in a.captures]
    for c in caps:
        _refuse_overwriting_inputs(a.out, c, "--out")
        _refuse_overwriting_inputs(ck, c, "--checkpoint")
    cap = caps[0] if len(caps) == 1 else caps
    cfg = fit_config(a, cap)
    for k, v in _backend_args(a).items():
        setattr(cfg, k, v)
    cfg = cfg.checked()
    evaluator = None
    interrupted = False
    with exclusive_lock(ck):
        if a.resume and not os.path.lexists(ck):
            raise ClothFitError(f"--resume: there is no checkpoint {ck} to continue (run without --resume to start)")
        if not a.resume and os.path.lexists(ck) and not a.force:
            raise ClothFitError(
                f"{ck} holds {_checkpoint_summary(ck)}: continue it with --resume, replace it "
                f"with --force, or choose another --out"
            )
        if cfg.evaluator == "blender":
            evaluator = _scene_evaluator(cfg)
        try:
            if a.resume:
                if a.max_evaluations is None:  # the budget the checkpointed fit was given
                    saved = read_checkpoint(ck)["config"].get("max_evaluations")
                    if isinstance(saved, int) and not isinstance(saved, bool) and saved >= 1:
                        cfg.max_evaluations = saved
                job = FitJob.resume(
                    ck, capture=cap, config=cfg, checkpoint_interval=D.CHECKPOINT_INTERVAL_S, evaluator=evaluator
                )
                print(f"resumed {ck} at {job.evaluations} evaluations", file=sys.stderr)
            else:
                job = FitJob(cap, cfg, checkpoint=ck, checkpoint_interval=D.CHECKPOINT_INTERVAL_S, evaluator=evaluator)
        except BaseException:
            if evaluator is not None:
                evaluator.close()
            raise
        if getattr(job.par, "fps_source", None):  # a blender-model fit: the scene frame rate its settings are for
            print(f"frame rate {job.par.model.fps:g} fps ({job.par.fps_source})", file=sys.stderr)
            for t in job.takes[1:]:
                print(f"  take {t.name}: {t.fps:g} fps ({t.fps_source})", file=sys.stderr)
        bar = fit_progress(job, a.quiet)
        try:
            job.run(callback=bar)
        except KeyboardInterrupt:
            interrupted = True
            with sigint_deferred():  # a second Ctrl-C must not lose the result being written
                job.cancel()
        except ClothFitError as e:  # e.g. a worker that died for good: the best so far is kept
            job.state.error = str(e)
            job.cancel()
        finally:
            if bar is not None:
                bar.done(job)
            with sigint_deferred():
                job.save_result(a.out)
            if evaluator is not None:
                evaluator.close()
    r = job.result()
    if job.state.error:
        raise ClothFitError(f"fit failed: {job.state.error} (the result so far is in {a.out})")
    keys = ("params", "identifiable") if r.get("params") else ("blender_cloth", "blender_scene")
    summary = {
        k: r[k]
        for k in keys
        + (
            "identifiable_error_pct",
            "best_E_sil_mean_pct",
            "evaluations",
            "stop_reason",
            "elapsed_s",
            "cancelled",
            "quality_choice",
            "time_offset_s",
            "time_scale",
            "floor",
            "verdict_kind",
            "verdict",
        )
        if k in r
    }
    summary.update(out=a.out, checkpoint=ck)
    _fit_report(r)
    if "identifiable_error_pct" in r:
        print(
            "recovery error [%]: "
            + ", ".join(f"{k} {v:.3g}" for k, v in r["identifiable_error_pct"].items() if v is not None)
        )
    if "true_params_ignored" in r:
        print(f"note: {r['true_params_ignored']}")
    if interrupted:
        raise Interrupted(f"the best result so far ({r['evaluations']} evaluations) is in {a.out}", summary)
    print(f"wrote {a.out}")
    return summary


def _manipulation_report(r, pad=""):
    """The fitted manipulation's lines for people (stderr), each after ``pad``."""
    if "time_offset_s" in r or r.get("manipulation_note"):
        t = r.get("time_offset_s")
        u = r.get("time_offset_uncertainty_s")
        flat = set(r.get("not_separated") or [])  # kept for the replay, not measurements
        if t is not None:
            tail = " (not separated)" if "time_offset_s" in flat else f" (+-{1000 * u:.1f} ms)" if u else ""
            print(f"{pad}time offset {1000 * t:+.1f} ms{tail}", file=sys.stderr)
        if r.get("time_scale") is not None:
            tail = " (not separated)" if "log_time_scale" in flat else ""
            print(f"{pad}time scale {r['time_scale']:.4g} (the capture's clock stretched){tail}", file=sys.stderr)
        for k, h in enumerate(r.get("handles") or []):
            if h.get("offset_bound_m"):
                loose = [f"handle{k}_{ax}" in flat for ax in "xyz"]
                shown = [f"{1000 * v:+.2f}" + ("?" if q else "") for v, q in zip(h["offset_m"], loose)]
                print(
                    f"{pad}handle {k} (vertex {h['vertex']}) moved by {', '.join(shown)} mm"
                    + (" (?: not separated)" if any(loose) else ""),
                    file=sys.stderr,
                )
        if r.get("manipulation_note"):
            print(f"{pad}note: {r['manipulation_note']}", file=sys.stderr)


def _fit_report(r):
    """The result's lines for people (stderr): quality chosen, manipulation, the floor, its warning and
    the verdict."""
    qc = r.get("quality_choice")
    if qc:
        tried = ", ".join(f"{t['quality']}: {t['train_E_sil_pct']:.3f} %" for t in qc["tried"])
        print(f"quality {qc['chosen']} ({qc['rule']}; tried {tried})", file=sys.stderr)
        if qc.get("advice"):
            print(f"note: {qc['advice']}", file=sys.stderr)
    _manipulation_report(r)
    for e in r.get("takes") or []:  # several takes: each take's own errors, verdict and manipulation
        fl = e.get("floor") or {}
        line = f"take {e['take']}"
        if fl.get("train_floor_pct") is not None:
            line += f": training {fl['train_E_sil_pct']:.3f} % (floor {fl['train_floor_pct']:.3f} %)"
        if fl.get("heldout_E_sil_pct") is not None:
            line += f", held-out {fl['heldout_E_sil_pct']:.3f} % (floor {fl['heldout_floor_pct']:.3f} %)"
        if e.get("alone_E_sil_pct") is not None:
            line += f"; searched alone {e['alone_E_sil_pct']:.3f} % training"
        print(line, file=sys.stderr)
        _manipulation_report(e, "  ")
        if e.get("verdict"):
            print(f"  verdict: {e['verdict']}", file=sys.stderr)
    for k, line in enumerate(interval_lines(r)):
        print(line if k == 0 else f"  {line}", file=sys.stderr)
    fl = r.get("floor") or {}
    if fl.get("train_floor_pct") is not None:
        line = f"training E_sil {fl['train_E_sil_pct']:.3f} % (floor {fl['train_floor_pct']:.3f} %)"
        if fl.get("heldout_E_sil_pct") is not None:
            line += f"; held-out {fl['heldout_E_sil_pct']:.3f} % (floor {fl['heldout_floor_pct']:.3f} %)"
        print(line, file=sys.stderr)
    if fl.get("warning"):
        print(f"warning: {fl['warning']}", file=sys.stderr)
    if r.get("verdict"):
        print(f"verdict: {r['verdict']}", file=sys.stderr)


def _fit_many_path(out_dir, i, capture):
    return os.path.join(out_dir, f"{i:03d}_{os.path.basename(os.path.normpath(capture))}.json")


def cmd_fit_many(a):
    from dataclasses import asdict

    from ..core.observation.capture import load_capture

    if a.workers is not None and a.workers < 1:
        raise ClothFitError(f"--workers {a.workers}: must be at least 1")
    configs = []
    for c in a.captures:
        cap = load_capture(c)  # bad captures fail here, before any worker starts
        cfg = fit_config(a, cap).checked()  # a bad option fails here too, before any worker
        configs.append(asdict(cfg))
    paths = [_fit_many_path(a.out_dir, i, c) for i, c in enumerate(a.captures)]
    for path in paths:
        refuse_existing(path, a.force, "result")
    os.makedirs(a.out_dir, exist_ok=True)
    t0 = time.time()
    from ..farm.tasks import fit_many

    every = None if a.quiet else progress_interval()
    results, kind, workers = fit_many(a.captures, configs, a.workers, a.address, a.executor, every)
    wall = time.time() - t0
    from ..core.jsonio import write_json

    fits = []
    for c, r, path in zip(a.captures, results, paths):
        write_json(path, r, strict=True)
        print(f"{c}: E_sil {r['best_E_sil_mean_pct']:.3f} % after {r['evaluations']} evaluations -> {path}")
        fits.append(
            {
                "capture": c,
                "out": path,
                "best_E_sil_mean_pct": r["best_E_sil_mean_pct"],
                "evaluations": r["evaluations"],
                "stop_reason": r.get("stop_reason"),
                "verdict_kind": r.get("verdict_kind"),
                "verdict": r.get("verdict"),
            }
        )
        if r.get("verdict"):
            print(f"  verdict: {r['verdict']}", file=sys.stderr)
    print(f"{len(results)} fits on {workers} {kind} worker(s) in {wall:.1f} s")
    return {"fits": fits, "workers": workers, "executor": kind, "wall_s": wall}


def cmd_evaluate(a):
    from ..core.fitting.evaluate import evaluate
    from ..core.observation.capture import load_capture

    refuse_existing(a.json, a.force, "--json")
    cap = load_capture(a.capture)
    params = params_arg(a, capture_truth(cap))
    elsewhere = bool(a.unknowns_cameras or a.unknowns_times)  # either implies --fit-unknowns
    r = evaluate(
        cap,
        params,
        cameras=camera_selection(cap, a.cameras),
        times=time_selection(a.times, cap),
        resolution=res(a.resolution),
        fit_unknowns=a.fit_unknowns or (D.HELD_UNKNOWNS_EVALUATIONS if elsewhere else 0),
        unknowns_on=(camera_selection(cap, a.unknowns_cameras), time_selection(a.unknowns_times, cap))
        if elsewhere
        else None,
    )
    if r["exploded"]:
        raise ClothFitError(f"the {r['model']['name']} model with these parameters explodes: no silhouette to score")
    s = f"silhouette error {r['silhouette_error_pct']:.3f} % over {len(r['cameras'])} cameras x {len(r['times'])} frames"
    if "shape_error_mm" in r:
        s += f"; shape error {r['shape_error_mm']:.3f} mm"
    print(s)
    rate = f"; simulated at {r['model']['fps']:g} fps" if r["model"].get("fps") else ""
    print(f"manipulation: {r['manipulation']}{rate}", file=sys.stderr)
    if isinstance(params, dict) and params.get("floor"):  # a fit's result: its own verdict beside the new errors
        from ..core.fitting.verdict import verdict

        r["fit_verdict_kind"], r["fit_verdict"] = verdict(params)
        print(f"the fit's verdict (on the takes it fitted): {r['fit_verdict']}", file=sys.stderr)
    if a.json:
        from ..core.jsonio import write_json

        write_json(a.json, r)
    return r


def cmd_verdict(a):
    from ..core.fitting.result import FitResult
    from ..core.fitting.verdict import verdict

    out = []
    for path in a.results:
        kind, line = verdict(FitResult.from_json(path, "fit result", need_parameters=False))
        print(f"{path}: {line}", file=sys.stderr)
        out.append({"result": path, "verdict_kind": kind, "verdict": line})
    return {"verdicts": out}


def _capture_floor(cap, cams, times, resolution):
    from ..core.observation.floor import capture_floor

    fidx = None if times is None else [cap.frame_index(t) for t in times]
    return capture_floor(cap, cams, fidx, resolution)


def cmd_floor(a):
    from ..core.observation.capture import load_capture

    refuse_existing(a.json, a.force, "--json")
    cap = load_capture(a.capture)
    cf = _capture_floor(cap, camera_selection(cap, a.cameras), time_selection(a.times, cap), res(a.resolution))
    d = cf.to_dict()
    print(
        f"noise floor {100 * d['floor']:.3f} % E_sil per image (median {100 * d['floor_median']:.3f} %; "
        f"resampling {100 * d['resampling']:.3f} %"
        + (f"; splatting the points {100 * d['splat']:.3f} %" if d["splat"] > 0 else "")
        + f") over {d['n_images']} images; a 1-pixel shift of the outline "
        f"costs {100 * d['rim']:.2f} %; {cf.limits}"
    )
    if a.json:
        from ..core.jsonio import write_json

        write_json(a.json, d)
    return d


def cmd_overlay(a):
    from ..core.observation.capture import load_capture
    from ..core.observation.overlay import capture_overlays

    refuse_filled_folder(a.out, a.force)
    cap = load_capture(a.capture)
    images = None
    if a.on_images:
        from ..core.footage.extract import footage_images

        images = footage_images(cap)
    cams, times = camera_selection(cap, a.cameras), time_selection(a.times, cap)
    floors = None
    if a.floor:
        floors = _capture_floor(cap, cams, times, None).per_image()
    from ..core.fitting.evaluate import for_take

    params, how = for_take(cap, params_arg(a, capture_truth(cap)))
    print(f"manipulation: {how}", file=sys.stderr)
    paths = capture_overlays(
        cap, params, a.out, cameras=cams, times=times, images=images, floors=floors, legend=interval_lines(params)
    )
    print(f"wrote {len(paths)} images under {a.out} (contact sheet: {paths[-1]})")
    out = {"out": a.out, "images": paths[:-1], "contact_sheet": paths[-1]}
    if a.floor:
        out["images"], out["floor_sheet"] = paths[:-2], paths[-2]
    return out


def _add_fit(sub):
    """``fit``: one capture, checkpointed, resumable."""
    s = add_command(
        sub,
        "fit",
        cmd_fit,
        "fit the model to a capture",
        "a summary of the fit as JSON (params, errors, evaluations, stop_reason, out); the whole result is in --out",
    )
    s.add_argument(
        "captures",
        nargs="+",
        metavar="TAKE",
        help="capture folder (capture.json, cameras.json, silhouettes); several: takes of one cloth, fitted "
        "together (one set of settings; each take its own cameras, frame rate and manipulation's unknowns)",
    )
    s.add_argument("--out", default="out/fit.json", help="result JSON to write (default: %(default)s)")
    selection_args(s, "fit")
    search_args(s)
    s.add_argument("--children", type=int, default=None, help="GA: SPX children per family (default: 5n = 15)")
    s.add_argument(
        "--target",
        type=float,
        default=None,
        help="stop when the mean E_sil per training image falls below this fraction, e.g. 0.005 = "
        "0.5 %% (default: no target)",
    )
    s.add_argument(
        "--restarts",
        type=int,
        default=None,
        help=f"cma-es: IPOP restarts after convergence, each with twice the population (default: paper "
        f"{D.FIT_RESTARTS}, blender {D.BLENDER_FIT_RESTARTS})",
    )
    s.add_argument(
        "--checkpoint",
        help=f"checkpoint file, written every {D.CHECKPOINT_INTERVAL_S:g} s and at the end "
        f"(default: OUT.checkpoint.json)",
    )
    again = s.add_mutually_exclusive_group()
    again.add_argument(
        "--resume",
        action="store_true",
        help="continue the checkpoint; refused if it is of another fit (capture, cameras, times, "
        "resolution, optimiser, population, seed, bounds...); --max-evaluations may grow",
    )
    again.add_argument(
        "--force", action="store_true", help="replace an existing result (--out) and checkpoint instead of refusing"
    )
    s.add_argument(
        "--backend",
        default="auto",
        choices=["auto", "numba", "numpy", "core", "blender"],
        help="where candidates are simulated: the core (auto, numba, numpy; core = auto) or blender "
        "(Blender's own solver on --blend, in worker processes) (default: %(default)s)",
    )
    s.add_argument("--blend", help="blender backend: the .blend holding the cloth object (colliders and all)")
    s.add_argument(
        "--object", help="blender backend: the cloth object (default: the scene's only mesh with a Cloth modifier)"
    )
    s.add_argument(
        "--frame-zero",
        type=float,
        default=None,
        help="blender backend: scene frame of capture time 0 (default: the scene's frame_start)",
    )
    farm_args(s, "blender backend")
    s.add_argument(
        "--quiet",
        action="store_true",
        help="no progress on stderr (a bar on a terminal or with CLOTHFIT_PROGRESS=1, else a line "
        f"every {D.PROGRESS_INTERVAL_S:g} s)",
    )
    model_args(s)
    s.add_argument(
        "--free",
        help="blender model: comma list of ClothSettings to search (default: the stiffnesses (compression with ANGULAR bending only), the "
        "tension, shear and bending damping and the air damping; why those: docs/models.md)",
    )
    s.add_argument(
        "--fixed",
        help="blender model: JSON (or file) of ClothSettings held fixed (default: Blender's "
        "defaults for the settings not searched)",
    )
    s.add_argument(
        "--bounds",
        help="JSON (or file) {name: [low, high]} search ranges; blender: Blender units at "
        "the fixed vertex mass (default: the model's ranges)",
    )
    s.add_argument("--init", help="warm start from this result JSON, a blender or paper fit (default: a cold start)")


def _add_fit_many(sub):
    """``fit-many``: many captures on the farm."""
    s = add_command(
        sub,
        "fit-many",
        cmd_fit_many,
        "fit many captures in parallel (Ray actors, or processes without Ray)",
        "one summary per fit (capture, out, E_sil, evaluations) and the workers used, as JSON",
    )
    s.add_argument("captures", nargs="+", help="capture folders")
    s.add_argument(
        "--out-dir",
        default="out/fits",
        help="folder for one result JSON per capture, NNN_<capture>.json (default: %(default)s)",
    )
    force_arg(s, "result files already in --out-dir")
    selection_args(s, "fit")
    search_args(s)
    farm_args(s, "the fits")
    model_args(s)
    s.add_argument(
        "--quiet",
        action="store_true",
        help=f"no progress lines on stderr (each fit: a line every {D.PROGRESS_INTERVAL_S:g} s, named by its capture)",
    )


def _add_scoring(sub):
    """``export-blender-cloth``, ``evaluate``, ``overlay``, ``floor``: reading a fit back."""
    add_export(sub)

    s = add_command(
        sub,
        "verdict",
        cmd_verdict,
        "the one-line verdict of fit results: at the floor, settings undetermined or at their bounds, far above it",
        "one verdict per result (verdict_kind, verdict) as JSON",
    )
    s.add_argument("results", nargs="+", help="result JSON files of fits")

    s = add_command(
        sub,
        "evaluate",
        cmd_evaluate,
        "silhouette and shape error of parameters on a capture",
        "the errors as JSON: mean, per camera and per time (silhouette [%], shape [mm] when the "
        "capture has its true shapes)",
    )
    s.add_argument("capture", help="capture folder")
    s.add_argument(
        "--params",
        help="a result JSON file, or JSON with m, k, l, d (default: a synthetic capture's "
        "truth, else the built-in ground truth)",
    )
    selection_args(s, "score")
    s.add_argument("--resolution", help="score at HxW [px] (default: the capture's)")
    s.add_argument(
        "--fit-unknowns",
        type=int,
        nargs="?",
        const=D.HELD_UNKNOWNS_EVALUATIONS,
        default=0,
        metavar="N",
        help="a take the result never saw: fit the unknowns its capture declares (time offset, handle offsets) on "
        f"the images scored, the settings held, in N evaluations (default N: {D.HELD_UNKNOWNS_EVALUATIONS}; "
        "without the option: its declared manipulation as it is)",
    )
    s.add_argument(
        "--unknowns-cameras",
        help="with a take the result never saw: fit its unknowns on these cameras instead of the scored ones (as "
        "--cameras; implies --fit-unknowns): score the held-out cameras of a take with unknowns fitted on others",
    )
    s.add_argument(
        "--unknowns-times",
        help="the same for frame times (as --times; implies --fit-unknowns): e.g. fit on 'even', score 'odd'",
    )
    s.add_argument("--json", help="also write the result to this file")
    force_arg(s, "--json")

    s = add_command(
        sub,
        "overlay",
        cmd_overlay,
        "observed vs model silhouette images and a contact sheet",
        "the image paths as JSON",
    )
    s.add_argument("capture", help="capture folder")
    s.add_argument(
        "--params",
        help="a result JSON file, or JSON with m, k, l, d (default: a synthetic capture's "
        "truth, else the built-in ground truth)",
    )
    s.add_argument(
        "--out",
        default="out/overlays",
        help="folder for the images, <camera>/<frame>.png and contact_sheet.png; new or empty unless --force "
        "(default: %(default)s)",
    )
    force_arg(s, "images already in --out")
    selection_args(s, "draw")
    s.add_argument(
        "--on-images",
        action="store_true",
        help="draw on the camera images the silhouettes were extracted from (image footage)",
    )
    s.add_argument(
        "--floor",
        action="store_true",
        help="estimate each image's noise floor (see the floor command), frame the contact sheet's tiles "
        "by E_sil / floor (green at it, amber above, red more than 2x) and write floor_sheet.png",
    )

    s = add_command(
        sub,
        "floor",
        cmd_floor,
        "estimate the noise floor of a capture's silhouettes from the silhouettes",
        "the capture's floor, its parts and the per-image floors as JSON",
    )
    s.add_argument("capture", help="capture folder")
    selection_args(s, "estimate")
    s.add_argument(
        "--resolution",
        help="for a fit at HxW [px]: the silhouettes area-resampled as the fitter does (default: the capture's)",
    )
    s.add_argument("--json", help="also write the result to this file")
    force_arg(s, "--json")


def register(sub):
    """The fitting family, in the order of ``--help``."""
    add_synth(sub)
    _add_fit(sub)
    _add_fit_many(sub)
    _add_scoring(sub)
