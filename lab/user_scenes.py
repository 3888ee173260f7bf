"""Blender scenes built the way a user builds them, as test truths, and why the core's
``blender`` model drifts from Blender on them.

``build`` (bpy): four .blend files made with bpy operators as a user clicks them in the UI:

* ``cotton``: Add > Mesh > Grid (16 x 16 subdivisions, 2 m), scaled to 0.3 and lifted to 1 m
  (object transform NOT applied), Cloth with the Cotton preset, Quality 15;
* ``silk``: Add > Mesh > Plane, Edit Mode > Subdivide (15 cuts), scaled to 0.3 and lifted,
  then Object > Apply > All Transforms, Cloth with the Silk preset, Quality 15;
* ``denim``: a Grid as ``cotton``, rotated 90 degrees about Z (not applied), the Denim preset,
  Quality 15;
* ``drop``: a Grid as ``cotton`` (default Cloth settings, Quality 5, no pins) falling onto a
  block (Add > Cube, scaled, Physics > Collision): the tablecloth of the tutorials.

Every scene keeps the defaults a user does not touch: 20 fps here, Speed Multiplier 1, Blender's
default frame range and cache, collisions of the cloth on. The three hanging cloths have a vertex
group "Pin" holding the four corners (weight 1, as Assign with the default weight does) as the
Cloth's Pin Group, and release one corner the way the Blender Stack Exchange answers do it: a
second group "Release" with that corner, and a Vertex Weight Mix modifier (A = Pin, B = Release,
Subtract, vertices in both) moved above the Cloth modifier, its Global Influence keyed 0 at frame
21 and 1 at frame 22 (default Bezier keys: the cloth reads whole frames, where they are 0 and 1).

``observe``: Blender's own solver simulates each scene (in a child process: this driver never
imports bpy) and reads the cloth as the solver receives it (``addon/blender/user_cloth.py``:
mesh, edge order, first-frame world positions, pin weights and targets per frame); the true
vertices and the scene reading are saved; silhouettes by the core rasteriser on the scene's own
triangles (it agrees with Workbench to < 1 % XOR) for a rig that is not ours (10 cameras around
the cloth at 1.5 - 2.3 m, 480 x 640, fx 520), with 5 % boundary noise. Captures in our format:
the scenario is what a user would declare, the 17 x 17 grid of 0.6 m at 1 m height with its four
corners as handles (one released at t = 0, the last frame it is held); a mesh that is not such a
grid (any vertex order, any 90-degree turn is fine) is refused: the capture format needs a grid.
The true shapes are stored in the grid's vertex order (the permutation is in meta).

``drift`` (no bpy): the core blender model with the TRUE settings against Blender's motion: as
a user gets it from the capture (``declared``), built from the scene itself (``scene``), and with
one difference at a time between the two (vertex numbering, face list, edge order, first-frame
positions, release frame, time scale, quality, pin weights, modifier order), plus the solver's own
chaos (one setting one float32 step off). ``all``: the three in order.

    python lab/user_scenes.py all --out out/user_scenes --json out/user_scenes/user_scenes.json
"""

from __future__ import annotations

import argparse
import math
import os
import subprocess
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)

from clothfit.core.errors import ClothFitError  # noqa: E402
from clothfit.core.physics import blender as B  # noqa: E402
from clothfit.core.physics.blender_scene import SceneCloth, grid_order  # noqa: E402
from clothfit.core.physics.scenario import ClothGrid, Handle, Scenario  # noqa: E402

FPS = 20  # the scenes' frame rate (Speed Multiplier 1: the cloth falls as under 0.4 g)
CUTS = 16  # quads per side: 17 x 17 vertices
SIZE = 2.0  # the primitives' default size
SCALE = 0.3  # the user's scale: a 0.6 m cloth
HEIGHT = 1.0  # lifted to 1 m
RELEASE = 21  # scene frame: the corner is held through this frame, free from the next
AFTER = 60  # frames captured after the release (3 s)
FRAME_START = 1  # Blender's default first frame (the cloth's rest frame)
NOISE = 0.05
SEED = 0

SCENES = {
    "cotton": {"mesh": "grid", "preset": "Cotton", "quality": 15, "rotate_z": 0.0, "apply": False, "pins": True},
    "silk": {"mesh": "plane", "preset": "Silk", "quality": 15, "rotate_z": 0.0, "apply": True, "pins": True},
    "denim": {"mesh": "grid", "preset": "Denim", "quality": 15, "rotate_z": 90.0, "apply": False, "pins": True},
    "drop": {"mesh": "grid", "preset": None, "quality": 5, "rotate_z": 0.0, "apply": False, "pins": False},
}
BLOCK = {"size": 0.3, "top": 0.6}  # the drop scene's block: 0.3 m wide, its top 0.4 m below the cloth


def configure(cuts=None, release=None, after=None):
    """Change the scenes' size and timing (smaller scenes for quick runs and tests)."""
    global CUTS, RELEASE, AFTER
    if cuts is not None:
        if cuts < 2:
            raise ClothFitError(f"--cuts {cuts}: a cloth needs at least 2 quads per side")
        CUTS = int(cuts)
    if release is not None:
        if release < FRAME_START + 1:
            raise ClothFitError(
                f"--release {release}: the corner must be held at least one frame after frame {FRAME_START}"
            )
        RELEASE = int(release)
    if after is not None:
        if after < 2:
            raise ClothFitError(f"--after {after}: at least 2 frames after the release")
        AFTER = int(after)


