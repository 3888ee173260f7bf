"""The search space of a fit: bounded real parameters <-> the unit cube, and the small
validators every optimiser shares (settings, non-finite fitness, checkpoint fields).

Encoding
--------
:class:`SearchSpace` maps each parameter to ``[0, 1]``: linearly between its bounds, or
linearly in ``log(x)`` for a log-scaled (scale) parameter, whose bounds must then be > 0.
The optimisers work only in this unit cube, ``ask`` returns decoded real values, and
``decode`` clips to the bounds, so a candidate can never leave them.

Non-finite fitness
------------------
An exploded or failed model is a bad candidate, never a crash (docs/method.md#spec-4): every non-finite value
(``nan``, ``+inf``, ``-inf``) is treated as ``+inf``, the worst. Such a candidate can never
become ``best_x``; in MGG it ranks last in its family; CMA-ES, which is rank based, ranks it
after every finite value. ``best_x`` stays ``None`` and ``best_f`` ``inf`` until a finite value
has been told.

Validators
----------
``checked_number``, ``checked_integer`` and ``checked_flag`` check an optimiser's settings; ``saved_value``, ``saved_array``,
``saved_field`` ... check a checkpoint's fields. Each raises a one-line :class:`ClothFitError`
naming the value at fault.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import ClothFitError

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

# --------------------------------------------------------------------------- helpers


def new_rng(seed: int | None) -> np.random.Generator:
    return np.random.Generator(np.random.PCG64(seed))


def _rng_from_state(state):
    rng = np.random.Generator(np.random.PCG64())
    rng.bit_generator.state = state
    return rng


def float_to_json(v: float) -> float | None:
    v = float(v)
    return v if math.isfinite(v) else None


def float_from_json(v: float | None) -> float:
    return math.inf if v is None else float(v)


def sanitize_fitness(f: ArrayLike, count: int) -> np.ndarray:
    """``f`` as a float (count,) array with every non-finite value replaced by ``+inf``."""
    try:
        arr = np.asarray(f, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise ClothFitError(f"fitness values must be numbers, got {f!r}") from exc
    if arr.shape[0] != count:
        raise ClothFitError(f"fitness: expected {count} values (one per candidate), got {arr.shape[0]}")
    return np.where(np.isfinite(arr), arr, np.inf)


def reflect_unit(U: np.ndarray) -> np.ndarray:
    """Reflect values into [0, 1] at the faces of the unit cube (triangle wave, any distance)."""
    V = np.mod(np.asarray(U, dtype=np.float64), 2.0)
    return np.where(V > 1.0, 2.0 - V, V)


# --------------------------------------------------------------------------- state validation


def saved_field(d: dict, key: str, where: str) -> Any:
    if key not in d:
        raise ClothFitError(f"checkpoint: {where} state lacks '{key}'")
    return d[key]


def check_keys(d: dict, allowed: Iterable[str], where: str) -> None:
    unknown = sorted(set(d) - set(allowed))
    if unknown:
        raise ClothFitError(f"checkpoint: {where} state has unknown fields {unknown} (not written by this version)")


def saved_value(
    d: dict,
    key: str,
    where: str,
    kind: type = float,
    lo: float | None = None,
    hi: float | None = None,
    allow_none: bool = False,
) -> Any:
    v = saved_field(d, key, where)
    if v is None and allow_none:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or (kind is int and not isinstance(v, int)):
        raise ClothFitError(
            f"checkpoint: {where} '{key}' must be {'an integer' if kind is int else 'a number'}, got {type(v).__name__}"
        )
    if kind is float and not math.isfinite(v):
        raise ClothFitError(f"checkpoint: {where} '{key}' must be finite, got {v!r}")
    if (lo is not None and v < lo) or (hi is not None and v > hi):
        raise ClothFitError(f"checkpoint: {where} '{key}' = {v!r} outside [{lo}, {hi}]")
    return kind(v)


def saved_array(
    d: dict, key: str, where: str, shape: tuple, allow_none: bool = False, inf_as_none: bool = False
) -> np.ndarray | None:
    """A nested list of numbers of the given shape (None in shape = any length), all finite
    (or ``None`` = +inf where ``inf_as_none``)."""
    v = saved_field(d, key, where)
    if v is None and allow_none:
        return None
    if not isinstance(v, list):
        raise ClothFitError(f"checkpoint: {where} '{key}' must be a list of numbers, got {type(v).__name__}")
    try:
        if inf_as_none:
            flat = np.array([math.inf if x is None else x for x in v], dtype=object)
            if any(isinstance(x, (bool, list, dict, str)) for x in flat):
                raise TypeError
            A = flat.astype(np.float64)
        else:
            A = np.array(v, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise ClothFitError(f"checkpoint: {where} '{key}' must be a (nested) list of numbers") from None
    if A.size == 0 and len(shape) == 2 and shape[0] is None and shape[1] is not None:
        A = A.reshape(0, shape[1])
    if A.ndim != len(shape) or any(s is not None and s != a for s, a in zip(shape, A.shape)):
        want = "x".join("*" if s is None else str(s) for s in shape)
        raise ClothFitError(f"checkpoint: {where} '{key}' has shape {A.shape}, expected {want}")
    if A.size > 10_000_000:
        raise ClothFitError(f"checkpoint: {where} '{key}' is too large ({A.size} numbers)")
    bad = np.isnan(A) | (np.isinf(A) if not inf_as_none else np.isneginf(A))
    if bad.any():
        raise ClothFitError(f"checkpoint: {where} '{key}' holds non-finite values")
    return A


def rng_state_from_json(v: Any, where: str) -> dict:
    """A PCG64 bit-generator state made of plain integers, validated."""
    if (
        not isinstance(v, dict)
        or set(v) != {"bit_generator", "state", "has_uint32", "uinteger"}
        or v["bit_generator"] != "PCG64"
        or not isinstance(v["state"], dict)
        or set(v["state"]) != {"state", "inc"}
    ):
        raise ClothFitError(f"checkpoint: {where} 'rng' is not a PCG64 generator state")
    ints = [v["state"]["state"], v["state"]["inc"], v["has_uint32"], v["uinteger"]]
    if not all(isinstance(i, int) and not isinstance(i, bool) and 0 <= i < 2**128 for i in ints):
        raise ClothFitError(f"checkpoint: {where} 'rng' must hold non-negative integers below 2**128")
    try:
        return _rng_from_state(v)
    except (TypeError, ValueError, OverflowError) as exc:  # (numpy: uinteger must fit its C type)
        raise ClothFitError(f"checkpoint: {where} 'rng' is invalid ({exc})") from None


def saved_stop_reason(d: dict, where: str, allowed: Iterable[str]) -> str | None:
    v = saved_field(d, "stop_reason", where)
    if v is not None and v not in allowed:
        raise ClothFitError(f"checkpoint: {where} 'stop_reason' {v!r} is not one of {list(allowed)}")
    return v


def checked_tie(tie: object, names: list, first: list, w: str) -> dict:
    """A staged search's ``tie``: follower -> leader, each follower a coordinate held in the first stage, its leader
    one searched there; in the space's order (anything else is a one-line error)."""
    if not isinstance(tie, dict):
        raise ClothFitError(f"{w}: 'tie' must map a held coordinate to a searched one")
    out = {}
    for f, lead in tie.items():
        if f not in names or f in first or lead not in first:
            raise ClothFitError(
                f"{w}: 'tie' {f!r} -> {lead!r} must map a held coordinate to one searched in the first stage"
            )
        out[str(f)] = str(lead)
    return {f: out[f] for f in names if f in out}


