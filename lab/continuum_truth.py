"""Test truths our cloth models did not make: a continuum cloth in NVIDIA Warp, seen by a rig that is not ours.

For the goals of fitting a real capture (lab/fit_goals.py). Neither the paper's sheet nor Blender's cloth made these captures:

* the engine is Warp's ``warp.sim`` (FEM membrane triangles, hinge bending, quadratic air drag,
  gravity 9.81 m/s^2), driven by ``lab/warp_cloth.py`` with physical fabric values (``MATERIALS``);
* its mesh is not our grid: 29 x 29 vertices with alternating diagonals; silhouettes are rasterised
  from the truth's own triangles; the ground-truth shapes for the shape error are the truth's surface
  sampled at the vertices of the grid a user would declare (barycentric on the deformed truth mesh
  from the rest-space positions);
* the scenario: a 25 cm square held at its four corners, brought 10 % closer together than the
  cloth's size (hands cannot hold a cloth taut), settled, corner 0 released at t = 0, 1.5 s at a
  phone's 30 fps (not 24, and not written anywhere a fitter reads it);
* the rig (``rig()``): 12 cameras at varied distances, heights and focal lengths, two nearly
  edge-on to the cloth's rest plane, 480 x 640, our synth's boundary noise (5 %) and a noise-free
  variant.

Steps:
  make      simulate every material, write ``OUT/<material>`` (noisy) and ``OUT/<material>_clean``
  takes     several takes of one cloth, each handled differently (corners released, a corner waved,
            two corners lifted and lowered): ``lab/continuum_takes.py``
  takes-baseline  fit each take alone, score the result on every take of its material
  baseline  fit each noisy capture as a new user would with today's code, through the CLI in
            subprocesses: ``python -m clothfit fit CAP --model blender --cameras n:4 --times <even>``
            (nothing else), then the same with ``--fps 30``; score with ``python -m clothfit evaluate``
            on the 8 held-out cameras and the odd frames; floor = the truth's own held-out error
            (its noise-free silhouettes against the noisy ones). Writes one JSON.

    python lab/continuum_truth.py make --out out/continuum
    python lab/continuum_truth.py baseline --out out/continuum --json out/continuum/baseline.json
    python lab/continuum_truth.py takes --out out/takes [--materials cotton,silk] [--takes one_corner,wave]
    python lab/continuum_truth.py takes-baseline --out out/takes --json out/takes/baseline.json
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
for p in (ROOT, os.path.join(ROOT, "lab")):
    if p not in sys.path:
        sys.path.insert(0, p)

import warp_cloth as W  # noqa: E402

FPS = 30.0  # a phone's frame rate: the capture's times are in seconds, nothing says 30
AFTER = 1.5  # seconds of motion after the release
SIDE = 0.25  # m: a handkerchief, big enough to drape (the bending lengths below are 1.5-4 cm)
HEIGHT = 0.40  # m: the held corners' height
HOLD = 0.90  # the corners are held at 90 % of the cloth's size apart
TRUTH_N = 29  # the truth's mesh: 29 x 29 vertices, alternating diagonals (ours: 16 or 21, one diagonal)
GRID_N = 21  # the grid a user declares for the fit (as lab/cross_simulator.py)
SETTLE_SCENARIO = 1.0  # s: the settling the user declares (whole frames at 24 and 30 fps)
SETTLE_TRUTH = 1.2  # s: the truth's own settling (pins ramped in over RAMP, damped still)
RAMP = 0.4
RELEASED = 0  # corner index released at t = 0 (vertex 0 of both meshes: (-side/2, -side/2))
NOISE = 0.05  # our synth's boundary noise (clothfit.core.defaults.NOISE_FRACTION)
TRAIN_CAMERAS = 4

# Fabric values: areal density (weighed fabrics), stretch E h from Kawabata KES-FB1 tensile tests
# (extension EMT at 500 gf/cm = 490 N/m: E h ~ 490 N/m / EMT), bending rigidity B from KES-FB2
# (1 gf cm^2/cm = 9.81e-5 N m). Typical published ranges (Kawabata & Niwa 1989, "Fabric performance
# in clothing and clothing manufacture", J. Text. Inst. 80; Hu, "Fabric testing", 2008, ch. 5 and 7):
MATERIALS = {
    "cotton": W.Material(
        "cotton",
        areal_density=0.13,
        stretch=1.0e4,
        poisson=0.3,
        bending=1.0e-5,
        source="cotton shirting/plain weave: 130 g/m^2 (100-150), EMT ~5 % -> E h ~ 1e4 N/m, "
        "B ~ 0.1 gf cm^2/cm (0.05-0.15) = 1e-5 N m",
    ),
    "silk": W.Material(
        "silk",
        areal_density=0.04,
        stretch=5.0e3,
        poisson=0.3,
        bending=1.5e-6,
        source="silk habotai 8-10 momme: 40 g/m^2 (35-45), EMT ~10 % -> E h ~ 5e3 N/m, "
        "B ~ 0.015 gf cm^2/cm = 1.5e-6 N m",
    ),
    "denim": W.Material(
        "denim",
        areal_density=0.40,
        stretch=3.0e4,
        poisson=0.3,
        bending=1.0e-4,
        source="12 oz denim: 400 g/m^2, EMT ~1.5 % -> E h ~ 3e4 N/m, B ~ 1 gf cm^2/cm = 1e-4 N m "
        "(held-out material: stiff and heavy)",
    ),
}
BASELINE_MATERIALS = ("cotton", "silk")  # denim: made, held out for later work (budget)


# ------------------------------------------------------------------------------------ scenario


def frame_times(after=AFTER):
    return np.arange(1, int(round(after * FPS)) + 1) / FPS


def hold_position(x, y):
    return (HOLD * x, HOLD * y, HEIGHT)


def user_scenario(n=GRID_N, after=AFTER):
    """What a user declares: a ``n x n`` grid of the cloth's measured size, pinned at its corners
    where the hands hold them, corner 0 released at t = 0."""
    from clothfit.core.physics.scenario import ClothGrid, Handle, Scenario

    grid = ClothGrid(n, n, SIDE, HEIGHT)
    handles = []
    for k, v in enumerate(grid.corners()):
        x, y = grid.rest[v][:2]
        handles.append(Handle(v, [0.0], [hold_position(x, y)], 0.0 if k == RELEASED else None))
    return Scenario(grid, handles, frame_times(after), SETTLE_SCENARIO)


def rig():
    """12 cameras that are not ours: (azimuth, elevation of the eye over the target [deg], distance
    [m], focal length [px]); 10 and 11 sit 1 cm above the held corners' plane, nearly edge-on."""
    from clothfit.core.observation.camera import Camera, intrinsics, look_at

    target = np.array([0.0, 0.0, HEIGHT - 0.10])
    spec = [
        (10, 25, 0.70, 700),
        (55, 12, 0.60, 560),
        (100, 35, 0.80, 820),
        (150, 15, 0.66, 600),
        (200, 30, 0.75, 760),
        (245, 6, 0.56, 520),
        (290, 20, 0.70, 660),
        (330, 48, 0.86, 860),
        (75, 62, 0.72, 700),
        (262, 72, 0.82, 760),
        (30, None, 0.62, 580),
        (190, None, 0.68, 620),
    ]
    cams = []
    for i, (az, el, dist, fx) in enumerate(spec):
        a = math.radians(az)
        if el is None:  # edge-on: the eye 1 cm above the rest plane z = HEIGHT
            dz = HEIGHT + 0.01 - target[2]
            horiz = math.sqrt(dist**2 - dz**2)
            eye = target + np.array([horiz * math.cos(a), horiz * math.sin(a), dz])
        else:
            e = math.radians(el)
            eye = target + dist * np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])
        R, t = look_at(eye, target)
        cams.append(Camera(intrinsics(float(fx), 640, 480), R, t, 640, 480, name=f"rig{i:02d}"))
    return cams