def _size_args():
    return ["--cuts", str(CUTS), "--release", str(RELEASE), "--after", str(AFTER)]


def side() -> float:
    return SIZE * SCALE


def n_frames(name) -> int:
    """Frames read after the first: the capture's, plus one (a release declared one frame late)."""
    return (RELEASE - FRAME_START if SCENES[name]["pins"] else 0) + AFTER + 1


def release_index(name) -> int:
    """The frame index (from the first frame) of t = 0."""
    return RELEASE - FRAME_START if SCENES[name]["pins"] else 0


# =============================================================================== build (bpy)


def _preset(cl, name):
    import bpy

    path = os.path.join(bpy.utils.preset_paths("cloth")[0], f"{name}.py")
    with bpy.context.temp_override(cloth=cl):
        bpy.ops.script.execute_preset(filepath=path, menu_idname="CLOTH_PT_presets")


def _select_only(obj):
    import bpy

    bpy.ops.object.select_all(action="DESELECT")
    obj.select_set(True)
    bpy.context.view_layer.objects.active = obj


def build_scene(
    name, path=None, cuts=None, release=None, end=None, pin_weight=1.0, mix_below_cloth=False, release_keys=(0, 1)
):
    """Build scene ``name`` of ``SCENES`` in the current (emptied) Blender session with bpy operators,
    as a user clicks it; save it to ``path`` when given. Returns the cloth object.

    ``pin_weight`` (the weight the corners are assigned), ``mix_below_cloth`` (the Vertex Weight Mix
    left below the Cloth modifier, where a new modifier lands) and ``release_keys`` (the frames,
    relative to ``release``, of the influence keys 0 and 1) build a user's slips, for the tests."""
    import bpy

    spec = SCENES[name]
    cuts = CUTS if cuts is None else cuts
    release = RELEASE if release is None else release
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.fps, scene.render.fps_base = FPS, 1.0
    scene.frame_start = FRAME_START
    loc = (0.0, 0.0, HEIGHT)
    rot = (0.0, 0.0, math.radians(spec["rotate_z"]))
    if spec["mesh"] == "grid":
        bpy.ops.mesh.primitive_grid_add(x_subdivisions=cuts, y_subdivisions=cuts, size=SIZE, location=loc, rotation=rot)
        obj = bpy.context.active_object
    else:
        bpy.ops.mesh.primitive_plane_add(size=SIZE, location=loc, rotation=rot)
        obj = bpy.context.active_object
        bpy.ops.object.mode_set(mode="EDIT")
        bpy.ops.mesh.select_all(action="SELECT")
        bpy.ops.mesh.subdivide(number_cuts=cuts - 1)
        bpy.ops.object.mode_set(mode="OBJECT")
    obj.name = "Cloth"
    obj.scale = (SCALE, SCALE, SCALE)
    if spec["apply"]:
        _select_only(obj)
        bpy.ops.object.transform_apply(location=True, rotation=True, scale=True)
    if spec["pins"]:
        # the corners, found as a user sees them: the four vertices farthest from the middle
        co = np.array([v.co[:] for v in obj.data.vertices])
        r = np.abs(co[:, 0] - co[:, 0].mean()) + np.abs(co[:, 1] - co[:, 1].mean())
        corners = sorted(np.argsort(-r, kind="stable")[:4].tolist())
        released = min(corners)
        pin = obj.vertex_groups.new(name="Pin")
        pin.add(corners, float(pin_weight), "REPLACE")
        rel = obj.vertex_groups.new(name="Release")
        rel.add([released], 1.0, "REPLACE")
    _select_only(obj)
    bpy.ops.object.modifier_add(type="CLOTH")
    cl = obj.modifiers[-1]
    if spec["preset"]:
        _preset(cl, spec["preset"])
    cl.settings.quality = spec["quality"]
    if spec["pins"]:
        cl.settings.vertex_group_mass = "Pin"
        bpy.ops.object.modifier_add(type="VERTEX_WEIGHT_MIX")
        mix = obj.modifiers[-1]
        if not mix_below_cloth:
            bpy.ops.object.modifier_move_to_index(modifier=mix.name, index=0)
        mix.vertex_group_a, mix.vertex_group_b = "Pin", "Release"
        mix.mix_mode, mix.mix_set = "SUB", "AND"
        for value, df in zip((0.0, 1.0), release_keys):
            mix.mask_constant = value
            mix.keyframe_insert("mask_constant", frame=release + df)
    else:
        h = BLOCK["size"]
        bpy.ops.mesh.primitive_cube_add(size=SIZE, location=(0.0, 0.0, BLOCK["top"] - h / 2))
        block = bpy.context.active_object
        block.name = "Block"
        block.scale = (h / SIZE, h / SIZE, h / SIZE)
        bpy.ops.object.modifier_add(type="COLLISION")
    if end is not None:
        scene.frame_end = end
        cl.point_cache.frame_end = end
    scene.frame_set(FRAME_START)
    if path:
        os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
        bpy.ops.wm.save_as_mainfile(filepath=os.path.abspath(path))
    return obj


def build(out, names=None):
    for name in names or SCENES:
        p = os.path.join(out, "blends", f"{name}.blend")
        build_scene(name, p)
        print(f"built {name}: {p}", flush=True)


# ===================================================================== simulate (bpy, a child)


def ulp_up(v: float) -> float:
    """The next float32 above ``v``: the smallest change Blender's settings can take."""
    return float(np.nextafter(np.float32(v), np.float32(np.inf)))


