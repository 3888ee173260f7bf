"""The CLI's habits: help on every option, ``--version`` from the manifest, the ``clothfit``
console script, stdout = one JSON document, exit codes 2 (bad data) / 64 (usage) / 130 (Ctrl-C, the
fit's best result kept), and the runtime / development requirements split."""

import argparse
import contextlib
import io
import json
import os
import re
import signal
import subprocess
import sys
import time
import tomllib

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from clothfit import cli  # noqa: E402


def _manifest_version():
    with open(os.path.join(ROOT, "blender_manifest.toml"), "rb") as f:
        return tomllib.load(f)["version"]


def run(*args, cwd=ROOT, timeout=300, **popen):
    env = {k: v for k, v in os.environ.items() if k != "CLOTHFIT_PROGRESS"}
    return subprocess.run(
        [sys.executable, "-m", "clothfit", *map(str, args)],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
        **popen,
    )


def in_process(*args):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = cli.main([str(a) for a in args])
    return rc, out.getvalue(), err.getvalue()


# ------------------------------------------------------------------ help


def _subcommands(parser):
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    helps = {c.dest: c.help for c in sub._choices_actions}
    return sub.choices, helps


def test_every_option_of_every_command_has_help_and_shows_its_default():
    parser = cli.build_parser()
    commands, helps = _subcommands(parser)
    assert {
        "fit",
        "evaluate",
        "overlay",
        "synth",
        "bench",
        "extract",
        "import-cameras",
        "export-cameras",
        "blender",
        "blender-agreement",
    } <= set(commands)
    missing = []
    for name, sub in commands.items():
        assert sub.prog == f"clothfit {name}", sub.prog
        assert helps.get(name) and sub.description, name
        for a in sub._actions:
            if isinstance(a, (argparse._HelpAction, argparse._VersionAction)):
                continue
            label = f"{name} {'/'.join(a.option_strings) or a.dest}"
            if not a.help or a.help == argparse.SUPPRESS:
                missing.append(f"{label}: no help")
            elif a.default not in (None, False, [], argparse.SUPPRESS) and "%(default)" not in a.help:
                missing.append(f"{label}: default {a.default!r} not shown with %(default)s")
            else:
                sub._get_formatter()._expand_help(a)  # the help text formats (no stray %)
    assert not missing, "\n".join(missing)
    # one help per command: import-cameras and export-cameras say different things
    assert len(set(helps.values())) == len(helps), helps
    for cmd in ("import-cameras", "export-cameras"):
        assert (
            commands[cmd].format_help()
            != commands["export-cameras" if cmd == "import-cameras" else "import-cameras"].format_help()
        )


def _headings(path):
    """The headings of a Markdown page and their anchors (MkDocs: ``{ #id }`` or the slug)."""
    names, anchors = set(), set()
    with open(path, encoding="utf-8") as f:
        for line in f:
            m = re.match(r"#+\s+(.*?)\s*(\{\s*#([\w-]+)\s*\})?\s*$", line)
            if m and not line.startswith("#!"):
                names.add(m.group(1).replace("`", ""))
                anchors.add(m.group(3) or re.sub(r"[^\w\s-]", "", m.group(1).lower()).strip().replace(" ", "-"))
    return names, anchors


def test_every_reference_in_the_help_texts_names_a_page_and_heading_that_exist():
    """A help text that sends the reader somewhere (``README, 'Heading'``, ``docs/page.md``,
    ``docs/page.md#anchor``, ``docs/page.md, 'Heading'``) names a page and heading that exist."""
    parser = cli.build_parser()
    commands, _ = _subcommands(parser)
    texts = [parser.description or "", parser.epilog or ""]
    for sub in commands.values():
        texts += [sub.description or "", sub.epilog or ""] + [a.help or "" for a in sub._actions]
    text = " ".join(" ".join(texts).split())
    bad, seen = [], 0
    for m in re.finditer(r"README(?:\.md)?(?:, ['\"]([^'\"]+)['\"])?", text):
        seen += 1
        if not m.group(1) or m.group(1).replace("`", "") not in _headings(os.path.join(ROOT, "README.md"))[0]:
            bad.append(m.group(0))
    for m in re.finditer(r"docs/([\w/]+\.md)(?:#([\w-]+))?(?:, ['\"]([^'\"]+)['\"])?", text):
        seen += 1
        page = os.path.join(ROOT, "docs", m.group(1))
        if not os.path.isfile(page):
            bad.append(m.group(0))
            continue
        names, anchors = _headings(page)
        if (m.group(2) and m.group(2) not in anchors) or (m.group(3) and m.group(3).replace("`", "") not in names):
            bad.append(m.group(0))
    assert seen and not bad, bad


