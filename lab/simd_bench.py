"""The hand-written LLVM IR kernels against their plain numba twins (docs/kernels.md).

    python lab/simd_bench.py --json out/simd.json [--min-time 3]

Runs the Blender cloth model (``physics/blender_kernels.py``) on the workload of ``python -m clothfit
bench``'s blender-model figures (the paper's 16 x 16 sheet, 0.5 s settling, then the training
times, quality 5, a population of 16 = two batches of 8 lanes with varied settings) twice, each in
its own process: once as shipped (``simd.py`` / ``blender_springs.py``'s LLVM vectors) and once with
``CLOTHFIT_NO_SIMD=1`` (``simd_plain.py``, ``blender_springs.springs_plain``). Writes per path the
simulated candidates per wall second and the CPU milliseconds per candidate, their ratio, and the
largest distance between the two paths' vertex positions (mm; 0 = the same trajectory to the bit).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _child(npz, min_time):
    sys.path.insert(0, ROOT)
    import time

    from clothfit.core import defaults as D
    from clothfit.core.physics import blender as B
    from clothfit.core.physics import simd
    from clothfit.core.physics.models import BlenderModel
    from clothfit.core.physics.scenario import ClothGrid, paper_scenario

    sc = paper_scenario(ClothGrid(16, 16, D.CLOTH_SIDE)).with_frames(D.TRAIN_TIMES)
    truth = {"tension_stiffness": 40.0, "shear_stiffness": 8.0, "bending_stiffness": 0.2, "air_damping": 2.0}
    base = B.check_settings(dict(truth, time_scale=B.physical_time_scale(D.BLENDER_FPS)))
    rng = np.random.default_rng(0)
    pop = 16
    P = np.repeat(B.settings_row(base)[None], pop, 0)
    for n in ("tension_stiffness", "shear_stiffness", "bending_stiffness", "air_damping", "tension_damping"):
        P[:, B.FLOAT_SETTINGS.index(n)] *= rng.uniform(0.8, 1.25, pop)
    model = BlenderModel(D.BLENDER_FPS, base["quality"], base["bending_model"])
    t0 = time.perf_counter()
    pos = model.simulate(sc, P, backend="numba").positions  # compiles on the first call
    compile_s = time.perf_counter() - t0
    t0, c0, reps = time.perf_counter(), time.process_time(), 0
    while True:
        model.simulate(sc, P, backend="numba")
        reps += 1
        wall = time.perf_counter() - t0
        if wall >= min_time:
            break
    cpu = time.process_time() - c0
    np.savez(npz, positions=np.asarray(pos))
    return {
        "simd": bool(simd.ENABLED),
        "candidates": pop,
        "timed_repeats": reps,
        "candidates_per_s": reps * pop / wall,
        "cpu_ms_per_candidate": 1000.0 * cpu / (reps * pop),
        "first_call_s": compile_s,
    }


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", required=True, help="where to write the figures (JSON)")
    ap.add_argument("--min-time", type=float, default=3.0, help="seconds of timed simulation per path (default 3)")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.child:
        print(json.dumps(_child(a.child, a.min_time)))
        return 0
    out, pos = {}, {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, off in (("simd", False), ("plain", True)):
            env = dict(os.environ, PYTHONPATH=ROOT)
            env.pop("CLOTHFIT_NO_SIMD", None)
            if off:
                env["CLOTHFIT_NO_SIMD"] = "1"
            npz = os.path.join(tmp, name + ".npz")
            r = subprocess.run(
                [
                    sys.executable,
                    os.path.abspath(__file__),
                    "--json",
                    a.json,
                    "--min-time",
                    str(a.min_time),
                    "--child",
                    npz,
                ],
                env=env,
                capture_output=True,
                text=True,
                cwd=ROOT,
            )
            if r.returncode != 0:
                raise SystemExit(f"{name} run failed: {r.stderr.strip().splitlines()[-1:]}")
            out[name] = json.loads(r.stdout.strip().splitlines()[-1])
            pos[name] = np.load(npz)["positions"]
            print(
                f"[{name}] {out[name]['candidates_per_s']:.1f} candidates/s, "
                f"{out[name]['cpu_ms_per_candidate']:.1f} ms CPU per candidate",
                file=sys.stderr,
            )
    if not out["simd"]["simd"] or out["plain"]["simd"]:
        raise SystemExit("the CLOTHFIT_NO_SIMD switch did not take effect")
    out["speed_ratio_cpu"] = out["plain"]["cpu_ms_per_candidate"] / out["simd"]["cpu_ms_per_candidate"]
    out["speed_ratio_wall"] = out["simd"]["candidates_per_s"] / out["plain"]["candidates_per_s"]
    out["max_diff_mm"] = float(np.max(np.linalg.norm(pos["simd"] - pos["plain"], axis=-1)) * 1000.0)
    out["load_1min"] = os.getloadavg()[0]
    os.makedirs(os.path.dirname(os.path.abspath(a.json)), exist_ok=True)
    with open(a.json, "w") as f:
        json.dump(out, f, indent=1)
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
