"""ChArUco corners found in the footage of ``clothfit calibrate``: the input folder (images per
camera or one video per camera), the detector, the blur test (:func:`sharpness`), the detection
pass over every camera and moment (:func:`detect_views`), and the checks that tell a wrong board
or dictionary from bad footage. The steps of a calibration: ``calibrate.py``.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from .. import defaults as D
from ..errors import ClothFitError
from ..observation.camera import check_camera_name
from .calib_board import Board, dictionaries, natural_key

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

IMAGE_EXTS = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".webp")


# ========================================================================= detection


@dataclass
class View:
    """The board seen by one camera at one moment: ChArUco corner ids and their pixel positions."""

    camera: str
    moment: str
    ids: np.ndarray  # (n,) int corner ids
    points: np.ndarray  # (n, 2) float pixel positions (pixel centres at integers)
    markers: int = 0
    sharpness: float = float("nan")
    marker_ratio: float = float("nan")  # marker side measured against the chessboard / the board's marker side


class Detector:
    """ChArUco corners of one board in grey images (``cv2.aruco.CharucoDetector``, subpixel corners)."""

    def __init__(self, board: Board):
        import cv2

        self.board = board
        self.cv = cv2
        self.cvb = board.cv_board()
        dp = cv2.aruco.DetectorParameters()
        dp.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX  # marker corners: for the interpolation
        cp = cv2.aruco.CharucoParameters()
        cp.minMarkers = 1  # a corner needs one adjacent marker
        cp.tryRefineMarkers = True
        self.det = cv2.aruco.CharucoDetector(self.cvb, cp, dp)
        self.marker_obj = {
            int(i): np.asarray(o, np.float64).reshape(4, 3)[:, :2]
            for i, o in zip(np.asarray(self.cvb.getIds()).reshape(-1), self.cvb.getObjPoints())
        }

    def marker_ratio(
        self, ids: np.ndarray, pts: np.ndarray, mids: np.ndarray, mcorners: Sequence[np.ndarray] | None
    ) -> float:
        """The markers' side as the chessboard corners measure it (a homography from the corners, the
        marker corners mapped back), over the side the board definition gives: 1 when they match."""
        cv2 = self.cv
        if ids.size < 8 or mids.size == 0:
            return float("nan")
        H, _ = cv2.findHomography(pts, self.board.corners()[ids][:, :2], 0)
        if H is None:
            return float("nan")
        sides = []
        for m, c in zip(mids, mcorners):
            if int(m) not in self.marker_obj:
                continue
            q = cv2.perspectiveTransform(np.asarray(c, np.float64).reshape(-1, 1, 2), H).reshape(4, 2)
            sides.append(np.mean(np.linalg.norm(q - np.roll(q, 1, axis=0), axis=1)))
        return float(np.median(sides) / self.board.marker_m) if sides else float("nan")

    def detect(self, grey: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, Sequence[np.ndarray] | None]:
        """(corner ids, (n, 2) pixels, marker ids found) of the board in ``grey`` (uint8)."""
        ch_corners, ch_ids, m_corners, m_ids = self.det.detectBoard(grey)
        mids = np.zeros(0, int) if m_ids is None else np.asarray(m_ids).reshape(-1).astype(int)
        if ch_ids is None or len(ch_ids) == 0:
            return np.zeros(0, int), np.zeros((0, 2)), mids, m_corners
        ids = np.asarray(ch_ids).reshape(-1).astype(int)
        pts = self.refine(grey, ids, np.asarray(ch_corners, np.float64).reshape(-1, 2))
        ok = np.all(np.isfinite(pts), axis=1)
        return ids[ok], pts[ok], mids, m_corners

    def refine(self, grey: np.ndarray, ids: np.ndarray, pts: np.ndarray) -> np.ndarray:
        """The corners refined again by ``cv2.cornerSubPix`` in a window scaled to the local square size.

        OpenCV 4.7 to 4.12 return ChArUco corners shifted by +0.5 px in x and y (https://github.com/opencv/opencv/issues/25539,
        fixed by pull request 28380): their refinement shifts its input by -0.5 px and its output
        back by +0.5 px. ``cornerSubPix`` converges to the saddle point whatever its start, so refining
        again here removes that shift on every version (measured: tests/test_calibrate.py). The window is
        the white gap between a corner and the nearest marker edge, ``(square - marker) / 2``, in the
        image (times 0.8, 2..10 px): marker edges inside the window would pull the corner."""
        cv2 = self.cv
        if pts.shape[0] == 0:
            return pts
        P = self.board.corners()[ids][:, :2]
        # pixels per square near each corner: the shortest image distance to a corner one square away
        px_per_square = np.full(len(ids), np.nan)
        if pts.shape[0] > 1:
            d_img = np.linalg.norm(pts[:, None] - pts[None], axis=-1)
            d_brd = np.linalg.norm(P[:, None] - P[None], axis=-1) / self.board.square_m
            one = np.abs(d_brd - 1) < 1e-6
            d_img = np.where(one, d_img, np.inf)
            px_per_square = d_img.min(axis=1)
        fallback = np.nanmedian(px_per_square[np.isfinite(px_per_square)]) if np.isfinite(px_per_square).any() else 20
        px_per_square = np.where(np.isfinite(px_per_square), px_per_square, fallback)
        gap = 0.5 * (self.board.square_m - self.board.marker_m) / self.board.square_m * px_per_square
        out = pts.copy()
        crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 60, 1e-3)
        win = np.clip(np.floor(0.8 * gap), 2, 10).astype(int)
        for w in np.unique(win):
            sel = win == w
            p = pts[sel].astype(np.float32).reshape(-1, 1, 2).copy()
            out[sel] = cv2.cornerSubPix(grey, p, (int(w), int(w)), (-1, -1), crit).reshape(-1, 2)
        return self._consistent(grey, ids, P, out, win, crit)

    def _consistent(self, grey, ids, P, pts, win, crit):
        """Check every corner against its neighbours: a homography from the corners within two squares
        (at least 6, fitted robustly) predicts it; a corner further than ``CALIB_CORNER_CHECK_PX``
        from the prediction is refined again from the prediction, and dropped (NaN) if it is still off.
        (OpenCV's interpolation sometimes lands a corner a few pixels off on a steep, small board.)"""
        cv2 = self.cv
        if len(ids) < 7:
            return pts
        out = pts.copy()
        d = np.linalg.norm(P[:, None] - P[None], axis=-1) / self.board.square_m
        tol = D.CALIB_CORNER_CHECK_PX
        for k in range(len(ids)):
            nb = np.flatnonzero((d[k] <= 2.0 + 1e-6) & (np.arange(len(ids)) != k))
            if nb.size < 6:
                continue
            H, _ = cv2.findHomography(P[nb], pts[nb], cv2.RANSAC, 1.0)
            if H is None:
                continue
            q = H @ np.array([P[k, 0], P[k, 1], 1.0])
            pred = q[:2] / q[2]
            if np.linalg.norm(pred - pts[k]) <= tol:
                continue
            w = int(win[k])
            again = cv2.cornerSubPix(
                grey, pred.astype(np.float32).reshape(1, 1, 2).copy(), (w, w), (-1, -1), crit
            ).reshape(2)
            out[k] = again if np.linalg.norm(again - pred) <= tol else np.nan
        return out


def sharpness(grey: np.ndarray, points: np.ndarray) -> float:
    """How sharp the board looks: in the board's region (the bounding box of its detected corners),
    the 99th percentile of |d/dx| and of |d/dy| (Sobel / 8: a unit step spread over w pixels gives
    about 1/w), the smaller of the two (motion blur smears one direction), divided by the region's
    contrast (95th - 5th percentile of grey). About 1 / edge width in pixels, independent of the
    board's size in the image and of exposure."""
    import cv2

    if points.shape[0] < 2:
        return float("nan")
    h, w = grey.shape[:2]
    x0, y0 = np.floor(points.min(0)).astype(int)
    x1, y1 = np.ceil(points.max(0)).astype(int)
    x0, y0, x1, y1 = max(0, x0), max(0, y0), min(w, x1 + 1), min(h, y1 + 1)
    if x1 - x0 < 8 or y1 - y0 < 8:
        return float("nan")
    roi = grey[y0:y1, x0:x1].astype(np.float32)
    gx = np.abs(cv2.Sobel(roi, cv2.CV_32F, 1, 0, ksize=3)) / 8
    gy = np.abs(cv2.Sobel(roi, cv2.CV_32F, 0, 1, ksize=3)) / 8
    contrast = float(np.percentile(roi, 95) - np.percentile(roi, 5))
    if contrast <= 1:
        return 0.0
    return float(min(np.percentile(gx, 99), np.percentile(gy, 99)) / contrast)


# ============================================================================== inputs


@dataclass
class Source:
    """Where the frames come from: images per camera folder, or one video per camera."""

    kind: str  # "images" | "videos"
    folder: str
    cameras: list  # camera names, natural order
    images: dict = field(default_factory=dict)  # images: {camera: {moment: path}}
    videos: dict = field(default_factory=dict)  # videos: {camera: path}


def find_source(folder: str) -> Source:
    """The cameras of ``folder``: sub-folders of images, or videos ``<camera>.<ext>``; not both."""
    from .video import VIDEO_EXTS

    if not os.path.isdir(folder):
        raise ClothFitError(f"calibration folder not found: {folder}")
    entries = sorted(os.listdir(folder), key=natural_key)
    dirs = [e for e in entries if not e.startswith(".") and os.path.isdir(os.path.join(folder, e))]
    vids = [
        e
        for e in entries
        if not e.startswith(".")
        and os.path.splitext(e)[1].lower() in VIDEO_EXTS
        and os.path.isfile(os.path.join(folder, e))
    ]
    img_dirs = {}
    for d in dirs:
        files = [
            f
            for f in os.listdir(os.path.join(folder, d))
            if not f.startswith(".")
            and os.path.splitext(f)[1].lower() in IMAGE_EXTS
            and os.path.isfile(os.path.join(folder, d, f))
        ]
        if files:
            img_dirs[d] = files
    if img_dirs and vids:
        raise ClothFitError(
            f"calibration folder {folder}: holds both camera folders of images "
            f"({', '.join(list(img_dirs)[:3])}) and videos ({', '.join(vids[:3])}); keep one kind"
        )
    if vids:
        names = [os.path.splitext(v)[0] for v in vids]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ClothFitError(f"calibration folder {folder}: camera '{dup[0]}' has several videos; keep one")
        for n in names:
            check_camera_name(n, f"calibration folder {folder}")
        return Source("videos", folder, names, videos={os.path.splitext(v)[0]: os.path.join(folder, v) for v in vids})
    if not img_dirs:
        raise ClothFitError(
            f"calibration folder {folder}: no camera folders of images "
            f"(<camera>/<moment>.png|jpg) and no videos (<camera>.mp4|mov|mkv|avi)"
        )
    images = {}
    for d, files in img_dirs.items():
        check_camera_name(d, f"calibration folder {folder}")
        by_moment = {}
        for f in files:
            stem = os.path.splitext(f)[0]
            if stem in by_moment:
                raise ClothFitError(
                    f"camera folder {os.path.join(folder, d)}: moment '{stem}' has several images "
                    f"({os.path.basename(by_moment[stem])}, {f}); keep one"
                )
            by_moment[stem] = os.path.join(folder, d, f)
        images[d] = dict(sorted(by_moment.items(), key=lambda kv: natural_key(kv[0])))
    return Source("images", folder, list(images), images=images)


def read_grey(path: str) -> np.ndarray:
    """An image file as uint8 grey; one-line errors for missing, empty or unreadable files."""
    import cv2

    from .extract import read_image

    img = read_image(path)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    return np.clip(np.round(img), 0, 255).astype(np.uint8)


def moment_name(t: float) -> str:
    """The name of a video moment: its capture time in seconds, e.g. ``t0012.500``."""
    return f"t{t:08.3f}"


def video_times(
    videos: dict[str, str], sync: dict[str, float], every: float, times: Sequence[float] | None = None
) -> list[float]:
    """Capture times sampled every ``every`` s over the span all videos cover (or ``times`` checked)."""
    from .video import Video

    spans = {}
    for name, path in videos.items():
        v = Video(path)
        spans[name] = (v.start - sync[name], v.end - sync[name])
    lo = max(s[0] for s in spans.values())
    hi = min(s[1] for s in spans.values())
    if times is not None:
        bad = [t for t in times if not lo <= t < hi]
        if bad:
            raise ClothFitError(
                f"--times: {bad[0]:g} s is outside the span every video covers ({lo:.3f} .. {hi:.3f} s of capture time)"
            )
        return sorted(float(t) for t in times)
    if not hi > lo:
        raise ClothFitError(
            "the videos do not overlap in capture time (check the sync): "
            + ", ".join(f"{n} {a:.2f}..{b:.2f} s" for n, (a, b) in spans.items())
        )
    if not (math.isfinite(every) and every > 0):
        raise ClothFitError(f"--every {every:g}: must be a positive number of seconds")
    n = int(math.floor((hi - lo - 1e-6) / every)) + 1
    return [round(lo + i * every, 6) for i in range(n)]


# ====================================================================== detection pass


@dataclass
class Detections:
    """What :func:`detect_views` found: the views kept, the image sizes, and why others were dropped."""

    views: dict  # {camera: {moment: View}}
    sizes: dict  # {camera: (width, height)}
    stats: dict  # {camera: {"frames", "found", "few_corners", "blurred", ...}}
    marker_ids: set = field(default_factory=set)
    debug_frames: dict = field(default_factory=dict)  # {(camera, moment): encoded JPEG} when asked
    moments: list = field(default_factory=list)  # every moment read, natural order (the first = the world's)


def detect_views(
    source: Source,
    board: Board,
    min_corners: int = D.CALIB_MIN_CORNERS,
    blur_ratio: float = D.CALIB_BLUR_RATIO,
    sync: dict[str, float] | None = None,
    times: Sequence[float] | None = None,
    keep_frames: bool = False,
    progress: Callable[[int, int, str, str], object] | None = None,
) -> Detections:
    """Detect the board in every frame; keep the views with enough corners, not collinear, not blurred."""
    import cv2

    det = Detector(board)
    views, sizes, stats, debug = {}, {}, {}, {}
    all_markers: set = set()
    read: set = set()
    for ci, cam in enumerate(source.cameras):
        frames = _frames(source, cam, sync, times)
        found = {}
        sharp = {}
        st = {"frames": 0, "found": 0, "few_corners": 0, "collinear": 0, "blurred": 0, "markers_only": 0}
        for moment, grey, where in frames:
            st["frames"] += 1
            read.add(moment)
            h, w = grey.shape[:2]
            if cam not in sizes:
                sizes[cam] = (w, h)
            elif sizes[cam] != (w, h):
                raise ClothFitError(
                    f"{where}: {w}x{h} px but camera '{cam}''s other frames are "
                    f"{sizes[cam][0]}x{sizes[cam][1]} (one camera, one image size)"
                )
            ids, pts, mids, mcorners = det.detect(grey)
            all_markers.update(int(m) for m in mids)
            if keep_frames:
                ok, buf = cv2.imencode(".jpg", grey, [cv2.IMWRITE_JPEG_QUALITY, 85])
                debug[(cam, moment)] = (buf.tobytes(), mids, mcorners)
            if ids.size == 0:
                if mids.size:
                    st["markers_only"] += 1
                continue
            st["found"] += 1
            if ids.size < min_corners:
                st["few_corners"] += 1
                continue
            if _collinear(board, ids):
                st["collinear"] += 1
                continue
            found[moment] = View(
                cam, moment, ids, pts, int(mids.size), marker_ratio=det.marker_ratio(ids, pts, mids, mcorners)
            )
            sharp[moment] = sharpness(grey, pts)
            if progress:
                progress(ci, len(source.cameras), cam, moment)
        if blur_ratio > 0 and found:
            vals = np.array([v for v in sharp.values() if math.isfinite(v)])
            ref = float(np.median(vals)) if vals.size else float("nan")
            for m in list(found):
                found[m].sharpness = sharp[m]
                if math.isfinite(ref) and math.isfinite(sharp[m]) and sharp[m] < blur_ratio * ref:
                    del found[m]
                    st["blurred"] += 1
            st["median_sharpness"] = ref
        views[cam] = found
        st["views"] = len(found)
        stats[cam] = st
    return Detections(views, sizes, stats, all_markers, debug, sorted(read, key=natural_key))


def _frames(source: Source, cam: str, sync, times):
    """Yield (moment, grey uint8, where) of one camera."""
    if source.kind == "images":
        for moment, path in source.images[cam].items():
            yield moment, read_grey(path), f"image {path}"
        return
    import cv2

    from .video import Video

    v = Video(source.videos[cam])
    vts = [sync[cam] + t for t in times]
    # decode in batches so that a long video never sits in memory as a whole
    batch = D.CALIB_VIDEO_BATCH
    for i in range(0, len(times), batch):
        frames, _ = v.frames_at(vts[i : i + batch])
        for t, fr in zip(times[i : i + batch], frames):
            yield moment_name(t), cv2.cvtColor(fr, cv2.COLOR_BGR2GRAY), f"video {source.videos[cam]} at {t:.3f} s"


def _collinear(board: Board, ids: np.ndarray) -> bool:
    P = board.corners()[ids][:, :2]
    P = P - P.mean(0)
    s = np.linalg.svd(P, compute_uv=False)
    return bool(s.size < 2 or s[1] < 1e-6 * max(s[0], 1e-12) + 0.1 * board.square_m)


# ===================================================================== board mismatch


def check_detections(det: Detections, board: Board, source: Source) -> None:
    """One-line errors when nothing fits: the board found nowhere (and which dictionary the markers
    belong to, if another one), markers found but no corners (a board definition that does not
    match), marker ids the board does not have."""
    total_views = sum(len(v) for v in det.views.values())
    frames = sum(s["frames"] for s in det.stats.values())
    if frames == 0:
        raise ClothFitError(f"calibration folder {source.folder}: no frames to read")
    extra = sorted(i for i in det.marker_ids if i >= board.n_markers)
    in_board = [i for i in det.marker_ids if i < board.n_markers]
    if extra and len(extra) >= max(2, len(in_board) // 4):
        other = sniff_dictionary(source, board, det)  # a wrong dictionary decodes a print into stray ids too
        if other:
            raise ClothFitError(
                f"--board {board.text}: stray {board.dictionary} ids up to {max(extra)}, but {other} "
                f"markers are there: the board definition does not match the printed board "
                f"(its dictionary)"
            )
        raise ClothFitError(
            f"--board {board.text}: markers with ids up to {max(extra)} were found but this board has "
            f"ids 0..{board.n_markers - 1}: the board definition does not match the printed board "
            f"(its numbers of squares?)"
        )
    ratios = np.array([v.marker_ratio for vs in det.views.values() for v in vs.values()])
    ratios = ratios[np.isfinite(ratios)]
    if ratios.size >= 3 and abs(float(np.median(ratios)) - 1) > D.CALIB_MARKER_RATIO_TOL:
        r = float(np.median(ratios))
        raise ClothFitError(
            f"--board {board.text}: the markers measure {r * board.marker_m * 1000:.1f} mm against "
            f"the chessboard, the board definition says {board.marker_m * 1000:g} mm: the board "
            f"definition does not match the printed board (its marker size)"
        )
    if total_views == 0 and not any(s["found"] for s in det.stats.values()):
        markers_only = sum(s["markers_only"] for s in det.stats.values())
        if markers_only:
            raise ClothFitError(
                f"--board {board.text}: {board.dictionary} markers were found in {markers_only} "
                f"frames but no chessboard corner between them: the board definition does not match "
                f"the printed board (squares, sizes or --legacy-board)"
            )
        other = sniff_dictionary(source, board, det)
        if other:
            raise ClothFitError(
                f"--board {board.text}: no {board.dictionary} marker in any of {frames} frames, but "
                f"{other} markers are there: the board definition does not match the printed board "
                f"(its dictionary)"
            )
        raise ClothFitError(
            f"the board ({board.text}) was found in none of the {frames} frames of "
            f"{source.folder} (check the board definition, lighting and focus)"
        )


def sniff_dictionary(source: Source, board: Board, det: Detections, per_camera: int = 3) -> str | None:
    """The predefined dictionary whose markers the first frames show, when it is not the board's."""
    import cv2

    frames = []
    for cam in source.cameras:
        if source.kind == "images":
            for path in list(source.images[cam].values())[:per_camera]:
                frames.append(read_grey(path))
    if not frames:
        return None

    def count(name):
        d = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name)))
        n = 0
        for g in frames:
            _, ids, _ = d.detectMarkers(g)
            n += 0 if ids is None else len(ids)
        return n

    own = count(board.dictionary)  # stray decodings of another dictionary's print: a few, not most
    best, best_n = None, 0
    for name, (_bits, _size) in sorted(dictionaries().items(), key=lambda kv: (kv[1][0], kv[1][1])):
        if name == board.dictionary:
            continue
        n = count(name)
        if n > best_n + 1:
            best, best_n = name, n
    return best if best_n >= 3 and best_n > 2 * own else None
