"""Trustworthy fits: nothing executed from files, no silent wrong results, no lost or
overwritten data, fits that stop when they have converged. The CLI is driven in-process
(``cli.main``, the same code path as ``python -m clothfit``) except for the kill -9 test."""

import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import base64
import json
import pickle
import random
import shutil
import signal
import subprocess
import time

import numpy as np
import pytest
from clothfit import cli
from clothfit.core import defaults as D
from clothfit.core import jsonio, safeio
from clothfit.core.errors import ClothFitError
from clothfit.core.fitting import objective as O
from clothfit.core.fitting.job import FitConfig, FitJob, read_checkpoint
from clothfit.core.observation import camera as C
from clothfit.core.observation import synth
from clothfit.core.physics.scenario import paper_scenario

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TIMES = [0.1, 0.2, 0.3, 0.4, 0.6, 0.8]


@pytest.fixture(scope="module")
def cap(tmp_path_factory):
    """6 cameras of lab18 at 60 x 80, 6 frames, the default 5 % boundary noise."""
    rig = C.load_rig("lab18")
    cams = [c.resized(60, 80) for c in rig[:6]]
    root = tmp_path_factory.mktemp("trust") / "cap"
    return synth.synth_capture(str(root), cameras=cams, scenario=paper_scenario(frame_times=TIMES), seed=3)


def fit(*args):
    """``python -m clothfit fit ...`` in-process -> (exit code, stdout, stderr) via capsys-free redirection."""
    import contextlib
    import io

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = cli.main([str(a) for a in args])
    return rc, out.getvalue(), err.getvalue()


def one_line_error(rc, out, err, *needles, code=2):
    assert rc == code, (rc, out, err)
    assert "Traceback" not in err, err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    for n in needles:
        assert str(n) in lines[0], (n, err)
    return lines[0]


FAST = ("--cameras", "0,2", "--times", "0.1,0.3", "--quiet")


# ------------------------------------------------------------------ convergence


def test_a_converged_fit_stops_long_before_a_huge_budget(cap):
    small = dict(train_cameras=[0, 3], train_times=[0.1, 0.3, 0.6], optimizer="cma-es", seed=0)
    job = FitJob(cap, FitConfig(max_evaluations=100_000, **small))
    r = job.run()
    assert r["stop_reason"] == "converged", r["stop_reason"]
    assert r["converged_by"] and r["evaluations"] < 2000
    assert max(r["identifiable_error_pct"].values()) < 2.0
    # the same fit with a budget it cannot finish within says so
    short = FitJob(cap, FitConfig(max_evaluations=100, **small)).run()
    assert short["stop_reason"] == "budget" and short["evaluations"] >= 100


def test_the_ga_stops_when_it_stagnates(cap, monkeypatch):
    """Job-level wiring of the GA's stagnation stop, on a cheap stand-in objective (a bowl in the
    identifiable coordinates): the real objective is exercised by the CMA-ES test above."""
    monkeypatch.setattr(O.SilhouetteObjective, "__call__", _bowl)
    r = FitJob(
        cap, FitConfig(train_cameras=[0], train_times=[0.1], optimizer="spx-mgg", seed=0, max_evaluations=1_000_000)
    ).run()
    assert r["stop_reason"] == "converged" and r["converged_by"] in (["stagnation"], ["tolx"])
    assert r["evaluations"] < 20_000


def _bowl(self, P, offsets=None):
    P = np.asarray(P)
    return np.log(P[:, 1] / P[:, 0] / 2e6) ** 2 + np.log(P[:, 3] / P[:, 0] / 9.0) ** 2 + 1.0


def test_ipop_restarts_continue_after_convergence(cap, monkeypatch):
    monkeypatch.setattr(O.SilhouetteObjective, "__call__", _bowl)
    one = FitJob(cap, FitConfig(train_cameras=[1], train_times=[0.2, 0.6], seed=1, max_evaluations=50_000)).run()
    two = FitJob(
        cap, FitConfig(train_cameras=[1], train_times=[0.2, 0.6], seed=1, max_evaluations=50_000, restarts=1)
    ).run()
    assert one["stop_reason"] == two["stop_reason"] == "converged"
    assert len(one["converged_by"]) == 1 and len(two["converged_by"]) == 2
    assert two["evaluations"] > one["evaluations"]
    assert two["best_E_all"] <= one["best_E_all"]


