"""Capture frames out of videos: one video per camera, read at exact times from container timestamps.

People film cloth with several phones or cameras started at different moments. The layout read here
is EasyMocap's ``videos/`` folder::

    videos/cam00.mp4  videos/cam01.mov  ...     one video per camera: <camera>.<mp4|mov|mkv|avi>
    plates/cam00.png  plates/cam01.mp4  ...     background plate per camera: an image (png/jpg) or a
                                                video of the empty scene (its per-pixel median frame)
    sync.json         {"cam00": 3.217, "cam01": 1.048, ...}: the video time [s] at which t = 0

Capture time ``t`` of camera ``c`` is video time ``sync[c] + t``. The frame taken is the one **on
display** at that time: the last frame whose presentation timestamp (from the container, so
variable frame rate works) is ``<=`` the video time, with a tolerance of ``TIME_TOL`` = 1 ms
(container timestamp precision: Matroska stores milliseconds). The report records, per frame,
the timestamp used and how far it lies before the asked time.

:func:`flash_sync` finds ``sync`` from a flash (or any sudden brightening, e.g. a light switched
on) seen by every camera: the frame with the largest rise of mean brightness marks the flash, and
``sync[c] = flash_video_time[c] - flash_time`` where ``flash_time`` is the capture time of the
flash (default 0). A clap needs audio and is not handled.

Videos are read with PyAV (``av``, FFmpeg) when it is installed, else with OpenCV's FFmpeg backend
(``cv2.VideoCapture``; what runs inside Blender, where the extension bundles OpenCV but not PyAV):
both give each frame's presentation timestamp from the container (tested: the same timestamps,
the same frames to within rounding of the colour conversion). ``CLOTHFIT_VIDEO_BACKEND=opencv``
forces OpenCV. Bad input is one line naming the file: a video that
does not open or has no video stream, a camera without a video or plate, a sync time outside the
video, a capture time past the video's end, a frame size different from the calibration.
"""

from __future__ import annotations

import math
import os
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import ClothFitError
from ..jsonio import read_json

if TYPE_CHECKING:
    from collections.abc import Callable, Collection, Sequence

    from ..observation.camera import Camera

VIDEO_EXTS = (".mp4", ".mov", ".mkv", ".avi")
PLATE_IMAGE_EXTS = (".png", ".jpg", ".jpeg")
TIME_TOL = 1e-3  # s: a frame starting up to this much after the asked time counts as on display
PLATE_FRAMES = 31  # frames of a plate video whose median is the plate


BACKENDS = ("av", "opencv")


def _av():
    try:
        import av
    except ImportError:
        raise ClothFitError("this video backend needs PyAV: pip install av (see requirements.txt)") from None
    return av


def default_backend() -> str:
    """``av`` when PyAV is importable (and not overridden by CLOTHFIT_VIDEO_BACKEND), else ``opencv``."""
    want = os.environ.get("CLOTHFIT_VIDEO_BACKEND", "").lower()
    if want in BACKENDS:
        return want
    import importlib.util

    return "av" if importlib.util.find_spec("av") is not None else "opencv"


def _open_error(path, e):
    detail = str(e).strip().splitlines()[0] if str(e).strip() else "no detail"
    return ClothFitError(f"video {path}: cannot be opened as a video ({type(e).__name__}: {detail})")


class _CvReader:
    """OpenCV's FFmpeg backend: frames in decode order with their presentation timestamps."""

    def __init__(self, path):
        import cv2

        self.cv2 = cv2
        self.cap = cv2.VideoCapture(path, cv2.CAP_FFMPEG)
        if not self.cap.isOpened():
            raise ClothFitError(f"video {path}: cannot be opened as a video (OpenCV's FFmpeg backend refuses it)")
        self.width = int(self.cap.get(cv2.CAP_PROP_FRAME_WIDTH))
        self.height = int(self.cap.get(cv2.CAP_PROP_FRAME_HEIGHT))

    def frames(self, decode):
        """Yield ``(timestamp [s], BGR frame or None)``; frames are decoded only when ``decode(t)``."""
        while self.cap.grab():
            t = self.cap.get(self.cv2.CAP_PROP_POS_MSEC) / 1000.0
            img = None
            if decode(t):
                ok, img = self.cap.retrieve()
                img = img if ok else None
            yield t, img

    def close(self):
        self.cap.release()


