"""Synthetic captures: our own model with known parameters, rasterised by the core (docs/method.md#spec-5).

The Blender layer has its own path that renders the observations with Blender instead; both write
the same capture format.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

import numpy as np

from .. import defaults as D
from ..errors import ClothFitError
from ..physics import blender as B
from ..physics.handling import handling_scenario
from ..physics.models import BlenderModel, ClothModel, PaperModel, get_model, simulate
from ..physics.paper import Params
from ..physics.scenario import Scenario
from .camera import Camera, load_rig
from .capture import Capture, write_capture
from .metrics import add_boundary_noise
from .raster import silhouette


def noise_rng(seed: int, cam: int, frame: int) -> np.random.Generator:
    """Independent, reproducible noise stream per image."""
    return np.random.default_rng([int(seed), int(cam), int(frame)])


def synth_capture(
    root: str | os.PathLike,
    params: dict[str, Any] | None = None,
    rig: str = D.DEFAULT_RIG,
    noise: float = D.NOISE_FRACTION,
    resolution: Sequence[int] | None = None,
    seed: int = 0,
    scenario: Scenario | None = None,
    cameras: Sequence[Camera] | None = None,
    truth_dt_safety: float = D.TRUTH_DT_SAFETY,
    model: str | dict[str, Any] | ClothModel | None = None,
    handling: str | None = None,
) -> Capture:
    """Simulate ``params`` on ``scenario`` (default: the paper's) with ``model`` (default: the paper's
    sheet, ``params`` = m, k, l, d, default the ground truth; ``"blender"`` or a Blender model dict:
    ``params`` = ClothSettings values, missing ones Blender's defaults, ``time_scale`` the real-time
    one for the model's frame rate) and write a capture with ``noise`` boundary noise to ``root``.
    ``handling``: a named handling (``physics.handling``, default ``release``: the paper's) for the
    default scenario; not with ``scenario``. Returns the Capture."""
    if (
        isinstance(truth_dt_safety, bool)
        or not isinstance(truth_dt_safety, (int, float))
        or not (0 < truth_dt_safety <= 1)
    ):  # also rejects NaN
        raise ClothFitError(
            f"synth: truth_dt_safety must be a number in (0, 1] (a fraction of the model's "
            f"stable time step), got {truth_dt_safety!r}"
        )
    if isinstance(noise, bool) or not isinstance(noise, (int, float)) or not (0 <= noise <= 1):
        raise ClothFitError(f"synth: noise must be a fraction in [0, 1], got {noise!r}")
    if handling is not None and scenario is not None:
        raise ClothFitError("synth: give a scenario or a handling, not both")
    scenario = scenario or handling_scenario(handling or D.HANDLING)
    model = get_model(model)
    if isinstance(model, BlenderModel):
        given = dict(params or {})
        given.setdefault("time_scale", B.physical_time_scale(model.fps))
        given.setdefault("quality", model.quality)
        given.setdefault("bending_model", model.bending_model)
        settings = B.check_settings(given, "ground-truth Blender settings")
        model = BlenderModel(model.fps, settings["quality"], settings["bending_model"])
        sim = model.simulate(scenario, B.settings_row(settings))
        truth = {"true_blender_cloth": settings, "true_model": model.to_dict()}
        cloth_mass = settings["mass"] * scenario.grid.n_vertices
        what = f"ground-truth Blender settings {settings}"
    else:
        p = Params.from_dict(params or D.GT_PARAMS, "ground-truth parameters")
        sim = simulate(scenario, [p], safety=truth_dt_safety)
        truth = {"true_params": p.as_dict(), "truth_dt_safety": truth_dt_safety}
        cloth_mass = p.m * scenario.grid.n_vertices
        what = f"ground-truth parameters {p.as_dict()}"
    cams = cameras if cameras is not None else load_rig(rig)
    if resolution is not None:
        cams = [c.resized(int(resolution[0]), int(resolution[1])) for c in cams]
    if sim.exploded[0]:
        raise ClothFitError(f"{what} make the simulation explode: {sim.reason[0]}")
    X = sim.positions[0]
    tris = scenario.grid.triangles
    sils = []
    for ci, cam in enumerate(cams):
        row = []
        for fi in range(X.shape[0]):
            s = silhouette(cam, X[fi], tris)
            if not s.any():
                raise ClothFitError(
                    f"camera '{cam.name}' does not see the cloth at t = {scenario.frame_times[fi]:.3f} s"
                )
            if noise > 0:
                s = add_boundary_noise(s, noise, noise_rng(seed, ci, fi))
            row.append(s)
        sils.append(row)
    meta = {
        "generator": f"synth (core {model.name} model, core rasteriser)",
        **truth,
        "noise_fraction": noise,
        "seed": seed,
        "rig": rig if cameras is None else "custom",
    }
    if handling not in (None, "release"):  # the paper's release writes the capture it always wrote
        meta["handling"] = handling
    return write_capture(
        root,
        cams,
        scenario,
        sils,
        shapes=X,
        cloth_mass=cloth_mass,
        meta=meta,
        model=None if isinstance(model, PaperModel) else model.to_dict(),
    )