# ------------------------------------------------------------------------------ truth sampling


def barycentric_sampler(V_rest, tris, points):
    """For each 2D point (rest space, x y), the truth triangle holding it and its barycentric weights."""
    P = np.asarray(points, dtype=np.float64)[:, :2]
    A, B, C = (V_rest[tris[:, k], :2] for k in range(3))
    tri_of = np.empty(len(P), dtype=np.int64)
    weights = np.empty((len(P), 3))
    v0, v1 = B - A, C - A
    den = v0[:, 0] * v1[:, 1] - v1[:, 0] * v0[:, 1]
    for i, p in enumerate(P):
        v2 = p - A
        b = (v2[:, 0] * v1[:, 1] - v1[:, 0] * v2[:, 1]) / den
        c = (v0[:, 0] * v2[:, 1] - v2[:, 0] * v0[:, 1]) / den
        a = 1.0 - b - c
        inside = np.minimum(np.minimum(a, b), c)
        k = int(np.argmax(inside))
        if inside[k] < -1e-9:
            raise ValueError(f"point {p} is outside the truth's mesh")
        tri_of[i] = k
        weights[i] = (a[k], b[k], c[k])
    return tri_of, weights


def sample(X, tris, tri_of, weights):
    """Positions (F, P, 3) of the sample points on the deformed truth meshes X (F, V, 3)."""
    T = tris[tri_of]  # (P, 3)
    return np.einsum("fpkd,pk->fpd", X[:, T], weights)


