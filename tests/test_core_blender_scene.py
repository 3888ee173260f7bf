"""``core/physics/blender_scene``: a scene's cloth as the core blender model runs it (no Blender).
Its agreement with Blender's own solver: tests/test_blender_user_scenes.py."""

import numpy as np
import pytest
from clothfit.core.errors import ClothFitError
from clothfit.core.physics import blender as B
from clothfit.core.physics.blender_scene import SceneCloth, grid_order, world_f32
from clothfit.core.physics.models import BlenderModel
from clothfit.core.physics.scenario import ClothGrid, Handle, Scenario


def test_world_f32_is_blenders_float32_transform():
    M = np.array([[0.0, -0.3, 0.0, 0.1], [0.3, 0.0, 0.0, -0.2], [0.0, 0.0, 0.3, 1.0], [0, 0, 0, 1]])
    X = np.array([[1.0, -1.0, 0.0], [0.125, 0.7, 0.0]])
    W = world_f32(M, X)
    f = np.float32
    x, y, z = f(0.125), f(0.7), f(0.0)
    r0 = ((x * f(0.0) + y * f(-0.3)) + f(0.0) * z) + f(0.1)
    assert W[1, 0] == float(r0) and W.dtype == np.float64
    assert np.allclose(W, X @ M[:3, :3].T + M[:3, 3], atol=1e-6)
    assert np.array_equal(W.astype(np.float32).astype(np.float64), W)  # float32 values


def test_grid_order_finds_a_users_numbering():
    grid = ClothGrid(5, 4, 0.4, height=1.0, side_y=0.3)
    rng = np.random.default_rng(0)
    perm = rng.permutation(grid.n_vertices)
    mesh = grid.rest[perm]  # mesh vertex k is grid vertex perm[k]
    p = grid_order(mesh + 1e-9, grid)
    assert np.array_equal(mesh[p], grid.rest)
    assert grid_order(mesh[:-1], grid) is None  # another vertex count
    off = mesh.copy()
    off[3, 0] += 0.01  # a vertex between grid points
    assert grid_order(off, grid) is None
    assert grid_order(grid.rest + [0.5, 0, 0], grid) is None  # moved off the grid


def _scene(grid, release_frame=4, n=10):
    """A scene cloth equal to the core's own grid scenario (a corner released after release_frame)."""
    faces = grid.quads.tolist()
    hv = np.array(grid.corners())
    W = np.ones((n + 1, 4))
    W[release_frame + 1 :, 0] = 0.0
    T = np.repeat(grid.rest[hv][None], n + 1, 0)
    s = B.check_settings({"time_scale": B.physical_time_scale(24)})
    net = B.Network.from_mesh(grid.rest, faces)
    return SceneCloth(
        grid.rest.astype(np.float32).astype(np.float64),
        faces,
        net.edges,
        net.triangles,
        hv,
        W,
        T,
        s,
        np.array([0, 0, -9.81]),
        24.0,
        1,
        {"object": "test"},
    )


def test_scene_cloth_on_our_own_grid_is_the_blender_model():
    """A scene reading of the core's own grid gives the core model's own motion, bit for bit."""
    grid = ClothGrid(6, 6, 0.1, height=0.0)
    sc = _scene(grid)
    times = np.arange(1, 7) / 24.0
    hs = [Handle(v, [0.0], grid.rest[v][None], 0.0 if v == 0 else None) for v in grid.corners()]
    scen = Scenario(grid, hs, times, 4 / 24.0)
    want = BlenderModel(24, 5).simulate(scen, sc.settings_row()[None]).positions[0]
    got, codes = sc.simulate()
    assert codes[0] == 0
    assert np.array_equal(got[0, 5:11], want)
    # the released corner falls, the network keeps the mesh's edge order
    assert np.linalg.norm(got[0, -1, 0] - got[0, 0, 0]) > 1e-3
    assert np.array_equal(sc.network().edges, sc.edges)


def test_scene_cloth_plan_and_errors(tmp_path):
    grid = ClothGrid(4, 4, 0.1)
    sc = _scene(grid, n=6)
    pl = sc.plan([1.0, 2.5, 6.0], release_frame=3)
    assert pl.lo.tolist() == [1, 2, 6] and pl.hi.tolist() == [1, 3, 6] and pl.w.tolist() == [0.0, 0.5, 0.0]
    assert pl.between == 1 and pl.release_frame == 3
    with pytest.raises(ClothFitError, match="outside the 6 frames"):
        sc.plan([6.5])
    rows = np.stack([sc.settings_row(), sc.settings_row(time_scale=1.0)])
    with pytest.raises(ClothFitError, match="one time_scale"):
        sc.simulate(rows)
    with pytest.raises(ClothFitError, match="tension_stiffness"):
        sc.settings_row(tension_stiffness=-1.0)


def test_scene_cloth_file_round_trip_and_bad_files(tmp_path):
    grid = ClothGrid(4, 3, 0.1, side_y=0.05)
    sc = _scene(grid, n=5)
    p = tmp_path / "s.npz"
    sc.save(p)
    back = SceneCloth.load(p)
    for k in ("rest", "edges", "triangles", "handle_vertices", "weights", "targets", "gravity"):
        assert np.array_equal(getattr(back, k), getattr(sc, k)), k
    assert back.faces == sc.faces and back.settings == sc.settings and back.info == sc.info
    assert back.fps == 24.0 and back.frame_start == 1 and back.n_frames == 5
    with pytest.raises(ClothFitError, match="file not found"):
        SceneCloth.load(tmp_path / "none.npz")
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip")
    with pytest.raises(ClothFitError, match="not a scene-cloth file"):
        SceneCloth.load(bad)
    other = tmp_path / "other.npz"
    np.savez(
        other,
        rest=np.zeros((1, 3)),
        edges=np.zeros((0, 2)),
        triangles=np.zeros((0, 3)),
        handle_vertices=np.zeros(0),
        weights=np.zeros((1, 0)),
        targets=np.zeros((1, 0, 3)),
        meta=np.array('{"format": "something else", "version": 1}'),
    )
    with pytest.raises(ClothFitError, match="is not 'silhouette-cloth-fit/scene-cloth'"):
        SceneCloth.load(other)
