"""Every number the docs quote is generated from, or checked against, a recorded output.

    python tools/docs_check.py [FILE.md ...]     # check (default: README.md and docs/**/*.md); exit 1 on a problem
    python tools/docs_check.py --write           # regenerate the generated blocks from the recordings
    python tools/docs_check.py --untagged        # list only the numbers that carry no tag

Recordings are ``docs/figures/NAME.json`` (``tools/figures.py record NAME`` writes them: the
command, the commit it ran at, the output) and citations ``docs/figures/cited_*.json`` (numbers
of a publication, with the reference; no command made them). In the Markdown, tags are HTML
comments, invisible on GitHub:

``<!--fig NAME KEY KEY ...-->``
    the last numbers before the tag (one per KEY, in order) are figures of recording NAME. A KEY is
    a path into the recorded output (``rows.3.mean_mm``; ``rows[material^=silk,train_cameras=4]``
    picks the first list item whose fields match, ``^=`` a prefix; ``rows.*.mm`` or
    ``rows.*[model=blender].mm`` is the list of every item's value, for ``min``/``max``/``mean``) or an expression of paths in
    braces (``{a.x}*1000``, ``{a}/{b}``, ``{max(a.list)}``, also ``min`` and ``mean``), or ``@seconds`` (a field of the recording itself: how
    long the command ran), optionally followed by ``~5%`` or ``~0.2``: the tolerance. Without one the quoted number must be the value rounded to the digits shown. ``_``
    skips a number (an input between figures).
``<!--cite NAME KEY ...-->``
    the same for a citation (``cited_*.json``): a publication's numbers, not our measurements.
``<!--in-->``
    the numbers since the previous tag are inputs or definitions (sizes, settings, counts of the
    set-up), not measurements.
``<!--inputs: why-->`` ... ``<!--/inputs-->``
    a region (lines of its own) whose untagged numbers are all inputs: option tables, limits and
    formats. Tags inside it are still checked.
``<!--gen VIEW-->`` ... ``<!--/gen-->``
    the lines between are generated: they must equal ``VIEW``'s rendering of the recordings
    (``--write`` rewrites them).

A tag covers the numbers after the previous tag of the same paragraph, list item or table row.
Not counted as numbers: inline code and code blocks (commands, options, file names), link
targets, version numbers (``Python 3.11``, ``4.5.15``), references (``Figure 3``, ``Table 1``,
``section 6.2``, ``eq. 6``), sizes written ``480 x 640``, compounds such as ``2-core`` or
``18-camera``, camera counts (``8 cameras``: the set-up), exponents (``s^2``), list numbering,
``t = 0.5`` times and names with digits (``cam00``, ``lab18``).
Every other number without a tag is an error, as is a tagged number that differs from its
recording beyond the tolerance, a key or recording that does not exist, a generated block that
differs from its rendering, and a measured figure in a code block's comment.
"""

from __future__ import annotations

import argparse
import glob
import json
import math
import os
import re
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
FIG_DIR = os.path.join(ROOT, "docs", "figures")
sys.path.insert(0, os.path.join(ROOT, "tools"))
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)

