# SPDX-License-Identifier: GPL-3.0-or-later
"""Silhouette Cloth Fit.

* ``addon.core``: the pure engine (cameras, cloth model, simulator, rasteriser, capture format,
  optimisers, fitting). Never imports ``bpy``; usable as ``python -m addon``.
* ``addon.blender``: the Blender layer (properties, operators, panel, scene builders, renders).

Importing this package does not import ``bpy``: ``register``/``unregister`` import the Blender
layer lazily, so the core and the CLI work without Blender.
"""


def register():
    from .blender import registration
    registration.register()


def unregister():
    from .blender import registration
    registration.unregister()
