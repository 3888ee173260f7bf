"""A blender-model fit taken to Blender: the script ``export-blender-cloth --python`` prints runs in
Blender as it is (real bpy module), the add-on's Apply Blender Cloth does the same, and a fit saved
as a preset is a file of Blender's own preset format that Blender's preset menu runs."""

import glob
import json
import os
import re

import pytest
from blender_support import bpy, factory  # noqa: F401
from clothfit import cli  # noqa: E402
from clothfit.core.errors import ClothFitError  # noqa: E402
from clothfit.core.physics import blender as B  # noqa: E402
from clothfit.core.physics.cloth_presets import COMPARED, PRESET_FILE_SETTINGS  # noqa: E402

pytestmark = pytest.mark.usefixtures("factory")

FPS = 30.0
FITTED = {
    "quality": 7,
    "bending_model": "LINEAR",
    "tension_stiffness": 33.0,
    "shear_stiffness": 7.5,
    "bending_stiffness": 2.25,
    "air_damping": 0.2,
    "time_scale": B.physical_time_scale(FPS),
}


def _result(tmp_path):
    res = {
        "model": {"name": "blender", "fps": FPS, "quality": 7, "bending_model": "LINEAR"},
        "blender_cloth": B.check_settings(FITTED),
        "blender_scene": {"fps": FPS},
    }
    p = tmp_path / "fit.json"
    p.write_text(json.dumps(res))
    return p


def _plane(name="Plane", cloth=True):
    bpy.ops.mesh.primitive_plane_add(size=1.0)
    obj = bpy.context.view_layer.objects.active
    obj.name = name
    if cloth:
        obj.modifiers.new("My cloth sim", "CLOTH")  # not named 'Cloth': found by type
    return obj


def _script(tmp_path, capsys, *extra):
    assert cli.main(["export-blender-cloth", str(_result(tmp_path)), "--python", *extra]) == 0
    return capsys.readouterr().out


def _run(text):
    exec(compile(text, "exported.py", "exec"), {"__name__": "__main__"})


def _cloth(obj):
    return [m for m in obj.modifiers if m.type == "CLOTH"][0].settings


def _assert_fitted(cs):
    want = B.check_settings(FITTED)
    for k, v in want.items():
        got = getattr(cs, k)
        assert got == v if isinstance(v, str) else got == pytest.approx(v, rel=1e-6), k


def test_printed_script_sets_the_active_objects_cloth_and_the_frame_rate(tmp_path, capsys):
    text = _script(tmp_path, capsys)
    assert text.startswith("#") and "\nimport bpy\n" in text
    obj = _plane()
    scene = bpy.context.scene
    assert scene.render.fps == 24
    _run(text)
    _assert_fitted(_cloth(obj))
    assert scene.render.fps / scene.render.fps_base == pytest.approx(FPS)


def test_printed_script_sets_a_named_object_not_the_active_one(tmp_path, capsys):
    text = _script(tmp_path, capsys, "--object", "Sheet")
    sheet = _plane("Sheet")
    other = _plane("Other")
    assert bpy.context.view_layer.objects.active == other
    _run(text)
    _assert_fitted(_cloth(sheet))
    assert _cloth(other).tension_stiffness == pytest.approx(B.DEFAULTS["tension_stiffness"])


@pytest.mark.parametrize(
    "setup,extra,message",
    [
        ("plain mesh", (), "object 'Plane' has no Cloth modifier"),
        ("nothing", (), "no active object"),
        ("cloth", ("--object", "Missing"), "no object named 'Missing'"),
    ],
)
def test_printed_script_fails_in_one_line_without_a_cloth_modifier(tmp_path, capsys, setup, extra, message):
    text = _script(tmp_path, capsys, *extra)
    if setup != "nothing":
        _plane(cloth=setup == "cloth")
    else:
        bpy.context.view_layer.objects.active = None
    scene = bpy.context.scene
    with pytest.raises(RuntimeError) as ei:
        _run(text)
    assert message in str(ei.value) and "\n" not in str(ei.value)
    assert scene.render.fps == 24  # nothing changed


def test_apply_blender_cloth_does_what_the_script_does(tmp_path):
    """The add-on's operator path on a user's mesh and the script give the same settings and frame rate;
    a mesh without a Cloth modifier is the same error."""
    from clothfit.blender import api

    res = json.loads(_result(tmp_path).read_text())
    scene = bpy.context.scene
    bare = _plane("Bare", cloth=False)
    with pytest.raises(ClothFitError, match="'Bare' has no Cloth modifier"):
        api.apply_blender_cloth(scene, bare, res)
    assert scene.render.fps == 24 and not bare.modifiers
    obj = _plane("Sheet")
    _, msg = api.apply_blender_cloth(scene, obj, res)
    _assert_fitted(_cloth(obj))
    assert scene.render.fps / scene.render.fps_base == pytest.approx(FPS)
    assert "nearest Blender preset" in msg


def _installed_presets():
    files = [f for d in bpy.utils.preset_paths("cloth") for f in glob.glob(os.path.join(d, "*.py"))]
    assert files, "the bpy module ships Blender's cloth presets"
    out = {}
    for f in files:
        values = {}
        for m in re.finditer(r"^bpy\.context\.cloth\.settings\.(\w+) = (.+)$", open(f).read(), re.M):
            values[m.group(1)] = eval(m.group(2))  # noqa: S307 - Blender's own literals
        out[os.path.basename(f)[:-3].lower()] = values
    return out


def test_stored_presets_equal_blenders_installed_preset_files():
    installed = _installed_presets()
    assert set(installed) == set(B.PRESETS)
    for name, values in installed.items():
        assert set(COMPARED) <= set(values), name
        for k, v in values.items():
            if k in B.PRESETS[name]:
                assert B.PRESETS[name][k] == pytest.approx(v), (name, k)
            elif k in B.DEFAULTS:
                pytest.fail(f"{name}: {k} is set by Blender's preset but not stored")


def test_preset_file_runs_as_blenders_preset_menu_runs_it(tmp_path, capsys):
    """Blender's preset menu runs the file with ``context.cloth`` the Cloth modifier; so does this test."""
    preset = tmp_path / "My fit.py"
    assert cli.main(["export-blender-cloth", str(_result(tmp_path)), "--preset", str(preset)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["preset"] == str(preset)
    text = preset.read_text()
    assert text.startswith("import bpy\ncloth = bpy.context.cloth\n")
    assert [ln.split(" = ")[0].split(".")[-1] for ln in text.splitlines() if ln.startswith("cloth.settings.")] == list(
        PRESET_FILE_SETTINGS
    )
    obj = _plane()
    mod = [m for m in obj.modifiers if m.type == "CLOTH"][0]
    with bpy.context.temp_override(cloth=mod):
        _run(text)
    _assert_fitted(mod.settings)


def test_a_blender_preset_itself_is_nearest_to_itself_at_distance_zero(tmp_path, capsys):
    for key, values in _installed_presets().items():
        settings = {k: v for k, v in values.items() if k in B.DEFAULTS}
        res = {"model": {"name": "blender", "fps": 24.0}, "blender_cloth": B.check_settings(settings)}
        p = tmp_path / f"{key}.json"
        p.write_text(json.dumps(res))
        assert cli.main(["export-blender-cloth", str(p)]) == 0
        near = json.loads(capsys.readouterr().out)["nearest_preset"]
        assert near["name"].lower() == key and near["distance"] == pytest.approx(0.0, abs=1e-12)
