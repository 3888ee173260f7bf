"""``python -m clothfit identifiability``: which Blender cloth settings silhouettes can tell apart.

For a cloth (Blender's defaults, and presets) in the paper's scenario (the 16 x 16, 10 cm sheet
hung by its corners, one released, 15 training times over 1.5 s), the core's blender model is
differentiated by central finite differences in the log of each setting (+-5 %). With ``J`` the
change of every vertex position at every training time per unit log-setting (metres), the
Fisher information of a fit whose observations resolve positions to ``sigma`` is
``F = J^T J / sigma^2`` and the Cramer-Rao bound on the standard deviation of each log setting
is ``sqrt(diag(F^-1))``: the relative precision a perfect fit could reach (lower is better; over
100 % means the data say next to nothing). Printed per setting:

* ``mm per +10 %``: RMS vertex displacement over all frames when the setting alone grows 10 %;
* ``alone %``: the bound if only this setting were free (sensitivity);
* ``all free %``: the bound with every listed setting free together (identifiability: large
  when other settings can compensate);
* ``default set %``: the bound with the default free set (``fitting.parameters.BLENDER_FREE``).

Positions are a generous stand-in for silhouettes (an outline sees only the motion across it), so
these bounds are optimistic; their order is what chooses the free set. The mass is not listed:
scaling it with every stiffness and damping leaves the motion unchanged (tested), so it is fixed.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Sequence
from typing import Any

import numpy as np

from .. import defaults as D
from ..physics import blender as B
from ..physics.models import BlenderModel
from ..physics.scenario import Scenario, paper_scenario

CANDIDATES = (
    "tension_stiffness",
    "compression_stiffness",
    "shear_stiffness",
    "bending_stiffness",
    "tension_damping",
    "compression_damping",
    "shear_damping",
    "bending_damping",
    "air_damping",
)
MATERIALS = {
    "default": {},
    # Blender's silk preset with spring dampings of 0.5 instead of 0 (a log-derivative needs a value)
    "silk": dict(B.PRESETS["silk"], tension_damping=0.5, compression_damping=0.5, shear_damping=0.5),
    "denim": B.PRESETS["denim"],
}
SIGMA_M = 0.5e-3  # positions resolved to 0.5 mm (about one pixel of the lab18 rig at the cloth)
STEP = 0.05  # +-5 % in log


def jacobian(
    settings: dict, names: Sequence[str] = CANDIDATES, fps: float = D.BLENDER_FPS, scenario: Scenario | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """(J (N, len(names)) metres per unit log setting, base positions (F, V, 3))."""
    scenario = scenario or paper_scenario(frame_times=D.TRAIN_TIMES)
    s = B.check_settings(dict(settings, time_scale=settings.get("time_scale", B.physical_time_scale(fps))))
    model = BlenderModel(fps, s["quality"], s["bending_model"])
    base = B.settings_row(s)
    rows = [base]
    for n in names:
        k = B.FLOAT_SETTINGS.index(n)
        for sgn in (1, -1):
            r = base.copy()
            r[k] = base[k] * np.exp(sgn * STEP)
            rows.append(r)
    sim = model.simulate(scenario, np.array(rows))
    if sim.exploded.any():
        bad = [names[(i - 1) // 2] for i in np.nonzero(sim.exploded)[0] if i > 0]
        raise RuntimeError(f"identifiability: the simulation exploded around {bad or 'the base settings'}")
    X = sim.positions
    J = np.stack([(X[1 + 2 * i] - X[2 + 2 * i]).ravel() / (2 * STEP) for i in range(len(names))], 1)
    return J, X[0]


def bounds_pct(J: np.ndarray, cols: Sequence[int], sigma: float = SIGMA_M) -> list[float]:
    """Cramer-Rao relative std [%] of the log settings ``cols`` free together."""
    F = J[:, cols].T @ J[:, cols] / sigma**2
    try:
        cov = np.linalg.inv(F)
    except np.linalg.LinAlgError:
        return [float("inf")] * len(cols)
    return [100.0 * float(np.sqrt(max(c, 0.0))) for c in np.diag(cov)]


def table(material: str, settings: dict, default_free: Sequence[str], sigma: float = SIGMA_M) -> dict:
    names = list(CANDIDATES)
    J, _ = jacobian(settings, names)
    n_obs = J.shape[0] // 3
    rms10 = [1000.0 * float(np.sqrt(np.mean(J[:, i] ** 2) * 3)) * np.log(1.1) for i in range(len(names))]
    alone = [bounds_pct(J, [i], sigma)[0] for i in range(len(names))]
    allf = bounds_pct(J, list(range(len(names))), sigma)
    dcols = [names.index(n) for n in default_free]
    dset = dict(zip(default_free, bounds_pct(J, dcols, sigma)))
    rows = []
    for i, n in enumerate(names):
        rows.append(
            {
                "setting": n,
                "mm_per_10pct": rms10[i],
                "alone_pct": alone[i],
                "all_free_pct": allf[i],
                "default_set_pct": dset.get(n),
            }
        )
    return {
        "material": material,
        "settings": B.check_settings(settings),
        "sigma_mm": sigma * 1000,
        "observed_points": n_obs,
        "rows": rows,
    }


def format_table(t: dict[str, Any]) -> str:
    out = [
        f"{t['material']}: Cramer-Rao relative std of each setting (positions to {t['sigma_mm']:g} mm, "
        f"{t['observed_points']} vertex observations)",
        f"  {'setting':24s} {'mm per +10 %':>12s} {'alone %':>9s} {'all free %':>11s} {'default set %':>14s}",
    ]
    for r in t["rows"]:
        d = "-" if r["default_set_pct"] is None else f"{r['default_set_pct']:.2f}"
        out.append(
            f"  {r['setting']:24s} {r['mm_per_10pct']:12.3f} {r['alone_pct']:9.3f} {r['all_free_pct']:11.2f} {d:>14s}"
        )
    return "\n".join(out)


def run(
    json_path: str | os.PathLike | None = None,
    materials: Iterable[str] | None = None,
    echo: Callable[[str], Any] = print,
) -> list[dict[str, Any]]:
    from ..fitting.parameters import BLENDER_FREE

    out = []
    for name in materials or MATERIALS:
        s = MATERIALS[name]
        t = table(name, s, BLENDER_FREE[B.check_settings(s)["bending_model"]])
        echo(format_table(t))
        out.append(t)
    if json_path:
        from ..jsonio import write_json

        write_json(json_path, out)
    return out
