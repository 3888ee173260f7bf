"""Multi-camera calibration from a ChArUco board (``clothfit calibrate``), no Blender.

Input: a folder with one folder of images per camera (``FOLDER/<camera>/<moment>.<png|jpg|...>``;
the same file name in two cameras is the same moment), or one video per camera
(``FOLDER/<camera>.<mp4|mov|mkv|avi>``, sampled at common capture times through the videos' sync,
see ``video.py``).

The steps, each its own function:

1. :func:`parse_board`: the board (``SQUARES_X,SQUARES_Y,SQUARE_M,MARKER_M,DICTIONARY``, OpenCV's
   ``CharucoBoard`` layout) checked;
2. :func:`detect_views`: ChArUco corners per image (``cv2.aruco.CharucoDetector``), a view kept
   when it has at least ``CALIB_MIN_CORNERS`` corners, not all on one line, and is not blurred
   (:func:`sharpness`: below ``CALIB_BLUR_RATIO`` x the camera's median sharpness = blurred);
3. :func:`initial_intrinsics`: per camera ``cv2.calibrateCamera`` on its own views (or the
   intrinsics given in a file, then the board poses by ``cv2.solvePnP``);
4. :func:`initial_extrinsics`: the cameras joined through the moments they share: relative poses
   averaged over the shared moments, along the spanning tree of most shared moments;
5. :func:`bundle_adjust`: every camera's intrinsics, distortion and pose and every moment's board
   pose refined jointly (``scipy.optimize.least_squares``, a sparse Jacobian, a robust loss), then
   corners and views far off their fit dropped and refined again;
6. :func:`world_frame`: the world is the board at the world moment (default: the first moment,
   by natural order of the names): origin at the centre of its chessboard, X along its squares_x
   direction, Y towards the top edge of the print, Z up out of the printed face, metres. Up is that
   board's normal unless a level board (``level``) or a gravity vector measured in one camera's
   frame (``gravity``) says otherwise; then Z is turned to up and X kept as close as possible to
   the board's X (its horizontal projection).

:func:`calibrate_folder` runs them all and returns the cameras and a report (per camera the
reprojection RMS, the views used and every view's RMS). Bad input is one ClothFitError line; this
module writes only what the caller asks, through :func:`write_outputs`, after everything
succeeded.
"""
from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, field

import numpy as np

from .. import defaults as D
from ..errors import ClothFitError
from ..observation.camera import Camera, check_camera_name

IMAGE_EXTS = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".webp")
DISTORTION_MODELS = {            # name -> which of (k1, k2, p1, p2, k3) are estimated
    "none": (),
    "k1": ("k1",),
    "k1k2": ("k1", "k2"),
    "k1k2p1p2": ("k1", "k2", "p1", "p2"),
    "k1k2p1p2k3": ("k1", "k2", "p1", "p2", "k3"),
}
DIST_ORDER = ("k1", "k2", "p1", "p2", "k3")
FLIP = np.diag([1.0, -1.0, -1.0])   # board axes (x right, y down the print, z into it) -> world (z out of the face)


# ============================================================================ the board

@dataclass(frozen=True)
class Board:
    """A ChArUco board in OpenCV's ``CharucoBoard`` layout (OpenCV >= 4.6; ``legacy``: the layout of
    older OpenCV, which differs only for an even number of rows)."""
    squares_x: int
    squares_y: int
    square_m: float
    marker_m: float
    dictionary: str
    legacy: bool = False

    @property
    def text(self) -> str:
        return f"{self.squares_x},{self.squares_y},{self.square_m:g},{self.marker_m:g},{self.dictionary}"

    @property
    def size_m(self) -> tuple:
        return self.squares_x * self.square_m, self.squares_y * self.square_m

    @property
    def n_markers(self) -> int:
        return self.squares_x * self.squares_y // 2

    @property
    def n_corners(self) -> int:
        return (self.squares_x - 1) * (self.squares_y - 1)

    def cv_dictionary(self):
        import cv2
        return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))

    def cv_board(self):
        import cv2
        b = cv2.aruco.CharucoBoard((self.squares_x, self.squares_y), float(self.square_m), float(self.marker_m),
                                   self.cv_dictionary())
        b.setLegacyPattern(bool(self.legacy))
        return b

    def corners(self) -> np.ndarray:
        """``(n_corners, 3)`` chessboard corners in the board frame [m], indexed by ChArUco corner id."""
        return np.asarray(self.cv_board().getChessboardCorners(), dtype=np.float64).reshape(-1, 3)

    def centre(self) -> np.ndarray:
        w, h = self.size_m
        return np.array([w / 2, h / 2, 0.0])

    def to_dict(self) -> dict:
        return {"squares_x": self.squares_x, "squares_y": self.squares_y, "square_m": self.square_m,
                "marker_m": self.marker_m, "dictionary": self.dictionary, "legacy": self.legacy, "text": self.text}


def dictionaries() -> dict:
    """``{name: (marker bits per side, markers)}`` of OpenCV's predefined ArUco dictionaries."""
    import cv2
    out = {}
    for name in dir(cv2.aruco):
        m = re.fullmatch(r"DICT_(\d)X\1_(\d+)", name)
        if m:
            out[name] = (int(m.group(1)), int(m.group(2)))
    for name in ("DICT_ARUCO_ORIGINAL", "DICT_ARUCO_MIP_36H12", "DICT_APRILTAG_16H5", "DICT_APRILTAG_25H9",
                 "DICT_APRILTAG_36H10", "DICT_APRILTAG_36H11"):
        if hasattr(cv2.aruco, name):
            d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))
            out[name] = (int(d.markerSize), int(d.bytesList.shape[0]))
    return out


def parse_board(text: str, legacy: bool = False) -> Board:
    """``SQUARES_X,SQUARES_Y,SQUARE_M,MARKER_M,DICTIONARY`` (e.g. ``9,7,0.04,0.03,DICT_5X5_100``) -> a
    checked :class:`Board`; one-line errors naming the part at fault."""
    parts = [p.strip() for p in str(text).split(",")]
    if len(parts) != 5:
        raise ClothFitError(f"--board {text!r}: expected SQUARES_X,SQUARES_Y,SQUARE_M,MARKER_M,DICTIONARY "
                            f"(e.g. 9,7,0.04,0.03,DICT_5X5_100)")
    try:
        sx, sy = int(parts[0]), int(parts[1])
    except ValueError:
        raise ClothFitError(f"--board {text!r}: the numbers of squares {parts[0]!r}, {parts[1]!r} must be "
                            f"whole numbers") from None
    try:
        sq, mk = float(parts[2]), float(parts[3])
    except ValueError:
        raise ClothFitError(f"--board {text!r}: the square and marker sizes {parts[2]!r}, {parts[3]!r} must be "
                            f"numbers in metres") from None
    name = parts[4].upper()
    if not name.startswith("DICT_"):
        name = "DICT_" + name
    if not (2 <= sx <= 100 and 2 <= sy <= 100) or sx * sy < 6:
        raise ClothFitError(f"--board {text!r}: {sx} x {sy} squares: need 2..100 per side and at least 6 squares "
                            f"(a ChArUco board needs inner corners)")
    if not (math.isfinite(sq) and 0.002 <= sq <= 2.0):
        raise ClothFitError(f"--board {text!r}: square size {sq:g} m outside 0.002..2 m (sizes are in metres: "
                            f"4 cm = 0.04)")
    if not (math.isfinite(mk) and 0 < mk < sq):
        raise ClothFitError(f"--board {text!r}: marker size {mk:g} m must be positive and smaller than the square "
                            f"({sq:g} m)")
    known = dictionaries()
    if name not in known:
        raise ClothFitError(f"--board {text!r}: unknown dictionary {parts[4]!r} (OpenCV's: "
                            f"{', '.join(sorted(known, key=_natural_key))})")
    b = Board(sx, sy, sq, mk, name, bool(legacy))
    if b.n_markers > known[name][1]:
        raise ClothFitError(f"--board {text!r}: {sx} x {sy} squares need {b.n_markers} markers but {name} has "
                            f"only {known[name][1]}")
    return b


