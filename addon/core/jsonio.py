"""The one place the project reads and writes JSON: one reader (one error style for every file a
user hands over), one encoder (numpy scalars and arrays as numbers and lists), one text form
(indent 1) and one safe writer."""

from __future__ import annotations

import json
import os
from typing import TYPE_CHECKING, Any

import numpy as np

from .errors import ClothFitError
from .safeio import atomic_write

if TYPE_CHECKING:
    from collections.abc import Callable


def read_json(path: str | os.PathLike, what: str = "JSON file", expect: type | None = dict) -> Any:
    """The parsed contents of ``path``; a missing, unreadable or corrupt file, or one whose top level
    is not ``expect``, raises a one-line ``ClothFitError`` naming ``what`` and the file."""
    try:
        with open(path, encoding="utf-8") as f:
            d = json.load(f)
    except FileNotFoundError:
        raise ClothFitError(f"{what} {path}: file not found") from None
    except IsADirectoryError:
        raise ClothFitError(f"{what} {path}: is a directory, not a file") from None
    except (OSError, UnicodeDecodeError) as e:
        raise ClothFitError(f"{what} {path}: cannot read it ({e})") from None
    except json.JSONDecodeError as e:
        raise ClothFitError(f"{what} {path}: not valid JSON ({e})") from None
    if expect is not None and not isinstance(d, expect):
        raise ClothFitError(
            f"{what} {path}: expected a JSON {'object' if expect is dict else expect.__name__}, got {type(d).__name__}"
        )
    return d


def encode(o: Any) -> Any:
    """The project's one JSON encoder (``json.dumps(default=encode)``): numpy scalars as numbers,
    arrays as (nested) lists; anything else is a TypeError."""
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o)}")


def dumps(
    obj: Any,
    strict: bool = False,
    indent: int | None = 1,
    sort_keys: bool = False,
    default: Callable[[Any], Any] | None = None,
) -> str:
    """JSON text with the project's encoder; ``strict``: no NaN / Infinity (ValueError); ``indent``
    None for one line (hashes)."""
    return json.dumps(obj, indent=indent, sort_keys=sort_keys, default=default or encode, allow_nan=not strict)


def plain(obj: Any) -> Any:
    """``obj`` as the plain JSON values a reader of its file gets back (numpy values converted)."""
    return json.loads(dumps(obj, indent=None))


def write_json(
    path: str | os.PathLike, obj: Any, strict: bool = False, default: Callable[[Any], Any] | None = None
) -> None:
    """Write ``obj`` as JSON (indent 1, a final newline) safely: temporary file, fsync, rename
    (``safeio.atomic_write``); ``strict``: no NaN / Infinity. One-line ClothFitError."""
    try:
        text = dumps(obj, strict, default=default)
    except (TypeError, ValueError) as e:
        raise ClothFitError(f"cannot write {path}: the data is not strict JSON ({e})") from None
    atomic_write(path, (text + "\n").encode("utf-8"))


def loads(text: str | bytes, what: str = "JSON text", expect: type | None = None) -> Any:
    """JSON text (a scene property, an option) parsed; not JSON, or a top level that is not
    ``expect``, raises a one-line ``ClothFitError`` naming ``what``."""
    try:
        d = json.loads(text)
    except (ValueError, RecursionError) as e:
        raise ClothFitError(f"{what}: not valid JSON ({e})") from None
    if expect is not None and not isinstance(d, expect):
        raise ClothFitError(
            f"{what}: expected a JSON {'object' if expect is dict else expect.__name__}, got {type(d).__name__}"
        )
    return d
