"""Two small takes of one cloth for the several-takes tests: a 7 x 7 Blender cloth hung by its four corners,
one take letting one corner go (24 fps), the other two corners (20 fps), each seen by eight cameras."""

from __future__ import annotations

import os

from clothfit.core.observation.synth import synth_capture
from clothfit.core.physics.scenario import ClothGrid, Handle, Scenario, paper_scenario

TRUTH = {"tension_stiffness": 40.0, "shear_stiffness": 8.0, "bending_stiffness": 0.2, "air_damping": 2.0}
GRID = ClothGrid(7, 7, 0.1)


def released(corners, times):
    """Four corners held, ``corners`` (indices into the grid's corners) let go at t = 0."""
    sc = paper_scenario(GRID, frame_times=times)
    cs = GRID.corners()
    hs = [
        Handle(h.vertex, h.times, h.positions, 0.0 if h.vertex in [cs[c] for c in corners] else None)
        for h in sc.handles
    ]
    return Scenario(GRID, hs, sc.frame_times)


def make_takes(root, frames_one: int, frames_two: int):
    """(one corner let go, ``frames_one`` frames at 24 fps; two corners let go, ``frames_two`` at 20 fps),
    written under ``root``."""
    kw = dict(rig="ring8", resolution=(60, 80), noise=0.05)
    one = synth_capture(
        os.path.join(str(root), "one_corner"),
        TRUTH,
        model={"name": "blender", "fps": 24},
        scenario=released([0], [k / 8 for k in range(1, frames_one + 1)]),
        **kw,
    )
    two = synth_capture(
        os.path.join(str(root), "two_corners"),
        TRUTH,
        model={"name": "blender", "fps": 20},
        scenario=released([0, 1], [k / 10 for k in range(1, frames_two + 1)]),
        **kw,
    )
    return one, two