SLIPS = {  # a user's slips built into a copy of a hanging scene: build_scene keyword arguments
    "release_keyed_over_5_frames": {"release_keys": (0, 5)},
    "pins_painted_0.95": {"pin_weight": 0.95},
    "mix_left_below_cloth": {"mix_below_cloth": True},
}
FLOOR_SETTINGS = ("tension_stiffness", "mass", "air_damping")  # each one float32 step up: the solver's chaos


def _blender_run(scene, obj, n, out, stem, info, floors=()):
    """Read the cloth (scene-cloth file) and simulate it in Blender: ``{stem}_scene.npz`` and
    ``{stem}_blender.npz`` (frames, and frames with each setting of ``floors`` one float32 step up)."""
    import io

    from clothfit.blender.cloth import cloth_modifier, simulate_frames
    from clothfit.blender.user_cloth import read_scene_cloth
    from clothfit.core.safeio import atomic_write

    sc = read_scene_cloth(scene, obj, n, info)
    sc.save(os.path.join(out, "truth", f"{stem}_scene.npz"))
    c0, t0 = time.process_time(), time.perf_counter()
    X, secs, its = simulate_frames(scene, obj, n)
    cpu = time.process_time() - c0
    arrays = {"frames": X, "cpu_s": cpu, "wall_s": time.perf_counter() - t0}
    cs = cloth_modifier(obj).settings
    for k in floors:
        v = getattr(cs, k)
        setattr(cs, k, ulp_up(v))
        arrays[f"frames_ulp_{k}"], _, _ = simulate_frames(scene, obj, n)
        setattr(cs, k, v)
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    atomic_write(os.path.join(out, "truth", f"{stem}_blender.npz"), buf.getvalue())
    return sc, cpu


def simulate(out, names=None):
    """Blender's solver on every scene (and on copies with a user's slips): the scene reading and
    Blender's frames, saved under ``out/truth``."""
    import bpy
    from clothfit.blender.render import quiet_stdout
    from clothfit.blender.scene_worker import find_cloth_object

    os.makedirs(os.path.join(out, "truth"), exist_ok=True)
    for name in names or SCENES:
        path = os.path.abspath(os.path.join(out, "blends", f"{name}.blend"))
        with quiet_stdout():
            bpy.ops.wm.open_mainfile(filepath=path, load_ui=False)
        scene = bpy.context.scene
        obj = find_cloth_object(scene)
        n = n_frames(name)
        floors = FLOOR_SETTINGS if not SCENES[name]["pins"] else FLOOR_SETTINGS[:1]
        sc, cpu = _blender_run(scene, obj, n, out, name, {"blend": path, "scene_name": name}, floors)
        print(
            f"simulated {name}: {n + 1} frames, {sc.n_vertices} vertices, {cpu:.1f} s CPU; "
            f"not modelled by the core: {sc.info['not_modelled'] or 'nothing'}",
            flush=True,
        )
        if not SCENES[name]["pins"]:
            continue
        for slip, kw in SLIPS.items():
            obj = build_scene(name, **kw)
            _blender_run(bpy.context.scene, obj, n, out, f"{name}_{slip}", {"scene_name": name, "slip": slip})
        print(f"simulated {name} with the slips {', '.join(SLIPS)}", flush=True)


# ===================================================================== observe (no bpy)


def rig():
    """Ten cameras as someone sets up tripods and phones around a hanging cloth: irregular
    azimuths, distances and heights, 480 x 640, fx 520 (a 63 degree horizontal view)."""
    from clothfit.core.observation.camera import Camera, intrinsics, look_at

    spots = [
        (8, 1.9, 1.05),
        (47, 1.6, 0.45),
        (83, 2.2, 1.6),
        (121, 1.7, 0.8),
        (158, 2.0, 1.25),
        (197, 1.55, 0.6),
        (236, 2.3, 1.9),
        (272, 1.8, 0.35),
        (311, 1.65, 1.15),
        (345, 2.1, 2.1),
    ]
    cams = []
    for k, (az, dist, z) in enumerate(spots):
        a = math.radians(az)
        eye = np.array([dist * math.cos(a), dist * math.sin(a), z])
        target = np.array([0.03 * math.sin(3 * a), 0.03 * math.cos(2 * a), 0.72])
        R, t = look_at(eye, target)
        cams.append(Camera(intrinsics(520.0, 640, 480), R, t, 640, 480, name=f"user{k:02d}"))
    return cams


def declared_scenario(name, grid=None, sc: SceneCloth | None = None) -> Scenario:
    """What a user declares for scene ``name``: the grid (17 x 17, 0.6 m, at 1 m), the corners as
    handles at the grid's corner positions, the released one (the corner the scene releases, found
    from the scene reading ``sc``) free after t = 0, settling from the first frame to t = 0."""
    grid = grid or ClothGrid(CUTS + 1, CUTS + 1, side(), height=HEIGHT)
    times = np.arange(1, AFTER + 1) / FPS
    if not SCENES[name]["pins"]:
        return Scenario(grid, [], times, 0.0, (0.0, 0.0, -9.81))
    corners = grid.corners()
    released = None
    if sc is not None:
        p = grid_order(sc.rest, grid)
        q = np.empty_like(p)
        q[p] = np.arange(p.size)
        r = release_index(name)
        freed = [
            int(q[v]) for v, w0, w1 in zip(sc.handle_vertices, sc.weights[r], sc.weights[r + 1]) if w0 > 0 and w1 == 0
        ]
        released = freed[0] if freed else None
    hs = [Handle(v, [0.0], grid.rest[v][None], 0.0 if v == released else None) for v in corners]
    return Scenario(grid, hs, times, (RELEASE - FRAME_START) / FPS, (0.0, 0.0, -9.81))


