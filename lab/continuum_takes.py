"""Several takes of one continuum cloth (Warp), each handled differently: truths for fitting one take and
predicting the others. Run through ``lab/continuum_truth.py takes`` and ``takes-baseline``.

One cloth (the 25 cm square of ``continuum_truth``, its 29 x 29 Warp mesh, its rig of 12 cameras at
480 x 640, 5 % boundary noise and a noise-free ``_clean`` variant), one material per run, and these
handlings (``TAKES``), each a capture folder ``OUT/<material>_<take>`` with 30 frames:

* ``one_corner`` (20 fps): four corners held 10 % closer than the cloth's size, corner 0 released at t = 0;
* ``two_adjacent`` (30 fps): corners 0 and 1 released: the cloth falls and swings under its held edge;
* ``two_diagonal`` (20 fps): corners 0 and 2 released;
* ``wave`` (30 fps): corner 0 released and corner 3 waved up and down (4 cm, 1.5 Hz) by a hand;
* ``lift`` (20 fps): nothing released; corners 2 and 3 lifted 10 cm and lowered again within 1.2 s.

A moving hand is declared in capture.json as a keyed handle path (``Handle(vertex, times, positions,
release_time)``, keys every 1/60 s) and the Warp truth drives that vertex along the same path, read
the same way (piecewise linear between the keys: ``warp_cloth.Pin.position``). The truth's settling is
``continuum_truth``'s: the hands come from the flat cloth to the first key, and it is damped still.

``takes-baseline`` fits each take alone as a new user would (``python -m clothfit fit CAP --model
blender --cameras n:4 --times <the 15 even frames>``, the default budget, one subprocess at a time) and
scores the result on every take of the material with ``python -m clothfit evaluate`` on the take's
8 held-out cameras and its 15 odd frames; the floor of a take is the truth's own held-out error (its
noise-free silhouettes against the noisy ones). One JSON file.

``takes-pairs`` fits every pair of three takes together (``python -m clothfit fit A B --model blender --cameras
n:4 --times odd``: each take's own 15 training frames) and scores each result the same way on all three, the
third a handling the fit never saw (evaluate replays it with its own handles at its own frame rate). With the
single-take rows of ``takes-baseline`` this is the docs' table per cloth (docs/results.md).
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass

import continuum_truth as CT
import numpy as np
import warp_cloth as W

FRAMES = 30  # frames of a take: the fit trains on the 15 even ones, the odd ones are held out
KEY_DT = 1.0 / 60.0  # s between the keys of a moving hand's path
WAVE_AMPLITUDE = 0.04  # m, up and down from the held position
WAVE_HZ = 1.5
LIFT_HEIGHT = 0.10  # m
LIFT_DURATION = 1.2  # s: up and down again (sin^2), then held where it started
BASELINE_TAKES = ("one_corner", "two_adjacent", "two_diagonal", "wave")  # lift: made, fitted when time allows


@dataclass(frozen=True)
class Take:
    """One handling of the cloth: corner indices (``ClothGrid.corners()`` order) released at t = 0,
    and corners moved by a hand along a path (corner index, path name)."""

    name: str
    fps: float
    released: tuple = ()
    moves: tuple = ()
    what: str = ""


TAKES = {
    t.name: t
    for t in (
        Take("one_corner", 20.0, (0,), (), "four corners held, corner 0 released"),
        Take("two_adjacent", 30.0, (0, 1), (), "corners 0 and 1 released: falls and swings under its held edge"),
        Take("two_diagonal", 20.0, (0, 2), (), "corners 0 and 2 released"),
        Take(
            "wave",
            30.0,
            (0,),
            ((3, "wave"),),
            f"corner 0 released, corner 3 waved up and down {WAVE_AMPLITUDE * 100:g} cm at {WAVE_HZ:g} Hz",
        ),
        Take(
            "lift",
            20.0,
            (),
            ((2, "lift"), (3, "lift")),
            f"corners 2 and 3 lifted {LIFT_HEIGHT * 100:g} cm and lowered within {LIFT_DURATION:g} s, none released",
        ),
    )
}


def frame_times(take, frames=FRAMES):
    return np.arange(1, frames + 1) / take.fps


def path_offsets(kind, end):
    """A hand's path as keys: times [s] from 0 every ``KEY_DT`` and displacements (K, 3) [m] from its hold."""
    if kind == "wave":
        t = np.arange(0.0, end + KEY_DT / 2, KEY_DT)
        dz = WAVE_AMPLITUDE * np.sin(2 * math.pi * WAVE_HZ * t)
    elif kind == "lift":
        t = np.arange(0.0, LIFT_DURATION + KEY_DT / 2, KEY_DT)
        dz = LIFT_HEIGHT * np.sin(math.pi * t / LIFT_DURATION) ** 2
    else:
        raise ValueError(f"unknown path {kind!r}")
    d = np.zeros((len(t), 3))
    d[:, 2] = dz
    return t, d


