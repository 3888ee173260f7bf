import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

"""The fitness (objective), an end-to-end fit on a small synthetic capture, checkpoint/resume,
cancel, evaluation on held-out cameras and the overlays."""

import json

import cv2
import numpy as np
import pytest
from clothfit.core import defaults as D
from clothfit.core.errors import ClothFitError
from clothfit.core.fitting.evaluate import evaluate
from clothfit.core.fitting.job import FitConfig, FitJob
from clothfit.core.fitting.objective import SilhouetteObjective
from clothfit.core.observation import camera as C
from clothfit.core.observation import overlay, raster, synth
from clothfit.core.physics import jit
from clothfit.core.physics.models import simulate
from clothfit.core.physics.scenario import paper_scenario

GT = dict(D.GT_PARAMS)
GT_ROW = [GT["m"], GT["k"], GT["l"], GT["d"]]
K10_ROW = [GT["m"], GT["k"] * 1.1, GT["l"], GT["d"]]
needs_numba = pytest.mark.skipif(not jit.available(), reason="numba not importable: no second backend")
BACKENDS = ["numpy", pytest.param("numba", marks=needs_numba)]

H, W = 120, 160


@pytest.fixture(scope="module")
def rig():
    return C.load_rig("lab18")


# ------------------------------------------------------------------ objective


@pytest.fixture(scope="module")
def small_problem(rig):
    """3 cameras of lab18 at 120x160, 5 frames, noise-free observations of the ground truth."""
    cams = [rig[i].resized(H, W) for i in (0, 9, 16)]
    sc = paper_scenario(frame_times=[0.1, 0.3, 0.5, 0.8, 1.2])
    X = simulate(sc, [GT], backend="numpy", safety=D.TRUTH_DT_SAFETY).positions[0]
    obs = [[raster.silhouette(c, X[f], sc.grid.triangles) for f in range(5)] for c in cams]
    return sc, cams, obs


@needs_numba
def test_objective_backends_agree(small_problem):
    sc, cams, obs = small_problem
    P = np.array([GT_ROW, K10_ROW])
    sim_a = simulate(sc, P, backend="numpy")
    sim_b = simulate(sc, P, backend="numba")
    assert np.abs(sim_a.positions - sim_b.positions).max() < 1e-6  # the simulations agree
    ea, xa = SilhouetteObjective(sc, cams, obs, backend="numpy").per_image(P)
    eb, xb = SilhouetteObjective(sc, cams, obs, backend="numba").per_image(P)
    assert ea.shape == eb.shape == (2, 3, 5)
    assert not xa.any() and not xb.any()
    assert np.all(np.isfinite(ea)) and np.all(ea >= 0)
    assert np.allclose(ea, eb, rtol=1e-9, atol=0), np.abs(ea - eb).max()
    # totals: eq. 7 is the sum of eq. 6 over the images; the perturbed k is worse than the truth
    fa = SilhouetteObjective(sc, cams, obs, backend="numpy")(P)
    assert np.allclose(fa, ea.sum(axis=(1, 2)), rtol=1e-12)
    assert fa[1] > fa[0] >= 0


class _Crumpled:
    """A model whose candidates are given positions (the rest sheet crumpled by random offsets): the
    scoring alone, on quads that project convex, concave, twisted and folded over."""

    name = "paper"
    row_names = ("seed",)

    def __init__(self, grid, n_frames, amplitude):
        self.grid, self.n_frames, self.amplitude = grid, n_frames, amplitude

    def to_dict(self):
        return {"name": self.name}

    def simulate(self, scenario, rows, backend="auto", offsets=None):
        from clothfit.core.physics.paper import SimResult

        X = []
        for r in np.asarray(rows).reshape(-1):
            rng = np.random.default_rng(int(r))
            shake = rng.normal(0.0, self.amplitude, (self.n_frames,) + self.grid.rest.shape)
            X.append(self.grid.rest[None] + shake)
        return SimResult(np.array(X), np.zeros(len(X), dtype=bool), np.zeros(len(X), dtype=int), [""] * len(X))


