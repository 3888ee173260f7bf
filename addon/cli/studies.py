"""The studies: paper (the paper's protocol), tables, bench, identifiability, occlusion, and rig."""

from __future__ import annotations

from ..core import defaults as D
from ..core.errors import ClothFitError
from .common import Text, add_command, farm_args, floats, force_arg, name_list, refuse_existing, res
from .progress import study_progress


def cmd_paper(a):
    from ..core.studies.experiment import run_paper

    refuse_existing(a.json, a.force, "--json")
    if a.workers is not None or a.address is not None:
        return _paper_parallel(a)
    return run_paper(
        a.json,
        quick=a.quick,
        out_dir=a.out,
        seed=a.seed,
        optimizer=a.optimizer,
        max_evaluations=a.max_evaluations,
        only=a.only,
        truth_dt_safety=a.truth_dt_safety,
        population=a.population,
        children=a.children,
        rig=a.rig,
        progress=study_progress(),
    )


def _paper_parallel(a):
    """``paper --workers N / --address``: the protocol's parts as tasks on Ray (or spawned processes)."""
    from ..core.jsonio import write_json
    from ..core.studies.experiment import format_tables
    from ..farm.tasks import PAPER_PARTS, paper_parts

    parts = [p for p in (a.only or ",".join(PAPER_PARTS)).split(",") if p]
    bad = [p for p in parts if p not in PAPER_PARTS]
    if bad:
        raise ClothFitError(f"--only: unknown part(s) {', '.join(bad)} (parts: {', '.join(PAPER_PARTS)})")
    if a.workers is not None and a.workers < 1:
        raise ClothFitError(f"--workers {a.workers}: must be at least 1")
    kw = {
        "quick": a.quick,
        "seed": a.seed,
        "optimizer": a.optimizer,
        "max_evaluations": a.max_evaluations,
        "truth_dt_safety": a.truth_dt_safety,
        "population": a.population,
        "children": a.children,
        "rig": a.rig,
    }
    out = paper_parts(parts, a.out, kw, a.workers, a.address, a.executor)
    write_json(a.json, out, strict=True)
    print(format_tables(out))
    print(
        f"{len(parts)} part(s) on {out['workers']} {out['executor']} worker(s) in {out['total_seconds']:.1f} s; wrote {a.json}"
    )
    return out


def cmd_tables(a):
    from ..core.jsonio import read_json
    from ..core.studies.experiment import format_tables

    return Text(format_tables(read_json(a.json, "paper JSON")))  # text tables by design (the JSON is the file itself)


def cmd_bench(a):
    from ..core.studies.bench import run_bench
    from ..farm.bench import bench_blender_workers

    refuse_existing(a.json, a.force, "--json")
    return run_bench(
        a.json,
        quick=a.quick,
        only_blender_workers=a.blender_workers,
        only_default_fit=a.default_fit,
        blender_workers=bench_blender_workers,
        progress=study_progress(),
    )


def cmd_identifiability(a):
    from ..core.studies.identifiability import MATERIALS, run

    refuse_existing(a.json, a.force, "--json")
    mats = name_list(a.materials)
    bad = [m for m in mats or [] if m not in MATERIALS]
    if bad:
        raise ClothFitError(f"--materials: unknown {', '.join(bad)} (known: {', '.join(MATERIALS)})")
    return run(a.json, mats)


def cmd_occlusion(a):
    from ..core.studies.occlusion import run_occlusion

    refuse_existing(a.json, a.force, "--json")
    return run_occlusion(
        a.json,
        out_dir=a.out,
        quick=a.quick,
        n_train=a.train_cameras,
        evaluations=a.max_evaluations,
        seed=a.seed,
        resolution=res(a.resolution),
        scales=floats(a.scales, "--scales"),
        truth_dt_safety=a.truth_dt_safety,
    )


def cmd_rig(a):
    from ..core.observation.camera import load_rig, spread_order

    cams = load_rig(a.rig)
    order = spread_order(cams)
    print(f"{len(cams)} cameras; training order (spread rule): {[cams[i].name for i in order]}")
    return {
        "rig": a.rig,
        "cameras": [c.name for c in cams],
        "training_order": [cams[i].name for i in order],
        "resolution": [cams[0].height, cams[0].width] if cams else None,
    }