def corner_hands(take, end):
    """Per corner index (``ClothGrid.corners()`` order): (hold relative to the cloth's centre, release
    time or None, path key times or None, path positions relative to the centre or None)."""
    moves = dict(take.moves)
    out = []
    for k, (sx, sy) in enumerate(((-1, -1), (1, -1), (-1, 1), (1, 1))):
        hold = np.array([CT.HOLD * sx * CT.SIDE / 2, CT.HOLD * sy * CT.SIDE / 2, 0.0])
        release = 0.0 if k in take.released else None
        if k in moves:
            t, d = path_offsets(moves[k], end)
            out.append((hold, release, t, hold + d))
        else:
            out.append((hold, release, None, None))
    return out


def take_scenario(take, grid_n=CT.GRID_N, frames=FRAMES):
    """What a user declares for a take: the grid, its four corner handles (paths keyed), the frame times."""
    from clothfit.core.physics.scenario import ClothGrid, Handle, Scenario

    grid = ClothGrid(grid_n, grid_n, CT.SIDE, CT.HEIGHT)
    ft = frame_times(take, frames)
    centre = np.array([0.0, 0.0, CT.HEIGHT])
    handles = []
    for v, (hold, release, kt, kp) in zip(grid.corners(), corner_hands(take, ft[-1])):
        assert np.allclose(grid.rest[v][:2] * CT.HOLD, hold[:2])
        if kt is None:
            handles.append(Handle(v, [0.0], [centre + hold], release))
        else:
            handles.append(Handle(v, kt, centre + kp, release))
    return Scenario(grid, handles, ft, CT.SETTLE_SCENARIO)


def simulate_take(mat, take, times, n_truth=CT.TRUTH_N, settle=CT.SETTLE_TRUTH, dt=None):
    """The Warp truth of a take: (rest mesh, triangles, positions (F, V, 3) in the world, facts)."""
    V, tris = W.sheet_mesh(n_truth, CT.SIDE)
    corners = [0, n_truth - 1, n_truth * (n_truth - 1), n_truth * n_truth - 1]
    pins = []
    for v, (hold, release, kt, kp) in zip(corners, corner_hands(take, float(np.max(times)))):
        if kt is None:
            pins.append(W.Pin(v, tuple(hold), release))
        else:
            pins.append(W.Pin(v, tuple(hold), release, tuple(kt), tuple(map(tuple, kp))))
    X, facts = W.simulate(
        V,
        tris,
        mat,
        pins,
        times,
        settle=settle,
        ramp=min(CT.RAMP, settle / 2),
        origin=(0.0, 0.0, CT.HEIGHT),
        dt=dt,
    )
    return V, tris, X, facts


def make_takes(
    out,
    materials=("cotton", "silk"),
    takes=tuple(TAKES),
    n_truth=CT.TRUTH_N,
    grid_n=CT.GRID_N,
    settle=CT.SETTLE_TRUTH,
    frames=FRAMES,
    cameras=None,
    seed=0,
):
    """Write ``out/<material>_<take>`` and its ``_clean`` twin for every material and take; returns
    {folder name: path}."""
    cams = CT.rig() if cameras is None else cameras
    written = {}
    for name in materials:
        mat = CT.MATERIALS[name]
        for ti, tk in enumerate(takes):
            take = TAKES[tk]
            t0 = time.time()
            sc = take_scenario(take, grid_n, frames)
            V, tris, X, facts = simulate_take(mat, take, sc.frame_times, n_truth, settle)
            meta = CT.truth_meta(mat, n_truth, V, tris, settle, facts, seed + ti, take.fps)
            meta["take"] = {"name": take.name, "what": take.what, "released_corners": list(take.released)}
            meta["take"]["moving_corners"] = [{"corner": k, "path": p} for k, p in take.moves]
            root = os.path.join(out, f"{name}_{tk}")
            noisy, clean = CT.write_truth(
                root, cams, sc, V, tris, X, mat.areal_density * CT.SIDE * CT.SIDE, meta, seed + ti
            )
            written[os.path.basename(noisy)], written[os.path.basename(clean)] = noisy, clean
            print(
                f"made {name} {tk}: {len(X)} frames at {take.fps:g} fps, {facts['cpu_s']:.0f} cpu s, "
                f"{time.time() - t0:.0f} s -> {root}",
                flush=True,
            )
    return written