def test_help_names_the_program_and_documents_stdout_and_exit_codes():
    r = run("blender", "--help")
    assert r.returncode == 0 and r.stdout.startswith("usage: clothfit blender"), r.stdout[:200]
    assert "__main__" not in r.stdout
    r = run("--help")
    assert r.returncode == 0 and r.stdout.startswith("usage: clothfit")
    text = " ".join(r.stdout.split())
    for needle in (
        "stdout carries one JSON document",
        "stderr",
        "2 bad data",
        "64 a command line the parser rejects",
        "130 interrupted by Ctrl-C",
    ):
        assert needle in text, needle


# ------------------------------------------------------------------ version


def test_version_comes_from_the_manifest():
    import clothfit

    version = _manifest_version()
    assert clothfit.version() == version
    r = run("--version")
    assert r.returncode == 0 and r.stdout.strip() == f"clothfit {version}"
    with open(os.path.join(ROOT, "pyproject.toml"), "rb") as f:
        project = tomllib.load(f)
    assert "version" not in project["project"] and "version" in project["project"]["dynamic"]
    hv = project["tool"]["hatch"]["version"]
    assert hv["path"] == "blender_manifest.toml"
    with open(os.path.join(ROOT, hv["path"])) as f:
        assert re.search(hv["pattern"], f.read()).group("version") == version


# ------------------------------------------------------------------ the console script


