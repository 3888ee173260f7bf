"""The commands that need the bpy module: blender (the whole pipeline) and blender-agreement."""

from __future__ import annotations

from ..core import defaults as D
from ..core.errors import ClothFitError
from .common import add_command, force_arg, refuse_existing


def cmd_blender(a):
    """The whole pipeline through Blender (build rig and cloth, simulate, render silhouettes, fit,
    overlays, save a .blend): needs the bpy module."""
    from ..blender import pipeline

    return pipeline.run(a)


def cmd_blender_agreement(a):
    if a.grid < 2 or a.grid > 200:
        raise ClothFitError(f"--grid {a.grid}: must be 2..200")
    refuse_existing(a.json, a.force, "--json")
    import bpy

    from ..blender import agreement

    out = {
        "grid": a.grid,
        "settle_s": a.settle,
        "after_s": a.after,
        "fps": a.fps,
        "blender": bpy.app.version_string,
        "handling": a.handling,
        "cases": agreement.run(a.grid, a.settle, a.after, a.fps, handling=a.handling),
    }
    if a.json:
        from ..core.jsonio import write_json

        write_json(a.json, out)
    return out


def register(sub):
    """The Blender family: ``blender`` (its options are the Blender layer's, ``blender/pipeline.py``) and
    ``blender-agreement``."""
    from ..blender import pipeline

    pipeline.add_arguments(
        add_command(
            sub,
            "blender",
            cmd_blender,
            "the whole pipeline through Blender (bpy module): rig, cloth, simulate, render "
            "silhouettes, fit, overlays, .blend",
            "a summary of the run as JSON",
        )
    )
    s = add_command(
        sub,
        "blender-agreement",
        cmd_blender_agreement,
        "the core's blender cloth model vs Blender's own solver, vertex by vertex (bpy module)",
        "every case's distances as JSON",
    )
    s.add_argument(
        "--grid", type=int, default=21, help="vertices per side of the 10 cm sheet, 2..200 (default: %(default)s)"
    )
    s.add_argument(
        "--settle",
        type=float,
        default=1.0,
        help="seconds of settling before t = 0: hung by four corners (hanging from two hands for --handling lift "
        "and apart) (default: %(default)s)",
    )
    s.add_argument(
        "--after", type=float, default=1.5, help="seconds simulated after the release (default: %(default)s)"
    )
    s.add_argument("--fps", type=float, default=24.0, help="scene frame rate [frames/s] (default: %(default)s)")
    s.add_argument(
        "--handling",
        choices=D.HANDLINGS,
        default="release",
        help="release: one corner let go after the settle; wave, lift, apart: the hands move along the paths "
        "of synth --handling instead (default: %(default)s)",
    )
    s.add_argument("--json", help="also write every figure to this file")
    force_arg(s, "--json")
