import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

"""The headless CLI ``python -m clothfit`` (the ``clothfit`` console script) in a subprocess: synth, fit,
evaluate, overlay with their JSON on stdout, and one-line errors (exit code 2, no traceback) for bad input.
The CLI's habits (help on every option, --version, exit codes 64 and 130, the console script) are in
test_cli_habits.py."""

import json
import shutil
import subprocess

import cv2
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def run(*args, timeout=300, env_extra=None):
    env = dict(os.environ)
    env.pop("CLOTHFIT_PROGRESS", None)
    env.update(env_extra or {})
    p = subprocess.run(
        [sys.executable, "-m", "clothfit", *[str(a) for a in args]],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    return p.returncode, p.stdout, p.stderr


def assert_one_line_error(rc, out, err, *needles):
    assert rc == 2, (rc, out, err)
    assert "Traceback" not in err, err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith("error: "), err
    for n in needles:
        assert str(n) in lines[0], (n, err)


@pytest.fixture(scope="module")
def cap(tmp_path_factory):
    root = tmp_path_factory.mktemp("cli") / "cap"
    rc, out, err = run("synth", "--out", root, "--resolution", "60x80")
    assert rc == 0, err
    assert "18 cameras x 30 frames" in err
    r = json.loads(out)
    assert len(r["cameras"]) == 18 and len(r["frame_times"]) == 30 and r["resolution"] == [60, 80]
    return root


def test_synth_writes_a_capture(cap):
    from clothfit.core.observation.capture import load_capture

    c = load_capture(str(cap), validate=True)  # every silhouette file readable, sizes right
    assert c.n_cameras == 18 and c.n_frames == 30
    assert all((k.height, k.width) == (60, 80) for k in c.cameras)
    assert c.shapes is not None and c.shapes.shape == (30, 256, 3)
    assert c.meta["true_params"]["k"] == 10.0


@pytest.fixture(scope="module")
def fit_json(cap):
    out = cap.parent / "fit.json"
    rc, so, err = run(
        "fit",
        cap,
        "--out",
        out,
        "--max-evaluations",
        60,
        "--cameras",
        "n:2",
        "--times",
        "0.1,0.2,0.3",
        "--optimizer",
        "cma-es",
        "--quiet",
    )
    assert rc == 0, err
    assert "Traceback" not in err
    assert f"wrote {out}" in err
    summary = json.loads(so)  # stdout: only the summary, as JSON
    assert summary["out"] == str(out) and summary["cancelled"] is False
    assert summary["evaluations"] >= 60 and set(summary["params"]) == {"m", "k", "l", "d"}
    with open(out) as f:
        assert json.load(f)["params"] == summary["params"]
    return out


def _progress_lines(err, budget):
    """The progress lines of a fit's stderr: (evaluations, {setting: value}) each."""
    import re

    got = []
    for line in err.replace("\r", "\n").splitlines():
        m = re.search(rf"(\d+)/{budget} evaluations, E_sil [\d.]+ %, .+ spent, .+ left: (.+)$", line)
        if m:
            words = m.group(2).split()
            pairs = [(n, v) for n, v in zip(words[::2], words[1::2]) if re.fullmatch(r"-?[\d.]+(e[-+]\d+)?", v)]
            got.append((int(m.group(1)), {n: float(v) for n, v in pairs}))  # (a bar's line may be cut)
    return got


@pytest.mark.parametrize("model", ["paper", "blender"])
def test_a_fit_shows_its_progress_with_the_fitted_models_own_settings(cap, tmp_path, model):
    """Where stderr is no terminal, a plain line at least every CLOTHFIT_PROGRESS_INTERVAL seconds (here
    0: every generation); on a terminal (CLOTHFIT_PROGRESS=1 stands for one) a bar. Both name the settings
    the fit searches, of the model it fits, and end at the budget."""
    budget = 16
    args = ["fit", cap, "--model", model, "--cameras", "n:2", "--times", "0.1,0.3", "--max-evaluations", budget]
    rc, so, err = run(*args, "--out", tmp_path / "lines.json", env_extra={"CLOTHFIT_PROGRESS_INTERVAL": "0"})
    assert rc == 0, err
    r = json.loads((tmp_path / "lines.json").read_text())
    names = {"k", "l", "d"} if model == "paper" else {n.replace("_stiffness", "") for n in r["free"]}
    lines = _progress_lines(err, budget)
    assert not [ln for ln in err.splitlines() if ln.startswith("[")] and len(lines) >= 2, err
    assert all(set(s) == names for _, s in lines), (names, err)
    assert [n for n, _ in lines] == sorted(n for n, _ in lines) and lines[-1][0] == r["evaluations"] <= budget
    if model == "blender":
        assert {"tension", "shear", "bending"} <= names
    rc, so, err = run(*args, "--out", tmp_path / "bar.json", env_extra={"CLOTHFIT_PROGRESS": "1"})
    assert rc == 0, err
    bars = [ln for ln in err.splitlines() if ln.startswith("[") and "evaluations" in ln]  # (text mode reads \\r as \\n)
    assert (
        bars and bars[-1].startswith("[" + "#" * 12 + "]") and _progress_lines(err, budget)[-1][0] == r["evaluations"]
    )
    first = "k" if model == "paper" else r["free"][0].replace("_stiffness", "")
    assert f"left: {first} " in bars[-1], err  # the settings by name, cut to the terminal's line
    rc, so, err = run(*args, "--out", tmp_path / "quiet.json", "--quiet", env_extra={"CLOTHFIT_PROGRESS_INTERVAL": "0"})
    assert rc == 0 and not _progress_lines(err, budget), err


def test_fit_writes_a_result_with_params(fit_json, cap):
    with open(fit_json) as f:
        r = json.load(f)
    p = r["params"]
    assert set(p) == {"m", "k", "l", "d"} and all(v > 0 for v in p.values())
    assert r["evaluations"] >= 60 and r["optimizer"] == "cma-es"
    assert r["train_times"] == [0.1, 0.2, 0.3]
    assert len(r["train_camera_indices"]) == 2
    assert r["n_train_images"] == 6
    assert r["identifiable"]["k_over_m"] == pytest.approx(p["k"] / p["m"])
    assert r["best_E_sil_mean_pct"] is not None and r["best_E_sil_mean_pct"] < 50
    assert "identifiable_error_pct" in r
    assert os.path.isfile(str(fit_json) + ".checkpoint.json")


def test_evaluate_prints_a_silhouette_error(fit_json, cap, tmp_path):
    js = tmp_path / "ev.json"
    rc, out, err = run(
        "evaluate", cap, "--params", fit_json, "--cameras", "heldout:2", "--times", "0.15,0.25", "--json", js
    )
    assert rc == 0, err
    assert "silhouette error" in err and "16 cameras x 2 frames" in err and "shape error" in err
    with open(js) as f:
        r = json.load(f)
    assert json.loads(out) == r  # stdout: the same result as --json
    assert len(r["cameras"]) == 16 and r["times"] == [0.15, 0.25]
    assert r["silhouette_error_pct"] > 0
    # the ground truth (default --params) scores better than a wrong k
    rc, out_gt, _ = run("evaluate", cap, "--cameras", "0,5", "--times", "0.5", "--json", tmp_path / "gt.json")
    rc2, _, _ = run(
        "evaluate",
        cap,
        "--cameras",
        "0,5",
        "--times",
        "0.5",
        "--params",
        '{"m": 1e-5, "k": 14.0, "l": 0.0066667, "d": 5e-5}',
        "--json",
        tmp_path / "bad.json",
    )
    assert rc == rc2 == 0
    with open(tmp_path / "gt.json") as f, open(tmp_path / "bad.json") as g:
        assert json.load(f)["silhouette_error_pct"] < json.load(g)["silhouette_error_pct"]


def test_overlay_writes_images(fit_json, cap, tmp_path):
    out = tmp_path / "ov"
    rc, so, err = run("overlay", cap, "--params", fit_json, "--out", out, "--cameras", "cam00,3", "--times", "0.1,0.2")
    assert rc == 0, err
    assert "wrote 5 images" in err
    r = json.loads(so)
    assert len(r["images"]) == 4 and r["contact_sheet"] == str(out / "contact_sheet.png")
    for cam in ("cam00", "cam03"):
        for f in ("001", "003"):
            img = cv2.imread(str(out / cam / f"{f}.png"))
            assert img is not None and img.shape == (60, 80, 3)
    assert cv2.imread(str(out / "contact_sheet.png")) is not None


# ------------------------------------------------------------------ bad input


def test_missing_capture_dir(tmp_path):
    missing = tmp_path / "no_such_capture"
    rc, out, err = run("fit", missing, "--out", tmp_path / "f.json", "--quiet")
    assert_one_line_error(rc, out, err, missing)
    rc, out, err = run("evaluate", missing)
    assert_one_line_error(rc, out, err, missing)


def test_corrupt_capture_json(cap, tmp_path):
    bad = tmp_path / "bad"
    shutil.copytree(cap, bad)
    (bad / "capture.json").write_text('{"format": "silhouette-cloth-fit/capture", "version": ')
    rc, out, err = run("fit", bad, "--out", tmp_path / "f.json", "--quiet")
    assert_one_line_error(rc, out, err, bad / "capture.json", "invalid JSON")
    rc, out, err = run("overlay", bad, "--out", tmp_path / "ov")
    assert_one_line_error(rc, out, err, bad / "capture.json")


def test_bad_resolution(cap, tmp_path):
    rc, out, err = run("synth", "--out", tmp_path / "s", "--resolution", "60by80")
    assert_one_line_error(rc, out, err, "60by80")
    assert not (tmp_path / "s" / "capture.json").exists()
    rc, out, err = run("fit", cap, "--out", tmp_path / "f.json", "--resolution", "12", "--max-evaluations", 5)
    assert_one_line_error(rc, out, err, "'12'")


def test_unknown_optimizer(cap, tmp_path):
    rc, out, err = run(
        "fit",
        cap,
        "--out",
        tmp_path / "f.json",
        "--optimizer",
        "simplex",
        "--max-evaluations",
        5,
        "--cameras",
        "0",
        "--times",
        "0.1",
    )
    assert_one_line_error(rc, out, err, "simplex")


def test_bad_values_named(cap, tmp_path):
    rc, out, err = run("evaluate", cap, "--times", "0.12")
    assert_one_line_error(rc, out, err, "0.12")
    rc, out, err = run("evaluate", cap, "--params", '{"m": 1e-5, "k": -3, "l": 0.0066, "d": 0}')
    assert_one_line_error(rc, out, err, "k=-3")
    rc, out, err = run("evaluate", cap, "--cameras", "camXX")
    assert_one_line_error(rc, out, err, "camXX")
    rc, out, err = run("fit", cap, "--out", tmp_path / "f.json", "--cameras", "n:40", "--quiet")
    assert_one_line_error(rc, out, err, "40")


def test_corrupt_params_file(cap, tmp_path):
    p = tmp_path / "params.json"
    p.write_text('{"m": 1e-5, "k": ')
    rc, out, err = run("evaluate", cap, "--params", p)
    assert_one_line_error(rc, out, err, p)


@pytest.mark.parametrize("opt,value", [("--times", "0.1,abc"), ("--cameras", "n:x")])
def test_non_numeric_times_or_camera_count(cap, opt, value):
    rc, out, err = run("evaluate", cap, opt, value)
    assert_one_line_error(rc, out, err, value.split(",")[-1].split(":")[-1])


def test_camera_index_out_of_range(cap):
    rc, out, err = run("evaluate", cap, "--cameras", "99")
    assert_one_line_error(rc, out, err, "99")


def test_max_evaluations_zero_is_refused_by_fit_and_fit_many(cap, tmp_path):
    """``fit`` and ``fit-many`` build their FitConfig with one function (cli/fitting.fit_config): a budget
    given is the budget, so ``--max-evaluations 0`` is bad data in both (fit-many used to read 0 as
    the default budget), refused before any work starts and before anything is written."""
    for args in (
        ("fit", cap, "--out", tmp_path / "f.json"),
        ("fit-many", cap, "--out-dir", tmp_path / "many", "--executor", "process"),
    ):
        rc, out, err = run(*args, "--max-evaluations", 0)
        assert_one_line_error(rc, out, err, "max_evaluations", "got 0")
    assert not (tmp_path / "f.json").exists() and not (tmp_path / "many").exists()


def test_fit_config_is_shared_and_reads_only_what_the_command_declares(cap):
    from argparse import Namespace

    from clothfit.cli.fitting import fit_config
    from clothfit.core import defaults as D
    from clothfit.core.observation.capture import load_capture

    c = load_capture(str(cap))
    base = dict(
        cameras="0,1",
        times="0.1,0.2",
        optimizer="cma-es",
        seed=3,
        max_evaluations=None,
        resolution="30x40",
        cloth_mass=None,
        population=None,
        quality=None,
        uncertain=None,
        model=None,
        fps=None,
        bending_model=None,
    )
    many = fit_config(Namespace(**base), c).checked()  # fit-many's options only
    assert many.max_evaluations == D.FIT_EVALUATIONS and many.train_cameras == [0, 1]
    assert many.train_times == [0.1, 0.2] and many.resolution == [30, 40] and many.seed == 3
    one = fit_config(
        Namespace(
            **base, backend="auto", children=4, target=0.01, free=None, fixed=None, init=None, bounds=None, restarts=2
        ),
        c,
    ).checked()
    assert (one.children, one.target_error, one.restarts) == (4, 0.01, 2)
    assert {k: v for k, v in vars(one).items() if k not in ("children", "target_error", "restarts")} == {
        k: v for k, v in vars(many).items() if k not in ("children", "target_error", "restarts")
    }


def test_search_options_reach_fitconfig():
    """``--search NAME=VALUE`` (fit, fit-many): an optimiser setting of FitConfig from the command line,
    e.g. active CMA, which our A/B found better; a bad name or value is a one-line error."""
    from clothfit.cli import build_parser
    from clothfit.cli.fitting import search_options
    from clothfit.core.errors import ClothFitError
    from clothfit.core.fitting.job import FitConfig

    for cmd in (["fit", "cap", "--out", "f.json"], ["fit-many", "cap"]):
        a = build_parser().parse_args(cmd + ["--search", "cma_active=true", "--search", "sigma0=0.2"])
        assert a.search == ["cma_active=true", "sigma0=0.2"]
    opts = search_options(["cma_active=true", "sigma0=0.2", "ga_stall=300"])
    assert opts == {"cma_active": True, "sigma0": 0.2, "ga_stall": 300}
    cfg = FitConfig(optimizer="cma-es", **search_options(["cma_active=on"])).checked()
    assert cfg.cma_active is True
    for bad in ("cma_activ=true", "sigma0", "sigma0=big"):
        with pytest.raises(ClothFitError, match="--search"):
            search_options([bad])
