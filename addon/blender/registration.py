# SPDX-License-Identifier: GPL-3.0-or-later
"""Registration of the Blender layer in one place (``bpy.utils.register_classes_factory``)."""
from __future__ import annotations

import bpy

from . import ops, panel, props

CLASSES = props.CLASSES + ops.CLASSES + panel.CLASSES
_register_classes, _unregister_classes = bpy.utils.register_classes_factory(CLASSES)


def register():
    _register_classes()
    props.register_scene_property()


def unregister():
    props.unregister_scene_property()
    _unregister_classes()
