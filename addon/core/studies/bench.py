"""``python -m clothfit bench --json FILE``: speed figures against their targets.

* candidate evaluations per second on the full paper workload: simulate one candidate over the
  settling phase and 1.5 s, rasterise and compare its silhouettes for 16 cameras x 15 training
  shapes at 480 x 640 (population batches, numba kernels when available, numpy reference path too);
* the split between simulation and silhouettes;
* the wall time of one whole 16-camera fit (the protocol's budget) -> target under 120 s.
"""

from __future__ import annotations

import os
import platform
import tempfile
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from .. import defaults as D
from ..fitting.job import FitConfig, FitJob
from ..fitting.objective import SilhouetteObjective
from ..fitting.progress import run_shown
from ..fitting.takes import first_frames_share
from ..jsonio import read_json, write_json
from ..observation.camera import select_training
from ..observation.capture import load_capture
from ..observation.raster import silhouette
from ..observation.synth import synth_capture
from ..physics import jit
from ..physics.models import simulate
from ..physics.paper import Params
from .experiment import DEFAULT_OPTIMIZER, FULL, QUICK

TARGET_EVALS_PER_S = 50.0
TARGET_FIT_S = 120.0


def _rate(fn, n_items, min_time=2.0):
    """(items per wall second, CPU milliseconds per item) of ``fn``."""
    fn()  # warm-up (jit compilation, caches)
    t0 = time.perf_counter()
    c0 = time.process_time()
    reps = 0
    while True:
        fn()
        reps += 1
        dt = time.perf_counter() - t0
        if dt >= min_time:
            return reps * n_items / dt, 1000.0 * (time.process_time() - c0) / (reps * n_items)


def _bench_blender_model(tmp, quick, paper_rate, progress=None):
    """The ``blender`` cloth model on the same workload (16 cameras x 15 shapes at 480 x 640, the
    paper's 16 x 16 sheet, 0.5 s settling + 1.5 s at 24 fps, quality 5), and a 4-camera fit of a
    21 x 21 cloth with the default free set."""
    from ..physics import blender as B
    from ..physics.scenario import ClothGrid, paper_scenario

    truth = {"tension_stiffness": 40.0, "shear_stiffness": 8.0, "bending_stiffness": 0.2, "air_damping": 2.0}
    cap = load_capture(synth_capture(os.path.join(tmp, "blender_cap"), truth, model="blender", seed=0).root)
    train, _ = select_training(cap.cameras, 16)
    fidx = [cap.frame_index(t) for t in D.TRAIN_TIMES]
    obs = [[cap.load_silhouette(c, f) for f in fidx] for c in train]
    sc = cap.scenario.with_frames(D.TRAIN_TIMES)
    cams = [cap.cameras[c] for c in train]
    base = B.check_settings(dict(truth, time_scale=B.physical_time_scale(D.BLENDER_FPS)))
    rng = np.random.default_rng(0)
    pop = 16  # two batches of 8 SIMD lanes
    P = np.repeat(B.settings_row(base)[None], pop, 0)
    for n in ("tension_stiffness", "shear_stiffness", "bending_stiffness", "air_damping", "tension_damping"):
        P[:, B.FLOAT_SETTINGS.index(n)] *= rng.uniform(0.8, 1.25, pop)
    obj = SilhouetteObjective(sc, cams, obs, backend="numba", model=cap.model)
    r, rc = _rate(lambda: obj(P), pop, min_time=3.0)
    s, sc_ms = _rate(lambda: obj.model.simulate(sc, P), pop, min_time=2.0)
    # the same candidates on the first five training frames (the line at the first stage's end, scored cheaply)
    k = D.BENCH_FIRST_FRAMES
    early = SilhouetteObjective(sc.with_frames(D.TRAIN_TIMES[:k]), cams, [o[:k] for o in obs], "numba", model=cap.model)
    _, ec = _rate(lambda: early(P), pop, min_time=2.0)
    counted = first_frames_share(D.TRAIN_TIMES, sc.settle_time, k)
    res = {
        "evals_per_s": r,
        "cpu_ms_per_eval": rc,
        "sim_only_per_s": s,
        "sim_cpu_ms_per_eval": sc_ms,
        "first_frames": {"frames": k, "cpu_ms_per_eval": ec, "cpu_ratio": ec / rc, "counted_share": counted},
        "ratio_to_target": r / TARGET_EVALS_PER_S,
        "ratio_to_paper_model": (r / paper_rate) if paper_rate else None,
    }
    print(
        f"[blender model] candidate evaluations/s: {r:.1f} (target {TARGET_EVALS_PER_S:.0f}, ratio "
        f"{r / TARGET_EVALS_PER_S:.2f}; paper model {paper_rate or float('nan'):.1f}/s); CPU per evaluation "
        f"{rc:.1f} ms (simulation {sc_ms:.1f} ms); simulation alone {s:.1f}/s",
        flush=True,
    )
    print(
        f"[blender model] on the first {k} training frames: {ec:.1f} ms CPU per evaluation, {ec / rc:.2f} of every "
        f"frame's (a fit counts {counted:.2f})",
        flush=True,
    )
    # a 4-camera fit of a 21 x 21 cloth, the default free set, CMA-ES
    sc21 = paper_scenario(ClothGrid(21, 21, D.CLOTH_SIDE))
    cap21 = load_capture(
        synth_capture(os.path.join(tmp, "blender_cap21"), truth, model="blender", seed=0, scenario=sc21).root
    )
    evals = 600 if quick else 3000
    t0 = time.perf_counter()
    job = FitJob(
        cap21,
        FitConfig(
            train_cameras=select_training(cap21.cameras, 4)[0], train_times=D.TRAIN_TIMES, max_evaluations=evals, seed=0
        ),
    )
    run_shown(job, progress, "blender model, 21 x 21, 4 cameras")
    wall = time.perf_counter() - t0
    res["fit_21x21_4cams"] = {
        "evaluations": job.evaluations,
        "wall_s": wall,
        "evals_per_s": job.evaluations / wall,
        "free": list(job.par.free),
        "best_E_sil_pct": 100 * job.best_error / job.objective.n_images,
    }
    print(
        f"[blender model] 4-camera fit of a 21 x 21 cloth ({len(job.par.free)} free settings, "
        f"{job.evaluations} evaluations): {wall:.1f} s wall, best training E_sil "
        f"{res['fit_21x21_4cams']['best_E_sil_pct']:.3f} %",
        flush=True,
    )
    return res