def test_every_candidate_exploding_is_an_error_not_a_result(cap, tmp_path, monkeypatch):
    monkeypatch.setattr(O.SilhouetteObjective, "__call__", lambda self, P: np.full(len(P), np.inf))
    out = tmp_path / "fit.json"
    line = one_line_error(*fit("fit", cap.root, "--out", out, "--max-evaluations", 100_000, *FAST), "explode")
    assert f"{D.FIT_EXPLODED_LIMIT // 7 * 7 + 7} candidates" in line  # stopped at the first generation past the limit
    r = json.loads(out.read_text())
    assert r["stop_reason"] == "error" and r["params"] is None and r["evaluations"] < 200
    assert read_checkpoint(str(out) + ".checkpoint.json")["stop_reason"] == "error"


# ------------------------------------------------------------------ resume rules


def test_resume_refuses_another_fit_and_may_grow_the_budget(cap, tmp_path):
    out = tmp_path / "fit.json"
    ck = str(out) + ".checkpoint.json"
    assert fit("fit", cap.root, "--out", out, "--max-evaluations", 21, "--seed", 4, *FAST)[0] == 0
    # a rerun without --resume would overwrite it
    one_line_error(*fit("fit", cap.root, "--out", out, "--seed", 4, *FAST), "--resume", "--force", ck)
    # another request: refused naming the differing fields
    line = one_line_error(
        *fit(
            "fit",
            cap.root,
            "--out",
            out,
            "--resume",
            "--optimizer",
            "spx-mgg",
            "--cameras",
            "0,1,2",
            "--times",
            "0.1,0.3",
            "--quiet",
        ),
        "optimizer",
        "cameras",
        "population",
    )
    assert "seed" in line  # --seed 4 was not given again
    one_line_error(
        *fit("fit", cap.root, "--out", out, "--resume", "--seed", 4, "--resolution", "30x40", *FAST), "resolution"
    )
    # the same fit with a larger budget continues where it stopped, to the uninterrupted result
    rc, so, err = fit("fit", cap.root, "--out", out, "--resume", "--seed", 4, "--max-evaluations", 49, *FAST)
    assert rc == 0, err
    assert "resumed" in err and "at 21 evaluations" in err
    resumed = json.loads(out.read_text())
    ref_out = tmp_path / "ref.json"
    assert fit("fit", cap.root, "--out", ref_out, "--max-evaluations", 49, "--seed", 4, *FAST)[0] == 0
    ref = json.loads(ref_out.read_text())
    assert resumed["evaluations"] == ref["evaluations"] == 49
    assert resumed["params"] == ref["params"] and resumed["history"] == ref["history"]
    # --force starts afresh
    assert fit("fit", cap.root, "--out", out, "--max-evaluations", 7, "--force", *FAST)[0] == 0
    assert json.loads(out.read_text())["evaluations"] == 7


def test_resume_with_a_changed_capture_is_refused(cap, tmp_path):
    copy = tmp_path / "cap"
    shutil.copytree(cap.root, copy)
    out = tmp_path / "fit.json"
    assert fit("fit", copy, "--out", out, "--max-evaluations", 14, *FAST)[0] == 0
    sil = copy / "sil" / cap.cameras[0].name / "000.png"
    import cv2

    img = cv2.imread(str(sil), cv2.IMREAD_GRAYSCALE)
    img[0, 0] = 255 - img[0, 0]
    cv2.imwrite(str(sil), img)
    one_line_error(*fit("fit", copy, "--out", out, "--resume", "--max-evaluations", 28, *FAST), "silhouettes_hash")


def test_resume_without_a_checkpoint_and_bad_checkpoints(cap, tmp_path):
    out = tmp_path / "fit.json"
    ck = tmp_path / "fit.json.checkpoint.json"
    one_line_error(*fit("fit", cap.root, "--out", out, "--resume", *FAST), "no checkpoint")
    assert not out.exists()
    for text, needle in (
        ("{}", "format"),
        ("[1, 2]", "JSON object"),
        ("{not json", "corrupt"),
        ("\x00\xff", "corrupt"),
    ):
        ck.write_bytes(text.encode("latin-1"))
        one_line_error(*fit("fit", cap.root, "--out", out, "--resume", *FAST), needle)
        # and a rerun without --resume does not replace it
        one_line_error(*fit("fit", cap.root, "--out", out, *FAST), "--force")
        assert ck.read_bytes() == text.encode("latin-1")


