"""How sure each setting is: the intervals stage (marginal intervals from the error's own noise), on an
error whose answer is known in closed form and on real fits of Blender's cloth."""

import math

import numpy as np
import pytest
from clothfit.core import defaults as D
from clothfit.core.fitting import intervals
from clothfit.core.fitting.job import FitConfig, FitJob
from clothfit.core.fitting.run_state import RunState
from clothfit.core.fitting.space import SearchSpace
from clothfit.core.observation.synth import synth_capture
from clothfit.core.physics.scenario import ClothGrid, paper_scenario


class _Par:
    def reported(self, name, coord):
        return name, float(coord)


class QuadraticJob:
    """What the stage needs of a fit, over a known error: a quadratic in (a, b) with a valley along
    a + b = 1 (a and b trade against each other), c without any effect, and noise of a known size."""

    def __init__(self, sigma=0.02, seed=0):
        self.space = SearchSpace(["a", "b", "c"], {"a": (0.0, 1.0), "b": (0.0, 1.0), "c": (0.0, 1.0)})
        self.npar = 3
        self.par = _Par()
        self.sigma = sigma
        self.rng = np.random.default_rng(seed)
        self.state = RunState()  # the fit's progress: evaluations, exploded, the stage's own state, the best
        # E = 10 + (a - 0.4)^2 / (2 s1^2) + (a + b - 1)^2 / (2 s2^2), in units of the temperature T
        self.T = D.INTERVAL_Z * math.sqrt(2.0) * sigma / D.INTERVAL_CHI2_HALF
        self.s1, self.s2 = 0.05, 0.01
        self.best_x = np.array([0.4, 0.6, 0.5])
        self.best_error = 10.0

    def chosen_quality(self):
        return None

    def error(self, X):
        a, b = X[:, 0], X[:, 1]
        q = (a - 0.4) ** 2 / (2 * self.s1**2) + (a + b - 1.0) ** 2 / (2 * self.s2**2)
        return 10.0 + self.T * q

    def evaluate(self, X):
        X = np.atleast_2d(X)
        return self.error(X) + self.sigma * self.rng.standard_normal(len(X))


def run_stage(job):
    steps = 0
    while not intervals.interval_step(job):
        steps += 1
        assert steps < 100
    return job.state.intervals["result"]


def lucky_job(pick):
    """A QuadraticJob whose first sampling round has one lucky point, ``pick`` (np.argmin or np.argmax) of the
    points' distances from the best in a, scoring 100 temperatures below everything else."""
    job = QuadraticJob()
    good = job.evaluate

    def lucky(X):
        f = good(X)
        st = job.state.intervals
        if st and st["phase"] == "sample" and st["round"] == 0:
            f[int(pick(np.abs(np.atleast_2d(X)[:, 0] - 0.4)))] -= 100 * job.T
        return f

    job.evaluate = lucky
    return job


def test_intervals_are_marginal_and_sized_by_the_errors_own_noise():
    job = QuadraticJob()
    r = run_stage(job)
    z = 1.6449
    # the 90 % marginal of exp(-E/T): a ~ N(0.4, s1), b = 1 - a + N(0, s2): sd(b) = sqrt(s1^2 + s2^2), at the
    # temperature the stage measured (its jitter's sd from a few draws: the widths go with its square root)
    scale = math.sqrt(r["interval_method"]["temperature"] / job.T)
    half_a = z * job.s1 * scale
    half_b = z * math.hypot(job.s1, job.s2) * scale
    (alo, ahi), (blo, bhi) = r["intervals"]["a"], r["intervals"]["b"]
    assert alo < 0.4 < ahi and blo < 0.6 < bhi
    assert (ahi - alo) / 2 == pytest.approx(half_a, rel=0.35)
    assert (bhi - blo) / 2 == pytest.approx(half_b, rel=0.35)
    # the curvature along b with a held would give z * s2: five times narrower than the marginal
    assert (bhi - blo) / 2 > 3 * z * job.s2 * scale
    assert r["interval_method"]["jitter_sd"] == pytest.approx(job.sigma, rel=0.5)


def test_a_setting_without_effect_is_undetermined_and_the_others_are_not():
    job = QuadraticJob()
    r = run_stage(job)
    assert r["undetermined"] == ["c"]
    assert r["intervals"]["c"] == pytest.approx([0.0, 1.0])
    assert r["interval_method"]["details"]["c"]["flat"]


def test_more_noise_gives_wider_intervals():
    widths = []
    for sigma in (0.01, 0.04):
        job = QuadraticJob(sigma=sigma)
        job.T = QuadraticJob(sigma=0.01).T  # the same error surface, only its noise grows
        r = run_stage(job)
        lo, hi = r["intervals"]["a"]
        widths.append(hi - lo)
    assert widths[1] > 1.5 * widths[0]


