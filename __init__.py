# SPDX-License-Identifier: GPL-3.0-or-later
"""Silhouette Cloth Fit: Blender extension entry point.

Blender imports this file as ``bl_ext.<repo>.silhouette_cloth_fit``; everything lives in the
``addon`` package next to it (a pure core plus a thin Blender layer). Relative imports only.
"""

from .addon import register, unregister  # noqa: F401