def bench_default_fit(
    tmp: str,
    echo: Callable[..., Any] = print,
    max_evaluations: int | None = None,
    progress: Callable[[str], Any] | None = None,
) -> dict[str, Any]:
    """The time to answer a capture: the default fit of a 21 x 21 blender-model cloth (1 s settle + 1.5 s
    at 24 fps, 25 cm), 4 training cameras, 15 training frames at 480 x 640, the quality chosen by the
    fit (the capture declares none) and the manipulation's unknowns estimated (time offset 50 ms,
    handles 5 mm); wall and CPU time with the load, against the 3-minute target."""
    from ..physics.scenario import ClothGrid, Scenario, paper_scenario

    sc0 = paper_scenario(ClothGrid(21, 21, 0.25), frame_times=D.FRAME_TIMES)
    sc = Scenario(sc0.grid, sc0.handles, sc0.frame_times, 1.0, sc0.gravity)
    truth = {"tension_stiffness": 15.0, "shear_stiffness": 5.0, "bending_stiffness": 0.5, "air_damping": 1.0}
    root = os.path.join(tmp, "default21")
    synth_capture(
        root, truth, model={"name": "blender", "fps": 24}, rig="lab18", resolution=(480, 640), scenario=sc, seed=0
    )
    path = os.path.join(root, "capture.json")
    d = read_json(path, "capture")
    d["model"] = {"name": "blender", "fps": 24}  # (a loaded model names a quality: auto below)
    d["uncertain"] = {"time_offset": 0.05, "handles": 0.005}
    write_json(path, d)
    cap = load_capture(root)
    train, _ = select_training(cap.cameras, 4)
    load = os.getloadavg()[0]
    t0, c0 = time.perf_counter(), time.process_time()
    job = FitJob(
        cap,
        FitConfig(
            train_cameras=train,
            train_times=D.TRAIN_TIMES,
            seed=0,
            quality="auto",
            max_evaluations=max_evaluations or D.FIT_EVALUATIONS,
        ),
    )
    r = run_shown(job, progress, "default fit")
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    out = {
        "workload": "21 x 21 blender cloth, 4 cameras x 15 frames at 480 x 640, quality chosen, time offset and "
        "4 handle offsets estimated",
        "evaluations": r["evaluations"],
        "wall_s": wall,
        "cpu_s": cpu,
        "load_1min_at_start": load,
        "target_s": 180.0,
        "ratio_to_target": wall / 180.0,
        "quality_choice": r.get("quality_choice"),
        "stages": r.get("stages"),
        "train_E_sil_pct": r["best_E_sil_mean_pct"],
        "floor": r.get("floor"),
    }
    echo(
        f"default fit (21 x 21, 4 cameras x 15 frames at 480 x 640, quality chosen, manipulation estimated; "
        f"{r['evaluations']} evaluations): {wall:.0f} s wall, {cpu:.0f} s CPU (target 180 s, ratio "
        f"{wall / 180.0:.2f}; 1-min load {load:.2f} at the start); quality "
        f"{(r.get('quality_choice') or {}).get('chosen')}",
        flush=True,
    )
    return out


