"""Occluders in the Blender render path: objects of the collection 'Occluders' hide the cloth
(Eevee holdouts, Workbench black) and are written as the capture's ignore masks."""

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from blender_support import factory, small_settings  # noqa: E402,F401
from clothfit.blender import api  # noqa: E402
from clothfit.blender import render as R  # noqa: E402
from clothfit.blender import scene as S  # noqa: E402
from clothfit.core.observation.capture import load_capture  # noqa: E402
from clothfit.core.observation.raster import silhouette  # noqa: E402

pytestmark = pytest.mark.usefixtures("factory")


def add_occluders(scene):
    """A post standing through the cloth's area and a 'hand' at a corner, in the collection Occluders."""
    coll = bpy.data.collections.new(R.OCCLUDERS)
    scene.collection.children.link(coll)
    bpy.ops.mesh.primitive_cylinder_add(radius=0.008, depth=0.3, location=(0.02, -0.01, 0.05))
    post = bpy.context.object
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.012, location=(-0.05, 0.05, 0.1))
    hand = bpy.context.object
    for o in (post, hand):
        for c in list(o.users_collection):
            c.objects.unlink(o)
        coll.objects.link(o)
    return [post, hand]


@pytest.fixture()
def occluded_scene(tmp_path):
    scene = bpy.context.scene
    small_settings(scene, tmp_path / "cap")
    for op in ("build_rig", "build_cloth", "simulate"):
        assert getattr(bpy.ops.clothfit, op)() == {"FINISHED"}
    occ = add_occluders(scene)
    return scene, occ


def _cloth(scene):
    return next(o for o in scene.objects if o.type == "MESH" and o.name.startswith("ClothFit Cloth"))


def check_masks(plain, pairs):
    """Cloth lost to the occluders lies under them; cloth and occluder pixels never overlap."""
    hidden_any = 0
    for m0, (m, g) in zip(plain, pairs):
        assert not np.any(m & g)
        assert not np.any(m & ~m0)  # occluders never add cloth
        assert not np.any(m0 & ~m & ~g)  # every cloth pixel lost is under an occluder
        hidden_any += int(np.count_nonzero(m0 & g))
    assert hidden_any > 50  # the occluders do hide cloth somewhere


def test_workbench_occluders_written_as_ignore_masks(occluded_scene):
    scene, occ = occluded_scene
    assert [o.name for o in R.occluder_objects(scene)] == [o.name for o in occ]
    cloth = _cloth(scene)
    objs = S.rig_objects(scene)
    scene.frame_set(S.frame_of_time(scene, 0.2))
    plain = R.render_masks(scene, cloth, objs)
    pairs = R.render_masks(scene, cloth, objs, occluders=occ)
    check_masks(plain, pairs)
    assert tuple(cloth.color) == (1.0, 1.0, 1.0, 1.0) and tuple(occ[0].color) == (1.0, 1.0, 1.0, 1.0)  # restored
    assert scene.display.shading.color_type == "MATERIAL"
    cap = api.render_silhouettes(scene)
    assert cap.has_ignore and cap.meta["occluders"] == [o.name for o in occ]
    cap = load_capture(cap.root, validate=True)
    m, g = cap.load_observation(0, 1)
    scene.frame_set(S.frame_of_time(scene, 0.2))
    want_m, want_g = R.render_masks(scene, cloth, objs[:1], occluders=occ)[0]
    assert np.array_equal(m, want_m) and np.array_equal(g, want_g)
    from clothfit.core.fitting.evaluate import evaluate

    r = evaluate(cap, api.params_from_scene(scene).as_dict())
    assert r["silhouette_error_pct"] < 1.0


def test_eevee_holdouts_match_workbench_and_the_core(occluded_scene):
    """Eevee (one sample, zero filter) against Workbench and the core rasteriser, two cameras."""
    scene, occ = occluded_scene
    cloth = _cloth(scene)
    objs = S.rig_objects(scene)[:2]
    cams = S.rig_cameras(scene)[:2]
    scene.frame_set(S.frame_of_time(scene, 0.2))
    X = S.evaluated_positions(cloth)
    core = [silhouette(c, X, S.grid_from_object(cloth).triangles) for c in cams]
    ev_plain = R.render_masks(scene, cloth, objs, engine="EEVEE")
    for e, k in zip(ev_plain, core):
        assert np.count_nonzero(e ^ k) <= 0.01 * k.sum()
    ev = R.render_masks(scene, cloth, objs, engine="EEVEE", occluders=occ)
    wb = R.render_masks(scene, cloth, objs, occluders=occ)
    check_masks(ev_plain, ev)
    for (em, eg), (wm, wg) in zip(ev, wb):
        assert np.count_nonzero(em ^ wm) <= 0.01 * wm.sum() + 2
        assert np.count_nonzero(eg ^ wg) <= 0.01 * wg.sum() + 2
    assert not any(o.is_holdout for o in occ + [cloth])  # restored
