"""make demo's pictures: the comparison drawn on camera images (core), and demo_blend/build_demo.py
writing its pictures and summary.json on a small setting (bpy module)."""

import json
import os
import sys

import numpy as np
import pytest
from blender_support import bpy, factory  # noqa: F401
from clothfit.core.errors import ClothFitError
from clothfit.core.observation.overlay import (
    ON_IMAGE_EXTRA_RGB,
    ON_IMAGE_MISSING_RGB,
    ON_IMAGE_OUTLINE_RGB,
    overlay_on_image,
    silhouette_box,
)

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _masks():
    obs = np.zeros((60, 80), bool)
    obs[20:40, 20:50] = True
    mod = np.zeros_like(obs)
    mod[20:40, 25:55] = True
    return obs, mod


def test_overlay_on_image_tints_the_differences_and_outlines_the_model():
    obs, mod = _masks()
    img = np.full((60, 80, 3), 100, np.uint8)
    out = overlay_on_image(img, obs, mod)
    assert out.shape == img.shape and out.dtype == np.uint8
    miss, extra = out[30, 22].astype(int), out[30, 52].astype(int)  # observed only / model only
    assert miss[0] > miss[2] + 50 and extra[2] > extra[0] + 50
    assert (out[30, 35] == 100).all()  # agreement: the image itself
    assert (out[5, 5] == 100).all()  # background untouched
    edge = out[30, 25].astype(int)  # the model's left edge: yellow
    assert edge[0] > 200 and edge[1] > 180 and edge[2] < 60 and ON_IMAGE_OUTLINE_RGB[2] < 60
    ign = np.zeros_like(obs)
    ign[:, :35] = True
    out2 = overlay_on_image(img, obs, mod, ignore=ign)
    assert (out2[30, 22] == 100).all()  # unknown truth: no tint
    assert ON_IMAGE_MISSING_RGB != ON_IMAGE_EXTRA_RGB


def test_overlay_on_image_crops_and_scales():
    obs, mod = _masks()
    box = silhouette_box([obs, mod], margin=0.1)
    y0, y1, x0, x1 = box
    assert y1 - y0 == x1 - x0 and y0 <= 20 and y1 >= 40 and x0 <= 20 and x1 >= 55
    out = overlay_on_image(np.zeros((60, 80, 3), np.uint8), obs, mod, box=box, size=200)
    assert max(out.shape[:2]) == 200
    assert silhouette_box([np.zeros((10, 12), bool)]) == (0, 10, 0, 12)


def test_overlay_on_image_refuses_mismatched_sizes():
    obs, mod = _masks()
    with pytest.raises(ClothFitError, match="do not match"):
        overlay_on_image(np.zeros((50, 80, 3), np.uint8), obs, mod)


def test_build_demo_writes_its_pictures_and_summary(tmp_path, monkeypatch):
    sys.path.insert(0, os.path.join(ROOT, "demo_blend"))
    import build_demo

    out = tmp_path / "demo"
    code = build_demo.main(
        [
            "--out",
            str(out),
            "--blend",
            "",
            "--rig",
            "ring8",
            "--times",
            "0.05:0.3:0.05",
            "--budget",
            "30",
            "--resolution",
            "60x80",
            "--train-cameras",
            "3",
            "--noise",
            "0",
            "--no-blender-model",
        ]
    )
    assert code == 0
    pics = out / "pictures"
    for name in (
        "fit_on_images.png",
        "error_curve.png",
        "parameters.png",
        "blender_rig.png",
        "blender_silhouettes.png",
        "blender_overlays_first_guess.png",
        "blender_overlays.png",
    ):
        assert (pics / name).is_file(), name
    s = json.loads((out / "summary.json").read_text())
    story = s["story"]
    assert set(story["pictures"]) >= {"fit_on_images.png", "error_curve.png", "parameters.png"}
    assert story["shown"]["roles"][0] == "training" and story["shown"]["roles"][1:] == ["held out", "held out"]
    assert story["train_E_sil_pct"]["first_guess"] > story["train_E_sil_pct"]["fitted"]
    assert set(story["identifiable_error_pct"]["fitted"]) == {"k_over_m", "d_over_m", "l"}
    assert s["seconds"] > 0 and s["settings"]["rig"] == "ring8"
