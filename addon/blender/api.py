# SPDX-License-Identifier: GPL-3.0-or-later
"""Scripting facade of the Blender layer: what the operators call, usable from any script.

Every function takes the scene (its ``scene.clothfit`` properties hold the settings) and raises
``ClothFitError`` on bad input; the operators turn that into a report. Typical pipeline::

    from addon.blender import api            # or bl_ext.<repo>.silhouette_cloth_fit.addon.blender
    api.build_rig(scene); api.build_cloth(scene); api.simulate(scene)
    cap = api.render_silhouettes(scene, "out/capture")
    result = api.run_fit(scene); api.apply_fit(scene); api.make_overlays(scene)
"""
from __future__ import annotations

import json
import math
import os
import time

import bpy
import numpy as np

from ..core import defaults as D
from ..core.camera import load_rig, ring_rig, select_training
from ..core.errors import ClothFitError
from ..core.model import ClothGrid, Params, paper_scenario
from . import render as R
from . import scene as S

RESULT_JSON = "fit_result.json"
OVERLAY_DIR = "overlays"


def props(scene):
    p = getattr(scene, "clothfit", None)
    if p is None:
        raise ClothFitError("Cloth Fit is not registered (scene.clothfit is missing)")
    return p


# ==================================================================== helpers

def parse_times(spec: str):
    """``"start:stop:step"`` (stop included) or ``"t1, t2, ..."`` -> sorted list of seconds."""
    s = (spec or "").strip()
    if not s:
        raise ClothFitError("frame times are empty: give start:stop:step or a comma list")
    try:
        if ":" in s:
            parts = [float(x) for x in s.split(":")]
            if len(parts) != 3:
                raise ValueError("need start:stop:step")
            a, b, st = parts
            if st <= 0 or b < a:
                raise ValueError("step must be > 0 and stop >= start")
            n = int(math.floor((b - a) / st + 1e-6)) + 1
            if n > 100000:
                raise ValueError("too many frames")
            t = [round(a + i * st, 9) for i in range(n)]
        else:
            t = [float(x) for x in s.replace(";", ",").split(",") if x.strip()]
    except ValueError as e:
        raise ClothFitError(f"frame times {spec!r}: {e}") from None
    t = sorted(set(t))
    if not t or t[0] < 0 or not all(math.isfinite(x) for x in t):
        raise ClothFitError(f"frame times {spec!r} must be finite and >= 0")
    return t


def abspath(path: str, what: str) -> str:
    if not path:
        raise ClothFitError(f"no {what} given")
    if path.startswith("//") and not bpy.data.filepath:
        raise ClothFitError(f"{what} {path!r} is relative to the .blend file, which is not saved yet: "
                            f"save the file or give an absolute path")
    return os.path.normpath(bpy.path.abspath(path))


def capture_dir(scene) -> str:
    return abspath(props(scene).capture_dir, "capture directory")


def params_from_scene(scene) -> Params:
    p = props(scene)
    par = Params(p.m, p.k, p.l, p.d)
    par.check("scene parameters")
    return par


def params_to_scene(scene, params):
    p = props(scene)
    d = params.as_dict() if hasattr(params, "as_dict") else dict(params)
    p.m, p.k, p.l, p.d = d["m"], d["k"], d["l"], d["d"]


# ======================================================================== rig

def rig_from_props(scene):
    p = props(scene)
    if p.rig_source == "PRESET":
        return load_rig(bpy.path.abspath(p.rig_preset) if p.rig_preset.startswith("//") else p.rig_preset)
    return ring_rig(n_per_ring=(p.ring_cameras,), elevations_deg=(p.ring_elevation,), distance=p.ring_distance,
                    target=(0.0, 0.0, p.ring_target_z), width=p.ring_width, height=p.ring_height, fx=p.ring_fx,
                    azimuth_offsets_deg=(0.0,))


def build_rig(scene, cameras=None):
    """Cameras (core ``Camera`` list, default: the rig the properties describe) into the scene."""
    return S.build_rig(scene, cameras if cameras is not None else rig_from_props(scene))


def rig_cameras(scene):
    return S.rig_cameras(scene)


# ====================================================================== cloth

def grid_from_props(scene) -> ClothGrid:
    p = props(scene)
    return ClothGrid(p.cloth_nx, side=p.cloth_side, height=p.cloth_height)


