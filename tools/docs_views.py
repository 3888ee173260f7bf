"""Generated blocks of the docs (``<!--gen VIEW-->`` ... ``<!--/gen-->``): view name -> function.

Each function gets ``recording(name)`` (the parsed docs/figures/NAME.json) and returns the block's
Markdown. Where a command prints the same table, the view calls the command's own formatter.
"""

from __future__ import annotations

import os
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
for _d in (ROOT, os.path.join(ROOT, "tools"), os.path.join(ROOT, "lab")):
    if _d not in sys.path:
        sys.path.insert(0, _d)


def _data(recording, name):
    rec = recording(name)
    if rec is None:
        raise KeyError(f"no recording docs/figures/{name}.json")
    return rec["data"]


def _provenance(recording, name):
    rec = recording(name)
    return f"`{rec['command']}`, commit {rec['commit']}{' + uncommitted changes' if rec.get('dirty') else ''}"


def identifiability_default(recording):
    from clothfit.core.studies.identifiability import format_table

    t = next(x for x in _data(recording, "identifiability") if x["material"] == "default")
    return "```\n" + format_table(t) + "\n```"


def blender_agreement(recording):
    d = _data(recording, "blender_agreement")
    out = [
        f"{d['grid']} x {d['grid']} sheet, 10 cm, hung by its corners, {d['settle_s']:g} s settle, one corner "
        f"released, {d['after_s']:g} s after, {d['fps']:g} fps: the core's blender model against Blender "
        f"{d.get('blender', '(version not recorded)')}:",
        "",
        "| case | quality | mean mm | max mm | equal frames | core s | Blender s |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in d["cases"]:
        out.append(
            f"| {r['case']} | {r['settings']['quality']} | {r['mean_mm']:.6f} | {r['max_mm']:.6f} | "
            f"{r['exactly_equal_frames']}/{r['frames']} | {r['core_s']:.2f} | {r['blender_s']:.2f} |"
        )
    worst_mean = max(r["mean_mm"] for r in d["cases"])
    worst_max = max(r["max_mm"] for r in d["cases"])
    out += ["", f"Worst case: mean {worst_mean:.6f} mm, max {worst_max:.6f} mm (goal: mean < 0.1 mm, max < 1 mm)."]
    return "\n".join(out)


def blender_agreement_drag(recording):
    """The same cases with a table: the cloth dropped onto it and one corner dragged along it."""
    d = _data(recording, "blender_agreement_drag")
    out = [
        f"{d['grid']} x {d['grid']} sheet, 10 cm, held flat by its corners, {d['settle_s']:g} s settle, dropped onto a "
        f"table and one corner dragged along it, {d['after_s']:g} s after, {d['fps']:g} fps: the core's blender model "
        f"with the table against Blender {d.get('blender', '(version not recorded)')} with a Collision object:",
        "",
        "| case | quality | mean mm | max mm | mean mm after the drop | equal frames |",
        "|---|---|---|---|---|---|",
    ]
    for r in d["cases"]:
        out.append(
            f"| {r['case']} | {r['settings']['quality']} | {r['mean_mm']:.2f} | {r['max_mm']:.1f} | "
            f"{r['mean_mm_after_release']:.2f} | {r['exactly_equal_frames']}/{r['frames']} |"
        )
    return "\n".join(out)


def cross_simulator(recording):
    from cross_simulator import format_table

    return format_table(_data(recording, "cross_simulator"))


def user_scenes(recording):
    from user_scenes import format_table

    return format_table(_data(recording, "user_scenes"))


def user_scenes_causes(recording):
    from user_scenes import format_causes

    return format_causes(_data(recording, "user_scenes"))


def demo_parameters(recording):
    d = _data(recording, "demo")["story"]
    idt, idg, idf = (d["identifiable"][k] for k in ("truth", "first_guess", "fitted"))
    ef, eg = d["identifiable_error_pct"]["fitted"], d["identifiable_error_pct"]["first_guess"]
    tr, ho, sh = d["train_E_sil_pct"], d["heldout_E_sil_pct"], d["shape_error_mm"]
    train = (
        f"{len(d['train_cameras'])} cameras x {len(d['train_times'])} times, "
        f"{d['fit_resolution'][0]} x {d['fit_resolution'][1]}"
    )
    held = (
        f"{len(d['heldout_cameras'])} cameras x {len(d['test_times'])} test times, "
        f"{d['image_size'][0]} x {d['image_size'][1]}"
    )
    rows = [
        (
            "k/m [1/s²]",
            f"{idt['k_over_m']:,.0f}",
            f"{idg['k_over_m']:,.0f} ({eg['k_over_m']:.0f} % off)",
            f"{idf['k_over_m']:,.0f} ({ef['k_over_m']:.2f} % off)",
        ),
        (
            "d/m [1/s]",
            f"{idt['d_over_m']:.4g}",
            f"{idg['d_over_m']:.4g} ({eg['d_over_m']:.0f} % off)",
            f"{idf['d_over_m']:.5g} ({ef['d_over_m']:.2f} % off)",
        ),
        (
            "l [mm]",
            f"{1000 * idt['l']:.4f}",
            f"{1000 * idg['l']:.4f} ({eg['l']:.0f} % off)",
            f"{1000 * idf['l']:.4f} ({ef['l']:.2f} % off)",
        ),
        (f"training E_sil ({train})", f"{tr['truth']:.2f} %", f"{tr['first_guess']:.1f} %", f"{tr['fitted']:.2f} %"),
        (f"held-out E_sil ({held})", f"{ho['truth']:.2f} %", f"{ho['first_guess']:.1f} %", f"{ho['fitted']:.2f} %"),
        ("shape error (held-out times)", "0", f"{sh['first_guess']:.2f} mm", f"{sh['fitted']:.3f} mm"),
    ]
    out = ["| | truth | first guess (the optimiser's start) | fitted |", "|---|---|---|---|"]
    out += [f"| {' | '.join(r)} |" for r in rows]
    return "\n".join(out)


def _rec_err(e):
    return ", ".join(f"{e[k]:.4f}" for k in ("k_over_m", "d_over_m", "l"))


def paper_table1(recording, name="paper", with_paper=True):
    rows = _data(recording, name)["table1"]
    cited = _data(recording, "cited_paper")["table1"]
    cams = [r["cameras"] for r in rows]
    out = [
        "| training cameras | " + " | ".join(str(c) for c in cams) + " |",
        "|---" * (len(cams) + 1) + "|",
        "| silhouette error [%], ours | " + " | ".join(f"{r['silhouette_error_pct']:.3f}" for r in rows) + " |",
        "| noise floor of the same images [%] | " + " | ".join(f"{r['floor_noise_only_pct']:.3f}" for r in rows) + " |",
        "| shape error [mm], ours | " + " | ".join(f"{r['shape_error_mm']:.4f}" for r in rows) + " |",
    ]
    if with_paper:
        ix = [cited["cameras"].index(c) for c in cams]
        out += [
            "| paper: silhouette error [%] | " + " | ".join(f"{cited['silhouette_pct'][i]:.3f}" for i in ix) + " |",
            "| paper: shape error [mm] | " + " | ".join(f"{cited['shape_mm'][i]:.3f}" for i in ix) + " |",
        ]
    out.append(
        "| k/m, d/m, l recovery error [%] | " + " | ".join(_rec_err(r["identifiable_error_pct"]) for r in rows) + " |"
    )
    out.append("| evaluations (converged) | " + " | ".join(str(r.get("evaluations", "-")) for r in rows) + " |")
    return "\n".join(out)


def paper_variants(recording):
    """Table 1's harder variants, one block of rows each."""
    cams = [r["cameras"] for r in _data(recording, "paper_mismatch")["table1"]]
    out = ["| variant | figure | " + " | ".join(f"{c} cam" for c in cams) + " |", "|---" * (len(cams) + 2) + "|"]

    def rows(name):
        return {r["cameras"]: r for r in _data(recording, name)["table1"]}

    def line(label, what, rs, f):
        out.append(f"| {label} | {what} | " + " | ".join(f(rs[c]) if c in rs else "-" for c in cams) + " |")

    m = rows("paper_mismatch")
    line("model mismatch", "held-out E_sil [%]", m, lambda r: f"{r['silhouette_error_pct']:.3f}")
    line("", "true parameters through the model [%]", m, lambda r: f"{r['floor_true_params_pct']:.3f}")
    line("", "shape error [mm]", m, lambda r: f"{r['shape_error_mm']:.3f}")
    line("", "k/m, d/m, l error [%]", m, lambda r: _rec_err(r["identifiable_error_pct"]).replace("0000", "00"))
    f = rows("paper_far")
    line("room-sized rig", "held-out E_sil [%]", f, lambda r: f"{r['silhouette_error_pct']:.3f}")
    line("", "noise floor [%]", f, lambda r: f"{r['floor_noise_only_pct']:.3f}")
    line("", "shape error [um]", f, lambda r: f"{1000 * r['shape_error_mm']:.1f}")
    g = rows("paper_ga")
    line("the paper's GA", "held-out E_sil [%]", g, lambda r: f"{r['silhouette_error_pct']:.3f}")
    line("", "shape error [mm]", g, lambda r: f"{r['shape_error_mm']:.2f}")
    line("", "k/m error [%]", g, lambda r: f"{r['identifiable_error_pct']['k_over_m']:.1f}")
    line("", "evaluations", g, lambda r: str(r["evaluations"]))
    return "\n".join(out)


def paper_table2(recording):
    """Silhouette error [%] with its excess over the held-out images' noise floor, the paper's
    numbers, and the shape error [um]."""
    rows = _data(recording, "paper")["table2"]
    cited = _data(recording, "cited_paper")["table2"]
    cams = cited["cameras"]
    out = [
        "| train resolution | "
        + " | ".join(f"{c} cameras (over the floor)" for c in cams)
        + " | paper "
        + " / ".join(str(c) for c in cams)
        + " | shape error "
        + " / ".join(str(c) for c in cams)
        + " [um] |",
        "|---" * (len(cams) + 3) + "|",
    ]
    for res in sorted({tuple(r["train_resolution"]) for r in rows}):
        cells, shape = [], []
        for c in cams:
            r = next(x for x in rows if tuple(x["train_resolution"]) == res and x["cameras"] == c)
            cells.append(
                f"{r['silhouette_error_pct']:.3f} (+{r['silhouette_error_pct'] - r['floor_noise_only_pct']:.3f})"
            )
            shape.append(f"{1000 * r['shape_error_mm']:.1f}")
        paper = " / ".join(f"{v:.3f}" for v in cited[f"{res[0]}x{res[1]}"])
        out.append(f"| {res[0]} x {res[1]} | " + " | ".join(cells) + f" | {paper} | {' / '.join(shape)} |")
    return "\n".join(out)


def paper_fig8(recording):
    rows = _data(recording, "paper")["fig8"]
    cams = sorted({r["cameras"] for r in rows})
    ns = sorted({r["train_shapes"] for r in rows})
    out = ["| training shapes N | " + " | ".join(str(n) for n in ns) + " |", "|---" * (len(ns) + 1) + "|"]
    for c in cams:
        by = {r["train_shapes"]: r for r in rows if r["cameras"] == c}
        out.append(
            f"| silhouette error [%], {c} camera{'s' if c > 1 else ''} | "
            + " | ".join(f"{by[n]['silhouette_error_pct']:.3f}" if n in by else "-" for n in ns)
            + " |"
        )
        out.append(
            f"| shape error [um], {c} camera{'s' if c > 1 else ''} | "
            + " | ".join(f"{1000 * by[n]['shape_error_mm']:.2f}" if n in by else "-" for n in ns)
            + " |"
        )
    return "\n".join(out)


OPT_LABELS = {
    "spx-mgg": "SPX + MGG, population 60, 30 children (textbook sizes)",
    "spx-mgg-small": "SPX + MGG, population 21, 15 children",
    "cma-es": "CMA-ES (population 7)",
}


def paper_optimizers(recording):
    o = _data(recording, "paper")["optimizers"]
    lv = o["levels_pct"]
    out = [
        "| optimiser | " + " | ".join(f"to {v:g} %" for v in lv) + " | median final | evaluations used |",
        "|---" * (len(lv) + 3) + "|",
    ]
    for opt, sm in o["summary"].items():
        cells = []
        for v in lv:
            med, reached = sm[f"median_evals_to_{v}"], sm[f"reached_{v}"]
            cells.append(f"never ({reached})" if med is None else f"{med:.0f} ({reached})")
        used = [r["evaluations"] for r in o["runs"] if r["optimizer"] == opt]
        u = f"{min(used)}" if min(used) == max(used) else f"{min(used)}-{max(used)}"
        out.append(
            f"| {OPT_LABELS.get(opt, opt)} | " + " | ".join(cells) + f" | {sm['final_E_sil_pct_median']:.3f} % | {u} |"
        )
    return "\n".join(out)


def _fmt(v, small=3):
    """A figure with the digits that matter: 0.178, 2.61, 53.3, 301."""
    return f"{v:.{small}f}" if abs(v) < 1 else f"{v:.2f}" if abs(v) < 10 else f"{v:.1f}" if abs(v) < 100 else f"{v:.0f}"


def occlusion(recording):
    d = _data(recording, "occlusion")
    c = d["clean"]
    out = [
        "| occluders (post width / hand radius, of the cloth's size in the view) | cloth hidden, mean / max | "
        "held-out E_sil: ignore masks | occluder as background | shape error: ignore / background |",
        "|---|---|---|---|---|",
        f"| none | 0 | {c['heldout_pct']:.3f} % | | {c['shape_error_mm']:.3f} mm |",
    ]
    for r in d["rows"]:
        out.append(
            f"| {100 * r['post_width']:.0f} % / {100 * r['hand_radius']:.0f} % | "
            f"{100 * r['hidden_fraction_mean']:.1f} % / {100 * r['hidden_fraction_max']:.1f} % | "
            f"{r['ignore']['heldout_pct']:.3f} % ({r['ratio_ignore']:.3f}x) | "
            f"{_fmt(r['background']['heldout_pct'])} % ({_fmt(r['ratio_background'])}x) | "
            f"{r['ignore']['shape_error_mm']:.3f} / {_fmt(r['background']['shape_error_mm'])} mm |"
        )
    return "\n".join(out)


def occlusion_variants(recording):
    """The same study with a model mismatch and with 1 or 2 training cameras: ratios to the clean fit."""
    out = [
        "| variant | clean fit | cloth hidden (mean) | ignore masks | occluders as background |",
        "|---|---|---|---|---|",
    ]
    for name, label in (
        ("occlusion_mismatch", "model mismatch (`--truth-dt-safety 0.125`)"),
        ("occlusion_quick_1cam", "1 training camera (`--quick --train-cameras 1`)"),
        ("occlusion_quick_2cam", "2 training cameras (`--quick --train-cameras 2`)"),
    ):
        d = _data(recording, name)
        hid = " / ".join(f"{100 * r['hidden_fraction_mean']:.0f} %" for r in d["rows"])
        ig = " / ".join(f"{r['ratio_ignore']:.3f}x" for r in d["rows"])
        bg = " / ".join(f"{_fmt(r['ratio_background'])}x" for r in d["rows"])
        out.append(f"| {label} | {d['clean']['heldout_pct']:.3f} % | {hid} | {ig} | {bg} |")
    return "\n".join(out)


def bench(recording):
    rec = recording("bench")
    d = rec["data"]
    nb, npy, fit, bm = d["numba"], d["numpy"], d["fit"], d.get("blender_model", {})
    t = d["targets"]
    out = [
        f"Measured on this {d['machine']['cpus']}-CPU machine, shared with other jobs (1-minute load "
        f"{d['machine']['load_average_1min_at_start']:.1f} at the start, {rec['load_1min_after']:.1f} at the end):",
        "",
        "| figure | measured | target |",
        "|---|---|---|",
        f"| candidate evaluations per second (numba kernels) | **{nb['evals_per_s']:.1f}** (CPU {nb['cpu_ms_per_eval']:.1f} ms "
        f"per evaluation: simulation {nb['sim_cpu_ms_per_eval']:.1f} ms, silhouettes "
        f"{nb['silhouette_share_of_cpu_pct']:.0f} %) | {t['evals_per_s']:.0f} |",
        f"| the numpy reference path (no numba) | {npy['evals_per_s']:.2f} evaluations per second (CPU "
        f"{npy['cpu_ms_per_eval']:.0f} ms per evaluation, {npy['cpu_ms_per_eval'] / nb['cpu_ms_per_eval']:.0f}x the "
        f"numba kernels' CPU time) | |",
        f"| whole 16-camera fit ({fit['optimizer']}, converged after {fit['evaluations']} evaluations) | "
        f"**{fit['wall_s']:.1f} s** | under {t['fit_seconds']:.0f} s |",
        f"| one checkpoint write ({d['checkpoint_bytes'] / 1000:.0f} KB, temp file + fsync + rename) | "
        f"{d['checkpoint_ms']:.1f} ms | |",
        f"| peak memory of the bench process (capture, 240 observed silhouettes, numba) | "
        f"{d['peak_memory_mb']:.0f} MB | |",
    ]
    if "evals_per_s" in bm:
        f21 = bm["fit_21x21_4cams"]
        out += [
            f"| **blender model**, same workload (16 x 16 quads, 0.5 s + 1.5 s at 24 fps, quality 5, batches of "
            f"16 on 8 vector lanes) | **{bm['evals_per_s']:.1f}** evaluations per second, CPU "
            f"{bm['cpu_ms_per_eval']:.1f} ms per evaluation (simulation {bm['sim_cpu_ms_per_eval']:.1f} ms) | "
            f"{t['evals_per_s']:.0f} |",
            f"| blender model: a 4-camera fit of a 21 x 21 cloth, default free set ({len(f21['free'])} settings), "
            f"CMA-ES, {f21['evaluations']} evaluations | {f21['wall_s']:.0f} s wall, training E_sil "
            f"{f21['best_E_sil_pct']:.2f} % | |",
        ]
    w = d.get("blender_workers", {}).get("runs", {})
    if "1" in w and "2" in w:
        out.append(
            f"| Blender's own solver as the evaluator (`--backend blender`, a 21 x 21 cloth onto a box, "
            f"{d['blender_workers']['frames_per_candidate']} frames per candidate): 1 / 2 Ray workers | "
            f"{w['1']['evals_per_s']:.1f} / {w['2']['evals_per_s']:.1f} evaluations per second "
            f"({w['2']['evals_per_s'] / w['1']['evals_per_s']:.2f}x) | 1.8x |"
        )
    return "\n".join(out)


def raster_agreement(recording, name="raster_agreement"):
    d = _data(recording, name)
    sm, rows = d["summary"], d["rows"]
    cams = {}
    for r in rows:
        cams.setdefault(r["camera"], []).append(r["xor_pct"])
    worst = max(cams, key=lambda c: sum(cams[c]) / len(cams[c]))
    out = [
        f"{sm['rig']}, {len(cams)} cameras x {sm['images'] // len(cams)} shapes = {sm['images']} images at "
        f"{sm['height']} x {sm['width']}, Blender {sm['blender']} {sm['engine'].title()}:",
        "",
        "| figure | value |",
        "|---|---|",
        f"| XOR pixels / silhouette area, all {sm['images']} images | {sm['xor_px_total']} px of "
        f"{sm['area_px_total']:,} px = **{sm['xor_pct_overall']:.4f} %** |",
        f"| per image: mean / max | {sm['xor_pct_mean']:.4f} % / {sm['xor_pct_max']:.4f} % (max {sm['xor_px_max']} "
        f"pixels) |",
        f"| images with identical silhouettes | {sm['images_with_zero_xor']} of {sm['images']} |",
        f"| worst camera (mean over its shapes) | {worst}, {sum(cams[worst]) / len(cams[worst]):.4f} % |",
        f"| time per Blender silhouette (render + PNG write/read) | {sm['blender_ms_per_silhouette']:.0f} ms |",
        f"| time per core silhouette (numpy rasteriser, same image) | {sm['core_ms_per_silhouette']:.1f} ms "
        f"({sm['blender_ms_per_silhouette'] / sm['core_ms_per_silhouette']:.0f}x faster) |",
    ]
    return "\n".join(out)


def raster_agreement_eevee(recording):
    return raster_agreement(recording, "raster_agreement_eevee")


def footage_cameras(recording):
    d = _data(recording, "footage")["auto"]
    rows = d["rows"]
    out = [
        "| camera | " + " | ".join(r["camera"].replace("cam", "") for r in rows) + " | mean |",
        "|---" * (len(rows) + 2) + "|",
        "| IoU | " + " | ".join(f"{r['iou']:.3f}" for r in rows) + f" | **{d['mean_iou']:.3f}** |",
        "| E_sil vs truth [%] | "
        + " | ".join(f"{r['e_sil_pct']:.1f}" for r in rows)
        + f" | **{d['mean_e_sil_pct']:.2f}** |",
        "| auto threshold | " + " | ".join(f"{r['threshold']:.1f}" for r in rows) + " | |",
    ]
    return "\n".join(out)


FOOTAGE_VARIANTS = [
    ("auto", "**defaults**", ""),
    ("single_plate", "one background plate (noise from the frames)", "`--single-plate`"),
    ("shadow_window_1", "per-pixel shadow factor", "`--shadow-window 1`"),
    ("no_refine", "no boundary refinement", "`--refine 0`"),
    ("otsu", "Otsu threshold", "`--threshold otsu`"),
    ("no_shadow", "no shadow model", "`--shadow-min 1`"),
    ("no_blur", "no blur", "`--blur 0`"),
    (
        "paper_recipe",
        "the paper's recipe: plain YUV difference, Otsu, no shadow model, no refinement",
        "`--threshold otsu --luma-weight 1 --shadow-min 1 --blur 0 --refine 0`",
    ),
]


def footage_variants(recording):
    d = _data(recording, "footage")
    out = ["| variant | flags | mean IoU | worst camera | E_sil vs truth [%] | warnings |", "|---|---|---|---|---|---|"]
    for key, label, flags in FOOTAGE_VARIANTS:
        v = d[key]
        out.append(
            f"| {label} | {flags} | {v['mean_iou']:.3f} | {v['min_iou']:.3f} | {v['mean_e_sil_pct']:.1f} | "
            f"{len(v['warnings'])} |"
        )
    return "\n".join(out)


def _mean(xs):
    return sum(xs) / len(xs)


def footage_fit(recording):
    d = _data(recording, "footage_fit")
    seeds = [d[k] for k in ("s0", "s1", "s2")]
    out = [
        "| training cameras | held-out E_sil vs extracted [%] | same for the true params [%] | held-out E_sil vs "
        "true masks [%] | shape error [mm] | k/m, d/m, l error [%] |",
        "|---|---|---|---|---|---|",
    ]
    for i, r0 in enumerate(seeds[0]):
        rs = [s[i] for s in seeds]
        e = {k: _mean([r["identifiable_error_pct"][k] for r in rs]) for k in ("k_over_m", "d_over_m", "l")}
        out.append(
            f"| {r0['cameras']} | {_mean([r['heldout_sil_err_vs_extracted_pct'] for r in rs]):.2f} | "
            f"{_mean([r['gt_params_heldout_sil_err_vs_extracted_pct'] for r in rs]):.2f} | "
            f"{_mean([r['heldout_sil_err_vs_true_pct'] for r in rs]):.2f} | "
            f"{_mean([r['shape_error_mm'] for r in rs]):.2f} | "
            f"{e['k_over_m']:.1f} / {e['d_over_m']:.1f} / {e['l']:.1f} |"
        )
    return "\n".join(out)


def blender_cloth_fit(recording):
    from blender_cloth_experiment import format_rows
    from clothfit.core.physics.paper import identifiable

    fit = _data(recording, "blender_cloth")["fit"]
    rows = [r for r in fit if "oracle" not in r]
    out = format_rows(rows).replace("[1/s^2]", "[1/s²]").split("\n")
    for i, r in enumerate(rows, 2):
        if len(r["heldout"]) < 3:
            out[i] = out[i].replace(
                f"| {r['heldout_sil_err_pct']:.2f} |",
                f"| {r['heldout_sil_err_pct']:.2f} ({len(r['heldout'])} held-out cameras) |",
                1,
            )
    for o in (r["oracle"] for r in fit if "oracle" in r):
        i = identifiable(o["params"])
        out.append(
            f"| *our model fitted to the true 3D shapes (oracle)* | *{o['all_cameras_sil_err_pct']:.2f} (all "
            f"cameras)* | *{o['shape_error_mm']:.2f}* | | *{i['k_over_m']:.3g}* | *{i['d_over_m']:.3g}* | "
            f"*{1000 * i['l']:.3f}* |"
        )
    return "\n".join(out)


def stopping(recording):
    d = _data(recording, "stopping")
    out = [
        "| optimiser | seed | evaluations | stopped by | best training E_sil | k/m, d/m, l error [%] |",
        "|---|---|---|---|---|---|",
    ]
    for r in d["runs"]:
        why = r["stop_reason"] + (f" ({', '.join(r['converged_by'])})" if r.get("converged_by") else "")
        out.append(
            f"| {r['optimizer']} | {r['seed']} | {r['evaluations']} | {why} | {r['best_E_sil_pct']:.4f} % | "
            f"{_rec_err(r['identifiable_error_pct'])} |"
        )
    return "\n".join(out)


def recordings(recording):
    """The table of every recording: what, command, commit, when."""
    import glob

    out = ["| recording | what | command | commit | recorded |", "|---|---|---|---|---|"]
    for p in sorted(glob.glob(os.path.join(ROOT, "docs", "figures", "*.json"))):
        name = os.path.basename(p)[:-5]
        rec = recording(name)
        if name.startswith("cited_"):
            out.append(f"| [{name}](figures/{name}.json) | citation | - | - | - |")
            continue
        cmd = rec["command"].split(" && ")
        cmd = f"`{cmd[0]}`" + (f" and {len(cmd) - 1} more" if len(cmd) > 1 else "")
        out.append(
            f"| [{name}](figures/{name}.json) | {rec.get('what', '')} | {cmd} | "
            f"{rec['commit']}{' (dirty)' if rec.get('dirty') else ''} | {rec['recorded_at'][:10]} |"
        )
    return "\n".join(out)


def fit_goals(recording):
    from fit_goals import format_table

    return format_table(_data(recording, "fit_goals"))


def floor_calibration(recording):
    from floor_calibration import table

    d = _data(recording, "floor_calibration")["calibration"]
    return table(d["synthetic"] + d["resampled"] + ([d["footage"]] if "footage" in d else []))


def _takes_table(recording, material, pairs_name):
    """One cloth's takes: each take fitted alone (takes_baseline) and pairs fitted together (``pairs_name``),
    every result scored on every take's held-out cameras and frames: held-out E_sil % / shape error mm, the takes
    a fit saw in bold; the settings its intervals leave undetermined."""
    takes = ("one_corner", "two_adjacent", "wave")
    rows = [r for r in _data(recording, "takes_baseline")["rows"] if r["material"] == material]
    rows += [r for r in _data(recording, pairs_name)["rows"] if r["material"] == material]
    fits = list(
        dict.fromkeys(r["fitted_on"] for r in rows if r["scored_on"] in takes and r["fitted_on"].split("+")[0] in takes)
    )
    out = [
        "| fitted on | " + " | ".join(t.replace("_", " ") for t in takes) + " | verdict | undetermined |",
        "|---|" + "---|" * (len(takes) + 2),
    ]
    for f in fits:
        seen = f.split("+")
        cells = []
        for t in takes:
            r = next((r for r in rows if r["fitted_on"] == f and r["scored_on"] == t), None)
            if r is None or "heldout_E_sil_pct" not in r:
                cells.append("")
                continue
            c = f"{r['heldout_E_sil_pct']:.1f} % / {r['shape_error_mm']:.1f} mm"
            cells.append(f"**{c}**" if t in seen else c)
        fit = next((r for r in rows if r["fitted_on"] == f and r.get("undetermined") is not None), None)
        undet = (
            ""
            if fit is None
            else ", ".join(n.replace("_stiffness", "").replace("_", " ") for n in fit["undetermined"]) or "none"
        )
        kind = next(
            (
                r.get("verdict_kind") or r.get("fit_verdict_kind")
                for r in rows
                if r["fitted_on"] == f and (r.get("verdict_kind") or r.get("fit_verdict_kind"))
            ),
            "",
        )
        out.append(f"| {f.replace('_', ' ').replace('+', ' + ')} | " + " | ".join(cells) + f" | {kind} | {undet} |")
    floors = {r["scored_on"]: r["floor_heldout_E_sil_pct"] for r in rows}
    out.append("| *the truth's own (floor)* | " + " | ".join(f"{floors[t]:.2f} %" for t in takes) + " | | |")
    return "\n".join(out)


def takes_cotton(recording):
    return _takes_table(recording, "cotton", "takes_pairs")


def takes_silk(recording):
    return _takes_table(recording, "silk", "takes_pairs_silk")


def _setting(r, n):
    """A real lift's fitted setting with its 90 % interval, marked when undetermined."""
    v, iv = (r.get("blender_cloth") or {}).get(n), (r.get("intervals") or {}).get(n)
    if v is None:
        return ""
    mark = " (undetermined)" if n in (r.get("undetermined") or []) else ""
    return f"{v:.3g} [{iv[0]:.3g}, {iv[1]:.3g}]{mark}" if iv else f"{v:.3g}"


def _settings(r):
    return " | ".join(_setting(r, n) for n in ("tension_stiffness", "bending_stiffness", "air_damping"))


def real_lifts(recording):
    """DiffCloud's real lifts, each trial fitted alone: held-out E_sil beside its floor (raised to the splatting's
    error the converter states), that error beside the fitted cloth's own, the real points' mean distance to the
    fitted cloth beside their own scatter, the fitted stretch of the clock, the stiffnesses with their 90 %
    intervals, the fit's time."""
    rows = _data(recording, "real_lifts")["rows"]
    out = [
        "| trial | held-out E_sil | its floor | splat error: stated / the fitted cloth's | real points to cloth "
        "(their scatter) | clock stretch | tension | bending | air damping | verdict | fit time |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        wall = f"{r['fit_elapsed_s']:.0f} s" + ("" if r.get("fit_wall_s") is None else f" (load {r['load'][0]:.1f})")
        out.append(
            f"| {r['trial']} | {r['heldout_E_sil_pct']:.1f} % | {r['heldout_floor_pct']:.1f} % "
            f"| {r['splat_floor_stated_pct']:.1f} / {r['splat_floor_pct']:.1f} % "
            f"| {r['points_mm']:.1f} mm ({r['points_scatter_mm']:.1f} mm) | {r.get('time_scale') or 1.0:.3f} "
            f"| {_settings(r)} | {r.get('verdict_kind') or ''} | {wall} |"
        )
    out.append("")
    for fabric in dict.fromkeys(r["fabric"] for r in rows):
        trials = [r for r in rows if r["fabric"] == fabric]
        names = [
            n
            for n in trials[0]["intervals"]
            if all(n in (r.get("intervals") or {}) and n in (r.get("blender_cloth") or {}) for r in trials)
        ]

        def inside(n, trials=trials):
            return all(
                a["intervals"][n][0] <= b["blender_cloth"][n] <= a["intervals"][n][1]
                for a in trials
                for b in trials
                if a is not b
            )

        agree = [n for n in names if inside(n)]
        apart = [n for n in names if not inside(n)]
        out.append(
            f"*{fabric}*: each trial's value within every other trial's interval for {', '.join(agree) or 'no setting'}; "
            f"not for {', '.join(apart) or 'any'}."
        )
        out.append("")
    return "\n".join(out).rstrip()


def real_lifts_pairs(recording):
    """DiffCloud's real lifts, per fabric two trials fitted together and the third predicted: each fitted trial's
    held-out E_sil (and alone), the third's held-out E_sil and real points predicted beside its own fit's, the
    shared settings with their 90 % intervals, the joint fit's time."""
    rows = _data(recording, "real_lifts_pairs")["rows"]
    out = [
        "| fabric | fitted together: held-out E_sil | predicted | held-out E_sil: predicted / its own fit | "
        "real points to cloth: predicted / its own fit | tension | bending | air damping | verdict | fit time |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        fitted = ", ".join(f"{t['take']} {t['heldout_E_sil_pct']:.1f} %" for t in r["takes"])
        p, a = r["third_predicted"], r["third_alone"]
        wall = f"{r['fit_elapsed_s']:.0f} s" + ("" if r.get("fit_wall_s") is None else f" (load {r['load'][0]:.1f})")
        out.append(
            f"| {r['fabric']} | {fitted} | {r['predicted']} | {p['heldout_E_sil_pct']:.1f} / {a['heldout_E_sil_pct']:.1f} % "
            f"({r['ratio_to_alone']:.2f}x) | {p['points_mm']:.1f} / {a['points_mm']:.1f} mm | {_settings(r)} "
            f"| {r.get('verdict_kind') or ''} | {wall} |"
        )
    return "\n".join(out)


VIEWS = {
    "real_lifts": real_lifts,
    "real_lifts_pairs": real_lifts_pairs,
    "blender_agreement.drag": blender_agreement_drag,
    "takes.cotton": takes_cotton,
    "takes.silk": takes_silk,
    "fit_goals": fit_goals,
    "floor_calibration": floor_calibration,
    "identifiability.default": identifiability_default,
    "blender_agreement": blender_agreement,
    "cross_simulator": cross_simulator,
    "user_scenes": user_scenes,
    "user_scenes.causes": user_scenes_causes,
    "demo.parameters": demo_parameters,
    "recordings": recordings,
    "stopping": stopping,
    "blender_cloth.fit": blender_cloth_fit,
    "footage.cameras": footage_cameras,
    "footage.variants": footage_variants,
    "footage.fit": footage_fit,
    "raster_agreement": raster_agreement,
    "raster_agreement.eevee": raster_agreement_eevee,
    "bench": bench,
    "occlusion": occlusion,
    "occlusion.variants": occlusion_variants,
    "paper.table1": paper_table1,
    "paper.table2": paper_table2,
    "paper.fig8": paper_fig8,
    "paper.variants": paper_variants,
    "paper.optimizers": paper_optimizers,
}
