"""Silhouettes that carry nothing to fit: every pixel set.

A silhouette with every pixel set (outside its ignore mask) is a segmentation that took the whole image (a
threshold on a white plate, an inverted matte): the fit would score every candidate against a full frame and
end at a number with no meaning (an all-white capture fitted to 96 % ``E_sil`` and exited 0). The fit refuses
it, naming the files. An empty silhouette is refused where it is read (``capture.load_observation``): the
error of an image is normalised by its observed area, so an image where the cloth left the view cannot be
scored; leave its frame (``--times``) or camera (``--cameras``) out.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from ..errors import ClothFitError

if TYPE_CHECKING:
    from .capture import Capture

SHOWN = 3  # files named in the message (and how many more)


def refuse_full_silhouettes(
    capture: Capture,
    cams: Sequence[int],
    fidx: Sequence[int],
    observed: Sequence[Sequence[np.ndarray]],
    ignore: Sequence[Sequence[np.ndarray | None]],
) -> None:
    """A one-line ``ClothFitError`` naming the camera, frame and file of every silhouette ``observed[c][f]`` (of
    cameras ``cams`` and frames ``fidx``) whose every pixel outside its ignore mask is set; nothing otherwise."""
    full = []
    for c, row, grow in zip(cams, observed, ignore):
        for f, o, g in zip(fidx, row, grow):
            if bool(np.all(o if g is None else (o | g))):
                full.append(f"camera '{capture.cameras[c].name}' frame {f} ({capture.silhouette_path(c, f)})")
    if full:
        more = f" and {len(full) - SHOWN} more" if len(full) > SHOWN else ""
        raise ClothFitError(
            f"{len(full)} silhouette(s) have every pixel set, nothing to fit (a segmentation that took the whole "
            f"image?): {'; '.join(full[:SHOWN])}{more}; fix them or leave those cameras (--cameras) or frames "
            f"(--times) out"
        )
