"""Where a fit is: one record of its progress, the part of a checkpoint a resumed fit starts from.

A fit (``job.FitJob``) runs in stages: the main ``search``; where the fit chooses the simulation's quality,
the quality ladder's ``rung`` stages; where the manipulation has unknowns, their ``profile``; the
``intervals`` of every setting; over several takes, each take searched ``alone``; then ``done``. Everything
that changes while it runs, besides the running optimiser's own state (``optimizer_state`` of the checkpoint,
the optimiser's ``state_dict``), lives in one ``RunState``: plain numbers, lists and dicts, written as the
checkpoint's ``stages`` and outcome fields and read back checked field by field (one-line ``ClothFitError``
naming the checkpoint). What the fit is of (its capture, cameras, model, bounds) is not here: that is the
job's identity (``checkpoint.identity``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from ..errors import ClothFitError

STAGES = ("search", "rung", "profile", "alone", "intervals", "done")
STOP_REASONS = ("converged", "budget", "target", "cancelled", "error")
SAVED_FIELDS = (
    "stage",
    "stage_quality",
    "stage_end",
    "done_evals",
    "records",
    "best_by_quality",
    "history_prev",
    "search_stop",
    "ladder",
    "profile",
    "start_f",
)
LATER_FIELDS = ("polish_rounds", "polish_scale", "intervals", "alone", "cut_batches", "again")  # absent from older ones
OUTCOME_FIELDS = ("elapsed", "exploded", "finished", "cancelled", "stop_reason", "error")


@dataclass
class RunState:
    """A fit's progress. ``stage``: the running stage (``STAGES``), at ``stage_quality`` (None: the model's
    own), ending at ``stage_end`` evaluations; ``done_evals``: evaluations of finished stages and of points
    scored aside (the running optimiser counts its own); ``records``: the finished search and rungs
    (evaluations, generations, best error, why each stopped); ``best_by_quality``: quality -> [best error,
    best point] (search space); ``history_prev``: [evaluations, best error] of the finished stages;
    ``search_stop``: why the main search stopped; ``profile``: the manipulation unknowns' profile
    (``offset_profile``), with ``polish_rounds`` done at step ``polish_scale``; ``start_f``: the user's own
    settings' error (the fit never answers worse); ``intervals``: the intervals stage's state
    (``intervals``); ``alone``: the each-take-alone stage's (``alone``); ``again``: the searches again (a search
    that ended above the floor its own jitter allows: ``searches`` started again, the evaluation ``start`` of the
    running one, ``why`` each began, ``ended`` how the last check came out and ``ends`` each search's best error and point). The outcome: ``elapsed`` seconds
    stepping, ``exploded`` candidates, ``cut_batches`` (last batches cut to a budget), ``finished``,
    ``cancelled``, ``stop_reason`` (``STOP_REASONS``), ``error``; ``final`` and ``take_finals``: the errors
    beside the floor made once at the end (``diagnose``; not saved: made again from the best point)."""

    stage: str = "search"
    stage_quality: int | None = None
    stage_end: int = 0
    done_evals: int = 0
    records: list[dict] = field(default_factory=list)
    best_by_quality: dict[int | None, list] = field(default_factory=dict)
    history_prev: list[list] = field(default_factory=list)
    search_stop: str | None = None
    profile: dict | None = None
    polish_rounds: int = 0
    polish_scale: float = 1.0
    start_f: float | None = None
    intervals: dict | None = None
    alone: dict | None = None
    again: dict | None = None
    elapsed: float = 0.0
    exploded: int = 0
    cut_batches: int = 0
    finished: bool = False
    cancelled: bool = False
    stop_reason: str | None = None
    error: str | None = None
    final: dict | None = None
    take_finals: list | None = None

    # ------------------------------------------------------------ progress
    def track(self, quality: int | None, f: float, x: Any) -> None:
        """A stage's best point at ``quality``, kept if it is the best there so far."""
        have = self.best_by_quality.get(quality)
        if have is None or f < have[0]:
            self.best_by_quality[quality] = [float(f), [float(v) for v in x]]

    def end_stage(self, record: dict, history: list[list], evaluations: int) -> None:
        """The running search or rung is over: its record, its history after the finished stages', its
        evaluations counted."""
        self.records.append(record)
        self.history_prev += [[int(a) + self.done_evals, b] for a, b in history]
        self.done_evals += int(evaluations)
        if record["stage"] == "search":
            self.search_stop = record["stop"]

    def reopen_search(self, search_end: int) -> None:
        """Back to the main search (a search that stopped on its budget, resumed with a larger one): the
        stages after it are forgotten and made again at its new end."""
        self.records = []
        self.done_evals = 0 if self.start_f is None else 1
        self.history_prev = []
        self.search_stop = None
        self.profile = None
        self.polish_rounds = 0
        self.polish_scale = 1.0
        self.intervals = None
        self.again = None
        self.stage = "search"
        self.stage_end = search_end
        self.stop_reason = None

    # ------------------------------------------------------------ saving
    def saved_stages(self, ladder_state: dict | None, alone_opt_state: dict | None) -> dict[str, Any]:
        """The checkpoint's ``stages``: this state's progress as plain numbers, with the quality ladder's state
        and the running each-take-alone optimiser's."""
        return {
            "stage": self.stage,
            "stage_quality": self.stage_quality,
            "stage_end": self.stage_end,
            "done_evals": self.done_evals,
            "records": self.records,
            "best_by_quality": [[q, f, x] for q, (f, x) in self.best_by_quality.items()],
            "history_prev": self.history_prev,
            "search_stop": self.search_stop,
            "ladder": ladder_state,
            "profile": self.profile,
            "polish_rounds": self.polish_rounds,
            "polish_scale": self.polish_scale,
            "start_f": self.start_f,
            "intervals": self.intervals,
            "alone": None
            if self.alone is None
            else dict(self.alone, opt=alone_opt_state if alone_opt_state is not None else self.alone.get("opt")),
            "cut_batches": self.cut_batches,
            "again": self.again,
        }

    def saved_outcome(self) -> dict[str, Any]:
        """The checkpoint's outcome fields (``OUTCOME_FIELDS``)."""
        return {k: getattr(self, k) for k in OUTCOME_FIELDS}

    @classmethod
    def from_saved(cls, st: Any, outcome: dict[str, Any], fit: FitShape, path: str) -> tuple[RunState, dict | None]:
        """A checkpoint's ``stages`` and outcome fields, checked against the fit resuming it (``fit``: its
        search space's size, unknowns, ladder...); returns the state and the saved ladder's state (None
        without a ladder). Of the outcome only the time spent and the candidates that exploded carry over (its
        types are checked by the checkpoint's reader): a resumed fit is running again until it stops."""
        bad = _bad(path)
        check_stages(st, fit, bad)
        s = cls(
            stage=st["stage"],
            stage_quality=st["stage_quality"],
            stage_end=st["stage_end"],
            done_evals=st["done_evals"],
            records=[dict(r) for r in st["records"]],
            best_by_quality={e[0]: [float(e[1]), [float(v) for v in e[2]]] for e in st["best_by_quality"]},
            history_prev=[list(e) for e in st["history_prev"]],
            search_stop=st["search_stop"],
            profile=st["profile"],
            polish_rounds=st.get("polish_rounds", 0),
            polish_scale=float(st.get("polish_scale", 1.0)),
            start_f=None if st["start_f"] is None else float(st["start_f"]),
            intervals=check_intervals_state(st.get("intervals"), fit.n, bad),
            alone=check_alone_state(st.get("alone"), fit.n_takes, bad),
            cut_batches=st.get("cut_batches", 0),
            again=check_again_state(st.get("again"), bad),
            elapsed=float(outcome["elapsed"]),
            exploded=int(outcome["exploded"]),
        )
        return s, st["ladder"]