def capture_scenario(scene):
    """The loaded capture's scenario (handles, settling), for scenario source CAPTURE."""
    from ..core.capture import load_capture as core_load
    return core_load(capture_dir(scene)).scenario


def scenario_for(scene, grid: ClothGrid, times=None):
    """The manipulation to simulate: the paper's (panel settings) or the loaded capture's."""
    p = props(scene)
    times = times if times is not None else parse_times(p.frame_times)
    if p.scenario_source == "CAPTURE":
        sc = capture_scenario(scene)
        g = sc.grid
        if (g.nx, g.ny) != (grid.nx, grid.ny):
            raise ClothFitError(f"the capture's cloth is a {g.nx}x{g.ny} grid but the scene's cloth is "
                                f"{grid.nx}x{grid.ny}: rebuild the cloth")
        return sc.with_frames(times)
    if not 0 <= p.released_corner <= 3:
        raise ClothFitError(f"released corner {p.released_corner} must be 0..3")
    sc = paper_scenario(grid, frame_times=times, released_corner=p.released_corner)
    sc.settle_time = float(p.settle_time)
    return sc


def build_cloth(scene):
    p = props(scene)
    grid = capture_scenario(scene).grid if p.scenario_source == "CAPTURE" else grid_from_props(scene)
    sc = scenario_for(scene, grid)
    obj = S.build_cloth(scene, grid, sc.handles)
    p.cloth_object = obj
    return obj


def cloth_object(scene):
    """The cloth object, checked against the grid it was built from (missing / edited = error)."""
    p = props(scene)
    obj = p.cloth_object
    if obj is None or obj.name not in bpy.data.objects or obj.users == 0:
        obj = bpy.data.objects.get(S.CLOTH_NAME)
    if obj is None:
        raise ClothFitError("the cloth object is missing: build the cloth first")
    S.check_cloth(obj)
    return obj


def scene_scenario(scene, times=None):
    obj = cloth_object(scene)
    return scenario_for(scene, S.grid_from_object(obj), times), obj


# ================================================================= simulation

def simulate(scene):
    """Simulate the scene's parameters and bake: one shape key per capture time plus t = 0."""
    from ..core.simulate import simulate as core_simulate
    times = parse_times(props(scene).frame_times)
    bake_times = sorted(set([0.0] + times))
    sc, obj = scene_scenario(scene, bake_times)
    par = params_from_scene(scene)
    t0 = time.time()
    res = core_simulate(sc, [par])
    if res.exploded[0]:
        raise ClothFitError(f"the simulation with m={par.m:g}, k={par.k:g}, l={par.l:g}, d={par.d:g} is unstable: "
                            f"{res.reason[0]}")
    frames = S.bake_shape_keys(scene, obj, bake_times, res.positions[0])
    scene.frame_set(frames[0])
    return {"frames": frames, "times": bake_times, "seconds": time.time() - t0}


# ============================================================ observations

