"""MkDocs hook: the command-line reference, generated from the parser at build time.

``docs/cli_reference.md`` holds the marker ``<!--cli-reference-->``; this hook replaces it with every
command of ``build_parser()`` (its usage, description and options, as ``--help`` prints them).
The parser is imported from ``clothfit.cli`` (the installed package), else from ``clothfit.cli`` (a
checkout).
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

MARKER = "<!--cli-reference-->"


def _build_parser():
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    if root not in sys.path:
        sys.path.insert(0, root)
    for name in ("clothfit.cli", "clothfit.cli"):
        try:
            mod = importlib.import_module(name)
        except ImportError:
            continue
        return mod.build_parser()
    raise ImportError("neither clothfit.cli nor clothfit.cli can be imported")


def _subcommands(parser):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {a.dest: a.help for a in action._choices_actions}
            return [(name, sub, helps.get(name)) for name, sub in action.choices.items()]
    return []


def _fence(text):
    return "```text\n" + text.rstrip("\n") + "\n```\n"


def render(parser=None):
    """The Markdown of the reference: the top-level usage, then one section per command."""
    parser = parser or _build_parser()
    os.environ.setdefault("COLUMNS", "100")
    out = ["## `clothfit`\n", _fence(parser.format_help())]
    for name, sub, summary in _subcommands(parser):
        out.append(f"## `{name}`\n")
        if summary:
            out.append(summary.strip() + "\n")
        out.append(_fence(sub.format_help()))
    return "\n".join(out)


def on_page_markdown(markdown, page, config, files):
    if MARKER not in markdown:
        return markdown
    return markdown.replace(MARKER, render())
