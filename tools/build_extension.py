"""Build the installable Blender extension: one zip per platform, by Blender's own builder.

    python tools/build_extension.py [--out dist] [--no-download] [--no-validate] [--check-only] [--remote]

Blender's builder is ``blender --command extension build --split-platforms``; its code is the script
``bl_pkg/cli/blender_ext.py`` that the ``bpy`` module ships too, so this tool runs that script with
this Python (no Blender binary needed) and gets exactly what Blender would build:
``dist/silhouette_cloth_fit-<version>-<platform>.zip`` for every platform of the manifest, each
with the wheels for that platform only (and a ``[build.generated]`` section naming them). Then every
zip goes through Blender's validator (``blender_ext.py validate``). Without the bpy module: run
``blender --command extension build --split-platforms --source-dir . --output-dir dist`` with a
Blender 4.2+ binary instead (the same code).

Before building, the manifest is checked (``check_manifest``): every wheel named is for a listed
platform and for Blender's Python (3.11: cp311 / abi3 / py3 tags), every listed platform gets
opencv-python-headless, numba and llvmlite (except ``NO_FAST_PATH``), the numba / llvmlite /
OpenCV versions are the ones ``requirements.txt`` (the runtime pins) has, and ``blender_version_max`` keeps
Blender versions with another Python out. ``--remote`` also asks the package index (pip's
resolver, ``--dry-run``: metadata only, nothing downloaded) that every named wheel file exists.

Missing wheels are downloaded with pip (unmodified PyPI wheels; numpy is not bundled: Blender ships
it) with the platform tags of the file name, e.g.::

    pip download --no-deps --only-binary=:all: --platform win_amd64 --python-version 3.11 \
        numba==0.68.1 -d wheels/
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import re
import subprocess
import sys
import tempfile
import tomllib

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MANIFEST = "blender_manifest.toml"
WHEEL_RE = re.compile(r"^(?P<name>[A-Za-z0-9_]+)-(?P<version>[^-]+)-")
REQUIRED = ("opencv_python_headless", "numba", "llvmlite")
# numba 0.68 / llvmlite 0.50 publish no macOS x86-64 wheels: that platform runs the numpy path
NO_FAST_PATH = {"macos-x64": ("numba", "llvmlite")}
PYTHON = (3, 11)  # Blender 4.2 .. 4.5
PYTHON_CHANGES_AT = "5.0.0"  # the first Blender with another Python


def read_manifest(root=ROOT):
    with open(os.path.join(root, MANIFEST), "rb") as f:
        return tomllib.load(f)


def download_wheel(rel: str, root=ROOT):
    """pip-download the (pinned, unmodified) wheel named ``rel`` into its folder."""
    fn = os.path.basename(rel)
    m = WHEEL_RE.match(fn)
    if not m:
        raise SystemExit(f"cannot parse wheel file name {fn}")
    name = m.group("name").replace("_", "-")
    dest = os.path.join(root, os.path.dirname(rel))
    cmd = [
        sys.executable,
        "-m",
        "pip",
        "download",
        "--no-deps",
        "--only-binary=:all:",
        *_pip_platform_args(fn),
        f"{name}=={m.group('version')}",
        "-d",
        dest,
    ]
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


MACHINES = {"x86_64": "x64", "amd64": "x64", "aarch64": "arm64", "arm64": "arm64"}


def wheel_platforms(filename: str) -> set:
    """Blender platforms a wheel file is for (Blender's own rule, ``blender_ext.py``): ``any`` = all."""
    tags = os.path.basename(filename)[:-4].split("-")[-1]
    out = set()
    for t in tags.split("."):
        if t == "any":
            return {"any"}
        machine = next((v for k, v in MACHINES.items() if t.endswith("_" + k)), t.rpartition("_")[2])
        if t.startswith("win"):
            out.add(f"windows-{machine}")
        elif t.startswith("macosx"):
            out |= {"macos-x64", "macos-arm64"} if machine == "universal2" else {f"macos-{machine}"}
        elif "linux" in t:
            out.add(f"linux-{machine}")
        else:
            out.add(t)
    return out


def wheel_python_ok(filename: str, python=PYTHON) -> bool:
    """True when the wheel installs on CPython ``python`` (tags cpXY, cp3X-abi3 with X <= minor, py3)."""
    parts = os.path.basename(filename)[:-4].split("-")
    py, abi = parts[-3], parts[-2]
    for tag in py.split("."):
        if tag in ("py3", f"py{python[0]}{python[1]}"):
            return True
        if tag == f"cp{python[0]}{python[1]}":
            return True
        if abi == "abi3" and tag.startswith("cp3") and int(tag[3:]) <= python[1]:
            return True
    return False


def _version_tuple(v: str):
    return tuple(int(x) for x in re.findall(r"\d+", v)[:3])


def requirement_pins(path=os.path.join(ROOT, "requirements.txt")) -> dict:
    pins = {}
    with open(path) as f:
        for line in f:
            line = line.split("#")[0].strip()
            if "==" in line:
                n, v = line.split("==", 1)
                pins[n.strip().lower().replace("-", "_")] = v.strip()
    return pins


def check_manifest(manifest=None, pins=None) -> list:
    """Problems of the manifest's platforms and wheels (empty list = fine); see the module text."""
    manifest = manifest or read_manifest()
    pins = requirement_pins() if pins is None else pins
    problems = []
    platforms = manifest.get("platforms") or []
    if not platforms:
        problems.append("no 'platforms' listed")
    per_platform = {p: {} for p in platforms}
    cpython_specific = False
    for w in manifest.get("wheels", []):
        fn = os.path.basename(w)
        m = WHEEL_RE.match(fn)
        if not m or not fn.endswith(".whl") or len(fn[:-4].split("-")) < 5:
            problems.append(f"{fn}: not a wheel file name")
            continue
        name, version = m.group("name").lower(), m.group("version")
        if not wheel_python_ok(fn):
            problems.append(f"{fn}: does not install on Python {PYTHON[0]}.{PYTHON[1]} (Blender 4.2 to 4.5)")
        if fn.split("-")[-3].startswith("cp") and fn.split("-")[-2] != "abi3":
            cpython_specific = True
        if name in pins and pins[name] != version:
            problems.append(f"{fn}: version {version} but requirements.txt pins {name}=={pins[name]}")
        plats = wheel_platforms(fn)
        targets = platforms if plats == {"any"} else sorted(plats)
        for p in targets:
            if p not in per_platform:
                problems.append(f"{fn}: for platform {p}, which 'platforms' does not list")
                continue
            if name in per_platform[p]:
                problems.append(f"{fn}: a second {name} wheel for {p} ({per_platform[p][name]})")
            per_platform[p][name] = fn
    for p, have in per_platform.items():
        for need in REQUIRED:
            if need in have and need in NO_FAST_PATH.get(p, ()):
                problems.append(
                    f"{p}: has {have[need]} but NO_FAST_PATH says it has none (update NO_FAST_PATH and docs/extension.md)"
                )
            if need not in have and need not in NO_FAST_PATH.get(p, ()):
                problems.append(f"{p}: no {need} wheel")
    vmax = manifest.get("blender_version_max")
    if cpython_specific and (not vmax or _version_tuple(vmax) > _version_tuple(PYTHON_CHANGES_AT)):
        problems.append(
            f"wheels built for CPython {PYTHON[0]}.{PYTHON[1]} only, but blender_version_max is "
            f"{vmax!r}: set it to {PYTHON_CHANGES_AT!r} or lower (Blender {PYTHON_CHANGES_AT} has "
            f"another Python)"
        )
    return problems


def _pip_platform_args(fn: str):
    plats = fn[:-4].split("-")[-1].split(".")
    if plats == ["any"]:
        return []
    args = []
    for p in plats:
        args += ["--platform", p]
    return args + ["--python-version", f"{PYTHON[0]}.{PYTHON[1]}"]


def remote_check(manifest=None) -> list:
    """Ask the package index (pip --dry-run: metadata only) that every named wheel file exists."""
    manifest = manifest or read_manifest()
    problems = []
    with tempfile.TemporaryDirectory() as tmp:
        for w in manifest.get("wheels", []):
            fn = os.path.basename(w)
            m = WHEEL_RE.match(fn)
            report = os.path.join(tmp, "report.json")
            cmd = [
                sys.executable,
                "-m",
                "pip",
                "install",
                "--dry-run",
                "--quiet",
                "--ignore-installed",
                "--no-deps",
                "--only-binary=:all:",
                "--target",
                os.path.join(tmp, "t"),
                "--report",
                report,
                *_pip_platform_args(fn),
                f"{m.group('name').replace('_', '-')}=={m.group('version')}",
            ]
            r = subprocess.run(cmd, capture_output=True, text=True)
            if r.returncode != 0:
                problems.append(f"{fn}: the index has no such wheel ({r.stderr.strip().splitlines()[-1]})")
                continue
            with open(report) as f:
                url = json.load(f)["install"][0]["download_info"]["url"]
            got = url.rsplit("/", 1)[-1]
            if got != fn:
                problems.append(f"{fn}: the index resolves {got} for these tags instead")
            else:
                print(f"ok  {fn}")
    return problems


def build(out_dir="dist", root=ROOT, download=True, check=True) -> dict:
    """Check the manifest, fetch missing wheels, run Blender's builder with --split-platforms, validate.
    Returns ``{platform: zip path}``."""
    manifest = read_manifest(root)
    problems = check_manifest(manifest)
    if problems:
        raise SystemExit("blender_manifest.toml: " + "; ".join(problems))
    for w in manifest.get("wheels", []):
        rel = w[2:] if w.startswith("./") else w
        if not os.path.isfile(os.path.join(root, rel)):
            if not download:
                raise SystemExit(f"missing wheel {rel} (run without --no-download)")
            download_wheel(rel, root)
    script = blender_ext_script()
    if script is None:
        raise SystemExit(
            "Blender's extension builder not found: install the bpy module (requirements.txt) or run "
            "`blender --command extension build --split-platforms --source-dir . --output-dir dist`"
        )
    out_dir = os.path.join(root, out_dir) if not os.path.isabs(out_dir) else out_dir
    os.makedirs(out_dir, exist_ok=True)
    r = subprocess.run(
        [sys.executable, script, "build", "--source-dir", root, "--output-dir", out_dir, "--split-platforms"],
        capture_output=True,
        text=True,
    )
    print((r.stdout + r.stderr).strip())
    if r.returncode != 0:
        raise SystemExit("Blender's builder failed")
    zips = {}
    for p in manifest["platforms"]:
        z = os.path.join(out_dir, f"{manifest['id']}-{manifest['version']}-{p.replace('-', '_')}.zip")
        if not os.path.isfile(z):
            raise SystemExit(f"Blender's builder did not write {z}")
        zips[p] = z
        print(f"{p}: {z} ({os.path.getsize(z) / 1e6:.1f} MB)")
        if check:
            validate(z)
    return zips


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default="dist", help="output directory (default dist/)")
    ap.add_argument("--no-download", action="store_true", help="fail instead of downloading missing wheels")
    ap.add_argument("--no-validate", action="store_true", help="skip Blender's validator")
    ap.add_argument("--check-only", action="store_true", help="only check the manifest (no build)")
    ap.add_argument("--remote", action="store_true", help="also ask the package index that every wheel exists")
    a = ap.parse_args(argv)
    problems = check_manifest()
    if a.remote:
        problems += remote_check()
    if problems:
        raise SystemExit("problems:\n  " + "\n  ".join(problems))
    print("manifest ok: " + ", ".join(read_manifest()["platforms"]))
    if not a.check_only:
        build(a.out, download=not a.no_download, check=not a.no_validate)


if __name__ == "__main__":
    main()
