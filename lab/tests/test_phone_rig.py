"""The phone rig, end to end without the truth in the inputs (the small version of ``lab/phone_rig.py e2e``).

Cycles renders (tiny: 3 phones, few samples) of a ChArUco board on the table, then of a cloth hung by four
clips with one let go; then, as a user runs them, ``clothfit calibrate``, ``handles``, ``extract``, ``fit``
and ``export-blender-cloth`` on those images, the clicks, the cloth's size and its mass only. The truth
(cameras, the cloth's motion by Blender's cloth model, the release instant) stays in the tool; the same
fit given the true cameras and manipulation is the reference. The full run is the recorded
``docs/figures/phone_rig_e2e.json``.
"""

import json
import os
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.join(ROOT, "lab"))

# the small rig: 3 phones at 324 x 576, 1 Cycles sample, 9 board poses, 12 frames, fits of 150 evaluations.
# Measured once (seed 11, `lab/phone_rig.py e2e --out /tmp/e2e_small --seed 11 --scale 0.3 --cameras 3
# --poses 9 --frames 12 --samples 1 --evals 150 --uncertain-evals 150 --fit-seed S`, after CMA-ES began to
# sample with the symmetric square root of its covariance): calibration RMS 0.34 px, worst focal 0.55 %, worst
# centre 2.9 mm; clips within 1.9 mm; release frame 3 for a true 4 (the handles' departure test fires a frame
# early at this size); replay 0.69 to 2.0 mm given the truth. Over fit seeds S = 0..7 the user's fit (the
# capture's uncertain block: clip offsets and time offset estimated) replays at 1.17 to 3.79 times the
# truth-given fit (median 2.68; the phone rig's goal of 2 on one seed of eight), the same fit told the clips are
# exact ("--uncertain none") at 1.23 to 3.46 times: 150 evaluations on this rig are a draw (the recorded full
# run, docs/figures/phone_rig_e2e.json, measures the goal). Tolerances about 2x the measurements: the ratios
# about twice their medians, above their worst seeds.
SEED, SCALE, POSES, FRAMES, SAMPLES, EVALS = "11", "0.3", "9", "12", "1", "150"
RMS_PX, FOCAL_PCT, CENTRE_MM, HANDLES_MM, ORACLE_MM, RATIO, RATIO_EXACT = 0.7, 1.2, 6.0, 4.0, 3.0, 5.0, 6.0
RELEASE_FRAMES = 1

bpy_missing = False
try:
    import importlib.util

    bpy_missing = importlib.util.find_spec("bpy") is None
except Exception:  # pragma: no cover
    bpy_missing = True


@pytest.mark.skipif(bpy_missing, reason="needs the bpy module (pinned in requirements-dev.txt)")
def test_phone_rig_end_to_end_small(tmp_path):
    import phone_rig as PR

    out = str(tmp_path / "e2e")
    js = str(tmp_path / "e2e.json")
    assert (
        PR.main(
            [
                "e2e",
                "--out",
                out,
                "--seed",
                SEED,
                "--scale",
                SCALE,
                "--cameras",
                "3",
                "--poses",
                POSES,
                "--frames",
                FRAMES,
                "--samples",
                SAMPLES,
                "--evals",
                EVALS,
                "--uncertain-evals",
                EVALS,
                "--json",
                js,
            ]
        )
        == 0
    )
    r = json.load(open(js))
    # every step of the user's pipeline wrote its file
    for f in ("cameras.json", "scenario.json", "capture/capture.json", "fit.json", "blender_cloth.json"):
        assert os.path.exists(os.path.join(out, f)), f
    cloth = json.load(open(os.path.join(out, "blender_cloth.json")))
    assert set(PR.FREE) <= set(cloth["blender_cloth"])
    # tolerances: see the measurement above
    c = r["calibration"]
    assert c["rms_px"] < RMS_PX, c
    assert c["worst"]["focal_pct"] < FOCAL_PCT, c
    assert c["worst"]["centre_mm"] < CENTRE_MM, c
    assert r["handles_max_mm"] < HANDLES_MM, r["handles_mm"]
    assert abs(r["release_frame"] - r["true_release_frame"]) <= RELEASE_FRAMES, (
        r["release_frame"],
        r["true_release_frame"],
    )
    assert r["fit"]["truth_given"]["replay"]["mean_mm"] < ORACLE_MM, r["fit"]
    assert r["shape_ratio_uncertain"] < RATIO, r["fit"]
    assert r["shape_ratio"] < RATIO_EXACT, r["fit"]  # the fit told the clips are exact (see above)
    # the spread over fit seeds on that folder (nothing rendered again): a row per seed with the three fits;
    # the true settings score best on the capture given the truth (true cameras and clips). With the
    # calibrated cameras, the true clips need not beat the measured ones: on this small rig (cameras
    # millimetres off) they score 9.12 % against 8.92 %, on the recorded 810 x 1440 rigs lower
    # (docs/phone_rig.md)
    sj = str(tmp_path / "spread.json")
    assert PR.main(["spread", "--e2e", out, "--fit-seeds", "0", "--evals", "40", "--json", sj]) == 0
    s = json.load(open(sj))
    assert s["fit_seeds"] == [0] and len(s["runs"]) == 1
    row = s["runs"][0]
    assert {"e2e", "uncertain", "truth_given"} <= set(row)
    assert row["ratio_e2e"] == pytest.approx(row["e2e"]["replay_mm"] / row["truth_given"]["replay_mm"])
    sc = s["true_settings_E_sil_pct"]
    assert sc["truth_given"] < min(sc["true_clips"], sc["measured_clips"]), sc
    assert max(s["clip_error_mm"]) == pytest.approx(r["handles_max_mm"], rel=1e-6)
