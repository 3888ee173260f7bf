"""FitConfig's optimiser options (fitting/job.py SEARCH_OPTIONS) reach the optimiser a fit builds:
unset, the optimiser is built as it always was and the fit's identity is unchanged; set, they are
checked, change what the optimiser does, and a checkpoint resumes only with the same ones."""

import json

import numpy as np
import pytest
from clothfit.core import defaults as D
from clothfit.core.errors import ClothFitError
from clothfit.core.fitting.job import SEARCH_OPTIONS, FitConfig, FitJob
from clothfit.core.observation import camera as C
from clothfit.core.observation import synth
from clothfit.core.physics.scenario import paper_scenario

H, W = 60, 80
BOUNDS = {"k_over_m": [2e5, 5e6], "d_over_m": [1.0, 25.0], "l_rel": [0.8, 1.25]}


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    """3 cameras of lab18 at 60x80, 3 frames of the paper's sheet (the fits below take 1-3 generations)."""
    rig = C.load_rig("lab18")
    cams = [rig[i].resized(H, W) for i in C.select_training(rig, 3)[0]]
    root = tmp_path_factory.mktemp("cap")
    return synth.synth_capture(str(root), cameras=cams, scenario=paper_scenario(frame_times=[0.1, 0.2, 0.4]), seed=1)


def cfg(**kw):
    d = dict(
        train_cameras=[0, 1],
        train_times=[0.2, 0.4],
        optimizer="cma-es",
        seed=3,
        max_evaluations=21,
        bounds=BOUNDS,
        backend="numpy",
    )
    d.update(kw)
    return FitConfig(**d)


def test_unset_options_build_the_optimiser_as_before_and_leave_the_identity_alone(capture):
    job = FitJob(capture, cfg())
    assert FitConfig().search_options() == {} and "search_options" not in job.identity()
    kw = job._optimizer_kw()
    n = job.space.n
    assert kw == {
        "tolx": D.FIT_TOLX,
        "tolfun": D.FIT_TOLFUN_PER_IMAGE * job.objective.n_images,
        "restarts": D.FIT_RESTARTS,
        "popsize": 4 + int(3 * np.log(n)),
    }
    assert job.opt.active is False and job.opt.sigma0 == 0.3
    # a config written before the options existed (no such keys) still loads
    old = {k: v for k, v in json.loads(json.dumps(cfg().__dict__)).items() if k not in SEARCH_OPTIONS}
    assert FitConfig.from_dict(old).search_options() == {}


def test_active_cma_reaches_the_optimiser_and_changes_its_covariance(capture):
    plain, active = FitJob(capture, cfg()), FitJob(capture, cfg(cma_active=True))
    assert plain.opt.active is False and active.opt.active is True
    assert active.identity()["search_options"] == {"cma_active": True}
    X0, X1 = plain.opt.ask(), active.opt.ask()
    np.testing.assert_array_equal(X0, X1)  # same seed: the same first generation ...
    plain.step()
    active.step()
    assert plain.opt.evaluations == active.opt.evaluations == len(X0)
    np.testing.assert_array_equal(plain.opt.mean, active.opt.mean)  # ... the same recombination ...
    assert not np.allclose(plain.opt.C, active.opt.C)  # ... but the worse half lowers C
    # the portfolio's runs are active by default: the option turns them off
    port = FitJob(
        capture,
        cfg(
            optimizer="cma-portfolio",
            cma_active=False,
            portfolio_runs=2,
            portfolio_polish="coord",
            portfolio_explore=0.25,
        ),
    )
    assert port.opt.active is False and port.opt.runs == 2 and len(port.opt.children) == 2
    assert port.opt.polish == "coord" and port.opt.explore == 0.25
    assert not any(c.active for c in port.opt.children)


def test_sigma0_tolerances_and_ga_options_reach_the_optimiser(capture):
    job = FitJob(capture, cfg(sigma0=0.05, tolx=1e-3, tolfun_per_image=1e-4))
    assert job.opt.sigma0 == 0.05 and job.opt.sigma == 0.05 and job.opt.tolx == 1e-3
    assert job.opt.tolfun == pytest.approx(1e-4 * job.objective.n_images)
    wide = FitJob(capture, cfg()).opt.ask()
    narrow = job.opt.ask()  # same seed, a sixth of the step: closer to the centre
    assert np.abs(job.space.encode(narrow) - 0.5).max() < np.abs(job.space.encode(wide) - 0.5).max()
    ga = FitJob(capture, cfg(optimizer="spx-mgg", ga_eps=1.5, ga_stall=50))
    assert ga.opt.eps == 1.5 and ga.opt.stall_evaluations == 50


@pytest.mark.parametrize(
    "kw, match",
    [
        ({"cma_active": "yes"}, "cma_active"),
        ({"sigma0": 0}, "sigma0"),
        ({"sigma0": float("nan")}, "sigma0"),
        ({"tolx": -1.0}, "tolx"),
        ({"ga_stall": 10, "optimizer": "cma-es"}, "ga_stall is a setting of spx-mgg"),
        ({"portfolio_runs": 2}, "portfolio_runs is a setting of cma-portfolio"),
        ({"optimizer": "cma-portfolio", "portfolio_runs": 65}, "portfolio_runs"),
        ({"optimizer": "cma-portfolio", "portfolio_polish": "newton"}, "portfolio_polish"),
        ({"optimizer": "spx-mgg", "cma_active": True}, "cma_active is a setting of cma-es and cma-portfolio"),
    ],
)
def test_bad_options_are_one_line_errors(kw, match):
    with pytest.raises(ClothFitError, match=match) as e:
        cfg(**kw).checked()
    assert "\n" not in str(e.value)


def test_a_checkpoint_resumes_only_with_the_same_options(capture, tmp_path):
    ck = str(tmp_path / "fit.checkpoint.json")
    ref = FitJob(capture, cfg(cma_active=True)).run()
    job = FitJob(capture, cfg(cma_active=True), checkpoint=ck)
    assert job.step()
    del job
    with pytest.raises(ClothFitError, match="search_options"):
        FitJob.resume(ck, capture=capture, config=cfg())
    r = FitJob.resume(ck, capture=capture).run()  # its own config: active CMA, to the same end
    assert r["history"] == ref["history"] and r["params"] == ref["params"]