@dataclass(frozen=True)
class FitShape:
    """What a saved state is checked against: the fit's search space size ``n``, its manipulation unknowns'
    names (None without), whether it has a quality ladder (``ladder``: its ``start``, ``probe_only`` and
    ``allows``), whether it has an intervals stage, and its number of takes."""

    n: int
    manip_names: tuple[str, ...] | None
    ladder: Any
    intervals_planned: bool
    n_takes: int


def _bad(path):
    def bad(what):
        return ClothFitError(f"checkpoint {path}: bad 'stages' ({what})")

    return bad


def _is_int(v, lo=0):
    return isinstance(v, int) and not isinstance(v, bool) and v >= lo


def _is_num(v):
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _is_q(v):
    return v is None or _is_int(v, 1) and v <= 80


def check_stages(st: Any, fit: FitShape, bad: Callable[[str], ClothFitError]) -> None:
    """A checkpoint's ``stages``, checked field by field against the fit resuming it."""
    if not isinstance(st, dict):
        raise bad("not an object")
    keys, later = set(SAVED_FIELDS), set(LATER_FIELDS)
    if set(st) - later != keys:
        raise bad(f"fields {sorted((set(st) - later) ^ keys)}")
    if not _is_int(st.get("polish_rounds", 0)) or not (
        _is_num(st.get("polish_scale", 1.0)) and 0 < st.get("polish_scale", 1.0) <= 1
    ):
        raise bad("polish_rounds or polish_scale")
    if not _is_int(st.get("cut_batches", 0)):
        raise bad("cut_batches")
    if st["stage"] not in STAGES or (st["stage"] == "intervals" and not fit.intervals_planned):
        raise bad(f"stage {st['stage']!r}")
    if not _is_q(st["stage_quality"]) or not _is_int(st["stage_end"]) or not _is_int(st["done_evals"]):
        raise bad("stage_quality, stage_end or done_evals")
    if not isinstance(st["records"], list) or not all(_is_record(r) for r in st["records"]):
        raise bad("records")
    bq = st["best_by_quality"]
    if not isinstance(bq, list) or not all(
        isinstance(e, list)
        and len(e) == 3
        and _is_q(e[0])
        and _is_num(e[1])
        and isinstance(e[2], list)
        and len(e[2]) == fit.n
        and all(_is_num(v) for v in e[2])
        for e in bq
    ):
        raise bad("best_by_quality")
    hp = st["history_prev"]
    if not isinstance(hp, list) or not all(
        isinstance(e, list) and len(e) == 2 and _is_int(e[0]) and (e[1] is None or _is_num(e[1])) for e in hp
    ):
        raise bad("history_prev")
    if st["search_stop"] not in (None, "converged", "budget"):
        raise bad("search_stop")
    if st["start_f"] is not None and not _is_num(st["start_f"]):
        raise bad("start_f")
    _check_profile(st["profile"], fit.manip_names, bad)
    if (st["ladder"] is None) != (fit.ladder is None):
        raise bad("a quality ladder in one and not the other")


