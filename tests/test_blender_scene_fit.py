"""``fit --backend blender``: Blender's own solver on a user's .blend (a cloth falling onto a box
collider, which no core model emulates) in worker processes, scored by the core objective.

The scene and its capture are made here with the bpy module; the fits run in *subprocesses*
without bpy (a process that imported bpy cannot start bpy workers: tested), on a local 2-worker
Ray instance bound to 127.0.0.1, or the spawned process pool when Ray is absent.
"""

import json
import os
import shutil
import subprocess
import sys
import tempfile

import numpy as np
import pytest
from blender_support import addon_preferences, bpy, ensure_registered, factory  # noqa: F401
from clothfit.blender import collider_scene as CS  # noqa: E402
from clothfit.blender.scene_worker import BlendScene  # noqa: E402
from clothfit.core.errors import ClothFitError  # noqa: E402
from clothfit.farm import executors  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SEED, POP, BUDGET = 3, 6, 13  # the scene's own settings, then two generations of six candidates


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """(blend, capture dir, frame zero): a 7 x 7 cloth released onto a box, 6 capture times."""
    d = tmp_path_factory.mktemp("scene")
    sc = CS.collider_scenario(7, settle=0.25, after=0.5, every=2)
    blend = str(d / "drop.blend")
    f0 = CS.build_scene(blend, sc)
    CS.observe(blend, sc, str(d / "cap"), frame_zero=f0, resolution=(60, 80))
    bpy.ops.wm.read_factory_settings(use_empty=True)
    return blend, str(d / "cap"), f0


def _env(**extra):
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTEST")}
    env.update(extra)
    return env


def _cli(args, **env):
    return subprocess.run(
        [sys.executable, "-m", "clothfit"] + args,
        cwd=ROOT,
        env=_env(**env),
        capture_output=True,
        text=True,
        timeout=600,
    )


def _fit_args(scene, out, *extra):
    blend, cap, f0 = scene
    return [
        "fit",
        cap,
        "--backend",
        "blender",
        "--blend",
        blend,
        "--frame-zero",
        str(f0),
        "--workers",
        "2",
        "--max-evaluations",
        str(BUDGET),
        "--population",
        str(POP),
        "--seed",
        str(SEED),
        "--quiet",
        "--out",
        str(out),
    ] + list(extra)


def _procs_with(text):
    found = []
    for p in os.listdir("/proc"):
        if not p.isdigit():
            continue
        try:
            with open(f"/proc/{p}/cmdline", "rb") as f:
                if text.encode() in f.read():
                    found.append(int(p))
        except OSError:
            pass
    return found


# ---------------------------------------------------------------- the worker, in this process


def test_worker_replays_the_observation_and_resets_between_candidates(scene):
    """The worker's Blender at the true settings gives the capture's vertices exactly; another
    candidate in between does not leak into the next (the cache is reset); fractional frames are
    read linearly between whole frames."""
    blend, cap, f0 = scene
    bs = BlendScene(blend)
    info = bs.info()
    assert info["object"] == "Cloth" and info["colliders"] == ["Table"] and info["n_vertices"] == 49
    truth = json.load(open(os.path.join(cap, "capture.json")))["meta"]["true_blender_cloth"]
    obs = np.load(os.path.join(cap, "shapes.npz"))["positions"]
    frames = f0 + np.arange(2, 13, 2)
    a = bs.simulate(truth, frames)
    other = bs.simulate(dict(truth, tension_stiffness=5.0, bending_stiffness=3.0), frames)
    b = bs.simulate(truth, frames)
    assert np.array_equal(a["positions"], obs) and np.array_equal(b["positions"], obs)
    assert 0 < a["cpu_seconds"] and 0 < a["seconds"]
    assert np.abs(other["positions"] - obs).max() > 1e-3
    half = bs.simulate(truth, [f0 + 2.5])["positions"][0]
    two = bs.simulate(truth, [f0 + 2, f0 + 3])["positions"]
    assert np.allclose(half, 0.5 * (two[0] + two[1]), atol=1e-12)
    # the box holds the cloth up: the core model (no colliders) lets it fall through
    from clothfit.core.observation.capture import load_capture
    from clothfit.core.physics import blender as B
    from clothfit.core.physics.models import BlenderModel

    c = load_capture(cap)
    core = BlenderModel(24).simulate(c.scenario, B.settings_row(B.check_settings(truth)))
    assert np.abs(core.positions[0] - obs).max() > 0.01