def find_camera_file(folder: str, camera: str, exts: Collection[str], what: str) -> str | None:
    """The file ``<camera><ext>`` in ``folder`` for one of ``exts`` (case-insensitive), or None;
    two candidates are an error."""
    if not os.path.isdir(folder):
        raise ClothFitError(f"{what} folder not found: {folder}")
    hits = sorted(
        f
        for f in os.listdir(folder)
        if os.path.splitext(f)[0] == camera
        and os.path.splitext(f)[1].lower() in exts
        and os.path.isfile(os.path.join(folder, f))
    )
    if len(hits) > 1:
        raise ClothFitError(
            f"{what} folder {folder}: camera '{camera}' has several files ({', '.join(hits)}); keep one"
        )
    return os.path.join(folder, hits[0]) if hits else None


class Video:
    """A video file's frame timestamps (s), size and end, from its container (PyAV: packets, no
    decoding; OpenCV: one pass over the frames)."""

    def __init__(self, path: str, backend: str | None = None):
        self.path = path
        self.backend = backend or default_backend()
        if self.backend not in BACKENDS:
            raise ClothFitError(f"video backend {self.backend!r} unknown (one of {', '.join(BACKENDS)})")
        if not os.path.isfile(path):
            raise ClothFitError(f"video {path}: file not found")
        if self.backend == "opencv":
            self._index_cv()
            return
        av = _av()
        try:
            with av.open(path) as c:
                if not c.streams.video:
                    raise ClothFitError(f"video {path}: has no video stream")
                st = c.streams.video[0]
                self.time_base = st.time_base
                self.width, self.height = st.codec_context.width, st.codec_context.height
                pts, durs = [], []
                for pkt in c.demux(st):
                    if pkt.pts is None:
                        continue
                    pts.append(int(pkt.pts))
                    durs.append(int(pkt.duration or 0))
        except ClothFitError:
            raise
        except Exception as e:  # av.error.InvalidDataError, FFmpegError, OSError ...
            raise _open_error(path, e) from None
        if not pts:
            raise ClothFitError(f"video {path}: holds no frames")
        order = np.argsort(pts, kind="stable")
        self.pts = np.asarray(pts, dtype=np.int64)[order]
        durs = np.asarray(durs, dtype=np.int64)[order]
        tb = float(self.time_base)
        self.times = self.pts * tb
        last = durs[-1] if durs[-1] > 0 else (np.median(np.diff(self.pts)) if self.pts.size > 1 else 0)
        self.start = float(self.times[0])
        self.end = float((self.pts[-1] + last) * tb)

    def _index_cv(self):
        r = _CvReader(self.path)
        try:
            self.width, self.height = r.width, r.height
            times = [t for t, _ in r.frames(lambda t: False)]
        finally:
            r.close()
        if not times:
            raise ClothFitError(f"video {self.path}: holds no frames (or OpenCV cannot decode them)")
        self.times = np.sort(np.asarray(times, dtype=np.float64))
        self.pts = np.round(self.times * 1e6).astype(np.int64)  # microseconds: the key of a frame
        last = float(np.median(np.diff(self.times))) if self.times.size > 1 else 0.0
        self.start = float(self.times[0])
        self.end = float(self.times[-1] + last)

    def _decode(self, want_keys, want_frames=True):
        """``{key: BGR frame}`` (or mean grey level when not ``want_frames``) of the frames with these keys
        (``None`` = all)."""
        got = {}
        if self.backend == "opencv":
            r = _CvReader(self.path)
            try:
                for t, img in r.frames(lambda t: want_keys is None or int(round(t * 1e6)) in want_keys):
                    if img is None:
                        continue
                    k = int(round(t * 1e6))
                    got[k] = img if want_frames else float(img.mean())
                    if want_keys is not None and len(got) == len(want_keys):
                        break
            finally:
                r.close()
            return got
        av = _av()
        with av.open(self.path) as c:
            for fr in c.decode(c.streams.video[0]):
                if want_keys is None or (fr.pts in want_keys and fr.pts not in got):
                    got[int(fr.pts)] = (
                        fr.to_ndarray(format="bgr24") if want_frames else float(fr.to_ndarray(format="gray").mean())
                    )
                    if want_keys is not None and len(got) == len(want_keys):
                        break
        return got

    def frame_index(self, video_time: float) -> int:
        """Index of the frame on display at ``video_time`` (see the module text)."""
        return int(np.searchsorted(self.times, video_time + TIME_TOL, side="right") - 1)

    def frames_at(
        self, video_times: Sequence[float], progress: Callable[[int, int], object] | None = None
    ) -> tuple[list[np.ndarray], list[float]]:
        """BGR uint8 frames on display at each of ``video_times``, and their timestamps [s]."""
        idx = [self.frame_index(t) for t in video_times]
        for t, i in zip(video_times, idx):
            if i < 0 or t > self.end:
                raise ClothFitError(
                    f"video {self.path}: time {t:.4f} s is outside the video ({self.start:.4f} .. {self.end:.4f} s)"
                )
        want = {int(self.pts[i]) for i in idx}
        try:
            got = self._decode(want)
        except ClothFitError:
            raise
        except Exception as e:
            raise ClothFitError(f"video {self.path}: decoding failed ({type(e).__name__}: {e})") from None
        if progress:
            progress(len(got), len(want))
        missing = sorted(want - set(got))
        if missing:
            tt = [float(self.times[np.searchsorted(self.pts, p)]) for p in missing[:5]]
            raise ClothFitError(
                f"video {self.path}: the frames at {', '.join(f'{t:.4f}' for t in tt)} s "
                f"are in the container but could not be decoded (a cut or corrupt file?)"
            )
        return [got[int(self.pts[i])] for i in idx], [float(self.times[i]) for i in idx]

    def sampled_frames(self, n: int) -> list[np.ndarray]:
        """About ``n`` frames spread evenly over the video (BGR uint8)."""
        pick = set(np.unique(np.linspace(0, self.pts.size - 1, min(n, self.pts.size)).round().astype(int)).tolist())
        frames, _ = self.frames_at([float(self.times[i]) for i in sorted(pick)])
        return frames

    def mean_brightness(self) -> np.ndarray:
        """Mean grey level of every frame, in timestamp order (for flash detection)."""
        try:
            vals = self._decode(None, want_frames=False)
        except ClothFitError:
            raise
        except Exception as e:
            raise ClothFitError(f"video {self.path}: decoding failed ({type(e).__name__}: {e})") from None
        return np.array([vals.get(int(p), np.nan) for p in self.pts])


