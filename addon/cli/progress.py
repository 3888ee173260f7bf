"""A fit's progress on stderr for the commands that run fits (``fit``, ``fit-many``): the core's one
formatter (``core.fitting.progress``) as a bar on a terminal (or with ``CLOTHFIT_PROGRESS=1``), else as
a plain line at least every ``defaults.PROGRESS_INTERVAL_S`` seconds (``CLOTHFIT_PROGRESS_INTERVAL``
overrides it, e.g. for a test); nothing with ``--quiet``."""

from __future__ import annotations

import math
import os
import shutil
import sys

from ..core import defaults as D
from ..core.errors import ClothFitError
from ..core.fitting.progress import FitProgress


def write_stderr(text: str) -> None:
    sys.stderr.write(text)
    sys.stderr.flush()


def progress_interval() -> float:
    """Seconds between two plain progress lines: ``CLOTHFIT_PROGRESS_INTERVAL`` if set, else the default."""
    text = os.environ.get("CLOTHFIT_PROGRESS_INTERVAL", "").strip()
    if not text:
        return D.PROGRESS_INTERVAL_S
    try:
        v = float(text)
    except ValueError:
        v = math.nan
    if not (math.isfinite(v) and v >= 0):
        raise ClothFitError(f"CLOTHFIT_PROGRESS_INTERVAL={text}: give a number of seconds >= 0")
    return v


def fit_progress(job, quiet: bool) -> FitProgress | None:
    """The progress of ``fit``'s job on stderr (None with ``--quiet``)."""
    if quiet:
        return None
    bar = sys.stderr.isatty() or os.environ.get("CLOTHFIT_PROGRESS") == "1"
    columns = None
    if bar:
        try:
            columns = os.get_terminal_size(sys.stderr.fileno()).columns
        except (OSError, ValueError):
            columns = shutil.get_terminal_size((100, 24)).columns
    return FitProgress(write_stderr, bar, progress_interval(), start=job.evaluations, columns=columns)


def study_progress():
    """For the commands that run many fits (``paper``, ``bench``): ``maker(label)`` -> a plain progress line
    of each fit, prefixed with its label, at least every ``progress_interval()`` seconds."""
    every = progress_interval()

    def maker(label: str) -> FitProgress:
        return FitProgress(write_stderr, False, every, f"{label}: ")

    return maker
