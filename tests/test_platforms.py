"""Every platform Blender runs on: the manifest's wheels, the Python guard, the licence, the docs.

No downloads here: the manifest is checked offline (``build_extension.check_manifest``); that every
named file exists on the index is ``python tools/build_extension.py --check-only --remote`` (metadata
only) and the builds themselves are in test_blender_extension.py.
"""

import copy
import importlib.util
import os
import re
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tools"))
import build_extension as B  # noqa: E402

PLATFORMS = {"windows-x64", "macos-arm64", "macos-x64", "linux-x64"}


def test_manifest_lists_every_platform_with_its_wheels():
    m = B.read_manifest()
    assert set(m["platforms"]) == PLATFORMS
    assert B.check_manifest(m) == []
    for p in PLATFORMS:
        have = {
            B.WHEEL_RE.match(os.path.basename(w)).group("name").lower()
            for w in m["wheels"]
            if B.wheel_platforms(w) & {"any", p}
        }
        assert "opencv_python_headless" in have, p
        assert "cma" not in have, p  # the CMA-ES optimiser is our own code: nothing to bundle
        fast = {"numba", "llvmlite"} <= have
        assert fast == (p not in B.NO_FAST_PATH), p


@pytest.mark.parametrize(
    "change, text",
    [
        (lambda m: m["wheels"].remove("./wheels/numba-0.68.1-cp311-cp311-win_amd64.whl"), "windows-x64: no numba"),
        (
            lambda m: m["wheels"].append("./wheels/numba-0.68.1-cp312-cp312-win_amd64.whl"),
            "does not install on Python 3.11",
        ),
        (
            lambda m: m["wheels"].append("./wheels/numba-0.62.1-cp311-cp311-macosx_10_15_x86_64.whl"),
            "pins numba==0.68.1",
        ),
        (lambda m: m["platforms"].remove("macos-arm64"), "which 'platforms' does not list"),
        (lambda m: m.pop("blender_version_max"), "blender_version_max"),
        (lambda m: m.__setitem__("blender_version_max", "5.1.0"), "blender_version_max"),
        (lambda m: m["platforms"].append("linux-arm64"), "linux-arm64: no opencv_python_headless"),
    ],
)
def test_check_manifest_finds_problems(change, text):
    m = copy.deepcopy(B.read_manifest())
    change(m)
    assert any(text in p for p in B.check_manifest(m)), B.check_manifest(m)


def test_wheel_platforms_agree_with_blenders_builder():
    script = B.blender_ext_script()
    if script is None:
        pytest.skip("bpy module (Blender's extension CLI) not installed")
    spec = importlib.util.spec_from_file_location("blender_ext", script)
    ext = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ext)
    names = [os.path.basename(w) for w in B.read_manifest()["wheels"]] + [
        "x-1-cp311-cp311-macosx_10_9_universal2.whl",
        "x-1-cp311-cp311-manylinux2014_aarch64.whl",
    ]
    for fn in names:
        for p in PLATFORMS | {"linux-arm64"}:
            theirs = ext.blender_platform_compatible_with_wheel_platform_from_filepath(p, fn)
            ours = bool(B.wheel_platforms(fn) & {"any", p})
            assert theirs == ours, (fn, p)


def test_licence_matches_the_manifest():
    m = B.read_manifest()
    assert m["license"] == ["SPDX:GPL-3.0-or-later"]
    text = open(os.path.join(ROOT, "LICENSE")).read()
    assert "GNU GENERAL PUBLIC LICENSE" in text and "Version 3, 29 June 2007" in text
    assert "either version 3 of the\nLicense, or (at your option) any later version" in text


def test_docs_say_where_the_fast_path_runs():
    text = open(os.path.join(ROOT, "docs", "extension.md")).read()
    sec = text[text.index("## Where the fast path runs") :]
    end = sec.find("\n#", 1)  # the next section, if the page goes on
    sec = sec if end < 0 else sec[:end]
    for p in PLATFORMS:
        assert p in sec, p
    assert re.search(r"macos-x64.*numpy", sec, re.S)