def test_a_lower_point_found_by_the_stage_becomes_the_fits_best():
    job = QuadraticJob()
    job.best_x = np.array([0.4 + 2 * job.s1, 0.6 - 2 * job.s1, 0.5])  # a search that stopped two sds short
    job.best_error = float(job.error(job.best_x[None])[0])
    r = run_stage(job)
    f, x = job.state.best_by_quality[None]
    assert f < job.best_error and r["interval_method"]["improved_best"]["to"] == f
    assert abs(x[0] - 0.4) < abs(job.best_x[0] - 0.4)
    assert r["interval_method"]["details"]["a"]["value"] == pytest.approx(x[0])  # the values: the new best's


def test_an_interval_reaches_around_a_lower_point_the_stage_found_as_around_the_searchs_end():
    job = lucky_job(np.argmax)  # the sampled point furthest from the best in a scores far below everything
    r = run_stage(job)
    f, x = job.state.best_by_quality[None]
    st = job.state.intervals
    assert r["interval_method"]["improved_best"]["to"] == f and abs(x[0] - 0.4) > 0.01
    below, above = np.subtract(intervals.axis_reach(st, 0), 0.4) * [-1, 1]
    lo, hi = r["intervals"]["a"]
    assert r["interval_method"]["details"]["a"]["value"] == pytest.approx(x[0])
    # not an interval with the reported value at one end: its axis's reach on both sides of it
    assert lo <= x[0] - below * (1 - 1e-9) and hi >= x[0] + above * (1 - 1e-9)


def test_a_round_whose_every_point_fails_keeps_the_last_proposal():
    job = QuadraticJob()
    good = job.evaluate
    job.evaluate = lambda X: np.where(np.abs(np.atleast_2d(X)[:, 0] - 0.4) < 1e-6, good(X), np.inf)
    r = run_stage(job)  # only the jittered best point scores: no sampled point has a weight
    means = [m for m, _ in job.state.intervals["props"]]
    assert all(np.allclose(m, means[0]) for m in means)
    assert r["intervals"]["a"][0] <= 0.4 <= r["intervals"]["a"][1]


def test_the_axis_reach_is_the_conditional_90_percent_interval_of_a_quadratic_error():
    # E = T (u - u0)^2 / (2 s^2) rises by T h^2 / (2 s^2) at a step h: the reach is u0 -+ z s
    s, h, T = 0.05, 0.1, 1.0
    r = T * h * h / (2 * s * s)
    st = {"u0": [0.3], "rise": [[h, r, 4 * r]], "threshold": 0.1, "temperature": T}
    lo, hi = intervals.axis_reach(st, 0)
    assert 0.3 - lo == pytest.approx(D.INTERVAL_Z * s) and hi - 0.3 == pytest.approx(D.INTERVAL_Z * s / 2)
    st["rise"] = [[h, 0.0, None]]  # no rise within the noise: at least the threshold's reach; a failed side: none
    lo, hi = intervals.axis_reach(st, 0)
    assert 0.3 - lo == pytest.approx(D.INTERVAL_Z * h * math.sqrt(T / 0.2)) and hi == 0.3
    assert intervals.axis_reach({"u0": [0.3]}, 0) is None  # a state from before the axes were kept


def test_weights_that_rest_on_one_lucky_point_do_not_make_an_interval_narrower_than_its_axis():
    job = lucky_job(np.argmin)  # the sampled point nearest the best in a scores far below all: its weight is all
    r = run_stage(job)
    assert r["interval_method"]["effective_points"] < 1.5
    # with b held, a's error is quadratic with sd 1 / sqrt(1 / s1^2 + 1 / s2^2), at the stage's temperature
    scale = math.sqrt(r["interval_method"]["temperature"] / job.T)
    cond = D.INTERVAL_Z * scale / math.sqrt(1 / job.s1**2 + 1 / job.s2**2)
    lo, hi = r["intervals"]["a"]
    assert hi - lo > 0.7 * 2 * cond
    assert r["interval_method"]["details"]["a"]["axis_widened"]


def test_the_stage_stays_within_its_budget():
    job = QuadraticJob()
    run_stage(job)
    assert job.state.done_evals <= intervals.interval_budget(3)


@pytest.fixture(scope="module")
def cap(tmp_path_factory):
    root = tmp_path_factory.mktemp("icap") / "cap"
    sc = paper_scenario(ClothGrid(7, 7, 0.1), frame_times=[0.1, 0.2, 0.3, 0.4, 0.6, 0.8])
    truth = {"tension_stiffness": 40.0, "shear_stiffness": 8.0, "bending_stiffness": 0.2, "air_damping": 2.0}
    return synth_capture(
        str(root),
        truth,
        model={"name": "blender", "fps": 24},
        rig="ring8",
        resolution=(60, 80),
        scenario=sc,
        noise=0.05,
    )


FREE = ["tension_stiffness", "shear_stiffness", "air_damping"]


