"""A small capture of Blender's cloth for the staged search's FitJob tests: tension 15 and shear 5, seen by a ring
of eight cameras at 45 x 60, noise-free."""

from __future__ import annotations

import os

from clothfit.core.observation.capture import load_capture
from clothfit.core.observation.synth import synth_capture


def small_blender_capture(folder: str):
    """The capture, written to ``folder``/cap and loaded."""
    root = os.path.join(str(folder), "cap")
    synth_capture(
        root,
        {"tension_stiffness": 15.0, "shear_stiffness": 5.0},
        model={"name": "blender", "fps": 24, "quality": 5},
        rig="ring8",
        resolution=(45, 60),
        noise=0.0,
    )
    return load_capture(root)
