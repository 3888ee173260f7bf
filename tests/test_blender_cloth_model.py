"""The core's ``blender`` cloth model against Blender's own Cloth modifier (real bpy module), and
the Blender-model fit's inputs and outputs.

Measured figures on the 21 x 21 sheet: ``python -m clothfit blender-agreement`` (docs/results.md,
"Blender's cloth: agreement with Blender, identifiability").
"""

import json
import os

import numpy as np
import pytest
from blender_support import bpy, factory  # noqa: F401
from clothfit import cli  # noqa: E402
from clothfit.blender import agreement  # noqa: E402
from clothfit.core.errors import ClothFitError  # noqa: E402
from clothfit.core.physics import blender as B  # noqa: E402
from clothfit.core.physics.models import BlenderModel, get_model, model_and_row  # noqa: E402

pytestmark = pytest.mark.usefixtures("factory")

CASES = [
    ("default", {}),
    ("silk, linear bending", dict(agreement.PRESETS["silk"], bending_model="LINEAR")),
    ("quality 2", {"quality": 2}),
    ("denim, quality 12", agreement.PRESETS["denim"]),
    ("soft pins", {"pin_stiffness": 5.0, agreement.PIN_WEIGHT: 0.95}),
]


@pytest.mark.parametrize("name,settings", CASES, ids=[c[0] for c in CASES])
def test_core_blender_model_moves_like_blenders_cloth(name, settings):
    """Hung by four corners, settled, one corner released: every vertex of every frame within
    0.01 mm of Blender's (the goal is mean < 0.1 mm, max < 1 mm; the kernel follows Blender's
    float32 operations, so the measured figure is 0)."""
    scene = bpy.context.scene
    sc = agreement.agreement_scenario(9, settle=0.5, after=0.75)
    r = agreement.compare(scene, sc, settings)
    assert r["frames"] == 1 + 12 + 18
    assert r["max_mm"] < 0.01, r
    # the comparison is not vacuous: the released corner falls by centimetres
    assert r["blender_cg_iterations"] is None or r["blender_cg_iterations"] > 0


def _slack_scenario(n=9, hold=0.8, settle=0.5, after=0.5):
    """The agreement sheet held with slack, as hands hold a cloth: its corners at ``hold`` of its size."""
    from clothfit.core.physics.scenario import Handle, Scenario

    sc = agreement.agreement_scenario(n, settle=settle, after=after)
    c = sc.grid.rest.mean(0)
    hs = [
        Handle(h.vertex, h.times, c + hold * (h.positions - c) * np.array([1.0, 1.0, 0.0]), h.release_time)
        for h in sc.handles
    ]
    return Scenario(sc.grid, hs, sc.frame_times, sc.settle_time, sc.gravity)


def test_slack_hold_keeps_the_flat_rest_shape_and_blender_agrees():
    """Corners held closer than the cloth's size: the rest shape (every rest length) is the flat
    sheet's, the handles come to their held places during the first half of the settle, and Blender
    built from that plan (keyed hooks) moves like the core to the bit."""
    sc = _slack_scenario()
    net, plan = BlenderModel(24).plan(sc)
    flat = B.Network.from_grid(sc.grid)
    assert np.array_equal(net.rest, sc.grid.rest) and np.allclose(net.struct_len, flat.struct_len)
    held = np.array([h.positions[0] for h in sc.handles])
    assert np.allclose(plan.targets[0], sc.grid.rest[plan.handle_vertices])
    ramp_end = round(plan.settle_frames * 0.5)
    assert np.allclose(plan.targets[ramp_end:, 1:], held[None, 1:])  # the held (unreleased) ones stay there
    assert np.all(np.diff(plan.ramp) >= 0) and plan.ramp[0] == 0 and plan.ramp[ramp_end] == 1
    r = agreement.compare(bpy.context.scene, sc, {})
    assert r["max_mm"] < 0.01, r


def test_the_comparison_sees_a_wrong_setting():
    """Blender's cloth with a different stiffness than the core's is reported far away."""
    scene = bpy.context.scene
    sc = agreement.agreement_scenario(9, settle=0.5, after=0.75)
    from clothfit.blender import cloth as BC
    from clothfit.core.physics.blender_kernels import Prepared

    s = B.check_settings({"time_scale": B.physical_time_scale(24)})
    model = BlenderModel(24)
    net, plan = model.plan(sc)
    core, _, _ = Prepared(net, plan, 5, s["time_scale"], sc.gravity, all_frames=True).run(B.settings_row(s)[None])
    obj = BC.build_cloth_object(scene, net, plan, dict(s, tension_stiffness=5.0, compression_stiffness=5.0))
    pos, _, _ = BC.simulate_frames(scene, obj, plan.n_frames, 1)
    d = np.linalg.norm(core[0] - pos, axis=-1) * 1000
    assert d.max() > 1.0


