"""The one JSON file reader of the core: one error style for every file a user hands over."""
from __future__ import annotations

import json
import os
from typing import Any

from .errors import ClothFitError


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
        raise ClothFitError(f"{what} {path}: expected a JSON {'object' if expect is dict else expect.__name__}, "
                            f"got {type(d).__name__}")
    return d