def test_a_checkpoint_carrying_a_pickle_cannot_run_code(cap, tmp_path):
    out = tmp_path / "fit.json"
    ck = str(out) + ".checkpoint.json"
    assert fit("fit", cap.root, "--out", out, "--max-evaluations", 14, *FAST)[0] == 0
    marker = tmp_path / "pwned"

    class Boom:
        def __reduce__(self):
            return (open, (str(marker), "w"))

    d = json.load(open(ck))
    d["optimizer_state"]["pickle_b64"] = base64.b64encode(pickle.dumps(Boom())).decode()
    open(ck, "w").write(json.dumps(d))
    one_line_error(
        *fit("fit", cap.root, "--out", out, "--resume", "--max-evaluations", 28, *FAST), "pickle_b64", "unknown fields"
    )
    d["optimizer_state"].pop("pickle_b64")
    d["exec"] = "os.system('x')"
    open(ck, "w").write(json.dumps(d))
    one_line_error(*fit("fit", cap.root, "--out", out, "--resume", "--max-evaluations", 28, *FAST), "exec")
    assert not marker.exists()


@pytest.mark.parametrize(
    "mutate, needle",
    [
        (lambda d: d["optimizer_state"].__setitem__("C", [[1, 0, 0], [0, -1, 0], [0, 0, 1]]), "positive-definite"),
        (lambda d: d["optimizer_state"].__setitem__("mean", [float("nan")] * 3), "non-finite"),
        (lambda d: d["optimizer_state"].__setitem__("evaluations", "lots"), "evaluations"),
        (lambda d: d.__setitem__("elapsed", -1), "elapsed"),
        (lambda d: d.__setitem__("stop_reason", "because"), "stop_reason"),
        (lambda d: d.__setitem__("config", {"seed": "x"}), "seed"),
        (lambda d: d.__setitem__("identity", None), "identity"),
        (lambda d: d["optimizer_state"]["space"]["bounds"].__setitem__("k_over_m", [1.0, 2.0]), "does not match"),
    ],
)
def test_tampered_checkpoints_are_one_line_errors(cap, tmp_path, mutate, needle):
    out = tmp_path / "fit.json"
    ck = str(out) + ".checkpoint.json"
    assert fit("fit", cap.root, "--out", out, "--max-evaluations", 14, *FAST)[0] == 0
    d = json.load(open(ck))
    mutate(d)
    open(ck, "w").write(json.dumps(d))
    one_line_error(*fit("fit", cap.root, "--out", out, "--resume", "--max-evaluations", 28, *FAST), needle)


def test_checkpoint_size_does_not_grow_with_generations(cap, tmp_path):
    sizes = []
    for n in (70, 700):
        ck = tmp_path / f"c{n}.json"
        job = FitJob(
            cap,
            FitConfig(train_cameras=[0], train_times=[0.1], seed=0, max_evaluations=n, restarts=0),
            checkpoint=str(ck),
        )
        job.opt.tolx = job.opt.tolfun = 0.0  # keep it running
        job.run()
        assert job.evaluations >= n
        sizes.append(ck.stat().st_size)
    assert sizes[1] < 2 * sizes[0], sizes  # 10x the generations, not 10x the bytes


# ------------------------------------------------------------------ safe writers


def test_writers_never_follow_planted_symlinks(cap, tmp_path):
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    out = tmp_path / "fit.json"
    ck = str(out) + ".checkpoint.json"
    for planted in (ck + ".tmp", str(out) + ".tmp", ck + ".lock"):
        os.symlink(victim, planted)
    rc, so, err = fit("fit", cap.root, "--out", out, "--max-evaluations", 7, *FAST)
    # the lock file is opened with O_NOFOLLOW: a planted symlink there is an error, never followed
    one_line_error(rc, so, err, "lock")
    os.unlink(ck + ".lock")
    assert fit("fit", cap.root, "--out", out, "--max-evaluations", 7, *FAST)[0] == 0
    assert victim.read_text() == "precious"
    # a symlink at the destination itself is replaced, its target untouched
    os.symlink(victim, tmp_path / "link.json")
    jsonio.write_json(tmp_path / "link.json", {"a": 1})
    assert victim.read_text() == "precious" and not os.path.islink(tmp_path / "link.json")
    assert json.loads((tmp_path / "link.json").read_text()) == {"a": 1}