@needs_numba
@pytest.mark.parametrize("crop", [False, True])
def test_the_numba_scoring_counts_every_pixel_of_crumpled_cloth_as_the_reference_raster(rig, crop):
    """The numba kernels cut each quad that projects convex into one span per row and any other into
    its two triangles; the pixels scored must be exactly the reference raster's triangles' pixels."""
    from clothfit.core.physics.crop import CropPlane
    from clothfit.core.physics.scenario import ClothGrid, Scenario

    base = paper_scenario(ClothGrid(9), frame_times=[0.1, 0.2, 0.3])
    plane = CropPlane.parse({"point": [0.0, 0.0, D.CLOTH_HEIGHT], "normal": [0.0, 0.3, 1.0]}) if crop else None
    sc = Scenario(base.grid, base.handles, base.frame_times, 0.2, base.gravity, crop=plane)
    cams = [rig[i].resized(H, W) for i in (0, 5, 9, 16)]
    model = _Crumpled(sc.grid, 3, 0.6 * sc.grid.spacing)
    # observations: other crumpled sheets, so that model and observation overlap partly
    obs_sim = _Crumpled(sc.grid, 3, 0.6 * sc.grid.spacing).simulate(sc, [99])
    obs = [
        [raster.silhouette(c, obs_sim.positions[0, f], sc.grid.triangles, crop=plane) for f in range(3)] for c in cams
    ]
    # pixels of unknown truth: a band of columns across every image (model pixels there leave the XOR)
    band = np.zeros((H, W), dtype=bool)
    band[:, 70:90] = True
    ignore = [[band] * 3 for _ in cams]
    rows = np.arange(6.0)[:, None]
    ea, _ = SilhouetteObjective(sc, cams, obs, backend="numpy", model=model, ignore=ignore).per_image(rows)
    eb, _ = SilhouetteObjective(sc, cams, obs, backend="numba", model=model, ignore=ignore).per_image(rows)
    assert np.all(np.isfinite(ea)) and ea.min() > 0.05
    np.testing.assert_array_equal(eb, ea)
    # the crumpling gives both kinds of quads: convex ones (one span per row) and others (two triangles)
    uv = cams[0].project(model.simulate(sc, [0]).positions[0, 0])[sc.grid.quads]  # (Q, 4, 2)
    e = np.roll(uv, -1, axis=1) - uv
    turn = e[:, :, 0] * np.roll(e, -1, axis=1)[:, :, 1] - e[:, :, 1] * np.roll(e, -1, axis=1)[:, :, 0]
    convex = np.all(turn > 0, axis=1) | np.all(turn < 0, axis=1)
    assert 0.2 < convex.mean() < 0.9


def test_a_meshs_triangles_pair_into_quads_that_hold_the_same_triangles():
    """A scene's mesh comes as Blender tessellates it (each quad's corners 0-1-2 then 0-2-3): consecutive
    triangles across a shared edge become one quad whose two triangles are exactly those; others stay alone."""
    from clothfit.core.physics.scenario import ClothGrid

    g = ClothGrid(5)
    tris = np.concatenate([g.quads[:, [0, 1, 2]], g.quads[:, [0, 2, 3]]], 1).reshape(-1, 3)
    tris = np.concatenate([tris, [[0, 6, 12]]])  # and a triangle on its own
    q = raster.paired_quads(tris)
    assert q.shape == (17, 4) and np.all(q[:16, 3] >= 0) and q[16, 3] == -1
    halves = [sorted(r[[0, 1, 2]]) for r in q] + [sorted(r[[0, 2, 3]]) for r in q[:16]]
    assert sorted(map(tuple, halves)) == sorted(tuple(sorted(t)) for t in tris)
    # the grid's own triangle list (one block of halves, then the other) pairs nowhere: all alone
    assert np.all(raster.paired_quads(g.triangles)[:, 3] == -1)


def test_objective_per_image_is_e_sil_of_the_model_silhouette(small_problem):
    """The numpy objective's per-image value equals metrics.e_sil of a separately rasterised model."""
    from clothfit.core.observation.metrics import e_sil

    sc, cams, obs = small_problem
    X = simulate(sc, [K10_ROW], backend="numpy").positions[0]
    esil, _ = SilhouetteObjective(sc, cams, obs, backend="numpy").per_image(np.array([K10_ROW]))
    for c, cam in enumerate(cams):
        for f in range(5):
            mod = raster.silhouette(cam, X[f], sc.grid.triangles)
            assert esil[0, c, f] == pytest.approx(e_sil(obs[c][f], mod), rel=1e-12)


BAD_ROWS = {
    "too_stiff": [1e-5, 1e9, GT["l"], 0.0],
    "negative_mass": [-1e-5, 10.0, GT["l"], 0.0],
    "nan_k": [1e-5, float("nan"), GT["l"], 0.0],
}