def load_truth(out, stem):
    sc = SceneCloth.load(os.path.join(out, "truth", f"{stem}_scene.npz"))
    with np.load(os.path.join(out, "truth", f"{stem}_blender.npz")) as z:
        tr = {k: z[k] for k in z.files}
    return sc, tr


def capture_frames(name):
    """Frame indices (from the first frame) of the capture times."""
    return release_index(name) + np.arange(1, AFTER + 1)


def observe(out, names=None):
    """Blender simulates (a child process), then the captures are written (no bpy here)."""
    from clothfit.core.observation.capture import write_capture
    from clothfit.core.observation.metrics import add_boundary_noise
    from clothfit.core.observation.raster import silhouette
    from clothfit.core.observation.synth import noise_rng

    me = os.path.abspath(__file__)
    sel = (["--scenes", ",".join(names)] if names else []) + _size_args()
    subprocess.run([sys.executable, me, "simulate", "--out", out] + sel, check=True)
    cams = rig()
    for name in names or SCENES:
        sc, tr = load_truth(out, name)
        grid = ClothGrid(CUTS + 1, CUTS + 1, side(), height=HEIGHT)
        p = grid_order(sc.rest, grid)
        if p is None:
            raise ClothFitError(
                f"scene {name}: its mesh is not the declared {grid.nx} x {grid.ny} grid of "
                f"{grid.side:g} m at {grid.height:g} m: the capture format needs a grid"
            )
        scen = declared_scenario(name, grid, sc)
        X = tr["frames"][capture_frames(name)]  # mesh order
        sils = []
        for ci, cam in enumerate(cams):
            row = []
            for fi in range(X.shape[0]):
                m = silhouette(cam, X[fi], sc.triangles)
                if not m.any():
                    raise ClothFitError(f"scene {name}: camera {cam.name} does not see the cloth at frame {fi}")
                row.append(add_boundary_noise(m, NOISE, noise_rng(SEED, ci, fi)))
            sils.append(row)
        s = sc.settings
        meta = {
            "generator": "Blender's own Cloth modifier on a scene built as a user builds it "
            "(lab/user_scenes.py), core rasteriser on the scene's triangles",
            "blend": sc.info.get("blend"),
            "object": sc.info.get("object"),
            "true_blender_cloth": s,
            "true_model": {"name": "blender", "fps": float(FPS), "quality": s["quality"]},
            "frame_zero": FRAME_START + release_index(name),
            "fps": float(FPS),
            "mesh_vertex_of_grid_vertex": p.tolist(),
            "noise_fraction": NOISE,
            "seed": SEED,
            "not_modelled": sc.info.get("not_modelled", []),
        }
        root = os.path.join(out, "captures", name)
        write_capture(root, cams, scen, sils, shapes=X[:, p], cloth_mass=s["mass"] * X.shape[1], meta=meta)
        print(f"observed {name}: {len(cams)} cameras x {X.shape[0]} frames -> {root}", flush=True)


# ======================================================================== drift (no bpy)


class Variant:
    """The core blender model between the user's declaration and the scene: each of five parts
    taken from the declared grid (False) or from the scene (True)."""

    PARTS = ("labels", "faces", "edges", "rest", "plan")

    def __init__(self, sc: SceneCloth, name: str):
        self.sc, self.name = sc, name
        self.grid = ClothGrid(CUTS + 1, CUTS + 1, side(), height=HEIGHT)
        self.p = grid_order(sc.rest, self.grid)  # grid vertex g is mesh vertex p[g]
        if self.p is None:
            raise ClothFitError(f"scene {name}: not the declared grid")
        self.q = np.empty_like(self.p)
        self.q[self.p] = np.arange(self.p.size)  # mesh vertex v is grid vertex q[v]
        self.scenario = declared_scenario(name, self.grid, sc)
        self.dplan = B.FramePlan.from_scenario(self.scenario, FPS)
        first = self.grid.rest.copy()
        first[self.dplan.handle_vertices] = self.dplan.targets[0]
        self.drest = np.empty_like(first)
        self.drest[self.p] = first  # the declared first frame, mesh labels

    def build(
        self,
        labels=True,
        faces=True,
        edges=True,
        rest=True,
        plan=True,
        weights_shift=0,
        frames_shift=0,
        weight=None,
        release=True,
    ):
        """(network, frame plan, vertex map to mesh labels or None) of one mix of the parts.

        Slips: ``weights_shift`` frames later pin weights (the release), ``frames_shift`` frames
        later capture frames read from the model, ``weight`` for the weight-1 pins, ``release=False``
        keeps every pin."""
        sc, p, q = self.sc, self.p, self.q
        fc = sc.faces if faces else [[int(p[g]) for g in quad] for quad in self.grid.quads]
        ed = sc.edges if edges else None
        X0 = sc.rest if rest else self.drest
        nf = sc.n_frames
        frames = capture_frames(self.name) + frames_shift
        if plan:
            hv, W = sc.handle_vertices, sc.weights.copy()
            T = sc.targets if rest else self.drest[hv][None].repeat(nf + 1, 0)
        else:
            hv = p[self.dplan.handle_vertices]
            W = np.zeros((nf + 1, hv.size))
            W[: self.dplan.weights.shape[0]] = self.dplan.weights
            W[self.dplan.weights.shape[0] :] = self.dplan.weights[-1]
            T = self.drest[hv][None].repeat(nf + 1, 0) if not rest else np.array([sc.rest[hv]] * (nf + 1))
        if weights_shift > 0:
            W = np.concatenate([W[:1].repeat(weights_shift, 0), W[:-weights_shift]])
        if not release:
            W = np.where(W.max(0, keepdims=True) > 0, W.max(0, keepdims=True), 0.0).repeat(nf + 1, 0)
        if weight is not None:
            W = np.where(W >= 1.0, weight, W)
        if not labels:  # renumber everything to the grid's numbering
            X0 = X0[p]
            fc = [[int(q[v]) for v in f] for f in fc]
            ed = None if ed is None else q[ed]
            hv = q[hv]
        net = B.Network.from_mesh(X0, fc, sc.settings["bending_model"], edges=ed)
        lo = frames.astype(np.int64)
        pl = B.FramePlan(
            float(FPS), release_index(self.name), nf, np.asarray(hv, dtype=np.int64), T, W, lo, lo, np.zeros(lo.size), 0
        )
        return net, pl, (None if labels else p)

    def run(self, rows=None, quality=None, **parts):
        """Positions at the capture times in MESH labels (P, F, V, 3), and the triangles used."""
        net, pl, back = self.build(**parts)
        from clothfit.core.physics.blender_kernels import Prepared

        rows = np.atleast_2d(self.sc.settings_row() if rows is None else rows)
        ts = float(rows[0, B.FLOAT_SETTINGS.index("time_scale")])
        q = int(self.sc.settings["quality"] if quality is None else quality)
        prep = Prepared(net, pl, q, ts, self.sc.gravity)
        out, codes, _ = prep.run(rows)
        X = prep.sample(out)
        tris = net.triangles
        if back is not None:  # grid labels -> mesh labels
            Y = np.empty_like(X)
            Y[:, :, back] = X
            X = Y
            tris = back[tris]
        return X, tris, codes


