"""The core's ``blender`` cloth model against Blender's own Cloth modifier, vertex by vertex.

    clothfit blender-agreement [--grid 21] [--settle 1.0] [--after 1.5] [--fps 24] [--handling release] [--json FILE]

The same cloth (a 10 cm sheet, ``--grid`` x ``--grid`` vertices, hung from its four corners),
pins, release (one corner let go after ``--settle`` seconds) and settings are simulated by the
core (``core.physics.blender_kernels``) and by Blender (``blender.cloth``: a mesh with the
network's edge order, pin group, Cloth modifier); every frame's vertices are compared. Prints
the mean and max distance [mm] over every vertex of every frame per case: Blender's default
cloth, its presets (silk: soft, little bending; cotton; denim; leather; rubber), the linear
bending model, and qualities from 2 to 15. ``--handling`` moves the hands along a synthetic handling's
paths instead of releasing a corner (``physics.handling``). Needs the bpy module.
"""

from __future__ import annotations

import time

import numpy as np

from ..core.errors import ClothFitError
from ..core.physics import blender as B
from ..core.physics.blender_kernels import Prepared
from ..core.physics.handling import handling_scenario
from ..core.physics.models import BlenderModel
from ..core.physics.scenario import ClothGrid, Scenario

PRESETS = B.PRESETS

PIN_WEIGHT = "pin weight"  # a case key: the handles' pin weight (< 1: Blender's soft goal springs)

CASES = [
    ("default", {}),
    ("silk (soft, little bending)", PRESETS["silk"]),
    ("cotton", PRESETS["cotton"]),
    ("denim (quality 12)", PRESETS["denim"]),
    ("leather (quality 15)", PRESETS["leather"]),
    ("rubber (quality 7)", PRESETS["rubber"]),
    ("linear bending", {"bending_model": "LINEAR"}),
    ("silk, linear bending", dict(PRESETS["silk"], bending_model="LINEAR")),
    ("default, quality 2", {"quality": 2}),
    ("default, quality 15", {"quality": 15}),
    ("default, time scale 1 (Blender's own)", {"time_scale": 1.0}),
    ("soft pins (weight 0.95, pin stiffness 5)", {"pin_stiffness": 5.0, PIN_WEIGHT: 0.95}),
]


def agreement_scenario(
    n: int = 21, settle: float = 1.0, after: float = 1.5, fps: float = 24.0, handling: str = "release"
) -> Scenario:
    """A 10 cm sheet of ``n`` x ``n`` vertices settled for ``settle`` seconds, then handled for
    ``after`` seconds (frame times every frame): by default hung from its corners and one corner
    released; another of ``defaults.HANDLINGS`` moves the hands along paths (``physics.handling``)."""
    grid = ClothGrid(n, n, 0.10)
    times = np.arange(1, int(round(after * fps)) + 1) / fps
    sc = handling_scenario(handling, grid, times)
    return Scenario(sc.grid, sc.handles, sc.frame_times, settle, sc.gravity, sc.colliders)


def compare(scene, scenario: Scenario, settings: dict, fps: float = 24.0, frame_start: int = 1) -> dict:
    """Simulate ``settings`` on ``scenario`` in the core and in Blender; distances over every frame."""
    from . import cloth as BC

    given = dict(settings)
    weight = given.pop(PIN_WEIGHT, None)
    if weight is not None:
        for h in scenario.handles:
            h.weight = float(weight)
    given.setdefault("time_scale", B.physical_time_scale(fps))
    s = B.check_settings(given, "agreement settings")
    model = BlenderModel(fps, s["quality"], s["bending_model"])
    net, plan = model.plan(scenario)
    if weight is not None:
        for h in scenario.handles:
            del h.weight
    t0 = time.perf_counter()
    prep = Prepared(net, plan, s["quality"], s["time_scale"], scenario.gravity, True, scenario.colliders)
    core, codes, _ = prep.run(B.settings_row(s)[None])
    t_core = time.perf_counter() - t0
    if codes[0]:
        raise ClothFitError(f"agreement: the core simulation of {s} exploded")
    obj = BC.build_cloth_object(
        scene, net, plan, s, name="Agreement Cloth", frame_start=frame_start, colliders=scenario.colliders
    )
    try:
        blender, t_blender, iters = BC.simulate_frames(scene, obj, plan.n_frames, frame_start)
    finally:
        BC.remove_cloth_object(obj)
    d = np.linalg.norm(core[0].astype(np.float64) - blender, axis=-1) * 1000.0
    after = d[plan.release_frame :]
    return {
        "settings": s,
        "frames": int(plan.n_frames + 1),
        "vertices": int(net.n_vertices),
        "mean_mm": float(d.mean()),
        "max_mm": float(d.max()),
        "mean_mm_after_release": float(after.mean()),
        "max_mm_after_release": float(after.max()),
        "exactly_equal_frames": int(np.sum(np.all(d == 0.0, axis=1))),
        "core_s": t_core,
        "blender_s": t_blender,
        "blender_cg_iterations": iters,
    }


HANDLING_TEXT = {
    "release": "hung by its corners, {settle:g} s settle, one corner released, {after:g} s after",
    "wave": "hung by its corners, {settle:g} s settle, one corner waved for {after:g} s",
    "lift": "hanging from two hands, {settle:g} s settle, lifted and lowered for {after:g} s",
    "apart": "hanging from two hands, {settle:g} s settle, the hands moving apart and back for {after:g} s",
    "drag": "held flat by its corners, {settle:g} s settle, dropped onto a table and one corner dragged along it, "
    "{after:g} s after",
}


def run(n=21, settle=1.0, after=1.5, fps=24.0, cases=None, echo=print, handling="release") -> list:
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scenario = agreement_scenario(n, settle, after, fps, handling)
    rows = []
    echo(
        f"{n} x {n} sheet, 10 cm, {HANDLING_TEXT[handling].format(settle=settle, after=after)}, "
        f"{fps:g} fps: core blender model vs Blender {bpy.app.version_string}"
    )
    echo(
        f"{'case':40s} {'q':>3s} {'mean mm':>9s} {'max mm':>9s} {'equal frames':>13s} {'core s':>7s} {'Blender s':>9s}"
    )
    for name, settings in cases or CASES:
        r = compare(scene, scenario, settings, fps)
        r["case"] = name
        rows.append(r)
        echo(
            f"{name:40s} {r['settings']['quality']:3d} {r['mean_mm']:9.6f} {r['max_mm']:9.6f} "
            f"{r['exactly_equal_frames']:6d}/{r['frames']:<6d} {r['core_s']:7.2f} {r['blender_s']:9.2f}"
        )
    worst = max(r["max_mm"] for r in rows)
    goal = "the goal with a table: within 2 mm" if scenario.colliders else "goal: mean < 0.1 mm, max < 1 mm"
    echo(f"worst case: mean {max(r['mean_mm'] for r in rows):.6f} mm, max {worst:.6f} mm ({goal})")
    return rows
