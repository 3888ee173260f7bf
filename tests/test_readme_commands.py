"""Every command in the README (and the getting-started page) runs as written after its set-up command
on a fresh machine: each line of their code blocks is a `make` target the Makefile has, `pip install`, or
the command line through the venv that `make venv` makes (`.venv/bin/clothfit`, after a line that makes
the venv), naming a real command and options the command line's own parser accepts; every path it reads
exists in the repository or is written by an earlier line. Nothing is run: the lines are parsed."""

import os
import re
import shlex

import pytest
from clothfit.cli import attach_number_lists, build_parser

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PAGES = ["README.md", "docs/getting_started.md"]
VENV_CLI = (".venv/bin/clothfit",)
VENV_PYTHON = ".venv/bin/python"
# options whose value is a file or folder the command writes (the others' paths are read)
OUTPUT_OPTIONS = {"--out", "-o", "--out-dir", "--json", "--preset", "--checkpoint", "--export", "--report", "--blend"}
PATHLIKE = re.compile(r"(/|\.(json|py|blend|npz|png|yml|yaml|mp4)$)")


def code_lines(path):
    """The command lines of a Markdown file's fenced code blocks (comments and blank lines dropped)."""
    text = open(os.path.join(ROOT, path), encoding="utf-8").read()
    out = []
    for block in re.findall(r"^```[^\n]*\n(.*?)^```", text, re.S | re.M):
        for line in block.splitlines():
            words = shlex.split(line, comments=True)
            if words:
                out.append(words)
    return out


def makefile_targets():
    """Target -> its prerequisites, from the Makefile."""
    targets = {}
    for line in open(os.path.join(ROOT, "Makefile"), encoding="utf-8"):
        m = re.match(r"^([\w.$()/-]+)\s*:(?!=)(.*)$", line)
        if m and not line.startswith("\t"):
            targets[m.group(1)] = m.group(2).split()
    return targets


def makes_the_venv(target, targets, seen=()):
    if target == "venv":
        return True
    return any(makes_the_venv(t, targets, seen + (target,)) for t in targets.get(target, []) if t not in seen)


def check_clothfit(argv, made):
    """Parse ``argv`` (after the program) with the real parser; the paths it reads must exist or be made."""
    problems = []
    parser = build_parser()
    try:
        parser.parse_args(attach_number_lists(argv))
    except SystemExit as e:
        return [f"the command line's parser rejects it (exit {e.code})"]
    prev = None
    for word in argv[1:]:
        if word.startswith("-"):
            prev = word.split("=")[0]
            continue
        if prev in OUTPUT_OPTIONS:
            made.add(os.path.normpath(word))
        elif PATHLIKE.search(word) and not os.path.exists(os.path.join(ROOT, word)):
            if os.path.normpath(word) not in made:
                problems.append(f"{word} neither exists nor is written by an earlier line")
        prev = None
    return problems


def check_page(path):
    targets = makefile_targets()
    made, problems = set(), []
    for words in code_lines(path):
        line = " ".join(words)
        prog = words[0]
        if prog == "make":
            for target in words[1:]:
                if target not in targets:
                    problems.append(f"{line}: the Makefile has no target {target!r}")
                elif makes_the_venv(target, targets):
                    made.update(os.path.normpath(p) for p in VENV_CLI + (VENV_PYTHON,))
        elif words[:2] == ["pip", "install"]:
            problems += [f"{line}: {p} does not exist" for p in words[2:] if not os.path.exists(os.path.join(ROOT, p))]
        elif prog in VENV_CLI or words[:3] == [VENV_PYTHON, "-m", "clothfit"]:
            if os.path.normpath(prog) not in made:
                problems.append(f"{line}: {prog} is made by `make venv`, which no earlier line runs")
            argv = words[1:] if prog in VENV_CLI else words[3:]
            problems += [f"{line}: {p}" for p in check_clothfit(argv, made)]
        elif prog in ("clothfit", "python", "python3") or prog.endswith("/python"):
            problems.append(f"{line}: {prog} runs only in an activated environment: write .venv/bin/clothfit")
        else:
            problems.append(f"{line}: a command this test does not know how to check")
    return problems


@pytest.mark.parametrize("page", PAGES)
def test_every_command_line_of_the_page_runs_as_written_after_its_set_up(page):
    problems = check_page(page)
    assert not problems, "\n".join(problems)


@pytest.mark.parametrize("page", PAGES)
def test_the_page_shows_the_quick_start_through_the_venv(page):
    lines = [" ".join(w) for w in code_lines(page)]
    assert any(ln.startswith(".venv/bin/clothfit fit ") for ln in lines)
    assert lines.index("make venv") < min(i for i, ln in enumerate(lines) if ln.startswith(".venv/bin/clothfit"))


def test_the_check_catches_what_fails_on_a_fresh_machine(tmp_path):
    """The checker itself: each kind of broken line is reported."""
    page = tmp_path / "page.md"
    page.write_text(
        "```\n"
        ".venv/bin/clothfit rig\n"  # before make venv
        "make venv\n"
        "make no-such-target\n"
        "python -m clothfit rig\n"  # needs an activated environment
        ".venv/bin/clothfit fit out/nowhere --out out/f.json\n"  # reads a capture nothing made
        ".venv/bin/clothfit fit-everything\n"  # no such command
        ".venv/bin/clothfit synth --out out/c --colour red\n"  # no such option
        ".venv/bin/clothfit synth --out out/c\n"
        ".venv/bin/clothfit fit out/c --out out/f.json\n"  # fine: out/c made above
        "```\n"
    )
    problems = check_page(str(page))  # an absolute path: read as it is
    wanted = [
        "made by `make venv`",
        "no target 'no-such-target'",
        "activated environment",
        "out/nowhere neither exists",
        "fit-everything",
        "--colour",
    ]
    assert len(problems) == len(wanted), problems
    for w, p in zip(wanted, problems):
        if w in ("fit-everything", "--colour"):
            assert "parser rejects" in p and w in p, p
        else:
            assert w in p, p
