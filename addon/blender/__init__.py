# SPDX-License-Identifier: GPL-3.0-or-later
"""The Blender layer of Silhouette Cloth Fit (imports ``bpy``).

``props`` (scene state), ``panel`` (sidebar), ``ops`` (operators), ``api`` (scripting facade the
operators call, a package by concern), ``scene`` (cameras, rig, cloth, bake), ``render`` (Blender silhouettes),
``registration`` (register/unregister). See ``docs/blender.md``.
"""