TAG_RE = re.compile(r"<!--\s*(fig|cite|in|gen|/gen)\b(.*?)-->", re.DOTALL)
COMMENT_RE = re.compile(r"<!--.*?-->", re.DOTALL)
CODE_RE = re.compile(r"(`+)(.+?)\1", re.DOTALL)
LINK_RE = re.compile(r"\]\(([^)]*)\)")
NUM_RE = re.compile(
    r"(?<![\w.\-+/])(?<!\d,)[-−]?\d{1,3}(?:,\d{3})+(?:\.\d+)?(?![\d,]\d)|(?<![\w.\-+/])[-−]?\d+(?:\.\d+)?"
    r"(?:e[-+]?\d+)?(?![\d])"
)
# not numbers of the docs (see the module docstring); each match is blanked before numbers are read
NOT_FIGURES = [
    r"\bx86-64\b",
    (
        r"\b(?:Python|Blender|bpy|numpy|OpenCV|opencv|numba|llvmlite|cma|Ray|ray|Mesa|PyAV|av|pillow|Eevee|Cycles|"
        r"COLMAP|Debian|Ubuntu|macOS|Windows|LTS|EGL|OpenGL|GL|CUDA|SAM|H\.)\s*v?\d+(?:\.\d+)*\+?"
        r"(?:\s*(?:to|-|and|or)\s*\d+\.\d+(?:\.\d+)*\+?)?"
    ),
    r"\b\d+\.\d+\.\d+(?:\.\d+)?\b",
    (
        r"\b(?:[Ii]ssues?|[Ss]ections?|SPEC section|Tables?|Fig\.|Figs\.|Figure|[Ee]q\.|[Ee]qs\.|[Ee]quation|[Ss]tep|"
        r"[Pp]art|[Cc]ommit|[Ss]eeds?|[Ll]evel|[Cc]hapter|[Vv]ersion|format|[Pp]ass|[Cc]olumn|[Rr]ow)\s+\d+(?:\.\d+)?"
        r"(?:\s*(?:,|and|or|to|-|/)\s*\d+(?:\.\d+)?)*"
    ),
    r"\b\d+(?:\.\d+)?\s*[x×]\s*\d+(?:\.\d+)?(?:\s*[x×]\s*\d+(?:\.\d+)?)?\b(?!\s*(?:faster|slower|fewer|more|the))",
    r"\b\d+(?:\.\d+)?-(?=[A-Za-z])",
    r"^\s*\d+\.\s",
    r"\bt\s*(?:=|<=|>=|<|>|≤|≥)\s*-?\d+(?:\.\d+)?(?:\s*(?:\.\.\.|…|,|to)\s*-?\d+(?:\.\d+)?)*",
    r"\b[A-Za-z_]+\d+[A-Za-z_\d]*\b",
    r"\b\d+(?![eE][-+]?\d)[A-Za-z_]*[A-Za-z_]\d+\w*\b",
    r"\b[23]D\b",
    r"\^-?\d+",
    r"\b\d+\s+(?:training\s+|held-out\s+|other\s+|rig\s+)?cameras?\b(?:\s+x\s+\d+)?",
]
NOT_RE = re.compile("|".join(f"(?:{p})" for p in NOT_FIGURES), re.MULTILINE)


class Problem:
    def __init__(self, path, line, msg):
        self.path, self.line, self.msg = path, line, msg

    def __str__(self):
        return f"{os.path.relpath(self.path, ROOT)}:{self.line}: {self.msg}"


# ----------------------------------------------------------------------------- recordings

_RECORDINGS = {}


def recording(name):
    if name not in _RECORDINGS:
        path = os.path.join(FIG_DIR, f"{name}.json")
        if not os.path.isfile(path):
            _RECORDINGS[name] = None
        else:
            with open(path) as f:
                _RECORDINGS[name] = json.load(f)
    return _RECORDINGS[name]


def check_recording(name, rec):
    """The recording's own format: a command and a commit (or, for a citation, the reference)."""
    if rec is None:
        return f"no recording docs/figures/{name}.json"
    if name.startswith("cited_"):
        return (
            None
            if rec.get("citation") and "data" in rec
            else f"docs/figures/{name}.json: a citation needs 'citation' and 'data'"
        )
    for k in ("command", "commit", "recorded_at", "data"):
        if k not in rec:
            return f"docs/figures/{name}.json: no '{k}' (record it with tools/figures.py)"
    return None


_SEL_RE = re.compile(r"^([^\[\]]+)?((?:\[[^\]]*\])*)$")


def _match(item, cond):
    for c in cond.split(","):
        if "^=" in c:
            k, v = c.split("^=", 1)
            if not isinstance(item, dict) or not str(item.get(k)).startswith(v):
                return False
        elif "=" in c:
            k, v = c.split("=", 1)
            if not isinstance(item, dict) or str(item.get(k)) != v:
                return False
    return True


def lookup(data, path):
    """Value at a dotted path (``a.b.3.c``; ``a[k=v,j^=p].c`` selects list items by their fields; a key
    that itself holds dots, ``median_evals_to_1.0``, is found too)."""
    cur = data
    parts = re.findall(r"(?:[^.\[\]]+|\[[^\]]*\])+", path)
    i = 0
    while i < len(parts):
        part = parts[i]
        if part.startswith("*"):  # every item of a list (those that have the rest)
            items = cur if isinstance(cur, list) else list(cur.values()) if isinstance(cur, dict) else None
            if items is None:
                raise KeyError(f"{path}: '*' of a {type(cur).__name__}")
            if part != "*":  # *[k=v]: the items whose fields match
                items = [x for x in items if _match(x, part[2:-1])]
            rest = ".".join(parts[i + 1 :])
            out = []
            for x in items:
                try:
                    out.append(lookup(x, rest) if rest else x)
                except (KeyError, IndexError, TypeError, ValueError):
                    pass
            return out
        # a key with dots in it ("median_evals_to_1.0"): join the following parts until one exists
        j = i
        while isinstance(cur, dict) and part not in cur and j + 1 < len(parts) and "[" not in part:
            j += 1
            part = part + "." + parts[j]
        if isinstance(cur, dict) and part not in cur:
            part, j = parts[i], i
        i = j + 1
        m = _SEL_RE.match(part)
        if not m:
            raise KeyError(path)
        key, sels = m.group(1), re.findall(r"\[([^\]]*)\]", m.group(2) or "")
        if key is not None:
            if isinstance(cur, list):
                cur = cur[int(key)]
            elif isinstance(cur, dict):
                if key not in cur:
                    raise KeyError(f"{path}: no '{key}'")
                cur = cur[key]
            else:
                raise KeyError(f"{path}: '{key}' of a {type(cur).__name__}")
        for s in sels:
            if not isinstance(cur, list):
                raise KeyError(f"{path}: [{s}] of a {type(cur).__name__}")
            hits = [x for x in cur if _match(x, s)]
            if not hits:
                raise KeyError(f"{path}: nothing matches [{s}]")
            cur = hits[0]
    return cur