def test_two_fits_to_the_same_out_do_not_share_files(cap, tmp_path):
    out = tmp_path / "fit.json"
    ck = str(out) + ".checkpoint.json"
    with safeio.exclusive_lock(ck):
        one_line_error(*fit("fit", cap.root, "--out", out, "--max-evaluations", 7, *FAST), "another fit")
        with pytest.raises(ClothFitError, match="another"):
            with safeio.exclusive_lock(ck):
                pass
    assert not out.exists()
    assert fit("fit", cap.root, "--out", out, "--max-evaluations", 7, *FAST)[0] == 0
    # writers use unique temporary names: none is left behind, nor the fit's lock file
    assert not [p for p in os.listdir(tmp_path) if p.endswith(".tmp")]
    assert not os.path.lexists(ck + ".lock")


def test_the_lock_file_goes_when_its_holder_ends_by_an_error_too(tmp_path):
    ck = str(tmp_path / "fit.json.checkpoint.json")
    with pytest.raises(KeyboardInterrupt):
        with safeio.exclusive_lock(ck):
            assert os.path.isfile(ck + ".lock")
            raise KeyboardInterrupt
    assert not os.path.lexists(ck + ".lock")
    with safeio.exclusive_lock(ck):  # and it can be taken again
        pass
    assert os.listdir(tmp_path) == []


def test_a_locker_whose_lock_file_was_removed_before_its_flock_locks_the_file_on_disk(tmp_path, monkeypatch):
    """The race of removing lock files: a second fit opens the lock file, the first fit removes it and
    ends, the second locks the removed file. It must lock the file on disk instead, so that a third fit
    is still refused while the second runs."""
    import fcntl

    ck = str(tmp_path / "fit.json.checkpoint.json")
    real = fcntl.flock
    calls = []

    def holder_leaves_first(fd, op):
        if not calls:  # the first holder removes the file this locker opened, then lets go
            os.unlink(ck + ".lock")
        calls.append(fd)
        return real(fd, op)

    monkeypatch.setattr(fcntl, "flock", holder_leaves_first)
    with safeio.exclusive_lock(ck):
        monkeypatch.setattr(fcntl, "flock", real)
        assert len(calls) == 2 and os.path.isfile(ck + ".lock")
        with pytest.raises(ClothFitError, match="another fit"):
            with safeio.exclusive_lock(ck):
                pass
    assert not os.path.lexists(ck + ".lock")


def test_outputs_never_replace_inputs(cap, tmp_path):
    one_line_error(*fit("fit", cap.root, "--out", os.path.join(cap.root, "capture.json"), *FAST), "capture.json")
    one_line_error(*fit("fit", cap.root, "--out", tmp_path, *FAST), "directory")
    (tmp_path / "file").write_text("x")
    one_line_error(*fit("fit", cap.root, "--out", tmp_path / "file" / "fit.json", *FAST), "cannot")


def test_bad_true_params_do_not_lose_the_result(cap, tmp_path):
    copy = tmp_path / "cap"
    shutil.copytree(cap.root, copy)
    for bad in ("k=10", {"m": 0.01, "k": 0, "l": 0.006, "d": 1e-4}, {"m": "x"}):
        cj = json.loads((copy / "capture.json").read_text())
        cj["meta"]["true_params"] = bad
        (copy / "capture.json").write_text(json.dumps(cj))
        out = tmp_path / "fit.json"
        rc, so, err = fit("fit", copy, "--out", out, "--max-evaluations", 14, "--force", *FAST)
        assert rc == 0, err
        r = json.loads(out.read_text())
        assert r["params"] is not None and "true_params_ignored" in r
        assert read_checkpoint(str(out) + ".checkpoint.json")["result"]["params"] == r["params"]


# ------------------------------------------------------------------ bad inputs: one line each


