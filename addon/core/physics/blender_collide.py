"""Blender's cloth-object collisions as its solver applies them, for planes and boxes (``colliders.py``).

Written from the equations of Blender's ``blenkernel/intern/collision.cc`` (``cloth_bvh_collision``,
``cloth_collision``, ``cloth_collision_response_static``) and ``simulation/intern/SIM_mass_spring.cc``
(``cloth_solve_collisions``); no code copied. After the velocity solve of every step:

1. the step's new positions ``tx = x + v dt`` and motions ``tv = tx - x``;
2. every cloth triangle (not all of its corners pinned) against every triangle of every collider's
   mesh (``colliders.Collider.mesh``, quads split as Blender splits them): the contact point is the
   corner nearest the collider triangle (the corners in order, the first of equals), at its
   distance; a cloth triangle with a corner behind the collider triangle's plane (single sided,
   Blender's default) takes the corner deepest behind it whose projection falls inside it, at
   distance 0, or none (nor does a nearest corner behind the plane). The pair counts when that
   distance is within ``distance_min + distance`` and its vector is longer than sqrt(FLT_EPSILON)
   (Blender's test); the normal points from the collider to the corner;
3. two passes of impulses (``_respond``). The contact point's motion ``tv`` is its corner's, or, on a
   cloth triangle too small for Blender's barycentric weights (``_small``: sides of about 1.7 cm or
   less), the mean of its three corners', the impulse then shared by the three. Against an
   approaching motion ``m = -tv . n > 0``: ``n m / 1.5`` and a Coulomb friction impulse
   ``min(friction m / 100, |tangential motion|) / 1.5`` against the tangential motion, and when
   ``m < 0.1 d / dt`` (``d = 8/9 (distance_min + distance) - distance``) a repulsion on all three
   corners; a receding point within ``d`` gets ``d dt / 4.5``. A vertex keeps, per axis, the
   largest impulse of its pairs; the impulses are added to ``tv`` and to the collision velocity;
4. the positions ``tx = x + tv`` of the free vertices; steps 2-4 again, ``collision_quality`` rounds
   in all, while there is a contact;
5. the free vertices' velocities ``v += dcvel / dt``; the solver then moves ``x += v dt``.

Differences from Blender: a contact is always at a cloth triangle's corner, never on one of its
edges or where a collider's corner or edge meets it (Blender's edge-edge and corner contacts matter at
a box's edges and corners); the broad phase is the exact test every round. The collider is static.
"""

from __future__ import annotations

import math

import numpy as np

from .jit import JIT, njit

CJIT = dict(JIT, error_model="numpy")  # no zero-division checks: every division here is by a positive length

F32 = np.float32
EPS = F32(1.1920928955078125e-07)  # FLT_EPSILON: Blender's ALMOST_ZERO
ZERO = F32(0.0)
ONE = F32(1.0)
C15 = F32(1.5)
C45 = F32(4.5)
TENTH = F32(0.1)
HUNDREDTH = F32(0.01)
EIGHT_NINTHS = F32(8.0 / 9.0)
FIVE = F32(5.0)
THIRD = F32(1.0 / 3.0)
EPS64 = float(EPS)