def _add_paper(sub):
    """``paper``, ``tables``, ``bench``."""
    s = add_command(
        sub,
        "paper",
        cmd_paper,
        "the paper's Table 1, Fig. 8 and Table 2 protocol",
        "every table and figure as JSON (the same as --json)",
    )
    s.add_argument("--json", required=True, help="write the tables and every figure to this JSON file")
    force_arg(s, "--json")
    s.add_argument(
        "--out", default="out/paper", help="folder for the captures, fits and overlays (default: %(default)s)"
    )
    s.add_argument(
        "--quick", action="store_true", help="a smaller protocol: 700 evaluations per fit, fewer cameras and seeds"
    )
    s.add_argument("--seed", type=int, default=0, help="random seed of the captures and fits (default: %(default)s)")
    s.add_argument("--optimizer", default=None, help=f"cma-es or spx-mgg (default: {D.DEFAULT_OPTIMIZER})")
    s.add_argument("--max-evaluations", type=int, default=None, help="budget of each fit (default: 2500, --quick 700)")
    s.add_argument("--only", default=None, help="comma list of parts: table1, fig8, table2, optimizers (default: all)")
    s.add_argument(
        "--population",
        type=int,
        default=None,
        help="optimiser population; GA: the MGG population (default: the optimiser's, see fit --help)",
    )
    s.add_argument("--children", type=int, default=None, help="GA: SPX children per family (default: 5n = 15)")
    s.add_argument("--rig", default=None, help=f"camera rig preset (default: {D.DEFAULT_RIG})")
    farm_args(
        s,
        "paper",
        workers_help="run the parts (table1, fig8, table2, optimizers) in parallel on this many workers "
        "(default: one after the other in this process)",
        address_help="run the parts on a running Ray cluster (auto, ray://host:port)",
        executor_help="with --workers / --address: Ray actors or spawned processes; auto = Ray when "
        "installed (default: %(default)s)",
    )
    s.add_argument(
        "--truth-dt-safety",
        type=float,
        default=None,
        help="time-step factor of the ground truth (default: the model's own; 0.125 = 4x finer truth, "
        "i.e. a model mismatch the fit cannot remove)",
    )

    s = add_command(
        sub,
        "tables",
        cmd_tables,
        "print the tables of a `paper` JSON again",
        "text tables (the one text command: the JSON is the file itself)",
    )
    s.add_argument("json", help="a JSON written by `paper --json`")

    s = add_command(sub, "bench", cmd_bench, "speed figures", "every figure as JSON (the same as --json)")
    s.add_argument("--json", required=True, help="write every figure to this JSON file")
    force_arg(s, "--json")
    s.add_argument(
        "--quick",
        action="store_true",
        help="shorter fits: 700 evaluations instead of 2500 (the blender model's fit 600 instead of 3000)",
    )
    s.add_argument(
        "--blender-workers",
        action="store_true",
        help="only Blender's solver as the fit's evaluator: evaluations/s with 1 and 2 Ray workers, "
        "Ray's start-up cost (needs bpy and ray)",
    )
    s.add_argument(
        "--default-fit",
        action="store_true",
        help="only the time to answer: the default fit of a 21 x 21 cloth, 4 cameras x 15 frames at "
        "480 x 640, quality chosen and the manipulation's unknowns estimated (target 3 minutes)",
    )


def _add_others(sub):
    """``identifiability``, ``occlusion``, ``rig``."""
    s = add_command(
        sub,
        "identifiability",
        cmd_identifiability,
        "which Blender cloth settings silhouettes can identify (sensitivity and Cramer-Rao table)",
        "the tables as JSON",
    )
    s.add_argument("--materials", help="comma list: default, silk, denim (default: all)")
    s.add_argument("--json", help="also write the tables to this file")
    force_arg(s, "--json")

    s = add_command(
        sub,
        "occlusion",
        cmd_occlusion,
        "study: a post and a hand hiding the cloth, as ignore masks vs as background",
        "the study's table as JSON (the same as --json)",
    )
    s.add_argument("--json", required=True, help="write the study to this JSON file")
    force_arg(s, "--json")
    s.add_argument("--out", default="out/occlusion", help="where the three captures are written (default: %(default)s)")
    s.add_argument("--quick", action="store_true", help="240x320, 700 evaluations")
    s.add_argument(
        "--train-cameras",
        type=int,
        default=4,
        help="cameras each fit trains on, by the spread rule (default: %(default)s)",
    )
    s.add_argument(
        "--scales",
        default="1,1.33,1.67",
        help="occluder sizes, x (post 15 %% of the cloth width, hand 12 %%) (default: %(default)s)",
    )
    s.add_argument(
        "--truth-dt-safety",
        type=float,
        default=None,
        help="time-step factor of the truth; 0.125 = 4x finer than the fitter: a model mismatch "
        "(default: the fitter's own)",
    )
    s.add_argument("--max-evaluations", type=int, default=None, help="budget of each fit (default: 2000, --quick 700)")
    s.add_argument("--resolution", help="HxW [px] (default: the rig's 480x640; --quick 240x320)")
    s.add_argument("--seed", type=int, default=0, help="random seed of the captures and fits (default: %(default)s)")

    s = add_command(
        sub,
        "rig",
        cmd_rig,
        "show a rig preset and its training-camera order",
        "the camera names and their training order as JSON",
    )
    s.add_argument(
        "rig",
        nargs="?",
        default=D.DEFAULT_RIG,
        help="a preset of rigs/ (lab18, lab18_far, ring8) or a cameras JSON (default: %(default)s)",
    )


def register(sub):
    """The studies family, in the order of ``--help``."""
    _add_paper(sub)
    _add_others(sub)
