"""clothfit handles: the manipulation measured from footage (footage/handles.py), the placed cloth grid
(scenario.ClothGrid origin/rotation) and the capture's uncertain block written by extract.

The truths are made here, not by the code under test: clip trajectories chosen in 3-D (a fixed clip,
a clip that lets go and falls with a jerk, a clip moved by hand), drawn by handles_support as markers
whose image position is exact to any sub-pixel, and marks = their true projections plus click noise.
"""

import json
import os
import sys

import numpy as np
import pytest

sys.path.insert(0, os.path.dirname(__file__))
import handles_support as S  # noqa: E402
from clothfit.cli import main as cli  # noqa: E402
from clothfit.core import defaults as D  # noqa: E402
from clothfit.core.errors import ClothFitError  # noqa: E402
from clothfit.core.footage import handles as HM  # noqa: E402
from clothfit.core.observation.camera import Camera, intrinsics, look_at, save_cameras  # noqa: E402
from clothfit.core.physics.rotation import rotation_matrix, rotation_vector  # noqa: E402
from clothfit.core.physics.scenario import ClothGrid, Handle, Scenario, Uncertainty  # noqa: E402

FPS = 30.0
TIMES = np.arange(20) / FPS
AT = {
    "left": {"at": "top-left"},
    "right": {"at": "top-right", "released": True},
    "middle": {"motion": "moving", "at": [0.15, 0.0]},
}


# ------------------------------------------------------------------ the placed grid


def test_grid_placement_is_backward_compatible():
    g = ClothGrid(7, 5, 0.12, side_y=0.08)
    assert g.to_dict() == {"nx": 7, "ny": 5, "side": 0.12, "side_y": 0.08, "height": 0.1}  # no new keys
    old = ClothGrid.from_dict({"nx": 7, "ny": 5, "side": 0.12, "side_y": 0.08, "height": 0.1})
    assert np.array_equal(old.rest, g.rest) and not old.placed
    assert np.array_equal(ClothGrid.from_dict({"nx": 4}).rest, ClothGrid(4).rest)


def test_grid_placement_rest_and_round_trip():
    r = np.array([0.3, -1.1, 0.7])
    g = ClothGrid(6, 4, 0.3, side_y=0.2, origin=[0.1, -0.2, 0.6], rotation=r)
    R = rotation_matrix(r)
    assert np.allclose(g.rest, np.array([0.1, -0.2, 0.6]) + g.local @ R.T)
    assert np.allclose(R @ R.T, np.eye(3)) and np.isclose(np.linalg.det(R), 1.0)
    assert np.allclose(rotation_matrix(rotation_vector(R)), R)
    assert g.height == 0.6
    h = ClothGrid.from_dict(json.loads(json.dumps(g.to_dict())))
    assert np.allclose(h.rest, g.rest) and h.placed
    # distances within the sheet are those of the flat grid: the rest lengths do not change
    assert np.allclose(
        np.linalg.norm(g.rest[1:] - g.rest[:-1], axis=1), np.linalg.norm(g.local[1:] - g.local[:-1], axis=1)
    )
    with pytest.raises(ClothFitError, match="differs from the z of its origin"):
        ClothGrid.from_dict({"nx": 3, "height": 0.1, "origin": [0, 0, 0.5]})
    with pytest.raises(ClothFitError, match="origin must be 3"):
        ClothGrid.from_dict({"nx": 3, "origin": [0, 0]})
    with pytest.raises(ClothFitError, match="rotation must be 3"):
        ClothGrid(3, rotation=[0, float("nan"), 0])


