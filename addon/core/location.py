"""Where this package lives, for the processes it starts (Ray actors, process pools, ``python -m``).

The package is installed as ``clothfit`` by a wheel and is the folder ``addon/`` in a checkout and in
the Blender extension; a checkout's editable install (``make venv``) maps the name ``clothfit`` onto
``addon/``. Workers are named from :data:`IMPORT_NAME`, the name this process imported the package
under when it is a top-level package (so objects sent to a worker unpickle as the same classes), else
(inside Blender: ``bl_ext.<repo>.silhouette_cloth_fit.addon``) the folder's name, importable once
:data:`PACKAGE_PARENT` is on the child's ``PYTHONPATH``.
"""

import os

PACKAGE_DIR = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))  # addon/ or clothfit/
PACKAGE_PARENT = os.path.dirname(PACKAGE_DIR)  # the checkout, the extension's folder or site-packages
_TOP = __name__.rsplit(".core.location", 1)[0]
IMPORT_NAME = _TOP if "." not in _TOP else os.path.basename(PACKAGE_DIR)  # "clothfit" or "addon"


def qualified(path: str) -> str:
    """``"farm.tasks:FitRunner"`` -> ``"<IMPORT_NAME>.farm.tasks:FitRunner"``."""
    return f"{IMPORT_NAME}.{path}"