@njit(inline="always", **CJIT)
def _closest(col, c, px, py, pz, out):
    """A point against the collider triangle ``col[c]``: ``out[0]`` its signed distance from the
    triangle's plane, ``out[1:4]`` the point minus its nearest point on the triangle, ``out[4]`` that
    vector's squared length, ``out[5]`` 1 when the nearest point is inside the triangle (the point's
    projection: Blender's ray along the normal hits it). Ericson's closest point on a triangle, as
    Blender's closest_on_tri_to_point_v3."""
    ax, ay, az = col[c, 0], col[c, 1], col[c, 2]
    abx, aby, abz = col[c, 3] - ax, col[c, 4] - ay, col[c, 5] - az
    acx, acy, acz = col[c, 6] - ax, col[c, 7] - ay, col[c, 8] - az
    apx, apy, apz = px - ax, py - ay, pz - az
    out[0] = apx * col[c, 9] + apy * col[c, 10] + apz * col[c, 11]
    out[5] = ZERO
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    qx, qy, qz = ax, ay, az
    if d1 > ZERO or d2 > ZERO:
        bpx, bpy, bpz = px - col[c, 3], py - col[c, 4], pz - col[c, 5]
        d3 = abx * bpx + aby * bpy + abz * bpz
        d4 = acx * bpx + acy * bpy + acz * bpz
        cpx, cpy, cpz = px - col[c, 6], py - col[c, 7], pz - col[c, 8]
        d5 = abx * cpx + aby * cpy + abz * cpz
        d6 = acx * cpx + acy * cpy + acz * cpz
        vc = d1 * d4 - d3 * d2
        vb = d5 * d2 - d1 * d6
        va = d3 * d6 - d5 * d4
        if d3 >= ZERO and d4 <= d3:
            qx, qy, qz = col[c, 3], col[c, 4], col[c, 5]
        elif vc <= ZERO and d1 >= ZERO and d3 <= ZERO:
            v = d1 / (d1 - d3)
            qx, qy, qz = ax + v * abx, ay + v * aby, az + v * abz
        elif d6 >= ZERO and d5 <= d6:
            qx, qy, qz = col[c, 6], col[c, 7], col[c, 8]
        elif vb <= ZERO and d2 >= ZERO and d6 <= ZERO:
            w = d2 / (d2 - d6)
            qx, qy, qz = ax + w * acx, ay + w * acy, az + w * acz
        elif va <= ZERO and (d4 - d3) >= ZERO and (d5 - d6) >= ZERO:
            w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
            qx = col[c, 3] + w * (col[c, 6] - col[c, 3])
            qy = col[c, 4] + w * (col[c, 7] - col[c, 4])
            qz = col[c, 5] + w * (col[c, 8] - col[c, 5])
        else:
            denom = ONE / (va + vb + vc)
            v = vb * denom
            w = vc * denom
            qx, qy, qz = ax + abx * v + acx * w, ay + aby * v + acy * w, az + abz * v + acz * w
            out[5] = ONE
    out[1] = px - qx
    out[2] = py - qy
    out[3] = pz - qz
    out[4] = out[1] * out[1] + out[2] * out[2] + out[3] * out[3]


@njit(**CJIT)
def _contacts(tx, free, tris, col, pair_t, pair_k, pair_c, pair_n, pair_d, s, sv):
    """The contact pairs (cloth triangle, collider triangle) at positions ``tx`` (3V,): their count (the
    pair arrays filled from 0). ``sv`` (V, 6): each vertex's ``_closest`` for the collider triangle
    at hand."""
    n = 0
    T = tris.shape[0]
    V = sv.shape[0]
    for c in range(col.shape[0]):
        reach = col[c, 14] + col[c, 12] + EPS
        near = False
        for v in range(V):
            _closest(col, c, tx[3 * v], tx[3 * v + 1], tx[3 * v + 2], s)
            for j in range(6):
                sv[v, j] = s[j]
            near = near or abs(s[0]) <= reach
        if not near:
            continue
        for t in range(T):
            i0, i1, i2 = tris[t, 0], tris[t, 1], tris[t, 2]
            if free[i0] == ZERO and free[i1] == ZERO and free[i2] == ZERO:
                continue
            lo = min(sv[i0, 0], min(sv[i1, 0], sv[i2, 0]))
            hi = max(sv[i0, 0], max(sv[i1, 0], sv[i2, 0]))
            if lo > reach or hi < -reach:  # the broad phase: the triangle's slab apart from the collider's
                continue
            best = -1
            dist = ZERO
            if lo < ZERO:  # Blender's back side: the corner deepest behind the triangle (its ray hits it)
                for k in range(3):
                    v = tris[t, k]
                    if sv[v, 5] != ZERO and -sv[v, 0] > dist:
                        best, dist = k, -sv[v, 0]
            if best >= 0:
                b0, b1, b2 = col[c, 9], col[c, 10], col[c, 11]
                d = ZERO
            else:  # the corner nearest the triangle; none when it lies behind (single sided)
                for k in range(3):
                    v = tris[t, k]
                    if best < 0 or sv[v, 4] < dist:
                        best, dist = k, sv[v, 4]
                v = tris[t, best]
                d = F32(math.sqrt(dist))
                if sv[v, 1] * col[c, 9] + sv[v, 2] * col[c, 10] + sv[v, 3] * col[c, 11] < ZERO:
                    continue
                dist = d
                b0, b1, b2 = sv[v, 1] / d, sv[v, 2] / d, sv[v, 3] / d
            if d > reach or dist * dist <= EPS:
                continue
            pair_t[n] = t
            pair_k[n] = best + 3 * _small(tx, i0, i1, i2)
            pair_c[n] = c
            pair_n[n, 0] = b0
            pair_n[n, 1] = b1
            pair_n[n, 2] = b2
            pair_d[n] = d
            n += 1
    return n


