"""Test setup for the lab's own tests: the repository root (``import clothfit``), the lab's scripts and the
product tests' support modules (``blender_support``) importable."""

import os
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
for _d in (ROOT, os.path.join(ROOT, "lab"), os.path.join(ROOT, "tests")):
    if _d not in sys.path:
        sys.path.insert(0, _d)