class Scorer:
    """Distance [mm] and held-out silhouette error [%] of model positions against a truth: the
    held-out cameras (all but the 4 a fit would train on) at the test times (t = 0.05, 0.15, ...),
    observed silhouettes as ``observe`` makes them (the capture's, or made the same way for a
    truth that has no capture)."""

    def __init__(self, cap, truth, tris, from_capture=True):
        from clothfit.core.observation.camera import select_training
        from clothfit.core.observation.metrics import add_boundary_noise
        from clothfit.core.observation.raster import silhouette
        from clothfit.core.observation.synth import noise_rng

        self.cams = cap.cameras
        _, self.held = select_training(self.cams, 4)
        self.test = list(range(0, AFTER, 2))
        self.truth = truth
        self.obs = {}
        for c in self.held:
            for f in self.test:
                self.obs[c, f] = (
                    cap.load_silhouette(c, f)
                    if from_capture
                    else add_boundary_noise(silhouette(self.cams[c], truth[f], tris), NOISE, noise_rng(SEED, c, f))
                )

    def esil(self, X, tris) -> float:
        from clothfit.core.observation.metrics import e_sil
        from clothfit.core.observation.raster import silhouette

        return 100.0 * float(
            np.mean([e_sil(o, silhouette(self.cams[c], X[f], tris)) for (c, f), o in self.obs.items()])
        )

    def __call__(self, X, tris, frames=None) -> dict:
        """``X`` (F, V, 3) or (1, F, V, 3) in the truth's vertex order; ``frames``: only those
        capture frames count for the distance (default all)."""
        X = X[0] if X.ndim == 4 else X
        sel = slice(None) if frames is None else frames
        if not np.all(np.isfinite(X[sel])):
            return {"mean_mm": None, "max_mm": None, "heldout_E_sil_pct": None, "exploded": True}
        d = np.linalg.norm(X[sel] - self.truth[sel], axis=-1) * 1000.0
        r = {"mean_mm": float(d.mean()), "max_mm": float(d.max())}
        if frames is None:
            r["heldout_E_sil_pct"] = self.esil(X, tris)
        return r


def _exact(X, T) -> dict:
    """How close two frame sets are against one float32 step of their coordinates (the output
    round trip local -> world of an object whose transform is not applied)."""
    d = np.linalg.norm(X - T, axis=-1)
    ulp = float(np.spacing(np.float32(np.abs(T).max())))
    beyond = np.nonzero(d.max(-1) > ulp)[0]
    return {
        "max_mm": float(d.max() * 1000),
        "one_float32_step_mm": ulp * 1000,
        "bitwise_equal": bool(np.array_equal(X, T)),
        "first_frame_beyond_one_step": int(beyond[0]) if beyond.size else None,
    }


def _fmt(r):
    if r.get("skipped"):
        return f"skipped: {r['skipped']}"
    if r.get("exploded"):
        return "exploded"
    e = r.get("heldout_E_sil_pct")
    return f"{r['mean_mm']:8.3f} / {r['max_mm']:8.3f} mm" + ("" if e is None else f"  E_sil {e:6.2f} %")