def render_silhouettes(scene, out_dir=None, noise=None, seed=None, progress=None):
    """Blender renders the cloth's silhouette from every rig camera at every capture time and
    writes a capture directory (core format). Returns the ``Capture``."""
    from ..core.capture import finalize_capture, save_silhouette, write_capture
    from ..core.metrics import add_boundary_noise
    from ..core.synth import noise_rng
    p = props(scene)
    root = abspath(out_dir, "capture directory") if out_dir else capture_dir(scene)
    noise = p.noise if noise is None else float(noise)
    seed = p.noise_seed if seed is None else int(seed)
    objs = S.rig_objects(scene)
    times = parse_times(p.frame_times)
    sc, cloth = scene_scenario(scene, times)
    missing = [t for t in times if f"t={t:.3f}" not in {kb.name for kb in
                                                       (cloth.data.shape_keys.key_blocks if cloth.data.shape_keys else [])}]
    if missing:
        raise ClothFitError(f"the cloth is not baked at t = {missing[0]:.3f} s ({len(missing)} capture times "
                            f"missing): simulate first")
    _refuse_foreign_capture(root)
    cams = S.rig_cameras(scene)
    shapes = S.baked_positions(cloth, times)
    par = params_from_scene(scene)
    meta = {"generator": f"{GENERATOR_PREFIX}{bpy.app.version_string} Workbench (addon/blender/render.py)",
            "true_params": par.as_dict(), "noise_fraction": noise, "seed": seed}
    # two steps: everything but capture.json now, capture.json only once every PNG is written, so a
    # render that fails midway never leaves a capture that looks complete
    pending = write_capture(root, cams, sc, None, shapes=shapes, cloth_mass=par.m * sc.grid.n_vertices, meta=meta,
                            finalize=False)
    frame0 = scene.frame_current
    tmp = os.path.join(root, ".render_tmp")
    os.makedirs(tmp, exist_ok=True)
    try:
        for fi, t in enumerate(times):
            scene.frame_set(S.frame_of_time(scene, t))
            masks = R.render_masks(scene, cloth, objs, tmpdir=tmp)
            for ci, m in enumerate(masks):
                if not m.any():
                    raise ClothFitError(f"camera '{cams[ci].name}' does not see the cloth at t = {t:.3f} s "
                                        f"(empty silhouette)")
                if noise > 0:
                    m = add_boundary_noise(m, noise, noise_rng(seed, ci, fi))
                save_silhouette(pending.silhouette_path(ci, fi), m)
            if progress:
                progress((fi + 1) / len(times))
        cap = finalize_capture(pending)
    finally:
        for f in os.listdir(tmp):
            os.remove(os.path.join(tmp, f))
        os.rmdir(tmp)
        scene.frame_set(frame0)
    p.capture_dir = root
    return cap


GENERATOR_PREFIX = "Blender "


def _refuse_foreign_capture(root):
    """Never overwrite a capture that this renderer did not write (real footage, synthetic...)."""
    path = os.path.join(root, "capture.json")
    if not os.path.isfile(path):
        return
    try:
        with open(path) as f:
            gen = str((json.load(f).get("meta") or {}).get("generator", ""))
    except (OSError, ValueError, AttributeError):
        gen = "?"
    if not gen.startswith(GENERATOR_PREFIX):
        raise ClothFitError(f"{root} already holds a capture written by {gen or 'another tool'!r}; Render Silhouettes "
                            f"only overwrites its own renders: choose another capture directory")


def load_capture(scene, path=None):
    """Read and fully validate a capture; its cameras become the rig, its scenario the settings,
    and each camera shows its observed silhouette (frame ``view_frame``) as background image."""
    from ..core.capture import load_capture as core_load
    p = props(scene)
    root = abspath(path, "capture directory") if path else capture_dir(scene)
    cap = core_load(root)
    cap.validate(full=True)
    S.build_rig(scene, cap.cameras)
    g = cap.scenario.grid
    p.cloth_nx, p.cloth_side, p.cloth_height = g.nx, g.side, g.height
    p.settle_time = cap.scenario.settle_time
    p.frame_times = ", ".join(f"{t:g}" for t in cap.frame_times)
    released = [h for h in cap.scenario.handles if h.release_time is not None]
    if released and released[0].vertex in g.corners():
        p.released_corner = g.corners().index(released[0].vertex)
    p.capture_dir = root
    p.scenario_source = "CAPTURE"
    p["view_frame"] = min(p.view_frame, cap.n_frames - 1)
    show_observations(scene, p.view_frame, cap)
    return cap


def _load_image(name, path):
    img = bpy.data.images.get(name)
    if img is None:
        img = bpy.data.images.load(path, check_existing=False)
        img.name = name
    elif bpy.path.abspath(img.filepath) != path:
        img.filepath = path
        img.reload()
    else:
        img.reload()
    return img


def show_background(cam_obj, image, alpha=0.6):
    cd = cam_obj.data
    bg = cd.background_images[0] if len(cd.background_images) else cd.background_images.new()
    bg.image = image
    bg.alpha = alpha
    bg.display_depth = "FRONT"
    cd.show_background_images = True
    return bg


def show_observations(scene, frame_index, cap=None, kind="observed"):
    """Camera backgrounds: observed silhouettes (or overlays) of capture frame ``frame_index``."""
    from ..core.capture import load_capture as core_load
    cap = cap or core_load(capture_dir(scene))
    fi = max(0, min(int(frame_index), cap.n_frames - 1))
    objs = {o.name: o for o in S.rig_objects(scene)}
    shown = 0
    for ci, c in enumerate(cap.cameras):
        obj = objs.get(c.name)
        if obj is None:
            continue
        if kind == "overlay":
            path = overlay_path(cap, ci, fi)
        else:
            path = cap.silhouette_path(ci, fi)
        if os.path.isfile(path):
            show_background(obj, _load_image(f"clothfit {kind} {c.name}", path))
            shown += 1
    return shown