def _backend_rates(out, sc, cams, obs, P):
    """Candidate evaluations per second (and the simulation's alone) on each backend, into ``out[backend]``."""
    backends = ["numba", "numpy"] if jit.available() else ["numpy"]
    for be in backends:
        obj = SilhouetteObjective(sc, cams, obs, backend=be)
        Pb = P if be == "numba" else P[:4]
        r, rc = _rate(lambda: obj(Pb), len(Pb), min_time=3.0 if be == "numba" else 1.0)  # noqa: B023 (called at once)
        s, sc_ms = _rate(lambda: simulate(sc, Pb, backend=be), len(Pb), min_time=1.5)  # noqa: B023
        out[be] = {
            "evals_per_s": r,
            "cpu_ms_per_eval": rc,
            "sim_only_per_s": s,
            "sim_cpu_ms_per_eval": sc_ms,
            "silhouette_share_of_cpu_pct": max(0.0, 100.0 * (1 - sc_ms / rc)),
            "ratio_to_target": r / TARGET_EVALS_PER_S,
        }
        print(
            f"[{be}] candidate evaluations/s: {r:.1f} (target {TARGET_EVALS_PER_S:.0f}, ratio {r / TARGET_EVALS_PER_S:.2f}); "
            f"CPU per evaluation {rc:.1f} ms (simulation {sc_ms:.1f} ms, silhouettes "
            f"{out[be]['silhouette_share_of_cpu_pct']:.0f} %); simulation alone {s:.1f}/s",
            flush=True,
        )


def _bench_fit(out, cap, train, evals, progress=None):
    """The timed 16-camera fit and what one checkpoint of it costs, into ``out``; the peak memory (MB) or None."""
    t0 = time.perf_counter()
    job = FitJob(
        cap,
        FitConfig(
            train_cameras=train, train_times=D.TRAIN_TIMES, optimizer=DEFAULT_OPTIMIZER, max_evaluations=evals, seed=0
        ),
    )
    run_shown(job, progress, "16-camera fit")
    wall = time.perf_counter() - t0
    try:
        import resource

        peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # kB on Linux
    except (ImportError, OSError):
        peak_mb = None
    out["peak_memory_mb"] = peak_mb
    out["fit"] = {
        "optimizer": DEFAULT_OPTIMIZER,
        "evaluations": job.evaluations,
        "wall_s": wall,
        "evals_per_s": job.evaluations / wall,
        "ratio_to_target": wall / TARGET_FIT_S,
        "best_E_sil_pct": 100 * job.best_error / job.objective.n_images,
    }
    print(
        f"16-camera fit ({DEFAULT_OPTIMIZER}, {job.evaluations} evaluations): {wall:.1f} s wall "
        f"(target {TARGET_FIT_S:.0f} s, ratio {wall / TARGET_FIT_S:.2f}), best training E_sil "
        f"{out['fit']['best_E_sil_pct']:.3f} %",
        flush=True,
    )
    with tempfile.TemporaryDirectory() as td:  # what one checkpoint costs (written at most every 2 s)
        ck = os.path.join(td, "fit.checkpoint.json")
        t0 = time.perf_counter()
        for _ in range(20):
            job.save_checkpoint(ck)
        out["checkpoint_ms"] = 1000 * (time.perf_counter() - t0) / 20
        out["checkpoint_bytes"] = os.path.getsize(ck)
    out["fit"]["stop_reason"] = job.state.stop_reason
    print(
        f"checkpoint: {out['checkpoint_ms']:.1f} ms per write ({out['checkpoint_bytes']} bytes, after "
        f"{job.generation} generations; written at most every {D.CHECKPOINT_INTERVAL_S:g} s by the CLI)",
        flush=True,
    )
    return peak_mb


