"""A fit's checkpoint (format v3): writing it, reading it back field by field, resuming a job from it.

A checkpoint records what it is a fit of (``identity``: a hash of the capture's cameras, frame
times and the training silhouettes; cameras, times, resolution, model, optimiser, population,
seed, bounds...), the optimiser's state, the fit's stages and the result so far. ``resume``
refuses a checkpoint whose identity differs from the job asked for, naming the differing fields;
only the budget (``max_evaluations``) and the target may change. Checkpoints hold plain numbers
only (no pickle) and are checked field by field when read (one-line ``ClothFitError``).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from dataclasses import asdict
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import ClothFitError
from ..jsonio import dumps, plain, write_json
from .optimise import optimizer_from_state
from .quality import Ladder
from .run_state import OUTCOME_FIELDS, STOP_REASONS, FitShape, RunState

if TYPE_CHECKING:
    from collections.abc import Sequence

    from numpy.typing import ArrayLike

    from ..observation.capture import Capture
    from .job import FitConfig, FitJob

CHECKPOINT_FORMAT = "silhouette-cloth-fit/checkpoint"
CHECKPOINT_VERSION = 3  # 3: the fit's stages (quality ladder, manipulation profile)
CHECKPOINT_KEYS = (
    "format",
    "version",
    "identity",
    "config",
    "capture",
    "optimizer_state",
    "stages",
    *OUTCOME_FIELDS,
    "result",
)
MAX_CHECKPOINT_BYTES = 64 * 1024 * 1024


def capture_hash(capture: Capture) -> str:
    """sha256 of a capture's cameras (name, size, K, R, t, dist), frame times and scenario."""
    return hashlib.sha256(
        dumps(
            {
                "cameras": [c.to_dict() for c in capture.cameras],
                "frame_times": [float(t) for t in capture.frame_times],
                "scenario": capture.scenario.to_dict(),
            },
            indent=None,
            sort_keys=True,
        ).encode()
    ).hexdigest()


def silhouettes_hash(
    observed: Sequence[Sequence[ArrayLike]], ignore: Sequence[Sequence[ArrayLike | None]] | None = None
) -> str:
    """sha256 of the training silhouettes and their ignore masks (as fitted), in order."""
    h = hashlib.sha256()
    for c, oc in enumerate(observed):
        for f, o in enumerate(oc):
            masks = [o]
            g = None if ignore is None else ignore[c][f]
            masks.append(g)
            for m in masks:
                if m is None:
                    h.update(b"none")
                    continue
                m = np.asarray(m, dtype=bool)
                h.update(np.asarray(m.shape, dtype=np.int64).tobytes())
                h.update(np.packbits(m).tobytes())
    return h.hexdigest()


def _int_attr(opt, name):
    """An optimiser's size setting (``popsize``, ``children``...) when it is a number, else None (the
    portfolio's ``children`` are its CMA-ES runs)."""
    v = getattr(opt, name, None)
    return int(v) if isinstance(v, (int, np.integer)) and not isinstance(v, bool) else None


def identity(job: FitJob) -> dict[str, Any]:
    """What this job is a fit of: a checkpoint is only resumed by a job with the same identity."""
    opt = job.opt if job.state.stage == "search" else job.main_optimizer()
    ident = {
        "capture_hash": job.capture_hash,
        "silhouettes_hash": job.silhouettes_hash,
        "cameras": [job.capture.cameras[c].name for c in job.train_cameras],
        "camera_indices": list(job.train_cameras),
        "times": list(job.train_times),
        "resolution": None if job.config.resolution is None else [int(x) for x in job.config.resolution],
        "model": job.model_at(job.start_quality).to_dict(),
        "fixed": None
        if getattr(job.par, "fixed", None) is None
        else dict(job.par.fixed, quality=job.start_quality or job.par.fixed.get("quality")),
        "mass": float(job.m),
        "optimizer": job.optimizer_name,
        "population": int(getattr(opt, "popsize", getattr(opt, "population", 0))),
        "children": _int_attr(opt, "children"),
        "restarts": _int_attr(opt, "restarts"),
        "seed": int(job.config.seed),
        "bounds": job.space.state_dict(),
        "initial": None if job.par.initial is None else np.asarray(job.par.initial).tolist(),
        "quality_ladder": None
        if job.ladder is None
        else {"start": job.ladder.start, "probe_only": job.ladder.probe_only},
        "scene": None
        if job.evaluator is None
        else {
            "blend": os.path.abspath(job.config.blend) if job.config.blend else None,
            "object": job.config.blend_object,
            "frame_zero": job.config.frame_zero,
        },
    }
    if len(job.takes) > 1:  # several takes: each one's capture, images, cameras and times
        ident["takes"] = [
            {
                "capture_hash": t.capture_hash,
                "silhouettes_hash": t.silhouettes_hash,
                "cameras": [t.capture.cameras[c].name for c in t.train_cameras],
                "times": list(t.train_times),
            }
            for t in job.takes
        ]
    if job.config.search_options():  # only when set: a checkpoint from before them resumes
        ident["search_options"] = job.config.search_options()
    return plain(ident)


