"""CLOTHFIT_NO_SIMD=1: the Blender kernel on the plain numba twins of the hand-written LLVM IR
(``physics/simd_plain.py``, ``blender_springs.springs_plain``) moves the cloth as the default
SIMD path does (docs/kernels.md).

Each path runs in its own process (the switch is read at import) on a 9 x 9 sheet hung by its
corners, one corner released, ten candidates (two batches of 8 lanes, the second padded) with
different settings: angular and linear bending, soft and stiff, quality 2 and 5. The tolerance is
the one the Blender-agreement tests hold the kernel to (every vertex of every frame within
0.01 mm); the figure measured is 0 (the same float32 operations in the same order).
"""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

SCRIPT = r"""
import json, sys
import numpy as np
from clothfit.core.physics import blender as B, blender_kernels as K, simd
from clothfit.core.physics.models import BlenderModel
from clothfit.core.physics.scenario import ClothGrid, Scenario, paper_scenario
grid = ClothGrid(9, 9, 0.10)
sc0 = paper_scenario(grid, frame_times=np.arange(1, 13) / 24.0)
sc = Scenario(sc0.grid, sc0.handles, sc0.frame_times, 0.25, sc0.gravity)
out = {"simd": bool(simd.ENABLED), "kernel_simd": K.simd is simd}
for quality, bending in ((5, "ANGULAR"), (2, "LINEAR")):
    rows = []
    for k in range(10):
        s = {"time_scale": B.physical_time_scale(24), "quality": quality, "bending_model": bending,
             "tension_stiffness": 5.0 + 20.0 * k, "compression_stiffness": 5.0 + 15.0 * k,
             "bending_stiffness": 0.05 + 0.3 * k, "air_damping": 0.5 + 0.3 * k}
        rows.append(B.settings_row(B.check_settings(s)))
    sim = BlenderModel(24, quality, bending).simulate(sc, np.stack(rows), backend="numba")
    out[bending] = np.asarray(sim.positions).tolist()
json.dump(out, sys.stdout)
"""


def _run(no_simd: bool) -> dict:
    env = dict(os.environ, PYTHONPATH=ROOT)
    env.pop("CLOTHFIT_NO_SIMD", None)
    if no_simd:
        env["CLOTHFIT_NO_SIMD"] = "1"
    r = subprocess.run([sys.executable, "-c", SCRIPT], cwd=ROOT, env=env, capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-2000:]
    return json.loads(r.stdout)


def test_no_simd_gives_the_same_trajectory():
    pytest.importorskip("numba")
    vec, plain = _run(False), _run(True)
    assert vec["simd"] and vec["kernel_simd"]
    assert not plain["simd"] and not plain["kernel_simd"]
    for bending in ("ANGULAR", "LINEAR"):
        a, b = np.asarray(vec[bending]), np.asarray(plain[bending])
        assert a.shape == b.shape == (10, 12, 81, 3)
        assert np.isfinite(a).all()
        # not vacuous: the candidates differ from one another by far more than the tolerance
        assert np.linalg.norm(a[0] - a[-1], axis=-1).max() * 1000 > 1.0
        d = np.linalg.norm(a - b, axis=-1) * 1000
        assert d.max() < 0.01, (bending, d.max())
