"""The distance of real points to a fitted cloth: exact point-to-triangle distances, one-sided (points the
cloth covers, not the part of the cloth the points miss)."""

import numpy as np
from clothfit.core.observation.metrics import points_to_cloth_m
from clothfit.core.physics.scenario import ClothGrid


def test_a_point_above_a_flat_cloth_is_its_height_away_and_one_beside_it_the_distance_to_its_edge():
    g = ClothGrid(5, 5, 0.2)
    X = g.rest.copy()
    lo, hi = X.min(0), X.max(0)
    flat = int(np.argmin(hi - lo))  # the axis the rest cloth is flat along
    inside = (lo + hi) / 2
    above = inside.copy()
    above[flat] += 0.03
    side = np.argmax(hi - lo)
    beside = inside.copy()
    beside[side] = hi[side] + 0.04
    d = points_to_cloth_m(np.array([inside, above, beside]), X, g.triangles)
    assert np.allclose(d, [0.0, 0.03, 0.04], atol=1e-12)


def test_it_is_the_nearest_point_of_any_triangle_checked_against_a_dense_sampling():
    rng = np.random.default_rng(3)
    X = rng.normal(size=(6, 3))
    T = np.array([[0, 1, 2], [1, 3, 4], [0, 2, 5], [2, 4, 5]])
    P = rng.normal(size=(200, 3)) * 2
    d = points_to_cloth_m(P, X, T)
    u = np.linspace(0.0, 1.0, 201)
    U, V = np.meshgrid(u, u)
    keep = U + V <= 1.0
    U, V = U[keep], V[keep]
    brute = np.full(len(P), np.inf)
    for a, b, c in X[T]:
        S = a + U[:, None] * (b - a) + V[:, None] * (c - a)
        brute = np.minimum(brute, np.sqrt(((P[:, None] - S[None]) ** 2).sum(-1)).min(1))
    assert np.all(d <= brute + 1e-12)  # never farther than a point of the mesh
    assert np.max(brute - d) < 0.02  # and the sampling's spacing close to the nearest one


def test_an_exploded_cloth_is_infinitely_far():
    g = ClothGrid(3, 3, 0.1)
    X = g.rest.copy()
    X[0] = np.nan
    assert np.isinf(points_to_cloth_m(np.zeros((2, 3)), X, g.triangles)).all()


def test_the_points_scatter_is_their_noise_about_the_surface_and_not_its_curvature():
    """Points on a plane with noise of sigma along its normal scatter by sigma sqrt(2/pi) on average; noise-free
    points on a cloth bent round a 10 cm cylinder (the density of a real lift) scatter by a fifth of that at most."""
    from clothfit.core.observation.metrics import points_scatter_m

    rng = np.random.default_rng(4)
    n, sigma = 3000, 0.001
    flat = np.c_[rng.uniform(-0.14, 0.14, (n, 2)), sigma * rng.standard_normal(n)]
    got = points_scatter_m(flat).mean()
    assert abs(got / (sigma * np.sqrt(2 / np.pi)) - 1.0) < 0.15, got
    a, y = rng.uniform(-1.4, 1.4, n), rng.uniform(-0.14, 0.14, n)
    bent = np.c_[0.1 * np.sin(a), y, 0.1 * np.cos(a)]
    assert points_scatter_m(bent).mean() < 0.2 * sigma
    assert points_scatter_m(flat[:3]).tolist() == [0.0, 0.0, 0.0]