def drift_scene(out, name) -> dict:
    """One scene: the core blender model with the true settings against Blender, declared and
    built from the scene, and each cause of their difference alone."""
    from clothfit.core.observation.capture import load_capture
    from clothfit.core.physics.models import BlenderModel

    sc, tr = load_truth(out, name)
    cap = load_capture(os.path.join(out, "captures", name))
    cf = capture_frames(name)
    T = tr["frames"][cf]
    v = Variant(sc, name)
    score = Scorer(cap, T, sc.triangles)
    res = {
        "vertices": sc.n_vertices,
        "settings": sc.settings,
        "not_modelled": sc.info.get("not_modelled", []),
        "blend": sc.info.get("blend"),
        "modifiers": sc.info.get("modifiers"),
        "vertex_order_is_grid_order": bool(np.all(v.p == np.arange(v.p.size))),
        "faces_are_grid_quads": [list(f) for f in sc.faces] == v.p[v.grid.quads].tolist(),
        "same_quads_other_order": sorted(map(tuple, sc.faces)) == sorted(map(tuple, v.p[v.grid.quads].tolist())),
        "edges_are_face_side_order": bool(np.array_equal(np.sort(sc.edges, 1), sc.network(edges=None).edges)),
        "blender_cpu_s": float(tr["cpu_s"]),
        "floor_heldout_E_sil_pct": score.esil(T, sc.triangles),
    }
    d32, s32 = v.drest.astype(np.float32), sc.rest.astype(np.float32)
    res["first_frame_declared_vs_scene"] = {
        "coordinates_differing_pct": 100.0 * float(np.mean(d32 != s32)),
        "max_difference_um": float(np.abs(d32.astype(np.float64) - s32).max() * 1e6),
    }
    row = B.settings_row(B.check_settings(cap.meta["true_blender_cloth"]))
    q = sc.settings["quality"]

    def declared(fps=FPS):
        m = BlenderModel(fps, q, sc.settings["bending_model"])
        sim = m.simulate(cap.scenario, row[None])
        X = np.full_like(sim.positions, np.nan)
        X[:, :, v.p] = sim.positions
        return X, v.p[cap.scenario.grid.triangles], sim

    # before: the core model as a user gets it from the capture (its own grid and declaration)
    Xd, td, sim = declared()
    res["declared"] = score(Xd, td)
    if sim.exploded[0]:
        res["declared"]["reason"] = sim.reason[0]
    # after: the core model built from the scene reading
    Xs, ts_, _ = v.run()
    res["scene"] = score(Xs, ts_)
    full, _ = sc.simulate()
    res["scene_vs_blender_every_frame"] = _exact(full[0], tr["frames"])
    # the solver's own chaos: one setting one float32 step up, in Blender (and in the core)
    floor = {}
    for k in FLOOR_SETTINGS:
        if f"frames_ulp_{k}" in tr:
            floor[k] = score(tr[f"frames_ulp_{k}"][cf], sc.triangles)
    res["blender_one_step"] = floor
    up = sc.settings_row(tension_stiffness=ulp_up(sc.settings["tension_stiffness"]))
    fu, _ = sc.simulate(up[None])
    res["core_one_step_vs_blender_one_step"] = _exact(fu[0], tr["frames_ulp_tension_stiffness"])
    if not SCENES[name]["pins"]:  # a collider: the core has no collisions; exact until contact
        contact = res["scene_vs_blender_every_frame"]["first_frame_beyond_one_step"]
        res["contact_frame"] = contact
        return res
    # the parts of the declaration, one at a time (the rest from the scene), and all of them
    causes = {}
    for part in Variant.PARTS:
        Xc, tc, _ = v.run(**{part: False})
        causes[part] = score(Xc, tc) | {"identical_to_scene": bool(np.array_equal(Xc, Xs))}
    Xh, th, _ = v.run(labels=False, faces=False, edges=False, rest=False, plan=False)
    res["declared_rebuilt_equal"] = bool(np.array_equal(Xh, Xd))
    causes["triangulation_only"] = {
        "heldout_E_sil_pct": score.esil(Xs[0], td),
        "mean_mm": 0.0,
        "max_mm": 0.0,
        "note": "the scene's positions drawn with the declared grid's triangles",
    }
    res["rounding_causes"] = causes
    # the user's slips
    slips = {}
    # t = 0 declared one frame after the true release: the model lets go one frame late
    slips["release_declared_one_frame_late"] = score(*v.run(weights_shift=1)[:2])
    # the cloth's first frame one frame earlier than the scene's: it settles one frame longer
    slips["settles_one_frame_longer"] = score(*v.run(weights_shift=1, frames_shift=1)[:2])
    slips["time_scale_real_time"] = score(*v.run(rows=sc.settings_row(time_scale=B.physical_time_scale(FPS))[None])[:2])
    slips["quality_5"] = score(*v.run(quality=5)[:2])
    try:  # the model's default frame rate (24) instead of the scene's
        X24, t24, _ = declared(24.0)
        slips["fps_24"] = score(X24, t24)
    except ClothFitError as e:  # the declared settling is not whole frames at 24 fps
        slips["fps_24"] = {"mean_mm": None, "max_mm": None, "heldout_E_sil_pct": None, "skipped": str(e)}
    for slip in SLIPS:  # Blender ran a copy of the scene with the slip
        ss, st = load_truth(out, f"{name}_{slip}")
        Tv = st["frames"][cf]
        sv = Scorer(cap, Tv, sc.triangles, from_capture=False)
        r = sv(Xs, ts_)  # the model as declared (= the scene's own) against that Blender
        full_v, _ = ss.simulate()
        r["scene_model_of_the_slip"] = _exact(full_v[0], st["frames"])
        slips[slip] = r
    res["slips"] = slips
    return res