def _capture_with(cap, tmp_path, edit_capture=None, edit_cameras=None, raw_cameras=None):
    copy = tmp_path / "cap"
    shutil.copytree(cap.root, copy)
    if edit_capture:
        cj = json.loads((copy / "capture.json").read_text())
        edit_capture(cj)
        (copy / "capture.json").write_text(json.dumps(cj))
    if edit_cameras:
        cj = json.loads((copy / "cameras.json").read_text())
        edit_cameras(cj)
        text = json.dumps(cj)
        for k, v in (raw_cameras or {}).items():
            text = text.replace(k, v)
        (copy / "cameras.json").write_text(text)
    return copy


def _scen(key, value):
    return lambda d: d["scenario"].__setitem__(key, value)


def _cloth(**kw):
    return lambda d: d["scenario"]["cloth"].update(kw)


def _cam0(key, value):
    return lambda d: d["cameras"][0].__setitem__(key, value)


BAD_CAPTURES = {
    "settle_time NaN": (_scen("settle_time", float("nan")), None, "settle_time"),
    "settle_time 1e9": (_scen("settle_time", 1e9), None, "settle_time"),
    "gravity NaN": (_scen("gravity", [0.0, 0.0, float("nan")]), None, "gravity"),
    "height NaN": (_cloth(height=float("nan")), None, "height"),
    "side infinite": (_cloth(side=float("inf"), side_y=float("inf")), None, "side"),
    "grid 100000": (_cloth(nx=100000, ny=100000), None, "too large"),
    "release NaN": (
        lambda d: d["scenario"]["handles"][0].__setitem__("release_time", float("nan")),
        None,
        "release_time",
    ),
    "pattern width": (lambda d: d.__setitem__("silhouettes", "sil/{camera}/{frame:0100000000d}.png"), None, "width"),
    "width abc": (None, _cam0("width", "abc"), "width"),
    "width null": (None, _cam0("width", None), "width"),
    "width 1e400": (None, _cam0("width", 987654321), "width"),
    "width 0.5": (None, _cam0("width", 0.5), "width"),
    "name ../esc": (None, _cam0("name", "../esc"), "../esc"),
    "name a/b": (None, _cam0("name", "a/b"), "a/b"),
}


@pytest.mark.parametrize("case", sorted(BAD_CAPTURES))
def test_bad_capture_values_are_one_line_errors(cap, tmp_path, case):
    ecap, ecam, needle = BAD_CAPTURES[case]
    raw = {"987654321": "1e400"} if case == "width 1e400" else None
    copy = _capture_with(cap, tmp_path, ecap, ecam, raw)
    out = tmp_path / "fit.json"
    one_line_error(*fit("fit", copy, "--out", out, "--max-evaluations", 7, *FAST), needle)
    assert not out.exists()


@pytest.mark.parametrize(
    "args, needle",
    [
        (("--max-evaluations", 0), "max_evaluations"),
        (("--max-evaluations", -5), "max_evaluations"),
        (("--children", 0, "--optimizer", "spx-mgg"), "children"),
        (("--population", 0), "population"),
        (("--population", 1), "population"),
        (("--restarts", -1), "restarts"),
        (("--resolution", "100000x100000"), "100000x100000"),
        (("--resolution", "0x40"), "positive"),
        (("--target", "nan"), "target_error"),
        (("--cloth-mass", "inf"), "cloth_mass"),
    ],
)  # --resume with --force: a usage error, exit code 64 (test_cli_habits.py)
def test_bad_fit_options_are_one_line_errors(cap, tmp_path, args, needle):
    out = tmp_path / "fit.json"
    one_line_error(*fit("fit", cap.root, "--out", out, *FAST, *args), needle)
    assert not out.exists()


def test_synth_truth_dt_safety_zero(tmp_path):
    for v in ("0", "-1", "nan"):
        one_line_error(*fit("synth", "--out", tmp_path / "c", "--truth-dt-safety", v), "truth_dt_safety")
    assert not (tmp_path / "c" / "capture.json").exists()


