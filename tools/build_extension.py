"""Build the installable Blender extension zip (what ``blender --command extension build`` makes).

    python tools/build_extension.py [--out dist] [--no-download] [--no-validate]

Layout of ``dist/silhouette_cloth_fit-<version>.zip`` (files at the zip root, as Blender's own
builder writes them): ``blender_manifest.toml``, ``__init__.py``, ``addon/`` (core + Blender
layer), ``rigs/`` (camera presets) and the wheels the manifest lists under ``wheels/``.
Everything else (tests/, out/, .venv/, .ci/, docs/, tools/, demo_blend/...) stays out; the
manifest's ``[build] paths_exclude_pattern`` is applied on top.

Missing wheels are downloaded with pip (unmodified PyPI wheels, numpy is not bundled: Blender
ships it), with the platform tags of the file name the manifest lists, e.g.::

    pip download --no-deps --only-binary=:all: --platform manylinux_2_17_x86_64 \
        --platform manylinux2014_x86_64 --python-version 3.11 opencv-python-headless==4.10.0.84 -d wheels/

When the ``bpy`` module is installed, the zip is checked with Blender's own validator
(``bl_pkg/cli/blender_ext.py validate``).
"""
from __future__ import annotations

import argparse
import fnmatch
import importlib.util
import os
import re
import subprocess
import sys
import tomllib
import zipfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MANIFEST = "blender_manifest.toml"
INCLUDE = ["blender_manifest.toml", "__init__.py", "addon", "rigs", "LICENSE", "README.md"]
INCLUDE_EXT = {".py", ".json", ".toml", ".md", ""}
WHEEL_RE = re.compile(r"^(?P<name>[A-Za-z0-9_]+)-(?P<version>[^-]+)-")


def read_manifest(root=ROOT):
    with open(os.path.join(root, MANIFEST), "rb") as f:
        return tomllib.load(f)


def _excluded(rel: str, patterns) -> bool:
    """gitignore-like: "/x/" anchored at the root, "x/" any directory named x, "*.ext" any file."""
    parts = rel.split("/")
    for pat in patterns:
        anchored = pat.startswith("/")
        p = pat.strip("/")
        is_dir = pat.endswith("/")
        if anchored:
            if is_dir and fnmatch.fnmatch(parts[0], p) and len(parts) > 1:
                return True
            if fnmatch.fnmatch(rel, p):
                return True
        else:
            cands = parts[:-1] if is_dir else parts
            if any(fnmatch.fnmatch(c, p) for c in cands):
                return True
    return False


def source_files(root=ROOT, manifest=None):
    manifest = manifest or read_manifest(root)
    patterns = manifest.get("build", {}).get("paths_exclude_pattern", [])
    out = []
    for top in INCLUDE:
        path = os.path.join(root, top)
        if os.path.isfile(path):
            out.append(top)
        elif os.path.isdir(path):
            for d, dirs, files in os.walk(path):
                dirs[:] = sorted(x for x in dirs if x != "__pycache__")
                for fn in sorted(files):
                    rel = os.path.relpath(os.path.join(d, fn), root).replace(os.sep, "/")
                    if os.path.splitext(fn)[1] in INCLUDE_EXT and not fn.endswith(".tmp"):
                        out.append(rel)
    out = [r for r in out if not _excluded(r, patterns)]
    for w in manifest.get("wheels", []):
        out.append(w[2:] if w.startswith("./") else w)
    return out


def download_wheel(rel: str, root=ROOT):
    """pip-download the (pinned, unmodified) wheel named ``rel`` into its folder."""
    fn = os.path.basename(rel)
    m = WHEEL_RE.match(fn)
    if not m:
        raise SystemExit(f"cannot parse wheel file name {fn}")
    name = m.group("name").replace("_", "-")
    parts = fn[:-4].split("-")
    plats = parts[-1].split(".")   # e.g. ["manylinux_2_17_x86_64", "manylinux2014_x86_64"] or ["any"]
    dest = os.path.join(root, os.path.dirname(rel))
    cmd = [sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary=:all:"]
    if plats != ["any"]:
        for plat in plats:
            cmd += ["--platform", plat]
        cmd += ["--python-version", "3.11"]
    cmd += [f"{name}=={m.group('version')}", "-d", dest]
    print("downloading:", " ".join(cmd))
    subprocess.run(cmd, check=True)
    if not os.path.isfile(os.path.join(root, rel)):
        raise SystemExit(f"pip did not produce {rel}")


def blender_ext_script():
    spec = importlib.util.find_spec("bpy")
    if spec is None or not spec.submodule_search_locations:
        return None
    base = list(spec.submodule_search_locations)[0]
    for d in sorted(os.listdir(base), reverse=True):
        p = os.path.join(base, d, "scripts", "addons_core", "bl_pkg", "cli", "blender_ext.py")
        if os.path.isfile(p):
            return p
    return None


def validate(zip_path):
    script = blender_ext_script()
    if script is None:
        print("bpy not installed: skipping Blender's validator")
        return None
    r = subprocess.run([sys.executable, script, "validate", zip_path], capture_output=True, text=True)
    print((r.stdout + r.stderr).strip())
    if r.returncode != 0 or "Success" not in r.stdout + r.stderr:
        raise SystemExit(f"Blender's validator rejected {zip_path}")
    return True


def build(out_dir="dist", root=ROOT, download=True, check=True):
    manifest = read_manifest(root)
    for w in manifest.get("wheels", []):
        rel = w[2:] if w.startswith("./") else w
        if not os.path.isfile(os.path.join(root, rel)):
            if not download:
                raise SystemExit(f"missing wheel {rel} (run without --no-download)")
            download_wheel(rel, root)
    files = source_files(root, manifest)
    out_dir = os.path.join(root, out_dir) if not os.path.isabs(out_dir) else out_dir
    os.makedirs(out_dir, exist_ok=True)
    zip_path = os.path.join(out_dir, f"{manifest['id']}-{manifest['version']}.zip")
    tmp = zip_path + ".tmp"
    with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as z:
        for rel in files:
            z.write(os.path.join(root, rel), rel, compress_type=zipfile.ZIP_STORED if rel.endswith(".whl") else None)
    os.replace(tmp, zip_path)
    size = os.path.getsize(zip_path)
    print(f"wrote {zip_path} ({len(files)} files, {size / 1e6:.1f} MB)")
    if check:
        validate(zip_path)
    return zip_path


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default="dist", help="output directory (default dist/)")
    ap.add_argument("--no-download", action="store_true", help="fail instead of downloading missing wheels")
    ap.add_argument("--no-validate", action="store_true", help="skip Blender's validator")
    a = ap.parse_args(argv)
    build(a.out, download=not a.no_download, check=not a.no_validate)


if __name__ == "__main__":
    main()