SLIP_NAMES = {
    "release_declared_one_frame_late": "t = 0 declared one frame after the release",
    "settles_one_frame_longer": "cloth's first frame one frame earlier (settles one frame longer)",
    "release_keyed_over_5_frames": "influence keyed over 5 frames (Blender)",
    "pins_painted_0.95": "pins assigned weight 0.95 (Blender)",
    "mix_left_below_cloth": "Vertex Weight Mix left below the Cloth (Blender)",
    "quality_5": "quality 5 (the model's default) instead of 15",
    "fps_24": "capture times read at 24 fps (the model's default)",
    "time_scale_real_time": "time_scale for real time (sqrt(1000)/fps) instead of 1",
}
PART_NAMES = {
    "labels": "vertex numbering",
    "faces": "face list (order, first corner)",
    "edges": "edge order (structural springs)",
    "rest": "first-frame positions (float32)",
    "plan": "pins and release as declared",
}


def summary(rows) -> dict:
    """The ranges the docs quote."""
    hang = [n for n, r in rows.items() if "slips" in r]
    out = {"hanging_scenes": hang}

    def rng(vals):
        vals = [v for v in vals if v is not None]
        return [min(vals), max(vals)] if vals else None

    if hang:
        H = [rows[n] for n in hang]
        out["scene_vs_blender_max_mm"] = max(r["scene_vs_blender_every_frame"]["max_mm"] for r in H)
        out["one_float32_step_mm"] = max(r["scene_vs_blender_every_frame"]["one_float32_step_mm"] for r in H)
        out["bitwise_equal_scenes"] = [n for n in hang if rows[n]["scene_vs_blender_every_frame"]["bitwise_equal"]]
        out["slip_scene_models_max_mm"] = max(
            c["scene_model_of_the_slip"]["max_mm"]
            for r in H
            for c in r["slips"].values()
            if "scene_model_of_the_slip" in c
        )
        out["core_one_step_vs_blender_one_step_max_mm"] = max(
            r["core_one_step_vs_blender_one_step"]["max_mm"] for r in H
        )
        out["declared_mean_mm"] = rng([r["declared"]["mean_mm"] for r in H])
        out["declared_max_mm"] = rng([r["declared"]["max_mm"] for r in H])
        out["declared_E_sil_pct"] = rng([r["declared"]["heldout_E_sil_pct"] for r in H])
        out["floor_E_sil_pct"] = rng([r["floor_heldout_E_sil_pct"] for r in H])
        out["rounding_alone_mean_mm"] = rng(
            [c["mean_mm"] for r in H for k, c in r["rounding_causes"].items() if k in PART_NAMES]
        )
        out["rounding_alone_max_mm"] = rng(
            [c["max_mm"] for r in H for k, c in r["rounding_causes"].items() if k in PART_NAMES]
        )
        out["blender_one_step_mean_mm"] = rng([r["blender_one_step"]["tension_stiffness"]["mean_mm"] for r in H])
        out["blender_one_step_max_mm"] = rng([r["blender_one_step"]["tension_stiffness"]["max_mm"] for r in H])
        out["slips"] = {
            k: {
                "mean_mm": rng([r["slips"][k]["mean_mm"] for r in H]),
                "max_mm": rng([r["slips"][k]["max_mm"] for r in H]),
                "E_sil_pct": rng([r["slips"][k]["heldout_E_sil_pct"] for r in H]),
            }
            for k in SLIP_NAMES
            if all(k in r["slips"] for r in H)
        }
    drop = [r for r in rows.values() if "contact_frame" in r]
    if drop:
        d = drop[0]
        f = d["blender_one_step"]
        out["collider"] = {
            "contact_frame": d["contact_frame"],
            "blender_one_step_mean_mm": rng([c["mean_mm"] for c in f.values()]),
            "blender_one_step_max_mm": rng([c["max_mm"] for c in f.values()]),
            "blender_one_step_E_sil_pct": rng([c["heldout_E_sil_pct"] for c in f.values()]),
            "floor_E_sil_pct": d["floor_heldout_E_sil_pct"],
        }
    return out


def _mm(c):
    if c is None or c.get("mean_mm") is None:
        return "-"
    e = c.get("heldout_E_sil_pct")
    return f"{c['mean_mm']:.3f} / {c['max_mm']:.3f}" + ("" if e is None else f" ({e:.2f} %)")


def format_table(doc) -> str:
    """Per scene: the core model as declared and as built from the scene, against Blender."""
    rows = doc["scenes"]
    out = [
        "| scene | mesh | core model as declared: mean / max mm (held-out E_sil) | "
        "built from the scene | every frame, max mm | noise floor E_sil | Blender, one float32 step of "
        "tension: mean / max mm (E_sil) |",
        "|---|---|---|---|---|---|---|",
    ]
    for n, r in rows.items():
        spec = SCENES.get(n, {})
        mesh = (
            ("Grid" if spec.get("mesh") == "grid" else "subdivided Plane")
            + (f" turned {spec['rotate_z']:g} deg" if spec.get("rotate_z") else "")
            + ("; transform applied" if spec.get("apply") else "; transform kept")
        )
        order = "numbered as our grid" if r["vertex_order_is_grid_order"] else "its own numbering"
        dec = (
            "exploded (no collisions: falls through the block)" if r["declared"].get("exploded") else _mm(r["declared"])
        )
        ex = r["scene_vs_blender_every_frame"]
        every = (
            "0 (bitwise)"
            if ex["bitwise_equal"]
            else f"{ex['max_mm']:.1e}"
            if ex["first_frame_beyond_one_step"] is None
            else f"exact to frame {ex['first_frame_beyond_one_step'] - 1}, then no collisions"
        )
        sc = _mm(r["scene"]) if "slips" in r else "-"
        out.append(
            f"| {n} (quality {r['settings']['quality']}) | {mesh}; {order} | {dec} | {sc} | {every} | "
            f"{r['floor_heldout_E_sil_pct']:.2f} % | {_mm(r['blender_one_step']['tension_stiffness'])} |"
        )
    return "\n".join(out)