def test_unexpected_exceptions_are_one_line_too(monkeypatch, tmp_path):
    import clothfit.cli as mod
    import clothfit.cli.studies as studies

    def boom(a):
        raise RuntimeError("disk on fire\nsecond line")

    monkeypatch.setattr(studies, "cmd_rig", boom)
    monkeypatch.delenv(mod.DEBUG_ENV, raising=False)
    line = one_line_error(*fit("rig"), "RuntimeError", "disk on fire", mod.DEBUG_ENV, code=1)
    assert "second line" in line  # folded onto the one line
    monkeypatch.setenv(mod.DEBUG_ENV, "1")
    with pytest.raises(RuntimeError):
        fit("rig")


# ------------------------------------------------------------------ extract, calibration names


def _footage(tmp_path, names=("cam00", "cam01"), dist=None):
    from test_extract import write_footage

    root = str(tmp_path / "footage")
    write_footage(root, n_cams=len(names))
    from clothfit.core.footage.calib_io import import_cameras

    cams = import_cameras(os.path.join(root, "cameras.yml"))
    for c, n in zip(cams, names):
        if n != c.name and os.path.isdir(os.path.join(root, c.name)):
            os.rename(os.path.join(root, c.name), os.path.join(root, os.path.basename(n) or "x"))
        c.name = n
        if dist is not None:
            c.dist = np.array(dist)
    return root, cams


def test_extract_into_its_footage_keeps_the_calibration(tmp_path):
    from clothfit.core.footage import extract as X
    from clothfit.core.footage.calib_io import export_cameras

    root, cams = _footage(tmp_path, dist=[-0.2, 0.05, 0.0, 0.0, 0.0])
    export_cameras(cams, os.path.join(root, "cameras.json"))
    js = json.load(open(os.path.join(root, "footage.json")))
    js["cameras"] = "cameras.json"
    json.dump(js, open(os.path.join(root, "footage.json"), "w"))
    before = open(os.path.join(root, "cameras.json")).read()
    with pytest.raises(ClothFitError, match="overwrite its input"):
        X.extract_capture(root, root, undistort=True)
    assert open(os.path.join(root, "cameras.json")).read() == before
    assert not os.path.exists(os.path.join(root, "capture.json"))
    X.extract_capture(root, str(tmp_path / "cap"), undistort=True)  # elsewhere: fine


@pytest.mark.parametrize("bad", ["../esc", "a/b", "..", "x\\..\\y"])
def test_calibration_camera_names_are_checked_before_anything_is_written(tmp_path, bad):
    from clothfit.core.footage import extract as X
    from clothfit.core.footage.calib_io import export_cameras, import_cameras

    root, cams = _footage(tmp_path)
    cams[1].name = bad
    export_cameras(cams, os.path.join(root, "cameras.yml"))  # OpenCV YAML carries the name
    with pytest.raises(ClothFitError) as e:
        import_cameras(os.path.join(root, "cameras.yml"))
    assert "\n" not in str(e.value)
    dbg = tmp_path / "dbg"
    with pytest.raises(ClothFitError):
        X.extract_capture(root, str(tmp_path / "cap"), debug_dir=str(dbg))
    assert not dbg.exists() and not (tmp_path / "esc").exists()
    with pytest.raises(ClothFitError):  # a list of cameras given directly is checked as well
        X.extract_capture(root, str(tmp_path / "cap"), cameras=cams, debug_dir=str(dbg))
    assert not dbg.exists()


# ------------------------------------------------------------------ kill -9