# ----------------------------------------------------------------------------------------- make


def simulate_truth(mat, n_truth=TRUTH_N, settle=SETTLE_TRUTH, ramp=RAMP, times=None, dt=None):
    """The truth of one material: (truth mesh rest V, triangles, positions (F, V, 3), facts)."""
    V, tris = W.sheet_mesh(n_truth, SIDE)
    corners = [0, n_truth - 1, n_truth * (n_truth - 1), n_truth * n_truth - 1]
    pins = [
        W.Pin(v, (HOLD * V[v, 0], HOLD * V[v, 1], 0.0), 0.0 if k == RELEASED else None) for k, v in enumerate(corners)
    ]
    X, facts = W.simulate(
        V,
        tris,
        mat,
        pins,
        frame_times() if times is None else times,
        settle=settle,
        ramp=ramp,
        origin=(0.0, 0.0, HEIGHT),
        dt=dt,
    )
    return V, tris, X, facts


def truth_meta(mat, n_truth, V, tris, settle, facts, seed, fps=FPS):
    """The capture's ``meta`` of a Warp truth (nothing in it is read by a fitter)."""
    return {
        "generator": f"NVIDIA Warp {W.WARP_VERSION} warp.sim (FEM triangles, hinge bending, air drag, "
        f"semi-implicit Euler) via lab/continuum_truth.py; core rasteriser on the truth's "
        f"own triangles",
        "truth_engine": "warp.sim",
        "material": mat.to_dict(),
        "truth_mesh": {
            "n": n_truth,
            "vertices": int(len(V)),
            "triangles": int(len(tris)),
            "diagonals": "alternating",
        },
        "truth_settle_s": settle,
        "truth_ramp_s": min(RAMP, settle / 2),
        "hold_fraction": HOLD,
        "true_fps_of_capture": fps,
        "sim": facts,
        "seed": seed,
        "note": "not made by any model of this repository: no true parameters of ours exist",
    }