# ------------------------------------------------------------------------------------- baseline


def _split(cap):
    """The fit's frames (the even ones: 2, 4, ...) and the held-out ones (1, 3, ...), and the cameras."""
    from clothfit.core.observation.camera import select_training

    even, odd = CT.even_odd(cap)
    _, held = select_training(cap.cameras, CT.TRAIN_CAMERAS)
    return even, odd, held


def _fit(root, res, cap, max_evaluations, log):
    even, _, _ = _split(cap)
    args = ["fit", root, "--model", "blender", "--cameras", f"n:{CT.TRAIN_CAMERAS}", "--times", CT.times_arg(even)]
    args += ["--out", res, "--force", "--quiet"]
    if max_evaluations:
        args += ["--max-evaluations", str(max_evaluations)]
    load0 = os.getloadavg()[0]
    fit, wall = CT._cli(args, log)
    return args, fit, wall, load0


def _score(root, res, cap, log):
    """``evaluate`` of a result on a take's held-out cameras and frames: (row fields, the command)."""
    _, odd, held = _split(cap)
    args = ["evaluate", root, "--params", res, "--cameras", f"heldout:{CT.TRAIN_CAMERAS}", "--times", CT.times_arg(odd)]
    try:
        ev, _ = CT._cli(args, log)
    except SystemExit as e:  # recorded, not hidden: the row says what failed
        return {"evaluate_failed": str(e)}, args
    return {"heldout_E_sil_pct": ev["silhouette_error_pct"], "shape_error_mm": ev.get("shape_error_mm")}, args


def takes_baseline(out, json_path, materials=("cotton",), takes=BASELINE_TAKES, max_evaluations=None, refit=False):
    """Fit each take alone, score each result on every take of its material; one JSON (rows kept
    across runs for other materials and fitted takes; a finished result is reused unless ``refit``)."""
    from clothfit.core.jsonio import read_json, write_json
    from clothfit.core.observation.capture import load_capture

    rows = []
    if os.path.isfile(json_path):
        keep = {(m, t) for m in materials for t in takes}
        rows = [
            r
            for r in read_json(json_path, "takes baseline JSON").get("rows", [])
            if (r["material"], r["fitted_on"]) not in keep
        ]
    log = os.path.join(out, "takes_baseline.log")
    os.makedirs(os.path.join(out, "fits"), exist_ok=True)
    for m in materials:
        caps = {t: load_capture(os.path.join(out, f"{m}_{t}")) for t in takes}
        floors = {t: CT.floor(c, _split(c)[2], _split(c)[1]) for t, c in caps.items()}
        for ta in takes:
            root = os.path.join(out, f"{m}_{ta}")
            res = os.path.join(out, "fits", f"{m}_{ta}.json")
            fit_row = {"reused": True}
            if refit or not os.path.isfile(res):
                args, fit, wall, load0 = _fit(root, res, caps[ta], max_evaluations, log)
                fit_row = {"fit_command": "python -m clothfit " + " ".join(args), "fit_wall_s": wall}
                fit_row.update(load_1min_before=load0, evaluations=fit.get("evaluations"))
                fit_row.update(train_E_sil_pct=fit.get("best_E_sil_mean_pct"), fit_verdict_kind=fit.get("verdict_kind"))
            fitted = read_json(res, "fit result")
            fit_row.update(
                blender_cloth=fitted.get("blender_cloth"),
                blender_scene=fitted.get("blender_scene"),
                quality_choice=fitted.get("quality_choice"),
                fps_source=fitted.get("fps_source"),
                fit_verdict_kind=fitted.get("verdict_kind"),
                intervals=fitted.get("intervals"),
                undetermined=fitted.get("undetermined"),
            )
            for tb in takes:
                score, args = _score(os.path.join(out, f"{m}_{tb}"), res, caps[tb], log)
                r = {"material": m, "fitted_on": ta, "scored_on": tb, "floor_heldout_E_sil_pct": floors[tb]}
                r.update(score, evaluate_command="python -m clothfit " + " ".join(args), result=res)
                r.update(heldout=f"{len(_split(caps[tb])[2])} cameras x {len(_split(caps[tb])[1])} frames")
                if tb == ta:
                    r.update(fit_row)
                rows.append(r)
                print(format_row(r), flush=True)
                write_json(json_path, _doc(rows, max_evaluations))
    return rows


