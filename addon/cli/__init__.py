"""Command line: ``clothfit <command> ...`` (the console script; ``python -m clothfit`` is the same).

No Blender needed except for ``blender`` and ``blender-agreement`` (the bpy module). The habits of
every command (``EPILOG``, also at the end of ``--help``): stdout carries one JSON document, the
command's result, and nothing else; messages for people (progress, tables, "wrote ...") go to
stderr. Exit codes: 0 done, 1 an unexpected failure, 2 bad data (a ClothFitError: one line naming
the file or value, never a traceback), 64 a command line the parser rejects, 130 Ctrl-C (a fit
keeps and reports its best result first).

The package: ``common.py`` (the habits above, the parser, shared options, the run-and-report path),
one module per command family that registers its commands (``fitting``, ``studies``, ``footage``,
``blender``), and here ``build_parser`` (the docs' CLI reference reads it) and ``main``.
"""

from __future__ import annotations

import os
import re
import sys

from ..core.errors import ClothFitError
from . import blender, fitting, footage, studies
from .common import (  # noqa: F401
    DEBUG_ENV,
    EPILOG,
    EXIT_BAD_DATA,
    EXIT_FAILURE,
    EXIT_INTERRUPTED,
    EXIT_USAGE,
    PROG,
    ArgumentParser,
    HelpFormatter,
    Interrupted,
    Text,
    emit,
    messages_to_stderr,
    one_line,
)

__all__ = [
    "build_parser",
    "main",
    "emit",
    "messages_to_stderr",
    "EXIT_FAILURE",
    "EXIT_BAD_DATA",
    "EXIT_USAGE",
    "EXIT_INTERRUPTED",
    "DEBUG_ENV",
    "PROG",
]


def build_parser():
    """The whole command line: every family's commands, in the order ``--help`` lists them."""
    from .. import version

    p = ArgumentParser(
        prog=PROG, description="Silhouette Cloth Fit: cloth parameters from multi-view silhouettes.", epilog=EPILOG
    )
    p.add_argument("--version", action="version", version=f"%(prog)s {version()}")
    sub = p.add_subparsers(dest="cmd", required=True, metavar="COMMAND")
    for family in (fitting, studies, footage, blender):  # the order of the command list in --help
        family.register(sub)
    return p


_NUMBER_LIST = re.compile(r"^-[0-9.]+(?:[eE][-+]?[0-9]+)?(?:,\s*-?[0-9.]+(?:[eE][-+]?[0-9]+)?)+$")


def attach_number_lists(argv: list) -> list:
    """``--times -0.15,-0.05,0.1`` -> ``--times=-0.15,-0.05,0.1``: argparse reads a value that starts with a
    minus sign and is no single number as an option (frames before the release have negative times)."""
    out = []
    for a in argv:
        prev = out[-1] if out else ""
        if _NUMBER_LIST.match(a) and prev.startswith("--") and "=" not in prev:
            out[-1] = f"{prev}={a}"
        else:
            out.append(a)
    return out


def main(argv=None):
    """Run a command (see ``EPILOG`` for stdout and the exit codes). Bad input: one line
    ``error: ...`` and exit code 2; a command line the parser rejects: its usage and exit code 64;
    any other failure: one line naming it and exit code 1 (the traceback only with the environment
    variable CLOTHFIT_DEBUG=1); Ctrl-C: one line and exit code 130."""
    argv = attach_number_lists(sys.argv[1:] if argv is None else [str(x) for x in argv])
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as e:  # --help / --version (0) or a usage error (64)
        return e.code if isinstance(e.code, int) else EXIT_USAGE
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    result, code = None, 0
    try:
        with messages_to_stderr():
            result = args.fn(args)
    except Interrupted as e:
        print(f"interrupted: {one_line(e)}", file=sys.stderr)
        result, code = e.result, EXIT_INTERRUPTED
    except KeyboardInterrupt:
        print(f"interrupted: {args.cmd} stopped", file=sys.stderr)
        return EXIT_INTERRUPTED
    except ClothFitError as e:
        print(f"error: {one_line(e)}", file=sys.stderr)
        return EXIT_BAD_DATA
    except Exception as e:  # noqa: BLE001 - the last line of defence: never a traceback for the user
        if os.environ.get(DEBUG_ENV):
            raise
        print(
            f"error: {args.cmd} failed: {type(e).__name__}: {one_line(e) or 'no message'} "
            f"(set {DEBUG_ENV}=1 for the traceback)",
            file=sys.stderr,
        )
        return EXIT_FAILURE
    try:
        emit(result)
    except BrokenPipeError:  # the reader went away (| head): nothing more to say
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    return code
