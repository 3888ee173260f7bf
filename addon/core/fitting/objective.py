"""The fitness of a population: simulate every candidate, rasterise, compare (eq. 6, 7).

``SilhouetteObjective`` holds the observed silhouettes of the chosen cameras and frames and returns,
for a population of parameter rows of its model (``physics.models``: the paper's sheet by default,
or Blender's cloth), ``E_all`` (sum of ``E_sil`` over all images) or the per-image ``E_sil``. A
candidate that explodes or goes non-finite scores ``inf`` (the worst), never an error. The numba
kernels (``kernels``) are used when available, else the numpy reference path.

Pixels of unknown truth (``ignore[c][f]``: occluders such as a hand or a post in front of the cloth)
leave eq. 6 entirely: they are neither observed cloth nor observed background, so a model pixel
there is neither missing nor extra, and the normaliser is the observed area outside them.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from ..errors import ClothFitError
from ..observation.coverage import refuse_full_silhouettes
from ..observation.floor import resample_ignore, resample_silhouette
from ..observation.raster import rasterize, rasterize_window
from ..observation.silhouette_kernels import pack_rows
from ..physics import jit, paper_kernels
from ..physics.crop import clip_mesh, clipped_quads, clipped_triangles
from ..physics.models import PaperModel, get_model
from ..physics.paper import simulate_numpy
from ..physics.scenario import Offsets
from . import kernels
from .config import check_resolution

if TYPE_CHECKING:
    from ..observation.camera import Camera
    from ..observation.capture import Capture


class SilhouetteObjective:
    def __init__(self, scenario, cameras, observed, backend: str = "auto", names=None, model=None, ignore=None):
        """``scenario.frame_times`` are the observed times; ``observed[c][f]`` a bool (H_c, W_c) image
        of camera ``cameras[c]`` at ``scenario.frame_times[f]``; ``model`` a model, name or dict
        (``physics.models.get_model``; default: the paper's sheet); ``ignore[c][f]`` a bool image of
        the pixels whose truth is unknown, or None (the whole list or any entry)."""
        self.scenario = scenario
        self.crop = scenario.crop  # the model's silhouettes leave out what the capture's crop left out
        self.model = get_model(model)
        self.paper = isinstance(self.model, PaperModel)
        self.cameras = list(cameras)
        C, F = len(self.cameras), scenario.frame_times.size
        if len(observed) != C:
            raise ClothFitError(f"objective: {len(observed)} silhouette lists for {C} cameras")
        self.areas = np.zeros((C, F))
        obs, ign = [], []
        for c, cam in enumerate(self.cameras):
            if len(observed[c]) != F:
                raise ClothFitError(f"objective: camera '{cam.name}' has {len(observed[c])} silhouettes for {F} frames")
            for f in range(F):
                o = np.asarray(observed[c][f], dtype=bool)
                nm = names[c][f] if names else f"camera '{cam.name}' frame {f}"
                if o.shape != (cam.height, cam.width):
                    raise ClothFitError(
                        f"{nm}: silhouette is {o.shape[0]}x{o.shape[1]} but camera '{cam.name}' is "
                        f"{cam.height}x{cam.width}"
                    )
                g = None if ignore is None or ignore[c][f] is None else np.asarray(ignore[c][f], dtype=bool)
                if g is not None:
                    if g.shape != o.shape:
                        raise ClothFitError(
                            f"{nm}: ignore mask is {g.shape[0]}x{g.shape[1]} but camera '{cam.name}' "
                            f"is {cam.height}x{cam.width}"
                        )
                    g = g if g.any() else None
                    if g is not None:
                        o = o & ~g
                a = int(o.sum())
                if a == 0:
                    raise ClothFitError(
                        f"{nm}: observed silhouette is empty" + (" outside the ignore mask" if g is not None else "")
                    )
                self.areas[c, f] = a
                obs.append(o)
                ign.append(g)
        self.observed = [[obs[c * F + f] for f in range(F)] for c in range(C)]
        self.ignore = [[ign[c * F + f] for f in range(F)] for c in range(C)]
        if backend == "auto":
            backend = "numba" if jit.available() else "numpy"
        if backend not in ("numba", "numpy"):
            raise ClothFitError(f"unknown backend {backend!r} (numba, numpy, auto)")
        self.backend = backend
        self.evaluations = 0
        if backend == "numba":
            # per image: the observed silhouette (and the ignore mask) in rows of 64-bit words over its
            # bounding box
            self._bits, self._bofs, self._bbs = pack_rows(obs, C, F)
            self._ibits, self._ibofs, self._ibbs = pack_rows(ign, C, F)
            self._Ks = np.array([c.K for c in self.cameras])
            self._Rs = np.array([c.R for c in self.cameras])
            self._ts = np.array([c.t for c in self.cameras])
            d = np.zeros((C, 5))
            for i, c in enumerate(self.cameras):
                if c.dist.size > 5 and np.any(c.dist[5:] != 0):
                    raise ClothFitError(
                        f"camera '{c.name}': only 5 distortion coefficients (k1 k2 p1 p2 k3) are "
                        f"supported in the fitter; undistort the silhouettes first"
                    )
                d[i, : min(5, c.dist.size)] = c.dist[:5]
            self._dists = d
            self._Hs = np.array([c.height for c in self.cameras], dtype=np.int64)
            self._Ws = np.array([c.width for c in self.cameras], dtype=np.int64)
            self._maxh = int(max(c.height for c in self.cameras))
            self._maxw = int(max(c.width for c in self.cameras))
            self._quads = np.ascontiguousarray(self._mesh_quads(), dtype=np.int64)

    def _views(self):
        """The training images as the scoring kernels take them (``kernels.Views``)."""
        return kernels.Views(
            self._Ks,
            self._Rs,
            self._ts,
            self._dists,
            self._Hs,
            self._Ws,
            self._bits,
            self._bofs,
            self._bbs,
            self._ibits,
            self._ibofs,
            self._ibbs,
            self.areas,
            self._quads,
            self._maxh,
            self._maxw,
        )

    @property
    def n_images(self) -> int:
        return int(self.areas.size)

    def per_image(self, P: ArrayLike, offsets: Offsets | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(esil (P, C, F), exploded (P,))``; exploded candidates have ``inf`` everywhere.
        ``offsets`` (``scenario.Offsets``): each candidate's own estimate of the manipulation's
        unknowns (time offset, handle offsets); None = the scenario as it is."""
        if offsets is not None and len(offsets) != np.asarray(P).reshape(len(offsets), -1).shape[0]:
            raise ClothFitError(f"objective: {len(offsets)} offsets for {np.asarray(P).shape[0]} candidates")
        if not self.paper or self.crop is not None or (offsets is not None and offsets.stretches):
            return self._per_image_positions(P, offsets)
        P = np.ascontiguousarray(np.asarray(P, dtype=np.float64).reshape(-1, 4))
        C, F = self.areas.shape
        self.evaluations += P.shape[0]
        if self.backend == "numba":
            esil = np.full((P.shape[0], C, F), np.inf)
            codes = np.zeros(P.shape[0], dtype=np.int64)
            sheet, moves = paper_kernels.kernel_inputs(
                paper_kernels.population_arrays(self.scenario, P.shape[0], offsets=offsets)
            )
            kernels.objective_population(P, sheet, moves, self._views(), esil, codes)
            exploded = codes != 0
            esil[exploded] = np.inf
            return esil, exploded
        sim = (
            simulate_numpy(self.scenario, P)
            if offsets is None
            else self.model.simulate(self.scenario, P, backend="numpy", offsets=offsets)
        )
        esil = np.full((P.shape[0], C, F), np.inf)
        tris = self.scenario.grid.triangles
        for p in range(P.shape[0]):
            if sim.exploded[p]:
                continue
            for c, cam in enumerate(self.cameras):
                uv = cam.project(sim.positions[p])  # (F, V, 2)
                for f in range(F):
                    esil[p, c, f] = self._esil_numpy(
                        uv[f], tris, cam, self.observed[c][f], self.areas[c, f], self.ignore[c][f]
                    )
        return esil, sim.exploded

    def _per_image_positions(self, rows, offsets=None):
        """A model simulated on its own (Blender's cloth: SIMD batches), then scored."""
        rows = np.asarray(rows, dtype=np.float64)
        rows = rows.reshape(-1, len(self.model.row_names))
        C, F = self.areas.shape
        self.evaluations += rows.shape[0]
        sim = (
            self.model.simulate(self.scenario, rows, backend=self.backend)
            if offsets is None
            else self.model.simulate(self.scenario, rows, backend=self.backend, offsets=offsets)
        )
        esil = np.full((rows.shape[0], C, F), np.inf)
        ok = ~sim.exploded
        if self.backend == "numba":
            X = np.ascontiguousarray(self._mesh_points(np.where(ok[:, None, None, None], sim.positions, 0.0)))
            kernels.score_population(X, ok, self._views(), esil)
        else:
            tris = self._mesh_triangles()
            for p in np.nonzero(ok)[0]:
                for c, cam in enumerate(self.cameras):
                    uv = cam.project(self._mesh_points(sim.positions[p]))
                    for f in range(F):
                        esil[p, c, f] = self._esil_numpy(
                            uv[f], tris, cam, self.observed[c][f], self.areas[c, f], self.ignore[c][f]
                        )
        esil[sim.exploded] = np.inf
        return esil, sim.exploded

    def silhouettes(self, row: ArrayLike, offsets: Offsets | None = None) -> list[list[np.ndarray]] | None:
        """The clean silhouettes ``[c][f]`` of one candidate (a parameter row of the model; ``offsets``
        of one candidate) rasterised as this objective scores them, or None when it explodes."""
        rows = np.asarray(row, dtype=np.float64).reshape(1, -1)
        if offsets is None:
            sim = self.model.simulate(self.scenario, rows, backend=self.backend)
        else:
            sim = self.model.simulate(self.scenario, rows, backend=self.backend, offsets=offsets)
        if sim.exploded[0] or not np.all(np.isfinite(sim.positions[0])):
            return None
        X, tris = self._mesh_points(sim.positions[0]), self._mesh_triangles()
        return [
            [rasterize(cam.project(X[f]), tris, cam.height, cam.width) for f in range(X.shape[0])]
            for cam in self.cameras
        ]

    def _mesh_triangles(self) -> np.ndarray:
        """The triangles the silhouettes are drawn from: the cloth's, or its clipped mesh's under a crop."""
        tris = self.scenario.grid.triangles
        return tris if self.crop is None else clipped_triangles(tris.shape[0])

    def _mesh_quads(self) -> np.ndarray:
        """``_mesh_triangles`` in pairs, the quads the scoring kernels cut into row spans (corners a b c d:
        the triangles a b c and a c d)."""
        grid = self.scenario.grid
        return grid.quads if self.crop is None else clipped_quads(grid.triangles.shape[0])

    def _mesh_points(self, X: np.ndarray) -> np.ndarray:
        """The points of ``_mesh_triangles`` for cloth positions ``X`` (..., V, 3)."""
        return X if self.crop is None else clip_mesh(X, self.scenario.grid.triangles, self.crop)[0]

    @staticmethod
    def _esil_numpy(uv, tris, cam, obs, area, ignore=None):
        r0, c0, win = rasterize_window(uv, tris, cam.height, cam.width)
        if ignore is not None and win.size:
            win = win & ~ignore[r0 : r0 + win.shape[0], c0 : c0 + win.shape[1]]
        nmod = int(win.sum())
        inter = int(np.count_nonzero(obs[r0 : r0 + win.shape[0], c0 : c0 + win.shape[1]] & win)) if nmod else 0
        return (area + nmod - 2 * inter) / area

    def __call__(self, P, offsets=None):
        esil, exploded = self.per_image(P, offsets)
        e = esil.sum(axis=(1, 2))
        e[exploded | ~np.isfinite(e)] = np.inf
        return e


def load_observed(
    capture: Capture, cams: Sequence[int], fidx: Sequence[int], resolution: Sequence[int] | None = None
) -> tuple[list[Camera], list[list[np.ndarray]], list[list[np.ndarray | None]]]:
    """Cameras, observed silhouettes and ignore masks ``[cam][frame]`` of a capture, at ``resolution``."""
    cameras = [capture.cameras[c] for c in cams]
    observed, ignore = capture.load_observations(cams, fidx)
    refuse_full_silhouettes(capture, cams, fidx, observed, ignore)
    if resolution is not None:
        h, w = check_resolution(resolution, "fit resolution")
        cameras = [c.resized(h, w) for c in cameras]
        observed = [[resample_silhouette(o, h, w) for o in oc] for oc in observed]
        ignore = [[resample_ignore(g, h, w) for g in gc] for gc in ignore]
    return cameras, observed, ignore
