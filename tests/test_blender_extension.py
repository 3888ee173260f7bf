"""The extension zips (one per platform, by Blender's own builder): layout, Blender's validator,
install + enable of the Linux zip in the bpy module.

The install runs in a subprocess with its own ``BLENDER_USER_RESOURCES`` so the user's Blender
config is untouched; there ``cv2``, ``numba`` and ``llvmlite`` are imported from the
extension's wheels only (the venv's copies are hidden), which proves that Blender installed the
bundled wheels and that the numba kernels work from them.
"""

import os
import subprocess
import sys
import textwrap
import zipfile

import pytest

pytest.importorskip("bpy")

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tools"))
import build_extension  # noqa: E402


@pytest.fixture(scope="module")
def ext_zips(tmp_path_factory):
    out = tmp_path_factory.mktemp("dist")
    try:
        return build_extension.build(str(out), download=True, check=False)
    except (SystemExit, subprocess.CalledProcessError) as e:
        pytest.skip(f"cannot build the extension (wheel download failed?): {e}")


@pytest.fixture(scope="module")
def ext_zip(ext_zips):
    return ext_zips["linux-x64"]


def test_zip_layout(ext_zips):
    manifest = build_extension.read_manifest()
    assert sorted(ext_zips) == sorted(manifest["platforms"])
    for platform, path in ext_zips.items():
        names = set(zipfile.ZipFile(path).namelist())
        assert os.path.basename(path) == f"silhouette_cloth_fit-{manifest['version']}-{platform.replace('-', '_')}.zip"
        for need in (
            "blender_manifest.toml",
            "__init__.py",
            "LICENSE",
            "addon/__init__.py",
            "addon/blender/ops.py",
            "addon/blender/registration.py",
            "addon/core/observation/camera.py",
            "addon/core/physics/paper.py",
            "rigs/lab18.json",
        ):
            assert need in names, need
        wheels = sorted(n for n in names if n.endswith(".whl"))
        want = sorted(w[2:] for w in manifest["wheels"] if build_extension.wheel_platforms(w) & {"any", platform})
        assert wheels == want, (platform, wheels)
        assert not any("numpy" in n for n in names)
        bad = [
            n
            for n in names
            if n.split("/")[0]
            in ("tests", "out", ".venv", ".ci", "docs", "tools", "lab", "demo_blend", "dist", ".git", "wheels.log")
            or "__pycache__" in n
            or n.endswith(".pyc")
        ]
        assert not bad, bad
        # the Python package's and the developers' files stay out of the extension
        dev = {"pyproject.toml", "requirements.txt", "requirements-dev.txt", "Makefile", ".gitignore"} & names
        assert not dev, dev
        assert not any("cma" in n for n in names)  # the optimiser is our own code: no cma wheel


def test_blender_validator_accepts_every_zip(ext_zips):
    for path in ext_zips.values():
        assert build_extension.validate(path)