def _doc(rows, max_evaluations):
    return {
        "what": "continuum cloth (Warp), several takes: each take fitted alone by the blender model as a new "
        "user would, scored on every take of its material (held-out cameras and frames)",
        "takes": {k: {"fps": t.fps, "what": t.what} for k, t in TAKES.items()},
        "train_cameras": CT.TRAIN_CAMERAS,
        "frames": FRAMES,
        "max_evaluations": max_evaluations or "the CLI's default",
        "rows": rows,
    }


def format_row(r):
    if "evaluate_failed" in r:
        return f"{r['material']} {r['fitted_on']} -> {r['scored_on']}: evaluate failed: {r['evaluate_failed']}"
    return (
        f"{r['material']} {r['fitted_on']:>12s} -> {r['scored_on']:12s}: held-out {r['heldout_E_sil_pct']:7.2f} % "
        f"(floor {r['floor_heldout_E_sil_pct']:.2f} %), shape {r['shape_error_mm']:.2f} mm"
    )


def format_table(rows):
    out = [
        "| material | fitted on | scored on | held-out E_sil % | shape error mm | floor % |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        if "evaluate_failed" in r:
            out.append(f"| {r['material']} | {r['fitted_on']} | {r['scored_on']} | failed | | |")
            continue
        out.append(
            f"| {r['material']} | {r['fitted_on']} | {r['scored_on']} | {r['heldout_E_sil_pct']:.2f} | "
            f"{r['shape_error_mm']:.2f} | {r['floor_heldout_E_sil_pct']:.2f} |"
        )
    return "\n".join(out)


# ------------------------------------------------------------------------------------- pairs

PAIR_TAKES = ("one_corner", "two_adjacent", "wave")  # the docs' three takes of each material


def _fit_pair(out, m, ta, tb, res, max_evaluations, log):
    """Takes ``ta`` and ``tb`` of material ``m`` fitted together as a user would (``fit A B``); the odd frames
    of each take are its own training frames (the baseline's even/odd split), the held-out cameras left out."""
    args = ["fit", os.path.join(out, f"{m}_{ta}"), os.path.join(out, f"{m}_{tb}"), "--model", "blender"]
    args += ["--cameras", f"n:{CT.TRAIN_CAMERAS}", "--times", "odd", "--out", res, "--force", "--quiet"]
    if max_evaluations:
        args += ["--max-evaluations", str(max_evaluations)]
    load0 = os.getloadavg()[0]
    fit, wall = CT._cli(args, log)
    return args, fit, wall, load0


def takes_pairs(out, json_path, materials=("cotton",), takes=PAIR_TAKES, max_evaluations=None, refit=False, only=None):
    """Every pair of ``takes`` fitted together, the result scored on each of the three (the third: a handling the
    fit never saw); one JSON, rows kept across runs for other materials; a finished result is reused unless
    ``refit``; ``only``: the pairs to fit ("a+b" names), all when None. With the single-take rows of
    ``takes-baseline`` this is the docs' table per cloth."""
    from clothfit.core.jsonio import read_json, write_json
    from clothfit.core.observation.capture import load_capture

    rows = []
    if os.path.isfile(json_path):
        rows = [r for r in read_json(json_path, "takes pairs JSON").get("rows", []) if r["material"] not in materials]
    log = os.path.join(out, "takes_pairs.log")
    os.makedirs(os.path.join(out, "pairs"), exist_ok=True)
    for m in materials:
        caps = {t: load_capture(os.path.join(out, f"{m}_{t}")) for t in takes}
        floors = {t: CT.floor(c, _split(c)[2], _split(c)[1]) for t, c in caps.items()}
        for i, ta in enumerate(takes):
            for tb in takes[i + 1 :]:
                if only is not None and f"{ta}+{tb}" not in only:
                    continue
                res = os.path.join(out, "pairs", f"{m}_{ta}+{tb}.json")
                fit_row = {"reused": True}
                if refit or not os.path.isfile(res):
                    args, fit, wall, load0 = _fit_pair(out, m, ta, tb, res, max_evaluations, log)
                    fit_row = {"fit_command": "python -m clothfit " + " ".join(args), "fit_wall_s": wall}
                    fit_row.update(load_1min_before=load0)
                fitted = read_json(res, "fit result")
                fit_row.update(
                    evaluations=fitted.get("evaluations"),
                    train_E_sil_pct=fitted.get("best_E_sil_mean_pct"),
                    verdict_kind=fitted.get("verdict_kind"),
                    blender_cloth=fitted.get("blender_cloth"),
                    blender_scene=fitted.get("blender_scene"),
                    intervals=fitted.get("intervals"),
                    undetermined=fitted.get("undetermined"),
                    take_verdicts={e["take"]: e.get("verdict_kind") for e in fitted.get("takes") or []},
                )
                for tc in takes:
                    score, args = _score(os.path.join(out, f"{m}_{tc}"), res, caps[tc], log)
                    r = {"material": m, "fitted_on": f"{ta}+{tb}", "scored_on": tc, "seen": tc in (ta, tb)}
                    r.update(score, floor_heldout_E_sil_pct=floors[tc], result=res)
                    r.update(evaluate_command="python -m clothfit " + " ".join(args))
                    if tc == ta:
                        r.update(fit_row)
                    rows.append(r)
                    print(format_row(r), flush=True)
                    write_json(json_path, _pairs_doc(rows, max_evaluations))
    return rows


def _pairs_doc(rows, max_evaluations):
    return {
        "what": "continuum cloth (Warp), several takes: every pair of three takes fitted together by the blender "
        "model (fit A B, default options), scored on each take's held-out cameras and frames, the third a handling "
        "the fit never saw",
        "takes": {k: {"fps": t.fps, "what": t.what} for k, t in TAKES.items()},
        "train_cameras": CT.TRAIN_CAMERAS,
        "frames": FRAMES,
        "max_evaluations": max_evaluations or "the CLI's default",
        "rows": rows,
    }


def add_parsers(sub):
    """The ``takes`` and ``takes-baseline`` steps of ``lab/continuum_truth.py``."""
    k = sub.add_parser("takes", help="simulate several takes of one cloth in Warp and write their captures")
    k.add_argument("--out", default="out/takes", help="folder of the captures (default: %(default)s)")
    k.add_argument("--materials", default="cotton,silk", help="comma list (default: %(default)s)")
    k.add_argument("--takes", default=",".join(TAKES), help="comma list (default: %(default)s)")
    k.add_argument("--frames", type=int, default=FRAMES, help="frames per take (default: %(default)s)")
    b = sub.add_parser("takes-baseline", help="fit each take alone, score it on every take of its material")
    b.add_argument("--out", default="out/takes", help="folder of the captures (default: %(default)s)")
    b.add_argument("--json", required=True, help="write the rows to this JSON file")
    b.add_argument("--materials", default="cotton", help="comma list (default: %(default)s)")
    b.add_argument("--takes", default=",".join(BASELINE_TAKES), help="comma list (default: %(default)s)")
    b.add_argument("--max-evaluations", type=int, default=None, help="budget per fit (default: the CLI's own)")
    b.add_argument("--refit", action="store_true", help="fit again even where a result exists")
    q = sub.add_parser("takes-pairs", help="fit every pair of three takes together, score each result on all three")
    q.add_argument("--out", default="out/takes", help="folder of the captures (default: %(default)s)")
    q.add_argument("--json", required=True, help="write the rows to this JSON file")
    q.add_argument("--materials", default="cotton", help="comma list (default: %(default)s)")
    q.add_argument("--takes", default=",".join(PAIR_TAKES), help="three takes, comma list (default: %(default)s)")
    q.add_argument("--max-evaluations", type=int, default=None, help="budget per fit (default: the CLI's own)")
    q.add_argument("--refit", action="store_true", help="fit again even where a result exists")
    q.add_argument("--pairs", help="only these pairs, comma list of A+B (default: every pair)")


def run(a):
    def names(text, known):
        out = [x for x in text.split(",") if x]
        bad = [x for x in out if x not in known]
        if bad:
            raise SystemExit(f"unknown {bad[0]!r} (known: {', '.join(known)})")
        return out

    mats, takes = names(a.materials, list(CT.MATERIALS)), names(a.takes, list(TAKES))
    if a.step == "takes":
        make_takes(a.out, mats, takes, frames=a.frames)
    elif a.step == "takes-pairs":
        only = None if not a.pairs else [x for x in a.pairs.split(",") if x]
        print(format_table(takes_pairs(a.out, a.json, mats, takes, a.max_evaluations, a.refit, only)))
    else:
        print(format_table(takes_baseline(a.out, a.json, mats, takes, a.max_evaluations, a.refit)))
