# SPDX-License-Identifier: GPL-3.0-or-later
"""Add-on preferences (Edit > Preferences > Add-ons > Silhouette Cloth Fit): defaults the
operators read, kept with Blender's user preferences rather than in each .blend.

``bl_idname`` is the add-on's module name as Blender knows it: for an installed extension the
package the extension root is imported as (``bl_ext.<repo>.silhouette_cloth_fit``), i.e. this
module's package without its ``.addon.blender`` tail. From a checkout (``import addon``, the tests,
``python -m clothfit``) there is no enabled add-on of that name, and ``preferences`` gives the defaults.
"""

from __future__ import annotations

import os
import tempfile

import bpy
from bpy.props import IntProperty, StringProperty

from ..core.errors import ClothFitError

_TAIL = ".addon.blender"


def addon_name(package: str = __package__) -> str:
    """The module name Blender registers the add-on under (the extension root package)."""
    return package[: -len(_TAIL)] if package.endswith(_TAIL) else package.split(".")[0]


ADDON_NAME = addon_name()


class ClothFitPreferences(bpy.types.AddonPreferences):
    """Defaults of the Cloth Fit operators"""

    bl_idname = ADDON_NAME

    workers: IntProperty(
        name="Workers",
        default=0,
        min=0,
        max=1024,
        description="Worker processes of a Blender-solver fit (Fit This Cloth's Settings); 0 = one per core "
        "of the machine that runs the fit",
    )
    ray_address: StringProperty(
        name="Ray Address",
        default="",
        description="A running Ray cluster for Blender-solver fits: auto, host:port or ray://host:port (start it "
        "outside Blender with `ray start --head`). Empty: the fit starts its own local workers. "
        "The add-on only connects: it never starts a cluster from Blender's UI",
    )
    cache_dir: StringProperty(
        name="Cache Folder",
        default="",
        subtype="DIR_PATH",
        description="Where Blender-solver fits keep their working files (a copy of the .blend, the result, "
        "the log). Empty: the system's temporary folder",
    )

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        col = layout.column()
        col.prop(self, "workers")
        col.prop(self, "ray_address")
        col.prop(self, "cache_dir")


class _Defaults:
    """The preferences' defaults, when the add-on is not enabled under ``ADDON_NAME`` (a checkout)."""

    workers = 0
    ray_address = ""
    cache_dir = ""


def preferences(context=None):
    """The add-on's preferences (or their defaults)."""
    context = context or bpy.context
    addon = context.preferences.addons.get(ADDON_NAME)
    prefs = getattr(addon, "preferences", None) if addon is not None else None
    return prefs if prefs is not None else _Defaults()


def cache_folder(context=None) -> str:
    """The preferences' cache folder, created if missing (empty: the system's temporary folder)."""
    path = preferences(context).cache_dir.strip()
    if not path:
        return tempfile.gettempdir()
    path = os.path.normpath(bpy.path.abspath(path))
    try:
        os.makedirs(path, exist_ok=True)
    except OSError as e:
        raise ClothFitError(f"cache folder {path} (add-on preferences): cannot create it ({e.strerror or e})") from None
    return path


CLASSES = (ClothFitPreferences,)