def saved_bool(d: dict, key: str, where: str) -> bool:
    """A checkpoint's required true/false field ``key``."""
    v = saved_field(d, key, where)
    if not isinstance(v, bool):
        raise ClothFitError(f"checkpoint: {where} '{key}' must be true or false")
    return v


def saved_step(d: dict, key: str, where: str) -> float:
    """A checkpoint's CMA-ES step ``key`` (unit cube): a number in (0, 10]."""
    return checked_number(saved_value(d, key, where, float), f"checkpoint: {where} '{key}'", 0.0, 10.0, lo_open=True)


def saved_active(d: dict, where: str) -> bool:
    v = d.get("active", False)  # older checkpoints: plain CMA-ES
    if not isinstance(v, bool):
        raise ClothFitError(f"checkpoint: {where} 'active' must be true or false")
    return v


def checked_number(v: Any, what: str, lo: float = 0.0, hi: float = math.inf, lo_open: bool = False) -> float:
    """``v`` as a finite float in ``[lo, hi]`` (``(lo, hi]`` where ``lo_open``), else a one-line
    ClothFitError naming ``what``: every real-valued setting of every optimiser goes through here."""
    try:
        x = float(v)
    except (TypeError, ValueError):
        x = math.nan
    if not (math.isfinite(x) and (x > lo if lo_open else x >= lo) and x <= hi):
        span = f">= {lo:g}" if hi == math.inf and not lo_open else f"in {'(' if lo_open else '['}{lo:g}, {hi:g}]"
        raise ClothFitError(f"{what} must be a finite number {span}, got {v!r}")
    return x