def test_export_blender_cloth_applies_in_blender(tmp_path, capsys):
    """A blender-model result's settings, exported and set on a Cloth modifier, are ClothSettings
    Blender accepts (every key an attribute, every value kept)."""
    res = {
        "model": {"name": "blender", "fps": 30.0, "quality": 7, "bending_model": "LINEAR"},
        "blender_cloth": B.check_settings(
            {
                "quality": 7,
                "bending_model": "LINEAR",
                "tension_stiffness": 33.0,
                "air_damping": 0.2,
                "time_scale": B.physical_time_scale(30),
            }
        ),
        "blender_scene": {"fps": 30.0},
    }
    p = tmp_path / "r.json"
    p.write_text(json.dumps(res))
    assert cli.main(["export-blender-cloth", str(p)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["blender_scene"] == {"fps": 30.0}
    me = bpy.data.meshes.new("m")
    me.from_pydata([(0, 0, 0), (1, 0, 0), (0, 1, 0)], [], [(0, 1, 2)])
    obj = bpy.data.objects.new("o", me)
    bpy.context.scene.collection.objects.link(obj)
    cs = obj.modifiers.new("Cloth", "CLOTH").settings
    for k, v in out["blender_cloth"].items():
        setattr(cs, k, v)
    for k, v in out["blender_cloth"].items():
        got = getattr(cs, k)
        assert got == v if isinstance(v, str) else got == pytest.approx(v, rel=1e-6), k


def test_result_without_blender_settings_is_refused(tmp_path, capsys):
    p = tmp_path / "paper.json"
    p.write_text(json.dumps({"model": {"name": "paper"}, "params": {"m": 1e-5, "k": 10, "l": 0.006, "d": 1e-4}}))
    assert cli.main(["export-blender-cloth", str(p)]) == 2
    assert "no Blender cloth settings" in capsys.readouterr().err


@pytest.mark.parametrize(
    "spec,msg",
    [
        ("cloth3000", "unknown model"),
        ({"name": "blender", "quality": 0}, "quality 0 must be >= 1"),
        ({"name": "blender", "fps": -24}, "frame rate"),
        ({"name": "blender", "bending_model": "CURVED"}, "bending_model"),
        ({"name": "blender", "gravity": 2}, "unknown key"),
    ],
)
def test_bad_models_are_one_line_errors(spec, msg):
    with pytest.raises(ClothFitError, match=msg):
        get_model(spec)


@pytest.mark.parametrize(
    "settings,msg",
    [
        ({"tension_stiffness": -1.0}, "tension_stiffness"),
        ({"mass": 0.0}, "mass"),
        ({"air_damping": float("nan")}, "air_damping"),
        ({"quality": 2.5}, "whole number"),
        ({"stiffness": 5}, "unknown or unsupported"),
    ],
)
def test_settings_outside_blenders_ranges_are_refused(settings, msg):
    with pytest.raises(ClothFitError, match=msg):
        model_and_row({"blender_cloth": settings})


def test_settings_that_explode_are_reported_not_raised():
    sc = agreement.agreement_scenario(7, settle=0.25, after=0.25)
    tear = {
        "tension_stiffness": 0.0,
        "compression_stiffness": 0.0,
        "shear_stiffness": 0.0,
        "bending_stiffness": 0.0,
        "time_scale": 10.0,
    }
    fly = {
        "quality": 1,
        "time_scale": 100.0,
        "tension_stiffness": 0.0,
        "compression_stiffness": 10000,
        "mass": 0.001,
        "air_damping": 0,
        "tension_damping": 0,
        "compression_damping": 0,
        "shear_damping": 0,
    }
    ok = {"time_scale": B.physical_time_scale(24)}
    rows = np.stack([B.settings_row(B.check_settings(s)) for s in (tear, ok, fly)])
    for backend in ("numba", "numpy"):
        sim = BlenderModel(24, 1).simulate(sc, rows, backend=backend)
        assert sim.exploded.tolist() == [True, False, True]
        assert "overstretched" in sim.reason[0] and "flew away" in sim.reason[2]
        assert np.isnan(sim.positions[[0, 2]]).all() and np.isfinite(sim.positions[1]).all()


def test_numpy_reference_tracks_the_kernel():
    """The float64 numpy reference (the backend without numba) follows the float32 kernel to a
    fraction of a millimetre on average; the kernel, not the reference, is Blender's to the bit
    (the CG's stopping iteration depends on rounding, so the two drift apart slowly)."""
    pytest.importorskip("numba")
    sc = agreement.agreement_scenario(9, settle=0.5, after=0.5)
    for st in ({}, dict(agreement.PRESETS["silk"]), {"bending_model": "LINEAR"}):
        s = B.check_settings(dict(st, time_scale=B.physical_time_scale(24)))
        m = BlenderModel(24, s["quality"], s["bending_model"])
        a = m.simulate(sc, B.settings_row(s), backend="numba").positions[0]
        b = m.simulate(sc, B.settings_row(s), backend="numpy").positions[0]
        d = np.linalg.norm(a - b, axis=-1) * 1000
        assert d.mean() < 0.3 and d.max() < 5.0, (st, d.mean(), d.max())


def test_numpy_reference_tracks_the_kernel_on_a_slack_hold_with_offsets():
    """Held with slack and with handle offsets (a fit of uncertain pins): the kernel's candidates and
    the reference's moved scenarios ramp the same way (the offset moves the held place only)."""
    pytest.importorskip("numba")
    from clothfit.core.physics.scenario import Offsets

    sc = _slack_scenario(after=0.3)
    s = B.check_settings({"time_scale": B.physical_time_scale(24)})
    m = BlenderModel(24)
    rows = np.repeat(B.settings_row(s)[None], 2, 0)
    off = np.zeros((2, 4, 3))
    off[1] = [[0.003, 0, 0], [0, -0.002, 0.001], [0, 0, 0], [-0.001, 0.001, 0]]
    o = Offsets(np.zeros(2), off)
    a = m.simulate(sc, rows, backend="numba", offsets=o).positions
    b = m.simulate(sc, rows, backend="numpy", offsets=o).positions
    d = np.linalg.norm(a - b, axis=-1) * 1000
    assert d.mean() < 0.3 and d.max() < 5.0, (d.mean(), d.max())
    moved = np.linalg.norm(a[1] - a[0], axis=-1) * 1000
    assert moved.max() > 1.0  # the offsets are not vacuous


def test_vertex_mass_scales_out():
    """Mass, every stiffness and damping scaled together: the same motion (why the mass is fixed)."""
    sc = agreement.agreement_scenario(7, settle=0.25, after=0.5)
    s = B.check_settings({"time_scale": B.physical_time_scale(24)})
    s2 = dict(s)
    for n in B.mass_scaled("ANGULAR"):
        s2[n] = s[n] * 3.0
    m = BlenderModel(24)
    sim = m.simulate(sc, np.stack([B.settings_row(s), B.settings_row(s2)]))
    d = np.linalg.norm(sim.positions[0] - sim.positions[1], axis=-1) * 1000
    assert d.max() < 0.05
    s3 = dict(s, tension_stiffness=s["tension_stiffness"] * 3.0)  # one alone does change it
    sim = m.simulate(sc, np.stack([B.settings_row(s), B.settings_row(s3)]))
    assert np.linalg.norm(sim.positions[0] - sim.positions[1], axis=-1).max() * 1000 > 0.5


def test_synth_fit_export_evaluate_round_trip(tmp_path, capsys):
    """A capture made by the blender model, fitted with --model blender on two free settings
    (the rest fixed at the truth), recovers them and replays through evaluate."""
    cap = str(tmp_path / "cap")
    truth = {"tension_stiffness": 40.0, "compression_stiffness": 40.0, "air_damping": 2.0}
    assert (
        cli.main(
            [
                "synth",
                "--out",
                cap,
                "--model",
                "blender",
                "--params",
                json.dumps(truth),
                "--resolution",
                "120x160",
                "--noise",
                "0",
            ]
        )
        == 0
    )
    capsys.readouterr()
    out = str(tmp_path / "fit.json")
    fixed = {
        k: v
        for k, v in B.DEFAULTS.items()
        if k not in ("tension_stiffness", "air_damping", "quality", "bending_model", "time_scale")
    }
    fixed["compression_stiffness"] = 40.0
    fixed.pop("mass")
    assert (
        cli.main(
            [
                "fit",
                cap,
                "--model",
                "blender",
                "--cameras",
                "n:4",
                "--times",
                "0.1,0.3,0.5,0.7,0.9",
                "--free",
                "tension_stiffness,air_damping",
                "--fixed",
                json.dumps(fixed),
                "--max-evaluations",
                "400",
                "--out",
                out,
                "--quiet",
            ]
        )
        == 0
    )
    r = json.loads(open(out).read())
    bc = r["blender_cloth"]
    # synth declares the 24 fps its cloth was simulated at: the fit takes it (its frames are 0.05 s apart)
    assert r["model"]["name"] == "blender" and r["blender_scene"] == {"fps": 24.0, "fps_source": "capture"}
    assert bc["tension_stiffness"] == pytest.approx(40.0, rel=0.1)
    assert bc["air_damping"] == pytest.approx(2.0, rel=0.3)
    assert bc["mass"] == pytest.approx(0.3) and "capture" in r["mass_source"]
    capsys.readouterr()
    assert cli.main(["evaluate", cap, "--params", out, "--times", "0.2,0.4"]) == 0
    ev = json.loads(capsys.readouterr().out)  # stdout: the result as JSON
    err, mm = ev["silhouette_error_pct"], ev["shape_error_mm"]
    assert err < 1.0 and mm < 0.5, ev
    assert os.path.isfile(out)


# ------------------------------------------------------------- the add-on: fit and apply Blender's cloth


def _blender_fit_scene(tmp_path, budget=60):
    from blender_support import run_error, small_settings  # noqa: F401

    scene = bpy.context.scene
    p = small_settings(scene, tmp_path / "cap")
    p.settle_time = 0.25  # 6 frames at 24 fps: Blender's cloth steps whole frames
    for op in ("build_rig", "build_cloth", "simulate", "render_silhouettes"):
        assert getattr(bpy.ops.clothfit, op)() == {"FINISHED"}
    p.fit_model = "BLENDER"
    p.max_evaluations = budget
    return scene, p


def test_addon_fits_blender_cloth_and_blender_replays_it(tmp_path):
    """Panel path: fit with the Blender Cloth model, Apply Blender Cloth builds a cloth with the
    fit's mesh, pins and release; Blender's own solver then moves it exactly as the core predicted."""
    from clothfit.blender import api
    from clothfit.blender import cloth as BC
    from clothfit.core.observation.capture import load_capture

    scene, p = _blender_fit_scene(tmp_path)
    res, level, msg = api.run_fit(scene)
    assert level == "INFO" and "tension=" in msg
    assert res["model"]["name"] == "blender" and res["blender_scene"]["fps"] == BC.scene_fps(scene)
    assert json.loads(p.fit_best_blender)["tension_stiffness"] == pytest.approx(
        res["blender_cloth"]["tension_stiffness"]
    )
    bpy.ops.object.select_all(action="DESELECT")
    bpy.context.view_layer.objects.active = None
    assert bpy.ops.clothfit.apply_blender_cloth() == {"FINISHED"}
    obj = bpy.data.objects[api.BLENDER_CLOTH_NAME]
    cl = BC.cloth_modifier(obj)
    got = BC.read_settings(cl)
    for k, v in res["blender_cloth"].items():
        assert got[k] == (v if isinstance(v, str) else pytest.approx(v, rel=1e-6)), k
    # Blender replays it: its frames at the capture times equal the core model's
    cap = load_capture(str(tmp_path / "cap"))
    model, row = model_and_row(res)
    core = model.simulate(cap.scenario, row[None]).positions[0]
    net, plan = model.plan(cap.scenario)
    frames, _, _ = BC.simulate_frames(scene, obj, plan.n_frames, scene.frame_start)
    assert plan.between == 0
    d = np.linalg.norm(frames[plan.lo] - core, axis=-1) * 1000
    assert d.max() < 0.01, d.max()
    # applying again replaces the fitted cloth rather than adding another
    assert bpy.ops.clothfit.apply_blender_cloth() == {"FINISHED"}
    assert sum(o.name.startswith(api.BLENDER_CLOTH_NAME) for o in bpy.data.objects) == 1


def test_apply_blender_cloth_on_a_users_mesh_and_bad_cases(tmp_path):
    from blender_support import run_error
    from clothfit.blender import api

    scene = bpy.context.scene
    res = {
        "model": {"name": "blender", "fps": 30.0},
        "blender_scene": {"fps": 30.0},
        "blender_cloth": B.check_settings({"tension_stiffness": 21.0, "time_scale": B.physical_time_scale(30)}),
    }
    me = bpy.data.meshes.new("user")
    me.from_pydata([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], [], [(0, 1, 2, 3)])
    obj = bpy.data.objects.new("user cloth", me)
    scene.collection.objects.link(obj)
    with pytest.raises(ClothFitError, match="'user cloth' has no Cloth modifier"):
        api.apply_blender_cloth(scene, obj, res)
    obj.modifiers.new("Cloth", "CLOTH")
    with pytest.raises(ClothFitError, match="for 30 fps but the scene runs at 24 fps"):
        api.apply_blender_cloth(scene, obj, res, set_fps=False)
    _, msg = api.apply_blender_cloth(scene, obj, res)
    assert "frame rate set from 24 to 30 fps" in msg and "no pin group" in msg
    assert scene.render.fps == 30
    cs = [m for m in obj.modifiers if m.type == "CLOTH"][0].settings
    assert cs.tension_stiffness == pytest.approx(21.0)
    with pytest.raises(ClothFitError, match="paper-model fit"):
        api.apply_blender_cloth(scene, obj, {"params": {"m": 1e-5, "k": 10, "l": 0.006, "d": 1e-4}})
    scene.clothfit.capture_dir = str(tmp_path / "nothing")
    msg = run_error("apply_blender_cloth")  # no fit result in the scene
    assert "no fit result" in msg
