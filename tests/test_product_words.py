"""No issue numbers in the product: a reader has no issue tracker to look them up.

Code, tests, lab scripts, tools, docs, the recordings and file names say what a thing is ("the
``--backend blender`` fit", "the phone rig"), never which issue asked for it. A link to another
project's tracker (``https://github.com/opencv/opencv/issues/...``) is a reference a reader can follow,
and is allowed. The scan reads the files git tracks (every file under the folders when there is no git).
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

FOLDERS = ("addon", "tests", "lab", "tools", "docs")
TOP_FILES = ("README.md", "mkdocs.yml")
TEXT_EXTENSIONS = (".md", ".json", ".jsonl", ".yml", ".yaml", ".py", ".toml", ".txt")
# what .gitignore leaves out, and the docs site and build folders
SKIPPED_DIRS = {
    ".git",
    ".venv",
    "out",
    "dist",
    "wheels",
    "build",
    "site",
    "__pycache__",
    ".pytest_cache",
    ".ruff_cache",
}

# "issue" or "issues", any case, then digits after spaces, "-", "_" or "#", also inside a name ("test_issueN");
# not "tissue"
ISSUE_RE = re.compile(r"(?<![A-Za-z0-9])issues?[-_ #]*\d+", re.IGNORECASE)
URL_RE = re.compile(r"https?://\S+")


def tracked_files(root: str) -> list[str]:
    """Every file of ``root`` (relative paths, ``/``-separated): git's tracked files where ``root`` is a
    git checkout and git runs, else a walk of the tree that skips virtual environments and outputs."""
    if os.path.exists(os.path.join(root, ".git")) and shutil.which("git"):
        p = subprocess.run(["git", "-C", root, "ls-files", "-z"], capture_output=True)
        if p.returncode == 0:
            return sorted(f for f in p.stdout.decode().split("\0") if f)
    out = []
    for d, dirs, files in os.walk(root):
        dirs[:] = [x for x in dirs if x not in SKIPPED_DIRS and not x.endswith(".egg-info")]
        out += [os.path.relpath(os.path.join(d, f), root).replace(os.sep, "/") for f in files]
    return sorted(out)


def product_texts(files: list[str]) -> list[str]:
    """The text files the rule covers: ``FOLDERS``' files with a ``TEXT_EXTENSIONS`` ending, and ``TOP_FILES``."""
    return [
        f
        for f in files
        if f in TOP_FILES or (f.split("/", 1)[0] in FOLDERS and "/" in f and f.endswith(TEXT_EXTENSIONS))
    ]


def issue_numbers_in_texts(root: str, files: list[str]) -> list[str]:
    """One ``FILE:LINE: ...`` message per line of ``files`` (relative to ``root``) that holds an issue number
    outside a URL."""
    problems = []
    for f in files:
        path = os.path.join(root, f)
        if not os.path.isfile(path):  # tracked but deleted in the work tree
            continue
        with open(path, encoding="utf-8", errors="replace") as fh:
            for n, line in enumerate(fh, 1):
                for m in ISSUE_RE.finditer(URL_RE.sub(lambda u: " " * len(u.group()), line)):
                    text = line.strip()
                    problems.append(f"{f}:{n}: {m.group()!r} is an issue number (say what the thing is): {text[:140]}")
    return problems


def issue_numbers_in_names(files: list[str]) -> list[str]:
    """One message per file whose path names an issue (``lab/issueN_goals.py`` with N a number)."""
    return [f"{f}: the file name holds an issue number (name what it is)" for f in files if ISSUE_RE.search(f)]


# --------------------------------------------------------------------------------------------- the tree


def test_no_issue_number_in_the_products_code_tests_lab_tools_docs_or_recordings():
    problems = issue_numbers_in_texts(ROOT, product_texts(tracked_files(ROOT)))
    assert not problems, f"{len(problems)} lines:\n" + "\n".join(problems[:60])


def test_no_file_is_named_after_an_issue():
    problems = issue_numbers_in_names(tracked_files(ROOT))
    assert not problems, "\n".join(problems)


def test_the_scan_covers_the_products_folders_and_its_recordings():
    texts = set(product_texts(tracked_files(ROOT)))
    for f in ("README.md", "mkdocs.yml", "addon/core/defaults.py", "tools/figures.py", "tests/test_product_words.py"):
        assert f in texts, f
    assert any(f.startswith("lab/") and f.endswith(".py") for f in texts)
    assert any(f.startswith("docs/figures/") and f.endswith(".json") for f in texts)
    assert any(f.startswith("docs/figures/") and f.endswith(".jsonl") for f in texts)