def write_truth(root, cams, sc, V, tris, X, cloth_mass, meta, seed, noise=NOISE):
    """Write ``root`` (silhouettes of the truth mesh ``X`` (F, V, 3) with ``noise`` boundary noise) and
    ``root + "_clean"`` (noise-free), both with the truth's shapes at the grid of ``sc``; returns both paths."""
    from clothfit.core.observation.capture import write_capture
    from clothfit.core.observation.metrics import add_boundary_noise
    from clothfit.core.observation.raster import silhouette
    from clothfit.core.observation.synth import noise_rng

    tri_of, w = barycentric_sampler(V, tris, sc.grid.rest[:, :2])
    shapes = sample(X, tris, tri_of, w)
    clean = [[silhouette(c, X[f], tris) for f in range(len(X))] for c in cams]
    noisy = [
        [add_boundary_noise(clean[ci][f], noise, noise_rng(seed, ci, f)) for f in range(len(X))]
        for ci in range(len(cams))
    ]
    out = []
    for variant, sils, nf in (("", noisy, noise), ("_clean", clean, 0.0)):
        write_capture(
            root + variant, cams, sc, sils, shapes=shapes, cloth_mass=cloth_mass, meta=dict(meta, noise_fraction=nf)
        )
        out.append(root + variant)
    return out


def make(out, materials=None, n_truth=TRUTH_N, grid_n=GRID_N, settle=SETTLE_TRUTH, after=None, cameras=None, seed=0):
    """Simulate each material and write ``out/<name>`` (5 % boundary noise) and ``out/<name>_clean``."""
    sc = user_scenario(grid_n, AFTER if after is None else after)
    cams = rig() if cameras is None else cameras
    written = {}
    for name in materials or list(MATERIALS):
        mat = MATERIALS[name]
        t0 = time.time()
        V, tris, X, facts = simulate_truth(
            mat, n_truth, settle=settle, ramp=min(RAMP, settle / 2), times=sc.frame_times
        )
        meta = truth_meta(mat, n_truth, V, tris, settle, facts, seed)
        noisy, clean = write_truth(
            os.path.join(out, name), cams, sc, V, tris, X, mat.areal_density * SIDE * SIDE, meta, seed
        )
        written[name], written[name + "_clean"] = noisy, clean
        print(
            f"made {name}: {len(X)} frames, {facts['steps']} steps of {facts['dt'] * 1e6:.1f} us, "
            f"{facts['cpu_s']:.0f} cpu s, {time.time() - t0:.0f} s -> {os.path.join(out, name)}",
            flush=True,
        )
    return written


# ------------------------------------------------------------------------------------- baseline


def even_odd(cap):
    t = cap.frame_times
    return list(t[1::2]), list(t[0::2])  # frames 2, 4, ... train; 1, 3, ... test


def times_arg(ts):
    return ",".join(f"{x:.9f}" for x in ts)


def floor(cap, cams, times):
    """The truth's own held-out error: its noise-free silhouettes (the _clean capture) against the noisy."""
    from clothfit.core.observation.capture import load_capture
    from clothfit.core.observation.metrics import e_sil

    clean = load_capture(cap.root.rstrip("/") + "_clean")
    fi = cap.frame_indices(times)
    errs = [e_sil(cap.load_silhouette(c, f), clean.load_silhouette(c, f)) for c in cams for f in fi]
    return 100.0 * float(np.mean(errs))


def _cli(args, log):
    cmd = [sys.executable, "-m", "clothfit"] + args
    t0 = time.time()
    p = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    wall = time.time() - t0
    with open(log, "a") as f:
        f.write("$ " + " ".join(cmd) + f"\n[exit {p.returncode}, {wall:.1f} s]\n{p.stderr}\n{p.stdout}\n")
    if p.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({p.returncode}): {p.stderr.strip().splitlines()[-1:]}")
    return json.loads(p.stdout), wall


