# SPDX-License-Identifier: GPL-3.0-or-later
"""Scene building: the cloth mesh, the handle empties of the Empties manipulation, and Simulate
(the core simulation of the scene's parameters, baked into shape keys)."""

from __future__ import annotations

import threading
import time

import bpy

from ...core.errors import ClothFitError
from ...core.physics.scenario import Handle
from .. import scene as S
from .reading import (
    capture_scenario,
    grid_from_props,
    parse_times,
    props,
    read_scene,
    scenario_for,
    scene_grid,
)
from .steps import Steps


def build_cloth(scene):
    p = props(scene)
    grid = capture_scenario(scene).grid if p.scenario_source == "CAPTURE" else grid_from_props(scene)
    if p.scenario_source == "EMPTIES":  # vertex groups only: no need to sample (or validate) the empties yet
        handles = [
            Handle(v, [0.0], grid.rest[v][None], link.release_time if link.use_release else None)
            for link, v in ((lk, lk.row * grid.nx + lk.column) for lk in p.handles)
            if link.row < grid.ny and link.column < grid.nx
        ]
    else:
        handles = scenario_for(scene, grid).handles
    obj = S.build_cloth(scene, grid, handles)
    p.cloth_object = obj
    return obj


HANDLE_COLLECTION = "ClothFit Handles"


def add_handle_empty(scene, row=None, column=None):
    """A new empty at grid vertex (row, column)'s rest position, linked to it; the manipulation
    source becomes Empties. Returns the link."""
    p = props(scene)
    row = p.new_handle_row if row is None or row < 0 else int(row)
    column = p.new_handle_column if column is None or column < 0 else int(column)
    grid = scene_grid(scene)
    if not (0 <= row < grid.ny and 0 <= column < grid.nx):
        raise ClothFitError(
            f"vertex row {row}, column {column} is outside the {grid.nx}x{grid.ny} cloth grid "
            f"(rows 0..{grid.ny - 1}, columns 0..{grid.nx - 1})"
        )
    v = row * grid.nx + column
    for i, link in enumerate(p.handles):
        if (link.row, link.column) == (row, column):
            raise ClothFitError(f"vertex row {row}, column {column} is already linked by handle #{i + 1}")
    coll = S.ensure_collection(scene, HANDLE_COLLECTION)
    obj = bpy.data.objects.new(f"ClothFit Handle r{row} c{column}", None)
    obj.empty_display_type = "SPHERE"
    obj.empty_display_size = max(grid.spacing, 1e-3)
    obj.location = [float(x) for x in grid.rest[v]]
    coll.objects.link(obj)
    link = p.handles.add()
    link.empty, link.row, link.column = obj, row, column
    p.handles_index = len(p.handles) - 1
    p.scenario_source = "EMPTIES"
    return link


def remove_handle(scene, index=None, delete_empty=False):
    """Remove handle link ``index`` (default: the active one); optionally delete its empty."""
    p = props(scene)
    i = p.handles_index if index is None or index < 0 else int(index)
    if not 0 <= i < len(p.handles):
        raise ClothFitError(f"no handle #{i + 1} to remove ({len(p.handles)} handles)")
    obj = p.handles[i].empty
    p.handles.remove(i)
    p.handles_index = max(0, min(p.handles_index, len(p.handles) - 1))
    if delete_empty and obj is not None:
        bpy.data.objects.remove(obj, do_unlink=True)


def simulate(scene):
    """Simulate the scene's parameters and bake: one shape key per capture time plus t = 0.
    Returns {"frames", "times", "seconds", "notes", "scenario"}."""
    return simulate_steps(scene, threaded=False).run()


def simulate_steps(scene, threaded=True) -> Steps:
    """``simulate`` in steps for the modal operator: read the scene, simulate (in a worker thread
    when ``threaded``: numpy/numba only, no bpy; each step checks on it), bake. Cancelled before
    the bake, the scene is unchanged (the previous bake stays; a running simulation finishes in
    its thread and is dropped); the bake itself is one step."""
    return Steps(_simulate_work, scene, threaded)


def _simulate_work(steps, scene, threaded):
    from ...core.physics.models import simulate as core_simulate

    times = parse_times(props(scene).frame_times)
    bake_times = sorted(set([0.0] + times))
    inp = read_scene(scene, bake_times)
    sc, par = inp.scenario, inp.params
    steps.kept = "the scene is unchanged (the previous bake is kept)"
    yield 0.0, f"simulating {sc.grid.nx}x{sc.grid.ny} cloth to t = {bake_times[-1]:g} s"
    t0 = time.time()
    if threaded:
        box = {}

        def work():
            try:
                box["res"] = core_simulate(sc, [par])
            except BaseException as e:  # noqa: BLE001 - handed to the main thread, raised there
                box["err"] = e

        worker = threading.Thread(target=work, name="clothfit-simulate", daemon=True)
        worker.start()
        while worker.is_alive():
            worker.join(0.01)  # a short wait per step: no busy loop, the UI stays responsive
            yield 0.5, f"simulating ({time.time() - t0:.1f} s)"
        if "err" in box:
            raise box["err"]
        res = box["res"]
    else:
        res = core_simulate(sc, [par])
    if res.exploded[0]:
        raise ClothFitError(
            f"the simulation with m={par.m:g}, k={par.k:g}, l={par.l:g}, d={par.d:g} is unstable: {res.reason[0]}"
        )
    yield 0.9, "baking shape keys"
    frames = S.bake_shape_keys(scene, inp.cloth, bake_times, res.positions[0])
    scene.frame_set(frames[0])
    return {
        "frames": frames,
        "times": bake_times,
        "seconds": time.time() - t0,
        "notes": list(inp.notes),
        "scenario": sc,
    }
