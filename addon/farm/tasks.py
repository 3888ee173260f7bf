"""Many independent fits on the same workers (``python -m addon fit-many CAPTURE...``): Ray actors
(a local instance or a cluster by ``--address``) or spawned processes without Ray. Each fit is the
one ``python -m addon fit`` runs (``FitJob`` with the same config and seed), so the results are
identical to local runs; the results come back to the driver, which writes them."""
from __future__ import annotations

import os
import time

from .executors import make_executor

RUNNER = "addon.farm.tasks:FitRunner"


class FitRunner:
    """Worker side: one fit per call."""

    def fit(self, capture_path, config: dict) -> dict:
        from ..core.fitting.job import FitConfig, FitJob
        from ..core.observation.capture import load_capture
        t0 = time.perf_counter()
        job = FitJob(load_capture(capture_path), FitConfig.from_dict(config))
        res = job.run()
        res["worker_pid"] = os.getpid()
        res["worker_wall_s"] = time.perf_counter() - t0
        return res


def fit_many(captures, configs, workers=None, address=None, executor="auto"):
    """Fit every capture with its ``FitConfig`` dict on the workers: (results in order, executor kind,
    number of workers)."""
    with make_executor(RUNNER, (), workers, address, executor) as ex:
        res = ex.map("fit", [(os.path.abspath(c), dict(cfg)) for c, cfg in zip(captures, configs)])
        return res, ex.kind, ex.workers
