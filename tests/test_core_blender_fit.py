"""Fitting Blender's cloth in the core (no bpy): the search space, warm starts, bad input, the
identifiability table."""

import json

import numpy as np
import pytest
from clothfit.core.errors import ClothFitError
from clothfit.core.fitting.job import FitConfig, FitJob
from clothfit.core.fitting.parameters import BLENDER_FREE, BlenderParameters, make_parameters
from clothfit.core.observation.synth import synth_capture
from clothfit.core.physics import blender as B
from clothfit.core.physics.models import BlenderModel, model_and_row
from clothfit.core.physics.scenario import ClothGrid, paper_scenario
from clothfit.core.studies import identifiability

pytest.importorskip("numba")

TRUTH = {"tension_stiffness": 40.0, "shear_stiffness": 8.0, "bending_stiffness": 0.2, "air_damping": 2.0}


@pytest.fixture(scope="module")
def cap(tmp_path_factory):
    root = tmp_path_factory.mktemp("bcap") / "cap"
    sc = paper_scenario(ClothGrid(9, 9, 0.1), frame_times=[0.1, 0.2, 0.4, 0.6, 0.8, 1.0])
    return synth_capture(
        str(root),
        TRUTH,
        model={"name": "blender", "fps": 24},
        rig="ring8",
        resolution=(90, 120),
        scenario=sc,
        noise=0.0,
    )


def test_capture_names_its_model_and_truth(cap):
    assert cap.model == {"name": "blender", "fps": 24.0, "quality": 5, "bending_model": "ANGULAR"}
    assert cap.meta["true_blender_cloth"]["tension_stiffness"] == 40.0
    assert cap.cloth_mass == pytest.approx(0.3 * 81)
    # a fit without --model uses the capture's
    par = make_parameters(cap, FitConfig())
    assert isinstance(par, BlenderParameters) and par.free == BLENDER_FREE["ANGULAR"]


def test_search_space_is_per_unit_mass_and_inside_blenders_limits(cap):
    par = make_parameters(cap, FitConfig(cloth_mass=81 * 3.0))  # 3 kg per vertex: ten times the default
    assert par.m == pytest.approx(3.0)
    for n, (_lo, hi) in zip(par.free, zip(par.space.lo, par.space.hi)):
        if n in par.scaled:  # coordinates per unit mass, Blender limit respected
            assert hi * par.m <= B.RANGES[n][1] * (1 + 1e-9)
    x = np.array([(a * b) ** 0.5 for a, b in zip(par.space.lo, par.space.hi)])
    s = par.settings(x)
    assert s["mass"] == pytest.approx(3.0)
    assert s["time_scale"] == pytest.approx(B.physical_time_scale(24))
    B.check_settings(s)
    k = par.free.index("tension_stiffness")
    assert s["tension_stiffness"] == pytest.approx(x[k] * 3.0)


@pytest.mark.parametrize(
    "cfg,msg",
    [
        (dict(free=["stiffness"]), "cannot search stiffness"),
        (dict(free=["tension_stiffness", "tension_stiffness"]), "distinct"),
        (dict(free=["tension_stiffness"], fixed={"tension_stiffness": 3}), "both free and fixed"),
        (dict(fixed={"air_damping": -1}), "air_damping"),
        (dict(bounds={"tension_stiffness": [5, 1]}), "search range of tension_stiffness is empty"),
        (dict(cloth_mass=-1.0), "cloth mass"),
        (dict(quality=0), "quality 0"),
        (dict(fps=0), "frame rate"),
        (dict(init="/nonexistent/r.json"), "file not found"),
    ],
)
def test_bad_blender_fit_settings_are_one_line_errors(cap, cfg, msg):
    with pytest.raises(ClothFitError, match=msg):
        make_parameters(cap, FitConfig(model="blender", **cfg))


