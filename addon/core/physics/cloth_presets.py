"""Fitted Cloth settings in the words an artist already uses: the nearest of Blender's own cloth
presets (Cotton, Denim, Leather, Rubber, Silk) and how far the fit is from it, and the fit written
as a preset file of Blender's own format (``scripts/presets/cloth/*.py``), which Blender's Cloth
panel lists in its preset menu once the file sits in a ``presets/cloth`` folder.

The distance compares the settings every preset sets and that scale with the mass
(``COMPARED``), each divided by the vertex mass: the cloth's motion depends on those ratios alone
(``blender_settings.MASS_SCALED``), and silhouettes cannot tell the mass itself. Per setting the
difference is ``log10(fit / preset)`` (values below ``D.PRESET_DISTANCE_FLOOR`` per kg count as that
floor, so a preset's zero damping is comparable); the distance is their root mean square, so 0.3
means the settings are typically a factor 2 apart. Quality, the Speed Multiplier (``time_scale``)
and the frame rate are not part of it: each result says its own.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from .. import defaults as D
from ..errors import ClothFitError
from .blender_settings import FLOAT_SETTINGS, PRESETS, check_settings

COMPARED = (
    "tension_stiffness",
    "compression_stiffness",
    "shear_stiffness",
    "bending_stiffness",
    "tension_damping",
    "compression_damping",
    "shear_damping",
    "air_damping",
)
# the settings a preset file written here sets, in the order of Blender's own "Add Cloth Preset"
# (bl_operators/presets.py, AddPresetCloth), then the two a fit also sets
PRESET_FILE_SETTINGS = ("quality", "mass", "air_damping", "bending_model") + FLOAT_SETTINGS[2:]


def preset_name(key: str) -> str:
    """``"cotton"`` -> ``"Cotton"``: the name of Blender's preset file and menu entry."""
    return key[:1].upper() + key[1:]


def _per_mass(settings: dict, name: str) -> float:
    return max(float(settings[name]) / float(settings["mass"]), D.PRESET_DISTANCE_FLOOR)


def preset_differences(settings: dict, preset: str) -> list[dict]:
    """Each compared setting of ``settings`` against Blender's preset ``preset`` (a key of
    ``PRESETS``), per kg of vertex mass: ``{"setting", "fit_per_kg", "preset_per_kg", "log10_ratio"}``,
    the biggest difference first."""
    if preset not in PRESETS:
        raise ClothFitError(f"unknown Blender cloth preset {preset!r} (known: {', '.join(PRESETS)})")
    s = check_settings(settings, "fitted settings")
    p = check_settings(PRESETS[preset], f"preset {preset}")
    out = []
    for n in COMPARED:
        a, b = _per_mass(s, n), _per_mass(p, n)
        out.append({"setting": n, "fit_per_kg": a, "preset_per_kg": b, "log10_ratio": math.log10(a / b)})
    out.sort(key=lambda d: -abs(d["log10_ratio"]))
    return out


def nearest_preset(settings: dict, n_named: int = 3) -> dict:
    """The Blender preset nearest to ``settings`` (ClothSettings values) and how far it is:
    ``{"name", "distance", "factor", "differences", "distances"}``: ``distance`` the root mean
    square of the per-setting log10 ratios (see the module), ``factor`` = 10 ** distance (the
    typical ratio), ``differences`` the ``n_named`` biggest (beyond 10 %) in words, ``distances`` every
    preset's distance."""
    dists = {}
    for key in PRESETS:
        diffs = preset_differences(settings, key)
        dists[key] = math.sqrt(sum(d["log10_ratio"] ** 2 for d in diffs) / len(diffs))
    best = min(dists, key=dists.get)
    diffs = preset_differences(settings, best)
    words = []
    for d in diffs[:n_named]:
        f = 10 ** d["log10_ratio"]
        if abs(d["log10_ratio"]) < math.log10(1.1):
            break  # within 10 %: not worth naming
        name = preset_name(best)
        words.append(f"{d['setting']} {f:.2g}x {name}'s" if f >= 1 else f"{d['setting']} 1/{1 / f:.2g} of {name}'s")
    if not words:
        words.append("no setting differs by more than 10 %")
    return {
        "name": preset_name(best),
        "distance": dists[best],
        "factor": 10 ** dists[best],
        "differences": words,
        "compared": "stiffness and damping settings per kg of vertex mass (log10 ratios, root mean square)",
        "distances": {preset_name(k): v for k, v in sorted(dists.items(), key=lambda kv: kv[1])},
    }


def preset_text(settings: dict, fps: float, source: str = "", comments: Sequence[str] = ()) -> str:
    """``settings`` as a Blender cloth preset file: ``import bpy``, ``cloth = bpy.context.cloth``,
    then one ``cloth.settings.NAME = value`` line per setting (the format Blender's own *Add Cloth
    Preset* writes). The frame rate the settings are for goes into a comment: a preset cannot set it; so do
    ``comments`` (comment lines: how sure each setting is)."""
    s = check_settings(settings, "fitted settings")
    if not (fps > 0 and math.isfinite(fps)):
        raise ClothFitError(f"frame rate {fps} must be a positive number")
    lines = [
        "import bpy",
        "cloth = bpy.context.cloth",
        "",
        f"# fitted by Silhouette Cloth Fit{f' ({source})' if source else ''} for a {fps:g} fps scene: Blender's cloth",
        "# moves per frame, so set the scene's frame rate to it (Output Properties > Format > Frame Rate)",
        *comments,
    ]
    lines += [f"cloth.settings.{n} = {s[n]!r}" for n in PRESET_FILE_SETTINGS]
    return "\n".join(lines) + "\n"