INSTALL = textwrap.dedent("""
    import importlib.machinery, os, sys
    import bpy, addon_utils
    zip_path, site = sys.argv[1], sys.argv[2]
    BUNDLED = ("cv2", "numba", "llvmlite")

    class HideOthers:  # hide the venv's copies: the bundled packages must come from their wheels
        def find_spec(self, name, path=None, target=None):
            if name in BUNDLED and path is None:
                paths = [p for p in sys.path if os.path.abspath(p) == os.path.abspath(site)
                         or not os.path.isdir(os.path.join(p, name))]
                spec = importlib.machinery.PathFinder.find_spec(name, paths)
                if spec is None:
                    raise ModuleNotFoundError(f"No module named {name!r}", name=name)
                return spec
            return None
    sys.meta_path.insert(0, HideOthers())

    assert not any(m in sys.modules for m in BUNDLED)
    r = bpy.ops.extensions.package_install_files(filepath=zip_path, repo="user_default", enable_on_install=True)
    assert r == {"FINISHED"}, r
    mod = "bl_ext.user_default.silhouette_cloth_fit"
    assert addon_utils.check(mod) == (True, True), addon_utils.check(mod)
    op = bpy.ops.clothfit.build_rig.get_rna_type()
    assert op.identifier == "CLOTHFIT_OT_build_rig"
    import cv2, numba
    for m in (cv2, numba):
        assert m.__file__.startswith(site), m.__file__
    jit = sys.modules.get(mod + ".addon.core.physics.jit") or __import__(mod + ".addon.core.physics.jit", fromlist=["x"])
    assert jit.available(), "numba kernels not available from the bundled wheels"
    scene = bpy.context.scene
    assert bpy.ops.clothfit.build_rig() == {"FINISHED"}
    assert len(bpy.data.collections["ClothFit Rig"].objects) == 18
    assert bpy.ops.clothfit.build_cloth() == {"FINISHED"}
    ops_mod = sys.modules[mod + ".addon.blender.ops"]
    assert ops_mod.__file__.startswith(os.environ["BLENDER_USER_RESOURCES"]), ops_mod.__file__
    prefs = bpy.context.preferences.addons[mod].preferences     # bl_idname = the extension's module
    assert type(prefs).__name__ == "ClothFitPreferences" and prefs.workers == 0, prefs
    menus = sys.modules[mod + ".addon.blender.menus"]
    assert menus.menu_import in bpy.types.TOPBAR_MT_file_import._dyn_ui_initialize()
    assert menus.menu_export in bpy.types.TOPBAR_MT_file_export._dyn_ui_initialize()
    addon_utils.disable(mod)
    assert not hasattr(bpy.types.Scene, "clothfit")
    assert menus.menu_import not in bpy.types.TOPBAR_MT_file_import._dyn_ui_initialize()
    print("INSTALL-OK", cv2.__version__, numba.__version__)
""")


def test_installs_and_enables_in_bpy(ext_zip, tmp_path):
    res = tmp_path / "user_resources"
    res.mkdir()
    site = (
        res / "extensions" / ".local" / "lib" / f"python{sys.version_info[0]}.{sys.version_info[1]}" / "site-packages"
    )
    script = tmp_path / "install.py"
    script.write_text(INSTALL)
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(res))
    r = subprocess.run(
        [sys.executable, str(script), ext_zip, str(site)],
        cwd=str(tmp_path),
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0 and "INSTALL-OK 4.10.0 0.68.1" in r.stdout, r.stdout[-3000:] + r.stderr[-3000:]


HIDE_PACKAGES = textwrap.dedent("""
    import importlib.machinery, os, sys
    sys.path.insert(0, sys.argv[1])
    BUNDLED = ("cv2", "numba", "llvmlite")

    class Missing:  # like Blender's own Python: none of the bundled packages installed
        def find_spec(self, name, path=None, target=None):
            if name in BUNDLED and path is None:
                paths = [p for p in sys.path if not os.path.isdir(os.path.join(p, name))
                         or ".blender_site" in p]
                spec = importlib.machinery.PathFinder.find_spec(name, paths)
                if spec is None:
                    raise ModuleNotFoundError(f"No module named {name!r}", name=name)
                return spec
            return None
    sys.meta_path.insert(0, Missing())
    from clothfit.blender import pipeline
    added = pipeline.ensure_wheels()
    import cv2, numba
    for m in (cv2, numba):
        assert ".blender_site" in m.__file__, m.__file__
    from clothfit.core.physics import jit
    assert jit.available()
    print("FROM-WHEELS", len(added), cv2.__version__, numba.__version__)
""")


def test_checkout_under_blender_binary_uses_the_wheels(ext_zip, tmp_path):  # ext_zip: the wheels are there
    """Under a Blender binary (no cv2, numba), the pipeline unpacks the wheels of wheels/."""
    script = tmp_path / "nopkgs.py"
    script.write_text(HIDE_PACKAGES)
    r = subprocess.run(
        [sys.executable, str(script), ROOT], cwd=str(tmp_path), capture_output=True, text=True, timeout=300
    )
    assert r.returncode == 0 and "FROM-WHEELS 3 4.10.0 0.68.1" in r.stdout, r.stdout[-2000:] + r.stderr[-2000:]
