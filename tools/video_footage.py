"""Video footage as phones record it, made here and extracted back: IoU against the true masks.

Writes, per camera, a video that starts at its own moment (sync time 0.3 .. 1.2 s before t = 0),
at a variable frame rate (intervals drawn from 1/40 .. 1/20 s, plus the frames at the capture
times), of the paper's cloth (ground truth) over a textured background, with sensor noise, a lossy
codec (H.264 via PyAV, yuv420p, CRF 23; one camera in Matroska, the rest MP4) and a flash 0.2 s
before t = 0; background plates as images for some cameras and as short videos of the empty scene
for the others; the calibration as EasyMocap intri.yml / extri.yml. Then runs
``python -m clothfit extract --videos ... --find-sync flash`` (or with the true sync file) and prints the
IoU of every extracted silhouette against the truth's own rasterised silhouette.

    python tools/video_footage.py --out out/video_footage [--cameras 6] [--resolution 480x640] [--sync true|flash]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from fractions import Fraction

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from clothfit.core import defaults as D  # noqa: E402
from clothfit.core.observation import camera as C  # noqa: E402
from clothfit.core.observation.raster import rasterize  # noqa: E402
from clothfit.core.physics.models import simulate  # noqa: E402
from clothfit.core.physics.scenario import paper_scenario  # noqa: E402

CAPTURE_TIMES = [0.05, 0.1, 0.2, 0.3, 0.45, 0.6, 0.8, 1.0]
FLASH_BEFORE = 0.2  # s before t = 0
CLOTH_BGR = (60, 110, 215)  # an orange-ish cloth


def background_texture(h, w, rng):
    """A textured background: smooth colour blotches at several scales plus a fine grain."""
    import cv2

    img = np.zeros((h, w, 3), np.float32)
    for scale, amp in ((64, 60), (16, 35), (4, 18)):
        small = rng.uniform(-1, 1, (max(2, h // scale), max(2, w // scale), 3)).astype(np.float32)
        img += amp * cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)
    return np.clip(img + np.array([120, 125, 110], np.float32), 0, 255)


def render(bg, cam, X, tris, rng, noise_sigma, ss=3, flash=0.0):
    """One camera frame: cloth (anti-aliased: ss x ss samples per pixel, shaded stripes) over ``bg``."""
    h, w = bg.shape[:2]
    big = cam.resized(h * ss, w * ss)
    cover = rasterize(big.project(X), tris, h * ss, w * ss).astype(np.float32)
    alpha = cover.reshape(h, ss, w, ss).mean((1, 3))[..., None]
    yy, xx = np.mgrid[0:h, 0:w]
    shade = (0.85 + 0.15 * np.sin(0.35 * xx + 0.2 * yy))[..., None]
    img = bg * (1 - alpha) + np.array(CLOTH_BGR, np.float32) * shade * alpha
    img = img * (1 + flash) + flash * 60
    img += rng.normal(0, noise_sigma, img.shape).astype(np.float32)
    return np.clip(img, 0, 255).astype(np.uint8)


def encode(path, frames, times, crf=23):
    """Write ``frames`` (BGR uint8) at presentation times ``times`` [s] (variable frame rate)."""
    import av

    h, w = frames[0].shape[:2]
    with av.open(path, "w") as c:
        st = c.add_stream("libx264", rate=30)
        st.width, st.height, st.pix_fmt = w, h, "yuv420p"
        st.time_base = Fraction(1, 1000)
        st.codec_context.time_base = Fraction(1, 1000)
        st.options = {"crf": str(crf), "preset": "veryfast"}
        for img, t in zip(frames, times):
            fr = av.VideoFrame.from_ndarray(img, format="bgr24")
            fr.pts = int(round(t * 1000))
            fr.time_base = Fraction(1, 1000)
            for pkt in st.encode(fr):
                c.mux(pkt)
        for pkt in st.encode():
            c.mux(pkt)


def write_easymocap(folder, cams):
    """EasyMocap's intri.yml / extri.yml (cv2.FileStorage, as its camera_utils writes them)."""
    import cv2

    os.makedirs(folder, exist_ok=True)
    fi = cv2.FileStorage(os.path.join(folder, "intri.yml"), cv2.FILE_STORAGE_WRITE)
    fe = cv2.FileStorage(os.path.join(folder, "extri.yml"), cv2.FILE_STORAGE_WRITE)
    names = [c.name for c in cams]
    for fs in (fi, fe):
        fs.startWriteStruct("names", cv2.FileNode_SEQ)
        for n in names:
            fs.write("", n)
        fs.endWriteStruct()
    for c in cams:
        fi.write(f"K_{c.name}", c.K)
        fi.write(f"dist_{c.name}", np.zeros((1, 5)))
        rvec = cv2.Rodrigues(c.R)[0]
        fe.write(f"R_{c.name}", rvec)
        fe.write(f"Rot_{c.name}", c.R)
        fe.write(f"T_{c.name}", c.t.reshape(3, 1))
    fi.release()
    fe.release()