def evaluate(rec, key):
    """A key's value: a path into the recorded output, ``@field`` a field of the recording itself,
    or an arithmetic expression of such paths in braces."""

    def value(path):
        m = re.fullmatch(r"(min|max|mean)\((.+)\)", path)
        if m:  # min / max / mean of a list (or a dict's values)
            xs = value(m.group(2))
            xs = list(xs.values()) if isinstance(xs, dict) else list(xs)
            if not xs:
                raise ValueError(f"{path}: empty")
            return min(xs) if m.group(1) == "min" else max(xs) if m.group(1) == "max" else sum(xs) / len(xs)
        return lookup(rec, path[1:]) if path.startswith("@") else lookup(rec["data"], path)

    if "{" not in key:
        return value(key)
    expr = re.sub(r"\{([^}]+)\}", lambda m: repr(float(value(m.group(1)))), key)
    if not re.fullmatch(r"[-+*/().\deE ]+|.*inf.*", expr):
        raise KeyError(f"{key}: not an arithmetic expression")
    return eval(expr, {"__builtins__": {}}, {})


def parse_number(text):
    """(value, half a unit of the last digit shown) of a number as written in the docs."""
    t = text.replace(",", "").replace("−", "-")
    mant = t.split("e")[0].split("E")[0]
    exp = int(t.split("e")[1]) if "e" in t else 0
    dec = len(mant.split(".")[1]) if "." in mant else 0
    return float(t), 0.5 * 10.0 ** (exp - dec)


def parse_key(k):
    tol = None
    if "~" in k:
        k, t = k.rsplit("~", 1)
        tol = ("rel", float(t[:-1]) / 100) if t.endswith("%") else ("abs", float(t))
    return k, tol


def check_value(quoted, key, rec):
    """None if the quoted number matches the recorded value, else a message. ``@field`` reads the
    recording's own fields (``@seconds``: how long the command ran), other keys its output."""
    k, tol = parse_key(key)
    try:
        v = evaluate(rec, k)
    except (KeyError, IndexError, ValueError, TypeError, ZeroDivisionError) as e:
        return f"key {k!r}: {e}"
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return f"key {k!r} is {v!r}, not a number"
    q, half = parse_number(quoted)
    allowed = half * (1 + 1e-9) + 1e-300
    if tol is not None:
        allowed += tol[1] * abs(v) if tol[0] == "rel" else tol[1]
    if not math.isfinite(v) or abs(q - v) > allowed:
        return f"{quoted} differs from the recorded {k} = {v:.6g} (allowed {allowed:.3g})"
    return None


# ----------------------------------------------------------------------------- Markdown


def blank(s, start, end):
    return s[:start] + " " * (end - start) + s[end:]


def numbers_in(text):
    """Numbers of a text fragment (code, links, comments and non-figures already blanked)."""
    t = NOT_RE.sub(lambda m: " " * len(m.group(0)), text)
    return [(m.start(), m.group(0)) for m in NUM_RE.finditer(t)]