def baseline(out, json_path, materials=BASELINE_MATERIALS, max_evaluations=None):
    from clothfit.core.observation.camera import select_training
    from clothfit.core.observation.capture import load_capture

    rows = []
    if os.path.isfile(json_path):  # a partial run (some materials) keeps the other materials' rows
        from clothfit.core.jsonio import read_json

        rows = [r for r in read_json(json_path, "baseline JSON").get("rows", []) if r["material"] not in materials]
    log = os.path.join(out, "baseline.log")
    os.makedirs(os.path.join(out, "fits"), exist_ok=True)
    for name in materials:
        root = os.path.join(out, name)
        cap = load_capture(root)
        even, odd = even_odd(cap)
        _, held = select_training(cap.cameras, TRAIN_CAMERAS)
        fl = floor(cap, held, odd)
        for variant, extra in (("new user", []), ("fps given", ["--fps", f"{FPS:g}"])):
            res = os.path.join(out, "fits", f"{name}_{'fps' if extra else 'user'}.json")
            fit_args = [
                "fit",
                root,
                "--model",
                "blender",
                "--cameras",
                f"n:{TRAIN_CAMERAS}",
                "--times",
                times_arg(even),
                "--out",
                res,
                "--force",
                "--quiet",
            ] + extra
            if max_evaluations:
                fit_args += ["--max-evaluations", str(max_evaluations)]
            load0 = os.getloadavg()[0]
            fit, wall = _cli(fit_args, log)
            ev, _ = _cli(
                ["evaluate", root, "--params", res, "--cameras", f"heldout:{TRAIN_CAMERAS}", "--times", times_arg(odd)],
                log,
            )
            r = {
                "material": name,
                "variant": variant,
                "fit_options": fit_args[2:],
                "heldout_cameras": len(held),
                "heldout_frames": len(odd),
                "heldout_E_sil_pct": ev["silhouette_error_pct"],
                "floor_heldout_E_sil_pct": fl,
                "shape_error_mm": ev.get("shape_error_mm"),
                "train_E_sil_pct": fit.get("best_E_sil_mean_pct"),
                "evaluations": fit.get("evaluations"),
                "wall_s": wall,
                "load_1min_before": load0,
                "fit_blender_cloth": fit.get("blender_cloth"),
                "fit_blender_scene": fit.get("blender_scene"),
                "result": os.path.relpath(res, ROOT),
            }
            rows.append(r)
            print(
                f"{name:7s} {variant:9s}: held-out E_sil {r['heldout_E_sil_pct']:6.2f} % (floor {fl:.2f} %), "
                f"shape {r['shape_error_mm']:.2f} mm, {r['evaluations']} evals, {wall:.0f} s (load {load0:.1f})",
                flush=True,
            )
            doc = {
                "what": "baseline: continuum cloth (Warp) fitted by today's blender model as a new user would",
                "fps_of_capture": FPS,
                "train_cameras": TRAIN_CAMERAS,
                "rows": rows,
            }
            from clothfit.core.jsonio import write_json

            write_json(json_path, doc)
    return rows


def converge(material, json_path, meshes=(21, 29, 41)):
    """How far the truth is from its continuum limit: the same material on finer meshes and with half
    the step, sampled at the user's grid; mean and max distance [mm] to the finest mesh per frame."""
    from clothfit.core.jsonio import write_json

    sc = user_scenario()
    runs = {}
    for n in meshes:
        V, tris, X, facts = simulate_truth(MATERIALS[material], n)
        tri_of, w = barycentric_sampler(V, tris, sc.grid.rest[:, :2])
        runs[f"n{n}"] = (sample(X, tris, tri_of, w), facts)
        print(f"{material} mesh {n} x {n}: {facts['cpu_s']:.0f} cpu s", flush=True)
    V, tris, X, facts = simulate_truth(
        MATERIALS[material], TRUTH_N, dt=W.stable_dt(*W.sheet_mesh(TRUTH_N, SIDE), MATERIALS[material]) / 2
    )
    tri_of, w = barycentric_sampler(V, tris, sc.grid.rest[:, :2])
    runs[f"n{TRUTH_N}_half_dt"] = (sample(X, tris, tri_of, w), facts)
    ref = runs[f"n{max(meshes)}"][0]
    base = runs[f"n{TRUTH_N}"][0]
    rows = []
    for k, (P, facts) in runs.items():
        d_ref = np.linalg.norm(P - ref, axis=-1) * 1000
        d_base = np.linalg.norm(P - base, axis=-1) * 1000
        rows.append(
            {
                "run": k,
                "vs_finest_mean_mm": float(d_ref.mean()),
                "vs_finest_max_mm": float(d_ref.max()),
                "vs_truth_mesh_mean_mm": float(d_base.mean()),
                "vs_truth_mesh_max_mm": float(d_base.max()),
                "dt": facts["dt"],
                "cpu_s": facts["cpu_s"],
            }
        )
        print(
            f"{k:14s}: vs {max(meshes)} x {max(meshes)} mean {rows[-1]['vs_finest_mean_mm']:.2f} mm, max "
            f"{rows[-1]['vs_finest_max_mm']:.2f} mm; vs the truth's mesh mean {rows[-1]['vs_truth_mesh_mean_mm']:.2f} mm",
            flush=True,
        )
    write_json(json_path, {"material": material, "rows": rows})
    return rows