# ------------------------------------------------------------------------------- the scan on a planted tree

ISSUE = "issue"  # written apart so that this file holds no issue number itself


def _write(root, rel, text):
    path = root / rel
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)


@pytest.fixture
def planted(tmp_path):
    """A small tree like ours, clean but for the lines and names planted in it."""
    _write(tmp_path, "addon/core/a.py", '"""A module."""\n\nX = 1  # the tissue 3 layers, handle #2\n')
    _write(tmp_path, "docs/a.md", "# A page\n\nSee https://github.com/opencv/opencv/issues/25539 upstream.\n")
    _write(tmp_path, "README.md", "# Read me\n")
    return tmp_path


def test_a_clean_tree_passes_with_tissue_handle_numbers_and_links_to_other_trackers(planted):
    files = tracked_files(str(planted))
    assert set(product_texts(files)) == {"addon/core/a.py", "docs/a.md", "README.md"}
    assert issue_numbers_in_texts(str(planted), product_texts(files)) == []
    assert issue_numbers_in_names(files) == []


@pytest.mark.parametrize(
    "line",
    [
        f"# fixed for {ISSUE} 12",
        f"    '''{ISSUE.title()} 20's goals measured.'''",
        f"see {ISSUE}s 9-10",
        f"the {ISSUE}-20 features",
        f"({ISSUE} #7)",
        f"python lab/{ISSUE}20_goals.py",
    ],
)
def test_a_planted_issue_number_is_found_with_its_file_and_line(planted, line):
    for rel in ("addon/core/a.py", "docs/a.md", "README.md"):
        with open(planted / rel, "a") as f:
            f.write(line + "\n")
    problems = issue_numbers_in_texts(str(planted), product_texts(tracked_files(str(planted))))
    assert sorted(p.split(": ", 1)[0] for p in problems) == ["README.md:2", "addon/core/a.py:4", "docs/a.md:4"]


def test_a_planted_line_in_a_recording_or_lab_script_is_found_and_outside_the_folders_is_not(planted):
    _write(planted, "docs/figures/x.json", '{\n "what": "' + ISSUE + ' 18: the rig"\n}\n')
    _write(planted, "lab/study.py", f"# {ISSUE} 3\n")
    _write(planted, ".venv/lib/site.py", f"# {ISSUE} 3\n")  # not ours
    _write(planted, "out/run/log.txt", f"{ISSUE} 3\n")  # an output, not tracked
    _write(planted, "addon/core/picture.png", f"{ISSUE} 3\n")  # not a text file the rule covers
    problems = issue_numbers_in_texts(str(planted), product_texts(tracked_files(str(planted))))
    assert sorted(p.split(": ", 1)[0] for p in problems) == ["docs/figures/x.json:2", "lab/study.py:1"]


def test_a_file_named_after_an_issue_is_found(planted):
    _write(planted, f"lab/{ISSUE}20_goals.py", "X = 1\n")
    _write(planted, f"docs/figures/{ISSUE}-18_rig.json", "{}\n")
    problems = issue_numbers_in_names(tracked_files(str(planted)))
    assert sorted(p.split(": ", 1)[0] for p in problems) == [
        f"docs/figures/{ISSUE}-18_rig.json",
        f"lab/{ISSUE}20_goals.py",
    ]


@pytest.mark.skipif(not shutil.which("git"), reason="needs git")
def test_in_a_git_checkout_only_tracked_files_are_read(planted):
    env = dict(os.environ, GIT_CONFIG_GLOBAL=os.devnull, GIT_CONFIG_NOSYSTEM="1")
    subprocess.run(["git", "init", "-q", str(planted)], check=True, env=env)
    subprocess.run(["git", "-C", str(planted), "add", "addon", "docs", "README.md"], check=True, env=env)
    _write(planted, "addon/core/scratch.py", f"# {ISSUE} 5\n")  # untracked
    files = tracked_files(str(planted))
    assert "addon/core/scratch.py" not in files and "addon/core/a.py" in files
    assert issue_numbers_in_texts(str(planted), product_texts(files)) == []
    subprocess.run(["git", "-C", str(planted), "add", "addon/core/scratch.py"], check=True, env=env)
    problems = issue_numbers_in_texts(str(planted), product_texts(tracked_files(str(planted))))
    assert [p.split(": ", 1)[0] for p in problems] == ["addon/core/scratch.py:1"]
