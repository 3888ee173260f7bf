"""A crop plane: the model's silhouettes leave out the part of the cloth the capture's data left out."""

import numpy as np
import pytest
from clothfit.core import defaults as D
from clothfit.core.errors import ClothFitError
from clothfit.core.fitting.objective import SilhouetteObjective
from clothfit.core.observation.camera import ring_rig
from clothfit.core.observation.raster import silhouette
from clothfit.core.physics import jit
from clothfit.core.physics.crop import CropPlane, clip_mesh
from clothfit.core.physics.models import simulate
from clothfit.core.physics.paper import Params
from clothfit.core.physics.scenario import ClothGrid, Scenario, paper_scenario


def _area(X, tris):
    a, b, c = X[tris[:, 0]], X[tris[:, 1]], X[tris[:, 2]]
    return float(np.linalg.norm(np.cross(b - a, c - a), axis=1).sum() / 2)


def _upright_grid(n=9):
    """A sheet standing up in the x-z plane: rows of vertices at heights 0.05 .. 0.15 m."""
    return ClothGrid(n, side=0.1, origin=(0.0, 0.0, 0.1), rotation=(np.pi / 2, 0.0, 0.0))


def test_a_clipped_sheet_keeps_exactly_the_area_above_an_oblique_plane():
    grid = ClothGrid(12, side=0.1, origin=(0.0, 0.0, 0.0))
    # x + y >= 0.02 keeps the part of the square [-0.05, 0.05]^2 beyond that line: a known area
    crop = CropPlane.parse({"point": [0.01, 0.01, 0.0], "normal": [1.0, 1.0, 0.0]})
    X, tris = clip_mesh(grid.rest, grid.triangles, crop)
    leg = 0.05 - (0.02 - 0.05)  # the kept part: the corner (0.05, 0.05) and the line x + y = 0.02
    assert _area(X, tris) == pytest.approx(leg * leg / 2, rel=1e-9)
    a, b, c = X[tris[:, 0]], X[tris[:, 1]], X[tris[:, 2]]
    drawn = np.linalg.norm(np.cross(b - a, c - a), axis=1) > 0  # the rest have no area and draw nothing
    assert crop.height(X[tris[drawn]].reshape(-1, 3)).min() >= -1e-12  # nothing drawn below the plane


def test_a_crop_at_a_row_of_vertices_draws_exactly_the_rows_above_it():
    grid = _upright_grid()
    cam = ring_rig((1,), (10.0,), 0.5, (0.0, 0.0, 0.1), 80, 60, 120.0, (90.0,))[0]
    z_rows = np.unique(np.round(grid.rest[:, 2], 12))
    cut = z_rows[4]
    crop = CropPlane.parse({"point": [0.0, 0.0, cut], "normal": [0.0, 0.0, 1.0]})
    keep = grid.rest[:, 2] >= cut - 1e-12
    tris_above = grid.triangles[np.all(keep[grid.triangles], axis=1)]
    cropped = silhouette(cam, grid.rest, grid.triangles, crop=crop)
    assert np.array_equal(cropped, silhouette(cam, grid.rest, tris_above))
    whole = silhouette(cam, grid.rest, grid.triangles)
    assert cropped.sum() < whole.sum() and not np.any(cropped & ~whole)


def test_no_crop_draws_the_whole_cloth_as_before():
    grid = _upright_grid()
    cam = ring_rig((1,), (10.0,), 0.5, (0.0, 0.0, 0.1), 80, 60, 120.0, (90.0,))[0]
    assert np.array_equal(
        silhouette(cam, grid.rest, grid.triangles, crop=None), silhouette(cam, grid.rest, grid.triangles)
    )


@pytest.mark.parametrize("backend", ["numpy", "numba"])
def test_the_fit_objective_scores_cropped_observations_against_the_cropped_model(backend):
    if backend == "numba" and not jit.available():
        pytest.skip("numba not importable")
    crop = CropPlane.parse({"point": [0.0, 0.0, 0.06], "normal": [0.0, 0.0, 1.0]})
    base = paper_scenario(ClothGrid(8), frame_times=[0.1, 0.2])
    cropped = Scenario(base.grid, base.handles, base.frame_times, 0.2, base.gravity, crop=crop)
    plain = Scenario(base.grid, base.handles, base.frame_times, 0.2, base.gravity)
    cams = ring_rig((3,), (20.0,), distance=0.5, target=(0.0, 0.0, 0.06), width=64, height=48, fx=90.0)
    truth = Params.from_dict(D.GT_PARAMS | {"l": 0.1 / 7})
    X = simulate(cropped, [truth]).positions[0]
    assert np.any(X[:, :, 2] < 0.06) and np.any(X[:, :, 2] > 0.06)  # the fallen corner hangs below the crop
    observed = [[silhouette(c, X[f], base.grid.triangles, crop=crop) for f in range(2)] for c in cams]
    row = np.array([[truth.m, truth.k, truth.l, truth.d]])
    e_crop = SilhouetteObjective(cropped, cams, observed, backend=backend)(row)[0]
    e_plain = SilhouetteObjective(plain, cams, observed, backend=backend)(row)[0]
    assert e_crop == 0.0
    assert e_plain > 0.1  # the whole cloth against cropped data: the part below the plane is extra


def test_a_scenario_keeps_its_crop_through_the_file_and_its_variants():
    crop = {"point": [0.0, 0.0, 0.05], "normal": [0.0, 0.0, 2.0]}
    sc = Scenario.from_dict(paper_scenario().to_dict() | {"crop": crop})
    assert sc.crop.normal == (0.0, 0.0, 1.0)
    again = Scenario.from_dict(sc.to_dict())
    assert again.crop == sc.crop
    assert sc.with_frames([0.1]).crop == sc.crop and sc.moved(0.01).crop == sc.crop
    assert "crop" not in paper_scenario().to_dict()


@pytest.mark.parametrize(
    "bad, names",
    [
        ({"point": [0, 0], "normal": [0, 0, 1]}, "point"),
        ({"point": [0, 0, 0], "normal": [0, 0, 0]}, "normal"),
        ({"point": [0, 0, float("nan")], "normal": [0, 0, 1]}, "point"),
        ({"normal": [0, 0, 1]}, "crop"),
    ],
)
def test_a_bad_crop_plane_is_one_line_naming_it(bad, names):
    with pytest.raises(ClothFitError) as e:
        CropPlane.parse(bad, "scenario crop")
    assert "\n" not in str(e.value) and names in str(e.value)