@pytest.mark.parametrize("model", ["paper", "blender"])
def test_both_models_simulate_a_placed_grid_as_the_same_cloth_moved(model):
    """A placed sheet (turned about the vertical, moved) under the same gravity moves exactly as the paper's
    sheet moved rigidly: both models build from grid.rest."""
    from clothfit.core.physics import blender as B
    from clothfit.core.physics.models import get_model
    from clothfit.core.physics.scenario import paper_scenario

    base = paper_scenario(ClothGrid(6, 6, 0.1), frame_times=[0.05, 0.1, 0.2])
    r = np.array([0.0, 0.0, 0.9])
    o = np.array([0.3, -0.1, 0.4])
    R = rotation_matrix(r)
    g = ClothGrid(6, 6, 0.1, origin=o, rotation=r)
    moved = Scenario(
        g,
        [Handle(h.vertex, h.times, o + (h.positions - [0, 0, 0.1]) @ R.T, h.release_time) for h in base.handles],
        base.frame_times,
    )
    m = get_model({"name": model})
    row = [1e-5, 10.0, g.spacing, 1e-4] if model == "paper" else B.settings_row(B.DEFAULTS)
    a = m.simulate(base, [row]).positions[0]
    b = m.simulate(moved, [row]).positions[0]
    # the blender model computes in float32 like Blender: coordinates 0.4 m from the origin round at 3e-8 m,
    # which the conjugate-gradient solve (its own tolerance) carries to about a micrometre
    assert np.abs(o + (a - [0, 0, 0.1]) @ R.T - b).max() < (1e-9 if model == "paper" else 1e-5)


# ------------------------------------------------------------------ triangulation


def phone_rig(n=3):
    """Phones around a hung cloth: 1920 x 1080, 65 degree field of view, about 1 m away."""
    cams = []
    for i, az in enumerate(np.linspace(-50, 50, n)):
        a = np.radians(az - 90)
        eye = np.array([np.cos(a), np.sin(a), 0.5]) * [1.0, 1.0, 1.0] + [0, 0, 0.3]
        R, t = look_at(eye, [0, 0, 0.45])
        cams.append(
            Camera(intrinsics(1500.0, 1920, 1080), R, t, 1920, 1080, f"phone{i}", np.array([0.1, -0.2, 0.0, 0.0, 0.05]))
        )
    return cams


def test_triangulation_exact_and_within_a_millimetre_at_click_noise():
    cams = phone_rig()
    rng = np.random.default_rng(1)
    X = np.array([0.12, 0.03, 0.52])
    t = HM.triangulate(cams, [c.project(X) for c in cams])
    assert np.linalg.norm(t.X - X) < 1e-7 and t.rms < 1e-4  # distortion undone exactly
    errs, inside = [], 0
    for _ in range(200):  # a person's click: 0.5 px
        t = HM.triangulate(cams, [c.project(X) + rng.normal(0, 0.5, 2) for c in cams], 0.5)
        errs.append(np.linalg.norm(t.X - X))
        inside += np.all(np.abs(t.X - X) <= 3 * np.sqrt(np.diag(t.cov)))
    assert np.percentile(errs, 95) < 1e-3, np.percentile(errs, 95)
    assert inside >= 190  # the covariance is honest (3 sigma)
    # the residual: a mark moved by 5 px in one camera shows in it
    pts = [c.project(X) for c in cams]
    pts[1] = pts[1] + [5.0, 0.0]
    assert HM.triangulate(cams, pts).residuals.max() > 1.0


# ------------------------------------------------------------------ synthetic footage


def _setup(tmp, release_time=0.21, seed=0, sigma=0.3, extra=AT, moving=True, fps=FPS):
    times = np.arange(20) / fps
    cams = S.rig()
    tr = S.clip_tracks(times, release_time=release_time, moving=moving)
    root = os.path.join(str(tmp), "footage")
    S.write_footage(root, cams, times, tr, seed=seed)
    save_cameras(os.path.join(root, "cameras.json"), cams)
    with open(os.path.join(root, "footage.json"), "w") as f:
        json.dump({"cameras": "cameras.json", "frame_times": times.tolist()}, f)
    marks = S.marks_for(cams, tr, sigma=sigma, seed=seed, extra=extra)
    mpath = os.path.join(str(tmp), "marks.json")
    with open(mpath, "w") as f:
        json.dump(marks, f)
    return root, mpath, cams, tr, times


def _run(root, mpath, out, *extra):
    return cli(
        [
            "handles",
            root,
            "--marks",
            mpath,
            "--size",
            f"{S.CLOTH_W}x{S.CLOTH_H}",
            "-o",
            out,
            "--clip-size",
            "0.016",
            *extra,
        ]
    )