def split_blocks(lines):
    """(first line number, text) of every paragraph, list item and table row outside code blocks and
    generated blocks; code-block lines separately as (line number, text, 'code')."""
    blocks, cur, cur_start = [], [], 0
    in_code = False

    def flush():
        nonlocal cur
        if cur:
            blocks.append((cur_start, "\n".join(cur), "text"))
        cur = []

    for i, line in enumerate(lines, 1):
        s = line.strip()
        if s.startswith("```"):
            flush()
            in_code = not in_code
            continue
        if in_code:
            blocks.append((i, line, "code"))
            continue
        if re.fullmatch(r"<!--\s*/?(?:inputs|gen)\b.*-->", s):  # region markers stand alone
            flush()
            continue
        if not s or s.startswith("#") and not s.startswith("#!"):
            flush()
            if s:
                blocks.append((i, line, "text"))
            continue
        if s.startswith("|") or re.match(r"^([*+-]|\d+\.)\s", s):
            flush()
            if s.startswith("|"):
                blocks.append((i, line, "text"))
                continue
        if not cur:
            cur_start = i
        cur.append(line)
    flush()
    return blocks


def line_of(block_start, text, pos):
    return block_start + text.count("\n", 0, pos)


def check_block(path, start, text, problems, stats, inputs_region=False):
    # blank inline code and link targets; keep comments (tags) in place
    t = CODE_RE.sub(lambda m: " " * len(m.group(0)), text)
    t = LINK_RE.sub(lambda m: "](" + " " * len(m.group(1)) + ")", t)
    pending = []  # unclaimed numbers since the previous tag: (pos, text)
    pos = 0
    for m in list(COMMENT_RE.finditer(t)) + [None]:
        seg_end = m.start() if m else len(t)
        for p, n in numbers_in(t[pos:seg_end]):
            pending.append((pos + p, n))
        if m is None:
            break
        pos = m.end()
        tm = TAG_RE.match(m.group(0))
        if not tm:
            continue
        kind, args = tm.group(1), tm.group(2).split()
        ln = line_of(start, t, m.start())
        if kind == "in":
            stats["inputs"] += len(pending)
            pending = []
            continue
        if kind in ("gen", "/gen"):
            continue
        if not args:
            problems.append(Problem(path, ln, f"<!--{kind}--> without a recording name"))
            continue
        name, keys = args[0], args[1:]
        rec = recording(name)
        bad = check_recording(name, rec)
        if bad is None and (kind == "cite") != name.startswith("cited_"):
            bad = f"{name}: 'cite' is for citations (cited_*.json), 'fig' for our recordings"
        if bad:
            problems.append(Problem(path, ln, bad))
            pending = []
            continue
        if len(keys) > len(pending):
            problems.append(
                Problem(
                    path, ln, f"<!--{kind} {name}--> has {len(keys)} keys but only {len(pending)} numbers precede it"
                )
            )
            pending = []
            continue
        claimed = pending[len(pending) - len(keys) :]
        for p0, n0 in pending[: len(pending) - len(keys)]:
            if inputs_region:
                stats["inputs"] += 1
            else:
                problems.append(Problem(path, line_of(start, t, p0), f"number {n0} has no tag ({_context(text, p0)})"))
        for (p, n), key in zip(claimed, keys):
            if key == "_":
                stats["inputs"] += 1
                continue
            msg = check_value(n, key, rec)
            stats["cited" if kind == "cite" else "figures"] += 1
            if msg:
                problems.append(Problem(path, line_of(start, t, p), f"[{name}] {msg}"))
        pending = []
    for p, n in pending:
        if inputs_region:
            stats["inputs"] += 1
        else:
            problems.append(Problem(path, line_of(start, t, p), f"number {n} has no tag ({_context(text, p)})"))


def _context(text, p, w=38):
    s = COMMENT_RE.sub("", text[max(0, p - w) : p + w]).replace("\n", " ")
    return "..." + s.strip() + "..."


MEASURE_IN_COMMENT = re.compile(r"(?:~|about\s+)?\b\d+(?:\.\d+)?\s*(?:s|min|ms|%|x|h|MB|kB)\b")


def check_code_line(path, ln, line, problems):
    """A code block holds commands; a measurement in its comment would escape the check."""
    if "#" not in line:
        return
    comment = line.split("#", 1)[1]
    comment = CODE_RE.sub(" ", comment)
    m = MEASURE_IN_COMMENT.search(NOT_RE.sub(lambda x: " " * len(x.group(0)), comment))
    if m:
        problems.append(
            Problem(
                path,
                ln,
                f"a measured figure in a code comment ({m.group(0).strip()!r}): "
                f"quote it in the text with a tag, or generate the block",
            )
        )


# ----------------------------------------------------------------------------- generated blocks


def render(view):
    from docs_views import VIEWS

    if view not in VIEWS:
        raise KeyError(f"unknown view {view!r}")
    return VIEWS[view](recording).rstrip("\n")


