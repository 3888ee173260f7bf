"""The on-disk capture format (docs/capture_format.md): cameras, frame times, handles, silhouettes, shapes.

One capture is one directory (full description: ``docs/capture_format.md``)::

    capture.json          format tag, version, scenario, frame times, file names, meta
    cameras.json          camera.save_cameras format (OpenCV convention)
    sil/{camera}/{frame:03d}.png   one 8-bit single-channel PNG per camera and frame,
                          0 = background, 255 = object
    shapes.npz            optional ground truth: positions (F, V, 3) [m], frame_times (F,)

The same format is written by the Blender renderer, by the synthetic generator and by the
real-footage extractor, and read by the fitter. Everything here is pure (numpy + cv2). This module
holds the capture (``Capture``), its loading and its writing; the silhouette files are read and
written by ``silhouette_files.py``, the format's names, file-name pattern and value checks are in
``capture_format.py``.
Every problem is a ``ClothFitError`` whose message names the file or the value at fault.
"""

from __future__ import annotations

import io
import json
import os
import string
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import ClothFitError
from ..jsonio import dumps, loads
from ..physics.scenario import Scenario, Uncertainty
from ..safeio import atomic_write
from .camera import Camera, check_camera_name, load_cameras, save_cameras
from .capture_format import (
    CAMERAS_JSON,
    CAPTURE_JSON,
    DEFAULT_IGNORE_PATTERN,
    DEFAULT_PATTERN,
    FORMAT,
    FRAME_TIME_TOL,
    MASK_KEYS,
    REQUIRED_KEYS,
    SHAPES_NPZ,
    VERSION,
    Time,
    check_cloth_mass,
    check_frame_times,
    check_model,
    check_pattern,
    check_shapes,
    field_regex,
    names_str,
    times_str,
)
from .silhouette_files import (
    check_mask_spec,
    mask_from_array,
    read_label_silhouette,
    read_matte,
    read_silhouette,
    save_silhouette,
    silhouette_where,
    write_bytes_atomic,
)

if TYPE_CHECKING:
    from collections.abc import Iterable, Sequence

    from numpy.typing import ArrayLike

# =========================================================================== capture