def _natural_key(s: str):
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", s)]


# ================================================================== printable board

PDF_POINTS_PER_M = 72 / 0.0254


def make_board(board: Board, png_path: str | None, pdf_path: str | None, dpi: float = D.CALIB_BOARD_DPI,
               margin_m: float = D.CALIB_BOARD_MARGIN_M) -> dict:
    """Write a printable board: a PNG (``dpi`` pixels per inch, stored in its pHYs chunk, each square a
    whole number of pixels) and a vector PDF whose page is the board plus ``margin_m`` of white on every
    side, at the board's stated size (print at 100 %, no "fit to page"). Returns what was written."""
    import cv2

    from ..safeio import atomic_write
    if not (math.isfinite(dpi) and 50 <= dpi <= 2400):
        raise ClothFitError(f"--dpi {dpi:g}: must be within 50..2400")
    if not (math.isfinite(margin_m) and 0 <= margin_m <= 1):
        raise ClothFitError(f"--margin {margin_m:g} m: must be within 0..1 m")
    out = {"board": board.to_dict(), "size_m": list(board.size_m), "margin_m": margin_m}
    if png_path:
        px_per_square = max(1, int(round(board.square_m / 0.0254 * dpi)))
        px_dpi = px_per_square / (board.square_m / 0.0254)          # the exact dpi of whole-pixel squares
        margin_px = int(round(margin_m / 0.0254 * px_dpi))
        w = board.squares_x * px_per_square + 2 * margin_px
        h = board.squares_y * px_per_square + 2 * margin_px
        if w * h > 400_000_000:
            raise ClothFitError(f"--dpi {dpi:g}: a {w} x {h} px image is too large; lower --dpi")
        img = board.cv_board().generateImage((w, h), marginSize=margin_px, borderBits=1)
        ok, buf = cv2.imencode(".png", img)
        if not ok:
            raise ClothFitError(f"cannot encode the board image {png_path}")
        atomic_write(png_path, _png_with_dpi(buf.tobytes(), px_dpi))
        out.update(png=png_path, png_px=[w, h], png_dpi=px_dpi, png_px_per_square=px_per_square)
    if pdf_path:
        data, page = _board_pdf(board, margin_m)
        atomic_write(pdf_path, data)
        out.update(pdf=pdf_path, pdf_page_pt=page, pdf_page_mm=[round(p / PDF_POINTS_PER_M * 1000, 3) for p in page])
    return out


def _png_with_dpi(png: bytes, dpi: float) -> bytes:
    """The PNG with a pHYs chunk (pixels per metre) right after IHDR, so that it prints at its size."""
    from ..observation.png import _chunk
    ppm = int(round(dpi / 0.0254))
    ihdr_end = 8 + 8 + 13 + 4
    import struct
    return png[:ihdr_end] + _chunk(b"pHYs", struct.pack(">IIB", ppm, ppm, 1)) + png[ihdr_end:]


