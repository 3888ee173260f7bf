"""The search of a ``--backend blender`` fit (``SceneParameters``), with a stand-in evaluator: the
scene's Cloth modifier values are the centre and the fixed values, the mass fixed and scaled out,
a warm start replaces the free values only; a FitJob over a model-like evaluator needs no bpy."""

import json

import numpy as np
import pytest
from clothfit.core.errors import ClothFitError
from clothfit.core.fitting.job import FitConfig, FitJob
from clothfit.core.fitting.parameters import BLENDER_FREE, SCENE_BOUND_FACTOR, SceneParameters
from clothfit.core.observation.synth import synth_capture
from clothfit.core.physics import blender as B
from clothfit.core.physics.models import BlenderModel
from clothfit.core.physics.scenario import ClothGrid, paper_scenario

SCENE = B.check_settings(
    {"mass": 0.5, "tension_stiffness": 30.0, "shear_damping": 0.0, "quality": 7, "time_scale": 1.25}
)


class CoreScene:
    """A stand-in for clothfit.farm.scene.BlendSceneEvaluator: the core's blender model on the capture's
    scenario, with a "scene" holding SCENE's settings."""

    name = "blender"
    row_names = B.FLOAT_SETTINGS

    def __init__(self, cap, fps=24.0):
        self.fps, self.quality, self.bending_model = fps, SCENE["quality"], SCENE["bending_model"]
        self.initial = dict(SCENE)
        self.cap = cap
        self.mesh = cap.scenario.grid
        self.model = BlenderModel(fps, self.quality, self.bending_model)
        self.evaluations = 0

    def to_dict(self):
        return self.model.to_dict()

    def settings(self, row):
        return self.model.settings(row)

    def scenario(self, times, crop=None):
        return self.cap.scenario.with_frames(times)

    def simulate(self, scenario, rows, backend="auto"):
        self.evaluations += len(np.atleast_2d(rows))
        return self.model.simulate(scenario, rows, backend)

    def describe(self):
        return {"backend": "blender", "executor": "stand-in", "workers": 1, "blender_evaluations": self.evaluations}


@pytest.fixture(scope="module")
def cap(tmp_path_factory):
    root = tmp_path_factory.mktemp("scap") / "cap"
    sc = paper_scenario(ClothGrid(7, 7, 0.1), frame_times=[0.1, 0.2, 0.3])
    c = synth_capture(
        str(root),
        {"tension_stiffness": 40.0},
        model={"name": "blender", "fps": 24},
        rig="ring8",
        resolution=(60, 80),
        scenario=sc,
        noise=0.0,
    )
    c.cloth_mass = None
    return c


def test_scene_values_are_the_centre_and_the_fixed_values(cap):
    par = SceneParameters(cap, FitConfig(), CoreScene(cap))
    assert par.m == 0.5 and "scene's vertex mass" in par.m_source
    assert par.free == BLENDER_FREE["ANGULAR"]
    assert par.fixed["quality"] == 7 and par.fixed["time_scale"] == 1.25  # the scene's, not the real-time one
    lo, hi = par.space.bounds["tension_stiffness"]
    assert lo == pytest.approx(30.0 / 0.5 / SCENE_BOUND_FACTOR) and hi == pytest.approx(30.0 / 0.5 * SCENE_BOUND_FACTOR)
    lo, hi = par.space.bounds["shear_damping"]  # zero in the scene: the presets' range
    assert 0 < lo < hi
    centre = np.sqrt(par.space.lo * par.space.hi)
    assert par.settings(centre)["tension_stiffness"] == pytest.approx(30.0)
    assert par.initial is None


def test_cloth_mass_moves_every_scaled_value(cap):
    par = SceneParameters(cap, FitConfig(cloth_mass=49 * 1.0), CoreScene(cap))  # 1 kg per vertex
    assert par.m == pytest.approx(1.0)
    assert par.fixed["compression_damping"] == pytest.approx(SCENE["compression_damping"] * 2)
    s = par.settings(np.sqrt(par.space.lo * par.space.hi))
    assert s["tension_stiffness"] == pytest.approx(60.0)
    B.check_settings(s)


def test_warm_start_replaces_the_free_values_only(cap, tmp_path):
    init = {
        "model": {"name": "blender", "fps": 24.0, "quality": 5, "bending_model": "ANGULAR"},
        "blender_cloth": B.check_settings(
            {"tension_stiffness": 45.0, "compression_damping": 9.0, "time_scale": B.physical_time_scale(24)}
        ),
        "blender_scene": {"fps": 24.0},
    }
    p = tmp_path / "init.json"
    p.write_text(json.dumps(init))
    par = SceneParameters(cap, FitConfig(init=str(p)), CoreScene(cap))
    x0 = par.initial[0]
    s = par.settings(x0)
    assert s["tension_stiffness"] == pytest.approx(45.0 * 0.5 / 0.3)  # moved to the scene's mass
    assert s["compression_damping"] == pytest.approx(SCENE["compression_damping"])  # not free: the scene's
    assert s["time_scale"] == 1.25 and "time_scale" in par.note


def test_fitjob_runs_over_a_model_like_evaluator(cap):
    ev = CoreScene(cap)
    job = FitJob(cap, FitConfig(evaluator="blender", max_evaluations=13, population=6, seed=1), evaluator=ev)
    res = job.run()
    assert res["backend"] == "blender" and res["raster_backend"] in ("numba", "numpy")
    # the scene's own settings first, then two generations of 6: the budget's 13
    assert res["evaluations"] == 13 and res["blender_evaluations"] == 13 and res["seconds"] >= 0
    assert res["best_E_sil_mean_pct"] <= res["start_E_sil_mean_pct"]
    assert res["blender_cloth"]["time_scale"] == 1.25


def test_blender_backend_without_workers_is_refused(cap):
    with pytest.raises(ClothFitError, match="needs its workers"):
        FitJob(cap, FitConfig(evaluator="blender"))