_REF = {}


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("kind", list(BAD_ROWS))
def test_exploded_candidates_score_inf(small_problem, backend, kind):
    sc, cams, obs = small_problem
    sc = sc.with_frames(sc.frame_times[:2])  # t = 0.1, 0.3: shorter simulations
    obs = [o[:2] for o in obs]
    obj = SilhouetteObjective(sc, cams, obs, backend=backend)
    if backend not in _REF:
        _REF[backend] = obj.per_image(np.array([K10_ROW]))[0][0]
    esil, exploded = obj.per_image(np.array([K10_ROW, BAD_ROWS[kind]]))  # never an exception
    assert exploded.tolist() == [False, True]
    assert np.all(esil[1] == np.inf)
    assert np.allclose(esil[0], _REF[backend], rtol=1e-12, atol=0)  # the good one is unaffected
    f = obj(np.array([BAD_ROWS[kind], K10_ROW]))
    assert f[0] == np.inf and f[1] == pytest.approx(_REF[backend].sum(), rel=1e-12)


def test_objective_input_errors(small_problem):
    sc, cams, obs = small_problem
    bad = [list(o) for o in obs]
    bad[1][2] = np.zeros((H, W + 1), bool)
    with pytest.raises(ClothFitError, match="120x161"):
        SilhouetteObjective(sc, cams, bad, backend="numpy")
    bad = [list(o) for o in obs]
    bad[0][0] = np.zeros((H, W), bool)
    with pytest.raises(ClothFitError, match="empty"):
        SilhouetteObjective(sc, cams, bad, backend="numpy")
    with pytest.raises(ClothFitError, match="2 silhouette lists for 3 cameras"):
        SilhouetteObjective(sc, cams, obs[:2], backend="numpy")
    with pytest.raises(ClothFitError, match="backend"):
        SilhouetteObjective(sc, cams, obs, backend="cuda")


# ------------------------------------------------------------ synthetic capture

TIMES = [0.1, 0.15, 0.2, 0.3, 0.4, 0.45, 0.6, 0.75, 0.8, 1.0, 1.2, 1.25]
TRAIN_TIMES = [0.1, 0.2, 0.4, 0.6, 0.8, 1.0]
TEST_TIMES = [0.15, 0.45, 0.75, 1.25]


@pytest.fixture(scope="module")
def capture(rig, tmp_path_factory):
    """6 cameras of lab18 at 120x160 (the 4 first of the spread order to train, 2 held out), 12
    frames, 5 % boundary noise, ground truth simulated with the finer truth step."""
    train, held = C.select_training(rig, 4)
    cams = [rig[i].resized(H, W) for i in train] + [rig[i].resized(H, W) for i in held[:2]]
    root = tmp_path_factory.mktemp("cap")
    cap = synth.synth_capture(str(root), cameras=cams, scenario=paper_scenario(frame_times=TIMES), seed=3)
    assert cap.n_cameras == 6 and cap.n_frames == 12
    assert cap.meta["true_params"] == GT
    return cap


# bounds ~2.5x around the truth on each side, for the short runs below
FIT_BOUNDS = {"k_over_m": [2e5, 5e6], "d_over_m": [1.0, 25.0], "l_rel": [0.8, 1.25]}


def test_end_to_end_cma_es_recovers_the_identifiable_parameters(capture):
    # the default search space (two decades in k/m and d/m, l within -40..+40 %)
    cfg = FitConfig(
        train_cameras=[0, 1, 2, 3], train_times=TRAIN_TIMES, optimizer="cma-es", seed=0, max_evaluations=500
    )
    job = FitJob(capture, cfg)
    assert job.m == pytest.approx(GT["m"]) and "cloth_mass" in job.m_source
    r = job.run()
    assert r["finished"] and not r["cancelled"] and r["evaluations"] >= 500
    assert r["n_train_images"] == 24
    err = r["identifiable_error_pct"]
    assert err["k_over_m"] < 3.0, err
    assert err["d_over_m"] < 4.0, err
    assert err["l"] < 1.0, err
    assert r["params"]["m"] == pytest.approx(GT["m"])
    assert r["best_E_sil_mean_pct"] < 4.0  # noise floor: 5 % of the boundary pixels flipped
    hist = [h[1] for h in r["history"] if h[1] is not None]
    assert hist == sorted(hist, reverse=True)  # best-so-far never worsens
    json.dumps(r)  # strict-JSON serialisable result


def _small_cfg(**kw):
    d = dict(
        train_cameras=[0, 2], train_times=[0.2, 0.6], optimizer="cma-es", seed=5, max_evaluations=42, bounds=FIT_BOUNDS
    )
    d.update(kw)
    return FitConfig(**d)


