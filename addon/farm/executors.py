"""Workers that each hold one object built once (a Blender scene: ``addon.blender.scene_worker``) and
run its methods on batches: Ray actors (a local Ray instance started for the job and shut down
after it, or a running cluster by address) or, without Ray, a pool of spawned processes.

Neither this module nor the fitting process imports ``bpy``: a process spawned from one that has
imported ``bpy`` inherits Blender's script paths and cannot import it (``No module named '_bpy'``),
so ``check_driver`` refuses to start workers from such a process (e.g. Blender's own UI).

A host is named by ``"module:Class"`` and its constructor arguments; its methods are called by name.
A ``ClothFitError`` raised in a worker comes back as a ``ClothFitError`` in the driver, one line.
"""

from __future__ import annotations

import importlib
import os
import sys
import time

from ..core.errors import ClothFitError
from ..core.location import IMPORT_NAME, PACKAGE_DIR, PACKAGE_PARENT

MAX_RESTARTS = 3  # a Ray actor killed mid-job is restarted this many times (its task re-run)


def _package_for_upload() -> str:
    """The package folder Ray uploads to a remote cluster's workers, named as they import it: the
    folder itself, or (a checkout, where ``clothfit`` is mapped onto ``addon/``) a copy named
    :data:`IMPORT_NAME` in a temporary folder."""
    if os.path.basename(PACKAGE_DIR) == IMPORT_NAME:
        return PACKAGE_DIR
    import shutil
    import tempfile

    dst = os.path.join(tempfile.mkdtemp(prefix="clothfit_upload_"), IMPORT_NAME)
    shutil.copytree(PACKAGE_DIR, dst, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    return dst


def ray_available() -> bool:
    if os.environ.get("CLOTHFIT_NO_RAY") == "1":
        return False
    import importlib.util

    return importlib.util.find_spec("ray") is not None


def check_driver(what="Blender workers"):
    """Refuse to start ``what`` from a process that has imported bpy (one-line error)."""
    if "bpy" in sys.modules:
        raise ClothFitError(
            f"this process has imported bpy, so the {what} it would start could not import it "
            f"(No module named '_bpy'): run the fit from a process without bpy "
            f"(python -m clothfit fit ...), or connect to a running Ray cluster started outside Blender"
        )


def check_address(address, timeout=3.0):
    """A cluster address (``auto``, ``host:port``, ``ray://host:port``) whose port answers; else a
    one-line error (Ray itself waits minutes on an unreachable address)."""
    import socket

    if address == "auto":
        return
    hostport = address.split("://", 1)[-1]
    host, _, port = hostport.rpartition(":")
    if not host or not port.isdigit():
        raise ClothFitError(f"--address {address!r}: expected auto, host:port or ray://host:port")
    try:
        socket.create_connection((host, int(port)), timeout=timeout).close()
    except OSError as e:
        raise ClothFitError(f"cannot connect to the Ray cluster at {address}: {e.strerror or e}") from None


def default_workers() -> int:
    return max(1, os.cpu_count() or 1)


class _Host:
    """Holds one object built from ``factory`` ("module:Class") in a worker; calls its methods."""

    def __init__(self, factory, args):
        self.error = None
        self.obj = None
        try:
            mod, name = factory.split(":")
            self.obj = getattr(importlib.import_module(mod), name)(*args)
        except ClothFitError as e:
            self.error = str(e)

    def call(self, method, *args):
        if self.error is not None:
            return ("error", self.error)
        try:
            return ("ok", getattr(self.obj, method)(*args))
        except ClothFitError as e:
            return ("error", str(e))

    def pid(self):
        return os.getpid()

    def node_ip(self):
        import ray

        return ray.util.get_node_ip_address()


def _unwrap(r):
    tag, value = r
    if tag == "error":
        raise ClothFitError(value)
    return value


class Executor:
    """Common interface: ``map(method, arglist)`` runs ``host.method(*args)`` for every args tuple
    (in parallel across the workers) and returns the results in order; ``close()`` ends the workers."""

    kind = "none"
    workers = 0
    after_submit = None  # test hook: called with the executor after a batch is submitted

    def map(self, method, arglist):
        raise NotImplementedError

    def call_first(self, method, *args):
        return self.map(method, [args])[0]

    def pids(self):
        raise NotImplementedError

    def close(self):
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class RayExecutor(Executor):
    """One Ray actor per worker. ``address=None``: a local Ray instance on 127.0.0.1 with ``workers``
    CPUs, started here and shut down by ``close()``; else connect to that cluster (``auto`` or
    ``ray://host:port``) and leave it running. Actors are restarted when they die
    (``MAX_RESTARTS``) and their pending tasks re-run."""

    kind = "ray"

    def __init__(self, factory, args, workers=None, address=None):
        check_driver("Ray workers")
        loopback = not address or address.split("://", 1)[-1].rpartition(":")[0] in ("127.0.0.1", "localhost")
        if loopback and "ray" not in sys.modules:
            # Ray turns a node address of 127.0.0.1 into the machine's own network address unless it runs
            # as a single-machine instance (its Windows/macOS mode): keep a local instance on loopback only
            os.environ["RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"] = "0"
        import ray

        self.ray = ray
        self.address = address
        self.own = False
        self.workers = int(workers or default_workers())
        if self.workers < 1:
            raise ClothFitError(f"--workers {workers}: must be at least 1")
        t0 = time.perf_counter()
        if ray.is_initialized():
            self.own = False
        elif address:
            check_address(address)
            try:
                ray.init(
                    address=address,
                    include_dashboard=False,
                    log_to_driver=False,
                    runtime_env={"py_modules": [_package_for_upload()]},
                )
            except Exception as e:  # ConnectionError, TimeoutError, ValueError... from Ray
                msg = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
                raise ClothFitError(f"cannot connect to the Ray cluster at {address}: {msg}") from None
        else:
            old = os.environ.get("PYTHONPATH")
            os.environ["PYTHONPATH"] = PACKAGE_PARENT + (os.pathsep + old if old else "")
            os.environ.setdefault("RAY_AUTH_MODE", "disabled")
            kw = {"_temp_dir": os.environ["CLOTHFIT_RAY_TMPDIR"]} if os.environ.get("CLOTHFIT_RAY_TMPDIR") else {}
            try:
                ray.init(
                    num_cpus=self.workers,
                    include_dashboard=False,
                    _node_ip_address="127.0.0.1",
                    log_to_driver=False,
                    configure_logging=True,
                    logging_level="ERROR",
                    **kw,
                )
            finally:
                if old is None:
                    os.environ.pop("PYTHONPATH", None)
                else:
                    os.environ["PYTHONPATH"] = old
            self.own = True
        self.startup_s = time.perf_counter() - t0
        Actor = ray.remote(num_cpus=1, max_restarts=MAX_RESTARTS, max_task_retries=MAX_RESTARTS)(_Host)
        self.actors = [Actor.remote(factory, tuple(args)) for _ in range(self.workers)]

    def map(self, method, arglist):
        refs = [self.actors[i % self.workers].call.remote(method, *a) for i, a in enumerate(arglist)]
        if self.after_submit is not None:
            self.after_submit(self)
        try:
            out = self.ray.get(refs)
        except self.ray.exceptions.RayActorError as e:
            raise ClothFitError(
                f"a Ray worker died {MAX_RESTARTS + 1} times ({type(e).__name__}): "
                f"the fit stops, the best result so far is kept"
            ) from None
        return [_unwrap(r) for r in out]

    def pids(self):
        return self.ray.get([a.pid.remote() for a in self.actors])

    def node_ips(self):
        """The address every worker and the driver (last) use as their node's: 127.0.0.1 locally."""
        return self.ray.get([a.node_ip.remote() for a in self.actors]) + [self.ray.util.get_node_ip_address()]

    def close(self):
        if self.ray is None:
            return
        for a in getattr(self, "actors", []):
            try:
                self.ray.kill(a)
            except Exception:
                pass
        self.actors = []
        if self.own and self.ray.is_initialized():
            self.ray.shutdown()
        self.ray = None


# ------------------------------------------------------------------- the pool without Ray

_HOST = None


def _pool_init(factory, args):
    global _HOST
    _HOST = _Host(factory, args)


def _pool_call(method, args):
    return _HOST.call(method, *args)


def _pool_pid(_=None):
    time.sleep(0.2)  # so that each process of the pool answers once
    return os.getpid()


class ProcessExecutor(Executor):
    """``workers`` processes started with 'spawn' (fresh interpreters: no state of the driver), each
    building the host once. A process that dies breaks the pool: it is started again once and the
    batch re-run; a second death is a one-line error."""

    kind = "process"

    def __init__(self, factory, args, workers=None):
        check_driver("worker processes")
        self.factory, self.args = factory, tuple(args)
        self.workers = int(workers or default_workers())
        if self.workers < 1:
            raise ClothFitError(f"--workers {workers}: must be at least 1")
        t0 = time.perf_counter()
        self._start()
        self.startup_s = time.perf_counter() - t0

    def _start(self):
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        env_old = os.environ.get("PYTHONPATH")
        os.environ["PYTHONPATH"] = PACKAGE_PARENT + (os.pathsep + env_old if env_old else "")
        try:
            self.pool = ProcessPoolExecutor(
                self.workers,
                mp_context=mp.get_context("spawn"),
                initializer=_pool_init,
                initargs=(self.factory, self.args),
            )
            # start every process now (the scenes load in parallel, before the first batch)
            list(self.pool.map(_pool_pid, range(self.workers)))
        finally:
            if env_old is None:
                os.environ.pop("PYTHONPATH", None)
            else:
                os.environ["PYTHONPATH"] = env_old

    def map(self, method, arglist):
        from concurrent.futures.process import BrokenProcessPool

        for attempt in range(2):
            try:
                futs = [self.pool.submit(_pool_call, method, tuple(a)) for a in arglist]
                if self.after_submit is not None and attempt == 0:
                    self.after_submit(self)
                return [_unwrap(f.result()) for f in futs]
            except BrokenProcessPool:
                self.pool.shutdown(wait=False, cancel_futures=True)
                if attempt:
                    break
                self._start()
        raise ClothFitError("a worker process died twice in one batch: the fit stops, the best result so far is kept")

    def pids(self):
        return sorted(p.pid for p in self.pool._processes.values())

    def close(self):
        if getattr(self, "pool", None) is not None:
            self.pool.shutdown(wait=True, cancel_futures=True)
            self.pool = None


EXECUTORS = ("auto", "ray", "process")


def make_executor(factory, args, workers=None, address=None, kind="auto") -> Executor:
    """Ray when importable (or asked for), else the spawned process pool; ``address`` needs Ray."""
    if kind not in EXECUTORS:
        raise ClothFitError(f"unknown executor {kind!r}: choose one of {', '.join(EXECUTORS)}")
    if kind == "auto":
        kind = "ray" if (ray_available() or address) else "process"
    if kind == "ray":
        if not ray_available():
            raise ClothFitError("Ray is not installed (pip install ray): use --executor process, or install it")
        return RayExecutor(factory, args, workers, address)
    if address:
        raise ClothFitError("--address needs Ray (--executor ray)")
    return ProcessExecutor(factory, args, workers)