def checked_flag(v: Any, what: str) -> bool:
    """``v`` as a bool (a numpy bool too; not 0 / 1 / "yes"), else a one-line ClothFitError."""
    if not isinstance(v, (bool, np.bool_)):
        raise ClothFitError(f"{what} must be true or false, got {v!r}")
    return bool(v)


def checked_integer(v: Any, what: str, lo: int = 1, hi: int | None = None) -> int:
    """``v`` as an int in ``lo..hi`` (no upper bound when None; a bool is not an integer), else a
    one-line ClothFitError naming ``what``."""
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or int(v) < lo or (hi is not None and int(v) > hi):
        span = f">= {lo}" if hi is None else f"in {lo}..{hi}"
        raise ClothFitError(f"{what} must be an integer {span}, got {v!r}")
    return int(v)


# --------------------------------------------------------------------------- search space


class SearchSpace:
    """Bounded real parameters <-> the unit cube ``[0, 1]^n`` (log scale where asked).

    ``names``: the free parameters in order; ``bounds``: name -> (lo, hi) (extra keys ignored);
    ``log_scaled``: name -> bool (missing = linear).
    """

    def __init__(self, names, bounds: dict, log_scaled: dict | None = None):
        names = [str(n) for n in names]
        if not names:
            raise ClothFitError("search space: no parameter names given")
        if len(set(names)) != len(names):
            raise ClothFitError(f"search space: duplicate parameter names in {names}")
        log_scaled = dict(log_scaled or {})
        lo, hi, logs = [], [], []
        for name in names:
            if name not in bounds:
                raise ClothFitError(f"search space: no bounds given for parameter '{name}'")
            try:
                a, b = bounds[name]
                a, b = float(a), float(b)
            except (TypeError, ValueError) as exc:
                raise ClothFitError(
                    f"search space: bounds of parameter '{name}' must be a pair of "
                    f"numbers (lo, hi), got {bounds[name]!r}"
                ) from exc
            if not (math.isfinite(a) and math.isfinite(b)):
                raise ClothFitError(f"search space: bounds of parameter '{name}' must be finite, got ({a}, {b})")
            if not a < b:
                raise ClothFitError(f"search space: parameter '{name}' needs lo < hi, got ({a}, {b})")
            is_log = bool(log_scaled.get(name, False))
            if is_log and a <= 0.0:
                raise ClothFitError(
                    f"search space: parameter '{name}' is log-scaled, so its bounds must be > 0, got ({a}, {b})"
                )
            lo.append(a)
            hi.append(b)
            logs.append(is_log)
        self.names = names
        self.lo = np.array(lo)
        self.hi = np.array(hi)
        self.log = np.array(logs, dtype=bool)
        self._tlo = np.where(self.log, np.log(np.where(self.log, self.lo, 1.0)), self.lo)
        self._thi = np.where(self.log, np.log(np.where(self.log, self.hi, 1.0)), self.hi)

    @property
    def n(self) -> int:
        return len(self.names)

    @property
    def bounds(self) -> dict:
        return {n: (float(a), float(b)) for n, a, b in zip(self.names, self.lo, self.hi)}

    @property
    def log_scaled(self) -> dict:
        return {n: bool(g) for n, g in zip(self.names, self.log)}

    def _rows(self, X, what):
        try:
            A = np.asarray(X, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ClothFitError(f"{what}: expected numbers, got {X!r}") from exc
        if A.ndim not in (1, 2) or A.shape[-1] != self.n:
            raise ClothFitError(
                f"{what}: expected shape ({self.n},) or (B, {self.n}) for parameters {self.names}, got {A.shape}"
            )
        return A

    def encode(self, X: ArrayLike) -> np.ndarray:
        """Real values (n,) or (B, n) -> unit-cube coordinates, same shape (not clipped)."""
        A = self._rows(X, "encode")
        A2 = A.reshape(-1, self.n)
        bad = ~np.isfinite(A2) | (self.log & (A2 <= 0.0))
        if bad.any():
            j = int(np.nonzero(bad.any(axis=0))[0][0])
            raise ClothFitError(
                f"encode: parameter '{self.names[j]}' has a non-finite"
                f"{' or non-positive (log-scaled)' if self.log[j] else ''} value "
                f"{A2[bad[:, j], j][0]!r}"
            )
        T = np.where(self.log, np.log(np.where(self.log, A2, 1.0)), A2)
        U = (T - self._tlo) / (self._thi - self._tlo)
        return U.reshape(A.shape)

    def decode(self, U: ArrayLike) -> np.ndarray:
        """Unit-cube coordinates (n,) or (B, n) -> real values, clipped to the bounds."""
        A = self._rows(U, "decode")
        A = np.clip(A, 0.0, 1.0)
        T = self._tlo + A * (self._thi - self._tlo)
        X = np.where(self.log, np.exp(T), T)
        return np.clip(X, self.lo, self.hi)

    def at_bound(self, x: ArrayLike, margin: float, relative: float = 0.0) -> dict[str, str]:
        """{name: "lower" or "upper"} of the parameters of one real vector ``x`` that lie within ``margin``
        (a share of the range, in the unit cube: log scale where log-scaled) of a bound, or, log-scaled ones,
        within a factor ``1 + relative`` of it (a narrow range)."""
        u = self.encode(self._rows(x, "at_bound").reshape(self.n))
        m = np.maximum(margin, np.where(self.log, np.log1p(relative) / (self._thi - self._tlo), 0.0))
        return {n: ("lower" if v <= 0.5 else "upper") for n, v, mk in zip(self.names, u, m) if v <= mk or v >= 1.0 - mk}

    def clip(self, X: ArrayLike) -> np.ndarray:
        """Real values clipped to the bounds."""
        return np.clip(self._rows(X, "clip"), self.lo, self.hi)

    def neighbours(self, x: ArrayLike, n: int, relative: float, seed: int) -> np.ndarray:
        """``n`` copies of a real vector ``x`` whose first ``self.n`` values (this space's parameters; any
        after them are kept) each move by ``relative`` of their size (log-scaled) or of their range (linear),
        random signs drawn from ``seed``, clipped to the bounds: the chaos probe of the jitter and intervals."""
        x = np.asarray(x, dtype=np.float64).reshape(-1)
        signs = np.random.default_rng(seed).choice([-1.0, 1.0], size=(n, self.n))
        tiny = np.where(self.log, np.abs(x[: self.n]), self.hi - self.lo) * relative
        X = np.repeat(x[None], n, axis=0)
        X[:, : self.n] = self.clip(x[None, : self.n] + signs * tiny)
        return X

    def to_dict(self, x: ArrayLike) -> dict[str, float]:
        """One real vector -> {name: value}."""
        x = self._rows(x, "to_dict").reshape(self.n)
        return {n: float(v) for n, v in zip(self.names, x)}

    def from_dict(self, values: dict) -> np.ndarray:
        """{name: value} -> one real vector (n,)."""
        missing = [n for n in self.names if n not in values]
        if missing:
            raise ClothFitError(f"parameter values: missing {missing}")
        return np.array([float(values[n]) for n in self.names])

    def subspace(self, names: list[str]) -> SearchSpace:
        """The space of ``names`` alone (in that order), with their bounds and scaling."""
        b, lg = self.bounds, self.log_scaled
        return SearchSpace(list(names), {n: b[n] for n in names}, {n: lg[n] for n in names})

    def state_dict(self) -> dict:
        return {
            "names": list(self.names),
            "bounds": {n: [float(a), float(b)] for n, a, b in zip(self.names, self.lo, self.hi)},
            "log_scaled": self.log_scaled,
        }

    @classmethod
    def from_state(cls, d: dict) -> SearchSpace:
        if not isinstance(d, dict):
            raise ClothFitError("checkpoint: search space must be an object")
        check_keys(d, ("names", "bounds", "log_scaled"), "search space")
        names, bounds, logs = d.get("names"), d.get("bounds"), d.get("log_scaled") or {}
        if (
            not isinstance(names, list)
            or not all(isinstance(n, str) for n in names)
            or len(names) > 1000
            or not isinstance(bounds, dict)
            or not isinstance(logs, dict)
            or not all(isinstance(v, list) and len(v) == 2 for v in bounds.values())
            or not all(isinstance(v, bool) for v in logs.values())
        ):
            raise ClothFitError(
                "checkpoint: search space needs 'names' (strings), 'bounds' (name: [lo, hi]) "
                "and 'log_scaled' (name: true/false)"
            )
        return cls(names, {k: tuple(v) for k, v in bounds.items()}, logs)

    def __repr__(self):
        parts = [
            f"{n}=[{a:g}, {b:g}]{' log' if g else ''}" for n, a, b, g in zip(self.names, self.lo, self.hi, self.log)
        ]
        return f"SearchSpace({', '.join(parts)})"
