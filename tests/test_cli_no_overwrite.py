"""Nothing a user made is replaced without --force: every command that writes a file or folder the user
names refuses an existing one in one line naming it and saying --force overwrites (exit code 2, the
file untouched), and replaces it with --force. A fit's --resume of the same fit still continues."""

import json
import os

import pytest
from clothfit import cli
from clothfit.core.physics import blender as B

RIG = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "rigs", "ring8.json")
MINE = "a file the user made\n"


def main(capsys, *args):
    code = cli.main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def assert_refused(capsys, path, *args):
    """The command is refused in one line naming ``path`` and --force, and ``path`` is untouched."""
    before = _snapshot(path)
    code, out, err = main(capsys, *args)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == cli.EXIT_BAD_DATA, (code, err)
    assert len(lines) == 1 and lines[0].startswith("error: ") and str(path) in lines[0] and "--force" in lines[0], err
    assert out == ""
    assert _snapshot(path) == before


def _snapshot(path):
    if os.path.isdir(path):
        return {n: _snapshot(os.path.join(path, n)) for n in sorted(os.listdir(path))}
    with open(path, "rb") as f:
        return f.read()


def _mine(path):
    os.makedirs(os.path.dirname(path), exist_ok=True)
    with open(path, "w") as f:
        f.write(MINE)
    return path


@pytest.fixture(scope="module")
def cap(tmp_path_factory):
    root = tmp_path_factory.mktemp("no_overwrite") / "cap"
    assert cli.main(["synth", "--out", str(root), "--rig", RIG, "--resolution", "30x40"]) == 0
    return root


@pytest.fixture()
def blender_result(tmp_path):
    p = tmp_path / "fit.json"
    p.write_text(
        json.dumps(
            {
                "model": {"name": "blender", "fps": 24.0},
                "blender_cloth": B.check_settings({"tension_stiffness": 20.0}),
                "blender_scene": {"fps": 24.0},
            }
        )
    )
    return p


def test_synth_refuses_a_folder_that_holds_files_and_writes_over_it_with_force(capsys, cap, tmp_path):
    out = tmp_path / "cap"
    _mine(str(out / "notes.txt"))
    assert_refused(capsys, out, "synth", "--out", out, "--rig", RIG, "--resolution", "30x40")
    assert not (out / "capture.json").exists()
    before = (cap / "capture.json").read_bytes()
    assert_refused(capsys, cap, "synth", "--out", cap, "--rig", RIG, "--resolution", "30x40", "--noise", "0")
    assert (cap / "capture.json").read_bytes() == before
    code, _, err = main(capsys, "synth", "--out", out, "--rig", RIG, "--resolution", "30x40", "--force")
    assert code == 0, err
    assert (out / "capture.json").is_file() and (out / "notes.txt").read_text() == MINE


def test_fit_refuses_an_existing_result_and_replaces_it_with_force(capsys, cap, tmp_path):
    out = _mine(str(tmp_path / "fit.json"))
    fit = ("fit", cap, "--out", out, "--max-evaluations", 8, "--cameras", "n:1", "--times", "0.1", "--quiet")
    assert_refused(capsys, out, *fit)
    assert not os.path.lexists(out + ".checkpoint.json") and not os.path.lexists(out + ".checkpoint.json.lock")
    code, summary, err = main(capsys, *fit, "--force")
    assert code == 0, err
    with open(out) as f:
        assert json.load(f)["evaluations"] == json.loads(summary)["evaluations"] > 0
    # the fit's own result and checkpoint: another run is refused, --resume continues the same fit
    before = _snapshot(out)
    code, _, err = main(capsys, *fit)
    assert code == cli.EXIT_BAD_DATA and "--resume" in err and "--force" in err
    assert _snapshot(out) == before
    code, _, err = main(capsys, *fit[:5], 16, *fit[6:], "--resume")
    assert code == 0, err
    with open(out) as f:
        assert json.load(f)["evaluations"] >= 16