def _is_record(r):
    return (
        isinstance(r, dict)
        and r.get("stage") in ("search", "rung")
        and _is_q(r.get("quality"))
        and _is_int(r.get("evaluations"))
        and _is_int(r.get("generations"))
        and (r.get("best_f") is None or _is_num(r.get("best_f")))
        and r.get("stop") in ("converged", "budget")
        and ("looks" not in r or _is_looks(r["looks"]))
    )


def _is_looks(lk):
    """A search record's ``looks`` (``StagedCMA.looks``): starts, each run's best value, how many agreed."""
    return (
        isinstance(lk, dict)
        and set(lk) == {"starts", "ended", "agreeing", "settings"}
        and _is_int(lk["starts"])
        and lk["starts"] >= 1
        and isinstance(lk["ended"], list)
        and 1 <= len(lk["ended"]) <= lk["starts"]
        and all(_is_num(v) for v in lk["ended"])
        and _is_int(lk["agreeing"])
        and 1 <= lk["agreeing"] <= len(lk["ended"])
        and isinstance(lk["settings"], list)
        and all(isinstance(n, str) for n in lk["settings"])
    )


def _check_profile(prof, names, bad):
    if prof is not None and (
        names is None
        or not isinstance(prof, dict)
        or set(prof) != set(names)
        or not all(
            isinstance(v, dict)
            and isinstance(v.get("separated"), bool)
            and (v.get("uncertainty") is None or _is_num(v.get("uncertainty")))
            for v in prof.values()
        )
    ):
        raise bad("profile")