def test_handles_end_to_end(tmp_path, capsys):
    root, mpath, cams, tr, times = _setup(tmp_path)
    out = str(tmp_path / "scenario.json")
    assert _run(root, mpath, out) == 0
    rep = json.loads(capsys.readouterr().out)
    doc = json.load(open(out))
    assert doc["format"] == HM.FORMAT
    sc = Scenario.from_dict(doc["scenario"])
    nx = sc.grid.nx
    assert (sc.grid.nx, sc.grid.ny) == (15, 12)  # about 16, odd: the middle clip falls on a vertex
    by = {h["name"]: h for h in rep["handles"]}
    assert [by[n]["vertex"] for n in ("left", "right", "middle")] == [0, nx - 1, (nx - 1) // 2]
    left, right, middle = sc.handles
    # the pins: within 1 mm of the truth
    assert np.linalg.norm(left.positions[0] - tr["left"][0]) < 1e-3
    assert np.linalg.norm(right.positions[0] - tr["right"][0]) < 1e-3
    # the moving clip's whole trajectory within 1 mm
    assert middle.times.size == len(times)
    assert np.abs(np.linalg.norm(middle.positions - tr["middle"], axis=1)).max() < 1e-3
    # the release: the first frame after the release instant, and the instant within a fifth of a frame
    assert by["right"]["release_frame"] == int(np.searchsorted(times, 0.21, side="right"))
    assert abs(right.release_time - 0.21) < 0.2 / FPS
    assert left.release_time is None and middle.release_time is None
    # the placed cloth hangs in the vertical plane of the clips, its top row through them
    assert abs(sc.grid.R[:, 2] @ [0, 0, 1]) < 0.01  # normal horizontal
    assert np.linalg.norm(sc.grid.rest[0] - tr["left"][0]) < 2e-3
    assert rep["cloth"]["placement_rms_mm"] < 1.5
    # the uncertain block: the fit's box per handle (D.HANDLE_FIT_BOX_M, whatever the triangulation leaves), time
    # within a frame; the triangulation's own 3 sigma, reported beside it, covers the actual error
    unc = Uncertainty.parse(doc["uncertain"], 3)
    assert list(unc.handles) == [D.HANDLE_FIT_BOX_M] * 3
    assert 0.5 / FPS - 1e-6 <= unc.time_offset <= 1.0 / FPS + 1e-6
    assert np.all(np.abs(right.positions[0] - tr["right"][0]) <= by["right"]["uncertain_mm"] / 1000)
    assert all(h["fit_box_mm"] == pytest.approx(1000 * D.HANDLE_FIT_BOX_M) for h in rep["handles"])
    for h in rep["handles"]:
        assert h["residual_rms_px"] < 1.0 and h["residual_rms_mm"] < 1.0 and h["track_frames"]
    assert by["left"]["drift_mm"] < 0.5


def test_extract_takes_the_scenario_and_its_uncertain_block(tmp_path, capsys):
    """`extract --scenario` reads the handles file: its scenario and its uncertain block land in the capture."""
    from clothfit.core.footage import extract as X
    from clothfit.core.observation.capture import load_capture

    root, mpath, cams, tr, times = _setup(tmp_path)
    out = str(tmp_path / "scenario.json")
    assert _run(root, mpath, out) == 0
    doc = json.load(open(out))
    scen, _, unc = X._resolve_scenario_uncertain(out, list(times), "test")
    assert unc == doc["uncertain"] and scen.grid.placed
    assert Scenario.from_dict(doc["scenario"]).to_dict() == scen.to_dict()
    # a capture written with it keeps both (silhouettes: anything non-empty)
    from clothfit.core.observation.capture import write_capture

    masks = [[_blob(c) for _ in times] for c in cams]
    u, src = X._uncertain_for(scen, None, unc, None)
    assert src == "the scenario file"
    cap = write_capture(str(tmp_path / "cap"), cams, scen, masks, uncertain=u)
    back = load_capture(cap.root)
    assert back.uncertain.to_dict() == doc["uncertain"]
    assert np.allclose(back.scenario.grid.rest, scen.grid.rest)
    # the explicit option wins; 'none' writes nothing; a bad block fails in one line
    assert X._uncertain_for(scen, "time_offset=0.01,handles=0.002", unc, None)[0].time_offset == 0.01
    assert X._uncertain_for(scen, "none", unc, None)[0] is None
    with pytest.raises(ClothFitError, match="3 handles"):
        X._uncertain_for(scen, None, {"handles": [0.001, 0.002]}, None)
    # frames read from videos: one frame period for the time, nothing for the handles
    u = X._uncertain_for(scen, None, None, None, 1 / 30)[0]
    assert u.time_offset == round(1 / 30, 6) and u.handles == (0.0,) * 3


def _blob(cam):
    m = np.zeros((cam.height, cam.width), bool)
    m[100:200, 100:200] = True
    return m


@pytest.mark.parametrize("phase", [0.1, 0.5, 0.9])
def test_release_frame_exact_at_any_phase(tmp_path, phase):
    """Releases early, mid-way and late between two frames: the release frame is the first after the instant."""
    t_r = 0.2 + phase / FPS
    root, mpath, cams, tr, times = _setup(tmp_path, release_time=t_r, seed=int(phase * 10))
    out = str(tmp_path / "s.json")
    assert _run(root, mpath, out) == 0
    doc = json.load(open(out))
    h = [x for x in doc["report"]["handles"] if x["name"] == "right"][0]
    assert h["release_frame"] == int(np.searchsorted(times, t_r, side="right")), (h, t_r)
    assert abs(h["release_time"] - t_r) < 0.25 / FPS


def test_without_at_the_cloth_hangs_by_its_top_edge(tmp_path, capsys):
    root, mpath, cams, tr, times = _setup(tmp_path, extra={"right": {"released": True}}, moving=False)
    out = str(tmp_path / "s.json")
    assert _run(root, mpath, out, "--grid", "16") == 0
    rep = json.loads(capsys.readouterr().out)
    assert "top edge" in rep["cloth"]["placement"]
    cols = sorted(h["column"] for h in rep["handles"])
    assert cols == [0, 7, 15] or cols == [0, 8, 15]  # the middle clip: half way, the grid has no centre column
    assert all(h["row"] == 0 for h in rep["handles"])


def test_fixed_handle_that_moves_is_flagged(tmp_path, capsys):
    extra = dict(AT, middle={"at": [0.15, 0.0]})  # the hand-moved clip declared fixed
    root, mpath, cams, tr, times = _setup(tmp_path, extra=extra)
    assert _run(root, mpath, str(tmp_path / "s.json")) == 0
    rep = json.loads(capsys.readouterr().out)
    assert any("declared fixed but moves" in w and "'middle'" in w for w in rep["warnings"])


def test_videos_and_sync(tmp_path, capsys):
    """The same footage as H.264 videos started at different moments, read at capture time + sync."""
    pytest.importorskip("av")
    import cv2

    sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(__file__)), "tools"))
    from video_footage import encode

    root, mpath, cams, tr, times = _setup(tmp_path)
    vids = tmp_path / "videos"
    vids.mkdir()
    sync = {}
    for i, c in enumerate(cams):
        sync[c.name] = 0.5 + 0.1 * i
        frames = [
            cv2.cvtColor(
                cv2.imread(os.path.join(root, c.name, f"{f:03d}.png"), cv2.IMREAD_GRAYSCALE), cv2.COLOR_GRAY2BGR
            )
            for f in range(len(times))
        ]
        encode(
            str(vids / f"{c.name}.mp4"),
            frames[:1] * 3 + frames,
            [sync[c.name] + t for t in (-0.3, -0.2, -0.1)] + [sync[c.name] + t for t in times],
            crf=12,
        )
    with open(tmp_path / "sync.json", "w") as f:
        json.dump(sync, f)
    out = str(tmp_path / "s.json")
    assert (
        cli(
            [
                "handles",
                "--videos",
                str(vids),
                "--sync",
                str(tmp_path / "sync.json"),
                "--cameras",
                os.path.join(root, "cameras.json"),
                "--fps",
                "30",
                "--frames",
                "20",
                "--marks",
                mpath,
                "--size",
                f"{S.CLOTH_W}x{S.CLOTH_H}",
                "--clip-size",
                "0.016",
                "-o",
                out,
            ]
        )
        == 0
    )
    doc = json.load(open(out))
    h = {x["name"]: x for x in doc["report"]["handles"]}
    assert h["right"]["release_frame"] == 7
    pins = Scenario.from_dict(doc["scenario"]).handles
    assert np.linalg.norm(pins[0].positions[0] - tr["left"][0]) < 1e-3