@pytest.mark.parametrize("name,msg", [("Nope", "no object named 'Nope'"), ("Table", "has no Cloth modifier")])
def test_bad_objects_are_one_line_errors(scene, name, msg):
    with pytest.raises(ClothFitError, match=msg):
        BlendScene(scene[0], name)


def test_driver_with_bpy_refuses_to_start_workers(scene):
    """This process has imported bpy: spawned workers would fail with "No module named '_bpy'"."""
    from clothfit.farm.scene import BlendSceneEvaluator

    for kind in ("process", "ray"):
        with pytest.raises(ClothFitError, match="imported bpy"):
            BlendSceneEvaluator(scene[0], workers=1, executor=kind)
    assert "bpy" in sys.modules


# ---------------------------------------------------------------- fits, in processes without bpy


@pytest.fixture(scope="module")
def ray_fit(scene, tmp_path_factory):
    pytest.importorskip("ray")
    out = tmp_path_factory.mktemp("rayfit") / "fit.json"
    tmp = tempfile.mkdtemp(prefix="cfray", dir="/tmp")
    r = _cli(_fit_args(scene, out), CLOTHFIT_RAY_TMPDIR=tmp)
    yield r, out, tmp
    shutil.rmtree(tmp, ignore_errors=True)


def test_fit_on_local_ray_writes_the_result_and_leaves_no_process(ray_fit):
    r, out, tmp = ray_fit
    assert r.returncode == 0, r.stderr[-2000:]
    res = json.load(open(out))
    assert res["backend"] == "blender" and res["executor"] == "ray" and res["workers"] == 2
    # the scene's own settings first (the fit never answers worse than them), then two generations of 6
    assert res["evaluations"] == BUDGET and res["blender_evaluations"] == BUDGET and res["seconds"] > 0
    assert res["scene"]["colliders"] == ["Table"] and res["scene"]["object"] == "Cloth"
    assert set(res["blender_cloth"]) >= {"tension_stiffness", "mass", "time_scale", "quality"}
    assert res["best_E_all"] is not None
    assert _procs_with(tmp) == []  # Ray's processes of that session are gone
    summary = json.loads(r.stdout)  # stdout is the summary alone: Ray's and Blender's output went to stderr
    assert summary["blender_cloth"] == res["blender_cloth"] and summary["out"] == str(out)


def test_no_ray_fallback_gives_the_same_fit(scene, ray_fit, tmp_path):
    """Without Ray: the spawned process pool, the same candidates and the same result."""
    out = tmp_path / "fit.json"
    r = _cli(_fit_args(scene, out), CLOTHFIT_NO_RAY="1")
    assert r.returncode == 0, r.stderr[-2000:]
    res = json.load(open(out))
    assert res["executor"] == "process"
    ray_res = json.load(open(ray_fit[1]))
    assert res["blender_cloth"] == ray_res["blender_cloth"] and res["best_E_all"] == ray_res["best_E_all"]


def _free_port():
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _kill_procs_with(text):
    import signal
    import time

    for sig in (signal.SIGTERM, signal.SIGKILL):
        for p in _procs_with(text):
            try:
                os.kill(p, sig)
            except OSError:
                pass
        for _ in range(50):
            if not _procs_with(text):
                return
            time.sleep(0.2)