def load_stages(job: FitJob, st: Any, outcome: dict[str, Any], path: str | os.PathLike) -> None:
    """A checkpoint's stages and outcome into ``job.state`` (``RunState.from_saved``: checked field by field,
    one-line errors), with the quality ladder's saved state checked against the job's ladder."""
    shape = FitShape(
        n=job.space.n,
        manip_names=None if job.manip is None else tuple(job.manip.names),
        ladder=job.ladder,
        intervals_planned=job.intervals_note is None,
        n_takes=len(job.takes),
    )
    state, saved_ladder = RunState.from_saved(st, outcome, shape, os.fspath(path))

    def bad(what):
        return ClothFitError(f"checkpoint {path}: bad 'stages' ({what})")

    ladder = None if saved_ladder is None else Ladder.from_state(saved_ladder)
    if ladder is not None and (
        not isinstance(saved_ladder, dict)
        or ladder.start != job.ladder.start
        or ladder.probe_only != job.ladder.probe_only
        or any(not ladder.allows(q) for q in ladder.tried)
    ):
        raise bad("quality ladder")
    if state.stage == "rung" and (ladder is None or not ladder.allows(state.stage_quality)):
        raise bad("a rung outside the ladder")
    if state.stage == "search":  # the search's end follows the budget asked for now (a search again's: from its start)
        again = state.again or {}
        state.stage_end = again["start"] + job.search_end if again.get("searches") else job.state.stage_end
    if ladder is not None and state.stage_quality is not None and not ladder.allows(state.stage_quality):
        raise bad("stage_quality outside the ladder")
    job.state, job.alone_opt = state, None
    if ladder is not None:
        job.ladder = ladder
    if state.stage_quality is not None:
        job.activate(state.stage_quality)


def reopen_search(job: FitJob) -> None:
    """A search that stopped on its budget and was followed by nothing but its profile continues
    when resumed with a larger budget (the profile is made again at its new end)."""
    s = job.state
    last = s.records[-1] if s.records else None
    if not (
        s.stage in ("done", "profile")
        and last
        and last["stage"] == "search"
        and last["stop"] == "budget"
        and len(s.records) == 1
        and job.config.max_evaluations > job.evaluations
    ):
        return
    quality = s.stage_quality
    s.reopen_search(job.search_end)
    if job.ladder is not None:
        job.ladder.tried.pop(quality, None)
        if quality in job.ladder.order:
            job.ladder.order.remove(quality)


def checkpoint_dict(job: FitJob) -> dict[str, Any]:
    """A job's checkpoint (format v3): what it is a fit of, its optimiser and stages, its result so far."""
    ck = {
        "format": CHECKPOINT_FORMAT,
        "version": CHECKPOINT_VERSION,
        "identity": job.identity(),
        "config": asdict(job.config),
        "capture": os.path.abspath(job.capture.root),
        "optimizer_state": job.opt.state_dict(),
        "stages": job.state.saved_stages(
            None if job.ladder is None else job.ladder.state_dict(),
            None if job.alone_opt is None else job.alone_opt.state_dict(),
        ),
        **job.state.saved_outcome(),
        "result": job.result(),
    }
    if len(job.takes) > 1:  # several takes: every take's capture (the first is also "capture")
        ck["takes"] = [os.path.abspath(t.capture.root) for t in job.takes]
    return ck