# ------------------------------------------------------------------ bad input: one line, nothing written


def _one_line_error(capsys, args, *needles):
    code = cli(args)
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert "\n" not in err and err.startswith("error: "), err
    for n in needles:
        assert n in err, err
    return err


def test_bad_inputs(tmp_path, capsys):
    import cv2

    root, mpath, cams, tr, times = _setup(tmp_path, extra=AT)
    marks = json.load(open(mpath))
    out = str(tmp_path / "s.json")
    base = ["handles", root, "--size", f"{S.CLOTH_W}x{S.CLOTH_H}", "-o", out, "--clip-size", "0.016"]

    def with_marks(m):
        p = str(tmp_path / "m.json")
        with open(p, "w") as f:
            json.dump(m, f)
        return base + ["--marks", p]

    bad = json.loads(json.dumps(marks))
    bad["handles"][0]["marks"]["cam1"] = [700.0, 20.0]
    _one_line_error(capsys, with_marks(bad), "'left'", "outside its 640x480 image", "cam1")
    bad = json.loads(json.dumps(marks))
    bad["handles"][1]["marks"] = {"cam2": bad["handles"][1]["marks"]["cam2"]}
    _one_line_error(capsys, with_marks(bad), "'right'", "at least 2 cameras")
    bad = json.loads(json.dumps(marks))
    bad["handles"][1]["marks"]["camX"] = [1, 1]
    _one_line_error(capsys, with_marks(bad), "camera 'camX' is not in the calibration")
    bad = json.loads(json.dumps(marks))
    bad["handles"][1]["relesed"] = True
    _one_line_error(capsys, with_marks(bad), "unknown key 'relesed'")
    bad = json.loads(json.dumps(marks))
    bad["handles"][0]["marks"]["cam0"] = (np.array(bad["handles"][0]["marks"]["cam0"]) + [30, 0]).tolist()
    _one_line_error(capsys, with_marks(bad), "'left'", "do not meet in 3-D")
    bad = json.loads(json.dumps(marks))
    bad["handles"][0]["released"] = True
    _one_line_error(capsys, with_marks(bad), "'left'", "declared released but stays")
    bad = json.loads(json.dumps(marks))
    bad["handles"][2]["at"] = [0.0, 0.0]
    _one_line_error(capsys, with_marks(bad), "'left' and 'middle' fall on the same grid vertex")
    # a cloth much wider than the clips are apart: the clips cannot all sit on it
    _one_line_error(capsys, base[:3] + ["0.5x0.3"] + base[4:] + ["--marks", mpath], "mm from its vertex")
    _one_line_error(capsys, base[:3] + ["0.5"] + base[4:] + ["--marks", mpath], "--size")
    # a track lost: the moving clip covered in 3 of the 4 cameras at frame 12
    for c in cams[:3]:
        p = os.path.join(root, c.name, "012.png")
        img = cv2.imread(p, cv2.IMREAD_GRAYSCALE)
        uv = c.project(tr["middle"][12])
        cv2.circle(img, (int(uv[0]), int(uv[1])), 25, 128, -1)
        cv2.imwrite(p, img)
    _one_line_error(capsys, base + ["--marks", mpath], "'middle'", "frame 12", "lost", "cam0")
    # unreadable media
    with open(os.path.join(root, "cam2", "005.png"), "wb") as f:
        f.write(b"not a png")
    _one_line_error(capsys, base + ["--marks", mpath], "005.png", "unreadable")
    os.remove(os.path.join(root, "cam2", "005.png"))
    _one_line_error(capsys, base + ["--marks", mpath], "cam2", "19 frames", "20 frame times")
    _one_line_error(capsys, base + ["--marks", str(tmp_path / "nope.json")], "marks file", "not found")
    assert not os.path.exists(out)
    # the output may not replace an input
    _one_line_error(capsys, ["handles", root, "--size", "0.3x0.24", "-o", mpath, "--marks", mpath], "overwrite")
    assert json.load(open(mpath)) == marks


