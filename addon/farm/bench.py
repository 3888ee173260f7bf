"""``bench``'s figures of Blender's own solver on workers (``fit --backend blender``): evaluations per
second with 1 and 2 Ray workers, Ray's start-up, the workers' load. The rest of ``bench`` is the core's
(``core/studies/bench.py``); the CLI passes :func:`bench_blender_workers` to it."""

from __future__ import annotations

import os
import time

import numpy as np

from ..core.location import IMPORT_NAME, PACKAGE_PARENT
from .executors import ray_available
from .scene import BlendSceneEvaluator

SCENE_SCRIPT = (
    "import sys; from " + IMPORT_NAME + ".blender import collider_scene as CS; "
    "sc = CS.collider_scenario(int(sys.argv[2]), settle=0.25, after=0.5); print(CS.build_scene(sys.argv[1], sc))"
)


def bench_blender_workers(tmp, grid=21, workers=(1, 2), candidates=48, echo=print):
    """Blender's own solver as the fit's evaluator (``--backend blender``): evaluations per second
    with 1 and 2 Ray workers on a ``grid`` x ``grid`` cloth falling onto a box (0.25 s hung, 0.5 s
    after the release, 24 fps, collisions on; ``addon/blender/collider_scene.py``), the batch of
    ``candidates`` scored by the core objective (4 cameras at 120 x 160), and Ray's start-up cost
    (``ray.init`` of a local instance; then until every worker has loaded the .blend). The scene is
    built by a child process with the bpy module; this process never imports bpy."""
    import subprocess
    import sys

    from ..core.fitting.objective import SilhouetteObjective
    from ..core.observation.camera import load_rig
    from ..core.physics import blender as B

    if not ray_available():
        echo("[blender workers] skipped: Ray is not installed")
        return {"skipped": "ray not installed"}
    blend = os.path.join(tmp, "bench_scene.blend")
    r = subprocess.run(
        [sys.executable, "-c", SCENE_SCRIPT, blend, str(grid)], cwd=PACKAGE_PARENT, capture_output=True, text=True
    )
    if r.returncode != 0:
        echo("[blender workers] skipped: building the scene needs the bpy module")
        return {"skipped": r.stderr.strip().splitlines()[-1] if r.stderr.strip() else "scene build failed"}
    f0 = int(r.stdout.strip().splitlines()[-1])
    times = np.arange(1, 13) / 24.0
    cams = [c.resized(120, 160) for c in load_rig("ring8")[:4]]
    out = {"grid": grid, "frames_per_candidate": int(f0 - 1 + 12), "candidates_per_batch": candidates, "runs": {}}
    rng = np.random.default_rng(0)
    for w in workers:
        t0 = time.perf_counter()
        ev = BlendSceneEvaluator(blend, frame_zero=f0, workers=w, executor="ray")
        try:
            ev.executor.pids()  # every worker has loaded the scene
            ready = time.perf_counter() - t0
            sc = ev.scenario(times)
            base = B.settings_row(ev.initial)
            P = np.repeat(base[None], candidates, 0)
            for n in ("tension_stiffness", "shear_stiffness", "bending_stiffness", "air_damping"):
                P[:, B.FLOAT_SETTINGS.index(n)] *= rng.uniform(0.7, 1.4, candidates)
            first = ev.simulate(sc, P[:1])
            X = first.positions[0]
            from ..core.observation.raster import silhouette as _sil

            obs = [[_sil(c, X[f], sc.grid.triangles) for f in range(len(times))] for c in cams]
            obj = SilhouetteObjective(sc, cams, obs, backend="auto", model=ev)
            obj(P[:2])  # jit warm-up
            t1 = time.perf_counter()
            c1 = time.process_time()
            busy0, cpu0 = ev.worker_seconds, ev.worker_cpu_seconds
            obj(P)
            wall = time.perf_counter() - t1
            busy, wcpu = ev.worker_seconds - busy0, ev.worker_cpu_seconds - cpu0
            # worker_s_per_eval: the simulation time a worker reports per candidate; if it grows with
            # the worker count, the workers share CPUs (other load), not a limit of the dispatch.
            # busy_fraction: summed worker simulation time / (workers x wall): 1.0 = no idle worker.
            out["runs"][str(w)] = {
                "evals_per_s": candidates / wall,
                "wall_s": wall,
                "driver_cpu_ms_per_eval": 1000 * (time.process_time() - c1) / candidates,
                "worker_s_per_eval": busy / candidates,
                "busy_fraction": busy / (w * wall),
                # > 1: Blender's solver uses more than one thread per worker
                "worker_cpu_per_wall": wcpu / busy if busy > 0 else None,
                "ray_init_s": ev.executor.startup_s,
                "ready_s": ready,
            }
        finally:
            ev.close()
        r = out["runs"][str(w)]
        echo(
            f"[blender workers] {w} worker(s): {candidates / wall:.2f} Blender evaluations/s "
            f"({grid} x {grid} cloth onto a box, {out['frames_per_candidate']} frames each, scored on 4 cameras); "
            f"a worker simulates one in {r['worker_s_per_eval']:.3f} s using {r['worker_cpu_per_wall'] or 0:.2f} CPUs, "
            f"workers busy {100 * r['busy_fraction']:.0f} % of the wall time; "
            f"Ray start-up {ev.executor.startup_s:.1f} s, workers ready (.blend loaded) after {ready:.1f} s",
            flush=True,
        )
    try:
        out["load_average_1min_at_end"] = os.getloadavg()[0]
    except OSError:
        pass
    if "1" in out["runs"] and "2" in out["runs"]:
        out["speedup_2_workers"] = out["runs"]["2"]["evals_per_s"] / out["runs"]["1"]["evals_per_s"]
        echo(
            f"[blender workers] 2 workers / 1 worker: {out['speedup_2_workers']:.2f}x (goal 1.8x; 1-minute load "
            f"{out.get('load_average_1min_at_end', float('nan')):.1f} on {os.cpu_count()} CPUs)",
            flush=True,
        )
    return out