def test_fit_and_fit_many_on_a_running_cluster_by_address(scene, ray_fit, tmp_path):
    """``--address HOST:PORT``: a Ray cluster started apart (``ray start --head`` on loopback, as
    docs/ray.md tells), the fit run from a directory outside the repository (its workers get ``addon``
    through Ray's ``py_modules``, not through the repository's path); the same result as the fit
    on a local instance, and the cluster is left running for the next fit. ``fit-many --address``
    on the same cluster gives the local fit of the capture."""
    pytest.importorskip("ray")
    tmp = tempfile.mkdtemp(prefix="cfrc", dir="/tmp")
    port = _free_port()
    ray_cli = os.path.join(os.path.dirname(sys.executable), "ray")
    env = {
        k: v
        for k, v in _env(RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER="0", RAY_AUTH_MODE="disabled").items()
        if k != "PYTHONPATH"
    }
    try:
        r = subprocess.run(
            [
                ray_cli,
                "start",
                "--head",
                "--node-ip-address=127.0.0.1",
                f"--port={port}",
                "--num-cpus=2",
                "--include-dashboard=false",
                "--disable-usage-stats",
                f"--temp-dir={tmp}",
            ],
            cwd=tmp,
            env=env,
            capture_output=True,
            text=True,
            timeout=180,
        )
        assert r.returncode == 0, (r.stdout + r.stderr)[-2000:]
        out = tmp_path / "fit.json"
        blend, cap, f0 = scene
        args = _fit_args(scene, out, "--address", f"127.0.0.1:{port}")
        fit = subprocess.run(
            [sys.executable, "-m", "clothfit"] + args,
            cwd=tmp,
            env=dict(env, PYTHONPATH=ROOT),
            capture_output=True,
            text=True,
            timeout=600,
        )
        assert fit.returncode == 0, fit.stderr[-2000:]
        res = json.load(open(out))
        assert res["executor"] == "ray" and res["evaluations"] == BUDGET  # the scene's own settings count
        ray_res = json.load(open(ray_fit[1]))
        assert res["blender_cloth"] == ray_res["blender_cloth"] and res["best_E_all"] == ray_res["best_E_all"]
        assert _procs_with(tmp), "the fit must leave the user's cluster running"
        # fit-many on the same cluster: core-model fits as Ray tasks, each the local fit of that capture
        many = tmp_path / "many"
        fm = subprocess.run(
            [
                sys.executable,
                "-m",
                "clothfit",
                "fit-many",
                cap,
                "--address",
                f"127.0.0.1:{port}",
                "--workers",
                "2",
                "--max-evaluations",
                "14",
                "--seed",
                "5",
                "--out-dir",
                str(many),
            ],
            cwd=tmp,
            env=dict(env, PYTHONPATH=ROOT),
            capture_output=True,
            text=True,
            timeout=600,
        )
        assert fm.returncode == 0, fm.stderr[-2000:]
        assert json.loads(fm.stdout)["executor"] == "ray"
        from clothfit.core.fitting.job import FitConfig, FitJob
        from clothfit.core.observation.capture import load_capture

        with open(many / f"000_{os.path.basename(cap)}.json") as f:
            got = json.load(f)
        local = FitJob(load_capture(cap), FitConfig(max_evaluations=14, seed=5)).run()
        assert got["params"] == local["params"] and got["best_E_all"] == local["best_E_all"]
        assert _procs_with(tmp), "fit-many must leave the user's cluster running"
    finally:
        _kill_procs_with(tmp)
        shutil.rmtree(tmp, ignore_errors=True)


KILL = r"""
import json, os, signal, sys
from clothfit.core.fitting.job import FitConfig, FitJob
from clothfit.core.observation.capture import load_capture
from clothfit.farm.scene import BlendSceneEvaluator
blend, cap, f0, seed, pop, budget = sys.argv[1], sys.argv[2], float(sys.argv[3]), *map(int, sys.argv[4:7])
kind = sys.argv[7]
ev = BlendSceneEvaluator(blend, frame_zero=f0, workers=2, executor=kind)
pids = ev.executor.pids()
ips = ev.executor.node_ips() if kind == "ray" else None
state = {"batch": 0}
def hook(ex):
    state["batch"] += 1
    if state["batch"] == 2:                 # the second generation's candidates are queued: kill one worker
        os.kill(pids[1], signal.SIGKILL)
ev.executor.after_submit = hook
job = FitJob(load_capture(cap), FitConfig(evaluator="blender", max_evaluations=budget, population=pop, seed=seed),
             evaluator=ev)
res = job.run()
after = ev.executor.pids()
ev.close()
print(json.dumps({"res": res, "pids": pids, "after": after, "ips": ips}, default=float))
"""