# ===================================================================== fitting

def fit_config(scene, capture):
    from ..core.fitting import FitConfig
    p = props(scene)
    ncam = len(capture.cameras)
    if p.train_cameras > ncam:
        raise ClothFitError(f"{p.train_cameras} training cameras asked but the capture has {ncam}")
    train, _ = select_training(capture.cameras, p.train_cameras)
    times = None
    if p.train_times == "PAPER":
        have = [t for t in D.TRAIN_TIMES if np.any(np.abs(capture.frame_times - t) < 1e-6)]
        times = have or None
    res = None if p.fit_resolution == "FULL" else [int(x) for x in p.fit_resolution.split("x")]
    return FitConfig(train_cameras=train, train_times=times, optimizer=p.optimizer, seed=p.seed,
                     max_evaluations=p.max_evaluations, resolution=res,
                     cloth_mass=p.fit_cloth_mass if p.fit_cloth_mass > 0 else None)


class FitSession:
    """One fit in progress: the core job plus what the UI shows. ``step`` = one generation."""

    def __init__(self, scene, job, result_path):
        self.scene_name = scene.name
        self.job = job
        self.result_path = result_path
        self.timer = None
        self.started = time.time()
        self.threaded = False       # the modal operator runs generations in a worker thread
        self.worker = None          # threading.Thread running one job.step() (threaded mode)
        self._outcome = None        # (more, exception) of the worker's step

    def _work(self):
        try:
            self._outcome = (self.job.step(), None)
        except BaseException as e:  # handed over to the main thread, which re-raises it
            self._outcome = (False, e)

    def wait(self):
        """Block until the running worker step (if any) has finished."""
        if self.worker is not None:
            self.worker.join()

    @property
    def scene(self):
        return bpy.data.scenes.get(self.scene_name)

    def status_text(self):
        j = self.job
        bp = j.best_params
        s = (f"Cloth Fit: generation {j.generation}, {j.evaluations}/{j.config.max_evaluations} evaluations, "
             f"best E_all {j.best_error:.4g}")
        if bp:
            s += f" | m={bp['m']:.3g} k={bp['k']:.4g} l={bp['l']:.4g} d={bp['d']:.3g}"
        return s + " | Esc cancels (keeps the best)"


def start_fit(scene, capture=None):
    """Load the capture, build the core ``FitJob``; returns a ``FitSession``."""
    from ..core.capture import load_capture as core_load
    from ..core.fitting import FitJob
    p = props(scene)
    if p.fit_running:
        raise ClothFitError("a fit is already running in this scene")
    cap = capture or core_load(capture_dir(scene))
    job = FitJob(cap, fit_config(scene, cap))
    sess = FitSession(scene, job, os.path.join(cap.root, RESULT_JSON))
    p.fit_running = True
    p.fit_progress = 0.0
    p.fit_generation = p.fit_evaluations = 0
    p.fit_status = f"fitting {len(job.train_cameras)} cameras x {len(job.train_times)} times"
    return sess


def _publish(scene, job):
    p = props(scene)
    p.fit_progress = job.progress
    p.fit_generation = job.generation
    p.fit_evaluations = job.evaluations
    bp = job.best_params
    if bp:
        p.fit_best_error = job.best_error
        p.fit_best_pct = 100.0 * job.best_error / max(1, job.objective.n_images)
        p.fit_best_m, p.fit_best_k, p.fit_best_l, p.fit_best_d = bp["m"], bp["k"], bp["l"], bp["d"]
        p.fit_has_result = True


def fit_step(session) -> bool:
    """One generation; publishes the live status. Returns False when the job is finished."""
    more = session.job.step()
    _publish(session.scene, session.job)
    return more