def fit(cap, checkpoint=None, budget=1000, **kw):
    cfg = FitConfig(model="blender", free=FREE, quality=5, max_evaluations=budget, train_cameras=[0, 2, 4, 6], **kw)
    return FitJob(cap, cfg, checkpoint=checkpoint)


def test_a_fit_ends_with_an_interval_for_every_free_setting_holding_its_value(cap):
    job = fit(cap)
    res = job.run()
    assert res["evaluations"] <= 1000
    assert set(res["intervals"]) == set(FREE)
    for n in FREE:
        lo, hi = res["intervals"][n]
        assert 0 < lo <= res["blender_cloth"][n] <= hi
    assert set(res["undetermined"]) <= set(FREE)
    assert res["interval_method"]["level"] == 0.9


def test_a_resumed_fit_reports_the_same_intervals(cap, tmp_path):
    ck = str(tmp_path / "fit.ckpt.json")
    whole = fit(cap).run()
    job = fit(cap, checkpoint=ck)
    while job.state.stage != "intervals" or (job.state.intervals or {}).get("phase") in (None, "jitter"):
        job.step()
    assert job.state.intervals["phase"] in ("axes", "sample")
    job.save_checkpoint(ck)
    resumed = FitJob.resume(ck, cap).run()
    assert resumed["intervals"] == whole["intervals"]
    assert resumed["undetermined"] == whole["undetermined"]


def test_no_interval_where_the_budget_or_the_images_cannot_give_one(cap):
    small = fit(cap, budget=200).run()
    assert small["intervals"] is None and "budget of 200" in small["intervals_note"]
    one = FitJob(
        cap,
        FitConfig(model="blender", free=FREE, quality=5, max_evaluations=1000, train_cameras=[0], train_times=[0.4]),
    ).run()
    assert one["intervals"] is None and "1 training image" in one["intervals_note"]
    off = fit(cap, intervals=False).run()
    assert off["intervals"] is None and "--no-intervals" in off["intervals_note"]


def test_the_intervals_are_shown_to_people_and_the_undetermined_marked(cap, tmp_path):
    import cv2
    from clothfit.core.fitting.result import interval_lines
    from clothfit.core.observation.overlay import capture_overlays

    res = fit(cap).run()
    res["undetermined"] = [FREE[0]]  # as a fit that could not tell it says
    lines = interval_lines(res)
    for n in FREE:
        (line,) = [x for x in lines if x.startswith(n)]
        lo, hi = res["intervals"][n]
        assert f"[{lo:.4g}, {hi:.4g}]" in line
        assert line.endswith("UNDETERMINED") == (n == FREE[0])
    plain = capture_overlays(cap, res, tmp_path / "a", cameras=[0], times=[0.4])
    shown = capture_overlays(cap, res, tmp_path / "b", cameras=[0], times=[0.4], legend=lines)
    ha, hb = cv2.imread(plain[-1]).shape[0], cv2.imread(shown[-1]).shape[0]
    assert hb >= ha + 18 * len(lines)
    assert interval_lines({"intervals": None, "intervals_note": "why"}) == ["no intervals: why"]
    assert not [x for x in lines if x.startswith("CAUTION")]
    res["floor"] = dict(res["floor"], far_above=True, heldout_ratio=6.5)  # a fit far above its floor
    (caution,) = [x for x in interval_lines(res) if x.startswith("CAUTION")]
    assert "6.5x above its floor" in caution and "outside them" in caution


def test_the_export_keeps_every_value_and_marks_the_undetermined(cap, tmp_path, capsys):
    import json

    from clothfit import cli

    res = fit(cap).run()
    res["undetermined"] = [FREE[0]]
    path = tmp_path / "fit.json"
    res.save(str(path))
    assert cli.main(["export-blender-cloth", str(path)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["intervals"] == {n: res["intervals"][n] for n in FREE} and out["undetermined"] == [FREE[0]]
    assert out["blender_cloth"][FREE[0]] == res["blender_cloth"][FREE[0]]  # the value kept
    assert cli.main(["export-blender-cloth", str(path), "--python"]) == 0
    script = capsys.readouterr().out
    (line,) = [x for x in script.splitlines() if x.startswith(f"# {FREE[0]} ")]
    assert line.endswith("UNDETERMINED")
    preset = tmp_path / "fitted.py"
    assert cli.main(["export-blender-cloth", str(path), "--preset", str(preset)]) == 0
    assert f"# {FREE[1]} " in preset.read_text()
    capsys.readouterr()
    assert "intervals_caveat" not in out and "CAUTION" not in script
    res["floor"] = dict(res["floor"], far_above=True, heldout_ratio=6.5)  # far above: the intervals say so
    res.save(str(path))
    assert cli.main(["export-blender-cloth", str(path)]) == 0
    assert "6.5x above its floor" in json.loads(capsys.readouterr().out)["intervals_caveat"]
    assert cli.main(["export-blender-cloth", str(path), "--python"]) == 0
    assert "# CAUTION: the fit ends 6.5x above its floor" in capsys.readouterr().out
