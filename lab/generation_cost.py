"""What a generation of the search costs by its size, on this machine: the default fit's workload (a 21 x 21 cloth of
Blender's model, 4 cameras x 15 frames at 480 x 640, quality 5, the manipulation's unknowns declared), candidates
scored in one batch of 1 to 32.

The simulation runs ``simd.W`` candidates side by side in one thread's vector lanes and batches of them in parallel
threads, so a batch of 1 costs what a batch of ``W`` does, and on two cores ``2 W`` cost what ``W`` do: the wall time
of a fit follows its generations more than its evaluations. Wall and CPU ms per batch (the best of ``--repeats``),
wall ms per candidate, and the load.

    python lab/generation_cost.py --json OUT
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

from clothfit.core import defaults as D  # noqa: E402
from clothfit.core.fitting.job import FitConfig, FitJob  # noqa: E402
from clothfit.core.jsonio import read_json, write_json  # noqa: E402
from clothfit.core.observation.camera import select_training  # noqa: E402
from clothfit.core.observation.capture import load_capture  # noqa: E402
from clothfit.core.observation.synth import synth_capture  # noqa: E402
from clothfit.core.physics import simd  # noqa: E402
from clothfit.core.physics.scenario import ClothGrid, Scenario, paper_scenario  # noqa: E402

SIZES = (1, 4, 8, 9, 12, 16, 17, 24, 32)


def workload(tmp: str):
    """The default fit's capture as ``bench --default-fit`` makes it, and a fit job on it at quality 5."""
    sc0 = paper_scenario(ClothGrid(21, 21, 0.25), frame_times=D.FRAME_TIMES)
    sc = Scenario(sc0.grid, sc0.handles, sc0.frame_times, 1.0, sc0.gravity)
    truth = {"tension_stiffness": 15.0, "shear_stiffness": 5.0, "bending_stiffness": 0.5, "air_damping": 1.0}
    root = os.path.join(tmp, "default21")
    synth_capture(root, truth, model={"name": "blender", "fps": 24}, rig="lab18", resolution=(480, 640), scenario=sc)
    path = os.path.join(root, "capture.json")
    d = read_json(path, "capture")
    d["uncertain"] = {"time_offset": 0.05, "handles": 0.005}
    write_json(path, d)
    cap = load_capture(root)
    train, _ = select_training(cap.cameras, 4)
    return FitJob(cap, FitConfig(train_cameras=train, train_times=D.TRAIN_TIMES, seed=0, quality=5))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json")
    a = ap.parse_args(argv)
    job = workload(tempfile.mkdtemp(prefix="gencost_"))
    rng = np.random.default_rng(0)
    load0 = os.getloadavg()[0]
    rows = []
    for n in SIZES:
        X = job.space.decode(0.4 + 0.2 * rng.random((n, job.space.n)))
        job.evaluate(X)  # compiled and warm
        walls, cpus = [], []
        for _ in range(a.repeats):
            t, c = time.perf_counter(), time.process_time()
            job.evaluate(X)
            walls.append(time.perf_counter() - t)
            cpus.append(time.process_time() - c)
        w, cp = min(walls), min(cpus)
        rows.append({"candidates": n, "wall_ms": 1e3 * w, "cpu_ms": 1e3 * cp, "wall_ms_per_candidate": 1e3 * w / n})
        print(f"{n:3d} candidates: {1e3 * w:7.1f} ms wall, {1e3 * cp:7.1f} ms CPU, {1e3 * w / n:6.1f} ms wall each")
    one = next(r for r in rows if r["candidates"] == 1)["wall_ms"]
    for r in rows:
        r["wall_over_one"] = r["wall_ms"] / one
    out = {
        "lanes": simd.W,
        "cpus": os.cpu_count(),
        "load_1min_before": load0,
        "load_1min_after": os.getloadavg()[0],
        "rows": rows,
    }
    if a.json:
        write_json(a.json, out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