def test_warm_start_from_a_blender_result_and_from_a_paper_result(cap, tmp_path):
    s = B.check_settings(dict(TRUTH, time_scale=B.physical_time_scale(30), quality=7))
    p = tmp_path / "b.json"
    p.write_text(
        json.dumps({"model": {"name": "blender", "fps": 30}, "blender_cloth": s, "blender_scene": {"fps": 30}})
    )
    par = make_parameters(cap, FitConfig(init=str(p)))
    assert par.model.fps == 30 and par.model.quality == 7  # the result's scene and quality
    got = par.settings(par.initial[0])
    for n in par.free:
        assert got[n] == pytest.approx(s[n], rel=1e-9), n
    q = tmp_path / "p.json"
    q.write_text(json.dumps({"model": {"name": "paper"}, "params": {"m": 1e-5, "k": 10, "l": 0.00667, "d": 1e-4}}))
    par = make_parameters(cap, FitConfig(model="blender", init=str(q)))
    got = par.settings(par.initial[0])
    assert got["tension_stiffness"] > 0 and got["air_damping"] > 0


def test_a_blender_fit_finds_settings_that_replay_the_capture(cap):
    """Default free set, CMA-ES: the fitted settings move the cloth within a millimetre of the truth
    on every frame (the settings need not be the truth's: several move it alike)."""
    job = FitJob(cap, FitConfig(model="blender", max_evaluations=700, seed=1))
    job.run()
    r = job.result()
    # the capture declares the rate its cloth was simulated at: it wins over its frame times (0.05 s apart)
    assert r["model"]["name"] == "blender" and r["blender_scene"] == {"fps": 24.0, "fps_source": "capture"}
    assert set(r["blender_cloth"]) == set(B.DEFAULTS)
    assert r["per_unit_mass"]["tension_stiffness"] == pytest.approx(r["blender_cloth"]["tension_stiffness"] / 0.3)
    model, row = model_and_row(r)
    X = model.simulate(cap.scenario, row[None]).positions[0]
    d = np.linalg.norm(X - cap.shapes, axis=-1) * 1000
    assert d.mean() < 1.0, d.mean()
    assert r["best_E_sil_mean_pct"] < 2.0


def test_result_settings_reproduce_the_motion_after_a_json_round_trip(cap, tmp_path):
    job = FitJob(cap, FitConfig(model="blender", max_evaluations=40, seed=0))
    job.run()
    path = tmp_path / "r.json"
    job.save_result(str(path))
    r = json.loads(path.read_text())
    model, row = model_and_row(r)
    a = model.simulate(cap.scenario, row[None]).positions[0]
    b = job.par.model.simulate(cap.scenario, job.to_params(job.opt.best_x)).positions[0]
    np.testing.assert_array_equal(a, b)


def test_identifiability_table_ranks_settings():
    t = identifiability.table("default", {}, BLENDER_FREE["ANGULAR"])
    rows = {r["setting"]: r for r in t["rows"]}
    assert set(rows) == set(identifiability.CANDIDATES)
    for r in t["rows"]:
        assert r["mm_per_10pct"] > 0 and np.isfinite(r["all_free_pct"])
        assert r["all_free_pct"] >= r["alone_pct"] * (1 - 1e-9)  # freeing others never helps
    assert rows["compression_damping"]["default_set_pct"] is None
    assert rows["tension_stiffness"]["mm_per_10pct"] > 10 * rows["bending_damping"]["mm_per_10pct"]


def test_blender_model_rows_are_checked():
    with pytest.raises(ClothFitError, match="rows must have"):
        BlenderModel().simulate(paper_scenario(frame_times=[0.1]), np.zeros((2, 3)))


def test_the_search_moves_alike_at_any_fixed_mass(cap):
    """The same search point means the same motion whatever mass is fixed: the fixed settings
    (Blender's defaults) move with the mass too (a 2.56 g cloth once fitted 44 % worse without)."""
    a = make_parameters(cap, FitConfig())  # the capture's 0.3 kg per vertex
    b = make_parameters(cap, FitConfig(cloth_mass=81 * 1e-5))  # the paper's 10 mg per vertex
    x = np.array([(lo * hi) ** 0.5 for lo, hi in zip(a.space.lo, a.space.hi)])
    np.testing.assert_allclose(b.space.lo, a.space.lo, rtol=1e-12)
    sa = a.model.simulate(cap.scenario, a.rows(x)).positions[0]
    sb = b.model.simulate(cap.scenario, b.rows(x)).positions[0]
    d = np.linalg.norm(sa - sb, axis=-1) * 1000  # float32 rounding differs between the two scales
    assert d.mean() < 0.05 and d.max() < 2.0, (d.mean(), d.max())