def format_table(rows):
    out = ["| material | fit | held-out E_sil % (floor) | shape error mm | evals | s |", "|---|---|---|---|---|---|"]
    for r in rows:
        out.append(
            f"| {r['material']} | {r['variant']} | {r['heldout_E_sil_pct']:.2f} ({r['floor_heldout_E_sil_pct']:.2f})"
            f" | {r['shape_error_mm']:.2f} | {r['evaluations']} | {r['wall_s']:.0f} |"
        )
    return "\n".join(out)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="step", required=True)
    m = sub.add_parser("make", help="simulate the materials in Warp and write the captures")
    m.add_argument("--out", default="out/continuum", help="folder of the captures (default: %(default)s)")
    m.add_argument("--materials", default=",".join(MATERIALS), help="comma list (default: %(default)s)")
    m.add_argument("--truth-n", type=int, default=TRUTH_N, help="truth mesh vertices per side (default: %(default)s)")
    m.add_argument("--grid", type=int, default=GRID_N, help="the user's grid vertices per side (default: %(default)s)")
    m.add_argument("--settle", type=float, default=SETTLE_TRUTH, help="truth settling [s] (default: %(default)s)")
    m.add_argument("--after", type=float, default=AFTER, help="seconds of motion (default: %(default)s)")
    b = sub.add_parser("baseline", help="fit the captures with today's CLI as a new user would, and score them")
    b.add_argument("--out", default="out/continuum", help="folder of the captures (default: %(default)s)")
    b.add_argument("--json", required=True, help="write the rows to this JSON file")
    b.add_argument("--materials", default=",".join(BASELINE_MATERIALS), help="comma list (default: %(default)s)")
    b.add_argument("--make", action="store_true", help="run make first (same --out)")
    b.add_argument("--max-evaluations", type=int, default=None, help="budget per fit (default: the CLI's own)")
    c = sub.add_parser("converge", help="the truth on finer meshes and with half the step (continuum check)")
    c.add_argument("--material", default="silk", help="material (default: %(default)s, the finest folds)")
    c.add_argument("--json", required=True, help="write the distances to this JSON file")
    t = sub.add_parser("table", help="print a baseline or takes-baseline JSON as a Markdown table")
    t.add_argument("json")
    import continuum_takes  # several takes of one cloth (it builds on this module's rig and truth)

    continuum_takes.add_parsers(sub)
    a = ap.parse_args(argv)
    if a.step in ("takes", "takes-baseline", "takes-pairs"):
        return continuum_takes.run(a)
    if a.step == "make":
        make(a.out, [x for x in a.materials.split(",") if x], a.truth_n, a.grid, a.settle, a.after)
    elif a.step == "baseline":
        mats = [x for x in a.materials.split(",") if x]
        if a.make:
            make(a.out, mats)
        rows = baseline(a.out, a.json, mats, a.max_evaluations)
        print(format_table(rows))
    elif a.step == "converge":
        converge(a.material, a.json)
    else:
        with open(a.json) as f:
            rows = json.load(f)["rows"]
        print(continuum_takes.format_table(rows) if rows and "fitted_on" in rows[0] else format_table(rows))


if __name__ == "__main__":
    main()