@pytest.mark.parametrize("kind", ["ray", "process"])
def test_worker_killed_mid_fit_is_restarted_and_its_candidates_evaluated_again(scene, ray_fit, kind):
    """Ray restarts the actor and re-runs its queued candidates; the process pool, broken by the
    death, is started again and the batch re-run. Either way the fit is the undisturbed one."""
    pytest.importorskip("ray")
    blend, cap, f0 = scene
    tmp = tempfile.mkdtemp(prefix="cfray", dir="/tmp")
    r = subprocess.run(
        [sys.executable, "-c", KILL, blend, cap, str(f0), str(SEED), str(POP), str(BUDGET), kind],
        cwd=ROOT,
        env=_env(CLOTHFIT_RAY_TMPDIR=tmp, PYTHONPATH=ROOT),
        capture_output=True,
        text=True,
        timeout=600,
    )
    shutil.rmtree(tmp, ignore_errors=True)
    assert r.returncode == 0, r.stderr[-2000:]
    d = json.loads(r.stdout.strip().splitlines()[-1])
    if kind == "ray":
        assert d["ips"] == ["127.0.0.1"] * 3  # Ray's local instance stays on the loopback address
        assert d["after"][0] == d["pids"][0] and d["after"][1] != d["pids"][1]  # worker 1 was replaced
    else:
        assert d["pids"][1] not in d["after"]  # a new pool
    res = d["res"]
    assert res["evaluations"] == BUDGET and res["blender_evaluations"] == BUDGET  # the scene's own settings count
    ray_res = json.load(open(ray_fit[1]))
    assert res["blender_cloth"] == ray_res["blender_cloth"] and res["best_E_all"] == ray_res["best_E_all"]
    assert _procs_with(tmp) == []


@pytest.mark.parametrize(
    "extra,msg",
    [
        (["--blend", "/nonexistent/x.blend"], "file not found"),
        (["--object", "Table", "--executor", "process", "--workers", "1"], "has no Cloth modifier"),
        (["--frame-zero", "100", "--executor", "process", "--workers", "1"], "outside the cloth cache"),
    ],
)
def test_bad_scene_input_is_one_line(scene, tmp_path, extra, msg):
    args = _fit_args(scene, tmp_path / "f.json")
    for k in range(0, len(extra), 2):  # later options win in argparse
        args += extra[k : k + 2]
    r = _cli(args, CLOTHFIT_NO_RAY="1")
    assert r.returncode == 2, r.stderr[-2000:]
    err = r.stderr.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and msg in err[0], r.stderr


def test_executor_refuses_address_without_ray():
    with pytest.raises(ClothFitError, match="needs Ray"):
        executors.make_executor("x:y", (), 1, address="auto", kind="process")


# ---------------------------------------------------------------- the add-on's operators


def _open(scene):
    blend, cap, f0 = scene
    bpy.ops.wm.open_mainfile(filepath=blend)
    ensure_registered()
    sc = bpy.context.scene
    obj = sc.objects["Cloth"]
    bpy.context.view_layer.objects.active = obj
    sc.clothfit.capture_dir = cap
    return sc, obj