def check_intervals_state(st: Any, n: int, bad: Callable[[str], ClothFitError]) -> dict | None:
    """The intervals stage's saved state (``intervals.start``'s fields), checked: None, or the state."""
    if st is None:
        return None
    phases = ("jitter", "axes", "sample", "done")
    ok = (
        isinstance(st, dict)
        and st.get("phase") in phases
        and isinstance(st.get("u0"), list)
        and len(st["u0"]) == n
        and isinstance(st.get("h"), list)
        and len(st["h"]) == n
        and isinstance(st.get("U"), list)
        and isinstance(st.get("F"), list)
        and len(st["U"]) == len(st["F"])
        and all(isinstance(u, list) and len(u) == n for u in st["U"])
        and all(v is None or (isinstance(v, (int, float)) and math.isfinite(v)) for v in st["F"])
        and isinstance(st.get("round"), int)
        and isinstance(st.get("props"), list)
        and _is_rises(st.get("rise"), n)
    )
    if not ok:
        raise bad("intervals")
    return st


def _is_rises(rise: Any, n: int) -> bool:
    """The axes phase's rises (``intervals``: per coordinate None or [step, rise below, rise above], a rise None
    where its evaluation failed); absent from older checkpoints."""
    if rise is None:
        return True
    return (
        isinstance(rise, list)
        and len(rise) == n
        and all(
            r is None
            or (
                isinstance(r, list)
                and len(r) == 3
                and _is_num(r[0])
                and r[0] > 0
                and all(v is None or _is_num(v) for v in r[1:])
            )
            for r in rise
        )
    )


def check_again_state(st: Any, bad: Callable[[str], ClothFitError]) -> dict | None:
    """The searches again (``RunState.again``), checked: None, or the state (``ends``, each ended search's best
    error and point, absent from older checkpoints: [])."""
    if st is None:
        return None
    ok = (
        isinstance(st, dict)
        and set(st) - {"ends"} == {"searches", "start", "why", "ended"}
        and _is_int(st["searches"])
        and _is_int(st["start"])
        and isinstance(st["why"], list)
        and len(st["why"]) == st["searches"]
        and all(isinstance(w, str) for w in st["why"])
        and (st["ended"] is None or isinstance(st["ended"], str))
        and isinstance(st.get("ends", []), list)
        and all(_is_end(e) for e in st.get("ends", []))
    )
    if not ok:
        raise bad("again")
    return {
        "searches": st["searches"],
        "start": st["start"],
        "why": list(st["why"]),
        "ended": st["ended"],
        "ends": [[] if not e else [float(e[0]), [float(v) for v in e[1]]] for e in st.get("ends", [])],
    }


def _is_end(e: Any) -> bool:
    """A search's end in ``again["ends"]``: [] (it found nothing) or [best error, best point]."""
    if e == []:
        return True
    return (
        isinstance(e, list)
        and len(e) == 2
        and _is_num(e[0])
        and isinstance(e[1], list)
        and all(_is_num(v) for v in e[1])
    )


def check_alone_state(st: Any, n_takes: int, bad: Callable[[str], ClothFitError]) -> dict | None:
    """The each-take-alone stage's saved state (``alone.alone_state``), checked: None, or the state."""
    if st is None:
        return None
    ok = (
        n_takes > 1
        and isinstance(st, dict)
        and isinstance(st.get("take"), int)
        and 0 <= st["take"] <= n_takes
        and isinstance(st.get("results"), list)
        and len(st["results"]) == st["take"]
        and all(isinstance(r, dict) for r in st["results"])
        and (st.get("opt") is None or isinstance(st["opt"], dict))
    )
    if not ok:
        raise bad("alone")
    return st
