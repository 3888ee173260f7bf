"""What a running fit shows while it runs: one formatter for the terminal's progress bar and for the
plain lines written where stderr is no terminal (a log, a pipe, a worker of ``fit-many``).

A line holds the evaluations done against the budget, the best training error so far, the fitted
model's own free settings by name (the paper's sheet: k, l, d; Blender's cloth: the ClothSettings
searched, e.g. tension, shear, bending, air damping), the time spent and the time left at the
evaluation rate so far (the budget's end: a fit that converges stops sooner).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

from .. import defaults as D


def duration_text(seconds: float) -> str:
    """``"45 s"``, ``"3 min 10 s"``, ``"2 h 05 min"``; ``"?"`` when unknown."""
    if not math.isfinite(seconds) or seconds < 0:
        return "?"
    s = int(round(seconds))
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60:02d} s"
    return f"{s // 3600} h {s % 3600 // 60:02d} min"


def free_settings(job: Any) -> dict[str, float]:
    """The best values so far of what the fit searches, by name: the paper model's k, l, d (m is fixed),
    or the Blender cloth settings in ``free`` ("_stiffness" left off: tension, shear, bending...)."""
    best = job.best_params
    if not best:
        return {}
    free = getattr(job.par, "free", None)
    if free is None:  # the paper's sheet
        return {k: float(v) for k, v in best.items() if k != "m"}
    return {n.replace("_stiffness", ""): float(best[n]) for n in free if n in best}


def progress_line(job: Any, seconds: float, rate: float) -> str:
    """One line: evaluations / budget, best E_sil per training image, the time spent (``seconds``) and
    the time left at ``rate`` evaluations per second, then the free settings by name."""
    n, budget = int(job.evaluations), int(getattr(job, "budget", job.config.max_evaluations))
    best = job.best_error
    err = f"{100 * best / job.objective.n_images:.3f} %" if math.isfinite(best) else "none yet"
    settings = " ".join(f"{k} {v:.4g}" for k, v in free_settings(job).items())
    left = 0.0 if job.state.finished else (budget - n) / rate if rate > 0 else math.nan
    text = f"{n}/{budget} evaluations, E_sil {err}, {duration_text(seconds)} spent, {duration_text(left)} left"
    return text + (f": {settings}" if settings else "")


class FitProgress:
    """A ``FitJob.run`` callback that reports progress through ``write`` (e.g. ``sys.stderr.write``).
    ``bar``: one terminal line redrawn (``\\r``) at most every ``D.PROGRESS_BAR_REFRESH_S``, cut to
    ``columns`` (the terminal's width) when given; else a whole line after the first generation, then
    one every ``interval`` seconds. Each is prefixed with ``label``. ``start``: the evaluations done
    before (a resumed fit: the rate counts this session's only). ``done(job)`` writes the last state.
    Never asks the job to stop."""

    def __init__(
        self,
        write: Callable[[str], Any],
        bar: bool,
        interval: float = D.PROGRESS_INTERVAL_S,
        label: str = "",
        width: int = 12,
        start: int = 0,
        columns: int | None = None,
        clock: Callable[[], float] = time.monotonic,
    ):
        self.write, self.bar, self.interval, self.label, self.width = write, bar, float(interval), label, width
        self.n0, self.columns, self.clock = int(start), columns, clock
        self.t0 = self.last = clock()
        self.shown = False

    def line(self, job: Any) -> str:
        spent = self.clock() - self.t0
        rate = (int(job.evaluations) - self.n0) / spent if spent > 0 else 0.0
        return progress_line(job, spent, rate)

    def __call__(self, job: Any) -> bool:
        now = self.clock()
        if self.shown and now - self.last < (D.PROGRESS_BAR_REFRESH_S if self.bar else self.interval):
            return False  # (the first generation is always shown: a first sign of life)
        self.last = now
        self._show(job)
        return False

    def _show(self, job: Any) -> None:
        self.shown = True
        text = self.line(job)
        if not self.bar:
            self.write(f"{self.label}{text}\n")
            return
        n = int(self.width * job.progress)
        shown = f"{self.label}[{'#' * n}{'.' * (self.width - n)}] {text}"
        if self.columns:  # one terminal line, or the carriage return cannot redraw it
            shown = shown[: self.columns - 1].ljust(self.columns - 1)
        self.write(f"\r{shown}")

    def done(self, job: Any = None) -> None:
        """The last state (when a job is given), and the bar's line ended."""
        if job is not None and job.evaluations:
            self._show(job)
        if self.bar:
            self.write("\n")


def run_shown(job: Any, progress: Callable[[str], FitProgress] | None = None, label: str = "") -> Any:
    """``job.run()`` with its progress shown by ``progress(label)`` (a :class:`FitProgress` maker; the
    studies' fits: the paper protocol, the bench) when given. Returns the job's result."""
    shown = progress(label) if progress is not None else None
    try:
        return job.run(callback=shown)
    finally:
        if shown is not None:
            shown.done(job)