def make_video_footage(
    root, n_cameras=4, resolution=(240, 320), seed=0, noise_sigma=4.0, times=CAPTURE_TIMES, plate_videos=True
):
    """Write videos/, plates/, sync.json, intri.yml/extri.yml under ``root``; return the truth:
    ``{"cameras", "times", "sync", "masks"[c][f]}``."""
    rng = np.random.default_rng(seed)
    rig = C.load_rig(D.DEFAULT_RIG)
    step = max(1, len(rig) // n_cameras)
    cams = [rig[i * step].resized(*resolution) for i in range(n_cameras)]
    tris = paper_scenario().grid.triangles
    vids, plates = os.path.join(root, "videos"), os.path.join(root, "plates")
    os.makedirs(vids, exist_ok=True)
    os.makedirs(plates, exist_ok=True)
    sync, plan = {}, []
    for cam in cams:
        s = round(float(rng.uniform(0.3, 1.2)), 3)  # video time at t = 0 (ms grid: container precision)
        sync[cam.name] = s
        vt = [0.0]
        while vt[-1] < s + times[-1] + 0.3:
            vt.append(vt[-1] + float(rng.uniform(1 / 40, 1 / 20)))
        must = [round(s + t, 3) for t in times] + [round(s - FLASH_BEFORE, 3)]
        vt = sorted(set([round(v, 3) for v in vt if all(abs(v - m) > 0.004 for m in must)] + must))
        plan.append(vt)
    # the cloth at every capture time any camera needs (before t = 0 it hangs settled: its t = 0 shape)
    need = sorted({round(v - sync[c.name], 3) for c, vt in zip(cams, plan) for v in vt if v - sync[c.name] > 0})
    sc = paper_scenario(frame_times=[0.0] + need)
    X = simulate(sc, [D.GT_PARAMS], safety=D.TRUTH_DT_SAFETY).positions[0]
    shape_at = {0.0: X[0]}
    shape_at.update({t: X[i + 1] for i, t in enumerate(need)})
    masks = []
    for ci, (cam, vt) in enumerate(zip(cams, plan)):
        bg = background_texture(cam.height, cam.width, rng)
        frames = []
        for v in vt:
            t = round(v - sync[cam.name], 3)
            flash = 0.6 if abs(t + FLASH_BEFORE) < 1e-9 else 0.0
            frames.append(render(bg, cam, shape_at[max(t, 0.0)], tris, rng, noise_sigma, flash=flash))
        ext = ".mkv" if ci == 0 else ".mp4"
        encode(os.path.join(vids, cam.name + ext), frames, vt)
        if plate_videos and ci % 2 == 1:
            empty = [np.clip(bg + rng.normal(0, noise_sigma, bg.shape), 0, 255).astype(np.uint8) for _ in range(12)]
            encode(os.path.join(plates, cam.name + ".mp4"), empty, [k / 30 for k in range(12)])
        else:
            import cv2

            plate = np.clip(bg + rng.normal(0, noise_sigma, bg.shape), 0, 255).astype(np.uint8)
            cv2.imwrite(os.path.join(plates, cam.name + ".png"), plate)
        masks.append([rasterize(cam.project(shape_at[round(t, 3)]), tris, cam.height, cam.width) for t in times])
    with open(os.path.join(root, "sync.json"), "w") as f:
        json.dump(sync, f, indent=1)
    write_easymocap(root, cams)
    return {"cameras": cams, "times": list(times), "sync": sync, "masks": masks}


def iou(a, b):
    return np.count_nonzero(a & b) / max(1, np.count_nonzero(a | b))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/video_footage")
    ap.add_argument("--cameras", type=int, default=6)
    ap.add_argument("--resolution", default="480x640")
    ap.add_argument("--noise", type=float, default=4.0, help="sensor noise sigma [grey levels]")
    ap.add_argument("--sync", choices=["true", "flash"], default="flash")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", help="also write the IoU figures to this file")
    a = ap.parse_args(argv)
    from clothfit.cli import main as cli
    from clothfit.core.observation.capture import load_capture

    res = [int(v) for v in a.resolution.split("x")]
    truth = make_video_footage(a.out, a.cameras, res, a.seed, a.noise)
    cap_dir = os.path.join(a.out, "capture")
    args = [
        "extract",
        "--videos",
        os.path.join(a.out, "videos"),
        "--plates",
        os.path.join(a.out, "plates"),
        "--cameras",
        a.out,
        "--times",
        ",".join(str(t) for t in truth["times"]),
        "--out",
        cap_dir,
        "--force",
    ]
    if a.sync == "flash":
        args += [
            "--find-sync",
            "flash",
            "--flash-time",
            str(-FLASH_BEFORE),
            "--sync",
            os.path.join(a.out, "sync_found.json"),
        ]
    else:
        args += ["--sync", os.path.join(a.out, "sync.json")]
    if cli(args) != 0:
        sys.exit(2)
    cap = load_capture(cap_dir)
    ious = np.array(
        [
            [iou(cap.load_silhouette(ci, fi), truth["masks"][ci][fi]) for fi in range(cap.n_frames)]
            for ci in range(cap.n_cameras)
        ]
    )
    for ci, cam in enumerate(cap.cameras):
        print(f"{cam.name}: IoU mean {ious[ci].mean():.4f}, worst {ious[ci].min():.4f}")
    print(
        f"mean IoU {ious.mean():.4f} (worst frame {ious.min():.4f}) over {ious.size} silhouettes, "
        f"{a.cameras} cameras at {a.resolution}, sync from {'the flash' if a.sync == 'flash' else 'sync.json'}"
    )
    if a.json:
        found = {}
        if a.sync == "flash":
            with open(os.path.join(a.out, "sync_found.json")) as f:
                found = json.load(f)
        with open(os.path.join(a.out, "sync.json")) as f:
            true_sync = json.load(f)
        out = {
            "cameras": [c.name for c in cap.cameras],
            "resolution": res,
            "sync": a.sync,
            "mean_iou": float(ious.mean()),
            "worst_iou": float(ious.min()),
            "camera_mean_iou": [float(v) for v in ious.mean(1)],
            "iou": ious.tolist(),
            "frame_times": [float(t) for t in cap.frame_times],
            "sync_error_s": {k: abs(found[k] - true_sync[k]) for k in found if k in true_sync},
            "worst_frame": {
                "camera": cap.cameras[int(np.argmin(ious.min(1)))].name,
                "time": float(cap.frame_times[int(np.argmin(ious.min(0)))]),
            },
        }
        out["max_sync_error_s"] = max(out["sync_error_s"].values(), default=None)
        with open(a.json, "w") as f:
            json.dump(out, f, indent=1)
    return ious


if __name__ == "__main__":
    main()