def write_checkpoint(path: str | os.PathLike, ck: dict[str, Any]) -> None:
    """Checkpoints and results: strict JSON (no NaN), written atomically (``jsonio.write_json``)."""
    write_json(path, ck, strict=True)


def resume(
    cls: type[FitJob],
    config_type: type[FitConfig],
    path: str | os.PathLike,
    capture: Capture | None = None,
    config: FitConfig | None = None,
    checkpoint_interval: float = 0.0,
    evaluator: Any = None,
) -> FitJob:
    """Continue a job from its checkpoint. ``config`` is the fit asked for now (default: the
    checkpoint's own); a checkpoint of another fit (another capture, cameras, times, resolution,
    model, optimiser, population, seed, bounds...) is refused naming the differing fields. The
    budget (``max_evaluations``) and the target may differ. ``evaluator``: the workers of a
    Blender-scene fit."""
    from ..observation.capture import load_capture

    ck = read_checkpoint(path)
    saved_cfg = config_type.from_dict(ck["config"])
    if config is None:
        config = saved_cfg
    if capture is not None:
        cap = capture
    elif "takes" in ck:
        cap = [load_capture(p) for p in ck["takes"]]
    else:
        cap = load_capture(ck["capture"])
    job = cls(cap, config, checkpoint=path, checkpoint_interval=checkpoint_interval, evaluator=evaluator)
    diff = identity_diff(ck["identity"], job.identity())
    if diff:
        names = list(dict.fromkeys(d.split(":")[0].split(".")[0] for d in diff))
        raise ClothFitError(
            f"checkpoint {path} is of another fit: {', '.join(names)} differ "
            f"({'; '.join(diff)}); resume with the same capture and options, or start afresh "
            f"with --force or another --out"
        )
    opt = optimizer_from_state(ck["optimizer_state"])
    load_stages(job, ck["stages"], ck, path)
    recs = job.state.records
    # after the searches alone (no rung), the stages that follow keep the last search's optimiser
    main = job.state.stage == "search" or (
        job.state.stage in ("done", "profile", "intervals") and bool(recs) and all(r["stage"] == "search" for r in recs)
    )
    # a search again's optimiser has its own seed (a rung's keeps the fit's)
    ref = job.main_optimizer() if main and (job.state.again or {}).get("searches") else job.opt
    mine = (
        type(ref),
        ref.space.state_dict(),
        ref.seed,
        _int_attr(ref, "popsize"),
        _int_attr(ref, "population"),
        _int_attr(ref, "children"),
        _int_attr(ref, "restarts"),
    )
    theirs = (
        type(opt),
        opt.space.state_dict(),
        opt.seed,
        _int_attr(opt, "popsize"),
        _int_attr(opt, "population"),
        _int_attr(opt, "children"),
        _int_attr(opt, "restarts"),
    )
    if main:
        same = mine == theirs
    else:  # a rung's optimiser: a warm-started one of the same space (job.rung_optimizer_name)
        same = opt.name == job.rung_optimizer_name() and mine[1:3] == theirs[1:3]
    if not same:
        raise ClothFitError(
            f"checkpoint {path}: its optimiser state does not match its recorded fit "
            f"(optimiser, bounds, seed or population differ)"
        )
    job.opt = opt
    reopen_search(job)
    job.update_stop()
    if job.state.finished:
        job.finalise()
    return job


def identity_diff(saved: Any, now: dict[str, Any]) -> list[str]:
    """Human-readable differences between two ``identity()`` dicts."""
    if not isinstance(saved, dict):
        return ["it records no identity"]
    out = []
    keys = sorted(set(saved) | set(now))
    differ = {k for k in keys if saved.get(k, "<missing>") != now.get(k, "<missing>")}
    if differ & {"cameras", "camera_indices", "times", "capture_hash"}:
        differ.discard("silhouettes_hash")  # other images, of course
    if "cameras" in differ:
        differ.discard("camera_indices")
    for k in keys:
        if k not in differ:
            continue
        a, b = saved.get(k, "<missing>"), now.get(k, "<missing>")
        if isinstance(a, dict) and isinstance(b, dict):  # name the entries that differ
            for sub in sorted(set(a) | set(b), key=str):
                if a.get(sub, "<missing>") != b.get(sub, "<missing>"):
                    out.append(
                        f"{k}.{sub}: checkpoint {_short(a.get(sub, '<missing>'), 40)}, "
                        f"now {_short(b.get(sub, '<missing>'), 40)}"
                    )
        else:
            out.append(f"{k}: checkpoint {_short(a, 40)}, now {_short(b, 40)}")
    return out


