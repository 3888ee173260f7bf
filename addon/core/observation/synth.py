"""Synthetic captures: our own model with known parameters, rasterised by the core (SPEC 5).

The Blender layer has its own path that renders the observations with Blender instead; both write
the same capture format.
"""
from __future__ import annotations

import numpy as np

from .. import defaults as D
from ..errors import ClothFitError
from ..physics.models import simulate
from ..physics.paper import Params
from ..physics.scenario import paper_scenario
from .camera import load_rig
from .capture import write_capture
from .metrics import add_boundary_noise
from .raster import silhouette


def noise_rng(seed: int, cam: int, frame: int) -> np.random.Generator:
    """Independent, reproducible noise stream per image."""
    return np.random.default_rng([int(seed), int(cam), int(frame)])


def synth_capture(root, params=None, rig=D.DEFAULT_RIG, noise=D.NOISE_FRACTION, resolution=None, seed=0,
                  scenario=None, cameras=None, truth_dt_safety=D.TRUTH_DT_SAFETY):
    """Simulate ``params`` (default: ground truth) on ``scenario`` (default: the paper's) and write a
    capture with ``noise`` boundary noise to ``root``. Returns the Capture."""
    p = Params.from_dict(params or D.GT_PARAMS, "ground-truth parameters")
    scenario = scenario or paper_scenario()
    cams = cameras if cameras is not None else load_rig(rig)
    if resolution is not None:
        cams = [c.resized(int(resolution[0]), int(resolution[1])) for c in cams]
    sim = simulate(scenario, [p], safety=truth_dt_safety)
    if sim.exploded[0]:
        raise ClothFitError(f"ground-truth parameters {p.as_dict()} make the simulation explode: {sim.reason[0]}")
    X = sim.positions[0]
    tris = scenario.grid.triangles
    sils = []
    for ci, cam in enumerate(cams):
        row = []
        for fi in range(X.shape[0]):
            s = silhouette(cam, X[fi], tris)
            if not s.any():
                raise ClothFitError(f"camera '{cam.name}' does not see the cloth at t = {scenario.frame_times[fi]:.3f} s")
            if noise > 0:
                s = add_boundary_noise(s, noise, noise_rng(seed, ci, fi))
            row.append(s)
        sils.append(row)
    meta = {"generator": "synth (core rasteriser)", "true_params": p.as_dict(), "noise_fraction": noise,
            "seed": seed, "truth_dt_safety": truth_dt_safety, "rig": rig if cameras is None else "custom"}
    return write_capture(root, cams, scenario, sils, shapes=X, cloth_mass=p.m * scenario.grid.n_vertices, meta=meta)