def run_bench(
    json_path: str | os.PathLike,
    quick: bool = False,
    only_blender_workers: bool = False,
    only_default_fit: bool = False,
    blender_workers: Callable[[str], dict[str, Any]] | None = None,
    progress: Callable[[str], Any] | None = None,
) -> dict[str, Any]:
    """The speed figures, written to ``json_path``. ``blender_workers(tmp) -> dict``: the figures of
    Blender's solver on workers (``farm.bench.bench_blender_workers``, passed in by the CLI: the farm
    is a layer above the core); without it they are reported as skipped."""
    if blender_workers is None:

        def blender_workers(tmp):
            return {"skipped": "Blender workers are measured by the CLI's bench (farm layer)"}

    if only_default_fit:
        out = {"default_fit": bench_default_fit(tempfile.mkdtemp(prefix="clothfit_bench_"), progress=progress)}
        write_json(json_path, out)
        return out
    if only_blender_workers:
        out = {"blender_workers": blender_workers(tempfile.mkdtemp(prefix="clothfit_bench_"))}
        write_json(json_path, out)
        return out
    S = QUICK if quick else FULL
    tmp = tempfile.mkdtemp(prefix="clothfit_bench_")
    cap = synth_capture(os.path.join(tmp, "cap"), seed=0)
    cap = load_capture(cap.root)
    train, _ = select_training(cap.cameras, 16)
    fidx = [cap.frame_index(t) for t in D.TRAIN_TIMES]
    obs = [[cap.load_silhouette(c, f) for f in fidx] for c in train]
    sc = cap.scenario.with_frames(D.TRAIN_TIMES)
    cams = [cap.cameras[c] for c in train]
    gt = Params(**cap.meta["true_params"])
    rng = np.random.default_rng(0)
    pop = 14  # a CMA-ES-sized batch (our fits ask 7..30 candidates per generation)
    P = np.array([[gt.m, gt.k * f1, gt.l * f2, gt.d * f3] for f1, f2, f3 in rng.uniform(0.9, 1.1, (pop, 3))])
    try:
        load = os.getloadavg()[0]
    except OSError:
        load = None
    out = {
        "machine": {
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "numba": jit.available(),
            "load_average_1min_at_start": load,
        },
        "workload": "16 cameras x 15 shapes at 480x640, settle 0.5 s + 1.5 s of motion, 705 springs",
        "targets": {"evals_per_s": TARGET_EVALS_PER_S, "fit_seconds": TARGET_FIT_S},
    }
    _backend_rates(out, sc, cams, obs, P)
    X = simulate(sc, [gt]).positions[0]
    t0 = time.perf_counter()
    n = 0
    for c in cams[:4]:
        for f in range(X.shape[0]):
            silhouette(c, X[f], sc.grid.triangles)
            n += 1
    out["numpy_full_frame_silhouette_ms"] = 1000 * (time.perf_counter() - t0) / n
    print(f"numpy full-frame silhouette (480x640): {out['numpy_full_frame_silhouette_ms']:.2f} ms", flush=True)
    evals = S["evals"]
    peak_mb = _bench_fit(out, cap, train, evals, progress)
    if peak_mb is not None:
        print(
            f"peak memory of the whole bench process (capture, 240 observed silhouettes, numba): {peak_mb:.0f} MB",
            flush=True,
        )
    if load is not None and load > 0.5:
        print(
            f"note: the machine was busy (1-min load {load:.2f} on {os.cpu_count()} CPUs at the start): wall-clock "
            f"figures are pessimistic; CPU ms per evaluation is the load-independent figure",
            flush=True,
        )
    if jit.available():
        out["blender_model"] = _bench_blender_model(tmp, quick, out.get("numba", {}).get("evals_per_s"), progress)
    out["blender_workers"] = blender_workers(tmp)
    write_json(json_path, out)
    return out
