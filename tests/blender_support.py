"""Shared fixtures of the tests/test_blender_*.py files (real ``bpy`` module).

``factory`` (autouse in those files) resets Blender to an empty factory scene before and after
each test; the add-on is registered once per session. ``small_capture`` is a capture rendered by
Blender once per session: a 4-camera ring at 160 x 120, three capture times.
"""

import os

import pytest

bpy = pytest.importorskip("bpy")

import clothfit  # noqa: E402
from clothfit.blender import registration  # noqa: E402


def ensure_registered():
    if not registration.is_registered():
        clothfit.register()


@pytest.fixture()
def factory():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    ensure_registered()
    yield bpy.context.scene
    bpy.ops.wm.read_factory_settings(use_empty=True)


def small_settings(scene, capture_dir=None):
    """A quick scene: ring of 4 cameras at 160 x 120, 3 capture times, short settling."""
    p = scene.clothfit
    p.rig_source = "RING"
    p.ring_cameras = 4
    p.ring_elevation = 30.0
    p.ring_distance = 0.5
    p.ring_fx = 250.0
    p.ring_width, p.ring_height = 160, 120
    p.frame_times = "0.1:0.3:0.1"
    p.settle_time = 0.3
    p.noise = 0.0
    p.train_cameras = 2
    p.train_times = "ALL"
    p.max_evaluations = 40
    if capture_dir:
        p.capture_dir = str(capture_dir)
    return p


@pytest.fixture(scope="session")
def small_capture(tmp_path_factory):
    """Directory of a Blender-rendered capture (small_settings), made once per session."""
    root = tmp_path_factory.mktemp("blender_capture") / "cap"
    bpy.ops.wm.read_factory_settings(use_empty=True)
    ensure_registered()
    scene = bpy.context.scene
    small_settings(scene, root)
    for op in ("build_rig", "build_cloth", "simulate", "render_silhouettes"):
        assert getattr(bpy.ops.clothfit, op)() == {"FINISHED"}
    bpy.ops.wm.read_factory_settings(use_empty=True)
    assert os.path.isfile(root / "capture.json")
    return root


def addon_preferences():
    """The add-on's preferences in this session. From a checkout the add-on is not enabled through
    Blender's add-on list, so its entry is added (as enabling does) under the module name the
    preferences class is registered for; a factory reset removes it again."""
    from clothfit.blender import prefs

    addons = bpy.context.preferences.addons
    if addons.get(prefs.ADDON_NAME) is None:
        addons.new().module = prefs.ADDON_NAME
    return addons[prefs.ADDON_NAME].preferences


def run_error(op, **kw):
    """Run ``bpy.ops.clothfit.<op>`` expecting an ERROR report; return its message."""
    with pytest.raises(RuntimeError) as ei:
        getattr(bpy.ops.clothfit, op)(**kw)
    msg = str(ei.value)
    assert "Traceback" not in msg, msg
    assert msg.startswith("Error: "), msg
    return msg


ICONS = {i.identifier for i in bpy.types.UILayout.bl_rna.functions["prop"].parameters["icon"].enum_items}


class FakeLayout:
    """Records what a panel draws; checks every property, operator, list and icon it names exists."""

    def __init__(self, log):
        self.log = log
        self.use_property_split = False
        self.enabled = True

    @staticmethod
    def _icon(kw):
        assert kw.get("icon", "NONE") in ICONS, kw["icon"]

    def prop(self, data, name, **kw):
        assert name in data.bl_rna.properties, name
        self._icon(kw)
        self.log.append(("prop", name))

    def operator(self, idname, **kw):
        mod, op = idname.split(".")
        getattr(getattr(bpy.ops, mod), op).get_rna_type()
        self._icon(kw)
        self.log.append(("operator", idname))

    def label(self, text="", **kw):
        self._icon(kw)
        self.log.append(("label", text))

    def template_list(self, listtype, list_id, data, propname, active_data, active_propname, **kw):
        ul = getattr(bpy.types, listtype)
        assert propname in data.bl_rna.properties and active_propname in active_data.bl_rna.properties
        params = [q.identifier for q in ul.bl_rna.functions["draw_item"].parameters]
        assert params[-2:] == ["index", "flt_flag"]
        for i, item in enumerate(getattr(data, propname)):  # draw the rows as Blender does: every argument
            ul.draw_item(None, bpy.context, self, data, item, 0, active_data, active_propname, i, 0)
        self.log.append(("list", listtype))

    def prop_search(self, data, name, search_data, search_name, **kw):
        assert name in data.bl_rna.properties and search_name in search_data.bl_rna.properties, name
        assert getattr(search_data.bl_rna.properties[search_name], "type", "") == "COLLECTION", search_name
        self._icon(kw)
        self.log.append(("prop", name))

    def row(self, **kw):
        return self

    column = box = row
