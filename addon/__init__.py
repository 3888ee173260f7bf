# SPDX-License-Identifier: GPL-3.0-or-later
"""Silhouette Cloth Fit.

* ``addon.core``: the pure engine (cameras, cloth model, simulator, rasteriser, capture format,
  optimisers, fitting). Never imports ``bpy``; usable as ``python -m clothfit``.
* ``addon.blender``: the Blender layer (properties, operators, panel, scene builders, renders).

Importing this package does not import ``bpy``: ``register``/``unregister`` import the Blender
layer lazily, so the core and the CLI work without Blender.
"""

import os

DIST_NAME = "silhouette-cloth-fit"  # the name pyproject.toml installs under (the console script ``clothfit``)


def version() -> str:
    """The project's version. It is written in one place, ``blender_manifest.toml`` (the extension's
    manifest): read from there in a checkout or an installed extension, and from the package metadata
    of a wheel install (whose build read it from the same file: pyproject.toml, ``[tool.hatch.version]``)."""
    manifest = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "blender_manifest.toml")
    if os.path.isfile(manifest):
        import tomllib

        with open(manifest, "rb") as f:
            m = tomllib.load(f)
        if m.get("id") == "silhouette_cloth_fit" and isinstance(m.get("version"), str):
            return m["version"]
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as dist_version

    try:
        return dist_version(DIST_NAME)
    except PackageNotFoundError:
        return "unknown"


def register():
    from .blender import registration

    registration.register()


def unregister():
    from .blender import registration

    registration.unregister()