def test_fit_many_refuses_results_already_in_its_folder(capsys, cap, tmp_path):
    out = _mine(str(tmp_path / "fits" / f"000_{cap.name}.json"))
    assert_refused(capsys, out, "fit-many", cap, "--out-dir", tmp_path / "fits", "--max-evaluations", 8)


@pytest.mark.parametrize("command", ["evaluate", "floor"])
def test_json_of_evaluate_and_floor_is_not_replaced_without_force(capsys, cap, tmp_path, command):
    js = _mine(str(tmp_path / "scores.json"))
    args = (command, cap, "--cameras", "0", "--times", "0.1", "--json", js)
    assert_refused(capsys, js, *args)
    code, out, err = main(capsys, *args, "--force")
    assert code == 0, err
    with open(js) as f:
        assert json.load(f) == json.loads(out)


def test_overlay_refuses_a_folder_with_overlays_and_draws_over_them_with_force(capsys, cap, tmp_path):
    out = tmp_path / "overlays"
    args = ("overlay", cap, "--out", out, "--cameras", "0", "--times", "0.1")
    code, _, err = main(capsys, *args)
    assert code == 0, err
    sheet = out / "contact_sheet.png"
    assert sheet.is_file()
    assert_refused(capsys, out, *args)
    os.utime(sheet, (0, 0))
    code, _, err = main(capsys, *args, "--force")
    assert code == 0, err
    assert sheet.stat().st_mtime > 0


@pytest.mark.parametrize("option", ["--out", "--preset"])
def test_export_blender_cloth_refuses_an_existing_file_and_replaces_it_with_force(
    capsys, blender_result, tmp_path, option
):
    path = _mine(str(tmp_path / "cloth.py"))
    args = ("export-blender-cloth", blender_result, "--python", option, path)
    assert_refused(capsys, path, *args)
    code, out, err = main(capsys, *args, "--force")
    assert code == 0, err
    text = open(path).read()
    assert text.startswith(("import bpy", "#")) and "20.0" in text


def test_camera_commands_refuse_an_existing_file_and_replace_it_with_force(capsys, tmp_path):
    for command in ("import-cameras", "export-cameras"):
        path = _mine(str(tmp_path / f"{command}.json"))
        assert_refused(capsys, path, command, RIG, "--out", path)
        code, _, err = main(capsys, command, RIG, "--out", path, "--force")
        assert code == 0, err
        with open(path) as f:
            assert len(json.load(f)["cameras"]) == 8


def test_calibrate_board_is_not_replaced_without_force(capsys, tmp_path):
    board = ("calibrate", "--make-board", "--board", "5,4,0.04,0.03,DICT_4X4_50", "--out", tmp_path / "board")
    code, _, err = main(capsys, *board)
    assert code == 0, err
    png = tmp_path / "board.png"
    assert_refused(capsys, png, *board)
    assert main(capsys, *board, "--force")[0] == 0


@pytest.mark.parametrize(
    "args",
    [
        ("calibrate", "FOLDER", "--board", "5,4,0.04,0.03,DICT_4X4_50", "--out", "{path}"),
        ("handles", "FOLDER", "--marks", "marks.json", "--size", "0.3x0.4", "-o", "{path}"),
        ("paper", "--json", "{path}"),
        ("bench", "--json", "{path}"),
        ("identifiability", "--json", "{path}"),
        ("occlusion", "--json", "{path}"),
        ("blender-agreement", "--json", "{path}"),
    ],
    ids=lambda a: a[0],
)
def test_commands_writing_a_named_file_refuse_an_existing_one_before_any_work(capsys, tmp_path, args):
    path = _mine(str(tmp_path / "mine.json"))
    assert_refused(capsys, path, *[path if a == "{path}" else a for a in args])


def test_extract_refuses_a_capture_folder_that_holds_files(capsys, cap, tmp_path):
    out = tmp_path / "capture"
    _mine(str(out / "capture.json"))
    assert_refused(capsys, out, "extract", cap, "-o", out)