def test_console_script_from_a_wheel(tmp_path):
    """Build the wheel (pyproject.toml, hatchling), install it into a folder of its own and run the
    ``clothfit`` script it brings, away from the checkout: version from the package metadata, rig
    presets from the wheel."""
    pytest.importorskip("hatchling", reason="the build backend is in requirements-dev.txt")
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "--quiet",
            "--no-deps",
            "--no-build-isolation",
            "-w",
            str(tmp_path / "dist"),
            ROOT,
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    (wheel,) = (tmp_path / "dist").glob("silhouette_cloth_fit-*.whl")
    import zipfile

    names = zipfile.ZipFile(wheel).namelist()
    assert (
        "clothfit/__main__.py" in names and "clothfit/cli/__init__.py" in names and "clothfit/rigs/lab18.json" in names
    )
    tops = {n.split("/")[0] for n in names if not n.split("/")[0].endswith(".dist-info")}
    assert tops == {"clothfit"}, tops  # the wheel's only top-level package
    site = tmp_path / "site"
    r = subprocess.run(
        [sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--target", str(site), str(wheel)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    script = site / "bin" / "clothfit"
    env = dict(os.environ, PYTHONPATH=str(site))
    r = subprocess.run([str(script), "--version"], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and r.stdout.strip() == f"clothfit {_manifest_version()}", r.stderr
    r = subprocess.run(
        [str(script), "rig", "ring8"], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120
    )
    assert r.returncode == 0, r.stderr
    assert len(json.loads(r.stdout)["cameras"]) == 8
    r = subprocess.run(
        [sys.executable, "-c", "import clothfit; print(clothfit.__file__)"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.stdout.strip().startswith(str(site)), r.stdout  # the wheel's copy ran, not the checkout


def test_the_venvs_console_script_runs():
    """``make venv`` installs the package editable: ``.venv/bin/clothfit`` (skipped in an environment
    made another way, e.g. a worktree sharing another checkout's venv)."""
    script = os.path.join(os.path.dirname(sys.executable), "clothfit")
    if not os.path.isfile(script):
        pytest.skip(f"{script} not installed (make venv installs it)")
    r = subprocess.run([script, "--version"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and r.stdout.strip() == f"clothfit {_manifest_version()}", r.stderr


# ------------------------------------------------------------------ stdout and exit codes


def test_export_blender_cloth_says_what_is_wrong_with_the_file(tmp_path):
    """A file that is no fit result is named as such, not read as the other model's parameters; a
    paper-model fit is named as one."""
    cases = [
        ({"a": 1}, "not a fit result"),
        ([1, 2], "expected a JSON object"),
        ({"model": {"name": "paper"}, "params": {"m": 1e-5, "k": 10, "l": 0.006, "d": 1e-4}}, "paper-model fit"),
    ]
    for i, (content, needle) in enumerate(cases):
        p = tmp_path / f"r{i}.json"
        p.write_text(json.dumps(content))
        rc, out, err = in_process("export-blender-cloth", p)
        assert rc == 2 and out == "" and "Traceback" not in err, err
        assert err.strip().startswith("error: ") and str(p) in err and needle in err, err
        assert "'m'" not in err and "m, k, l, d)" not in err, err
    (tmp_path / "text.json").write_text("garbage")
    rc, out, err = in_process("export-blender-cloth", tmp_path / "text.json")
    assert rc == 2 and "not valid JSON" in err, err


def test_usage_errors_exit_64_bad_data_exits_2(tmp_path):
    for args, needle in (
        (["fit"], "required: TAKE"),
        (["no-such-command"], "invalid choice"),
        (["fit", tmp_path, "--max-evaluations", "many"], "invalid int value"),
        (["fit", tmp_path, "--resume", "--force"], "not allowed with"),
        (["synth"], "--out"),
    ):
        r = run(*args)
        assert r.returncode == cli.EXIT_USAGE == 64, (args, r.returncode, r.stderr)
        assert r.stderr.startswith("usage: clothfit") and needle in r.stderr, r.stderr
        assert r.stdout == ""
    r = run("fit", tmp_path / "missing", "--quiet")  # well-formed command line, bad data
    assert r.returncode == cli.EXIT_BAD_DATA == 2
    assert r.stderr.strip().startswith("error: ") and len(r.stderr.strip().splitlines()) == 1 and r.stdout == ""


def test_messages_go_to_stderr_at_the_file_descriptor_level(capfd):
    """What libraries write to stdout from C (Blender, Ray) goes to stderr while a command runs."""
    with cli.messages_to_stderr():
        print("from python")
        os.write(sys.stdout.fileno(), b"from C\n")
    cli.emit({"a": 1.0, "b": float("nan")})
    out, err = capfd.readouterr()
    assert "from python" in err and "from C" in err
    assert json.loads(out) == {"a": 1.0, "b": None}  # strict JSON: NaN as null


def test_rig_prints_only_json_and_tables_prints_text(tmp_path):
    r = run("rig", "ring8")
    assert r.returncode == 0 and "training order" in r.stderr
    d = json.loads(r.stdout)
    assert d["rig"] == "ring8" and sorted(d["training_order"]) == sorted(d["cameras"])
    p = tmp_path / "paper.json"
    p.write_text(json.dumps({"table1": []}))
    rc, out, _ = in_process("tables", p)
    assert rc == 0 and not out.lstrip().startswith("{")


def test_ctrl_c_in_any_command_is_130_and_one_line(monkeypatch):
    from clothfit.core.observation import synth

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(synth, "synth_capture", interrupted)
    rc, out, err = in_process("synth", "--out", "/nonexistent/never")
    assert rc == cli.EXIT_INTERRUPTED == 130
    assert err.strip() == "interrupted: synth stopped" and out == ""


@pytest.fixture(scope="module")
def cap(tmp_path_factory):
    root = tmp_path_factory.mktemp("habits") / "cap"
    r = run("synth", "--out", root, "--resolution", "60x80")
    assert r.returncode == 0, r.stderr
    return root


def test_ctrl_c_stops_a_fit_with_130_and_keeps_its_best_result(cap, tmp_path):
    """SIGINT to a running fit: exit code 130, one line saying where the best result is, that result
    written (cancelled, with parameters) and also reported on stdout."""
    out = tmp_path / "fit.json"
    ck = tmp_path / "fit.json.checkpoint.json"
    env = {k: v for k, v in os.environ.items() if k != "CLOTHFIT_PROGRESS"}
    # a budget it cannot spend in the test's time (IPOP restarts go on after each convergence)
    # ``python -m clothfit`` with Python's own Ctrl-C handling, also when this test runs in a background job
    # (whose SIGINT the shell ignores, and Python then leaves ignored)
    main = (
        "import signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
        "from clothfit.cli import main; sys.exit(main())"
    )
    p = subprocess.Popen(
        [
            sys.executable,
            "-c",
            main,
            "fit",
            str(cap),
            "--out",
            str(out),
            "--cameras",
            "n:2",
            "--times",
            "0.1,0.2,0.3",
            "--max-evaluations",
            "1000000",
            "--restarts",
            "20",
            "--quiet",
        ],
        cwd=ROOT,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        t0 = time.monotonic()
        while not ck.exists() and p.poll() is None and time.monotonic() - t0 < 240:
            time.sleep(0.1)  # the checkpoint: the first generation is done
        assert p.poll() is None, p.communicate()
        assert ck.exists()
        p.send_signal(signal.SIGINT)
        so, se = p.communicate(timeout=120)
    finally:
        if p.poll() is None:
            p.kill()
            p.communicate()
    assert p.returncode == 130, se
    lines = [ln for ln in se.splitlines() if ln.strip()]
    assert lines[-1] == f"interrupted: the best result so far ({json.loads(so)['evaluations']} evaluations) is in {out}"
    assert "Traceback" not in se
    r = json.loads(out.read_text())
    assert r["cancelled"] is True and r["stop_reason"] == "cancelled" and r["params"] is not None
    assert 0 < r["evaluations"] < 1000000
    summary = json.loads(so)
    assert summary["cancelled"] is True and summary["params"] == r["params"] and summary["out"] == str(out)
    from clothfit.core.fitting.job import read_checkpoint

    assert read_checkpoint(str(ck))["cancelled"] is True


# ------------------------------------------------------------------ requirements


def _pins(path):
    pins = {}
    with open(os.path.join(ROOT, path)) as f:
        for line in f:
            line = line.split("#")[0].strip()
            if "==" in line:
                name, v = line.split("==")
                pins[name.strip().lower()] = v.strip()
    return pins


def test_runtime_and_development_requirements_are_split():
    runtime, dev = _pins("requirements.txt"), _pins("requirements-dev.txt")
    with open(os.path.join(ROOT, "requirements-dev.txt")) as f:
        assert "-r requirements.txt" in f.read().splitlines()
    assert not {"pytest", "pillow", "cma", "hatchling"} & set(runtime), runtime
    assert {"pytest", "pillow"} <= set(dev) and not set(dev) & set(runtime)
    # what the runtime list lacks is imported by no module of the add-on
    for name in ("pytest", "cma", "PIL"):
        pattern = re.compile(rf"^\s*(import|from)\s+{name}\b", re.MULTILINE)
        for folder, _, files in os.walk(os.path.join(ROOT, "addon")):
            for fn in files:
                if fn.endswith(".py"):
                    with open(os.path.join(folder, fn)) as f:
                        assert not pattern.search(f.read()), (name, fn)
    # the package's dependency ranges hold the pinned versions
    from packaging.requirements import Requirement

    with open(os.path.join(ROOT, "pyproject.toml"), "rb") as f:
        project = tomllib.load(f)["project"]
    reqs = [Requirement(r) for r in project["dependencies"]]
    reqs += [Requirement(r) for extra in project["optional-dependencies"].values() for r in extra]
    for req in reqs:
        name = req.name.lower()
        assert name in runtime, f"{name} is a dependency of pyproject.toml but not pinned in requirements.txt"
        assert req.specifier.contains(runtime[name]), (str(req), runtime[name])
    assert project["scripts"] == {"clothfit": "clothfit.cli:main"}


def test_makefile_installs_the_development_requirements_and_the_package():
    with open(os.path.join(ROOT, "Makefile")) as f:
        text = f.read()
    stamp = re.search(r"^\$\(STAMP\):(.*)$", text, re.MULTILINE).group(1).split()
    assert {"requirements.txt", "requirements-dev.txt", "pyproject.toml"} <= set(stamp)
    assert "pip install --quiet -r requirements-dev.txt" in text and "-e ." in text
    with open(os.path.join(ROOT, ".ci", "run")) as f:
        assert "make test" in f.read()


def test_a_list_of_times_that_starts_before_the_release_is_read_as_a_value_not_an_option():
    """Frames before the release have negative times: ``--times -0.15,-0.05,0.1`` is the option's value (argparse
    alone reads it as an unknown option), and a single negative number or an option's own ``=`` is left as it was."""
    argv = ["fit", "cap", "--times", "-0.15,-0.05,0.1", "--seed", "-1", "--gravity=-9.8,0,0", "--quiet"]
    assert cli.attach_number_lists(argv) == [
        "fit",
        "cap",
        "--times=-0.15,-0.05,0.1",
        "--seed",
        "-1",
        "--gravity=-9.8,0,0",
        "--quiet",
    ]
    args = cli.build_parser().parse_args(cli.attach_number_lists(["fit", "cap", "--times", "-1e-1, 0.2", "--quiet"]))
    assert args.times == "-1e-1, 0.2"
    with pytest.raises(SystemExit), contextlib.redirect_stderr(io.StringIO()):
        cli.build_parser().parse_args(["fit", "cap", "--times", "-0.15,0.1"])  # what argparse alone does
