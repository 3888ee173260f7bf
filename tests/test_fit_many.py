"""``fit-many``: independent fits on the same workers (a local 2-worker Ray on 127.0.0.1, or the
spawned process pool without Ray) give exactly the results of local fits with the same seeds.
The driver runs in a subprocess (the test process may have imported bpy)."""

import json
import os
import subprocess
import sys

import pytest
from clothfit.core.fitting.job import FitConfig, FitJob
from clothfit.core.observation.capture import load_capture
from clothfit.core.observation.synth import synth_capture

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TIMES = [0.2, 0.4]


@pytest.fixture(scope="module")
def caps(tmp_path_factory):
    d = tmp_path_factory.mktemp("many")
    return [
        synth_capture(str(d / f"c{s}"), rig="ring8", resolution=(60, 80), seed=s, noise=0.05 * s).root for s in (1, 2)
    ]


@pytest.mark.parametrize("env", [{}, {"CLOTHFIT_NO_RAY": "1"}], ids=["ray", "no-ray"])
def test_fit_many_equals_local_fits(caps, tmp_path, env):
    if not env:
        pytest.importorskip("ray")
    out = tmp_path / "fits"
    e = {k: v for k, v in os.environ.items() if not k.startswith("PYTEST")}
    e.update(env, CLOTHFIT_PROGRESS_INTERVAL="0")  # each fit's progress lines: here one per generation
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "clothfit",
            "fit-many",
            *caps,
            "--max-evaluations",
            "30",
            "--seed",
            "4",
            "--times",
            ",".join(map(str, TIMES)),
            "--workers",
            "2",
            "--out-dir",
            str(out),
        ],
        cwd=ROOT,
        env=e,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    assert f"2 fits on 2 {'process' if env else 'ray'} worker(s)" in r.stderr
    summary = json.loads(r.stdout)
    assert summary["workers"] == 2 and summary["executor"] == ("process" if env else "ray")
    if env:  # the spawned workers share the driver's stderr (Ray's forwarding of it is Ray's)
        for c in caps:
            shown = [ln for ln in r.stderr.splitlines() if ln.startswith(f"{c}: ") and "/30 evaluations, E_sil" in ln]
            assert shown and shown[-1].startswith(f"{c}: 30/30 evaluations") and "left: k " in shown[-1], r.stderr
    assert [f["out"] for f in summary["fits"]] == [
        str(out / f"{i:03d}_{os.path.basename(c)}.json") for i, c in enumerate(caps)
    ]
    for i, c in enumerate(caps):
        got = json.load(open(out / f"{i:03d}_{os.path.basename(c)}.json"))
        local = FitJob(load_capture(c), FitConfig(train_times=TIMES, max_evaluations=30, seed=4)).run()
        assert got["params"] == local["params"] and got["best_E_all"] == local["best_E_all"]
        assert got["evaluations"] == local["evaluations"]
        # each fit's one-line verdict, in the summary and on stderr
        assert summary["fits"][i]["verdict"] == got["verdict"] and f"  verdict: {got['verdict']}" in r.stderr


def test_fit_many_bad_capture_is_one_line(tmp_path):
    r = subprocess.run(
        [sys.executable, "-m", "clothfit", "fit-many", str(tmp_path / "nope")],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "not found" in r.stderr


def test_unreachable_cluster_address_is_one_line(caps):
    import socket

    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()  # nothing listens there now
    r = subprocess.run(
        [sys.executable, "-m", "clothfit", "fit-many", caps[0], "--address", f"127.0.0.1:{port}"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    err = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(err) == 1 and "cannot connect to the Ray cluster" in err[0], r.stderr


def test_paper_parts_on_workers_equal_the_local_protocol(tmp_path, capsys):
    """``paper --workers 2``: the parts run as tasks (here Ray, or the process pool without it), the
    numbers are the local run's."""
    from clothfit.core.studies.experiment import run_paper

    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "clothfit",
            "paper",
            "--quick",
            "--only",
            "table1,fig8",
            "--max-evaluations",
            "20",
            "--workers",
            "2",
            "--json",
            str(tmp_path / "par.json"),
            "--out",
            str(tmp_path / "par"),
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    assert "2 part(s) on 2" in r.stderr
    par = json.load(open(tmp_path / "par.json"))
    assert json.loads(r.stdout) == par  # stdout: the same document as --json
    loc = run_paper(
        str(tmp_path / "loc.json"), quick=True, out_dir=str(tmp_path / "loc"), only="table1,fig8", max_evaluations=20
    )
    capsys.readouterr()

    def strip(rows):
        return [{k: v for k, v in row.items() if "seconds" not in k} for row in rows]

    assert strip(par["table1"]) == strip(loc["table1"]) and strip(par["fig8"]) == strip(loc["fig8"])
    assert par["identifiable"] == loc["identifiable"]
