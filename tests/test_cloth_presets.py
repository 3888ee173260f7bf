"""A fit in the words an artist already uses: the nearest of Blender's own cloth presets, how far,
and which settings differ most (core, no Blender)."""

import pytest
from clothfit.core.errors import ClothFitError
from clothfit.core.physics import blender as B
from clothfit.core.physics.cloth_presets import COMPARED, nearest_preset, preset_differences, preset_text


@pytest.mark.parametrize("key", sorted(B.PRESETS))
def test_each_preset_is_its_own_nearest_at_distance_zero(key):
    near = nearest_preset(B.PRESETS[key])
    assert near["name"].lower() == key
    assert near["distance"] == pytest.approx(0.0, abs=1e-12) and near["factor"] == pytest.approx(1.0)
    assert near["differences"] == ["no setting differs by more than 10 %"]


def test_a_lighter_cloth_that_moves_the_same_is_at_the_same_preset():
    """Every mass-scaled setting times the same factor moves the same cloth: silhouettes cannot tell."""
    denim = B.check_settings(B.PRESETS["denim"])
    light = {k: (v * 0.5 if k in B.mass_scaled(denim["bending_model"]) else v) for k, v in denim.items()}
    near = nearest_preset(light)
    assert near["name"] == "Denim" and near["distance"] == pytest.approx(0.0, abs=1e-12)


def test_the_biggest_difference_is_named_first_with_its_factor():
    cotton = B.check_settings(B.PRESETS["cotton"])
    stiffer = dict(cotton, bending_stiffness=cotton["bending_stiffness"] * 4)
    near = nearest_preset(stiffer)
    assert near["name"] == "Cotton" and near["distance"] > 0
    assert near["differences"][0] == "bending_stiffness 4x Cotton's"
    diffs = preset_differences(stiffer, "cotton")
    assert diffs[0]["setting"] == "bending_stiffness" and [d["setting"] for d in diffs[1:]] != []
    assert sorted(d["setting"] for d in diffs) == sorted(COMPARED)
    assert near["distances"]["Cotton"] == near["distance"] == min(near["distances"].values())


def test_a_stiff_heavy_cloth_is_nearer_leather_than_silk():
    near = nearest_preset(dict(B.PRESETS["leather"], bending_stiffness=120.0))
    assert near["name"] == "Leather"
    assert near["distances"]["Silk"] > near["distances"]["Leather"]


def test_preset_text_is_blenders_preset_format_and_refuses_bad_values():
    text = preset_text(B.PRESETS["silk"], 24.0, "fit.json")
    lines = text.splitlines()
    assert lines[:2] == ["import bpy", "cloth = bpy.context.cloth"]
    body = [ln for ln in lines if ln.startswith("cloth.settings.")]
    assert "cloth.settings.bending_stiffness = 0.05" in body and "cloth.settings.bending_model = 'ANGULAR'" in body
    with pytest.raises(ClothFitError, match="tension_stiffness"):
        preset_text(dict(B.PRESETS["silk"], tension_stiffness=-1.0), 24.0)
    with pytest.raises(ClothFitError, match="frame rate"):
        preset_text(B.PRESETS["silk"], 0.0)
