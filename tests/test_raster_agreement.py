"""The core rasteriser's silhouettes vs. Blender's own renders of the same deformed cloth.

lab18 rig at 480 x 640, the paper scenario simulated by the core, baked into the mesh, rendered by
Workbench (AA off) and rasterised by ``core.observation.raster.silhouette``: XOR < 1 % of the silhouette area
for every (camera, shape). Measured figures: ``python lab/raster_agreement.py`` (docs/results.md).
"""

import numpy as np
import pytest
from blender_support import bpy, factory  # noqa: F401
from clothfit.blender import api  # noqa: E402
from clothfit.blender import render as R  # noqa: E402
from clothfit.blender import scene as S  # noqa: E402
from clothfit.core.observation.raster import silhouette  # noqa: E402

pytestmark = pytest.mark.usefixtures("factory")

CAMERAS = [0, 5, 9, 12, 16, 17]  # upper ring, lower ring, the two top cameras
TIMES = [0.0, 0.3, 0.75, 1.2]  # settled, falling, swinging


def test_core_raster_matches_blender_render():
    scene = bpy.context.scene
    p = scene.clothfit
    p.rig_source, p.rig_preset = "PRESET", "lab18"
    p.frame_times = ", ".join(str(t) for t in TIMES[1:])
    api.build_rig(scene)
    cloth = api.build_cloth(scene)
    api.simulate(scene)
    objs = S.rig_objects(scene)
    cams = S.rig_cameras(scene)
    assert S.render_size(scene) == (640, 480)
    tris = S.grid_from_object(cloth).triangles
    worst = 0.0
    total_xor = total_area = 0
    for t in TIMES:
        scene.frame_set(S.frame_of_time(scene, t))
        X = S.evaluated_positions(cloth)
        np.testing.assert_allclose(X, S.baked_positions(cloth, [t])[0], atol=1e-6)
        masks = R.render_masks(scene, cloth, [objs[i] for i in CAMERAS])
        for ci, m in zip(CAMERAS, masks):
            core = silhouette(cams[ci], X, tris)
            area = int(core.sum())
            xor = int(np.count_nonzero(core ^ m))
            assert area > 2000, (ci, t, area)
            assert xor / area < 0.01, f"camera {cams[ci].name} t={t}: XOR {xor} px of {area} px"
            worst = max(worst, xor / area)
            total_xor += xor
            total_area += area
    print(f"\nworst XOR/area {100 * worst:.4f} %, overall {100 * total_xor / total_area:.4f} %")
