"""``export-blender-cloth``: a blender-model fit as Cloth modifier settings: JSON, a script that runs
in Blender as it is (``--python``), or a preset of Blender's own format (``--preset``)."""

from __future__ import annotations

import os
import pprint

from ..core.errors import ClothFitError
from ..core.location import PACKAGE_DIR
from .common import Text, add_command, force_arg, refuse_existing

SCRIPT_FILE = os.path.join(PACKAGE_DIR, "blender", "cloth_script.py")  # read as text: it imports bpy


def blender_script(settings: dict, fps: float, object_name=None, source="", comments=(), colliders=None) -> str:
    """The script that puts ``settings`` on a Cloth modifier in Blender: the Blender layer's
    ``cloth_script.py`` (the function the add-on's Apply Blender Cloth calls) and one call of it;
    ``colliders`` (a scenario's ``Collisions``): the colliders too, as mesh objects with a Collision
    modifier, and the cloth's collisions on (``add_colliders``)."""
    with open(SCRIPT_FILE, encoding="utf-8") as f:
        body = f.read().rstrip("\n")
    lines = [
        body,
        "",
        "",
        f"# the fit{f' in {source}' if source else ''}: Blender cloth settings for a {fps:g} fps scene",
        *comments,
        f"SETTINGS = {pprint.pformat(settings, sort_dicts=False)}",
        f"obj = apply_cloth_settings(SETTINGS, fps={fps!r}, object_name={object_name!r})",
        f'print(f"fitted Cloth settings applied to {{obj.name!r}}, scene at {fps:g} fps")',
    ]
    if colliders is not None:
        from ..core.physics.colliders import blender_objects

        lines += [
            "# the colliders of the fit's scene (Collision modifiers) and the cloth's collision settings",
            f"COLLIDERS = {pprint.pformat(blender_objects(colliders), sort_dicts=False, width=119)}",
            f"COLLISION_SETTINGS = {pprint.pformat(colliders.settings_dict(), sort_dicts=False)}",
            "made = add_colliders(COLLIDERS, COLLISION_SETTINGS, obj.name)",
            "print('colliders:', ', '.join(o.name for o in made))",
        ]
    return "\n".join(lines) + "\n"


def _write_text(path, text):
    from ..core.safeio import atomic_write

    atomic_write(path, text.encode("utf-8"))


def cmd_export_blender_cloth(a):
    from ..core.fitting.result import FitResult, interval_comments
    from ..core.physics.cloth_presets import nearest_preset, preset_text

    if a.object and not a.python:
        raise ClothFitError("--object names the object of the --python script: give --python too")
    for path, what in ((a.out, "--out"), (a.preset, "--preset")):
        refuse_existing(path, a.force, what)
    if a.out and a.preset and os.path.realpath(a.out) == os.path.realpath(a.preset):
        raise ClothFitError(f"--out and --preset are the same file {a.out}")
    out = FitResult.from_json(a.result, "result").blender_export()
    s, fps = out["blender_cloth"], out["blender_scene"]["fps"]
    near = out["nearest_preset"] = nearest_preset(s)
    manip = out.get("manipulation") or {}
    print(
        f"nearest Blender preset: {near['name']}, typically {near['factor']:.2g}x apart "
        f"({'; '.join(near['differences'])})"
    )
    if a.preset:
        _write_text(a.preset, preset_text(s, fps, a.result, interval_comments(out)))
        print(f"wrote the preset {a.preset}: copy it into Blender's presets/cloth folder for the Cloth panel's menu")
        out["preset"] = a.preset
    text = None
    if a.python:  # the one command whose stdout is not JSON: Python, by request
        comments = _manipulation_comments(manip, near) + interval_comments(out)
        cols = None
        if out.get("colliders"):
            from ..core.physics.colliders import Collisions

            cols = Collisions.from_dicts(out["colliders"], out.get("collision_settings"), a.result)
        text = blender_script(s, fps, a.object, a.result, comments, cols)
    if a.out:
        from ..core.jsonio import dumps

        _write_text(a.out, text if text is not None else dumps(out))
        print(f"wrote {a.out}")
        return dict(out, out=a.out)
    return Text(text) if text is not None else out


def _manipulation_comments(manip, near):
    lines = [f"# nearest of Blender's own presets: {near['name']}, typically {near['factor']:.2g}x apart"]
    if manip.get("time_offset_s") is not None:
        lines.append(
            f"# the fit read the footage {1000 * manip['time_offset_s']:+.1f} ms off: the release "
            f"happened at capture time + time_offset_s"
        )
    if manip.get("time_scale") is not None:
        lines.append(
            f"# the fit read the capture's clock stretched by {manip['time_scale']:.4g}: true time = "
            f"time_scale x capture time - time_offset_s, the pins' keys stretched alike"
        )
    for h in manip.get("handles") or []:
        if any(h.get("offset_m") or []):
            lines.append(
                f"# pin at vertex {h['vertex']}: moved by {[round(v * 1000, 2) for v in h['offset_m']]} mm "
                f"from the capture's measurement"
            )
        times, pos = h.get("times") or [], h.get("positions") or []
        if len(times) > 1 and len(pos) == len(times) and any(p != pos[0] for p in pos):
            lines.append(
                f"# pin at vertex {h['vertex']}: moves along a path ({len(times)} keys, {times[0]:g} to "
                f"{times[-1]:g} s; the result's manipulation.handles): this script sets the settings only, so "
                f"drive your cloth's pin along it (e.g. a Hook to a keyed empty, as Apply Blender Cloth does)"
            )
    return lines


def add_export(sub):
    """Register ``export-blender-cloth``."""
    s = add_command(
        sub,
        "export-blender-cloth",
        cmd_export_blender_cloth,
        "the Cloth modifier settings of a blender-model fit result",
        "the settings as JSON (blender_cloth, blender_scene, nearest_preset), or with --python a "
        "script that puts them on a Cloth modifier in Blender",
    )
    s.add_argument("result", help="result JSON of a fit with --model blender")
    s.add_argument(
        "--python",
        action="store_true",
        help="print a Blender script instead of JSON: it sets the settings on the Cloth modifier (found by "
        "type) of the active object or --object, and the scene's frame rate; run it in Blender's Text Editor "
        "or with blender --python FILE",
    )
    s.add_argument(
        "--object", help="with --python: the object the script puts the settings on (default: the active one)"
    )
    s.add_argument(
        "--preset",
        metavar="FILE.py",
        help="also write the settings as a Blender cloth preset (Blender's own format; in a presets/cloth "
        "folder it appears in the Cloth panel's preset menu)",
    )
    s.add_argument("--out", help="write the JSON (or with --python the script) to this file instead of stdout")
    force_arg(s, "--out and --preset")