@njit(inline="always", **CJIT)
def _small(tx, i0, i1, i2):
    """1 when Blender's barycentric weights of a point on the cloth triangle fall back to 1/3 each: the
    determinant ``|p1 - p3|^2 |p2 - p3|^2 - ((p1 - p3).(p2 - p3))^2`` (in double, as Blender) below
    FLT_EPSILON, i.e. twice the triangle's area under sqrt(FLT_EPSILON) m^2 (sides of about 1.7 cm or
    less), so that the contact's impulse is shared by the three corners; else 0."""
    a = 0.0
    b = 0.0
    c = 0.0
    for x in range(3):
        e1 = float(tx[3 * i0 + x]) - float(tx[3 * i2 + x])
        e2 = float(tx[3 * i1 + x]) - float(tx[3 * i2 + x])
        a += e1 * e1
        b += e1 * e2
        c += e2 * e2
    return 1 if abs(a * c - b * b) < EPS64 else 0


@njit(inline="always", **CJIT)
def _take(imp, cnt, v, i0, i1, i2):
    """Blender's cloth_collision_impulse_vert: per axis, the larger impulse in magnitude."""
    if abs(imp[3 * v]) < abs(i0):
        imp[3 * v] = i0
    if abs(imp[3 * v + 1]) < abs(i1):
        imp[3 * v + 1] = i1
    if abs(imp[3 * v + 2]) < abs(i2):
        imp[3 * v + 2] = i2
    cnt[v] += 1


@njit(**CJIT)
def _respond(tv, tris, col, n_pairs, pair_t, pair_k, pair_c, pair_n, pair_d, tm, imp, cnt, seen, rep_of, stamp):
    """One pass of cloth_collision_response_static over the pairs; True when any pair responded.

    ``pair_k`` 0..2: the contact is that corner (weight 1); 3..5: the same corner, but the contact's
    motion and impulse are shared by the three corners (weights 1/3: ``_small``). Pairs with the same
    single contact corner and collider triangle give that corner the same impulse (the motions change
    only after the pass): it is computed once (``seen[v * C + c] == stamp``, its repulsion in
    ``rep_of``), and only the repulsion of the other corners is taken again. Zero impulses are not
    taken (they change no vertex)."""
    result = False
    C = col.shape[0]
    for p in range(n_pairs):
        t, k, c = pair_t[p], pair_k[p], pair_c[p]
        shared = k >= 3
        k = k % 3
        v = tris[t, k]
        nx, ny, nz = pair_n[p, 0], pair_n[p, 1], pair_n[p, 2]
        key = v * C + c
        if not shared and seen[key] == stamp:
            rep = rep_of[key]
            if rep != ZERO:
                for j in range(3):
                    if j != k:
                        _take(imp, cnt, tris[t, j], nx * rep, ny * rep, nz * rep)
            continue
        if shared:
            i0, i1, i2 = tris[t, 0], tris[t, 1], tris[t, 2]
            rx = -(tv[3 * i0] * THIRD + tv[3 * i1] * THIRD + tv[3 * i2] * THIRD)
            ry = -(tv[3 * i0 + 1] * THIRD + tv[3 * i1 + 1] * THIRD + tv[3 * i2 + 1] * THIRD)
            rz = -(tv[3 * i0 + 2] * THIRD + tv[3 * i1 + 2] * THIRD + tv[3 * i2 + 2] * THIRD)
        else:
            rx, ry, rz = -tv[3 * v], -tv[3 * v + 1], -tv[3 * v + 2]
        mag = rx * nx + ry * ny + rz * nz
        d = (col[c, 14] + col[c, 12]) * EIGHT_NINTHS - pair_d[p]
        a0, a1, a2 = ZERO, ZERO, ZERO  # the contact point's impulse (shared by the weights)
        rep = ZERO  # every corner's repulsion
        responded = False
        if mag > ZERO:
            ux, uy, uz = rx - nx * mag, ry - ny * mag, rz - nz * mag
            ut = F32(math.sqrt(ux * ux + uy * uy + uz * uz))
            mt = min(col[c, 13] * HUNDREDTH * mag, ut)
            if mt > EPS:
                f = mt / C15 / ut
                a0, a1, a2 = ux * f, uy * f, uz * f
            imp_n = mag / C15
            a0 += nx * imp_n
            a1 += ny * imp_n
            a2 += nz * imp_n
            if mag < TENTH * d * tm and d > EPS:
                r = min(d / tm, TENTH * d * tm - mag)
                if imp_n > EPS:
                    r = min(r, FIVE * imp_n)
                rep = max(imp_n, r) / C15
            responded = True
        elif d > EPS:
            imp_n = d / tm / C45
            a0, a1, a2 = nx * imp_n, ny * imp_n, nz * imp_n
            responded = True
        if not shared:
            seen[key] = stamp
            rep_of[key] = rep
        if responded:
            result = True
            for j in range(3):
                w = THIRD if shared else (ONE if j == k else ZERO)
                i0, i1, i2 = a0 * w + nx * rep, a1 * w + ny * rep, a2 * w + nz * rep
                if i0 != ZERO or i1 != ZERO or i2 != ZERO:
                    _take(imp, cnt, tris[t, j], i0, i1, i2)
    return result


