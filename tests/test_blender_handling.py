"""Handles that move along paths in Blender (real bpy module): a capture whose corner is waved, loaded
into a scene, is simulated (Simulate's shape keys) and replayed by Blender's own cloth (Apply Blender
Cloth: the pins' hooks follow keyed empties) with that corner on its path, and Blender's cloth moves
as the core's blender model does."""

import numpy as np
import pytest
from blender_support import bpy, factory  # noqa: F401
from clothfit.blender import api  # noqa: E402
from clothfit.blender import cloth as BC  # noqa: E402
from clothfit.core import defaults as D  # noqa: E402
from clothfit.core.observation import camera as C  # noqa: E402
from clothfit.core.observation.synth import synth_capture  # noqa: E402
from clothfit.core.physics import blender as B  # noqa: E402
from clothfit.core.physics.handling import handling_scenario, moving_handles  # noqa: E402
from clothfit.core.physics.models import BlenderModel  # noqa: E402
from clothfit.core.physics.scenario import ClothGrid  # noqa: E402

pytestmark = pytest.mark.usefixtures("factory")

FPS = 24.0
TIMES = np.arange(1, 13) / FPS  # half a second: most of a wave at 1.5 Hz


def _waved_capture(tmp_path):
    sc = handling_scenario("wave", grid=ClothGrid(9, 9, D.CLOTH_SIDE), frame_times=TIMES)
    sc.settle_time = 0.25
    cams = [c.resized(30, 40) for c in C.load_rig("lab18")[:3]]
    settings = B.check_settings({"time_scale": B.physical_time_scale(FPS)})
    synth_capture(str(tmp_path / "cap"), settings, scenario=sc, cameras=cams, noise=0.0, model={"name": "blender"})
    return sc, settings


def _result(settings):
    return {
        "model": {"name": "blender", "fps": FPS, "quality": settings["quality"], "bending_model": "ANGULAR"},
        "blender_cloth": settings,
        "blender_scene": {"fps": FPS},
    }


def test_a_waved_corner_moves_on_its_path_in_blender_and_blenders_cloth_moves_like_the_core(tmp_path):
    sc, settings = _waved_capture(tmp_path)
    waved = moving_handles(sc)
    assert len(waved) == 1
    v = waved[0]
    path = sc.handles[[h.vertex for h in sc.handles].index(v)]
    scene = bpy.context.scene
    p = scene.clothfit
    api.load_capture(scene, str(tmp_path / "cap"))
    assert "corner 0 moving" in p.capture_releases
    assert bpy.ops.clothfit.build_cloth() == {"FINISHED"}
    # Simulate (the core's model of the scene, baked into shape keys): the corner on its path
    p.frame_times = ", ".join(f"{t:.6f}" for t in TIMES)
    out = api.simulate(scene)
    keys = {kb.name: kb for kb in p.cloth_object.data.shape_keys.key_blocks}
    for t in TIMES[::3]:
        at = np.array(keys[f"t={t:.3f}"].data[v].co[:])
        assert np.abs(at - path.position(t)).max() < 1e-6, t
    assert len(out["times"]) == 1 + len(TIMES)
    # Apply Blender Cloth: Blender's own cloth with the capture's pins; the corner follows a keyed empty
    obj, _ = api.apply_blender_cloth(scene, None, result=_result(settings))
    net, plan = BlenderModel(FPS).plan(sc)
    frames, _, _ = BC.simulate_frames(scene, obj, plan.n_frames, scene.frame_start)
    on_path = plan.frame_of(TIMES).round().astype(int)
    got = frames[on_path, v]
    assert np.abs(got - path.position(TIMES)).max() < 1e-5  # float32 positions of a 10 cm cloth
    assert np.ptp(got[:, 2]) > 1.5 * D.WAVE_AMPLITUDE  # it did go up and down
    # and the whole cloth moves as the core's blender model moves it (as the still-corner cross-checks)
    core = BlenderModel(FPS).simulate(sc, B.settings_row(settings)[None]).positions[0]
    d = np.linalg.norm(plan.sample(frames) - core, axis=-1) * 1000.0
    assert d.max() < 0.01, d.max()


def test_replays_leave_no_hook_empties_behind(tmp_path):
    """Every replay of a scenario whose handles move builds keyed empties for the hooks; removing the
    replayed cloth removes them too, so replays and repeated Apply do not pile up empties."""
    sc, settings = _waved_capture(tmp_path)
    scene = bpy.context.scene
    before = {o.name for o in bpy.data.objects}
    for _ in range(2):
        BC.replay(scene, sc, settings, FPS)
    assert {o.name for o in bpy.data.objects} == before
    api.load_capture(scene, str(tmp_path / "cap"))
    assert bpy.ops.clothfit.build_cloth() == {"FINISHED"}
    for _ in range(2):
        obj, _ = api.apply_blender_cloth(scene, None, result=_result(settings))
    empties = [o for o in bpy.data.objects if o.type == "EMPTY" and o.name.startswith("clothfit_handle")]
    hooked = {m.object.name for m in obj.modifiers if m.type == "HOOK"}
    assert {o.name for o in empties} == hooked and len(hooked) == len(moving_handles(sc)) == 1


@pytest.mark.parametrize("handling", ["wave", "lift", "apart"])
def test_blenders_cloth_moves_like_the_core_blender_model_under_every_handling(handling):
    """The hands' paths of every synthetic handling (the two-hand ones held with slack, hanging from an
    edge) on Blender's own cloth: every vertex of every frame within 0.01 mm of the core's blender model,
    as the still-corner cross-checks (tests/test_blender_cloth_model.py); the hands did move."""
    from clothfit.blender import agreement
    from clothfit.core.physics.scenario import Scenario

    sc = handling_scenario(handling, grid=ClothGrid(9, 9, D.CLOTH_SIDE), frame_times=np.arange(1, 19) / FPS)
    sc = Scenario(sc.grid, sc.handles, sc.frame_times, 0.5, sc.gravity)
    for settings in ({}, dict(agreement.PRESETS["silk"])):
        r = agreement.compare(bpy.context.scene, sc, settings)
        assert r["max_mm"] < 0.01, (handling, settings, r)
    moved = max(np.ptp(h.position(sc.frame_times), axis=0).max() for h in sc.handles)
    assert moved > 0.01


def test_blender_agreement_runs_under_a_handling():
    """``blender-agreement --handling lift``: the same comparison with the hands on the lift's paths
    (the header says so); Blender's cloth and the core's agree to 0.01 mm. Without it, the scenario is
    the one it always compared: four corners held, one released."""
    from clothfit import cli
    from clothfit.blender import agreement
    from clothfit.core.physics.scenario import paper_scenario

    lines = []
    rows = agreement.run(7, 0.25, 0.5, FPS, cases=[("default", {})], echo=lines.append, handling="lift")
    assert "lifted and lowered" in lines[0] and rows[0]["max_mm"] < 0.01
    assert len(moving_handles(agreement.agreement_scenario(7, 0.25, 0.5, FPS, "lift"))) == 2
    sc = agreement.agreement_scenario(7)
    ref = paper_scenario(ClothGrid(7, 7, 0.10), frame_times=sc.frame_times)
    assert sc.to_dict() == dict(ref.to_dict(), settle_time=1.0)
    assert cli.build_parser().parse_args(["blender-agreement", "--handling", "wave"]).handling == "wave"
    with pytest.raises(SystemExit):
        cli.build_parser().parse_args(["blender-agreement", "--handling", "shake"])