class Capture:
    """A capture in memory: cameras, scenario, frame times and where the silhouettes are.

    Silhouettes are read on demand (``load_silhouette``). Frame indices refer to
    ``frame_times`` of this object; a ``subset`` keeps pointing at the right files.
    """

    def __init__(
        self,
        root,
        cameras,
        scenario: Scenario,
        pattern: str = DEFAULT_PATTERN,
        shapes=None,
        cloth_mass=None,
        meta=None,
        json_path=None,
        _file_frames=None,
        _all_camera_names=None,
        model=None,
        masks=None,
        uncertain=None,
    ):
        self.root = os.path.abspath(str(root))
        self.json_path = json_path or os.path.join(self.root, CAPTURE_JSON)
        where = f"capture {self.json_path}"
        self.cameras = list(cameras)
        if not self.cameras:
            raise ClothFitError(f"{where}: no cameras")
        for i, c in enumerate(self.cameras):
            if not isinstance(c, Camera):
                raise ClothFitError(f"{where}: camera #{i} is a {type(c).__name__}, not a Camera")
            check_camera_name(c.name, where)
        names = [c.name for c in self.cameras]
        if len(set(names)) != len(names):
            raise ClothFitError(f"{where}: camera names are not unique: {names}")
        if not isinstance(scenario, Scenario):
            raise ClothFitError(f"{where}: scenario must be a Scenario, got {type(scenario).__name__}")
        self.scenario = scenario
        self.frame_times = np.asarray(scenario.frame_times, dtype=np.float64).copy()
        self.pattern = check_pattern(pattern, f"{where}: silhouettes pattern")
        self._file_frames = (
            np.arange(self.frame_times.size) if _file_frames is None else np.asarray(_file_frames, dtype=np.int64)
        )
        self._all_camera_names = list(_all_camera_names) if _all_camera_names is not None else names
        self.shapes = (
            None if shapes is None else check_shapes(shapes, self.frame_times.size, scenario.grid.n_vertices, where)
        )
        self.cloth_mass = check_cloth_mass(cloth_mass, where)
        if meta is None:
            meta = {}
        if not isinstance(meta, dict):
            raise ClothFitError(f"{where}: meta must be an object/dict, got {type(meta).__name__}")
        self.meta = meta
        self.model = check_model(model, where)
        self.masks = check_mask_spec(masks, where)
        if uncertain is not None and not isinstance(uncertain, Uncertainty):
            uncertain = Uncertainty.parse(uncertain, len(scenario.handles), f"{where}: uncertain")
        self.uncertain = uncertain  # what the manipulation could not measure (None: all exact)
        self._check_unique_paths()

    # ------------------------------------------------------------------ basics
    @property
    def n_cameras(self) -> int:
        return len(self.cameras)

    @property
    def n_frames(self) -> int:
        return int(self.frame_times.size)

    @property
    def camera_names(self) -> list[str]:
        return [c.name for c in self.cameras]

    @property
    def point_mass(self) -> float | None:
        """``cloth_mass / n_vertices`` [kg] (the fixed m of docs/method.md#spec-2), or None."""
        return None if self.cloth_mass is None else self.cloth_mass / self.scenario.grid.n_vertices

    def __repr__(self):
        return (
            f"Capture({self.root!r}, {self.n_cameras} cameras, {self.n_frames} frames, "
            f"shapes={'yes' if self.shapes is not None else 'no'})"
        )

    def camera_index(self, name: str) -> int:
        for i, c in enumerate(self.cameras):
            if c.name == name:
                return i
        raise ClothFitError(
            f"capture {self.json_path}: no camera named {name!r} (cameras: {', '.join(self.camera_names)})"
        )

    def frame_index(self, time: float, tol: float = 1e-6) -> int:
        try:
            t = float(time)
        except (TypeError, ValueError):
            raise ClothFitError(f"capture {self.json_path}: frame time must be a number, got {time!r}") from None
        d = np.abs(self.frame_times - t)
        i = int(np.argmin(d))
        if not (d[i] <= tol):
            avail = ", ".join(f"{x:g}" for x in self.frame_times)
            raise ClothFitError(
                f"capture {self.json_path}: time {t:g} s is not a frame of the capture "
                f"(tolerance {tol:g}); available times: {avail}"
            )
        return i

    def frame_indices(self, times: Iterable[float], tol: float = 1e-6) -> list[int]:
        return [self.frame_index(t, tol) for t in times]

    def _check_cam(self, ci):
        if not isinstance(ci, (int, np.integer)) or not (0 <= ci < self.n_cameras):
            raise ClothFitError(f"capture {self.json_path}: camera index {ci!r} out of range 0..{self.n_cameras - 1}")
        return int(ci)

    def _check_frame(self, fi):
        if not isinstance(fi, (int, np.integer)) or not (0 <= fi < self.n_frames):
            raise ClothFitError(f"capture {self.json_path}: frame index {fi!r} out of range 0..{self.n_frames - 1}")
        return int(fi)

    # ------------------------------------------------------------- silhouettes
    def _relpath(self, name: str, file_frame: int, time: float) -> str:
        return self.pattern.format(camera=name, frame=int(file_frame), time=Time(time))

    def silhouette_path(self, cam_index: int, frame_index: int) -> str:
        ci, fi = self._check_cam(cam_index), self._check_frame(frame_index)
        rel = self._relpath(self.cameras[ci].name, self._file_frames[fi], self.frame_times[fi])
        return os.path.join(self.root, *rel.replace("\\", "/").split("/"))

    def ignore_path(self, cam_index: int, frame_index: int) -> str | None:
        """The ignore mask file of a camera and frame (the capture's ``ignore`` pattern), or None."""
        if "ignore" not in self.masks:
            return None
        ci, fi = self._check_cam(cam_index), self._check_frame(frame_index)
        rel = self.masks["ignore"].format(
            camera=self.cameras[ci].name, frame=int(self._file_frames[fi]), time=Time(self.frame_times[fi])
        )
        return os.path.join(self.root, *rel.replace("\\", "/").split("/"))

    @property
    def has_ignore(self) -> bool:
        """True when the capture marks pixels of unknown truth (``ignore_ids`` or an ``ignore`` pattern)."""
        return "ignore_ids" in self.masks or "ignore" in self.masks

    def load_observation(
        self, cam_index: int, frame_index: int, allow_empty: bool = False, binarize_threshold: float | None = None
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """``(mask, ignore)`` of a camera and frame: the cloth silhouette (bool (H, W)) and the pixels
        whose truth is unknown (bool (H, W), or None when the capture marks none). Cloth pixels under
        an ignore mask are not cloth (they count as unknown); the silhouette must keep some pixel
        outside the ignored ones (eq. 6 divides by that area) unless ``allow_empty``."""
        ci, fi = self._check_cam(cam_index), self._check_frame(frame_index)
        cam = self.cameras[ci]
        shape = (cam.height, cam.width)
        src = f"camera '{cam.name}', frame {fi}, t={self.frame_times[fi]:g} s"
        path = self.silhouette_path(ci, fi)
        ignore = None
        if "silhouette_ids" in self.masks:
            mask, ignore = read_label_silhouette(
                path,
                self.masks["silhouette_ids"],
                self.masks.get("ignore_ids", ()),
                shape,
                allow_empty=allow_empty,
                source=src,
            )
        elif "matte_threshold" in self.masks:
            mask = read_matte(path, self.masks["matte_threshold"], shape, allow_empty=allow_empty, source=src)
        else:
            mask = read_silhouette(
                path, shape, binarize_threshold=binarize_threshold, allow_empty=allow_empty, source=src
            )
        if "ignore" in self.masks:
            extra = read_silhouette(self.ignore_path(ci, fi), shape, allow_empty=True, source=f"ignore mask of {src}")
            ignore = extra if ignore is None else (ignore | extra)
        if ignore is not None:
            mask = mask & ~ignore
            if not allow_empty and not mask.any():
                raise ClothFitError(
                    f"{silhouette_where(path, src)}: every cloth pixel is ignored (hidden by the ignore mask "
                    f"or ignore labels): nothing left to compare"
                )
        return mask, ignore

    def load_silhouette(
        self, cam_index: int, frame_index: int, allow_empty: bool = False, binarize_threshold: float | None = None
    ) -> np.ndarray:
        """bool (H, W) silhouette of camera ``cam_index`` at frame ``frame_index`` (validated); pixels
        of unknown truth (``load_observation``) are not part of it."""
        return self.load_observation(cam_index, frame_index, allow_empty, binarize_threshold)[0]

    def load_silhouettes(
        self,
        cam_indices: Iterable[int] | None = None,
        frame_indices: Iterable[int] | None = None,
        allow_empty: bool = False,
        binarize_threshold: float | None = None,
    ) -> list[list[np.ndarray]]:
        """``[[mask for frame in frame_indices] for cam in cam_indices]`` (None = all)."""
        cams = range(self.n_cameras) if cam_indices is None else cam_indices
        frames = range(self.n_frames) if frame_indices is None else list(frame_indices)
        return [[self.load_silhouette(ci, fi, allow_empty, binarize_threshold) for fi in frames] for ci in cams]

    def load_observations(
        self,
        cam_indices: Iterable[int] | None = None,
        frame_indices: Iterable[int] | None = None,
        allow_empty: bool = False,
    ) -> tuple[list[list[np.ndarray]], list[list[np.ndarray | None]]]:
        """``(masks, ignores)``, each ``[cam][frame]`` (an ignore entry is None where nothing is ignored)."""
        cams = range(self.n_cameras) if cam_indices is None else cam_indices
        frames = range(self.n_frames) if frame_indices is None else list(frame_indices)
        pairs = [[self.load_observation(ci, fi, allow_empty) for fi in frames] for ci in cams]
        return [[m for m, _ in row] for row in pairs], [[i for _, i in row] for row in pairs]

    def _check_unique_paths(self):
        seen = {}
        patterns = [("silhouettes", self.pattern)] + (
            [("ignore", self.masks["ignore"])] if "ignore" in self.masks else []
        )
        for kind, pat in patterns:
            for _ci, c in enumerate(self.cameras):
                for fi in range(self.n_frames):
                    p = pat.format(camera=c.name, frame=int(self._file_frames[fi]), time=Time(self.frame_times[fi]))
                    if p in seen:
                        raise ClothFitError(
                            f"capture {self.json_path}: {kind} pattern {pat!r} gives the same file {p} "
                            f"to {seen[p]} and to camera '{c.name}' frame {fi}{f' ({kind})' if kind != 'silhouettes' else ''}"
                        )
                    seen[p] = f"camera '{c.name}' frame {fi}" + (f" ({kind})" if kind != "silhouettes" else "")

    # ------------------------------------------------------------------ subset
    def subset(self, cam_indices: Iterable[int] | None = None, frame_indices: Iterable[int] | None = None) -> Capture:
        """The same capture restricted to some cameras and frames (files are not touched)."""
        cams = list(range(self.n_cameras)) if cam_indices is None else [self._check_cam(c) for c in cam_indices]
        frames = list(range(self.n_frames)) if frame_indices is None else [self._check_frame(f) for f in frame_indices]
        if not cams or not frames:
            raise ClothFitError(f"capture {self.json_path}: a subset needs at least one camera and one frame")
        if np.any(np.diff(frames) <= 0):
            raise ClothFitError(f"capture {self.json_path}: subset frame indices must increase, got {frames}")
        if len(set(cams)) != len(cams):
            raise ClothFitError(f"capture {self.json_path}: subset camera indices repeat: {cams}")
        scen = self.scenario.with_frames(self.frame_times[frames])
        shapes = None if self.shapes is None else self.shapes[frames]
        return Capture(
            self.root,
            [self.cameras[c] for c in cams],
            scen,
            self.pattern,
            shapes,
            self.cloth_mass,
            dict(self.meta),
            self.json_path,
            self._file_frames[frames],
            self._all_camera_names,
            model=self.model,
            masks=self.masks,
            uncertain=self.uncertain,
        )

    # ---------------------------------------------------------------- validate
    def validate(
        self, full: bool = True, allow_empty: bool = False, binarize_threshold: float | None = None
    ) -> Capture:
        """Check the capture against its files; raise one ClothFitError describing the problems.

        Always: the silhouette directory layout matches the cameras ("camera count mismatch"
        when the silhouette tree holds a camera that is not in cameras.json, or a camera of
        cameras.json has no silhouette at all), shapes are (F, V, 3). With ``full``, every
        silhouette of every camera and frame is also read and checked (exists, decodes, size,
        binary, not empty).
        """
        where = f"capture {self.json_path}"
        names = self.camera_names
        # ---- silhouette tree vs cameras
        found = self._scan_camera_names()
        unknown = [] if found is None else sorted(set(found) - set(self._all_camera_names))
        without = [
            c.name
            for ci, c in enumerate(self.cameras)
            if not any(os.path.isfile(self.silhouette_path(ci, fi)) for fi in range(self.n_frames))
        ]
        if unknown or without:
            all_names = self._all_camera_names
            msg = (
                f"{where}: camera count mismatch: cameras.json lists {len(all_names)} cameras ({names_str(all_names)})"
            )
            if found is not None:
                msg += (
                    f" but the silhouettes (pattern {self.pattern!r}) are for {len(set(found))} cameras "
                    f"({names_str(sorted(set(found)))})"
                )
            if unknown:
                msg += f"; silhouettes of cameras not in cameras.json: {', '.join(unknown)}"
            if without:
                msg += (
                    f"; cameras without any silhouette: {', '.join(without)} (expected e.g. "
                    f"{self.silhouette_path(names.index(without[0]), 0)})"
                )
            raise ClothFitError(msg)
        # ---- shapes
        if self.shapes is not None:
            check_shapes(self.shapes, self.n_frames, self.scenario.grid.n_vertices, where)
        # ---- every file
        if full:
            problems = []
            for ci in range(self.n_cameras):
                for fi in range(self.n_frames):
                    try:
                        self.load_observation(ci, fi, allow_empty=allow_empty, binarize_threshold=binarize_threshold)
                    except ClothFitError as e:
                        problems.append(str(e))
            if problems:
                head = "\n  ".join(problems[:10])
                more = f"\n  ... and {len(problems) - 10} more" if len(problems) > 10 else ""
                raise ClothFitError(
                    f"{where}: {len(problems)} bad silhouette file(s) of "
                    f"{self.n_cameras * self.n_frames}:\n  {head}{more}"
                )
        return self

    def _scan_camera_names(self):
        """Camera names present in the silhouette tree, or None when the pattern cannot be scanned.

        The tree is scanned at the first path component holding {camera}; the components before
        it must be plain directories. If that component is a directory level (e.g. sil/{camera}/...)
        sub-directories are matched, else files.
        """
        parts = self.pattern.replace("\\", "/").split("/")
        k = next(i for i, p in enumerate(parts) if "{camera" in p)
        for p in parts[:k]:
            if any(name is not None for _, name, _, _ in string.Formatter().parse(p)):
                return None
        parent = os.path.join(self.root, *parts[:k]) if k else self.root
        if not os.path.isdir(parent):
            return []
        rx = field_regex(parts[k])
        known = [(n, field_regex(parts[k], n)) for n in self._all_camera_names]
        is_dir_level = k < len(parts) - 1
        names = []
        for entry in sorted(os.listdir(parent)):
            if entry.startswith(".") or entry.endswith(".tmp"):
                continue
            full = os.path.join(parent, entry)
            if is_dir_level != os.path.isdir(full):
                continue
            name = next((n for n, r in known if r.match(entry)), None)
            if name is None:
                m = rx.match(entry)
                name = m.group("camera") if m else None
            if name is not None:
                names.append(name)
        return names

    # ------------------------------------------------------------------ io
    def to_dict(self) -> dict:
        d = {
            "format": FORMAT,
            "version": VERSION,
            "cameras": CAMERAS_JSON,
            "scenario": self.scenario.to_dict(),
            "frame_times": self.frame_times.tolist(),
            "silhouettes": self.pattern,
        }
        if self.shapes is not None:
            d["shapes"] = SHAPES_NPZ
        if self.cloth_mass is not None:
            d["cloth_mass"] = self.cloth_mass
        if self.model is not None:
            d["model"] = self.model
        d.update(self.masks)
        if self.uncertain is not None:
            d["uncertain"] = self.uncertain.to_dict()
        d["meta"] = self.meta
        return d


# ========================================================================= loading


def _resolve(root: str, rel, where: str, key: str) -> str:
    if not isinstance(rel, str) or not rel.strip():
        raise ClothFitError(f"{where}: '{key}' must be a file name, got {rel!r}")
    return rel if os.path.isabs(rel) else os.path.join(root, rel)


def load_capture(path: str | os.PathLike, validate: bool = False) -> Capture:
    """Read a capture directory (or its capture.json). Silhouettes are not read here.

    The JSON structure, cameras.json and shapes.npz are checked with precise messages; with
    ``validate=True`` also ``Capture.validate(full=True)`` (every silhouette file).
    """
    path = os.fspath(path)
    if os.path.isdir(path):
        json_path = os.path.join(path, CAPTURE_JSON)
        if not os.path.isfile(json_path):
            if os.path.isfile(os.path.join(path, CAMERAS_JSON)):  # a writer started but did not finish
                raise ClothFitError(
                    f"capture directory {path}: {CAPTURE_JSON} missing: the capture is incomplete "
                    f"({CAMERAS_JSON} was written but the writer never finalised it, e.g. a "
                    f"render or extraction stopped midway); write the capture again"
                )
            raise ClothFitError(f"capture directory {path} has no {CAPTURE_JSON} ({CAPTURE_JSON} missing: {json_path})")
    elif os.path.isfile(path):
        json_path = path
    else:
        raise ClothFitError(f"capture not found: {path} (give a capture directory or its {CAPTURE_JSON})")
    root = os.path.dirname(os.path.abspath(json_path))
    where = json_path

    try:
        with open(json_path, "rb") as f:
            raw = f.read()
        text = raw.decode("utf-8-sig")
    except (OSError, UnicodeDecodeError) as e:
        raise ClothFitError(f"{where}: cannot read ({e})") from None
    try:
        d = json.loads(text)
    except json.JSONDecodeError as e:
        raise ClothFitError(f"{where}: invalid JSON at line {e.lineno}, column {e.colno}: {e.msg}") from None
    if not isinstance(d, dict):
        raise ClothFitError(f"{where}: expected a JSON object at the top level, got {type(d).__name__}")

    fmt = d.get("format")
    if fmt != FORMAT:
        raise ClothFitError(f"{where}: 'format' is {fmt!r}, expected {FORMAT!r} (is this a capture.json?)")
    missing = [k for k in REQUIRED_KEYS if k not in d]
    if missing:
        raise ClothFitError(f"{where}: missing key(s) {', '.join(repr(k) for k in missing)}")
    ver = d["version"]
    if isinstance(ver, bool) or not isinstance(ver, int):
        raise ClothFitError(f"{where}: 'version' must be an integer, got {ver!r}")
    if ver != VERSION:
        raise ClothFitError(
            f"{where}: capture format version {ver} is not supported (this reader knows version {VERSION})"
        )

    # ---- scenario and frame times
    if not isinstance(d["scenario"], dict):
        raise ClothFitError(f"{where}: 'scenario' must be an object, got {type(d['scenario']).__name__}")
    try:
        scenario = Scenario.from_dict(d["scenario"], source=f"{where} scenario")
    except ClothFitError as e:
        msg = str(e)
        raise ClothFitError(msg if where in msg else f"{where}: {msg}") from None
    except (TypeError, ValueError, AttributeError, KeyError) as e:
        raise ClothFitError(f"{where}: bad 'scenario' ({type(e).__name__}: {e})") from None
    top = check_frame_times(d["frame_times"], where, "'frame_times'")
    st = scenario.frame_times
    if top.shape != st.shape or np.max(np.abs(top - st)) > FRAME_TIME_TOL:
        raise ClothFitError(
            f"{where}: frame_times mismatch between the top level {times_str(top)} and the scenario {times_str(st)}"
        )

    pattern = check_pattern(d["silhouettes"], f"{where}: 'silhouettes' pattern")

    # ---- cameras
    cam_path = _resolve(root, d["cameras"], where, "cameras")
    if not os.path.isfile(cam_path):
        raise ClothFitError(f"{where}: cameras file {cam_path} not found (named by 'cameras': {d['cameras']!r})")
    cameras = load_cameras(cam_path)

    # ---- optional parts
    shapes = None
    if d.get("shapes") is not None:
        shapes_path = _resolve(root, d["shapes"], where, "shapes")
        shapes = read_shapes(shapes_path, scenario.frame_times, scenario.grid.n_vertices)
    cloth_mass = check_cloth_mass(d.get("cloth_mass"), where)
    meta = d.get("meta", {})
    if meta is None:
        meta = {}
    if not isinstance(meta, dict):
        raise ClothFitError(f"{where}: 'meta' must be an object, got {type(meta).__name__}")

    masks = check_mask_spec({k: d.get(k) for k in MASK_KEYS}, where)
    cap = Capture(
        root,
        cameras,
        scenario,
        pattern,
        shapes,
        cloth_mass,
        meta,
        json_path=json_path,
        model=d.get("model"),
        masks=masks,
        uncertain=d.get("uncertain"),
    )
    if validate:
        cap.validate(full=True)
    return cap


def read_shapes(path: str, frame_times: ArrayLike | None = None, n_vertices: int | None = None) -> np.ndarray:
    """``positions`` (F, V, 3) of a shapes.npz, checked against the capture's frames and grid."""
    where = f"shapes file {path}"
    if not os.path.isfile(path):
        raise ClothFitError(f"{where}: not found")
    try:
        with np.load(path, allow_pickle=False) as z:
            keys = list(z.files)
            if "positions" not in keys:
                raise ClothFitError(f"{where}: no 'positions' array (arrays present: {', '.join(keys) or 'none'})")
            pos = np.array(z["positions"])
            ft = np.array(z["frame_times"]) if "frame_times" in keys else None
    except ClothFitError:
        raise
    except Exception as e:  # zipfile.BadZipFile, ValueError, OSError, EOFError...
        raise ClothFitError(f"{where}: corrupt or unreadable .npz ({type(e).__name__}: {e})") from None
    if frame_times is not None and n_vertices is not None:
        pos = check_shapes(pos, len(frame_times), n_vertices, where)
    if ft is not None and frame_times is not None:
        ft = ft.reshape(-1).astype(np.float64)
        ref = np.asarray(frame_times, dtype=np.float64)
        if ft.shape != ref.shape or np.max(np.abs(ft - ref)) > FRAME_TIME_TOL:
            raise ClothFitError(f"{where}: frame_times {times_str(ft)} differ from the capture's {times_str(ref)}")
    return pos


# ========================================================================= writing


def write_capture(
    root: str | os.PathLike,
    cameras: Iterable[Camera],
    scenario: Scenario,
    silhouettes: Sequence[Sequence[ArrayLike]] | None,
    shapes: ArrayLike | None = None,
    cloth_mass: float | None = None,
    meta: dict[str, Any] | None = None,
    pattern: str = DEFAULT_PATTERN,
    allow_empty: bool = False,
    finalize: bool = True,
    model: Any = None,
    ignore: Sequence[Sequence[ArrayLike | None]] | bool | None = None,
    ignore_pattern: str = DEFAULT_IGNORE_PATTERN,
    uncertain: Uncertainty | dict[str, Any] | None = None,
) -> Capture | PendingCapture:
    """Write a capture directory and return it as a ``Capture`` (or a ``PendingCapture``).

    ``silhouettes[c][f]`` (bool / 0-1 / 0-255 arrays of camera c's height x width) for every
    camera and every frame of ``scenario.frame_times``; or None when the caller writes each PNG
    itself at ``capture.silhouette_path(c, f)`` with ``save_silhouette`` (a renderer).
    Order: an old capture.json is removed first, then cameras.json, shapes.npz and the PNGs, and
    capture.json is written last (temporary file + rename), so a directory with a capture.json
    is always complete.

    ``finalize=False`` (the two-step API for renderers): everything but capture.json is written
    and a :class:`PendingCapture` is returned; the caller writes the silhouettes, then calls
    :func:`finalize_capture` (which checks that every silhouette file exists) to write
    capture.json. A writer that fails midway thus leaves no capture.json, and loading the
    directory says "capture.json missing". ``finalize=True`` with ``silhouettes=None`` writes
    capture.json at once (a metadata-only capture, e.g. a cameras container): only for callers
    that do not need the PNGs to be there.

    ``ignore[c][f]`` (bool arrays or None = nothing ignored): pixels whose truth is unknown
    (occluders), written as binary PNGs under ``ignore_pattern`` and named by the capture's
    ``ignore`` key. ``ignore=True`` with ``silhouettes=None``: the renderer writes them too, at
    ``capture.ignore_path(c, f)``.
    """
    root = os.path.abspath(os.fspath(root))
    masks = {"ignore": ignore_pattern} if ignore is not None else None
    cap = Capture(
        root, cameras, scenario, pattern, shapes, cloth_mass, meta, model=model, masks=masks, uncertain=uncertain
    )
    where = f"capture {cap.json_path}"
    if os.path.splitext(cap.pattern)[1].lower() != ".png":
        raise ClothFitError(
            f"{where}: silhouettes pattern {cap.pattern!r} must end with .png (silhouettes are written as lossless PNG)"
        )
    try:
        text = dumps(cap.to_dict(), strict=True)
    except (TypeError, ValueError) as e:
        raise ClothFitError(f"{where}: meta is not JSON serialisable ({e})") from None
    cap.meta = loads(text)["meta"]  # what a reader will get back

    ign_arrays = ignore if ignore is not None and ignore is not True else None
    if silhouettes is not None:
        _check_silhouettes(cap, silhouettes, allow_empty, where, ign_arrays)

    try:
        os.makedirs(root, exist_ok=True)
        if os.path.exists(cap.json_path):
            os.remove(cap.json_path)
        save_cameras(os.path.join(root, CAMERAS_JSON), cap.cameras)
        if cap.shapes is not None:
            buf = io.BytesIO()
            np.savez_compressed(buf, positions=cap.shapes, frame_times=cap.frame_times)
            atomic_write(os.path.join(root, SHAPES_NPZ), buf.getvalue())
    except OSError as e:
        raise ClothFitError(f"{where}: cannot write ({e})") from None

    if silhouettes is not None:
        for ci in range(cap.n_cameras):
            for fi in range(cap.n_frames):
                save_silhouette(cap.silhouette_path(ci, fi), silhouettes[ci][fi])
    else:
        for ci in range(cap.n_cameras):
            os.makedirs(os.path.dirname(cap.silhouette_path(ci, 0)), exist_ok=True)
            if cap.has_ignore:
                os.makedirs(os.path.dirname(cap.ignore_path(ci, 0)), exist_ok=True)
    if ign_arrays is not None:
        for ci, cam in enumerate(cap.cameras):
            for fi in range(cap.n_frames):
                m = ign_arrays[ci][fi]
                save_silhouette(cap.ignore_path(ci, fi), np.zeros((cam.height, cam.width), bool) if m is None else m)

    pending = PendingCapture(cap, text)
    if not finalize:
        return pending
    return pending.finalize(check_files=silhouettes is not None)


class PendingCapture:
    """A capture written except for its capture.json (``write_capture(..., finalize=False)``).

    ``capture`` is the ``Capture`` it will become (``silhouette_path`` etc. work already);
    :meth:`finalize` / :func:`finalize_capture` writes capture.json once every silhouette is there.
    Until then ``load_capture`` refuses the directory ("capture.json missing").
    """

    def __init__(self, capture: Capture, text: str):
        self.capture = capture
        self._text = text
        self.finalized = False

    @property
    def root(self) -> str:
        return self.capture.root

    @property
    def json_path(self) -> str:
        return self.capture.json_path

    def silhouette_path(self, cam_index: int, frame_index: int) -> str:
        return self.capture.silhouette_path(cam_index, frame_index)

    def ignore_path(self, cam_index: int, frame_index: int) -> str | None:
        return self.capture.ignore_path(cam_index, frame_index)

    def missing_silhouettes(self) -> list[str]:
        """Paths of the silhouette (and ignore mask) files not written yet."""
        cap = self.capture
        paths = [cap.silhouette_path(ci, fi) for ci in range(cap.n_cameras) for fi in range(cap.n_frames)]
        if cap.has_ignore:
            paths += [cap.ignore_path(ci, fi) for ci in range(cap.n_cameras) for fi in range(cap.n_frames)]
        return [p for p in paths if not os.path.isfile(p)]

    def finalize(self, check_files: bool = True) -> Capture:
        """Write capture.json (temporary file + rename) and return the ``Capture``.

        ``check_files``: refuse (ClothFitError naming the missing files) unless every
        silhouette file exists. The files' contents are not read (``validate`` does that)."""
        where = f"capture {self.json_path}"
        if check_files:
            missing = self.missing_silhouettes()
            if missing:
                n = self.capture.n_cameras * self.capture.n_frames
                head = "\n  ".join(missing[:5])
                more = f"\n  ... and {len(missing) - 5} more" if len(missing) > 5 else ""
                raise ClothFitError(
                    f"{where}: cannot finalise: {len(missing)} of {n} silhouette files are missing:\n  {head}{more}"
                )
        try:
            write_bytes_atomic(self.json_path, self._text.encode("utf-8"))
        except OSError as e:
            raise ClothFitError(f"{where}: cannot write ({e})") from None
        self.finalized = True
        return self.capture

    def __repr__(self):
        return f"PendingCapture({self.root!r}, finalized={self.finalized})"


def finalize_capture(pending: PendingCapture, check_files: bool = True) -> Capture:
    """Second step of ``write_capture(..., finalize=False)``: write capture.json last."""
    if not isinstance(pending, PendingCapture):
        raise ClothFitError(
            f"finalize_capture needs the PendingCapture returned by write_capture(..., "
            f"finalize=False), got {type(pending).__name__}"
        )
    return pending.finalize(check_files)


def _check_silhouettes(cap: Capture, silhouettes, allow_empty: bool, where: str, ignore=None):
    try:
        n = len(silhouettes)
    except TypeError:
        raise ClothFitError(
            f"{where}: silhouettes must be indexable [camera][frame], got {type(silhouettes).__name__}"
        ) from None
    if n != cap.n_cameras:
        raise ClothFitError(f"{where}: silhouettes for {n} cameras but {cap.n_cameras} cameras given")
    for ci, cam in enumerate(cap.cameras):
        row = silhouettes[ci]
        if len(row) != cap.n_frames:
            raise ClothFitError(
                f"{where}: camera '{cam.name}' has {len(row)} silhouettes but the scenario has "
                f"{cap.n_frames} frame times"
            )
        for fi in range(cap.n_frames):
            w = f"{where}: silhouette of camera '{cam.name}' frame {fi} (t={cap.frame_times[fi]:g})"
            m = mask_from_array(row[fi], w)
            if m.shape != (cam.height, cam.width):
                raise ClothFitError(f"{w}: shape {m.shape} but the camera is {cam.height} x {cam.width} (H x W)")
            if ignore is not None and ignore[ci][fi] is not None:
                g = mask_from_array(ignore[ci][fi], w + " ignore mask")
                if g.shape != m.shape:
                    raise ClothFitError(
                        f"{w}: ignore mask shape {g.shape} but the camera is {cam.height} x {cam.width}"
                    )
                m = m & ~g
            if not allow_empty and not m.any():
                raise ClothFitError(
                    f"{w}: empty silhouette (no object pixel{' outside the ignore mask' if ignore else ''})"
                )