def test_fit_this_cloth_operator_fits_in_its_own_process_and_apply_writes_the_settings(scene, monkeypatch, tmp_path):
    monkeypatch.setenv("CLOTHFIT_NO_RAY", "1")
    sc, obj = _open(scene)
    prefs = addon_preferences()  # the operator's defaults: workers and working folder
    prefs.workers, prefs.cache_dir = 2, str(tmp_path / "cache")
    sc.clothfit.max_evaluations = 6
    assert bpy.ops.clothfit.fit_scene_cloth(frame_zero=scene[2]) == {"FINISHED"}
    assert obj["clothfit_scene_fit_result"].startswith(str(tmp_path / "cache" / "clothfit_scene_fit_"))
    res = json.load(open(obj["clothfit_scene_fit_result"]))
    assert res["evaluations"] >= 6 and not res["cancelled"] and res["workers"] == 2
    assert res["backend"] == "blender" and res["executor"] == "process" and res["scene"]["object"] == "Cloth"
    assert sc.clothfit.fit_verdict == res["verdict"] and res["blender_scene"]["fps_source"] == "the scene's (--blend)"
    before = obj.modifiers["Cloth (Cloth Fit)"].settings.tension_stiffness
    assert bpy.ops.clothfit.apply_scene_fit() == {"FINISHED"}
    cs = obj.modifiers["Cloth (Cloth Fit)"].settings
    for k in ("tension_stiffness", "bending_stiffness", "air_damping", "time_scale"):
        assert getattr(cs, k) == pytest.approx(res["blender_cloth"][k], rel=1e-6)
    # six candidates may find nothing better than the scene's own settings: then those are the answer
    assert res["best_E_sil_mean_pct"] <= res["start_E_sil_mean_pct"]
    assert (cs.tension_stiffness != before) == (res["best_E_sil_mean_pct"] < res["start_E_sil_mean_pct"])
    bpy.ops.wm.read_factory_settings(use_empty=True)


def test_esc_stops_the_fit_and_keeps_the_best(scene, monkeypatch, tmp_path):
    from clothfit.blender.scene_fit import SceneFitSession

    monkeypatch.setenv("CLOTHFIT_NO_RAY", "1")
    sc, obj = _open(scene)
    # restarts keep the fit running until Esc (a converged fit would stop on its own first on a busy machine)
    s = SceneFitSession(
        sc,
        obj,
        scene[1],
        3000,
        workers=2,
        frame_zero=scene[2],
        extra=["--population", "6", "--restarts", "20"],
        out_dir=str(tmp_path / "fit"),
    )
    res = s.wait(sc, poll=lambda sess: sess.progress()[0] >= 12)
    assert s.cancelled and res["cancelled"] and 12 <= res["evaluations"] < 3000
    assert res["blender_cloth"]["tension_stiffness"] > 0
    bpy.ops.wm.read_factory_settings(use_empty=True)


def test_unreachable_ray_address_of_the_preferences_is_a_one_line_error(scene, tmp_path):
    """The preferences' Ray address is only connected to (never started), checked before anything is
    written: a closed port on the loopback address is one line, and the cache folder stays empty."""
    import socket

    with socket.socket() as s:  # a loopback port that nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    sc, obj = _open(scene)
    prefs = addon_preferences()
    prefs.ray_address, prefs.cache_dir = f"ray://127.0.0.1:{port}", str(tmp_path / "cache")
    with pytest.raises(RuntimeError, match=f"cannot connect to the Ray cluster at ray://127.0.0.1:{port}") as ei:
        bpy.ops.clothfit.fit_scene_cloth(frame_zero=scene[2])
    assert "\n" not in str(ei.value).strip()
    assert os.listdir(tmp_path / "cache") == []
    bpy.ops.wm.read_factory_settings(use_empty=True)


def test_operator_without_a_cloth_is_a_one_line_error(scene):
    sc, obj = _open(scene)
    bpy.context.view_layer.objects.active = sc.objects["Table"]
    with pytest.raises(RuntimeError, match="has no Cloth modifier"):
        bpy.ops.clothfit.fit_scene_cloth()
    with pytest.raises(RuntimeError, match="has no Cloth modifier"):
        bpy.ops.clothfit.apply_scene_fit()
    bpy.ops.wm.read_factory_settings(use_empty=True)
