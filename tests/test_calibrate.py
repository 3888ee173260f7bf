"""clothfit calibrate (footage/calibrate.py): ChArUco multi-camera calibration through the CLI.

The truth is made here, not by the code under test: the printed board traced exactly through known
OpenCV cameras (tests/calib_synth.py: every pixel's ray meets the board plane, 3x supersampled,
sensor noise), small images so the test runs in seconds. The photoreal measurement against the
phone rig's goals is ``lab/phone_rig.py calibrate`` (docs/figures/phone_rig_calib.json).
"""

import json
import os
import shutil
import sys

import numpy as np
import pytest

sys.path.insert(0, os.path.dirname(__file__))
import calib_synth as S  # noqa: E402
from clothfit.cli import main as cli  # noqa: E402
from clothfit.core.footage import calibrate as CB  # noqa: E402
from clothfit.core.observation.camera import load_cameras  # noqa: E402

BOARD = "9,7,0.04,0.03,DICT_5X5_100"


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """4 portrait phones 300 x 400 px, the board flat on the table (m000) then 16 poses held up."""
    board = CB.parse_board(BOARD)
    cams = S.phone_rig(4, 300, 400, seed=1)
    poses = S.wave_poses(board, cams, n=16, seed=1)
    root = str(tmp_path_factory.mktemp("calib") / "images")
    seen = S.write_dataset(root, board, cams, poses, seed=1)
    return {"board": board, "cams": cams, "poses": poses, "root": root, "seen": seen}


def _copy(dataset, tmp_path):
    dst = str(tmp_path / "images")
    shutil.copytree(dataset["root"], dst)
    return dst


def _one_line_error(capsys, argv, *needles, code=2):
    capsys.readouterr()
    assert cli(argv) == code
    err = capsys.readouterr().err.strip()
    line = err.splitlines()[-1]
    assert line.startswith("error: "), err
    assert "Traceback" not in err
    for n in needles:
        assert n in line, (n, line)
    return line


def test_calibrate_recovers_the_cameras(dataset, tmp_path, capsys):
    out = str(tmp_path / "cams.json")
    capsys.readouterr()
    assert cli(["calibrate", dataset["root"], "--board", BOARD, "--out", out, "--debug", str(tmp_path / "dbg")]) == 0
    rep = json.loads(capsys.readouterr().out)
    est = {c.name: c for c in load_cameras(out)}
    truth = S.cameras_in_world(dataset["cams"], dataset["board"], dataset["poses"][0])
    errs = S.errors(truth, [est[t.name] for t in truth])
    # Measured at 300 x 400 px, 7-9 views per camera, 1.5 grey levels of noise (seeds 0-2): focal
    # 0.43-0.76 %, centres 2.5-5.1 mm, rotations 0.37-0.77 deg, RMS 0.23-0.24 px. The tolerances are
    # about twice the worst; the phone rig's goals are measured on photoreal phone-sized renders.
    for name, e in errs.items():
        assert e["focal_pct"] < 1.5, (name, e)
        assert e["centre_mm"] < 10.0, (name, e)
        assert e["rotation_deg"] < 1.5, (name, e)
    assert rep["rms_px"] < 0.5
    for c in rep["cameras"]:
        assert c["rms_px"] < 0.5 and c["views_used"] >= 5
    # world frame: the flat board, Z up: every true camera is above the table, so is every estimate
    assert all(c.center[2] > 0.2 for c in est.values())
    assert len(os.listdir(str(tmp_path / "dbg"))) > 0


def test_make_board(tmp_path, capsys):
    capsys.readouterr()
    assert cli(["calibrate", "--make-board", "--board", BOARD, "--out", str(tmp_path / "board")]) == 0
    r = json.loads(capsys.readouterr().out)
    assert os.path.getsize(r["png"]) > 1000 and os.path.getsize(r["pdf"]) > 500
    import cv2

    img = cv2.imread(r["png"], cv2.IMREAD_GRAYSCALE)
    ids, pts, _, _ = CB.Detector(CB.parse_board(BOARD)).detect(img)
    assert ids.size == CB.parse_board(BOARD).n_corners  # the printed board is found whole


def test_bad_inputs(dataset, tmp_path, capsys):
    import cv2

    out = str(tmp_path / "cams.json")

    def args(folder, *extra):
        return ["calibrate", folder, "--board", BOARD, "--out", out, *extra]

    # unreadable media, named
    root = _copy(dataset, tmp_path / "a")
    with open(os.path.join(root, "phone1", "m003.png"), "wb") as f:
        f.write(b"not a png")
    _one_line_error(capsys, args(root), "m003.png")
    # no folder, no cameras
    _one_line_error(capsys, args(str(tmp_path / "nope")), "not found")
    os.makedirs(tmp_path / "empty")
    _one_line_error(capsys, args(str(tmp_path / "empty")), "no camera folders")
    # the board found nowhere: grey frames
    blank = tmp_path / "blank"
    for c in ("phone0", "phone1"):
        os.makedirs(blank / c)
        for k in range(3):
            cv2.imwrite(str(blank / c / f"m{k:03d}.png"), np.full((400, 300), 120, np.uint8))
    _one_line_error(capsys, args(str(blank)), "found in none of the 6 frames")
    # a board definition that does not match the print: another dictionary, another layout
    _one_line_error(
        capsys,
        ["calibrate", dataset["root"], "--board", "9,7,0.04,0.03,DICT_4X4_50", "--out", out],
        "DICT_5X5",
        "does not match",
    )
    _one_line_error(
        capsys, ["calibrate", dataset["root"], "--board", "5,4,0.04,0.03,DICT_5X5_100", "--out", out], "does not match"
    )
    # a camera that sees the board too rarely
    root = _copy(dataset, tmp_path / "b")
    files = sorted(os.listdir(os.path.join(root, "phone2")))
    for f in files[3:]:
        os.remove(os.path.join(root, "phone2", f))
    _one_line_error(capsys, args(root), "camera 'phone2'", "3 usable view(s)", "at least 5")
    # cameras not connected by shared views: {phone0, phone1} and {phone2, phone3} never see a moment together
    root = _copy(dataset, tmp_path / "c")
    first = set()
    for c in ("phone0", "phone1"):
        first |= {os.path.splitext(f)[0] for f in os.listdir(os.path.join(root, c))}
    for c in ("phone2", "phone3"):
        for f in os.listdir(os.path.join(root, c)):
            if os.path.splitext(f)[0] in first:
                os.remove(os.path.join(root, c, f))
    left = {c: len(os.listdir(os.path.join(root, c))) for c in ("phone2", "phone3")}
    assert min(left.values()) >= 3, left
    _one_line_error(capsys, args(root, "--min-views", "3"), "not connected by shared views", "phone0", "phone2")
    # the first moment (the world frame: the board flat on the table) not found: never silently another world
    root = _copy(dataset, tmp_path / "d")
    for c in os.listdir(root):
        p = os.path.join(root, c, "m000.png")
        if os.path.exists(p):
            cv2.imwrite(p, np.full((400, 300), 120, np.uint8))
    _one_line_error(capsys, args(root), "first moment m000", "--world")
    # nothing half-written
    assert not os.path.exists(out)
    # a bad --board text
    _one_line_error(capsys, ["calibrate", dataset["root"], "--board", "9,7,0.04", "--out", out], "--board")
