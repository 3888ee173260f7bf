"""DiffCloud's real lifts (a cloth lifted from a table by one corner, point clouds of two depth cameras) fitted as a
user fits them: converted with ``clothfit points-to-capture``, each trial fitted alone with ``clothfit fit``, scored
with ``clothfit evaluate`` on the cameras and frames the fit did not see and against the real points themselves.

    python lab/real_lifts.py convert [--diffcloud out/diffcloud_real2sim] [--out out/real_lifts] [--fabrics paper,navy]
    python lab/real_lifts.py trials [--diffcloud DIR] [--out out/real_lifts] [--fabrics paper,navy] [--seed N] [--trials T,..] --json FILE
    python lab/real_lifts.py pairs [--diffcloud DIR] [--out out/real_lifts] [--fabrics paper,navy] --json FILE
    python lab/real_lifts.py pictures [--out out/real_lifts] [--fabrics paper,navy] [--images docs/img]

``DIR`` (default ``out/diffcloud_real2sim``) is a checkout of https://github.com/priyasundaresan/diffcloud_real2sim (no licence: nothing of it is copied
here; docs/point_clouds.md). ``convert`` writes ``OUT/setup.json`` (the constants below, read from that repository's
files) and one capture per trial (``OUT/<trial>``: ``paper``, ``paper2``, ``paper3``, ``navy`` ...). ``trials`` fits
each trial (``python -m clothfit fit CAP --model blender --cameras n:4 --times even``, the default budget; a finished
fit in ``OUT/fits`` is reused) and scores it: held-out E_sil (the 2 other cameras, the odd frames), the floor, the
mean distance of the real points to the fitted cloth over every kept frame (``points_mm``), the splatting's own error
(``splat_floor``: the floor the images' noise cannot show), the settings and their
90 % intervals, the fit's time (its result's ``elapsed_s``; wall and CPU time too when it ran here, with the load). One JSON file. ``pairs`` fits each fabric's first two trials together
(``OUT/pairs``) and predicts the third (``_predict``) beside the third fitted alone. ``pictures`` draws each
fabric's first trial: the real points (dark) on the fitted cloth (light, cropped as the fit saw it) at three frames
from two of the virtual cameras, ``IMAGES/real_lifts_<fabric>.png``.

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


def _heldout(cap: str, fr: dict) -> tuple[list, list]:
    """(the cameras, the frame times) of capture ``cap`` that the fit ``fr`` did not train on."""
    with open(os.path.join(cap, "cameras.json")) as f:
        names = [c["name"] for c in json.load(f)["cameras"]]
    with open(os.path.join(cap, "capture.json")) as f:
        times = json.load(f)["frame_times"]
    held = [n for n in names if n not in fr["train_cameras"]]
    return held, [t for t in times if min(abs(t - u) for u in fr["train_times"]) > 1e-6]


def _score(cap: str, fit: str, fr: dict) -> dict:
    held, odd = _heldout(cap, fr)
    h, _, _ = _clothfit(
        ["evaluate", cap, "--params", fit, "--cameras", ",".join(held), "--times", ",".join(map(str, odd))]
    )
    allf, _, _ = _clothfit(["evaluate", cap, "--params", fit])
    return {
        "heldout_E_sil_pct": h["silhouette_error_pct"],
        "points_mm": allf["points_mm"],
        "points_scatter_mm": allf["points_scatter_mm"],
        "points_mm_per_time": allf["points_mm_per_time"],
        "times": allf["times"],
    }


def _fitted(cap_dir: str, fit: str, times=None):
    """(the capture, the fitted cloth's vertices at ``times`` (default: every frame), the real points there)."""
    sys.path.insert(0, ROOT)
    from clothfit.core.observation.capture import load_capture
    from clothfit.core.observation.points import capture_points
    from clothfit.core.physics.models import model_and_row
    from clothfit.core.physics.scenario import fitted_scenario

    cap = load_capture(cap_dir)
    with open(fit) as f:
        fr = json.load(f)
    fidx = list(range(cap.n_frames)) if times is None else [cap.frame_index(t) for t in times]
    model, row = model_and_row(fr)
    sc = fitted_scenario(cap.scenario.with_frames([cap.frame_times[i] for i in fidx]), fr)
    return cap, model.simulate(sc, row[None]).positions[0], capture_points(cap, fidx)


def splat_floor(cap_dir: str, fit: str, seed: int = 0) -> float:
    """The splatting's own error [%] for the fitted cloth: sampled with as many points above the crop as each real
    frame keeps, splatted as the converter splats the real points, against the same cloth's silhouette (every
    camera and frame; ``point_clouds.splat_floor``). The converter states the same for Blender's default cloth
    before any fit (``meta.splat_floor``, which the fit's floor uses): the two side by side check that statement."""
    import numpy as np

    cap, X, _ = _fitted(cap_dir, fit)
    from clothfit.core.footage.point_clouds import splat_floor as stated

    m = cap.meta
    P = stated(
        cap.cameras,
        X,
        cap.scenario.grid.triangles,
        cap.scenario.crop,
        m["points_per_frame"],
        m["splat_radius_m"],
        m.get("erode_radius_m", 0.0),
        seed,
    )
    return 100.0 * float(np.nanmean(P))


def _fit(fit: str, caps: list, seed: int = 0) -> tuple[dict, float | None, float | None]:
    """(the result, wall s, CPU s) of the fit of ``caps`` together as a user fits them (``--seed`` where not 0); a
    finished ``fit`` is reused (then no times)."""
    wall = cpu = None
    if not os.path.exists(fit):
        with open(fit[: -len(".json")] + ".log", "w") as log:
            _, wall, cpu = _clothfit(
                ["fit", *caps, "--model", "blender", "--cameras", "n:4", "--times", "even", "--out", fit]
                + (["--seed", str(seed)] if seed else []),
                log,
            )
    with open(fit) as f:
        return json.load(f), wall, cpu


def _predict(cap: str, fit: str, alone: dict) -> dict:
    """A trial the fit ``fit`` never saw, scored as its own fit ``alone`` was, as a user scores it: its unknowns (the
    clock's stretch and offset, the grasp) fitted with the settings held on the cameras and frames its own fit
    trained on (``evaluate --unknowns-cameras --unknowns-times``), its held-out cameras and frames and its real
    points scored with them."""
    held, odd = _heldout(cap, alone)
    on = [
        "--unknowns-cameras",
        ",".join(alone["train_cameras"]),
        "--unknowns-times",
        ",".join(map(str, alone["train_times"])),
    ]
    h, _, _ = _clothfit(
        ["evaluate", cap, "--params", fit, "--cameras", ",".join(held), "--times", ",".join(map(str, odd)), *on]
    )
    allf, _, _ = _clothfit(["evaluate", cap, "--params", fit, *on])
    return {
        "manipulation": h["manipulation"],
        "time_scale": h.get("time_scale"),
        "time_offset_s": h.get("time_offset_s"),
        "heldout_E_sil_pct": h["silhouette_error_pct"],
        "points_mm": allf["points_mm"],
        "points_mm_per_time": allf["points_mm_per_time"],
    }


def pairs(a) -> None:
    """Per fabric: its first two trials fitted together, the third predicted (``_predict``) beside its own fit."""
    convert(a)
    os.makedirs(os.path.join(a.out, "pairs"), exist_ok=True)
    os.makedirs(os.path.join(a.out, "fits"), exist_ok=True)
    rows = []
    for fabric in a.fabrics.split(","):
        *two, third = TRIALS[fabric]
        load = os.getloadavg()
        fr, wall, cpu = _fit(
            os.path.join(a.out, "pairs", "+".join(two) + ".json"), [os.path.join(a.out, t) for t in two]
        )
        alone, _, _ = _fit(os.path.join(a.out, "fits", f"{third}.json"), [os.path.join(a.out, third)])
        cap = os.path.join(a.out, third)
        own = _score(cap, os.path.join(a.out, "fits", f"{third}.json"), alone)
        pred = _predict(cap, os.path.join(a.out, "pairs", "+".join(two) + ".json"), alone)
        row = {
            "fabric": fabric,
            "fitted": two,
            "predicted": third,
            "blender_cloth": fr.get("blender_cloth"),
            "intervals": fr.get("intervals"),
            "undetermined": fr.get("undetermined"),
            "verdict_kind": fr.get("verdict_kind"),
            "takes": [
                {
                    "take": t.get("take"),
                    "heldout_E_sil_pct": (t.get("floor") or {}).get("heldout_E_sil_pct"),
                    "heldout_floor_pct": (t.get("floor") or {}).get("heldout_floor_pct"),
                    "alone_E_sil_pct": t.get("alone_E_sil_pct"),
                }
                for t in fr.get("takes") or []
            ],
            "third_alone": {"heldout_E_sil_pct": own["heldout_E_sil_pct"], "points_mm": own["points_mm"]},
            "third_predicted": pred,
            "ratio_to_alone": pred["heldout_E_sil_pct"] / own["heldout_E_sil_pct"],
            "fit_elapsed_s": fr.get("elapsed_s"),
            "fit_wall_s": wall,
            "fit_cpu_s": cpu,
            "load": [round(x, 2) for x in load],
        }
        rows.append(row)
        print(
            f"{'+'.join(two)} -> {third}: held-out {pred['heldout_E_sil_pct']:.1f} % (alone "
            f"{own['heldout_E_sil_pct']:.1f} %), points {pred['points_mm']:.1f} mm",
            file=sys.stderr,
        )
    with open(a.json, "w") as f:
        json.dump({"rows": rows}, f, indent=1)


def trials(a) -> None:
    convert(a)  # the captures not made yet
    fits = os.path.join(a.out, "fits" if not a.seed else f"fits_seed{a.seed}")
    os.makedirs(fits, exist_ok=True)
    rows = []
    for fabric in a.fabrics.split(","):
        for trial in TRIALS[fabric]:
            if a.trials and trial not in a.trials.split(","):
                continue
            cap, fit = os.path.join(a.out, trial), os.path.join(fits, f"{trial}.json")
            load = os.getloadavg()
            fr, wall, cpu = _fit(fit, [cap], a.seed)
            fl = fr.get("floor") or {}
            row = {
                "fabric": fabric,
                "trial": trial,
                "seed": a.seed,
                "train_E_sil_pct": fl.get("train_E_sil_pct"),
                "train_floor_pct": fl.get("train_floor_pct"),
                "heldout_floor_pct": fl.get("heldout_floor_pct"),
                "verdict_kind": fr.get("verdict_kind"),
                "blender_cloth": fr.get("blender_cloth"),
                "intervals": fr.get("intervals"),
                "undetermined": fr.get("undetermined"),
                "time_scale": fr.get("time_scale"),
                "time_offset_s": fr.get("time_offset_s"),
                "fit_elapsed_s": fr.get("elapsed_s"),  # the fit's own time (its result's), reused or not
                "fit_wall_s": wall,
                "fit_cpu_s": cpu,
                "load": [round(x, 2) for x in load],
            }
            row.update(_score(cap, fit, fr))
            row["splat_floor_pct"] = splat_floor(cap, fit)
            with open(os.path.join(cap, "capture.json")) as f:
                row["splat_floor_stated_pct"] = 100.0 * json.load(f)["meta"]["splat_floor"]["mean"]
            rows.append(row)
            print(
                f"{trial}: held-out {row['heldout_E_sil_pct']:.1f} %, points {row['points_mm']:.1f} mm", file=sys.stderr
            )
    with open(a.json, "w") as f:
        json.dump({"rows": rows}, f, indent=1)


PICTURE_TIMES = (1.0, 1.6, 2.4)  # s: the cloth leaving the table, half lifted, hanging from its corner
PICTURE_CAMERAS = (0, 2)


def pictures(a) -> None:
    import cv2
    import numpy as np

    sys.path.insert(0, ROOT)
    from clothfit.core.observation.raster import silhouette

    for fabric in a.fabrics.split(","):
        trial = TRIALS[fabric][0]
        cap, X, pts = _fitted(os.path.join(a.out, trial), os.path.join(a.out, "fits", f"{trial}.json"), PICTURE_TIMES)

        tiles = []
        for c in PICTURE_CAMERAS:
            cam = cap.cameras[c].resized(480, 640)
            row_tiles = []
            for k, t in enumerate(PICTURE_TIMES):
                img = np.full((480, 640, 3), 255, np.uint8)
                img[silhouette(cam, X[k], cap.scenario.grid.triangles, crop=cap.scenario.crop)] = (200, 170, 120)
                uv = np.rint(cam.project(pts[k])).astype(int)
                ok = (uv[:, 0] >= 0) & (uv[:, 0] < 640) & (uv[:, 1] >= 0) & (uv[:, 1] < 480)
                for u, v in uv[ok]:
                    cv2.circle(img, (int(u), int(v)), 1, (40, 40, 160), -1)
                cv2.putText(img, f"{trial} {cam.name} t = {t:.1f} s", (10, 28), 0, 0.8, (0, 0, 0), 2)
                row_tiles.append(img)
            tiles.append(np.concatenate(row_tiles, 1))
        os.makedirs(a.images, exist_ok=True)
        path = os.path.join(a.images, f"real_lifts_{fabric}.png")
        cv2.imwrite(path, cv2.resize(np.concatenate(tiles, 0), None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA))
        print(f"wrote {path}", file=sys.stderr)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("convert")
    t = sub.add_parser("trials")
    t.add_argument("--json", required=True)
    t.add_argument("--seed", type=int, default=0, help="the fits' seed (fits of another seed in OUT/fits_seed<N>)")
    t.add_argument("--trials", help="only these trials (comma separated), e.g. navy,navy2")
    pr = sub.add_parser("pairs")
    pr.add_argument("--json", required=True)
    pic = sub.add_parser("pictures")
    pic.add_argument("--images", default=os.path.join(ROOT, "docs", "img"))
    for p in (c, t, pr, pic):
        p.add_argument("--diffcloud", default="out/diffcloud_real2sim")
        p.add_argument("--out", default="out/real_lifts")
        p.add_argument("--fabrics", default="paper,navy")
    a = ap.parse_args(argv)
    a.out = os.path.abspath(a.out)
    {"convert": convert, "trials": trials, "pairs": pairs, "pictures": pictures}[a.cmd](a)


if __name__ == "__main__":
    main()