def _short(v, limit=80):
    s = json.dumps(v, default=str) if not isinstance(v, str) else v
    return s if len(s) <= limit else s[: limit - 3] + "..."


def read_checkpoint(path: str | os.PathLike) -> dict[str, Any]:
    """A checkpoint's JSON, checked at the top level (the optimiser state is checked by the optimiser)."""
    path = os.fspath(path)
    try:
        if os.path.isdir(path):
            raise ClothFitError(f"checkpoint {path} is a directory")
        with open(path, "rb") as f:
            raw = f.read(MAX_CHECKPOINT_BYTES + 1)
    except FileNotFoundError:
        raise ClothFitError(f"checkpoint not found: {path}") from None
    except OSError as e:
        raise ClothFitError(f"checkpoint {path}: cannot read it ({e.strerror or e})") from None
    if len(raw) > MAX_CHECKPOINT_BYTES:
        raise ClothFitError(f"checkpoint {path} is larger than {MAX_CHECKPOINT_BYTES} bytes: not a checkpoint")
    try:
        ck = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as e:
        raise ClothFitError(f"checkpoint {path} is corrupt: {str(e).splitlines()[0]}") from None
    if not isinstance(ck, dict):
        raise ClothFitError(f"checkpoint {path} is corrupt: expected a JSON object")
    if ck.get("format") != CHECKPOINT_FORMAT:
        raise ClothFitError(
            f"checkpoint {path}: 'format' is {ck.get('format')!r}, expected {CHECKPOINT_FORMAT!r} "
            f"(a checkpoint of an older version cannot be resumed: start afresh with --force)"
        )
    if ck.get("version") != CHECKPOINT_VERSION:
        raise ClothFitError(
            f"checkpoint {path}: version {ck.get('version')!r} is not supported "
            f"(this reader knows version {CHECKPOINT_VERSION})"
        )
    unknown = sorted(set(ck) - set(CHECKPOINT_KEYS) - {"takes"})
    missing = [k for k in CHECKPOINT_KEYS if k not in ck]
    if unknown or missing:
        raise ClothFitError(
            f"checkpoint {path}: "
            + ", ".join(
                x
                for x in (
                    f"unknown fields {unknown}" if unknown else "",
                    f"missing fields {missing}" if missing else "",
                )
                if x
            )
        )
    for k in ("identity", "config", "optimizer_state"):
        if not isinstance(ck[k], dict):
            raise ClothFitError(f"checkpoint {path}: '{k}' must be an object")
    if not isinstance(ck["capture"], str) or not ck["capture"]:
        raise ClothFitError(f"checkpoint {path}: 'capture' must be a path")
    t = ck.get("takes")
    if "takes" in ck and (not isinstance(t, list) or len(t) < 2 or not all(isinstance(p, str) and p for p in t)):
        raise ClothFitError(f"checkpoint {path}: 'takes' must be a list of two or more capture paths")
    e = ck["elapsed"]
    if isinstance(e, bool) or not isinstance(e, (int, float)) or not math.isfinite(e) or e < 0:
        raise ClothFitError(f"checkpoint {path}: 'elapsed' must be a number >= 0")
    x = ck["exploded"]
    if isinstance(x, bool) or not isinstance(x, int) or x < 0:
        raise ClothFitError(f"checkpoint {path}: 'exploded' must be an integer >= 0")
    for k in ("finished", "cancelled"):
        if not isinstance(ck[k], bool):
            raise ClothFitError(f"checkpoint {path}: '{k}' must be true or false")
    if ck["stop_reason"] is not None and ck["stop_reason"] not in STOP_REASONS:
        raise ClothFitError(f"checkpoint {path}: 'stop_reason' {ck['stop_reason']!r} is not one of {STOP_REASONS}")
    ck["elapsed"] = float(e)
    return ck