def test_checkpoint_and_resume_continue_to_the_budget(capture, tmp_path):
    ref = FitJob(capture, _small_cfg()).run()
    assert ref["evaluations"] == 42  # 6 generations of 7

    ck = str(tmp_path / "fit.checkpoint.json")
    job = FitJob(capture, _small_cfg(), checkpoint=ck)
    assert job.step() and job.step()
    assert job.evaluations == 14
    with open(ck) as f:
        saved = json.load(f)
    assert saved["result"]["evaluations"] == 14 and saved["finished"] is False
    del job

    job2 = FitJob.resume(ck, capture=capture)
    assert job2.evaluations == 14 and not job2.state.finished
    r = job2.run()
    assert r["evaluations"] == 42 and r["finished"]
    # the resumed run is the uninterrupted one
    assert r["params"] == ref["params"]
    assert r["history"] == ref["history"]
    # resuming a finished job does nothing more
    job3 = FitJob.resume(ck, capture=capture)
    assert job3.state.finished and not job3.step() and job3.evaluations == 42
    with pytest.raises(ClothFitError, match="not found"):
        FitJob.resume(str(tmp_path / "missing.json"), capture=capture)


def test_the_evaluation_budget_is_a_hard_cap_and_the_count_is_honest(capture, tmp_path):
    """A budget that is no multiple of the population: the last generation is cut to what is left, every
    candidate scored is counted, none more; resumed with a larger budget, the fit is the uninterrupted one."""
    pop = FitJob(capture, _small_cfg()).opt.ask().shape[0]
    budget = 2 * pop + 2
    ck = str(tmp_path / "cut.checkpoint.json")
    job = FitJob(capture, _small_cfg(max_evaluations=budget), checkpoint=ck)
    scored = []
    score = job.evaluate

    # what the search scores (the report at the end scores the best again: not a candidate)
    def counted(X, objective=None):
        if not job.state.finished:
            scored.append(len(X))
        return score(X, objective)

    job.evaluate = counted
    r = job.run()
    assert sum(scored) == r["evaluations"] == budget and r["stop_reason"] == "budget"
    assert scored[-1] == budget % pop
    ref = FitJob(capture, _small_cfg(max_evaluations=6 * pop)).run()
    again = FitJob.resume(ck, capture=capture, config=_small_cfg(max_evaluations=6 * pop)).run()
    assert again["evaluations"] == ref["evaluations"] == 6 * pop
    assert again["params"] == ref["params"] and again["history"] == ref["history"]
    # a budget smaller than the first generation: that generation is cut, and there is an answer
    tiny = FitJob(capture, _small_cfg(max_evaluations=pop - 2)).run()
    assert tiny["evaluations"] == pop - 2 and tiny["params"] and tiny["stop_reason"] == "budget"


def test_a_fits_progress_lines_come_at_their_interval_and_name_the_settings(capture):
    """The studies' fits (paper, bench) show their progress through ``run_shown``: lines prefixed with the
    fit's label, the first after the first generation, then one per interval, and the last state at the
    end; each names the paper model's free settings."""
    from clothfit.core.fitting.progress import FitProgress, run_shown

    pop = FitJob(capture, _small_cfg()).opt.ask().shape[0]
    out, labels = [], []

    def every_generation(label):
        labels.append(label)
        return FitProgress(out.append, False, interval=0.0, label=f"{label}: ")

    r = run_shown(FitJob(capture, _small_cfg(max_evaluations=2 * pop)), every_generation, "table1, 4 cameras")
    assert labels == ["table1, 4 cameras"] and r["evaluations"] == 2 * pop
    assert all(x.startswith("table1, 4 cameras: ") and x.endswith("\n") for x in out) and len(out) >= 2
    assert out[-1].startswith(f"table1, 4 cameras: {2 * pop}/{2 * pop} evaluations") and "left: k " in out[-1]
    assert " l " in out[-1] and " d " in out[-1] and " m " not in out[-1]  # the mass is fixed, not searched
    out.clear()
    run_shown(FitJob(capture, _small_cfg(max_evaluations=3 * pop)), lambda label: FitProgress(out.append, False, 1e6))
    assert len(out) == 2 and out[0].startswith(f"{pop}/{3 * pop} ") and out[1].startswith(f"{3 * pop}/{3 * pop} ")


