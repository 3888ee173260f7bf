"""FitResult: a fit's result written and read back (the same JSON as the plain dict results always
were), the keys its readers depend on checked with one-line errors; its readers (warm start, the
Blender export) and the checkpoint module it left job.py for."""

import json

import numpy as np
import pytest
from clothfit.core.errors import ClothFitError
from clothfit.core.fitting import checkpoint
from clothfit.core.fitting.job import FitConfig, FitJob, read_checkpoint
from clothfit.core.fitting.parameters import load_init
from clothfit.core.fitting.result import RESULT_FORMAT, FitResult
from clothfit.core.observation import camera as C
from clothfit.core.observation import synth
from clothfit.core.physics.scenario import fitted_scenario, paper_scenario

BLENDER = {
    "format": RESULT_FORMAT,
    "version": 1,
    "model": {"name": "blender", "fps": 30.0, "quality": 5},
    "blender_cloth": {"quality": 5, "mass": 0.3, "tension_stiffness": 15.0, "air_damping": 1.0},
    "blender_scene": {"fps": 30.0},
    "params": None,
    "time_offset_s": 0.012,
    "handles": [{"vertex": 0, "offset_m": [0.001, 0.0, -0.002]}],
    "best_E_sil_mean_pct": 1.5,
}


def _old_writer(path, obj):
    """How results were written before FitResult (an atomic JSON writer with job.py's own encoder)."""

    def default(o):
        if isinstance(o, np.generic):
            return o.item()
        if isinstance(o, np.ndarray):
            return o.tolist()
        raise TypeError(type(o))

    with open(path, "w", encoding="utf-8") as f:
        f.write(json.dumps(obj, indent=1, default=default, allow_nan=False) + "\n")


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """A real (short) paper-model fit of a 3-camera synthetic capture: its result and checkpoint."""
    root = tmp_path_factory.mktemp("res")
    rig = C.load_rig("lab18")
    cap = synth.synth_capture(
        str(root / "cap"),
        cameras=[rig[i].resized(60, 80) for i in (0, 9, 16)],
        scenario=paper_scenario(frame_times=[0.2, 0.6]),
        seed=3,
    )
    job = FitJob(cap, FitConfig(seed=5, max_evaluations=14), checkpoint=str(root / "ck.json"))
    res = job.run()
    return job, res, root


def test_a_fits_result_is_a_fitresult_written_as_the_plain_dict_always_was(fitted):
    job, res, root = fitted
    assert isinstance(res, FitResult) and type(res.to_json()) is dict and res.to_json() == dict(res)
    job.save_result(str(root / "new.json"))
    _old_writer(str(root / "old.json"), res.to_json())
    assert (root / "new.json").read_bytes() == (root / "old.json").read_bytes()
    back = FitResult.from_json(str(root / "new.json"))
    assert back.to_json() == json.loads((root / "new.json").read_text())
    assert list(back) == list(res)  # the same keys in the same order
    assert back.paper_params.as_dict() == res["params"] and not back.is_blender
    # the checkpoint holds the same result
    assert read_checkpoint(str(root / "ck.json"))["result"] == back.to_json()
    # a warm start reads it as a FitResult
    init = load_init(str(root / "new.json"))
    assert isinstance(init, FitResult) and init["params"] == res["params"]


def test_from_json_of_a_dict_keeps_old_dict_access_and_the_physics_layer_takes_it():
    r = FitResult.from_json(dict(BLENDER))
    assert r["blender_cloth"]["tension_stiffness"] == 15.0 and r.get("nothing") is None
    assert r.is_blender and r.manipulation == {"time_offset_s": 0.012, "handles": BLENDER["handles"]}
    sc = paper_scenario(frame_times=[0.2])
    hs = [{"vertex": h.vertex, "offset_m": [0.0, 0.0, 0.01 * k]} for k, h in enumerate(sc.handles)]
    r2 = FitResult.from_json(dict(BLENDER, handles=hs))
    assert isinstance(r2, dict)
    moved = fitted_scenario(sc, r2)  # a plain-dict reader takes it as it is
    assert moved.frame_times == pytest.approx([0.2 - 0.012])
    for k, (a, b) in enumerate(zip(moved.handles, sc.handles)):
        assert np.allclose(a.positions - b.positions, [0.0, 0.0, 0.01 * k])


@pytest.mark.parametrize(
    "change, key",
    [
        ({"blender_cloth": None, "params": None}, "'blender_cloth' or 'params'"),
        ({"blender_cloth": [1, 2]}, "'blender_cloth'"),
        ({"format": "silhouette-cloth-fit/checkpoint"}, "'format'"),
        ({"version": 2}, "'version'"),
        ({"model": 3}, "'model'"),
        ({"blender_scene": {"fps": -1}}, "'blender_scene.fps'"),
        ({"handles": "left"}, "'handles'"),
        ({"time_offset_s": "soon"}, "'time_offset_s'"),
    ],
)
def test_a_missing_or_bad_key_is_one_line_naming_the_file_and_the_key(tmp_path, change, key):
    path = tmp_path / "r.json"
    path.write_text(json.dumps(dict(BLENDER, **change)))
    with pytest.raises(ClothFitError) as e:
        FitResult.from_json(str(path))
    msg = str(e.value)
    assert "\n" not in msg and str(path) in msg and key in msg, msg


def test_a_missing_key_names_it_and_a_result_without_parameters_may_still_be_read(tmp_path):
    d = {k: v for k, v in BLENDER.items() if k not in ("blender_cloth", "params")}
    path = tmp_path / "empty.json"
    path.write_text(json.dumps(d))
    with pytest.raises(ClothFitError, match=r"^warm-start result .*empty.json: no 'blender_cloth' or 'params'"):
        load_init(str(path))
    assert FitResult.from_json(str(path), need_parameters=False)["best_E_sil_mean_pct"] == 1.5
    with pytest.raises(ClothFitError, match="not valid JSON"):
        (tmp_path / "bad.json").write_text("{")
        FitResult.from_json(str(tmp_path / "bad.json"))
    with pytest.raises(ClothFitError, match="expected a JSON object"):
        FitResult.from_json([1])


def test_the_blender_export_is_the_results_settings_and_manipulation():
    r = FitResult.from_json(dict(BLENDER))
    out = r.blender_export()
    assert out["blender_scene"] == {"fps": 30.0} and out["manipulation"]["time_offset_s"] == 0.012
    assert out["blender_cloth"]["tension_stiffness"] == 15.0 and out["blender_cloth"]["quality"] == 5
    paper = FitResult.from_json({"model": {"name": "paper"}, "params": {"m": 0.01, "k": 30.0, "l": 0.1, "d": 0.02}})
    with pytest.raises(ClothFitError, match="paper-model fit has no Blender cloth settings"):
        paper.blender_export()


def test_the_checkpoint_module_is_jobs_checkpoint(fitted):
    job, _, root = fitted
    ck = read_checkpoint(str(root / "ck.json"))
    assert ck["format"] == checkpoint.CHECKPOINT_FORMAT and ck["version"] == checkpoint.CHECKPOINT_VERSION == 3
    assert ck["identity"] == job.identity() == checkpoint.identity(job)
    assert set(ck) == set(checkpoint.CHECKPOINT_KEYS)