def test_marks_parsing(tmp_path):
    cams = S.rig(2)
    ok = {"handles": [{"name": "a", "at": "bottom-right", "marks": {"cam0": [1, 2], "cam1": [3, 4]}, "size": 0.02}]}
    h = HM.parse_marks(ok, cams, 5, (0.3, 0.2))[0]
    assert h.at == (0.3, 0.2) and h.size == 0.02 and h.frame == 0 and h.motion == "fixed"
    for bad, needle in (
        (dict(ok, frame=5), "frame 5"),
        ({"handles": []}, "non-empty"),
        ({"handles": [dict(ok["handles"][0], at="middle")]}, "corner"),
        ({"handles": [dict(ok["handles"][0], at=[0.4, 0])]}, "off the 0.3 x 0.2 m cloth"),
        ({"handles": [dict(ok["handles"][0], motion="wobbly")]}, "motion"),
        ({"handles": ok["handles"] * 2}, "two handles have this name"),
        ({"handles": [dict(ok["handles"][0], marks={"cam0": [1], "cam1": [3, 4]})]}, "[x, y]"),
    ):
        with pytest.raises(ClothFitError, match=None) as e:
            HM.parse_marks(bad, cams, 5, (0.3, 0.2))
        assert needle in str(e.value) and "\n" not in str(e.value)