def test_kill_9_at_random_moments_leaves_a_resumable_checkpoint(cap, tmp_path):
    """A fit killed (SIGKILL) at random moments, resumed each time: the checkpoint always loads and the
    resumed run ends with the uninterrupted run's result."""
    args = [
        "fit",
        cap.root,
        "--cameras",
        "0,2,4",
        "--times",
        "0.1,0.3,0.6",
        "--max-evaluations",
        1200,
        "--optimizer",
        "spx-mgg",
        "--seed",
        2,
        "--quiet",
    ]
    ref_out = tmp_path / "ref.json"
    env = dict(os.environ, PYTHONPATH=ROOT)
    t0 = time.monotonic()  # the whole run in a process of its own: start-up included
    r0 = subprocess.run(
        [sys.executable, "-m", "clothfit", *map(str, args), "--out", str(ref_out)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
    )
    whole = time.monotonic() - t0
    assert r0.returncode == 0, r0.stderr
    ref = json.loads(ref_out.read_text())
    out = tmp_path / "fit.json"
    ck = str(out) + ".checkpoint.json"
    rnd = random.Random(12)
    killed = resumed = 0
    for attempt in range(10):
        if attempt >= 4 and killed and resumed:
            break
        cmd = [sys.executable, "-m", "clothfit", *map(str, args), "--out", str(out)]
        if os.path.exists(ck):
            read_checkpoint(ck)  # loadable whenever it exists
            cmd.append("--resume")
            resumed += 1
        p = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        # a random moment inside the run (however fast this machine is, and however its load changes):
        # the first attempt is killed once its first checkpoint is on disk, a random moment after that
        if not killed:
            while p.poll() is None and not os.path.exists(ck):
                time.sleep(0.02)
            time.sleep(rnd.uniform(0.0, 0.2) * whole)
        else:
            time.sleep(rnd.uniform(0.2, 1.0) * whole)
        if p.poll() is None:
            p.send_signal(signal.SIGKILL)
            killed += 1
        p.wait()
        if p.returncode == 0:  # this attempt ran to its end before its moment came: the output is written
            break
    if not out.exists():
        cmd = [sys.executable, "-m", "clothfit", *map(str, args), "--out", str(out)]
        if os.path.exists(ck):
            cmd.append("--resume")
        done = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True)
        assert done.returncode == 0, done.stderr
    r = json.loads(out.read_text())
    assert r["evaluations"] == ref["evaluations"] and r["params"] == ref["params"]
    assert r["stop_reason"] == ref["stop_reason"]
    assert killed >= 1 and resumed >= 1, (killed, resumed)


# ------------------------------------------------------------------ fuzz: every input loads or is one ClothFitError

JUNK = [
    None,
    True,
    0,
    -1,
    1e400,
    float("nan"),
    -1e308,
    2**70,
    "",
    "abc",
    "../x",
    [],
    [1],
    [[1, 2], [3]],
    {},
    {"a": 1},
    0.5,
    100000,
]


def _paths(node, prefix=()):
    yield prefix
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _paths(v, prefix + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node[:4]):
            yield from _paths(v, prefix + (i,))


def _mutated(doc, rnd):
    d = json.loads(json.dumps(doc))
    path = rnd.choice([p for p in _paths(d) if p])
    node = d
    for k in path[:-1]:
        node = node[k]
    if rnd.random() < 0.15 and isinstance(node, dict):
        node.pop(path[-1])
    else:
        node[path[-1]] = rnd.choice(JUNK)
    return d, path


@pytest.mark.parametrize("which", ["capture.json", "cameras.json"])
def test_fuzzed_capture_files_load_or_fail_in_one_line(cap, tmp_path, which):
    from clothfit.core.observation.capture import load_capture

    copy = tmp_path / "cap"
    shutil.copytree(cap.root, copy)
    doc = json.loads((copy / which).read_text())
    rnd = random.Random(which)
    for _ in range(150):
        d, path = _mutated(doc, rnd)
        (copy / which).write_text(json.dumps(d))
        try:
            c = load_capture(str(copy))
            FitJob(c, FitConfig(train_cameras=[0], train_times=[0.1], max_evaluations=7))
        except ClothFitError as e:
            assert "\n" not in str(e), (path, str(e))
        except Exception as e:  # noqa: BLE001
            pytest.fail(f"{which} {path}: {type(e).__name__}: {e}")
    (copy / which).write_text(json.dumps(doc))


def test_fuzzed_checkpoints_resume_or_fail_in_one_line(cap, tmp_path):
    out = tmp_path / "fit.json"
    ck = str(out) + ".checkpoint.json"
    assert (
        fit("fit", cap.root, "--out", out, "--max-evaluations", 14, "--cameras", "0", "--times", "0.1", "--quiet")[0]
        == 0
    )
    doc = json.load(open(ck))
    rnd = random.Random(5)
    for _ in range(300):
        d, path = _mutated(doc, rnd)
        open(ck, "w").write(json.dumps(d))
        try:
            job = FitJob.resume(ck, capture=cap)
            job.step()
        except ClothFitError as e:
            assert "\n" not in str(e), (path, str(e))
        except Exception as e:  # noqa: BLE001
            pytest.fail(f"checkpoint {path}: {type(e).__name__}: {e}")
