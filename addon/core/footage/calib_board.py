"""The ChArUco board of ``clothfit calibrate``: its description parsed and checked
(``SQUARES_X,SQUARES_Y,SQUARE_M,MARKER_M,DICTIONARY``, OpenCV's ``CharucoBoard`` layout) and its
printable PNG and PDF (``--make-board``). The steps of a calibration: ``calibrate.py``.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .. import defaults as D
from ..errors import ClothFitError

if TYPE_CHECKING:
    import cv2

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

    def cv_dictionary(self) -> cv2.aruco.Dictionary:
        import cv2

        return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))

    def cv_board(self) -> cv2.aruco.CharucoBoard:
        import cv2

        b = cv2.aruco.CharucoBoard(
            (self.squares_x, self.squares_y), float(self.square_m), float(self.marker_m), self.cv_dictionary()
        )
        b.setLegacyPattern(bool(self.legacy))
        return b

    def corners(self) -> np.ndarray:
        """``(n_corners, 3)`` chessboard corners in the board frame [m], indexed by ChArUco corner id."""
        return np.asarray(self.cv_board().getChessboardCorners(), dtype=np.float64).reshape(-1, 3)

    def centre(self) -> np.ndarray:
        w, h = self.size_m
        return np.array([w / 2, h / 2, 0.0])

    def to_dict(self) -> dict:
        return {
            "squares_x": self.squares_x,
            "squares_y": self.squares_y,
            "square_m": self.square_m,
            "marker_m": self.marker_m,
            "dictionary": self.dictionary,
            "legacy": self.legacy,
            "text": self.text,
        }


def dictionaries() -> dict:
    """``{name: (marker bits per side, markers)}`` of OpenCV's predefined ArUco dictionaries."""
    import cv2

    out = {}
    for name in dir(cv2.aruco):
        m = re.fullmatch(r"DICT_(\d)X\1_(\d+)", name)
        if m:
            out[name] = (int(m.group(1)), int(m.group(2)))
    for name in (
        "DICT_ARUCO_ORIGINAL",
        "DICT_ARUCO_MIP_36H12",
        "DICT_APRILTAG_16H5",
        "DICT_APRILTAG_25H9",
        "DICT_APRILTAG_36H10",
        "DICT_APRILTAG_36H11",
    ):
        if hasattr(cv2.aruco, name):
            d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))
            out[name] = (int(d.markerSize), int(d.bytesList.shape[0]))
    return out


def parse_board(text: str, legacy: bool = False) -> Board:
    """``SQUARES_X,SQUARES_Y,SQUARE_M,MARKER_M,DICTIONARY`` (e.g. ``9,7,0.04,0.03,DICT_5X5_100``) -> a
    checked :class:`Board`; one-line errors naming the part at fault."""
    parts = [p.strip() for p in str(text).split(",")]
    if len(parts) != 5:
        raise ClothFitError(
            f"--board {text!r}: expected SQUARES_X,SQUARES_Y,SQUARE_M,MARKER_M,DICTIONARY "
            f"(e.g. 9,7,0.04,0.03,DICT_5X5_100)"
        )
    try:
        sx, sy = int(parts[0]), int(parts[1])
    except ValueError:
        raise ClothFitError(
            f"--board {text!r}: the numbers of squares {parts[0]!r}, {parts[1]!r} must be whole numbers"
        ) from None
    try:
        sq, mk = float(parts[2]), float(parts[3])
    except ValueError:
        raise ClothFitError(
            f"--board {text!r}: the square and marker sizes {parts[2]!r}, {parts[3]!r} must be numbers in metres"
        ) from None
    name = parts[4].upper()
    if not name.startswith("DICT_"):
        name = "DICT_" + name
    if not (2 <= sx <= 100 and 2 <= sy <= 100) or sx * sy < 6:
        raise ClothFitError(
            f"--board {text!r}: {sx} x {sy} squares: need 2..100 per side and at least 6 squares "
            f"(a ChArUco board needs inner corners)"
        )
    if not (math.isfinite(sq) and 0.002 <= sq <= 2.0):
        raise ClothFitError(
            f"--board {text!r}: square size {sq:g} m outside 0.002..2 m (sizes are in metres: 4 cm = 0.04)"
        )
    if not (math.isfinite(mk) and 0 < mk < sq):
        raise ClothFitError(
            f"--board {text!r}: marker size {mk:g} m must be positive and smaller than the square ({sq:g} m)"
        )
    known = dictionaries()
    if name not in known:
        raise ClothFitError(
            f"--board {text!r}: unknown dictionary {parts[4]!r} (OpenCV's: {', '.join(sorted(known, key=natural_key))})"
        )
    b = Board(sx, sy, sq, mk, name, bool(legacy))
    if b.n_markers > known[name][1]:
        raise ClothFitError(
            f"--board {text!r}: {sx} x {sy} squares need {b.n_markers} markers but {name} has only {known[name][1]}"
        )
    return b


def natural_key(s: str) -> list:
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", s)]


# ================================================================== printable board

PDF_POINTS_PER_M = 72 / 0.0254


def make_board(
    board: Board,
    png_path: str | None,
    pdf_path: str | None,
    dpi: float = D.CALIB_BOARD_DPI,
    margin_m: float = D.CALIB_BOARD_MARGIN_M,
) -> dict:
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
        px_dpi = px_per_square / (board.square_m / 0.0254)  # the exact dpi of whole-pixel squares
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
    from ..observation.png import png_chunk

    ppm = int(round(dpi / 0.0254))
    ihdr_end = 8 + 8 + 13 + 4
    import struct

    return png[:ihdr_end] + png_chunk(b"pHYs", struct.pack(">IIB", ppm, ppm, 1)) + png[ihdr_end:]


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
    rects = []  # (x, y, w, h) in board metres, y down the print

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
            while c < bits:  # runs of black cells as one rectangle
                if cell[r, c] < 128:
                    c1 = c
                    while c1 < bits and cell[r, c1] < 128:
                        c1 += 1
                    add(x0 + c * s, y0 + r * s, (c1 - c) * s, s)
                    c = c1
                else:
                    c += 1
    ops = ["0 g"]
    for x, y, w, h in rects:  # PDF y goes up from the bottom of the page
        ops.append(f"{(x + margin_m) * k:.4f} {ph - (y + h + margin_m) * k:.4f} {w * k:.4f} {h * k:.4f} re f")
    caption = (
        f"ChArUco {board.text}{' legacy' if board.legacy else ''}: squares {board.square_m * 1000:g} mm, "
        f"markers {board.marker_m * 1000:g} mm. Print at 100 % (no fit to page); measure a square."
    )
    if margin_m * k >= 9:
        ops.append(
            f"BT /F1 7 Tf {max(2.0, margin_m * k * 0.25):.2f} {max(2.0, margin_m * k * 0.3):.2f} Td "
            f"({_pdf_text(caption)}) Tj ET"
        )
    content = "\n".join(ops).encode("ascii")
    objs_pdf = [
        b"<< /Type /Catalog /Pages 2 0 R >>",
        b"<< /Type /Pages /Kids [3 0 R] /Count 1 >>",
        f"<< /Type /Page /Parent 2 0 R /MediaBox [0 0 {pw:.4f} {ph:.4f}] /Contents 4 0 R "
        f"/Resources << /Font << /F1 5 0 R >> >> >>".encode("ascii"),
        b"<< /Length " + str(len(content)).encode() + b" >>\nstream\n" + content + b"\nendstream",
        b"<< /Type /Font /Subtype /Type1 /BaseFont /Helvetica >>",
    ]
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
