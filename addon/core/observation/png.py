"""Label PNGs read as their stored values: palette indices or grey levels, never converted.

Segmenters (SAM 2, XMem, DAVIS tooling) write masks as indexed-colour (palette) PNGs whose pixel
values are object ids. OpenCV's decoder turns a palette image into the palette's colours and loses
the ids, so for a palette PNG we rewrite its ``PLTE`` chunk in memory into a grey ramp (entry i =
(i, i, i), same number of entries, ``tRNS`` dropped) and let OpenCV decode that: every pixel then
decodes to its own index, whatever the bit depth, row filters or interlacing. Greyscale PNGs
(8 or 16 bit) are decoded unchanged. RGB/RGBA PNGs are not label images and are refused.
"""

from __future__ import annotations

import struct
import zlib

import numpy as np

from ..errors import ClothFitError

SIGNATURE = b"\x89PNG\r\n\x1a\n"
COLOUR_TYPE_NAMES = {0: "greyscale", 2: "RGB", 3: "palette", 4: "greyscale + alpha", 6: "RGBA"}
LABEL_COLOUR_TYPES = (0, 3, 4)


def _chunks(data: bytes, where: str):
    pos, out = 8, []
    while pos + 8 <= len(data):
        n, typ = struct.unpack(">I4s", data[pos : pos + 8])
        if pos + 12 + n > len(data):
            raise ClothFitError(f"{where}: corrupt or truncated PNG (chunk {typ!r} runs past the end of the file)")
        out.append((typ, data[pos + 8 : pos + 8 + n]))
        pos += 12 + n
        if typ == b"IEND":
            break
    return out


def png_chunk(typ: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + typ + body + struct.pack(">I", zlib.crc32(typ + body) & 0xFFFFFFFF)


def png_info(data: bytes, where: str) -> tuple[int, int, int, int]:
    """``(width, height, bit_depth, colour_type)`` of PNG bytes (error naming ``where`` otherwise)."""
    if data[:8] != SIGNATURE:
        raise ClothFitError(f"{where}: not a PNG file (label images must be PNG)")
    if len(data) < 33 or data[12:16] != b"IHDR":
        raise ClothFitError(f"{where}: corrupt PNG (no IHDR chunk)")
    w, h, depth, ctype = struct.unpack(">IIBB", data[16:26])
    return w, h, depth, ctype


def _grey_ramp_palette(data: bytes, where: str) -> bytes:
    out = [SIGNATURE]
    seen = False
    for typ, body in _chunks(data, where):
        if typ == b"PLTE":
            n = len(body) // 3
            body = bytes(np.repeat(np.arange(n, dtype=np.uint8), 3))
            seen = True
        elif typ == b"tRNS":
            continue
        out.append(png_chunk(typ, body))
    if not seen:
        raise ClothFitError(f"{where}: corrupt palette PNG (no PLTE chunk)")
    return b"".join(out)


def decode_label_png(data: bytes, where: str) -> np.ndarray:
    """Label values (H, W) (uint8, or uint16 for 16-bit grey) of PNG bytes."""
    import cv2

    if not data:
        raise ClothFitError(f"{where}: the file is empty (0 bytes), not an image")
    w, h, depth, ctype = png_info(data, where)
    if ctype not in LABEL_COLOUR_TYPES:
        raise ClothFitError(
            f"{where}: a label image must be a palette (indexed-colour) or greyscale PNG; this one is "
            f"{COLOUR_TYPE_NAMES.get(ctype, f'colour type {ctype}')} ({depth}-bit)"
        )
    if ctype == 3:
        data = _grey_ramp_palette(data, where)
    try:
        img = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    except cv2.error:  # pragma: no cover - depends on the OpenCV build
        img = None
    if img is None or img.size == 0:
        raise ClothFitError(f"{where}: corrupt or unreadable PNG ({len(data)} bytes that OpenCV cannot decode)")
    if img.ndim == 3:
        img = img[..., 0]  # palette -> equal B, G, R = the index; grey + alpha -> the grey
    if img.shape != (h, w):
        raise ClothFitError(f"{where}: corrupt PNG (decoded {img.shape} but the header says {h} x {w})")
    return img


def read_label_png(path: str, where: str | None = None) -> np.ndarray:
    """The label values (H, W) of a palette or greyscale PNG file: palette indices or grey values."""
    where = where or path
    try:
        with open(path, "rb") as f:
            data = f.read()
    except FileNotFoundError:
        raise ClothFitError(f"{where}: file not found") from None
    except OSError as e:
        raise ClothFitError(f"{where}: cannot read ({e})") from None
    return decode_label_png(data, where)