def test_grid_resolution_puts_clips_on_vertices():
    assert HM.grid_resolution(0.3, 0.24) == (16, 13)
    nx, ny = HM.grid_resolution(0.3, 0.2, ats=[(0, 0), (0.1, 0), (0.3, 0)])
    assert abs(0.1 / (0.3 / (nx - 1)) - round(0.1 / (0.3 / (nx - 1)))) < 1e-9
    assert HM.grid_resolution(0.3, 0.2, nx=5, ny=4) == (5, 4)
    with pytest.raises(ClothFitError):
        HM.grid_resolution(0.3, 0.2, nx=5)


def test_release_of_a_corner_that_snaps_away():
    """The core's paper sheet hung by four clips: the released corner springs back within milliseconds (a
    jump, not a fall from rest). Its release frame is the departure frame at every phase; a fall from rest
    (the synthetic clip) is recovered one frame before its departure when it started under the threshold."""
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(__file__)), "lab"))
    import phone_handles as P

    rng = np.random.default_rng(0)
    for seed in range(6):
        tr = P.truth(seed)
        X = tr["positions"][:, tr["vertices"]["right"]] + rng.normal(0, 3e-5, (len(tr["times"]), 3))
        r = HM.detect_release(tr["times"], X, 0, HM.HandleOptions())
        assert r.release_frame == int(np.searchsorted(tr["times"], tr["release_time"], side="right"))
        assert r.extrapolated_time is None  # no parabola from rest fits a snap
        lo, hi = tr["times"][r.release_frame - 1], tr["times"][r.release_frame]
        assert lo <= r.release_time < hi
    t = np.arange(20) / FPS
    t_r = 0.2 + 0.9 / FPS  # 3 ms before frame 7: 0.05 mm of fall there
    X = S.clip_tracks(t, t_r)["right"] + rng.normal(0, 1e-5, (20, 3))
    r = HM.detect_release(t, X, 0, HM.HandleOptions())
    assert r.departure_frame == 8 and r.back and r.release_frame == 7
    assert abs(r.release_time - t_r) < 0.1 / FPS