def test_cancel_keeps_the_best_so_far(capture, tmp_path):
    ck = str(tmp_path / "c.json")
    job = FitJob(capture, _small_cfg(max_evaluations=10_000), checkpoint=ck)
    job.step()
    job.step()
    best = job.best_params
    assert best is not None
    job.cancel()
    assert not job.step()  # a cancelled job does no more work
    r = job.result()
    assert r["cancelled"] is True and r["finished"] is True
    assert r["params"] == best
    assert r["best_E_all"] is not None and np.isfinite(r["best_E_all"]) and r["best_E_all"] > 0
    assert r["evaluations"] == 14
    with open(ck) as f:
        assert json.load(f)["cancelled"] is True
    # a callback returning True cancels after the current generation
    job = FitJob(capture, _small_cfg(max_evaluations=10_000))
    r = job.run(callback=lambda j: True)
    assert r["cancelled"] and r["evaluations"] == 7 and r["params"] is not None


def test_fitjob_config_errors(capture):
    with pytest.raises(ClothFitError, match="7"):
        FitJob(capture, _small_cfg(train_cameras=[0, 7]))
    with pytest.raises(ClothFitError, match="0.33"):
        FitJob(capture, _small_cfg(train_times=[0.33]))
    with pytest.raises(ClothFitError, match="simplex"):
        FitJob(capture, _small_cfg(optimizer="simplex"))
    with pytest.raises(ClothFitError, match="unknown keys"):
        FitConfig.from_dict({"optimiser": "cma-es"})


def test_evaluate_prefers_the_truth_on_held_out_cameras(capture):
    held = [4, 5]
    good = evaluate(capture, GT, cameras=held, times=TEST_TIMES)
    bad = evaluate(capture, dict(GT, k=GT["k"] * 1.2), cameras=held, times=TEST_TIMES)
    assert good["cameras"] == [capture.cameras[i].name for i in held]
    assert good["times"] == TEST_TIMES
    assert not good["exploded"] and not bad["exploded"]
    assert 0 < good["silhouette_error_pct"] < bad["silhouette_error_pct"]
    assert len(good["silhouette_error_pct_per_camera"]) == 2 and len(good["silhouette_error_pct_per_time"]) == 4
    assert good["silhouette_error_pct"] == pytest.approx(np.mean(good["silhouette_error_pct_per_camera"]))
    # shapes: the truth is within a fraction of a millimetre (the model's step is 4x the truth's)
    assert good["shape_error_mm"] < 0.5 < bad["shape_error_mm"]


# -------------------------------------------------------------------- overlays


def test_overlay_colours_on_a_hand_made_pair():
    obs = np.array([[1, 1, 0, 0]], bool)
    mod = np.array([[1, 0, 1, 0]], bool)
    img = overlay.overlay_image(obs, mod)
    assert img.dtype == np.uint8 and img.shape == (1, 4, 3)
    white, red, blue, black = img[0]
    assert white.tolist() == [255, 255, 255]
    assert red.tolist() == list(overlay.MISSING_RGB) and red[0] > 200 and red[1] < 100 and red[2] < 100
    assert blue.tolist() == list(overlay.EXTRA_RGB) and blue[2] > 200 and blue[0] < 100
    assert black.tolist() == [0, 0, 0]
    with pytest.raises(ClothFitError, match="differ"):
        overlay.overlay_image(obs, np.zeros((2, 4), bool))


def test_capture_overlays_write_one_png_per_image_and_a_contact_sheet(capture, tmp_path):
    out = tmp_path / "ov"
    cams, times = [0, 4], [0.1, 0.75]
    paths = overlay.capture_overlays(capture, GT, str(out), cameras=cams, times=times)
    assert len(paths) == 5 and paths[-1].endswith("contact_sheet.png")
    assert all(os.path.isfile(p) for p in paths)
    X = simulate(capture.scenario.with_frames(times), [GT]).positions[0]
    k = 0
    for c in cams:
        cam = capture.cameras[c]
        for j, t in enumerate(times):
            f = capture.frame_index(t)
            p = paths[k]
            k += 1
            assert os.path.dirname(p).endswith(cam.name)
            rgb = cv2.imread(p, cv2.IMREAD_COLOR)[..., ::-1]
            obs = capture.load_silhouette(c, f)
            mod = raster.silhouette(cam, X[j], capture.scenario.grid.triangles)
            assert np.array_equal(rgb, overlay.overlay_image(obs, mod))
            # all four classes present: agreement dominates, noise gives both missing and extra pixels
            assert (rgb == 255).all(-1).sum() > 10 * (rgb == overlay.MISSING_RGB).all(-1).sum() > 0
            assert (rgb == overlay.EXTRA_RGB).all(-1).sum() > 0
    sheet = cv2.imread(paths[-1])
    assert sheet is not None and sheet.shape[0] > 50 and sheet.shape[1] >= 6 * 213
