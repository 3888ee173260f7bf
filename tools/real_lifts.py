"""DiffCloud's real lifts (a cloth lifted from a table by one corner, point clouds of two depth cameras) fitted as a
user fits them: converted with ``clothfit points-to-capture``, each trial fitted alone with ``clothfit fit``, scored
with ``clothfit evaluate`` on the cameras and frames the fit did not see and against the real points themselves.

    python tools/real_lifts.py convert [--diffcloud out/diffcloud_real2sim] [--out out/real_lifts] [--fabrics paper,navy]
    python tools/real_lifts.py trials [--diffcloud DIR] [--out out/real_lifts] [--fabrics paper,navy] --json FILE

``DIR`` (default ``out/diffcloud_real2sim``) is a checkout of https://github.com/priyasundaresan/diffcloud_real2sim (no licence: nothing of it is copied
here; docs/point_clouds.md). ``convert`` writes ``OUT/setup.json`` (the constants below, read from that repository's
files) and one capture per trial (``OUT/<trial>``: ``paper``, ``paper2``, ``paper3``, ``navy`` ...). ``trials`` fits
each trial (``python -m clothfit fit CAP --model blender --cameras n:4 --times even``, the default budget; a finished
fit in ``OUT/fits`` is reused) and scores it: held-out E_sil (the 2 other cameras, the odd frames), the floor, the
mean distance of the real points to the fitted cloth over every kept frame (``points_mm``), the settings and their
90 % intervals, the wall and CPU time of the fit with the machine's load. One JSON file.

Only ``paper`` and ``navy`` are fitted here: DiffCloud's other fabrics (polka, redblack, tan) are kept apart for a
check the project's own tuning never saw.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TRIALS = {"paper": ("paper", "paper2", "paper3"), "navy": ("navy", "navy2", "navy3")}
CLOUDS = "sim/diffcloud/pysim/lift_real_pcls/lift_{trial}"
PATH = "real/kinova_percep/hardware/utils/trajs/lift_traj.npy"


def setup(diffcloud: str) -> dict:
    """The conversion of a lift (docs/point_clouds.md): DiffCloud's units (0.35 m), its robot-to-clouds frame
    (``lift_real2sim.yaml``), the diamond cloth (0.278 m side, its far corner towards -y), the table under it (the
    flat cloth's height, 4 mm below the gripper's first waypoint), a crop 7 mm above the flat cloth, silhouettes closed (discs of 8 mm eroded by 5 mm: 3500 points leave gaps in discs
    of 5 mm), the frames from
    0.8 s (before, almost nothing has left the table), and the unknowns a user cannot measure: the frame interval's
    stretch, the time offset and where the gripper holds the corner."""
    return {
        "unit_scale": 0.35,
        "frame_interval": 0.1,
        "splat_radius": 0.008,
        "erode_radius": 0.005,
        "cloth": {"side": 0.278, "grid": 16, "across": [0, -1, 0]},
        "path": {
            "file": os.path.join(os.path.abspath(diffcloud), PATH),
            "frame": {"translation": [0.67, 0.15, 0.0], "scale": 0.35, "z_rotation_deg": 90},
        },
        "crop": {"point": [0, 0, 0.085], "normal": [0, 0, 1]},
        "cameras": {"resolution": [240, 320]},
        "uncertain": {"time_scale": 1.4, "handles": 0.02, "time_offset": 0.2},
        "first_frame": 8,
        "colliders": [{"type": "plane", "point": [0, 0, 0.074], "normal": [0, 0, 1], "distance": 0.002, "friction": 5}],
        "collision_settings": {"distance_min": 0.002, "collision_quality": 2},
    }


def _clothfit(args: list, log=None) -> tuple[dict, float, float]:
    """(its JSON, wall s, CPU s of the child) of ``python -m clothfit ARGS``."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.time()
    p = subprocess.run([sys.executable, "-m", "clothfit", *args], capture_output=True, text=True, cwd=ROOT)
    wall = time.time() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if log is not None:
        log.write(p.stderr)
    if p.returncode != 0:
        raise SystemExit(f"clothfit {' '.join(args)} failed: {p.stderr.strip().splitlines()[-1:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return json.loads(p.stdout), wall, cpu


def convert(a) -> None:
    os.makedirs(a.out, exist_ok=True)
    sp = os.path.join(a.out, "setup.json")
    with open(sp, "w") as f:
        json.dump(setup(a.diffcloud), f, indent=1)
    for fabric in a.fabrics.split(","):
        for trial in TRIALS[fabric]:
            cap = os.path.join(a.out, trial)
            if os.path.exists(os.path.join(cap, "capture.json")):
                continue
            clouds = os.path.join(a.diffcloud, CLOUDS.format(trial=trial))
            r, _, _ = _clothfit(["points-to-capture", clouds, sp, "--out", cap])
            print(f"{trial}: {r['frames']} frames, left out {len(r['left_out'])}", file=sys.stderr)


def _score(cap: str, fit: str, fr: dict) -> dict:
    with open(os.path.join(cap, "cameras.json")) as f:
        names = [c["name"] for c in json.load(f)["cameras"]]
    with open(os.path.join(cap, "capture.json")) as f:
        times = json.load(f)["frame_times"]
    held = [n for n in names if n not in fr["train_cameras"]]
    odd = [t for t in times if min(abs(t - u) for u in fr["train_times"]) > 1e-6]
    h, _, _ = _clothfit(
        ["evaluate", cap, "--params", fit, "--cameras", ",".join(held), "--times", ",".join(map(str, odd))]
    )
    allf, _, _ = _clothfit(["evaluate", cap, "--params", fit])
    return {
        "heldout_E_sil_pct": h["silhouette_error_pct"],
        "points_mm": allf["points_mm"],
        "points_mm_per_time": allf["points_mm_per_time"],
        "times": allf["times"],
    }


def trials(a) -> None:
    convert(a)  # the captures not made yet
    fits = os.path.join(a.out, "fits")
    os.makedirs(fits, exist_ok=True)
    rows = []
    for fabric in a.fabrics.split(","):
        for trial in TRIALS[fabric]:
            cap, fit = os.path.join(a.out, trial), os.path.join(fits, f"{trial}.json")
            wall = cpu = None
            load = os.getloadavg()
            if not os.path.exists(fit):
                with open(os.path.join(fits, f"{trial}.log"), "w") as log:
                    _, wall, cpu = _clothfit(
                        ["fit", cap, "--model", "blender", "--cameras", "n:4", "--times", "even", "--out", fit], log
                    )
            with open(fit) as f:
                fr = json.load(f)
            fl = fr.get("floor") or {}
            row = {
                "fabric": fabric,
                "trial": trial,
                "train_E_sil_pct": fl.get("train_E_sil_pct"),
                "train_floor_pct": fl.get("train_floor_pct"),
                "heldout_floor_pct": fl.get("heldout_floor_pct"),
                "verdict_kind": fr.get("verdict_kind"),
                "blender_cloth": fr.get("blender_cloth"),
                "intervals": fr.get("intervals"),
                "undetermined": fr.get("undetermined"),
                "time_scale": fr.get("time_scale"),
                "time_offset_s": fr.get("time_offset_s"),
                "fit_wall_s": wall,
                "fit_cpu_s": cpu,
                "load": [round(x, 2) for x in load],
            }
            row.update(_score(cap, fit, fr))
            rows.append(row)
            print(
                f"{trial}: held-out {row['heldout_E_sil_pct']:.1f} %, points {row['points_mm']:.1f} mm", file=sys.stderr
            )
    with open(a.json, "w") as f:
        json.dump({"rows": rows}, f, indent=1)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("convert")
    t = sub.add_parser("trials")
    t.add_argument("--json", required=True)
    for p in (c, t):
        p.add_argument("--diffcloud", default="out/diffcloud_real2sim")
        p.add_argument("--out", default="out/real_lifts")
        p.add_argument("--fabrics", default="paper,navy")
    a = ap.parse_args(argv)
    a.out = os.path.abspath(a.out)
    {"convert": convert, "trials": trials}[a.cmd](a)


if __name__ == "__main__":
    main()
