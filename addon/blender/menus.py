# SPDX-License-Identifier: GPL-3.0-or-later
"""File > Import / Export entries: each opens Blender's file browser on one ``clothfit`` operator
(``browse=True``), which then makes its one call into the scripting API."""

from __future__ import annotations

import bpy


def menu_import(self, context):
    layout = self.layout
    layout.operator("clothfit.load_capture", text="Cloth Capture (.json)").browse = True
    layout.operator("clothfit.import_cameras", text="Cameras (OpenCV, COLMAP, JSON)").browse = True


def menu_export(self, context):
    self.layout.operator("clothfit.export_cameras", text="Cameras (OpenCV, COLMAP, JSON)").browse = True


def _menus():
    return ((bpy.types.TOPBAR_MT_file_import, menu_import), (bpy.types.TOPBAR_MT_file_export, menu_export))


def register():
    for menu, draw in _menus():
        menu.append(draw)


def unregister():
    for menu, draw in _menus():
        menu.remove(draw)
