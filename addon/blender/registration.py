# SPDX-License-Identifier: GPL-3.0-or-later
"""Registration of the Blender layer in one place (``bpy.utils.register_classes_factory``): add-on
preferences, scene properties, operators, panels, and the File > Import / Export menu entries.

With the ``bpy`` module (no Blender binary), a process that exits while Python operators are
still registered hangs in bpy 4.5's teardown; so in that mode an ``atexit`` hook unregisters.
"""

from __future__ import annotations

import atexit

import bpy

from . import menus, ops, panel, prefs, props, scene_fit

CLASSES = prefs.CLASSES + props.CLASSES + ops.CLASSES + scene_fit.CLASSES + panel.CLASSES
_register_classes, _unregister_classes = bpy.utils.register_classes_factory(CLASSES)
_state = {"registered": False, "atexit": False}


def register():
    _register_classes()
    props.register_scene_property()
    menus.register()
    _state["registered"] = True
    if not bpy.app.binary_path and not _state["atexit"]:
        atexit.register(_unregister_at_exit)
        _state["atexit"] = True


def unregister():
    if not _state["registered"]:  # idempotent: the atexit hook may have run before addon_utils' disable
        return
    menus.unregister()
    props.unregister_scene_property()
    _unregister_classes()
    _state["registered"] = False


def is_registered():
    return _state["registered"]


def _unregister_at_exit():
    if _state["registered"]:
        unregister()