def video_sizes(videos_dir: str) -> dict:
    """``{camera: (height, width)}`` of every video in ``videos_dir`` (for calibrations without image size)."""

    class Sizes(dict):
        source = videos_dir

    out = Sizes()
    if not os.path.isdir(videos_dir):
        raise ClothFitError(f"videos folder not found: {videos_dir}")
    for f in sorted(os.listdir(videos_dir)):
        stem, ext = os.path.splitext(f)
        if ext.lower() not in VIDEO_EXTS:
            continue
        p = os.path.join(videos_dir, f)
        if default_backend() == "opencv":
            r = _CvReader(p)
            out[stem] = (r.height, r.width)
            r.close()
            continue
        av = _av()
        try:
            with av.open(p) as c:
                if c.streams.video:
                    cc = c.streams.video[0].codec_context
                    out[stem] = (cc.height, cc.width)
        except Exception as e:
            raise _open_error(p, e) from None
    return out


def read_sync(path: str, camera_names: Collection[str]) -> dict[str, float]:
    """``{camera: video time [s] at t = 0}`` from a sync JSON file (an object camera -> seconds)."""
    d = read_json(path, "sync file")
    bad = {k: v for k, v in d.items() if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)}
    if bad:
        k = next(iter(bad))
        raise ClothFitError(f"sync file {path}: camera '{k}': {bad[k]!r} is not a time in seconds")
    missing = [n for n in camera_names if n not in d]
    if missing:
        raise ClothFitError(f"sync file {path}: no time for camera(s) {', '.join(missing)}")
    return {n: float(d[n]) for n in camera_names}


def flash_time_of(video: Video) -> float:
    """Timestamp [s] of the frame with the largest rise of mean brightness over its predecessor."""
    b = video.mean_brightness()
    if b.size < 2:
        raise ClothFitError(f"video {video.path}: too short to find a flash")
    rise = np.diff(b)
    i = int(np.nanargmax(rise))
    med = float(np.nanmedian(rise))
    spread = 1.4826 * float(np.nanmedian(np.abs(rise - med)))
    if not rise[i] > max(10.0 * spread, 10.0):
        raise ClothFitError(
            f"video {video.path}: no flash found (largest brightening {rise[i]:.1f} grey levels is "
            f"not clearly above the frame-to-frame changes, robust sigma {spread:.2f})"
        )
    return float(video.times[i + 1])