INPUTS_BEGIN = re.compile(r"^\s*<!--\s*inputs\b.*-->\s*$")
INPUTS_END = re.compile(r"^\s*<!--\s*/inputs\s*-->\s*$")
GEN_BEGIN = re.compile(r"^\s*<!--\s*gen\s+(\S+)\s*-->\s*$")
GEN_END = re.compile(r"^\s*<!--\s*/gen\s*-->\s*$")


def generated_regions(lines):
    """[(view, first content line index, end marker index)] (0-based indices)."""
    out, i = [], 0
    while i < len(lines):
        m = GEN_BEGIN.match(lines[i])
        if m:
            j = i + 1
            while j < len(lines) and not GEN_END.match(lines[j]):
                j += 1
            out.append((m.group(1), i + 1, j))
            i = j
        i += 1
    return out


def check_file(path, write=False, stats=None):
    stats = stats if stats is not None else {"figures": 0, "cited": 0, "inputs": 0, "generated": 0}
    problems = []
    with open(path, encoding="utf-8") as f:
        lines = f.read().split("\n")
    regions = generated_regions(lines)
    new_lines = list(lines)
    for view, a, b in reversed(regions):
        if b >= len(lines):
            problems.append(Problem(path, a, f"<!--gen {view}--> has no <!--/gen-->"))
            continue
        try:
            text = render(view)
        except Exception as e:  # noqa: BLE001 - report any renderer failure as a docs problem
            problems.append(Problem(path, a, f"view {view}: {type(e).__name__}: {e}"))
            continue
        stats["generated"] += 1
        want = text.split("\n")
        if lines[a:b] != want:
            if write:
                new_lines[a:b] = want
            else:
                diff = next((k for k, (x, y) in enumerate(zip(lines[a:b], want)) if x != y), min(b - a, len(want)))
                problems.append(
                    Problem(
                        path,
                        a + 1 + diff,
                        f"generated block {view} differs from its rendering (run `python tools/docs_check.py --write`)",
                    )
                )
    if write and new_lines != lines:
        with open(path, "w", encoding="utf-8") as f:
            f.write("\n".join(new_lines))
        print(f"rewrote generated blocks in {os.path.relpath(path, ROOT)}")
    # everything outside generated blocks
    masked = list(lines)
    for _, a, b in regions:
        for k in range(a, min(b, len(masked))):
            masked[k] = ""
    in_inputs, opened = set(), None
    for i, line in enumerate(lines, 1):
        if INPUTS_BEGIN.match(line):
            opened = i
        elif INPUTS_END.match(line):
            if opened is None:
                problems.append(Problem(path, i, "<!--/inputs--> without <!--inputs-->"))
            else:
                in_inputs.update(range(opened, i))
            opened = None
    if opened is not None:
        problems.append(Problem(path, opened, "<!--inputs--> has no <!--/inputs-->"))
    for start, text, kind in split_blocks(masked):
        if kind == "code":
            check_code_line(path, start, text, problems)
        else:
            check_block(path, start, text, problems, stats, inputs_region=start in in_inputs)
    return problems, stats


def default_files():
    """README.md and every page of the docs site (docs/, subfolders included)."""
    return [os.path.join(ROOT, "README.md")] + sorted(
        glob.glob(os.path.join(ROOT, "docs", "**", "*.md"), recursive=True)
    )


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python tools/docs_check.py", description=__doc__.split("\n")[0])
    ap.add_argument("files", nargs="*", help="Markdown files (default: README.md, docs/**/*.md)")
    ap.add_argument("--write", action="store_true", help="rewrite the generated blocks from the recordings")
    ap.add_argument("--untagged", action="store_true", help="list only numbers without a tag")
    a = ap.parse_args(argv)
    files = [os.path.abspath(f) for f in a.files] or default_files()
    stats = {"figures": 0, "cited": 0, "inputs": 0, "generated": 0}
    problems = []
    for f in files:
        p, _ = check_file(f, write=a.write, stats=stats)
        problems += p
    for name in sorted(os.path.basename(p)[:-5] for p in glob.glob(os.path.join(FIG_DIR, "*.json"))):
        bad = check_recording(name, recording(name))
        if bad:
            problems.append(Problem(os.path.join(FIG_DIR, f"{name}.json"), 1, bad))
    shown = [p for p in problems if not a.untagged or "has no tag" in p.msg]
    for p in shown:
        print(p)
    print(
        f"docs-check: {stats['figures']} figures checked against recordings, {stats['cited']} citations, "
        f"{stats['generated']} generated blocks, {stats['inputs']} numbers marked as inputs; "
        f"{len(problems)} problems",
        file=sys.stderr,
    )
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
