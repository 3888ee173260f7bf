# SPDX-License-Identifier: GPL-3.0-or-later
"""Several takes of one cloth from the scene (``core.fitting.takes``): the loaded capture plus the other takes
listed in the Fitting section (``add_take``, ``remove_take``), loaded for a fit (``take_captures``); after a fit
of several takes, each take's verdict (``show_take_verdicts``) and the take Apply Blender Cloth replays
(``chosen_take``)."""

from __future__ import annotations

import os

from ...core.errors import ClothFitError
from .reading import abspath, capture_dir, props


def _same_folder(a: str, b: str) -> bool:
    return os.path.normcase(os.path.realpath(a)) == os.path.normcase(os.path.realpath(b))


def add_take(scene, path):
    """Add the capture folder ``path`` (or its capture.json) to the scene's other takes; it must load as a
    capture (``core.observation.capture.load_capture``, its silhouette folders checked) and be neither the
    loaded capture nor a take already listed. Returns the capture."""
    from ...core.observation.capture import load_capture as core_load

    p = props(scene)
    cap = core_load(abspath(path, "take folder"))
    cap.validate(full=False)
    if p.capture_dir:
        try:
            main = capture_dir(scene)
        except ClothFitError:
            main = None
        if main is not None and _same_folder(main, cap.root):
            raise ClothFitError(f"take {cap.root} is the loaded capture: it is in the fit already")
    for t in p.fit_takes:
        if _same_folder(abspath(t.directory, "take folder"), cap.root):
            raise ClothFitError(f"take {cap.root} is listed already")
    item = p.fit_takes.add()
    item.directory = cap.root
    item.name = os.path.basename(os.path.normpath(cap.root))
    p.fit_takes_index = len(p.fit_takes) - 1
    return cap


def remove_take(scene, index: int = -1) -> str:
    """Remove the other take at ``index`` (-1: the active one) from the list; returns its folder."""
    p = props(scene)
    n = len(p.fit_takes)
    i = p.fit_takes_index if index < 0 else index
    if not 0 <= i < n:
        raise ClothFitError(f"no take #{i} to remove (the list has {n})")
    folder = p.fit_takes[i].directory
    p.fit_takes.remove(i)
    p.fit_takes_index = max(0, min(p.fit_takes_index, len(p.fit_takes) - 1))
    return folder


def take_captures(scene) -> list:
    """The other takes of the scene's fit, loaded (``core.observation.capture.load_capture``) in list order."""
    from ...core.observation.capture import load_capture as core_load

    out = []
    for t in props(scene).fit_takes:
        out.append(core_load(abspath(t.directory, f"take {t.name!r} folder")))
    return out


def show_take_verdicts(scene, result: dict):
    """A fit result's takes (its ``takes``: none for a fit of one take) into the scene: each take's name,
    verdict and frame rate for the Fitting section and the Take choice of Apply Blender Cloth (a chosen take
    the result does not hold is cleared: the loaded capture's again)."""
    p = props(scene)
    p.fit_take_results.clear()
    for e in result.get("takes") or []:
        item = p.fit_take_results.add()
        item.name = str(e.get("take", ""))
        item.verdict = str(e.get("verdict") or "")
        item.verdict_kind = str(e.get("verdict_kind") or "")
        item.fps = float(e.get("fps") or 0.0)
    if p.apply_take and p.apply_take not in p.fit_take_results:
        p.apply_take = ""


def chosen_take(scene, result: dict, take: str | None = None) -> dict | None:
    """The entry of ``result["takes"]`` that Apply Blender Cloth replays: the take named ``take`` (None: the
    scene's choice; empty: the loaded capture's, found by its capture hash or folder); None for a result of one
    take (asked for no take). A take the result does not hold is a one-line error naming it."""
    from ...core.fitting.checkpoint import capture_hash
    from ...core.observation.capture import load_capture as core_load

    name = props(scene).apply_take if take is None else take
    entries = [e for e in result.get("takes") or [] if isinstance(e, dict)]
    names = ", ".join(str(e.get("take")) for e in entries)
    if not entries:
        if name:
            raise ClothFitError(f"take {name!r} is not in the fit result: it is a fit of one take (choose no take)")
        return None
    if name:
        for e in entries:
            if e.get("take") == name:
                return e
        raise ClothFitError(f"take {name!r} is not in the fit result (its takes: {names})")
    root = capture_dir(scene)
    try:
        h = capture_hash(core_load(root))
    except ClothFitError:
        h = None
    for e in entries:
        if (h is not None and e.get("capture_hash") == h) or _same_folder(str(e.get("capture", "")), root):
            return e
    raise ClothFitError(f"the loaded capture {root} is not a take of the fit result (its takes: {names}): choose one")