def flash_sync(
    videos_dir: str, camera_names: Collection[str], flash_time: float = 0.0, out_path: str | None = None
) -> dict[str, float]:
    """Sync times from a flash seen by every camera at capture time ``flash_time``; optionally
    written to ``out_path`` as a sync file."""
    sync = {}
    for name in camera_names:
        p = find_camera_file(videos_dir, name, VIDEO_EXTS, "videos")
        if p is None:
            raise ClothFitError(
                f"camera '{name}': no video {name}.<{'|'.join(e[1:] for e in VIDEO_EXTS)}> in {videos_dir}"
            )
        sync[name] = flash_time_of(Video(p)) - float(flash_time)
    if out_path:
        from ..jsonio import write_json

        write_json(out_path, sync)
    return sync


def read_plate(plates_dir: str, camera: Camera) -> tuple[np.ndarray, str]:
    """The background plate of a camera (BGR uint8) and where it came from."""
    img_path = find_camera_file(plates_dir, camera.name, PLATE_IMAGE_EXTS, "plates")
    vid_path = find_camera_file(plates_dir, camera.name, VIDEO_EXTS, "plates")
    if img_path and vid_path:
        raise ClothFitError(
            f"plates folder {plates_dir}: camera '{camera.name}' has both an image and a video plate "
            f"({os.path.basename(img_path)}, {os.path.basename(vid_path)}); keep one"
        )
    if img_path:
        import cv2

        img = cv2.imread(img_path, cv2.IMREAD_COLOR)
        if img is None:
            raise ClothFitError(f"plate {img_path}: unreadable image (not an image, corrupt or truncated)")
        src = img_path
    elif vid_path:
        v = Video(vid_path)
        frames = v.sampled_frames(PLATE_FRAMES)
        img = np.median(np.stack(frames), axis=0).astype(np.uint8)
        src = f"{vid_path} (median of {len(frames)} frames)"
    else:
        raise ClothFitError(f"camera '{camera.name}': no plate {camera.name}.<png|jpg|mp4|mov|mkv|avi> in {plates_dir}")
    if img.shape[:2] != (camera.height, camera.width):
        raise ClothFitError(
            f"plate {img_path or vid_path}: {img.shape[0]}x{img.shape[1]} (HxW) but camera "
            f"'{camera.name}' images {camera.height}x{camera.width}"
        )
    return img, src


def camera_frames(
    videos_dir: str,
    camera: Camera,
    sync_time: float,
    frame_times: Sequence[float],
    sync_path: str = "sync file",
    progress: Callable[[int, int], object] | None = None,
) -> tuple[list[np.ndarray], dict[str, Any]]:
    """The frames of one camera at the capture times, and a report (video, timestamps used)."""
    path = find_camera_file(videos_dir, camera.name, VIDEO_EXTS, "videos")
    if path is None:
        raise ClothFitError(
            f"camera '{camera.name}': no video {camera.name}.<{'|'.join(e[1:] for e in VIDEO_EXTS)}> in {videos_dir}"
        )
    v = Video(path)
    if (v.height, v.width) != (camera.height, camera.width):
        raise ClothFitError(
            f"video {path}: frames are {v.height}x{v.width} (HxW) but camera '{camera.name}' images "
            f"{camera.height}x{camera.width}"
        )
    if not (v.start - TIME_TOL <= sync_time <= v.end):
        raise ClothFitError(
            f"{sync_path}: camera '{camera.name}': sync time {sync_time:.4f} s is outside video {path} "
            f"({v.start:.4f} .. {v.end:.4f} s)"
        )
    vts = [sync_time + float(t) for t in frame_times]
    for t, vt in zip(frame_times, vts):
        if vt >= v.end:
            raise ClothFitError(
                f"video {path}: capture time {float(t):g} s is video time {vt:.4f} s, past the video's "
                f"end ({v.end:.4f} s)"
            )
    frames, used = v.frames_at(vts, progress)
    report = {
        "video": path,
        "sync": sync_time,
        "video_times": vts,
        "frame_timestamps": used,
        "lag_s": [vt - u for vt, u in zip(vts, used)],
        "frames_in_video": int(v.pts.size),
        "mean_fps": float((v.pts.size - 1) / (v.times[-1] - v.times[0])) if v.pts.size > 1 else None,
    }
    return frames, report
