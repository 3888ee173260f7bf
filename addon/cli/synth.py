"""``synth``: a synthetic capture, with the handling its cloth is given (``--handling``).

``extend(sub)`` adds ``--handling`` to the ``synth`` command the fitting family registers and makes
``cmd_synth`` (here) its command: the paper's release, a corner waved, two hands lifting the cloth or
moving apart (``core.physics.handling``)."""

from __future__ import annotations

from ..core import defaults as D
from .common import _model_spec, _params, _res


def cmd_synth(a):
    from ..core.observation.synth import synth_capture
    from .common import refuse_filled_folder

    refuse_filled_folder(a.out, a.force)
    kw = {} if a.truth_dt_safety is None else {"truth_dt_safety": a.truth_dt_safety}
    spec = _model_spec(a)
    params = _params(a, {} if spec and spec["name"] == "blender" else None)
    if spec and spec["name"] == "blender":
        params = params.get("blender_cloth", params)
    handling = getattr(a, "handling", D.HANDLING)
    cap = synth_capture(
        a.out,
        params,
        rig=a.rig,
        noise=a.noise,
        resolution=_res(a.resolution),
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
    f"back over {D.APART_DURATION:g} s (default: %(default)s)"
)


def extend(sub):
    """``--handling`` on the ``synth`` command of ``sub`` (the subparsers), run by ``cmd_synth``."""
    s = sub.choices["synth"]
    s.add_argument("--handling", choices=D.HANDLINGS, default=D.HANDLING, help=HANDLING_HELP)
    s.set_defaults(fn=cmd_synth)