def _board_pdf(board: Board, margin_m: float) -> tuple:
    """A one-page vector PDF of the board (black squares and marker cells as filled rectangles) and
    its page size in points."""
    import cv2
    k = PDF_POINTS_PER_M
    bw, bh = board.size_m
    pw, ph = (bw + 2 * margin_m) * k, (bh + 2 * margin_m) * k
    cvb = board.cv_board()
    ids = np.asarray(cvb.getIds()).reshape(-1)
    objs = [np.asarray(o, dtype=np.float64).reshape(4, 3) for o in cvb.getObjPoints()]
    dic = board.cv_dictionary()
    bits = int(dic.markerSize) + 2
    rects = []                                            # (x, y, w, h) in board metres, y down the print

    def add(x, y, w, h):
        rects.append((x, y, w, h))
    marker_squares = set()
    for o in objs:
        cx, cy = o[:, 0].mean(), o[:, 1].mean()
        marker_squares.add((int(cx // board.square_m), int(cy // board.square_m)))
    for j in range(board.squares_y):
        for i in range(board.squares_x):
            if (i, j) not in marker_squares:
                add(i * board.square_m, j * board.square_m, board.square_m, board.square_m)
    for mid, o in zip(ids, objs):
        cell = cv2.aruco.generateImageMarker(dic, int(mid), bits, borderBits=1)
        x0, y0 = o[0, 0], o[0, 1]
        s = (o[1, 0] - o[0, 0]) / bits
        for r in range(bits):
            c = 0
            while c < bits:                                # runs of black cells as one rectangle
                if cell[r, c] < 128:
                    c1 = c
                    while c1 < bits and cell[r, c1] < 128:
                        c1 += 1
                    add(x0 + c * s, y0 + r * s, (c1 - c) * s, s)
                    c = c1
                else:
                    c += 1
    ops = ["0 g"]
    for x, y, w, h in rects:                               # PDF y goes up from the bottom of the page
        ops.append(f"{(x + margin_m) * k:.4f} {ph - (y + h + margin_m) * k:.4f} {w * k:.4f} {h * k:.4f} re f")
    caption = (f"ChArUco {board.text}{' legacy' if board.legacy else ''}: squares {board.square_m * 1000:g} mm, "
               f"markers {board.marker_m * 1000:g} mm. Print at 100 % (no fit to page); measure a square.")
    if margin_m * k >= 9:
        ops.append(f"BT /F1 7 Tf {max(2.0, margin_m * k * 0.25):.2f} {max(2.0, margin_m * k * 0.3):.2f} Td "
                   f"({_pdf_text(caption)}) Tj ET")
    content = "\n".join(ops).encode("ascii")
    objs_pdf = [b"<< /Type /Catalog /Pages 2 0 R >>",
                b"<< /Type /Pages /Kids [3 0 R] /Count 1 >>",
                f"<< /Type /Page /Parent 2 0 R /MediaBox [0 0 {pw:.4f} {ph:.4f}] /Contents 4 0 R "
                f"/Resources << /Font << /F1 5 0 R >> >> >>".encode("ascii"),
                b"<< /Length " + str(len(content)).encode() + b" >>\nstream\n" + content + b"\nendstream",
                b"<< /Type /Font /Subtype /Type1 /BaseFont /Helvetica >>"]
    out = bytearray(b"%PDF-1.4\n")
    offsets = []
    for i, body in enumerate(objs_pdf, 1):
        offsets.append(len(out))
        out += f"{i} 0 obj\n".encode() + body + b"\nendobj\n"
    xref = len(out)
    out += f"xref\n0 {len(objs_pdf) + 1}\n0000000000 65535 f \n".encode()
    for o in offsets:
        out += f"{o:010d} 00000 n \n".encode()
    out += f"trailer\n<< /Size {len(objs_pdf) + 1} /Root 1 0 R >>\nstartxref\n{xref}\n%%EOF\n".encode()
    return bytes(out), [round(pw, 4), round(ph, 4)]


def _pdf_text(s: str) -> str:
    return s.replace("\\", "\\\\").replace("(", "\\(").replace(")", "\\)")


# ========================================================================= detection

@dataclass
class View:
    """The board seen by one camera at one moment: ChArUco corner ids and their pixel positions."""
    camera: str
    moment: str
    ids: np.ndarray                 # (n,) int corner ids
    points: np.ndarray              # (n, 2) float pixel positions (pixel centres at integers)
    markers: int = 0
    sharpness: float = float("nan")
    marker_ratio: float = float("nan")   # marker side measured against the chessboard / the board's marker side


class Detector:
    """ChArUco corners of one board in grey images (``cv2.aruco.CharucoDetector``, subpixel corners)."""

    def __init__(self, board: Board):
        import cv2
        self.board = board
        self.cv = cv2
        self.cvb = board.cv_board()
        dp = cv2.aruco.DetectorParameters()
        dp.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX      # marker corners: for the interpolation
        cp = cv2.aruco.CharucoParameters()
        cp.minMarkers = 1                                                # a corner needs one adjacent marker
        cp.tryRefineMarkers = True
        self.det = cv2.aruco.CharucoDetector(self.cvb, cp, dp)
        self.marker_obj = {int(i): np.asarray(o, np.float64).reshape(4, 3)[:, :2]
                           for i, o in zip(np.asarray(self.cvb.getIds()).reshape(-1), self.cvb.getObjPoints())}

    def marker_ratio(self, ids, pts, mids, mcorners) -> float:
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

    def detect(self, grey: np.ndarray):
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

        OpenCV 4.7 to 4.12 return ChArUco corners shifted by +0.5 px in x and y (opencv/opencv issue
        25539, fixed by pull request 28380): their refinement shifts its input by -0.5 px and its output
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
            again = cv2.cornerSubPix(grey, pred.astype(np.float32).reshape(1, 1, 2).copy(), (w, w), (-1, -1),
                                     crit).reshape(2)
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
    kind: str                                  # "images" | "videos"
    folder: str
    cameras: list                              # camera names, natural order
    images: dict = field(default_factory=dict)  # images: {camera: {moment: path}}
    videos: dict = field(default_factory=dict)  # videos: {camera: path}


def find_source(folder: str) -> Source:
    """The cameras of ``folder``: sub-folders of images, or videos ``<camera>.<ext>``; not both."""
    from .video import VIDEO_EXTS
    if not os.path.isdir(folder):
        raise ClothFitError(f"calibration folder not found: {folder}")
    entries = sorted(os.listdir(folder), key=_natural_key)
    dirs = [e for e in entries if not e.startswith(".") and os.path.isdir(os.path.join(folder, e))]
    vids = [e for e in entries if not e.startswith(".") and os.path.splitext(e)[1].lower() in VIDEO_EXTS
            and os.path.isfile(os.path.join(folder, e))]
    img_dirs = {}
    for d in dirs:
        files = [f for f in os.listdir(os.path.join(folder, d))
                 if not f.startswith(".") and os.path.splitext(f)[1].lower() in IMAGE_EXTS
                 and os.path.isfile(os.path.join(folder, d, f))]
        if files:
            img_dirs[d] = files
    if img_dirs and vids:
        raise ClothFitError(f"calibration folder {folder}: holds both camera folders of images "
                            f"({', '.join(list(img_dirs)[:3])}) and videos ({', '.join(vids[:3])}); keep one kind")
    if vids:
        names = [os.path.splitext(v)[0] for v in vids]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ClothFitError(f"calibration folder {folder}: camera '{dup[0]}' has several videos; keep one")
        for n in names:
            check_camera_name(n, f"calibration folder {folder}")
        return Source("videos", folder, names, videos={os.path.splitext(v)[0]: os.path.join(folder, v) for v in vids})
    if not img_dirs:
        raise ClothFitError(f"calibration folder {folder}: no camera folders of images "
                            f"(<camera>/<moment>.png|jpg) and no videos (<camera>.mp4|mov|mkv|avi)")
    images = {}
    for d, files in img_dirs.items():
        check_camera_name(d, f"calibration folder {folder}")
        by_moment = {}
        for f in files:
            stem = os.path.splitext(f)[0]
            if stem in by_moment:
                raise ClothFitError(f"camera folder {os.path.join(folder, d)}: moment '{stem}' has several images "
                                    f"({os.path.basename(by_moment[stem])}, {f}); keep one")
            by_moment[stem] = os.path.join(folder, d, f)
        images[d] = dict(sorted(by_moment.items(), key=lambda kv: _natural_key(kv[0])))
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


def video_times(videos: dict, sync: dict, every: float, times=None) -> list:
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
            raise ClothFitError(f"--times: {bad[0]:g} s is outside the span every video covers "
                                f"({lo:.3f} .. {hi:.3f} s of capture time)")
        return sorted(float(t) for t in times)
    if not hi > lo:
        raise ClothFitError("the videos do not overlap in capture time (check the sync): " +
                            ", ".join(f"{n} {a:.2f}..{b:.2f} s" for n, (a, b) in spans.items()))
    if not (math.isfinite(every) and every > 0):
        raise ClothFitError(f"--every {every:g}: must be a positive number of seconds")
    n = int(math.floor((hi - lo - 1e-6) / every)) + 1
    return [round(lo + i * every, 6) for i in range(n)]


# ====================================================================== detection pass

@dataclass
class Detections:
    """What :func:`detect_views` found: the views kept, the image sizes, and why others were dropped."""
    views: dict                                # {camera: {moment: View}}
    sizes: dict                                # {camera: (width, height)}
    stats: dict                                # {camera: {"frames", "found", "few_corners", "blurred", ...}}
    marker_ids: set = field(default_factory=set)
    debug_frames: dict = field(default_factory=dict)   # {(camera, moment): encoded JPEG} when asked
    moments: list = field(default_factory=list)        # every moment read, natural order (the first = the world's)


def detect_views(source: Source, board: Board, min_corners: int = D.CALIB_MIN_CORNERS,
                 blur_ratio: float = D.CALIB_BLUR_RATIO, sync: dict | None = None, times=None,
                 keep_frames: bool = False, progress=None) -> Detections:
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
                raise ClothFitError(f"{where}: {w}x{h} px but camera '{cam}''s other frames are "
                                    f"{sizes[cam][0]}x{sizes[cam][1]} (one camera, one image size)")
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
            found[moment] = View(cam, moment, ids, pts, int(mids.size),
                                 marker_ratio=det.marker_ratio(ids, pts, mids, mcorners))
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
    return Detections(views, sizes, stats, all_markers, debug, sorted(read, key=_natural_key))


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
        frames, _ = v.frames_at(vts[i:i + batch])
        for t, fr in zip(times[i:i + batch], frames):
            yield moment_name(t), cv2.cvtColor(fr, cv2.COLOR_BGR2GRAY), f"video {source.videos[cam]} at {t:.3f} s"


def _collinear(board: Board, ids: np.ndarray) -> bool:
    P = board.corners()[ids][:, :2]
    P = P - P.mean(0)
    s = np.linalg.svd(P, compute_uv=False)
    return bool(s.size < 2 or s[1] < 1e-6 * max(s[0], 1e-12) + 0.1 * board.square_m)


# ===================================================================== board mismatch

def check_detections(det: Detections, board: Board, source: Source):
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
        other = sniff_dictionary(source, board, det)    # a wrong dictionary decodes a print into stray ids too
        if other:
            raise ClothFitError(f"--board {board.text}: stray {board.dictionary} ids up to {max(extra)}, but {other} "
                                f"markers are there: the board definition does not match the printed board "
                                f"(its dictionary)")
        raise ClothFitError(f"--board {board.text}: markers with ids up to {max(extra)} were found but this board has "
                            f"ids 0..{board.n_markers - 1}: the board definition does not match the printed board "
                            f"(its numbers of squares?)")
    ratios = np.array([v.marker_ratio for vs in det.views.values() for v in vs.values()])
    ratios = ratios[np.isfinite(ratios)]
    if ratios.size >= 3 and abs(float(np.median(ratios)) - 1) > D.CALIB_MARKER_RATIO_TOL:
        r = float(np.median(ratios))
        raise ClothFitError(f"--board {board.text}: the markers measure {r * board.marker_m * 1000:.1f} mm against "
                            f"the chessboard, the board definition says {board.marker_m * 1000:g} mm: the board "
                            f"definition does not match the printed board (its marker size)")
    if total_views == 0 and not any(s["found"] for s in det.stats.values()):
        markers_only = sum(s["markers_only"] for s in det.stats.values())
        if markers_only:
            raise ClothFitError(f"--board {board.text}: {board.dictionary} markers were found in {markers_only} "
                                f"frames but no chessboard corner between them: the board definition does not match "
                                f"the printed board (squares, sizes or --legacy-board)")
        other = sniff_dictionary(source, board, det)
        if other:
            raise ClothFitError(f"--board {board.text}: no {board.dictionary} marker in any of {frames} frames, but "
                                f"{other} markers are there: the board definition does not match the printed board "
                                f"(its dictionary)")
        raise ClothFitError(f"the board ({board.text}) was found in none of the {frames} frames of "
                            f"{source.folder} (check the board definition, lighting and focus)")


def sniff_dictionary(source: Source, board: Board, det: Detections, per_camera: int = 3):
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
    own = count(board.dictionary)        # stray decodings of another dictionary's print: a few, not most
    best, best_n = None, 0
    for name, (bits, size) in sorted(dictionaries().items(), key=lambda kv: (kv[1][0], kv[1][1])):
        if name == board.dictionary:
            continue
        n = count(name)
        if n > best_n + 1:
            best, best_n = name, n
    return best if best_n >= 3 and best_n > 2 * own else None


# ================================================================= camera geometry

def rodrigues(r: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(N, 3, 3)`` of rotation vectors ``(N, 3)`` (Rodrigues' formula, vectorised;
    first order below 1e-12 rad)."""
    r = np.asarray(r, dtype=np.float64).reshape(-1, 3)
    th = np.linalg.norm(r, axis=1)
    small = th < 1e-12
    k = r / np.where(small, 1.0, th)[:, None]
    z = np.zeros(len(r))
    Kx = np.stack([np.stack([z, -k[:, 2], k[:, 1]], -1), np.stack([k[:, 2], z, -k[:, 0]], -1),
                   np.stack([-k[:, 1], k[:, 0], z], -1)], 1)
    s, c = np.sin(th)[:, None, None], (1 - np.cos(th))[:, None, None]
    R = np.eye(3)[None] + s * Kx + c * (Kx @ Kx)
    rx = np.stack([np.stack([z, -r[:, 2], r[:, 1]], -1), np.stack([r[:, 2], z, -r[:, 0]], -1),
                   np.stack([-r[:, 1], r[:, 0], z], -1)], 1)
    return np.where(small[:, None, None], np.eye(3)[None] + rx, R)


def rotvec(R: np.ndarray) -> np.ndarray:
    import cv2
    return cv2.Rodrigues(np.asarray(R, dtype=np.float64))[0].reshape(3)


def project_points(X_cam: np.ndarray, fx, fy, cx, cy, dist) -> np.ndarray:
    """Pixels of camera-frame points with OpenCV's (k1, k2, p1, p2, k3) distortion; all arrays
    broadcast per point."""
    z = X_cam[:, 2]
    x = X_cam[:, 0] / z
    y = X_cam[:, 1] / z
    k1, k2, p1, p2, k3 = (dist[:, i] for i in range(5))
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([fx * xd + cx, fy * yd + cy], -1)


def _mean_rotation(Rs) -> np.ndarray:
    """Robust mean of rotations: the medoid, then the chordal mean of those within 5 degrees of it."""
    Rs = np.asarray(Rs)
    if len(Rs) == 1:
        return Rs[0]
    tr = np.einsum("aij,bij->ab", Rs, Rs)
    ang = np.arccos(np.clip((tr - 1) / 2, -1, 1))
    med = int(np.argmin(ang.sum(1)))
    keep = ang[med] < math.radians(5.0)
    U, _, Vt = np.linalg.svd(Rs[keep].sum(0))
    R = U @ Vt
    if np.linalg.det(R) < 0:
        U[:, -1] *= -1
        R = U @ Vt
    return R


def rotation_angle_deg(R: np.ndarray) -> float:
    return math.degrees(math.acos(max(-1.0, min(1.0, (float(np.trace(R)) - 1) / 2))))


# ========================================================================= options

@dataclass
class Options:
    """How to calibrate (the CLI's options; every default in ``defaults.py``)."""
    distortion: str = D.CALIB_DISTORTION
    square_pixels: bool = True                 # fx = fy
    shared: bool = False                       # one set of intrinsics for every camera (same phone model)
    fixed: dict = field(default_factory=dict)  # {camera: Camera} whose intrinsics are held fixed
    world: str | None = None                   # moment of the world board (default: the first moment)
    level: str | None = None                   # a moment where the board lies level (its normal = up)
    gravity: tuple | None = None               # (camera, (gx, gy, gz)): gravity in that camera's frame
    min_views: int = D.CALIB_MIN_VIEWS
    min_corners: int = D.CALIB_MIN_CORNERS
    blur_ratio: float = D.CALIB_BLUR_RATIO
    loss: str = D.CALIB_LOSS
    loss_scale_px: float = D.CALIB_LOSS_SCALE_PX
    outlier_px: float = D.CALIB_OUTLIER_PX

    def check(self):
        if self.distortion not in DISTORTION_MODELS:
            raise ClothFitError(f"--distortion {self.distortion!r}: one of {', '.join(DISTORTION_MODELS)}")
        if self.loss not in ("linear", "huber", "soft_l1", "cauchy"):
            raise ClothFitError(f"--loss {self.loss!r}: one of linear, huber, soft_l1, cauchy")
        for nm, v, lo in (("--min-views", self.min_views, 1), ("--min-corners", self.min_corners, 4)):
            if not isinstance(v, int) or v < lo:
                raise ClothFitError(f"{nm} {v!r}: must be a whole number >= {lo}")
        if not (0 <= self.blur_ratio < 1):
            raise ClothFitError(f"--blur-ratio {self.blur_ratio:g}: must be within 0..1 (0 = keep blurred frames)")
        if not (self.loss_scale_px > 0 and self.outlier_px > 0):
            raise ClothFitError("the loss scale and the outlier threshold must be positive pixels")
        if self.gravity is not None:
            g = np.asarray(self.gravity[1], float)
            if g.shape != (3,) or not np.all(np.isfinite(g)) or np.linalg.norm(g) < 1e-9:
                raise ClothFitError(f"--gravity {self.gravity[0]}:{self.gravity[1]}: needs three numbers, not all zero")
        if self.level is not None and self.gravity is not None:
            raise ClothFitError("--level and --gravity both say where up is: give one of them")
        return self


# ================================================================= initial estimates

@dataclass
class Intrinsics:
    K: np.ndarray
    dist: np.ndarray               # 5 coefficients k1, k2, p1, p2, k3
    fixed: bool = False


def _obj_img(board: Board, views):
    P = board.corners()
    obj = [P[v.ids].astype(np.float32) for v in views]
    img = [v.points.reshape(-1, 1, 2).astype(np.float32) for v in views]
    return obj, img


def _cv_flags(opts: Options) -> int:
    import cv2
    est = set(DISTORTION_MODELS[opts.distortion])
    f = 0
    if opts.square_pixels:
        f |= cv2.CALIB_FIX_ASPECT_RATIO
    if "k1" not in est:
        f |= cv2.CALIB_FIX_K1
    if "k2" not in est:
        f |= cv2.CALIB_FIX_K2
    if "k3" not in est:
        f |= cv2.CALIB_FIX_K3
    if "p1" not in est:
        f |= cv2.CALIB_ZERO_TANGENT_DIST
    return f


def initial_intrinsics(board: Board, views: dict, sizes: dict, opts: Options):
    """Per camera: (Intrinsics, {moment: (R, t) board -> camera}) from its own views; with
    ``opts.shared`` one calibrateCamera over every camera's views; fixed cameras: solvePnP."""
    import cv2
    intr, poses = {}, {}
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-10)
    free = [c for c in views if c not in opts.fixed]
    if opts.shared and free:
        sz = {sizes[c] for c in free}
        if len(sz) > 1:
            raise ClothFitError("--shared-intrinsics: the cameras' images differ in size (" +
                                ", ".join(f"{c} {sizes[c][0]}x{sizes[c][1]}" for c in free) + "): one lens, one size")
    groups = [free] if opts.shared and free else [[c] for c in free]
    for group in groups:
        vs = [v for c in group for v in views[c].values()]
        obj, img = _obj_img(board, vs)
        w, h = sizes[group[0]]
        K0 = np.array([[1.0, 0, (w - 1) / 2], [0, 1.0, (h - 1) / 2], [0, 0, 1]])
        try:
            rms, K, dist, rv, tv = cv2.calibrateCamera(obj, img, (w, h), K0, np.zeros(5), flags=_cv_flags(opts),
                                                       criteria=crit)
        except cv2.error as e:
            raise ClothFitError(f"camera(s) {', '.join(group)}: OpenCV's calibrateCamera failed on "
                                f"{len(vs)} views ({str(e).strip().splitlines()[-1]})") from None
        if not (np.all(np.isfinite(K)) and K[0, 0] > 0):
            raise ClothFitError(f"camera(s) {', '.join(group)}: no finite intrinsics from {len(vs)} views "
                                f"(more views at varied tilts needed)")
        d5 = np.zeros(5)
        d5[:min(5, dist.size)] = np.asarray(dist).reshape(-1)[:5]
        for c in group:
            intr[c] = Intrinsics(K.copy(), d5.copy())
        for v, r, t in zip(vs, rv, tv):
            poses.setdefault(v.camera, {})[v.moment] = (cv2.Rodrigues(r)[0], np.asarray(t, float).reshape(3))
    for c in views:
        if c not in opts.fixed:
            continue
        cam = opts.fixed[c]
        if (cam.width, cam.height) != tuple(sizes[c]):
            raise ClothFitError(f"--intrinsics: camera '{c}' is {cam.width}x{cam.height} there but its images are "
                                f"{sizes[c][0]}x{sizes[c][1]}")
        if cam.dist.size > 5 and np.any(cam.dist[5:] != 0):
            raise ClothFitError(f"--intrinsics: camera '{c}' uses more than 5 distortion coefficients "
                                f"(k1, k2, p1, p2, k3 are supported)")
        d5 = np.zeros(5)
        d5[:min(5, cam.dist.size)] = cam.dist[:5]
        intr[c] = Intrinsics(cam.K.copy(), d5, fixed=True)
        for v in views[c].values():
            obj, img = _obj_img(board, [v])
            ok, r, t = cv2.solvePnP(obj[0], img[0], cam.K, d5, flags=cv2.SOLVEPNP_IPPE)
            if ok:
                poses.setdefault(c, {})[v.moment] = (cv2.Rodrigues(r)[0], np.asarray(t, float).reshape(3))
    return intr, poses


def initial_extrinsics(poses: dict, reference: str | None = None):
    """Camera poses ``{camera: (R, t)}`` in the reference camera's frame, and board poses
    ``{moment: (R, t)}`` (board -> reference frame), from per-view board poses, along the spanning
    tree of most shared moments. Cameras not connected: one-line error naming the groups."""
    cams = list(poses)
    shared = {(a, b): sorted(set(poses[a]) & set(poses[b])) for i, a in enumerate(cams) for b in cams[i + 1:]}
    groups = _components(cams, [(a, b) for (a, b), s in shared.items() if s])
    if len(groups) > 1:
        desc = "; ".join("{" + ", ".join(g) + "}" for g in groups)
        raise ClothFitError(f"the cameras are not connected by shared views: {desc} share no moment where both "
                            f"see the board (show the board to neighbouring cameras at once, e.g. lying on the "
                            f"table between them)")
    ref = reference or max(cams, key=lambda c: (sum(len(s) for (a, b), s in shared.items() if c in (a, b)),
                                                 len(poses[c])))
    cam_pose = {ref: (np.eye(3), np.zeros(3))}
    while len(cam_pose) < len(cams):        # Prim: the edge with most shared moments to a new camera
        best = None
        for (a, b), s in shared.items():
            if (a in cam_pose) != (b in cam_pose) and s and (best is None or len(s) > len(best[2])):
                best = (a, b, s) if a in cam_pose else (b, a, s)
        a, b, s = best
        # relative a -> b from every shared moment: R_ab = R_bm R_am^T, t_ab = t_bm - R_ab t_am
        Rab = [poses[b][m][0] @ poses[a][m][0].T for m in s]
        R = _mean_rotation(Rab)
        t = np.median([poses[b][m][1] - R @ poses[a][m][1] for m in s], axis=0)
        Ra, ta = cam_pose[a]
        cam_pose[b] = (R @ Ra, R @ ta + t)
    board_pose = {}
    moments = sorted({m for c in cams for m in poses[c]}, key=_natural_key)
    for m in moments:
        Rs, ts = [], []
        for c in cams:
            if m in poses[c]:
                Rc, tc = cam_pose[c]
                Rcm, tcm = poses[c][m]
                Rs.append(Rc.T @ Rcm)
                ts.append(Rc.T @ (tcm - tc))
        board_pose[m] = (_mean_rotation(Rs), np.median(ts, axis=0))
    return ref, cam_pose, board_pose


def _components(nodes, edges):
    parent = {n: n for n in nodes}

    def find(x):
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x
    for a, b in edges:
        parent[find(a)] = find(b)
    groups = {}
    for n in nodes:
        groups.setdefault(find(n), []).append(n)
    return sorted(groups.values(), key=lambda g: (-len(g), g))


# =================================================================== bundle adjustment

@dataclass
class Problem:
    """The observations and the parameter layout of the bundle adjustment."""
    cams: list
    moments: list
    ref: str
    obs_cam: np.ndarray             # (N,) camera index per corner observation
    obs_mom: np.ndarray             # (N,) moment index
    obs_X: np.ndarray               # (N, 3) board point
    obs_x: np.ndarray               # (N, 2) detected pixel
    intr_group: list                # per camera: index of its intrinsic group (-1: fixed)
    n_intr: int                     # parameters per intrinsic group
    dist_idx: list                  # which of the 5 distortion coefficients are free
    square_pixels: bool
    fixed_intr: dict                # camera index -> Intrinsics (fixed)


def _intr_layout(opts: Options):
    dist_idx = [DIST_ORDER.index(k) for k in DISTORTION_MODELS[opts.distortion]]
    return (3 if opts.square_pixels else 4) + len(dist_idx), dist_idx


def _pack(prob: Problem, intr: dict, cam_pose: dict, board_pose: dict) -> np.ndarray:
    x = []
    groups_done = set()
    for ci, c in enumerate(prob.cams):
        g = prob.intr_group[ci]
        if g < 0 or g in groups_done:
            continue
        groups_done.add(g)
        K, d = intr[c].K, intr[c].dist
        f = [0.5 * (K[0, 0] + K[1, 1])] if prob.square_pixels else [K[0, 0], K[1, 1]]
        x += f + [K[0, 2], K[1, 2]] + [d[i] for i in prob.dist_idx]
    for c in prob.cams:
        if c == prob.ref:
            continue
        R, t = cam_pose[c]
        x += list(rotvec(R)) + list(t)
    for m in prob.moments:
        R, t = board_pose[m]
        x += list(rotvec(R)) + list(t)
    return np.asarray(x, dtype=np.float64)


def _n_groups(prob: Problem) -> int:
    return max([g for g in prob.intr_group if g >= 0], default=-1) + 1


def _unpack(prob: Problem, x: np.ndarray):
    """(fx, fy, cx, cy, dist5) per camera, (rvec, t) per camera, (rvec, t) per moment."""
    ng = _n_groups(prob)
    C, M = len(prob.cams), len(prob.moments)
    intr = x[:ng * prob.n_intr].reshape(ng, prob.n_intr)
    o = ng * prob.n_intr
    ext = np.zeros((C, 6))
    others = [ci for ci, c in enumerate(prob.cams) if c != prob.ref]
    ext[others] = x[o:o + 6 * len(others)].reshape(-1, 6)
    o += 6 * len(others)
    brd = x[o:o + 6 * M].reshape(M, 6)
    fx, fy, cx, cy = np.zeros(C), np.zeros(C), np.zeros(C), np.zeros(C)
    dist = np.zeros((C, 5))
    nf = 1 if prob.square_pixels else 2
    for ci in range(C):
        g = prob.intr_group[ci]
        if g < 0:
            it = prob.fixed_intr[ci]
            fx[ci], fy[ci], cx[ci], cy[ci] = it.K[0, 0], it.K[1, 1], it.K[0, 2], it.K[1, 2]
            dist[ci] = it.dist
            continue
        p = intr[g]
        fx[ci] = p[0]
        fy[ci] = p[0] if prob.square_pixels else p[1]
        cx[ci], cy[ci] = p[nf], p[nf + 1]
        dist[ci, prob.dist_idx] = p[nf + 2:]
    return fx, fy, cx, cy, dist, ext, brd


def _residuals(x: np.ndarray, prob: Problem) -> np.ndarray:
    fx, fy, cx, cy, dist, ext, brd = _unpack(prob, x)
    Rc, tc = rodrigues(ext[:, :3]), ext[:, 3:]
    Rm, tm = rodrigues(brd[:, :3]), brd[:, 3:]
    c, m = prob.obs_cam, prob.obs_mom
    Xr = np.einsum("nij,nj->ni", Rm[m], prob.obs_X) + tm[m]
    Xc = np.einsum("nij,nj->ni", Rc[c], Xr) + tc[c]
    uv = project_points(Xc, fx[c], fy[c], cx[c], cy[c], dist[c])
    return (uv - prob.obs_x).ravel()


def _sparsity(prob: Problem):
    from scipy.sparse import lil_matrix  # noqa: PLC0415  (scipy checked in bundle_adjust)
    ng = _n_groups(prob)
    N = prob.obs_cam.size
    others = [ci for ci, c in enumerate(prob.cams) if c != prob.ref]
    ext_col = {ci: ng * prob.n_intr + 6 * k for k, ci in enumerate(others)}
    mom0 = ng * prob.n_intr + 6 * len(others)
    n = mom0 + 6 * len(prob.moments)
    S = lil_matrix((2 * N, n), dtype=np.int8)
    rows = np.arange(N)
    for ci in range(len(prob.cams)):
        sel = rows[prob.obs_cam == ci]
        r = np.concatenate([2 * sel, 2 * sel + 1])
        g = prob.intr_group[ci]
        if g >= 0:
            for k in range(prob.n_intr):
                S[r, g * prob.n_intr + k] = 1
        if ci in ext_col:
            for k in range(6):
                S[r, ext_col[ci] + k] = 1
    for mi in range(len(prob.moments)):
        sel = rows[prob.obs_mom == mi]
        r = np.concatenate([2 * sel, 2 * sel + 1])
        for k in range(6):
            S[r, mom0 + 6 * mi + k] = 1
    return S.tocsr()


def _problem(board: Board, views: dict, intr: dict, ref: str, opts: Options) -> Problem:
    cams = list(views)
    moments = sorted({m for c in cams for m in views[c]}, key=_natural_key)
    mi = {m: i for i, m in enumerate(moments)}
    P = board.corners()
    oc, om, oX, ox = [], [], [], []
    for ci, c in enumerate(cams):
        for m, v in views[c].items():
            oc.append(np.full(v.ids.size, ci))
            om.append(np.full(v.ids.size, mi[m]))
            oX.append(P[v.ids])
            ox.append(v.points)
    n_intr, dist_idx = _intr_layout(opts)
    group, fixed = [], {}
    free = [c for c in cams if not intr[c].fixed]
    for ci, c in enumerate(cams):
        if intr[c].fixed:
            group.append(-1)
            fixed[ci] = intr[c]
        else:
            group.append(0 if opts.shared else free.index(c))
    return Problem(cams, moments, ref, np.concatenate(oc), np.concatenate(om), np.concatenate(oX),
                   np.concatenate(ox), group, n_intr, dist_idx, opts.square_pixels, fixed)


def bundle_adjust(board: Board, views: dict, intr: dict, ref: str, cam_pose: dict, board_pose: dict,
                  opts: Options, max_nfev: int = D.CALIB_MAX_NFEV):
    """Refine everything jointly; returns (intrinsics, camera poses, board poses, per-observation
    residual vectors (N, 2), the problem, the optimiser's status)."""
    try:
        from scipy.optimize import least_squares
    except ImportError:
        raise ClothFitError("calibrate needs scipy for its bundle adjustment: pip install scipy "
                            "(see requirements.txt)") from None
    prob = _problem(board, views, intr, ref, opts)
    x0 = _pack(prob, intr, cam_pose, board_pose)
    r0 = _residuals(x0, prob)
    if not np.all(np.isfinite(r0)):
        raise ClothFitError("calibration: the initial estimate puts the board behind a camera (the views are "
                            "inconsistent: are the same moment's images really of the same moment?)")
    # x_scale "jac" evens out pixels, metres and radians; lsmr's default tolerances stop its inner solves
    # too early on this ill-conditioned system (hundreds of tiny steps): 1e-10 converges in tens
    res = least_squares(_residuals, x0, jac_sparsity=_sparsity(prob), method="trf", loss=opts.loss,
                        f_scale=opts.loss_scale_px, x_scale="jac", max_nfev=max_nfev, args=(prob,),
                        xtol=1e-10, ftol=1e-10, gtol=1e-10, tr_solver="lsmr",
                        tr_options={"atol": 1e-10, "btol": 1e-10})
    fx, fy, cx, cy, dist, ext, brd = _unpack(prob, res.x)
    out_intr, out_cam, out_board = {}, {}, {}
    for ci, c in enumerate(prob.cams):
        K = np.array([[fx[ci], 0, cx[ci]], [0, fy[ci], cy[ci]], [0, 0, 1.0]])
        out_intr[c] = Intrinsics(K, dist[ci].copy(), intr[c].fixed)
        out_cam[c] = (rodrigues(ext[ci, :3])[0], ext[ci, 3:].copy())
    for k, m in enumerate(prob.moments):
        out_board[m] = (rodrigues(brd[k, :3])[0], brd[k, 3:].copy())
    return out_intr, out_cam, out_board, res.fun.reshape(-1, 2), prob, res


# ====================================================================== world frame

def world_frame(board: Board, ref_cam_pose: dict, board_pose: dict, world: str, opts: Options):
    """The transform reference frame -> world ``(R, t)`` (see the module text) and how up was set."""
    if world not in board_pose:
        raise ClothFitError(f"--world {world}: no camera saw the board at that moment (moments seen: "
                            f"{', '.join(list(board_pose)[:8])}{' ...' if len(board_pose) > 8 else ''})")
    Rw, tw = board_pose[world]
    # board -> world: X_w = FLIP (X_b - centre); ref -> board: X_b = Rw^T (X_r - tw)
    R = FLIP @ Rw.T
    t = -FLIP @ Rw.T @ tw - FLIP @ board.centre()
    up_source = f"the board at the world moment {world}"
    up = None
    if opts.level is not None:
        if opts.level not in board_pose:
            raise ClothFitError(f"--level {opts.level}: no camera saw the board at that moment")
        Rl, _ = board_pose[opts.level]
        up = R @ (Rl @ np.array([0.0, 0.0, -1.0]))           # the level board's face normal, in the world
        up_source = f"the level board at moment {opts.level}"
    elif opts.gravity is not None:
        cam, g = opts.gravity
        if cam not in ref_cam_pose:
            raise ClothFitError(f"--gravity {cam}:...: no camera '{cam}' (cameras: {', '.join(ref_cam_pose)})")
        Rc, _ = ref_cam_pose[cam]
        g = np.asarray(g, float) / np.linalg.norm(g)
        up = -(R @ (Rc.T @ g))
        up_source = f"gravity measured in camera {cam}"
    tilt = 0.0
    if up is not None:
        up /= np.linalg.norm(up)
        tilt = math.degrees(math.acos(max(-1.0, min(1.0, float(up[2])))))
        xb = np.array([1.0, 0.0, 0.0])
        x = xb - up * (xb @ up)
        if np.linalg.norm(x) < 1e-6:
            raise ClothFitError(f"{up_source}: up lies along the board's X axis; the board at the world moment "
                                f"cannot set the heading")
        x /= np.linalg.norm(x)
        y = np.cross(up, x)
        Q = np.stack([x, y, up])                          # old world -> new world
        R, t = Q @ R, Q @ t
    return R, t, {"moment": world, "up": up_source, "board_tilt_deg": tilt}


# ========================================================================== the run

@dataclass
class Result:
    cameras: list                 # Camera objects (world frame)
    report: dict
    board_poses: dict = field(default_factory=dict)   # {moment: (R, t)} board -> world


def calibrate_views(board: Board, det: Detections, opts: Options, log=None) -> Result:
    """Calibrate from detected views (see the module text); ``log(text)`` for progress messages."""
    opts.check()
    say = log or (lambda s: None)
    views = {c: dict(sorted(v.items(), key=lambda kv: _natural_key(kv[0]))) for c, v in det.views.items()}
    if opts.shared and not [c for c in views if c not in opts.fixed]:
        opts.shared = False
    # too few views: per camera (estimated intrinsics), per group for shared intrinsics, 1 for fixed
    few = []
    for c, v in views.items():
        need = 1 if c in opts.fixed else opts.min_views
        if opts.shared and c not in opts.fixed:
            need = 1
        if len(v) < need:
            few.append((c, len(v), need))
    if opts.shared:
        total = sum(len(v) for c, v in views.items() if c not in opts.fixed)
        if total < opts.min_views:
            few.append(("(shared intrinsics)", total, opts.min_views))
    if few:
        c, n, need = few[0]
        st = det.stats.get(c, {})
        why = f"; of its {st.get('frames', 0)} frames, {st.get('found', 0)} show the board" if st else ""
        dropped = ", ".join(f"{st[k]} {k.replace('_', ' ')}" for k in ("few_corners", "collinear", "blurred")
                            if st.get(k))
        raise ClothFitError(f"camera '{c}' sees the board in {n} usable view(s), at least {need} needed{why}"
                            f"{' (dropped: ' + dropped + ')' if dropped else ''}"
                            f"{'; other cameras short too: ' + ', '.join(f[0] for f in few[1:]) if len(few) > 1 else ''}")
    intr, poses = initial_intrinsics(board, views, det.sizes, opts)
    for c in views:                        # views whose pose failed (solvePnP) are dropped
        views[c] = {m: v for m, v in views[c].items() if m in poses.get(c, {})}
    ref, cam_pose, board_pose = initial_extrinsics(poses)
    say(f"initial estimate: reference camera {ref}, {len(board_pose)} moments")
    dropped_views = []
    rejected = 0
    for rnd in range(D.CALIB_ROUNDS):
        intr, cam_pose, board_pose, resid, prob, status = bundle_adjust(board, views, intr, ref, cam_pose,
                                                                         board_pose, opts)
        err = np.linalg.norm(resid, axis=1)
        say(f"bundle adjustment round {rnd + 1}: RMS {math.sqrt(np.mean(err ** 2)):.3f} px over {err.size} corners "
            f"({status.nfev} evaluations)")
        if rnd == D.CALIB_ROUNDS - 1:
            break
        views, n_rej, n_drop = _drop_outliers(views, prob, err, opts, dropped_views)
        rejected += n_rej
        if not n_rej and not n_drop:
            break
        board_pose = {m: p for m, p in board_pose.items() if any(m in views[c] for c in views)}
        _components_check(views, "after dropping the views far off the joint fit, ")
    # world frame
    moments = prob.moments
    world = opts.world
    if world is None:
        # the world is the board flat on the table at the first moment filmed: never silently another one
        world = det.moments[0] if det.moments else moments[0]
        if world not in board_pose:
            seen = [c for c in views if world in det.views.get(c, {})]
            raise ClothFitError(f"the board at the first moment {world} (the world frame: the board flat on the "
                                f"table) is in no usable view{' (its views were dropped: ' + ', '.join(seen) + ')' if seen else ''}"
                                f": retake it where every phone sees it, or give --world MOMENT of another flat view")
    R_w, t_w, frame = world_frame(board, cam_pose, board_pose, world, opts)
    cams_out = []
    for c in prob.cams:
        Rc, tc = cam_pose[c]
        R = Rc @ R_w.T
        t = tc - R @ t_w
        w, h = det.sizes[c]
        it = intr[c]
        dist = it.dist[:len(DIST_ORDER)].copy()
        cams_out.append(Camera(it.K, _orthonormal(R), t, w, h, name=c, dist=dist))
    board_world = {}
    for m, (Rb, tb) in board_pose.items():          # board -> world
        board_world[m] = (R_w @ Rb, R_w @ tb + t_w)
    report = _report(board, det, views, prob, resid, cams_out, frame, dropped_views, rejected, opts, status)
    return Result(cams_out, report, board_world)


def _components_check(views, prefix=""):
    cams = list(views)
    edges = [(a, b) for i, a in enumerate(cams) for b in cams[i + 1:] if set(views[a]) & set(views[b])]
    groups = _components(cams, edges)
    if len(groups) > 1:
        raise ClothFitError(f"{prefix}the cameras are not connected by shared views: " +
                            "; ".join("{" + ", ".join(g) + "}" for g in groups))


def _view_errors(views, prob, err):
    """(camera, moment, View, its corners' errors) in the order of the problem's observations."""
    k = 0
    for c in prob.cams:
        for m, v in views[c].items():
            yield c, m, v, err[k:k + v.ids.size]
            k += v.ids.size


def _drop_outliers(views, prob, err, opts: Options, dropped_views: list):
    """Corners further than max(outlier_px, CALIB_OUTLIER_SIGMAS robust sigmas) from the fit are
    dropped; a view left with fewer than min_corners is dropped whole, unless its camera would fall
    below its minimum of views. Returns (views, corners dropped, views dropped)."""
    thr = max(opts.outlier_px, D.CALIB_OUTLIER_SIGMAS * 1.4826 * float(np.median(err)))
    out = {c: {} for c in views}
    n_rej, gone = 0, []
    for c, m, v, e in _view_errors(views, prob, err):
        keep = e <= thr
        if keep.sum() < opts.min_corners:
            gone.append({"camera": c, "moment": m, "rms_px": float(np.sqrt(np.mean(e ** 2))),
                         "why": f"fewer than {opts.min_corners} corners within {thr:.2f} px of the joint fit"})
            continue
        n_rej += int((~keep).sum())
        out[c][m] = v if keep.all() else View(c, m, v.ids[keep], v.points[keep], v.markers, v.sharpness)
    for c in views:
        need = 1 if (c in opts.fixed or opts.shared) else opts.min_views
        if len(out[c]) < need:                  # never below the minimum: that camera keeps every view
            out[c] = dict(views[c])
            gone = [g for g in gone if g["camera"] != c]
    dropped_views += gone
    return out, n_rej, len(gone)


def _orthonormal(R):
    U, _, Vt = np.linalg.svd(R)
    return U @ Vt


def _report(board, det, views, prob, resid, cams_out, frame, dropped_views, rejected, opts, status) -> dict:
    err = np.linalg.norm(resid, axis=1)
    cams = []
    k = 0
    per_view = {}
    for c in prob.cams:
        for m, v in views[c].items():
            e = err[k:k + v.ids.size]
            k += v.ids.size
            per_view.setdefault(c, {})[m] = {"rms_px": float(np.sqrt(np.mean(e ** 2))), "corners": int(v.ids.size)}
    for ci, (c, cam) in enumerate(zip(prob.cams, cams_out)):
        e = err[prob.obs_cam == ci]
        shared = sorted({m for m in views[c] if sum(m in views[o] for o in views) > 1}, key=_natural_key)
        cams.append({"name": c, "width": cam.width, "height": cam.height,
                     "rms_px": float(np.sqrt(np.mean(e ** 2))), "max_px": float(e.max()),
                     "views_used": len(views[c]), "views_shared": len(shared), "corners": int(e.size),
                     "fx": float(cam.K[0, 0]), "fy": float(cam.K[1, 1]), "cx": float(cam.K[0, 2]),
                     "cy": float(cam.K[1, 2]), "dist": cam.dist.tolist(), "centre_m": cam.center.tolist(),
                     "intrinsics": "fixed" if c in opts.fixed else ("shared" if opts.shared else "estimated"),
                     "frames": det.stats.get(c, {}), "views": per_view.get(c, {})})
    return {"board": board.to_dict(), "rms_px": float(np.sqrt(np.mean(err ** 2))), "corners": int(err.size),
            "moments": len(prob.moments), "cameras": cams, "world": frame,
            "options": {"distortion": opts.distortion, "square_pixels": opts.square_pixels, "shared": opts.shared,
                        "fixed": sorted(opts.fixed), "min_views": opts.min_views, "min_corners": opts.min_corners,
                        "blur_ratio": opts.blur_ratio, "loss": opts.loss, "loss_scale_px": opts.loss_scale_px,
                        "outlier_px": opts.outlier_px},
            "rejected_corners": rejected, "dropped_views": dropped_views,
            "optimizer": {"nfev": int(status.nfev), "status": int(status.status), "message": str(status.message)}}


# ====================================================================== whole command

def calibrate_folder(folder: str, board: Board, opts: Options, sync: dict | None = None, every: float | None = None,
                     times=None, debug_dir: str | None = None, log=None) -> tuple:
    """Detect and calibrate: (Result, Detections, Source). Videos need ``sync`` ({camera: video time
    at capture time 0}); they are sampled every ``every`` s (or at ``times``). ``debug_dir``: the
    detections drawn per camera and moment (see :func:`write_debug`), also when the calibration
    fails after the detection (that is when they are needed)."""
    opts.check()
    say = log or (lambda s: None)
    src = find_source(folder)
    t = None
    if src.kind == "videos":
        if sync is None:
            raise ClothFitError(f"calibration folder {folder} holds videos: give their sync (--sync FILE or "
                                f"--find-sync flash)")
        missing = [c for c in src.cameras if c not in sync]
        if missing:
            raise ClothFitError(f"the sync has no time for camera(s) {', '.join(missing)}")
        t = video_times(src.videos, sync, D.CALIB_VIDEO_EVERY_S if every is None else every, times)
        say(f"{len(src.cameras)} videos, {len(t)} moments from {t[0]:.2f} to {t[-1]:.2f} s")
    else:
        say(f"{len(src.cameras)} cameras, {sum(len(v) for v in src.images.values())} images")
    unknown = [c for c in opts.fixed if c not in src.cameras]
    if unknown and not any(c in src.cameras for c in opts.fixed):
        raise ClothFitError(f"--intrinsics: none of its cameras ({', '.join(unknown[:5])}) is a camera of {folder} "
                            f"({', '.join(src.cameras)})")
    opts.fixed = {c: cam for c, cam in opts.fixed.items() if c in src.cameras}   # the others: another rig's
    det = detect_views(src, board, opts.min_corners, opts.blur_ratio, sync, t, keep_frames=bool(debug_dir))
    for c in src.cameras:
        st = det.stats[c]
        say(f"  {c}: {st['frames']} frames, board in {st['found']}, {st['views']} views kept"
            + "".join(f", {st[k]} {k.replace('_', ' ')}" for k in ("few_corners", "collinear", "blurred") if st[k]))
    result = None
    try:
        check_detections(det, board, src)
        if opts.world is not None:
            seen = {m for v in det.views.values() for m in v}
            if opts.world not in seen:
                raise ClothFitError(f"--world {opts.world}: no camera has a usable view of the board at that moment")
        result = calibrate_views(board, det, opts, log)
    finally:
        if debug_dir:
            n = write_debug(debug_dir, det, result, board)
            say(f"wrote {n} debug images under {debug_dir}")
    return result, det, src


def write_outputs(result: Result, out: str, export: str | None = None, fmt: str = "auto",
                  report_path: str | None = None) -> dict:
    """Write the cameras JSON (ours, with the calibration's summary), and optionally an export
    (``calib_io.export_cameras``) and the full report. Every destination is checked before the first
    file is written; each file is written atomically."""
    from ..safeio import atomic_json
    from .calib_io import FORMATS, export_cameras
    dests = [p for p in (out, export, report_path) if p]
    real = [os.path.realpath(p) for p in dests]
    if len(set(real)) < len(real):
        raise ClothFitError(f"--out, --export and --report must be different files ({', '.join(dests)})")
    for p in (out, report_path):
        if p and os.path.isdir(p):
            raise ClothFitError(f"cannot write {p}: it is a directory")
    if export and fmt not in FORMATS:
        raise ClothFitError(f"--format {fmt!r}: one of {', '.join(FORMATS)}")
    summary = {k: result.report[k] for k in ("board", "rms_px", "world", "moments")}
    summary["cameras"] = {c["name"]: {"rms_px": c["rms_px"], "views_used": c["views_used"]}
                          for c in result.report["cameras"]}
    from ..observation.camera import save_cameras
    save_cameras(out, result.cameras, extra={"calibration": summary})
    written = {"out": out}
    if export:
        export_cameras(result.cameras, export, fmt)
        written["export"] = export
    if report_path:
        atomic_json(report_path, result.report)
        written["report"] = report_path
    return written


def write_debug(folder: str, det: Detections, result: Result | None, board: Board):
    """Per camera and moment a JPEG: detected markers (blue), ChArUco corners (green) and, after a
    calibration, where the cameras reproject them (red crosses)."""
    import cv2

    from ..safeio import atomic_write
    P = board.corners()
    cams = {c.name: c for c in (result.cameras if result else [])}
    written = 0
    for (cam, moment), (jpg, mids, mcorners) in det.debug_frames.items():
        grey = cv2.imdecode(np.frombuffer(jpg, np.uint8), cv2.IMREAD_GRAYSCALE)
        img = cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR)
        for c in (mcorners or ()):
            cv2.polylines(img, [np.round(np.asarray(c).reshape(-1, 2)).astype(np.int32)], True, (255, 128, 0), 1,
                          cv2.LINE_AA)
        v = det.views.get(cam, {}).get(moment)
        if v is not None:
            for p in v.points:
                cv2.circle(img, (int(round(p[0])), int(round(p[1]))), 4, (0, 200, 0), 1, cv2.LINE_AA)
        if result is not None and cam in cams and moment in result.board_poses:
            Rb, tb = result.board_poses[moment]
            uv = cams[cam].project(P @ Rb.T + tb)
            for q in uv:
                if np.all(np.isfinite(q)):
                    x, y = int(round(q[0])), int(round(q[1]))
                    cv2.line(img, (x - 3, y), (x + 3, y), (0, 0, 255), 1)
                    cv2.line(img, (x, y - 3), (x, y + 3), (0, 0, 255), 1)
        text = "blue: markers, green: corners" + (", red: reprojected" if result is not None else "")
        if v is None:
            text = "board not used here: " + ("markers only" if mcorners else "nothing found")
        elif result is not None:
            info = next((c["views"].get(moment) for c in result.report["cameras"] if c["name"] == cam), None)
            if info:
                text += f", view RMS {info['rms_px']:.2f} px"
        cv2.putText(img, text, (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(img, text, (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
        ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 90])
        atomic_write(os.path.join(folder, cam, f"{moment}.jpg"), buf.tobytes())
        written += 1
    return written