def format_causes(doc) -> str:
    """Each difference alone (the rest from the scene) against Blender, per hanging scene."""
    rows = {n: r for n, r in doc["scenes"].items() if "slips" in r}
    names = list(rows)
    out = [
        "| difference from the scene, alone | " + " | ".join(f"{n}: mean / max mm (E_sil)" for n in names) + " |",
        "|---|" + "---|" * len(names),
    ]
    for k, label in PART_NAMES.items():
        cells = []
        for n in names:
            c = rows[n]["rounding_causes"][k]
            cells.append("no change" if c.get("identical_to_scene") else _mm(c))
        out.append(f"| {label} | " + " | ".join(cells) + " |")
    out.append(
        "| the declared grid's triangles (silhouettes only) | "
        + " | ".join(f"({rows[n]['rounding_causes']['triangulation_only']['heldout_E_sil_pct']:.2f} %)" for n in names)
        + " |"
    )
    for k, label in SLIP_NAMES.items():
        out.append(f"| {label} | " + " | ".join(_mm(rows[n]["slips"].get(k)) for n in names) + " |")
    return "\n".join(out)


def drift(out, names=None, json_path=None):
    """The core blender model with the true settings against Blender, per scene and cause."""
    rows = {}
    c0, t0 = time.process_time(), time.perf_counter()
    for name in names or SCENES:
        r = rows[name] = drift_scene(out, name)
        ex = r["scene_vs_blender_every_frame"]
        print(
            f"{name}: declared {_fmt(r['declared'])}; scene {_fmt(r['scene'])} (floor E_sil "
            f"{r['floor_heldout_E_sil_pct']:.2f} %); scene vs Blender every frame max {ex['max_mm']:.2g} mm "
            f"(one float32 step {ex['one_float32_step_mm']:.2g} mm, first beyond: {ex['first_frame_beyond_one_step']})",
            flush=True,
        )
        for k, c in r["blender_one_step"].items():
            print(f"    Blender, {k} one float32 step up: {_fmt(c)}", flush=True)
        for group in ("rounding_causes", "slips"):
            for k, c in r.get(group, {}).items():
                extra = "  (no change)" if c.get("identical_to_scene") else ""
                if "scene_model_of_the_slip" in c:
                    extra = (
                        f"  (scene model of that Blender scene: max {c['scene_model_of_the_slip']['max_mm']:.2g} mm)"
                    )
                if c.get("mean_mm") is not None and c.get("note"):
                    print(f"    {k:34s} E_sil {c['heldout_E_sil_pct']:6.2f} %", flush=True)
                else:
                    print(f"    {k:34s} {_fmt(c)}{extra}", flush=True)
    doc = {
        "scenes": rows,
        "summary": summary(rows),
        "fps": FPS,
        "after_frames": AFTER,
        "release_frame": RELEASE,
        "grid": CUTS + 1,
        "cameras": len(rig()),
        "drift_cpu_s": time.process_time() - c0,
        "drift_wall_s": time.perf_counter() - t0,
    }
    print(format_table(doc), flush=True)
    print(format_causes(doc), flush=True)
    if json_path:
        from clothfit.core.jsonio import write_json

        os.makedirs(os.path.dirname(os.path.abspath(json_path)), exist_ok=True)
        write_json(json_path, doc)
    return doc


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument(
        "step",
        choices=["build", "simulate", "observe", "drift", "all"],
        help="build the .blend files (bpy), simulate them in Blender (bpy), observe (simulate in a "
        "child, then write captures), drift (core model vs Blender), or all of them",
    )
    ap.add_argument("--out", default="out/user_scenes", help="output directory")
    ap.add_argument("--scenes", default=None, help=f"comma-separated subset of {', '.join(SCENES)}")
    ap.add_argument("--json", default=None, help="write the drift figures to this JSON file")
    ap.add_argument("--cuts", type=int, default=CUTS, help="quads per side of the cloth meshes")
    ap.add_argument("--release", type=int, default=RELEASE, help="the last scene frame the corner is held")
    ap.add_argument("--after", type=int, default=AFTER, help="frames captured after the release")
    a = ap.parse_args(argv)
    try:
        configure(a.cuts, a.release, a.after)
    except ClothFitError as e:
        ap.error(str(e))
    names = [s.strip() for s in a.scenes.split(",")] if a.scenes else None
    for n in names or []:
        if n not in SCENES:
            ap.error(f"unknown scene {n!r} (choose from {', '.join(SCENES)})")
    me = os.path.abspath(__file__)
    sel = (["--scenes", a.scenes] if a.scenes else []) + _size_args()
    if a.step == "build":
        build(a.out, names)
    elif a.step == "simulate":
        simulate(a.out, names)
    elif a.step == "observe":
        observe(a.out, names)
    elif a.step == "drift":
        drift(a.out, names, a.json)
    else:
        subprocess.run([sys.executable, me, "build", "--out", a.out] + sel, check=True)
        observe(a.out, names)
        drift(a.out, names, a.json)
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except ClothFitError as e:
        print(f"error: {e}", file=sys.stderr)
        sys.exit(2)