@njit(**CJIT)
def collide(X, Vel, free, tris, col, dt):
    """Blender's collision step for every lane of ``X``/``Vel`` (3V, L) float32 after the velocity solve
    (``Vel`` the new velocities, ``X`` the step's start): changes ``Vel`` of the free vertices
    (``free[v]`` 1, 0 pinned). ``col`` (C, N_COLUMNS): ``colliders.Collider.packed`` rows."""
    if col.shape[0] == 0:
        return
    V3, L = X.shape
    V = V3 // 3
    T = tris.shape[0]
    C = col.shape[0]
    rounds_max = int(col[0, 15])
    tm = ONE / dt
    tv = np.empty(V3, dtype=np.float32)
    dcv = np.zeros(V3, dtype=np.float32)
    imp = np.zeros(V3, dtype=np.float32)
    cnt = np.zeros(V, dtype=np.int64)
    pair_t = np.empty(T * C, dtype=np.int64)
    pair_k = np.empty(T * C, dtype=np.int64)
    pair_c = np.empty(T * C, dtype=np.int64)
    pair_n = np.empty((T * C, 3), dtype=np.float32)
    pair_d = np.empty(T * C, dtype=np.float32)
    s = np.empty(6, dtype=np.float32)
    sv = np.empty((V, 6), dtype=np.float32)
    seen = np.zeros(V * C, dtype=np.int64)
    rep_of = np.zeros(V * C, dtype=np.float32)
    stamp = 0
    txl = np.empty(V3, dtype=np.float32)
    for l in range(L):
        for i in range(V3):
            txl[i] = X[i, l] + Vel[i, l] * dt
            tv[i] = txl[i] - X[i, l]
            dcv[i] = ZERO
        ret = 0
        rounds = 0
        while True:
            ret2 = 0
            n = _contacts(txl, free, tris, col, pair_t, pair_k, pair_c, pair_n, pair_d, s, sv)
            if n > 0:
                for _ in range(2):
                    stamp += 1
                    if not _respond(
                        tv, tris, col, n, pair_t, pair_k, pair_c, pair_n, pair_d, tm, imp, cnt, seen, rep_of, stamp
                    ):
                        break
                    ret += 1  # Blender counts the vertices given impulses, zero ones too: here, that some were
                    for v in range(V):
                        if cnt[v] > 0:
                            for a in range(3):
                                tv[3 * v + a] += imp[3 * v + a]
                                dcv[3 * v + a] += imp[3 * v + a]
                                imp[3 * v + a] = ZERO
                            cnt[v] = 0
                ret2 += ret
                if ret2 > 0:
                    for v in range(V):
                        if free[v] != ZERO:
                            for a in range(3):
                                txl[3 * v + a] = X[3 * v + a, l] + tv[3 * v + a]
            rounds += 1
            if not (ret2 > 0 and rounds_max > rounds):
                break
        if ret > 0:
            for v in range(V):
                if free[v] != ZERO:
                    for a in range(3):
                        Vel[3 * v + a, l] = Vel[3 * v + a, l] + dcv[3 * v + a] * tm
