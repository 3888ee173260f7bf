"""``synth``: a synthetic capture, with the handling its cloth is given (``--handling``).

``add_synth(sub)`` declares the command (the fitting family registers it first): the paper's release, a corner
waved, two hands lifting the cloth or moving apart (``core.physics.handling``)."""

from __future__ import annotations

from ..core import defaults as D
from .common import add_command, force_arg, model_args, model_spec, params_arg, res


def cmd_synth(a):
    from ..core.observation.synth import synth_capture
    from .common import refuse_filled_folder

    refuse_filled_folder(a.out, a.force)
    kw = {} if a.truth_dt_safety is None else {"truth_dt_safety": a.truth_dt_safety}
    spec = model_spec(a)
    params = params_arg(a, {} if spec and spec["name"] == "blender" else None)
    if spec and spec["name"] == "blender":
        params = params.get("blender_cloth", params)
    handling = getattr(a, "handling", D.HANDLING)
    cap = synth_capture(
        a.out,
        params,
        rig=a.rig,
        noise=a.noise,
        resolution=res(a.resolution),
        seed=a.seed,
        model=spec,
        handling=handling,
        **kw,
    )
    print(
        f"wrote capture {a.out}: {len(cap.cameras)} cameras x {len(cap.frame_times)} frames"
        + ("" if handling == D.HANDLING else f", handling {handling}")
    )
    return {
        "capture": a.out,
        "cameras": [c.name for c in cap.cameras],
        "frame_times": list(cap.frame_times),
        "resolution": [cap.cameras[0].height, cap.cameras[0].width],
        "handling": handling,
    }


HANDLING_HELP = (
    "how the cloth is handled after it settles: release = four corners held, one let go at t = 0 "
    f"(the paper's); wave = four corners held, corner {D.WAVE_CORNER} waved up and down by "
    f"{D.WAVE_AMPLITUDE * 100:g} cm at {D.WAVE_FREQUENCY:g} Hz; lift = the cloth hanging from two hands "
    f"at the corners of one edge, lifted by {D.LIFT_HEIGHT * 100:g} cm and lowered over {D.LIFT_DURATION:g} s; "
    f"apart = the same two hands {D.APART_HOLD:g} of the edge apart, moving to {D.APART_SPREAD:g} of it and "
    f"back over {D.APART_DURATION:g} s; drag = a table {D.DRAG_TABLE_DROP * 100:g} cm below the cloth, three corners let "
    f"go at t = 0 and the fourth dragged {D.DRAG_DISTANCE * 100:g} cm along the table (--model blender: the "
    "capture declares the table) (default: %(default)s)"
)


def add_synth(sub):
    """``synth``: a synthetic capture, with the handling its cloth is given."""
    s = add_command(
        sub,
        "synth",
        cmd_synth,
        "make a synthetic capture from ground-truth parameters",
        "the capture's cameras, frame times and image size as JSON",
    )
    s.add_argument("--out", required=True, help="capture folder to write (new or empty unless --force)")
    force_arg(s, "the files of a capture already in --out")
    s.add_argument(
        "--rig",
        default=D.DEFAULT_RIG,
        help="camera rig: a preset of rigs/ (lab18, lab18_far, ring8) or a cameras JSON (default: %(default)s)",
    )
    s.add_argument(
        "--params",
        help="JSON or a JSON file: the paper model's m [kg per point mass], k [N/m], l [m], "
        "d [N s/m], or Blender cloth settings with --model blender (default: the built-in "
        "ground truth)",
    )
    s.add_argument(
        "--noise",
        type=float,
        default=D.NOISE_FRACTION,
        help="fraction of the silhouettes' boundary pixels flipped (default: %(default)s)",
    )
    s.add_argument("--resolution", help="image size HxW [px], e.g. 120x160 (default: the rig's)")
    s.add_argument("--seed", type=int, default=0, help="random seed of the boundary noise (default: %(default)s)")
    s.add_argument(
        "--truth-dt-safety",
        type=float,
        default=None,
        help="time step of the truth as a factor of sqrt(m/k); 0.125 = 4x finer than the fitter's "
        "(default: the model's own)",
    )
    model_args(s, "paper")
    s.add_argument("--handling", choices=D.HANDLINGS, default=D.HANDLING, help=HANDLING_HELP)
