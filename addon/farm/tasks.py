"""Many independent fits on the same workers (``python -m clothfit fit-many CAPTURE...``): Ray actors
(a local instance or a cluster by ``--address``) or spawned processes without Ray. Each fit is the
one ``python -m clothfit fit`` runs (``FitJob`` with the same config and seed), so the results are
identical to local runs; the results come back to the driver, which writes them."""

from __future__ import annotations

import os
import sys
import time

from ..core.location import qualified
from .executors import make_executor

RUNNER = qualified("farm.tasks:FitRunner")


class FitRunner:
    """Worker side: one fit per call."""

    def fit(self, capture_path, config: dict, progress: dict | None = None) -> dict:
        """``progress``: {"interval": seconds, "label": text}: a progress line on this worker's stderr
        at least that often, prefixed with the label (``core.fitting.progress``); None: quiet."""
        from ..core.fitting.job import FitConfig, FitJob
        from ..core.fitting.progress import FitProgress
        from ..core.observation.capture import load_capture

        t0 = time.perf_counter()
        job = FitJob(load_capture(capture_path), FitConfig.from_dict(config))
        shown = None
        if progress is not None:
            shown = FitProgress(_write_stderr, False, float(progress["interval"]), f"{progress['label']}: ")
        res = job.run(callback=shown)
        if shown is not None:
            shown.done(job)
        res["worker_pid"] = os.getpid()
        res["worker_wall_s"] = time.perf_counter() - t0
        return res


def _write_stderr(text):
    sys.stderr.write(text)
    sys.stderr.flush()


def fit_many(captures, configs, workers=None, address=None, executor="auto", progress_interval=None):
    """Fit every capture with its ``FitConfig`` dict on the workers: (results in order, executor kind,
    number of workers). ``progress_interval``: seconds between each fit's progress lines on the
    workers' stderr (None: none)."""
    args = []
    for c, cfg in zip(captures, configs):
        shown = None if progress_interval is None else {"interval": progress_interval, "label": c}
        args.append((os.path.abspath(c), dict(cfg), shown))
    with make_executor(RUNNER, (), workers, address, executor) as ex:
        res = ex.map("fit", args)
        return res, ex.kind, ex.workers


PAPER_RUNNER = qualified("farm.tasks:PaperRunner")
PAPER_PARTS = ("table1", "fig8", "table2", "optimizers")
PART_KEYS = {
    "table1": ("table1", "identifiable"),
    "fig8": ("fig8",),
    "table2": ("table2",),
    "optimizers": ("optimizers",),
}


class PaperRunner:
    """Worker side: one part of the paper protocol (its own capture, synthesised from the seed)."""

    def part(self, part, out_dir, kwargs: dict) -> dict:
        import contextlib
        import io

        from ..core.studies.experiment import run_paper

        sub = os.path.join(out_dir, f"part_{part}")
        with contextlib.redirect_stdout(io.StringIO()):
            res = run_paper(os.path.join(sub, "paper.json"), out_dir=sub, only=part, **kwargs)
        res["worker_pid"] = os.getpid()
        return res


def paper_parts(parts, out_dir, kwargs, workers=None, address=None, executor="auto"):
    """The paper protocol's parts run in parallel on the workers, merged into one result (each part
    is the local run's ``paper --only PART`` with the same seed: the same numbers)."""
    t0 = time.perf_counter()
    with make_executor(PAPER_RUNNER, (), workers, address, executor) as ex:
        res = ex.map("part", [(p, os.path.abspath(out_dir), dict(kwargs)) for p in parts])
        kind, n = ex.kind, ex.workers
    out = {k: v for k, v in res[0].items() if k not in sum(PART_KEYS.values(), ()) + ("total_seconds", "worker_pid")}
    for p, r in zip(parts, res):
        for k in PART_KEYS[p]:
            if k in r:
                out[k] = r[k]
    out["parts"] = {
        p: {"seconds": r.get("total_seconds"), "worker_pid": r.get("worker_pid")} for p, r in zip(parts, res)
    }
    out["executor"], out["workers"] = kind, n
    out["total_seconds"] = time.perf_counter() - t0
    return out