def fit_tick(session):
    """Threaded stepping for the modal operator: the generation runs in a worker thread (numpy /
    numba only, no bpy), the main thread publishes. Returns None while a generation is running,
    True after a generation when there are more (the next one is started at once), False when the
    job is finished. Exceptions of the worker are re-raised here, on the main thread."""
    import threading
    if session.worker is not None:
        if session.worker.is_alive():
            return None
        session.worker.join()
        session.worker = None
        more, err = session._outcome
        session._outcome = None
        if err is not None:
            raise err
        _publish(session.scene, session.job)
        if not more:
            return False
    elif session.job.finished:
        return False
    else:
        more = None
    session.worker = threading.Thread(target=session._work, name="clothfit-fit-step", daemon=True)
    session.worker.start()
    return more


def finish_fit(session, cancelled=False):
    """Stop (cancel keeps the best), write the result JSON, update the status. -> (level, message)."""
    session.wait()  # a generation still running in the worker finishes first (its result is kept)
    if session.worker is not None:
        session.worker = None
        if session._outcome and session._outcome[1] is None:
            _publish(session.scene, session.job)
    job = session.job
    scene = session.scene
    if cancelled and not job.finished:
        job.cancel()
    elif cancelled:
        job.cancelled = True
    p = props(scene)
    p.fit_running = False
    _publish(scene, job)
    job.save_result(session.result_path)
    p.result_path = session.result_path
    bp = job.best_params
    if bp is None:
        p.fit_status = "cancelled before the first generation: no result"
        return "WARNING", "Fit cancelled before the first generation finished: no result"
    kept = f"best E_sil {p.fit_best_pct:.3f} % after {job.evaluations} evaluations"
    if job.cancelled:
        p.fit_status = f"cancelled at generation {job.generation}; {kept} kept"
        return "WARNING", f"Fit cancelled at generation {job.generation}: {kept} kept ({session.result_path})"
    p.fit_status = f"finished: {kept}"
    return "INFO", f"Fit finished: {kept}; k={bp['k']:.4g} l={bp['l']:.4g} d={bp['d']:.3g} ({session.result_path})"


def run_fit(scene, callback=None):
    """Synchronous fit (background mode, scripts). ``callback(session) -> True`` cancels."""
    sess = start_fit(scene)
    cancelled = False
    try:
        while fit_step(sess):
            if callback is not None and callback(sess):
                cancelled = True
                break
    except BaseException:
        props(scene).fit_running = False
        raise
    level, msg = finish_fit(sess, cancelled)
    return sess.job.result(), level, msg


def load_result(scene, path=None):
    p = props(scene)
    path = path or (bpy.path.abspath(p.result_path) if p.result_path else os.path.join(capture_dir(scene), RESULT_JSON))
    if not os.path.isfile(path):
        raise ClothFitError(f"no fit result at {path}: run the fit first")
    try:
        with open(path) as f:
            res = json.load(f)
    except (OSError, json.JSONDecodeError) as e:
        raise ClothFitError(f"fit result {path} is unreadable: {e}") from None
    if not isinstance(res, dict) or not isinstance(res.get("params"), dict):
        raise ClothFitError(f"fit result {path} has no parameters (the fit found none)")
    return res


def apply_fit(scene, result=None):
    """Fitted parameters -> the scene's m, k, l, d; then re-simulate and bake."""
    p = props(scene)
    if result is None and p.fit_has_result and p.fit_best_k > 0:
        par = Params(p.fit_best_m, p.fit_best_k, p.fit_best_l, p.fit_best_d)
        try:  # prefer the full-precision numbers of the result file
            par = Params.from_dict(load_result(scene)["params"], "fit result")
        except ClothFitError:
            pass
    else:
        res = result if result is not None else load_result(scene)
        par = Params.from_dict(res["params"] if "params" in res else res, "fit result")
    par.check("fitted parameters")
    params_to_scene(scene, par)
    return simulate(scene)


# ==================================================================== overlays

def overlay_path(cap, ci, fi):
    return os.path.join(cap.root, OVERLAY_DIR, cap.cameras[ci].name, f"{fi:03d}.png")


def model_masks_core(scene, cap, frame_indices):
    from ..core.raster import silhouette
    from ..core.simulate import simulate as core_simulate
    sc = cap.scenario.with_frames([float(cap.frame_times[i]) for i in frame_indices])
    res = core_simulate(sc, [params_from_scene(scene)])
    if res.exploded[0]:
        raise ClothFitError(f"the scene's parameters make the simulation unstable: {res.reason[0]}")
    X = res.positions[0]
    tris = sc.grid.triangles
    return [[silhouette(c, X[k], tris) for k in range(len(frame_indices))] for c in cap.cameras]


