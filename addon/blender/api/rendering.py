# SPDX-License-Identifier: GPL-3.0-or-later
"""Render Silhouettes: Blender renders the baked cloth from every rig camera at every capture
time into a capture directory (core format).

The scene is read once up front (``read_scene``: times, cloth, manipulation, bake, cameras,
parameters) into core objects; then each step renders one capture time (every camera) through
``render.py``. Occluders (collection ``Occluders``) hide the cloth and are written as ignore masks.
"""

from __future__ import annotations

import os

import bpy
import numpy as np

from ...core.errors import ClothFitError
from .. import render as R
from .. import scene as S
from .reading import props, read_scene, refuse_foreign_capture
from .steps import Steps


def render_silhouettes(scene, out_dir=None, noise=None, seed=None, progress=None, engine=None):
    """Render every rig camera at every capture time into a capture directory; returns the
    ``Capture``. ``engine``: WORKBENCH or EEVEE (default: the scene's setting); ``noise``/``seed``:
    boundary noise (default: the scene's); ``progress(fraction)`` after each capture time."""
    return render_steps(scene, out_dir, noise, seed, engine).run(progress)


def render_steps(scene, out_dir=None, noise=None, seed=None, engine=None) -> Steps:
    """``render_silhouettes`` in steps, one capture time (every camera) per step, for the modal
    operator. Cancelled, it keeps the silhouettes rendered so far on disk; capture.json is written
    only after the last one, so a stopped render never looks like a complete capture."""
    return Steps(_render_work, scene, out_dir, noise, seed, engine)


def _render_work(steps, scene, out_dir, noise, seed, engine):
    from ...core.observation.capture import (
        finalize_capture,
        write_capture,
    )
    from ...core.observation.metrics import add_boundary_noise
    from ...core.observation.silhouette_files import save_silhouette
    from ...core.observation.synth import noise_rng

    p = props(scene)
    noise = p.noise if noise is None else float(noise)
    seed = p.noise_seed if seed is None else int(seed)
    engine = getattr(p, "render_engine", "WORKBENCH") if engine is None else engine
    inp = read_scene(scene, capture=True, out_dir=out_dir, rig=True, baked=True)
    root, times, cams, sc, par = inp.capture_dir, inp.times, inp.cameras, inp.scenario, inp.params
    refuse_foreign_capture(root, GENERATOR_PREFIX, "Render Silhouettes", "renders")
    check_bake_follows_handles(sc, inp.shapes)
    occluders = R.occluder_objects(scene)
    # the cameras as Blender renders them: the exact (float64) imported camera while the Blender
    # camera still shows it, minus lens distortion (Blender renders a pinhole image)
    dropped = inp.distortion_dropped
    meta = {
        "generator": f"{GENERATOR_PREFIX}{bpy.app.version_string} {engine.title()} (addon/blender/render.py)",
        "true_params": par.as_dict(),
        "noise_fraction": noise,
        "seed": seed,
    }
    if occluders:
        meta["occluders"] = [o.name for o in occluders]
    if dropped:
        meta["distortion_dropped"] = dropped
    steps.kept = "nothing was written"
    yield 0.0, f"rendering {len(cams)} cameras x {len(times)} capture times"
    # two steps: everything but capture.json now, capture.json only once every PNG is written, so a
    # render that fails or stops midway never leaves a capture that looks complete
    pending = write_capture(
        root,
        cams,
        sc,
        None,
        shapes=inp.shapes,
        cloth_mass=par.m * sc.grid.n_vertices,
        meta=meta,
        finalize=False,
        ignore=True if occluders else None,
    )
    steps.kept = f"no silhouette was rendered yet; {root} holds the capture's cameras.json (no capture.json)"
    frame0 = scene.frame_current
    tmp = os.path.join(root, ".render_tmp")
    os.makedirs(tmp, exist_ok=True)
    try:
        for fi, t in enumerate(times):
            scene.frame_set(S.frame_of_time(scene, t))
            masks = R.render_masks(
                scene,
                inp.cloth,
                inp.camera_objects,
                tmpdir=tmp,
                engine=engine,
                occluders=occluders if occluders else None,
            )
            for ci, m in enumerate(masks):
                ign = None
                if occluders:
                    m, ign = m
                if not m.any():
                    raise ClothFitError(
                        f"camera '{cams[ci].name}' does not see the cloth at t = {t:.3f} s "
                        f"(empty silhouette{', occluders included' if occluders else ''})"
                    )
                if noise > 0:
                    m = add_boundary_noise(m, noise, noise_rng(seed, ci, fi))
                    if ign is not None:
                        m &= ~ign  # boundary noise at an occluder's edge is not cloth seen
                save_silhouette(pending.silhouette_path(ci, fi), m)
                if ign is not None:
                    save_silhouette(pending.ignore_path(ci, fi), ign)
            steps.kept = (
                f"kept the silhouettes of {fi + 1} of {len(times)} capture times ({(fi + 1) * len(cams)} "
                f"files) in {root}; capture.json not written (the capture is incomplete: render again)"
            )
            if fi + 1 < len(times):
                yield (fi + 1) / len(times), f"capture time {fi + 1}/{len(times)} (t = {t:.3f} s)"
        cap = finalize_capture(pending)
    finally:
        for f in os.listdir(tmp):
            os.remove(os.path.join(tmp, f))
        os.rmdir(tmp)
        scene.frame_set(frame0)
    p.capture_dir = root
    return cap


GENERATOR_PREFIX = "Blender "
BAKE_TOL = 1e-5  # m: a held handle vertex of the bake vs the manipulation's position for it


def check_bake_follows_handles(scenario, shapes):
    """Raise unless the baked shapes hold every handle where the scenario puts it (the bake is of
    this manipulation: e.g. no empty moved, no corner changed since Simulate)."""
    times = scenario.frame_times
    for h in scenario.handles:
        held = h.held(times)
        if not held.any():
            continue
        want = h.position(times[held])
        got = shapes[held][:, h.vertex]
        err = np.linalg.norm(got - want, axis=-1)
        k = int(np.argmax(err))
        if err[k] > BAKE_TOL:
            raise ClothFitError(
                f"the baked cloth does not follow the current manipulation: the handle on vertex "
                f"{h.vertex} is {1000 * err[k]:.3f} mm away from its position at t = "
                f"{times[held][k]:.3f} s (handles, empties or settings changed since Simulate): "
                f"simulate again"
            )
