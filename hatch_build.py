"""Build hook (hatchling): the editable install of a checkout (``make venv``: ``pip install -e .``).

The wheel installs the folder ``addon/`` as the package ``clothfit`` (``sources`` in pyproject.toml).
Hatchling's editable installs cannot rename a package, so this hook adds to the editable wheel a
``.pth`` file and a small import finder that maps the name ``clothfit`` onto the checkout's ``addon/``
(the way the ``editables`` package does). Nothing of this goes into a normal wheel.
"""

import os
import tempfile

from hatchling.builders.hooks.plugin.interface import BuildHookInterface

FINDER = '''"""Editable install of Silhouette Cloth Fit: ``import clothfit`` loads the checkout's addon/."""
import importlib.util
import sys

PACKAGE = {package!r}


class _ClothfitFinder:
    @classmethod
    def find_spec(cls, name, path=None, target=None):
        if name != "clothfit":
            return None
        return importlib.util.spec_from_file_location(
            "clothfit", PACKAGE + "/__init__.py", submodule_search_locations=[PACKAGE])


if not any(f is _ClothfitFinder or getattr(f, "__name__", "") == "_ClothfitFinder" for f in sys.meta_path):
    sys.meta_path.append(_ClothfitFinder)
'''


class CustomBuildHook(BuildHookInterface):
    def initialize(self, version, build_data):
        if self.target_name != "wheel" or version != "editable":
            return
        tmp = tempfile.mkdtemp(prefix="clothfit_editable_")
        package = os.path.join(self.root, "addon").replace(os.sep, "/")
        with open(os.path.join(tmp, "_clothfit_finder.py"), "w") as f:
            f.write(FINDER.format(package=package))
        with open(os.path.join(tmp, "_clothfit_finder.pth"), "w") as f:
            f.write("import _clothfit_finder\n")
        build_data["force_include_editable"][os.path.join(tmp, "_clothfit_finder.py")] = "_clothfit_finder.py"
        build_data["force_include_editable"][os.path.join(tmp, "_clothfit_finder.pth")] = "_clothfit_finder.pth"