def model_masks_blender(scene, cap, frame_indices):
    cloth = cloth_object(scene)
    baked = {round(t, 3) for t in S.baked_times(cloth)}
    times = [float(cap.frame_times[i]) for i in frame_indices]
    miss = [t for t in times if round(t, 3) not in baked]
    if miss:
        raise ClothFitError(f"the cloth is not baked at t = {miss[0]:.3f} s: simulate (or apply the fit) first")
    objs = {o.name: o for o in S.rig_objects(scene)}
    cam_objs = []
    for c in cap.cameras:
        if c.name not in objs:
            raise ClothFitError(f"the rig has no camera '{c.name}' of the capture: load the capture first")
        cam_objs.append(objs[c.name])
    out = [[None] * len(times) for _ in cap.cameras]
    frame0 = scene.frame_current
    try:
        for k, t in enumerate(times):
            scene.frame_set(S.frame_of_time(scene, t))
            for ci, m in enumerate(R.render_masks(scene, cloth, cam_objs)):
                out[ci][k] = m
    finally:
        scene.frame_set(frame0)
    return out


def make_overlays(scene, source=None, frame_indices=None, sheet_frame=None):
    """Observed vs. model silhouettes per camera and frame -> ``<capture>/overlays/<cam>/<f>.png``,
    a contact sheet of all cameras at one frame, E_sil per image in ``overlays/summary.json``;
    cameras show their overlay as background. Returns the summary dict."""
    from ..core.capture import load_capture as core_load
    from ..core.metrics import e_sil
    from ..core.overlay import contact_sheet, label, overlay_image, write_rgb
    p = props(scene)
    cap = core_load(capture_dir(scene))
    fidx = list(range(cap.n_frames)) if frame_indices is None else [int(i) for i in frame_indices]
    for i in fidx:
        if not 0 <= i < cap.n_frames:
            raise ClothFitError(f"overlay frame index {i} outside 0..{cap.n_frames - 1}")
    source = source or p.overlay_source
    model = (model_masks_blender if source == "BLENDER" else model_masks_core)(scene, cap, fidx)
    errs = np.zeros((cap.n_cameras, len(fidx)))
    sheet_fi = fidx[len(fidx) // 2] if sheet_frame is None else int(sheet_frame)
    tiles = []
    for ci, c in enumerate(cap.cameras):
        for k, fi in enumerate(fidx):
            obs = cap.load_silhouette(ci, fi)
            mod = model[ci][k]
            if mod.shape != obs.shape:
                raise ClothFitError(f"camera '{c.name}': model silhouette {mod.shape} and observed {obs.shape} differ "
                                    f"in size")
            errs[ci, k] = e_sil(obs, mod, name=cap.silhouette_path(ci, fi))
            img = overlay_image(obs, mod)
            write_rgb(overlay_path(cap, ci, fi), img)
            if fi == sheet_fi:
                tiles.append(label(img, f"{c.name} t={cap.frame_times[fi]:.2f} E={100 * errs[ci, k]:.2f}%"))
    out_dir = os.path.join(cap.root, OVERLAY_DIR)
    sheet_path = None
    if tiles:
        sheet = contact_sheet(tiles, cols=min(6, len(tiles)))
        sheet_path = os.path.join(out_dir, "contact_sheet.png")
        write_rgb(sheet_path, sheet)
        img = _load_image("clothfit contact sheet", sheet_path)
        img.use_fake_user = False
    summary = {"source": source, "params": params_from_scene(scene).as_dict(),
               "frames": fidx, "times": [float(cap.frame_times[i]) for i in fidx],
               "cameras": cap.camera_names, "E_sil_pct": (100 * errs).tolist(),
               "mean_E_sil_pct": float(100 * errs.mean()), "contact_sheet": sheet_path,
               "contact_sheet_frame": sheet_fi}
    with open(os.path.join(out_dir, "summary.json"), "w") as f:
        json.dump(summary, f, indent=1)
    p.overlay_dir = out_dir
    p.overlay_error = summary["mean_E_sil_pct"]
    show_observations(scene, p.view_frame if p.view_frame in fidx else fidx[0], cap, kind="overlay")
    return summary
