"""The commands behind the figures the docs quote, and their recorded outputs (docs/figures/).

    python tools/figures.py list                      # every source: command, cost, recorded when / at which commit
    python tools/figures.py record NAME [NAME...]     # run the command, write docs/figures/NAME.json
    python tools/figures.py record NAME --from FILE   # record an output a run of that exact command already wrote
    python tools/figures.py rerun [NAME...]           # run the cheap commands again, compare with the recording
    python tools/figures.py pictures                  # copy the recorded demo run's pictures to docs/img

A *source* is one command of this repository that writes a JSON file. ``record`` runs it and writes
``docs/figures/NAME.json``: the command line, the commit it ran at (``dirty`` when addon/ or tools/
had uncommitted changes), when, how long, the machine's load, and under ``data`` the JSON the
command wrote. The docs quote those numbers (``tools/docs_check.py`` checks every quote against
them); ``rerun`` runs the cheap sources again and compares the fresh output with the recording
within each source's tolerance (timings are not compared: they depend on the machine's load).
Expensive sources (a full paper run, the 45-minute cross-simulator experiment) are recorded once
and only checked against their recording.
"""

from __future__ import annotations

import argparse
import datetime
import fnmatch
import json
import math
import os
import shlex
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
FIG_DIR = os.path.join(ROOT, "docs", "figures")
RUN_DIR = os.path.join(ROOT, "out", "figures")
FORMAT = "silhouette-cloth-fit/figures"

# Keys whose values are wall-clock or CPU times (or depend on them): never compared by ``rerun``.
TIMING = (
    "*seconds*",
    "*_s",
    "*wall*",
    "*per_s*",
    "*_ms*",
    "*time*",
    "*load*",
    "*speed*",
    "*evals_per_s*",
    "*elapsed*",
    "*memory*",
    "*ready*",
    "*init*",
)


# name -> source. ``argv``: the command ({out} = the JSON it writes, {py} = this Python);
# ``output``: the file the command writes (default {out}); ``cost``: "cheap" (seconds to a few
# minutes: ``rerun`` runs it) or "expensive"; ``rtol``/``atol``: rerun tolerance of the
# deterministic figures (a fit with a fixed seed gives the same numbers: 0); ``what``: one line.
def _phone_rig(cmd, out, seed, scale, poses, close=None):
    """The command line of a phone-rig rehearsal (lab/phone_rig.py): ``calibrate`` (the board's renders
    alone) or ``e2e`` (the whole session: 15 frames, both fits at 2500 evaluations; the renders a previous run
    of the same seed left are kept, so a pipeline change is measured again without rendering), 4 Cycles
    samples."""
    argv = ["{py}", "lab/phone_rig.py", cmd, "--out", f"out/phone_rig/{out}", "--seed", str(seed)]
    argv += ["--scale", scale, "--poses", str(poses)] + ([] if close is None else ["--close", str(close)])
    if cmd == "e2e":
        argv += ["--frames", "15", "--samples", "4", "--evals", "2500", "--uncertain-evals", "2500", "--keep-renders"]
    else:
        argv += ["--samples", "4"]
    return argv + ["--json", "{out}"]


def _spread(rig, box=None, uncertain_only=False, optimizer=None):
    """The command line of ``lab/phone_rig.py spread`` on a recorded phone rig's folder; ``box`` [m]: the
    uncertain fit alone (beside the fit given the truth) with every clip's box at that size; ``uncertain_only``:
    the uncertain fit alone (beside the fit given the truth) in the capture's own boxes; ``optimizer``: the
    uncertain fit's search (alone, beside the fit given the truth)."""
    argv = ["{py}", "lab/phone_rig.py", "spread", "--e2e", f"out/phone_rig/e2e_s{rig}"]
    if box is not None or uncertain_only or optimizer:
        argv += ["--kinds", "uncertain,truth_given"]
    if box is not None:
        argv += ["--uncertain", f"time_offset=0.033333,handles={box:g}"]
    if optimizer:
        argv += ["--optimizer", optimizer]
    return argv + ["--json", "{out}"]


def _offsets_with(*search):
    """The command line of the offsets goal with the fit's ``--search`` settings."""
    return ["{py}", "lab/fit_goals.py", "offsets"] + [x for s in search for x in ("--search", s)] + ["--json", "{out}"]


# the five exact-model captures the search's variants are judged on (docs/search.md, "Runs again"): the goal's
# (made by lab/fit_goals.py exact), fresh, damped, and a soft and a stiff cloth away from the search's centre
SEARCH_RUNS_CAPTURES = ["out/fit_goals/exact", "synth:fresh", "synth:damped", "synth:soft", "synth:stiff"]


def _search_ab_reused(strategies, *rows, captures=SEARCH_RUNS_CAPTURES, seeds="0-4", spread=None):
    """lab/search_ab.py's strategies x ``seeds`` on ``captures`` (default: seeds 0-4 on the five captures of
    search_runs): the fits of the rows files (drop --only-reused to run the missing ones); ``spread``: a recorded
    jitter spread (search_jitter_spread), the summary's seeds within its 90th percentile."""
    argv = [
        "{py}",
        "lab/search_ab.py",
        *captures,
        "--strategies",
        strategies,
        "--seeds",
        seeds,
        "--reuse",
        *rows,
        "--only-reused",
        "--json-summary",
        "{out}",
    ]
    return argv + (["--spread", spread] if spread else [])


# the search's variant "a line of bendings through the first run's end" (docs/search.md), as its recordings ran it
LINE_SEARCH = [
    "--search",
    "staged_restart_grid_rows=48",
    "--search",
    "staged_restart_grid_columns=1",
    "--search",
    "staged_restart_grid_sigma=0.02",
]


def window_cameras(*search):
    """``lab/early_window.py cameras`` as the line's recordings ran it: the time goal's capture, 4 training cameras,
    seeds 0-3, with these ``--search`` options."""
    return ["{py}", "lab/early_window.py", "cameras", "--n", "4", "--seeds", "0-3", *search, "--json", "{out}"]


# the same line with a cap on each first-stage run (docs/search.md, "A cap on the first run"), as its recordings ran it
CAP_LINE_SEARCH = [*LINE_SEARCH, "--search", "staged_run_cap=0.16"]
# that line, also tried with tension and with shear 0.01 of the cube either side of the run's end (one at a time),
# the first run cut at 0.10 of the budget so that the line's five passes fit in the share of runs again
NEAR_LINE_SEARCH = [*LINE_SEARCH, "--search", "staged_run_cap=0.1", "--search", "staged_restart_grid_near=0.01"]
# the same five passes once, at the first stage's end through its best point; the second stage from the best of all
END_LINE_SEARCH = [
    *LINE_SEARCH,
    "--search",
    "staged_restart_grid_near=0.01",
    "--search",
    "staged_restart_grid_at_end=true",
]

# the same, the first stage cut to 0.3 of the budget so that the line's 240 evaluations come out of it, not the second
SHORT_END_LINE_SEARCH = [*END_LINE_SEARCH, "--search", "staged_first_fraction=0.3"]
# the line alone (no passes either side) once at the first stage's end: 48 evaluations
CENTRE_END_LINE_SEARCH = [*LINE_SEARCH, "--search", "staged_restart_grid_at_end=true"]

# that, then a run over the strong settings alone from the best point of all for 0.1 of the budget, before the second
END_RUN_SEARCH = [*SHORT_END_LINE_SEARCH, "--search", "staged_restart_grid_end_run=0.1"]

# the line at the first stage's end (with its passes) scored on the first 5 training frames, its best 6 cells again on
# every frame: the line at about 0.6 of its cost, the first stage at its default length
FRAMES_END_LINE_SEARCH = [*END_LINE_SEARCH, "--search", "staged_restart_grid_frames=5"]

SOURCES = {
    "demo": {
        "argv": ["{py}", "demo_blend/build_demo.py", "--out", "out/demo", "--blend", "out/demo/demo.blend"],
        "output": "out/demo/summary.json",
        "cost": "cheap",
        "rtol": 1e-6,
        "what": "make demo, first part: the Blender pipeline on lab18 (render, fit, overlays, pictures)",
    },
    "paper_quick": {
        "argv": [
            "{py}",
            "-m",
            "clothfit",
            "paper",
            "--quick",
            "--json",
            "{out}",
            "--out",
            "out/paper_quick",
            "--only",
            "table1",
        ],
        "cost": "cheap",
        "rtol": 1e-6,
        "what": "make demo, second part: Table 1 at 240 x 320",
    },
    "identifiability": {
        "argv": ["{py}", "-m", "clothfit", "identifiability", "--json", "{out}"],
        "cost": "cheap",
        "rtol": 1e-6,
        "what": "sensitivity and Cramer-Rao bounds of Blender's cloth settings",
    },
    "simd": {
        "argv": ["{py}", "lab/simd_bench.py", "--json", "{out}"],
        "cost": "cheap",
        "rtol": 0,
        "atol": 0,
        "what": "the hand-written LLVM IR kernels against their plain numba twins (CLOTHFIT_NO_SIMD=1)",
    },
    "blender_agreement": {
        "argv": ["{py}", "-m", "clothfit", "blender-agreement", "--json", "{out}"],
        "cost": "cheap",
        "rtol": 0,
        "atol": 1e-9,
        "what": "the core's blender model against Blender's own cloth, 12 cases",
    },
    "blender_agreement_drag": {
        "argv": [
            "{py}",
            "-m",
            "clothfit",
            "blender-agreement",
            "--handling",
            "drag",
            "--settle",
            "0.5",
            "--json",
            "{out}",
        ],
        "cost": "cheap",
        "rtol": 0,
        "atol": 1e-9,
        "what": "the core's blender model with a table against Blender's own cloth and Collision object: a cloth "
        "dropped onto a table and one corner dragged along it, 12 cases",
    },
    "sensitivity": {
        "argv": ["{py}", "lab/sensitivity.py", "--json", "{out}"],
        "cost": "cheap",
        "rtol": 1e-6,
        "what": "how far a relative change of k moves the paper sheet (chaos below d/m = 8 /s)",
    },
    "raster_agreement": {
        "argv": ["{py}", "lab/raster_agreement.py", "--json", "{out}"],
        "cost": "cheap",
        "rtol": 0,
        "what": "core rasteriser against Blender's Workbench renders, 540 images",
    },
    "raster_agreement_eevee": {
        "argv": ["{py}", "lab/raster_agreement.py", "--engine", "eevee", "--times", "0.1:1.5:0.2", "--json", "{out}"],
        "cost": "expensive",
        "what": "core rasteriser against Blender's Eevee renders, 144 images (software GL: minutes)",
    },
    "bench": {
        "argv": ["{py}", "-m", "clothfit", "bench", "--json", "{out}"],
        "cost": "expensive",
        "what": "speed figures (make bench)",
    },
    "optimiser_ab": {
        "argv": ["{py}", "lab/optimiser_ab.py", "all", "0-5", "--json", "{out}"],
        "cost": "expensive",
        "what": "our CMA-ES plain / active against the cma package, cotton capture of the cross-simulator, seeds 0-5 "
        "(needs lab/cross_simulator.py observe --out out/cross2)",
    },
    "search_landscape": {
        "argv": ["{py}", "lab/search_ab.py", "synth:default", "--landscape", "{out}", "--local", "0.05"],
        "cost": "expensive",
        "what": "the search that reaches the floor: the exact-model capture's truth perturbed group by group (train and held-out "
        "error), and a CMA-ES run started 5 % from the truth (about 2 CPU min)",
    },
    "search_slice": {
        "argv": ["{py}", "lab/search_ab.py", "synth:default", "synth:fresh", "--slice", "{out}"],
        "cost": "cheap",
        "rtol": 0,
        "what": "the search that reaches the floor: the first stage's slice of two exact-model captures: training error over bending x "
        "air damping (16 x 16 across their ranges), tension and shear at the truth and 0.01 of the unit cube off "
        "(about 1 CPU min)",
    },
    "search_runs": {
        "argv": _search_ab_reused(
            "staged,staged-runs,staged-rs,staged-rs48,staged-pop24",
            "docs/figures/search_runs_rows.jsonl",
        ),
        "cost": "cheap",
        "rtol": 0,
        "what": "the search that reaches the floor: runs again in the first stage ('staged-runs', 'staged-rs48'; not kept then, 'staged-rs48' with "
        "the warm tail the default since search_rs_tail) against "
        "one run (the default, 'staged'), and 'staged-rs' and 'staged-pop24' where run, seeds 0-4 on five exact-model "
        "captures (the goal's, made by lab/fit_goals.py exact; fresh, damped, and a soft and a stiff cloth away "
        "from the search's centre): the fits of the rows file (drop --only-reused to run the missing ones, about "
        "1 CPU min each)",
    },
    "search_pop16": {
        "argv": _search_ab_reused(
            "staged,staged-pop16,staged-pop16-3900",
            "docs/figures/search_runs_rows.jsonl",
            "docs/figures/search_pop16_rows.jsonl",
        ),
        "cost": "cheap",
        "rtol": 0,
        "what": "the search that reaches the floor: populations of 16 in both stages (two whole batches of the kernel's 8 lanes, one per "
        "core; tried, not kept) at the default's 2500 evaluations ('staged-pop16') and at about its wall time on two "
        "cores ('staged-pop16-3900'), against the default ('staged', the rows of search_runs), seeds 0-4 on its five "
        "captures: the fits of the rows files (drop --only-reused to run the missing ones)",
    },
    "search_warm": {
        "argv": _search_ab_reused(
            "staged,staged-warm,staged-tail20,staged-stuck32,staged-stuck20,staged-runs-tail20",
            "docs/figures/search_runs_rows.jsonl",
            "docs/figures/search_warm_rows.jsonl",
        ),
        "cost": "cheap",
        "rtol": 0,
        "what": "the search that reaches the floor: the second stage's first steps: warm (the first stage's covariance on the strong "
        "settings), a warm tail for the last 20 % of the budget, and that tail only where the second stage has found "
        "nothing better (from 68 % and from 80 %: the default then, until search_rs_tail), against the default before "
        "('staged', the rows of search_runs); seeds 0-4 on its five captures where run (the rows file: drop --only-reused to run the rest)",
    },
    "search_rs_tail": {
        "argv": _search_ab_reused(
            "staged,staged-stuck20,staged-rs48,staged-rs48-stuck20,staged-rs48-tail20",
            "docs/figures/search_runs_rows.jsonl",
            "docs/figures/search_warm_rows.jsonl",
            "docs/figures/search_rs_tail_rows.jsonl",
        ),
        "cost": "cheap",
        "rtol": 0,
        "what": "the search that reaches the floor: runs again in the first stage's own share followed by the warm tail, only where the "
        "second stage found nothing better ('staged-rs48-stuck20') and in every fit ('staged-rs48-tail20': the default "
        "then), against the default before ('staged-stuck20', its missing rows those of 'staged', the same search "
        "where its tail did not start), runs again alone ('staged-rs48') and one run ('staged'), seeds 0-4 on the five "
        "captures of search_runs: the fits of the rows files (drop --only-reused to run the missing ones)",
    },
    "search_stall": {
        "argv": _search_ab_reused(
            "staged-rs48-tail20,staged-rs48-stall10",
            "docs/figures/search_rs_tail_rows.jsonl",
            "docs/figures/search_stall_rows.jsonl",
        ),
        "cost": "cheap",
        "rtol": 0,
        "what": "the search that reaches the floor: the warm tail also started as soon as the second stage gains less than 1 % over 10 % "
        "of the budget ('staged-rs48-stall10'; tried, not kept), against the default then ('staged-rs48-tail20', the "
        "rows of search_rs_tail), seeds 0-4 where run (the goal's capture): the fits of the rows files (drop "
        "--only-reused to run the missing ones)",
    },
    "search_step": {
        "argv": _search_ab_reused(
            "staged-rs48-tail20,staged-rs48-step02,staged-rs48-step01",
            "docs/figures/search_rs_tail_rows.jsonl",
            "docs/figures/search_step_rows.jsonl",
        ),
        "cost": "cheap",
        "rtol": 0,
        "what": "the search that reaches the floor: runs again counting a first-stage run settled at steps below 0.02 ('staged-rs48-step02') "
        "or 0.01 ('staged-rs48-step01') of the cube instead of 0.005, the default then ('staged-rs48-tail20', the "
        "rows of search_rs_tail; 0.01 the default since where no quality ladder follows), seeds 0-4 on the five "
        "captures of search_runs: the fits of the rows files (drop --only-reused to run the missing ones)",
    },
    "search_step10": {
        "argv": _search_ab_reused(
            "staged-rs48-tail20,staged-rs48-step01",
            "docs/figures/search_rs_tail_rows.jsonl",
            "docs/figures/search_step_rows.jsonl",
            "docs/figures/search_step10_rows.jsonl",
            captures=["out/fit_goals/exact"],
            seeds="0-9",
        ),
        "cost": "cheap",
        "rtol": 0,
        "what": "the search that reaches the floor: the default since (runs again settled at 0.01, 'staged-rs48-step01') against the "
        "default before (0.005, 'staged-rs48-tail20') over ten seeds, 0-9, on the goal's capture: seeds 0-4 the rows "
        "of search_step and search_rs_tail, seeds 5-9 those of search_step10_rows.jsonl (drop --only-reused to run "
        "the missing ones)",
    },
    "search_grid": {
        "argv": _search_ab_reused(
            "staged-rs48-step01,staged-grid",
            "docs/figures/search_grid_rows.jsonl",
            captures=["out/fit_goals/exact"],
            seeds="0-9",
            spread="docs/figures/search_jitter_spread.json",
        ),
        "cost": "cheap",
        "rtol": 0,
        "what": "runs again from a grid: the first run's end followed by an 8 x 8 grid over bending and air damping, the "
        "later runs started at its best cells ('staged-grid', fit --search staged_restart_grid=true) against the "
        "default ('staged-rs48-step01'), seeds 0-9 on the goal's capture: the fits of the rows file (drop "
        "--only-reused to run them again)",
    },
    "quick_start": {
        "argv": ["{py}", "lab/quick_start.py", "--seeds", "0-4", "--json", "{out}"],
        "cost": "expensive",
        "what": "the README's Quick start as a new user runs it (synth --model blender at 120 x 160, fit --cameras n:4), "
        "the fit's seeds 0-4 (0: the command as written): each setting against the capture's truth, its interval, the "
        "held-out ratio to the stated floor, the verdict (about 6 min)",
    },
    "search_jitter_spread": {
        "argv": ["{py}", "lab/search_ab.py", *SEARCH_RUNS_CAPTURES, "--jitter-spread", "{out}"],
        "cost": "cheap",
        "rtol": 1e-6,
        "what": "the jitter floor's spread on the five captures of search_runs (the goal's made by lab/fit_goals.py "
        "exact): the held-out ratio of 40 points a part in 10^7 from the truth, its 10th, 50th and 90th percentiles "
        "and maximum (a few seconds per capture)",
    },
    "search_jitter_check": {
        "argv": [
            "{py}",
            "lab/search_ab.py",
            *SEARCH_RUNS_CAPTURES,
            "--jitter-check",
            "{out}",
            "--reuse",
            "docs/figures/search_grid_rows.jsonl",
            "docs/figures/search_grid4_rows.jsonl",
            "--strategies",
            "staged-grid",
            "--seeds",
            "0-9",
            "--spread",
            "docs/figures/search_jitter_spread.json",
        ],
        "cost": "expensive",
        "rtol": 1e-6,
        "what": "the jitter floor a fit states (fitting/jitter.py: the noise floor plus the silhouettes' difference "
        "between the fit and 40 neighbours a part in 10^7 away), checked where the truth is known: at the truth beside "
        "the truth's own neighbours' errors, and at the 50 fits of search_grid and search_grid4 (the default search, "
        "seeds 0-9) the rules that call a fit at the floor (2x alone; 2x or the jitter floor at its 50th, 75th, 90th "
        "percentile) against the truth's own spread (about 6 min)",
    },
    "search_looks": {
        "argv": ["{py}", "lab/search_ab.py", "--looks-check", "docs/figures/search_jitter_check.json", "{out}"],
        "cost": "cheap",
        "rtol": 1e-9,
        "what": "looking again where a fit ends above its own jitter floor (the training side, as a fit knows it when its "
        "search ends), from search_jitter_check's 50 fits alone: the fits within the truth's own spread with one "
        "look, a second look, up to three, two always (another seed's search = the mean over the other seeds' fits)",
    },
    "search_grid4": {
        "argv": _search_ab_reused(
            "staged-rs48-step01,staged-grid",
            "docs/figures/search_grid4_rows.jsonl",
            captures=["synth:fresh", "synth:stiff", "synth:damped", "synth:soft"],
            seeds="0-9",
            spread="docs/figures/search_jitter_spread.json",
        ),
        "cost": "cheap",
        "rtol": 0,
        "what": "runs again from a grid ('staged-grid') against the default ('staged-rs48-step01') on the four other "
        "captures of search_runs, seeds 0-9 (0-4 and 5-9 each run side by side in one session), with the seeds within "
        "each capture's jitter spread (search_jitter_spread): the fits of the rows file (drop --only-reused to run "
        "them again)",
    },
    "search_bend": {
        "argv": _search_ab_reused(
            "staged-rs48-step01,staged-rs48-step01-bend",
            "docs/figures/search_step_rows.jsonl",
            "docs/figures/search_step10_rows.jsonl",
            "docs/figures/search_bend_rows.jsonl",
            seeds="0-9",
        ),
        "cost": "cheap",
        "rtol": 0,
        "what": "the search that reaches the floor: runs again each started at another bending ('staged-rs48-step01-bend'; tried, not "
        "kept) against the default ('staged-rs48-step01'), seeds 0-9 on the five captures of search_runs (seeds 0-4 "
        "of the default's from search_step, 5-9 of the goal's capture from search_step10): the fits of the rows files "
        "(drop --only-reused to run the missing ones)",
    },
    "search_pop16_wall": {
        "argv": [
            "{py}",
            "lab/search_ab.py",
            "out/fit_goals/exact",
            "--strategies",
            "staged,staged-pop16",
            "--seeds",
            "0",
            "--reuse",
            "docs/figures/search_pop16_wall_rows.jsonl",
            "--only-reused",
            "--json-summary",
            "{out}",
        ],
        "cost": "cheap",
        "rtol": 0,
        "what": "the search that reaches the floor: the default search and 'staged-pop16' one after the other on one machine (the goal's "
        "capture, seed 0): CPU and wall time of the same 2500 evaluations (drop --only-reused to run them again)",
    },
    "search_profile": {
        "argv": [
            "{py}",
            "lab/search_ab.py",
            "out/fit_goals/exact",
            "synth:fresh",
            "--profile",
            "{out}",
            "--profile-evals",
            "64,96",
            "--seeds",
            "0-1",
        ],
        "cost": "expensive",
        "rtol": 0,
        "what": "the search that reaches the floor: a first stage by profile over bending (tried, not kept) on two exact-model captures, "
        "64 and 96 evaluations per bending value, seeds 0-1 (about 6 CPU min)",
    },
    "same_fit": {
        "argv": ["{py}", "lab/same_fit.py", "--json", "{out}"],
        "cost": "cheap",
        "rtol": 0,
        "what": "a seed's fit natively and with NumPy's AVX-512 kernels switched off (as on a CPU without them): the "
        "same fit? (about 1 CPU min)",
    },
    "search_oracle": {
        "argv": ["{py}", "lab/search_ab.py", "synth:fresh", "--oracle", "{out}", "--samples", "128"],
        "cost": "expensive",
        "what": "the search that reaches the floor: 128 points 1e-7, 1e-5 and 1e-3 (relative) round the truth of the fresh exact-model "
        "capture, and the best of n by training error: what a search that came that close could keep (about 1 CPU min)",
    },
    "search_tune": {
        "argv": [
            "{py}",
            "lab/search_ab.py",
            "--summary",
            "docs/figures/search_tune_rows.jsonl",
            "--json-summary",
            "{out}",
        ],
        "cost": "cheap",
        "rtol": 0,
        "what": "the search that reaches the floor: the strategies tried on the tuning capture (rows written by lab/search_ab.py)",
    },
    "search_ab": {
        "argv": [
            "{py}",
            "lab/search_ab.py",
            "synth:fresh",
            "--strategies",
            "baseline,active32,staged,staged-race3,staged-scan,staged-tie",
            "--seeds",
            "0-9",
            "--reuse",
            "docs/figures/search_ab_rows.jsonl",
            "--only-reused",
            "--json-summary",
            "{out}",
        ],
        "cost": "cheap",
        "rtol": 0,
        "what": "the search that reaches the floor: search strategies on a fresh exact-model capture (blender model, lab18, 240 x 320, "
        "5 % noise, tension 25 shear 8), held-out error over the floor, seeds 0-9 where run: the fits are those of "
        "the rows file (written by this tool; drop --only-reused to run the missing ones, about 2 CPU min each)",
    },
    "search_ab_damped": {
        "argv": [
            "{py}",
            "lab/search_ab.py",
            "synth:damped",
            "--strategies",
            "baseline,staged,staged-race3,staged-scan,staged-tie,staged-recipe",
            "--seeds",
            "0-9",
            "--reuse",
            "docs/figures/search_ab_damped_rows.jsonl",
            "--only-reused",
            "--json-summary",
            "{out}",
        ],
        "cost": "cheap",
        "rtol": 0,
        "what": "the search that reaches the floor: the strong settings first ('staged') against today's search on an exact-model capture "
        "whose every setting is off Blender's defaults (tension 15, compression 9, dampings 12 / 2 / 1.5), seeds 0-9 "
        "where run: the fits of the rows file (drop --only-reused to run the missing ones, about 2 CPU min each)",
    },
    "blender_scene_warm": {
        "argv": [
            "{py}",
            "lab/blender_scene_fit.py",
            "all",
            "--out",
            "out/scene_warm",
            "--release",
            "corner",
            "--drop",
            "0.07",
            "--after",
            "0.75",
            "--every",
            "1",
            "--warm",
        ],
        "output": "out/scene_warm/summary.json",
        "cost": "expensive",
        "what": "one-corner release onto a box: Blender fit from the core model's warm start",
    },
    "blender_scene_cold": {
        "argv": [
            "{py}",
            "lab/blender_scene_fit.py",
            "all",
            "--out",
            "out/scene_cold",
            "--release",
            "corner",
            "--drop",
            "0.07",
            "--after",
            "0.75",
            "--every",
            "1",
        ],
        "output": "out/scene_cold/summary.json",
        "cost": "expensive",
        "what": "one-corner release onto a box: Blender fit from the scene's starting settings",
    },
    "bench_default_fit": {
        "argv": ["{py}", "-m", "clothfit", "bench", "--default-fit", "--json", "{out}"],
        "cost": "expensive",
        "what": "the time to answer as bench prints it: the default fit of a 21 x 21 cloth, 4 cameras x 15 "
        "frames at 480 x 640, quality chosen, manipulation estimated (about 3 min)",
    },
    "bench_blender_workers": {
        "argv": ["{py}", "-m", "clothfit", "bench", "--blender-workers", "--json", "{out}"],
        "cost": "expensive",
        "what": "Blender's solver as the evaluator with 1 and 2 Ray workers",
    },
    "paper": {
        "argv": ["{py}", "-m", "clothfit", "paper", "--json", "{out}", "--out", "out/paper"],
        "cost": "expensive",
        "what": "the paper protocol: Table 1, Fig. 8, Table 2, optimisers (make paper)",
    },
    "occlusion": {
        "argv": ["{py}", "-m", "clothfit", "occlusion", "--json", "{out}"],
        "cost": "expensive",
        "what": "the occluder study: ignore masks vs occluders counted as background",
    },
    "user_scenes": {
        "argv": ["{py}", "lab/user_scenes.py", "all", "--out", "out/user_scenes", "--json", "{out}"],
        "cost": "cheap",
        "rtol": 1e-9,
        "atol": 1e-12,
        "what": "Blender scenes built as a user builds them; the core blender model's drift from them, cause by cause",
    },
    "fit_goals": {
        "argv": ["{py}", "lab/fit_goals.py", "all", "--json", "{out}"],
        "cost": "expensive",
        "what": "the goals for fitting a real capture, measured through the CLI on fresh captures (exact model, offsets, continuum, "
        "collider, time); each goal also alone: lab/fit_goals.py GOAL --json FILE",
    },
    "fit_goals_time": {
        "argv": ["{py}", "lab/fit_goals.py", "time", "--diagnose", "--json", "{out}"],
        "cost": "expensive",
        "what": "the time goal (a 21 x 21 quality-15 cloth at 480 x 640 whose capture "
        "names no quality, release and pins declared with error and uncertain), then the same fit told the quality, "
        "and the truth's capture with only its quality left out (about 8 min)",
    },
    "fit_goals_time_refit": {
        "argv": ["{py}", "lab/fit_goals.py", "time", "--quality", "10,12", "--json", "{out}"],
        "cost": "expensive",
        "what": "the time goal's capture refitted as the floor block of its default fit advises (its ladder chose 10, "
        "42 % below the search at 5): a search at quality 10 from the start, and at 12, the highest quality the "
        "ladder tried (about 11 min)",
    },
    "fit_goals_time_quality": {
        "argv": ["{py}", "lab/fit_goals.py", "time_quality", "--json", "{out}"],
        "cost": "cheap",
        "rtol": 1e-9,
        "atol": 1e-12,
        "what": "the time goal's capture: its true settings simulated at each quality of the fit's ladder and at "
        "the truth's own 15 (training E_sil on the true capture)",
    },
    "fit_goals_offsets_sensitivity": {
        "argv": ["{py}", "lab/fit_goals.py", "offsets_sensitivity", "--json", "{out}"],
        "cost": "cheap",
        "rtol": 1e-6,
        "atol": 1e-9,
        "what": "the offsets goal's capture: its truth scored as the goal scores a fit, the same with only the time "
        "offset or one pin moved, and its jitter floor (16 points a part in 10^7 from the truth)",
    },
    "fit_goals_offsets_coverage": {
        "argv": ["{py}", "lab/fit_goals.py", "offsets_coverage", "--json", "{out}"],
        "cost": "cheap",
        "rtol": 0,
        "what": "the offsets goal's fits (the recordings fit_goals_offsets_seeds and fit_goals_offsets_hold, no fit run): each "
        "stated offset's error over the uncertainty the fit states, and the share within 1x and 2x",
    },
    "takes_baseline": {
        "argv": [
            "{py}",
            "lab/continuum_truth.py",
            "takes-baseline",
            "--out",
            "out/takes",
            "--materials",
            "cotton,silk",
            "--takes",
            "one_corner,two_adjacent,wave",
            "--json",
            "{out}",
        ],
        "cost": "expensive",
        "what": "several takes of one continuum cloth (Warp; cotton, silk): each of three takes fitted alone by the "
        "blender model as a new user would, scored on the held-out cameras and frames of every take (the captures: "
        "lab/continuum_truth.py takes --out out/takes; a finished fit in out/takes/fits is reused: about 45 min "
        "without them)",
    },
    "takes_pairs": {
        "argv": [
            "{py}",
            "lab/continuum_truth.py",
            "takes-pairs",
            "--out",
            "out/takes",
            "--materials",
            "cotton",
            "--json",
            "{out}",
        ],
        "cost": "expensive",
        "what": "the cotton: every pair of the three takes fitted together (fit A B), scored on all three, the "
        "third a handling the fit never saw (a finished fit in out/takes/pairs is reused: about 45 min without them)",
    },
    "takes_pairs_silk": {
        "argv": [
            "{py}",
            "lab/continuum_truth.py",
            "takes-pairs",
            "--out",
            "out/takes",
            "--materials",
            "silk",
            "--pairs",
            "one_corner+two_adjacent",
            "--json",
            "{out}",
        ],
        "cost": "expensive",
        "what": "the silk: its one-corner and edge (two adjacent corners) releases fitted together, scored on those "
        "and on the waved take (a finished fit in out/takes/pairs is reused: about 15 min without it)",
    },
    "real_lifts": {
        "argv": ["{py}", "lab/real_lifts.py", "trials", "--fabrics", "paper,navy", "--json", "{out}"],
        "cost": "expensive",
        "what": "DiffCloud's real lifts (fabrics paper and navy, three trials each; a checkout of its repository in "
        "out/diffcloud_real2sim): each trial converted with points-to-capture and fitted alone as a user fits it, "
        "scored on its held-out cameras and frames and against the real points (a finished fit in "
        "out/real_lifts/fits is reused: about 30 min without them)",
    },
    "real_lifts_navy_seed1": {
        "argv": [
            "{py}",
            "lab/real_lifts.py",
            "trials",
            "--fabrics",
            "navy",
            "--trials",
            "navy,navy2",
            "--seed",
            "1",
            "--json",
            "{out}",
        ],
        "cost": "expensive",
        "what": "the two navy trials whose fits ended far above the third's (45 % held-out against 25 %) fitted again "
        "with another seed: how much of their error is the search's (out/real_lifts/fits_seed1; about 10 min)",
    },
    "real_lifts_pairs": {
        "argv": ["{py}", "lab/real_lifts.py", "pairs", "--fabrics", "paper,navy", "--json", "{out}"],
        "cost": "expensive",
        "what": "DiffCloud's real lifts, per fabric (paper, navy) its first two trials fitted together as a user fits "
        "them and the third predicted: its unknowns (clock stretch and offset, the grasp) fitted with the settings held "
        "on the images its own fit trained on, then scored on its held-out cameras and frames and against its real "
        "points, beside the third fitted alone (finished fits in out/real_lifts/pairs and fits are reused: about 20 "
        "min without them)",
    },
    "interval_coverage": {
        "argv": ["{py}", "lab/interval_coverage.py", "--captures", "6", "--json", "{out}"],
        "cost": "expensive",
        "what": "how often a fit's 90 % intervals hold the truth: six synthetic captures of Blender's cloth (11 x 11, "
        "lab18 at 120 x 160, 5 % noise, settings drawn within a factor 3 of Blender's defaults), each fitted with the "
        "default options and 4 training cameras; the truth's own error tells the fits in its basin apart (about 8 min)",
    },
    "interval_coverage_check": {
        "argv": ["{py}", "lab/interval_coverage.py", "--first", "6", "--captures", "6", "--json", "{out}"],
        "cost": "expensive",
        "what": "the same as interval_coverage on six other captures (cap06-cap11), none of which set the intervals' "
        "calibration (about 8 min)",
    },
    "fit_goals_offsets_seeds": {
        "argv": ["{py}", "lab/fit_goals.py", "offsets", "--seeds", "0-2", "--json", "{out}"],
        "cost": "expensive",
        "what": "the offsets goal with the default fit over seeds 0-2 (one fit each, about 4 min)",
    },
    "fit_goals_offsets_jitter": {
        "argv": ["{py}", "lab/fit_goals.py", "offsets", "--seeds", "0-4", "--json", "{out}"],
        "cost": "expensive",
        "what": "the release/pins goal's capture fitted with the default, seeds 0-4: each result's floor block with the "
        "jitter floor measured at the fit (the check of the jitter rule on fits it was not chosen on; about 7 min)",
    },
    "fit_goals_exact_seeds_0_4": {
        "argv": ["{py}", "lab/fit_goals.py", "exact", "--seeds", "0-4", "--json", "{out}"],
        "cost": "expensive",
        "what": "the exact-model goal's capture fitted as a user fits it (fit --cameras n:4, the default search, which "
        "searches again where a search ends above its own jitter floor), seeds 0-4: held-out ratio to the truth's "
        "error per seed (about 12 min)",
    },
    "fit_goals_exact_seeds_5_9": {
        "argv": ["{py}", "lab/fit_goals.py", "exact", "--seeds", "5-9", "--json", "{out}"],
        "cost": "expensive",
        "what": "the same, seeds 5-9 (run side by side with seeds 0-4; about 12 min)",
    },
    "fit_goals_exact_seeds_10_14": {
        "argv": ["{py}", "lab/fit_goals.py", "exact", "--seeds", "10-14", "--json", "{out}"],
        "cost": "expensive",
        "what": "the same, seeds 10-14: seeds no variant of the search was compared on (about 12 min)",
    },
    "generation_cost": {
        "argv": ["{py}", "lab/generation_cost.py", "--json", "{out}"],
        "cost": "cheap",
        "rtol": 1.0,
        "what": "what a generation of the search costs by its size on this machine (the default fit's workload, one "
        "batch of 1 to 32 candidates): wall and CPU ms, and wall over one candidate's (about 1 min)",
    },
    "fit_goals_continuum_again": {
        "argv": ["{py}", "lab/fit_goals.py", "continuum", "--json", "{out}"],
        "cost": "expensive",
        "what": "the continuum goal (Warp's cotton and silk, fitted as a new user would) with the default that searches "
        "again where a search ends above its jitter floor: a truth our model did not make (about 15 min)",
    },
    "fit_goals_continuum_once": {
        "argv": ["{py}", "lab/fit_goals.py", "continuum", "--json", "{out}"],
        "cost": "expensive",
        "what": "the continuum goal with the default since a fit whose quality is still to be chosen searches once "
        "(the same command as fit_goals_continuum_again, a later commit; about 13 min)",
    },
    "early_window_landscape": {
        "argv": ["{py}", "lab/early_window.py", "landscape", "--json", "{out}"],
        "cost": "cheap",
        "rtol": 0.05,
        "what": "the default fit's capture: the truth's training error in three windows of the training frames with "
        "one strong setting scaled from 1 + 1e-6 to 0.1 (which frames can lead a search to the truth; about 1 min)",
    },
    "early_window_slice": {
        "argv": ["{py}", "lab/early_window.py", "slice", "--points", "48", "--json", "{out}"],
        "cost": "cheap",
        "rtol": 0.05,
        "what": "the default fit's capture: the truth's training error with bending at 48 values across the search's "
        "range and shear at 0.95, 1 and 1.05 of the truth's (how narrow the truth's bending valley is; under a minute)",
    },
    "early_window_line": {
        "argv": window_cameras(*LINE_SEARCH, "--search", "staged_restart_step=0.01"),
        "cost": "expensive",
        "what": "the default fit of the time goal's capture with runs again settled at 0.01 of the cube and the grid "
        "a line of 48 bendings through the first run's end (a variant of the search), seeds 0-3 (about 12 min)",
    },  # fmt: skip
    "line_exact": {
        "argv": [
            "{py}",
            "lab/fit_goals.py",
            "exact",
            "--seeds",
            "0-9",
            *LINE_SEARCH,
            "--json",
            "{out}",
        ],
        "cost": "expensive",
        "what": "the exact-model goal's capture fitted with the grid a line of 48 bendings through the first run's "
        "end (a variant of the search), seeds 0-9 (about 20 min)",
    },
    "line_offsets": {
        "argv": [
            "{py}",
            "lab/fit_goals.py",
            "offsets",
            "--seeds",
            "0-4",
            *LINE_SEARCH,
            "--json",
            "{out}",
        ],
        "cost": "expensive",
        "what": "the release/pins goal's capture fitted with the grid a line of 48 bendings (a variant of the "
        "search), seeds 0-4 (about 12 min)",
    },
    "quick_start_line": {
        "argv": [
            "{py}",
            "lab/quick_start.py",
            "--seeds",
            "0-4",
            *LINE_SEARCH,
            "--json",
            "{out}",
        ],
        "cost": "expensive",
        "what": "the README's Quick start with the grid a line of 48 bendings (a variant of the search), seeds 0-4 "
        "(about 6 min)",
    },  # fmt: skip
    "early_window_cap": {
        "argv": window_cameras("--search", "staged_run_cap=0.16"),
        "cost": "expensive",
        "what": "the default fit of the time goal's capture with each first-stage run cut at 0.16 of the budget (the "
        "default 8 x 8 grid; a variant of the search), seeds 0-3 (about 17 min)",
    },
    "early_window_cap_line": {
        "argv": window_cameras(*CAP_LINE_SEARCH),
        "cost": "expensive",
        "what": "the default fit of the time goal's capture with a line of 48 bendings and each first-stage run cut at "
        "0.16 of the budget (a variant of the search), seeds 0-3 (about 17 min on a machine twice as slow as the others')",
    },  # fmt: skip
    "cap_line_exact": {
        "argv": ["{py}", "lab/fit_goals.py", "exact", "--seeds", "0-4", *CAP_LINE_SEARCH, "--json", "{out}"],
        "cost": "expensive",
        "what": "the exact-model goal's capture with a line of 48 bendings and each first-stage run cut at 0.16 of the "
        "budget (a variant of the search), seeds 0-4 (about 20 min on a machine twice as slow as the others' recordings)",
    },  # fmt: skip
    "cap_line_exact_5_9": {
        "argv": ["{py}", "lab/fit_goals.py", "exact", "--seeds", "5-9", *CAP_LINE_SEARCH, "--json", "{out}"],
        "cost": "expensive",
        "what": "the exact-model goal's capture with a line of 48 bendings and each first-stage run cut at 0.16 of the "
        "budget (a variant of the search), seeds 5-9 (about 15 min on a machine twice as slow as the others' recordings)",
    },  # fmt: skip
    "cap_line_offsets": {
        "argv": ["{py}", "lab/fit_goals.py", "offsets", "--seeds", "0-4", *CAP_LINE_SEARCH, "--json", "{out}"],
        "cost": "expensive",
        "what": "the release/pins goal's capture with a line of 48 bendings and each first-stage run cut at 0.16 of "
        "the budget (a variant of the search), seeds 0-4 (about 33 min on a machine twice as slow as the others')",
    },  # fmt: skip
    "early_window_near_line": {
        "argv": window_cameras(*NEAR_LINE_SEARCH),
        "cost": "expensive",
        "what": "the default fit of the time goal's capture with the line of 48 bendings tried also with tension and "
        "with shear 0.01 of the cube either side of the run's end, the first run cut at 0.10 of the budget (a variant "
        "of the search), seeds 0-3 (about 20 min on a machine twice as slow as the others')",
    },  # fmt: skip
    "early_window_around": {
        "argv": [
            "{py}",
            "lab/early_window.py",
            "around",
            "--from",
            "docs/figures/early_window_cap_line.json",
            "--seeds",
            "2-3",
            "--json",
            "{out}",
        ],
        "cost": "expensive",
        "what": "the line of 48 bendings through the capped line's fits that ended in other basins (seeds 2-3 of the "
        "time goal's capture), at their own tension and shear and with each moved 0.01 of the cube either way "
        "(about 3 min)",
    },  # fmt: skip
    "early_window_end_line": {
        "argv": window_cameras(*END_LINE_SEARCH),
        "cost": "expensive",
        "what": "the default fit of the time goal's capture with the line of 48 bendings, also with tension and with "
        "shear 0.01 of the cube either side, run once at the first stage's end through its best point (a variant of the "
        "search), seeds 0-3 (about 20 min on a machine twice as slow as the others')",
    },  # fmt: skip
    "end_line_exact_5_9": {
        "argv": ["{py}", "lab/fit_goals.py", "exact", "--seeds", "5-9", *END_LINE_SEARCH, "--json", "{out}"],
        "cost": "expensive",
        "what": "the exact-model goal's capture with the line of 48 bendings, also with tension and with shear 0.01 of "
        "the cube either side, run once at the first stage's end through its best point (a variant of the search), "
        "seeds 5-9 (about 15 min on a machine twice as slow as the others' recordings)",
    },  # fmt: skip
    "early_window_end_line_short": {
        "argv": window_cameras(*SHORT_END_LINE_SEARCH),
        "cost": "expensive",
        "what": "early_window_end_line's search with the first stage cut to 0.3 of the budget (the line paid by the "
        "first stage, not the second), seeds 0-3 (about 30 min beside the CI)",
    },  # fmt: skip
    "end_line_short_exact_5_9": {
        "argv": ["{py}", "lab/fit_goals.py", "exact", "--seeds", "5-9", *SHORT_END_LINE_SEARCH, "--json", "{out}"],
        "cost": "expensive",
        "what": "end_line_exact_5_9's search with the first stage cut to 0.3 of the budget, seeds 5-9 (about 25 min "
        "beside the CI)",
    },  # fmt: skip
    "early_window_end_centre": {
        "argv": window_cameras(*CENTRE_END_LINE_SEARCH),
        "cost": "expensive",
        "what": "the default fit of the time goal's capture with the line of 48 bendings alone (no passes either side), "
        "once at the first stage's end through its best point, seeds 0-3 (about 30 min beside the CI)",
    },  # fmt: skip
    "end_centre_exact_5_9": {
        "argv": ["{py}", "lab/fit_goals.py", "exact", "--seeds", "5-9", *CENTRE_END_LINE_SEARCH, "--json", "{out}"],
        "cost": "expensive",
        "what": "the exact-model goal's capture with the line of 48 bendings alone, once at the first stage's end "
        "through its best point, seeds 5-9 (about 25 min beside other work)",
    },  # fmt: skip
    "end_line_short_offsets_0_2": {
        "argv": ["{py}", "lab/fit_goals.py", "offsets", "--seeds", "0-2", *SHORT_END_LINE_SEARCH, "--json", "{out}"],
        "cost": "expensive",
        "what": "the release/pins goal's capture with end_line_short_exact_5_9's search, seeds 0-2 (about 25 min beside "
        "other work)",
    },  # fmt: skip
    "early_window_end_run": {
        "argv": window_cameras(*END_RUN_SEARCH),
        "cost": "expensive",
        "what": "early_window_end_line_short's search, then a run over the strong settings alone from the best point "
        "of all for 0.1 of the budget before the second stage, seeds 0-3 (about 30 min beside the CI)",
    },  # fmt: skip
    "end_run_exact_5_9": {
        "argv": ["{py}", "lab/fit_goals.py", "exact", "--seeds", "5-9", *END_RUN_SEARCH, "--json", "{out}"],
        "cost": "expensive",
        "what": "early_window_end_run's search on the exact-model goal's capture, seeds 5-9 (about 25 min beside "
        "other work)",
    },  # fmt: skip
    "early_window_end_frames": {
        "argv": window_cameras(*FRAMES_END_LINE_SEARCH),
        "cost": "expensive",
        "what": "early_window_end_line's search with the line scored on the first 5 training frames and its best 6 "
        "cells again on every frame (the line at about 0.6 of its cost), the first stage at its default length, seeds "
        "0-3 (about 40 min beside the CI)",
    },  # fmt: skip
    "early_window_end_line_cameras8": {
        "argv": [
            "{py}",
            "lab/early_window.py",
            "cameras",
            "--n",
            "8",
            "--seeds",
            "0-3",
            *END_LINE_SEARCH,
            "--json",
            "{out}",
        ],
        "cost": "expensive",
        "what": "early_window_end_line's search with 8 training cameras instead of 4 (more views of the one take, "
        "the held-out floor on the cameras left), seeds 0-3 (about 40 min beside the CI)",
    },  # fmt: skip
    "inside_end_frames": {
        "argv": ["{py}", "lab/early_window.py", "inside", "--seeds", "0-3", *FRAMES_END_LINE_SEARCH, "--json", "{out}"],
        "cost": "expensive",
        "what": "early_window_end_frames's fits run to their line at the first stage's end, the line scored on the "
        "first 5 frames and on every frame: which cells each keeps, seeds 0-3 (about 25 min)",
    },  # fmt: skip
    "around_default_all": {
        "argv": [
            "{py}",
            "lab/early_window.py",
            "around",
            "--from",
            "docs/figures/default_fit_intervals.json",
            "--seeds",
            "0-3",
            "--json",
            "{out}",
        ],
        "cost": "expensive",
        "what": "the line of 48 bendings (and its four passes a step either side in tension and shear) through the "
        "default fit's ends on the time goal's capture, seeds 0-3, scored on every training frame (about 3 min)",
    },  # fmt: skip
    "around_default_first5": {
        "argv": [
            "{py}",
            "lab/early_window.py",
            "around",
            "--from",
            "docs/figures/default_fit_intervals.json",
            "--seeds",
            "0-3",
            "--first",
            "--k",
            "5",
            "--json",
            "{out}",
        ],
        "cost": "expensive",
        "what": "around_default_all's lines scored on the first 5 training frames only (the simulation stops at 0.5 s "
        "instead of 1.5 s, after the same 1 s of settling; about 1.5 min)",
    },  # fmt: skip
    "early_window_fits": {
        "argv": ["{py}", "lab/early_window.py", "fits", "--seeds", "0-3", "--json", "{out}"],
        "cost": "expensive",
        "what": "the default fit beside a fit in two steps of the same budget (the first five training frames alone, "
        "then all from there), seeds 0-3 of the default fit's capture (about 20 min)",
    },
    "early_window_cameras": {
        "argv": ["{py}", "lab/early_window.py", "cameras", "--n", "8", "--seeds", "0-3", "--json", "{out}"],
        "cost": "expensive",
        "what": "the default fit of the time goal's capture with 8 training cameras instead of 4, seeds 0-3: more "
        "views of one take against the low-bending basin (about 12 min)",
    },
    "default_fit_intervals": {
        "argv": ["{py}", "lab/early_window.py", "cameras", "--n", "4", "--seeds", "0-3", "--json", "{out}"],
        "cost": "expensive",
        "what": "the default fit of the time goal's capture as a user runs it (4 training cameras, quality chosen), "
        "seeds 0-3: where it ends, and what its intervals tell the user of how sure each strong setting is "
        "(about 10 min)",
    },
    "early_window_first_ten": {
        "argv": ["{py}", "lab/early_window.py", "frames", "--k", "10", "--seeds", "0-3", "--json", "{out}"],
        "cost": "expensive",
        "what": "the time goal's capture fitted on its first 10 training frames alone (the last five, which blur "
        "bending, left out), seeds 0-3, scored on the held-out cameras at every training time (about 10 min)",
    },
    "search_again_line": {
        "argv": ["{py}", "lab/search_again_line.py", "out/fit_goals/exact", "--seeds", "9,12", "--json", "{out}"],
        "cost": "expensive",
        "what": "the training error on the line between where a fit's two searches ended, on the exact goal's seeds 9 "
        "and 12 (the first search in another basin than the truth's, the second at the floor): is there a ridge a "
        "rule could see (about 6 min)",
    },
    "fit_goals_offsets_e4000": {
        "argv": [
            "{py}",
            "lab/fit_goals.py",
            "offsets",
            "--seeds",
            "0-2",
            "--max-evaluations",
            "4000",
            "--json",
            "{out}",
        ],
        "cost": "expensive",
        "what": "the offsets goal with 4000 evaluations instead of the default 2500, seeds 0-2 (about 6 min)",
    },
    "fit_goals_offsets_hold": {
        "argv": ["{py}", "lab/fit_goals.py", "offsets", "--hold-frames", "--seeds", "0-2", "--json", "{out}"],
        "cost": "expensive",
        "what": "the offsets goal on a capture with two frames before the release too (the cloth held by all "
        "four corners), trained on them as well; the default fit, seeds 0-2 (about 5 min)",
    },
    "fit_goals_search": {
        "argv": ["{py}", "lab/fit_goals.py", "search", "--json", "{out}"],
        "cost": "expensive",
        "what": "the search goal over seeds 0-4 with the fit's default search (cma-staged) and with cma-es, "
        "the default before it, and the offsets goal with cma-es (about 25 min)",
    },
    "fit_goals_offsets_runs": {
        "argv": _offsets_with("staged_restart_step=0.005", "staged_first_fraction=0.72", "staged_explore=0.56"),
        "cost": "expensive",
        "what": "the offsets goal with runs again in the first stage (tried, not kept; docs/search.md), one fit "
        "(about 3 min)",
    },
    "fit_goals_offsets_rs48": {
        "argv": _offsets_with("staged_restart_step=0.005"),
        "cost": "expensive",
        "what": "the offsets goal with runs again within the first stage's own share (staged-rs48; tried, not "
        "kept; docs/search.md), one fit (about 3 min)",
    },
    "fit_goals_continuum_rs48": {
        "argv": [
            "{py}",
            "lab/fit_goals.py",
            "continuum",
            "--search",
            "staged_restart_step=0.005",
            "--json",
            "{out}",
        ],
        "cost": "expensive",
        "what": "the continuum goal (cotton and silk from Warp) with runs again within the first stage's own "
        "share (staged-rs48; tried, not kept; docs/search.md), one fit each (about 7 min)",
    },
    "cross_simulator": {
        "argv": ["{py}", "lab/cross_simulator.py", "all", "--out", "out/cross2", "--budget", "2500"],
        "output": "out/cross2/cross_simulator.json",
        "cost": "expensive",
        "what": "Blender's cloth as the truth, fitted by both core models (about 45 min)",
    },
    "continuum_baseline": {
        "argv": ["{py}", "lab/continuum_truth.py", "baseline", "--make", "--out", "out/continuum", "--json", "{out}"],
        "cost": "expensive",
        "what": "the continuum baseline: a Warp continuum cloth (cotton, silk; 30 fps, a rig not ours) fitted by "
        "today's CLI as a new user would, and with --fps 30 (about 40 min on a loaded machine)",
    },
    "paper_mismatch": {
        "argv": [
            "{py}",
            "-m",
            "clothfit",
            "paper",
            "--only",
            "table1",
            "--truth-dt-safety",
            "0.125",
            "--json",
            "{out}",
            "--out",
            "out/paper_mismatch",
        ],
        "cost": "expensive",
        "what": "Table 1 with a model mismatch: the truth simulated with a 4x finer time step",
    },
    "paper_far": {
        "argv": [
            "{py}",
            "-m",
            "clothfit",
            "paper",
            "--only",
            "table1",
            "--rig",
            "lab18_far",
            "--json",
            "{out}",
            "--out",
            "out/paper_far",
        ],
        "cost": "expensive",
        "what": "Table 1 on a room-sized rig (the cameras at 1.25 m)",
    },
    "paper_ga": {
        "argv": [
            "{py}",
            "-m",
            "clothfit",
            "paper",
            "--only",
            "table1",
            "--optimizer",
            "spx-mgg",
            "--population",
            "60",
            "--children",
            "30",
            "--json",
            "{out}",
            "--out",
            "out/paper_ga",
        ],
        "cost": "expensive",
        "what": "Table 1 with the paper's GA at its textbook sizes",
    },
    "occlusion_mismatch": {
        "argv": [
            "{py}",
            "-m",
            "clothfit",
            "occlusion",
            "--truth-dt-safety",
            "0.125",
            "--json",
            "{out}",
            "--out",
            "out/occlusion_mismatch",
        ],
        "cost": "expensive",
        "what": "the occluder study with a model mismatch",
    },
    "occlusion_quick_1cam": {
        "argv": [
            "{py}",
            "-m",
            "clothfit",
            "occlusion",
            "--quick",
            "--train-cameras",
            "1",
            "--json",
            "{out}",
            "--out",
            "out/occlusion_q1",
        ],
        "cost": "expensive",
        "what": "the occluder study, 1 training camera, 240 x 320, 700 evaluations",
    },
    "occlusion_quick_2cam": {
        "argv": [
            "{py}",
            "-m",
            "clothfit",
            "occlusion",
            "--quick",
            "--train-cameras",
            "2",
            "--json",
            "{out}",
            "--out",
            "out/occlusion_q2",
        ],
        "cost": "expensive",
        "what": "the occluder study, 2 training cameras, 240 x 320, 700 evaluations",
    },
    "video_footage": {
        "argv": ["{py}", "tools/video_footage.py", "--out", "out/video_footage", "--json", "{out}"],
        "cost": "expensive",
        "what": "videos as phones record them, synced by a flash, extracted: IoU",
    },
    "footage": {
        "steps": [
            ["{py}", "lab/render_footage.py", "render", "--out", "out/real/footage"],
            ["{py}", "-m", "clothfit", "extract", "out/real/footage", "-o", "out/real/capture", "--force"],
            [
                "{py}",
                "lab/render_footage.py",
                "score",
                "--footage",
                "out/real/footage",
                "--capture",
                "out/real/capture",
                "--json",
                "out/real/score_auto.json",
            ],
            [
                "{py}",
                "lab/render_footage.py",
                "score",
                "--footage",
                "out/real/footage",
                "--capture",
                "out/real/capture_single",
                "--single-plate",
                "--json",
                "out/real/score_single.json",
            ],
            [
                "{py}",
                "lab/render_footage.py",
                "score",
                "--footage",
                "out/real/footage",
                "--capture",
                "out/real/capture_sw1",
                "--shadow-window",
                "1",
                "--json",
                "out/real/score_sw1.json",
            ],
            [
                "{py}",
                "lab/render_footage.py",
                "score",
                "--footage",
                "out/real/footage",
                "--capture",
                "out/real/capture_norefine",
                "--refine",
                "0",
                "--json",
                "out/real/score_norefine.json",
            ],
            [
                "{py}",
                "lab/render_footage.py",
                "score",
                "--footage",
                "out/real/footage",
                "--capture",
                "out/real/capture_otsu",
                "--threshold",
                "otsu",
                "--json",
                "out/real/score_otsu.json",
            ],
            [
                "{py}",
                "lab/render_footage.py",
                "score",
                "--footage",
                "out/real/footage",
                "--capture",
                "out/real/capture_noshadow",
                "--shadow-min",
                "1",
                "--json",
                "out/real/score_noshadow.json",
            ],
            [
                "{py}",
                "lab/render_footage.py",
                "score",
                "--footage",
                "out/real/footage",
                "--capture",
                "out/real/capture_noblur",
                "--blur",
                "0",
                "--json",
                "out/real/score_noblur.json",
            ],
            [
                "{py}",
                "lab/render_footage.py",
                "score",
                "--footage",
                "out/real/footage",
                "--capture",
                "out/real/capture_paper",
                "--threshold",
                "otsu",
                "--luma-weight",
                "1",
                "--shadow-min",
                "1",
                "--blur",
                "0",
                "--refine",
                "0",
                "--json",
                "out/real/score_paper.json",
            ],
        ],
        "outputs": {
            "footage": "out/real/footage/footage.json",
            "auto": "out/real/score_auto.json",
            "single_plate": "out/real/score_single.json",
            "shadow_window_1": "out/real/score_sw1.json",
            "no_refine": "out/real/score_norefine.json",
            "otsu": "out/real/score_otsu.json",
            "no_shadow": "out/real/score_noshadow.json",
            "no_blur": "out/real/score_noblur.json",
            "paper_recipe": "out/real/score_paper.json",
        },
        "cost": "expensive",
        "what": "photoreal footage rendered by Cycles, extracted: IoU per variant (about 20 min)",
    },
    "footage_fit": {
        "steps": [
            [
                "{py}",
                "lab/render_footage.py",
                "fit",
                "--capture",
                "out/real/capture",
                "--footage",
                "out/real/footage",
                "--cameras",
                "2,4,8,16",
                "--evals",
                "3000",
                "--seed",
                str(s),
                "--json",
                f"out/real/fit_auto_s{s}.json",
            ]
            for s in (0, 1, 2)
        ]
        + [
            [
                "{py}",
                "lab/render_footage.py",
                "fit",
                "--capture",
                "out/real/capture_paper",
                "--footage",
                "out/real/footage",
                "--cameras",
                "4,16",
                "--evals",
                "3000",
                "--seed",
                "0",
                "--json",
                "out/real/fit_paper_s0.json",
            ]
        ],
        "outputs": {
            "s0": "out/real/fit_auto_s0.json",
            "s1": "out/real/fit_auto_s1.json",
            "s2": "out/real/fit_auto_s2.json",
            "paper_recipe": "out/real/fit_paper_s0.json",
        },
        "cost": "expensive",
        "what": "fits on the extracted footage silhouettes (needs the footage recording's files)",
    },
    "floor_calibration": {
        "steps": [
            ["{py}", "lab/floor_calibration.py", "--out", "out/floor_cal", "--json", "out/floor_cal/calibration.json"]
        ],
        "outputs": {"calibration": "out/floor_cal/calibration.json"},
        "cost": "expensive",
        "what": "the noise-floor estimate (with the true and a wrong model as baseline, and from the images alone) "
        "against the true settings' error as the fit sees it on synthetic captures (both models, 2 rigs, "
        "4 resolutions, 5 noise levels, resampled fits); the photoreal part (--footage, --capture) is not recorded yet",
    },
    "blender_cloth": {
        "steps": [
            ["{py}", "lab/blender_cloth_experiment.py", "check-units", "--json", "out/blendercloth/units.json"],
            ["{py}", "lab/blender_cloth_experiment.py", "observe", "--out", "out/blendercloth/capture"],
            [
                "{py}",
                "lab/blender_cloth_experiment.py",
                "fit",
                "--capture",
                "out/blendercloth/capture",
                "--cameras",
                "4,8,16",
                "--oracle",
                "--json",
                "out/blendercloth/fit.json",
                "--overlays",
                "out/blendercloth/overlays",
            ],
        ],
        "outputs": {"units": "out/blendercloth/units.json", "fit": "out/blendercloth/fit.json"},
        "cost": "expensive",
        "what": "Blender's cloth simulator as the truth, fitted by the paper's sheet",
    },
    "blender_scene_fit_pop12": {
        "argv": ["{py}", "lab/blender_scene_fit.py", "all", "--out", "out/scene_fit_pop12", "--population", "12"],
        "output": "out/scene_fit_pop12/summary.json",
        "cost": "expensive",
        "what": "the same, population 12",
    },
    "blender_scene_fit_2400": {
        "argv": ["{py}", "lab/blender_scene_fit.py", "all", "--out", "out/scene_fit_2400", "--budget", "2400"],
        "output": "out/scene_fit_2400/summary.json",
        "cost": "expensive",
        "what": "the same, 2400 evaluations",
    },
    "blender_scene_fit_480x640": {
        "argv": ["{py}", "lab/blender_scene_fit.py", "all", "--out", "out/scene_fit_480", "--resolution", "480x640"],
        "output": "out/scene_fit_480/summary.json",
        "cost": "expensive",
        "what": "the same, silhouettes at 480 x 640",
    },
    "stopping": {
        "argv": ["{py}", "lab/stopping.py", "--json", "{out}"],
        "cost": "cheap",
        "rtol": 1e-6,
        "what": "fits that stop by themselves: CMA-ES and SPX + MGG on a small capture, budget 100,000",
    },
    "phone_rig_calib_s101": {
        "argv": _phone_rig("calibrate", "calib_s101", 101, "0.375", 14, close=0),
        "cost": "expensive",
        "what": "the phone rig: clothfit calibrate on Cycles renders of a ChArUco board before 4 phones (seed 101), against "
        "the true cameras",
    },
    "phone_rig_calib_s202": {
        "argv": _phone_rig("calibrate", "calib_s202", 202, "0.375", 14, close=4),
        "cost": "expensive",
        "what": "the phone rig: calibrate as docs/phone_rig.md now asks (the board also held close before each phone, 4 poses), seed 202, 405 x 720",
    },
    "phone_rig_calib_s303": {
        "argv": _phone_rig("calibrate", "calib_s303", 303, "0.75", 14, close=4),
        "cost": "expensive",
        "what": "the phone rig: calibrate as docs/phone_rig.md now asks (4 close poses per phone), seed 303, at 810 x 1440 (0.75 of a phone's video)",
    },
    "phone_rig_calib_s404": {
        "argv": _phone_rig("calibrate", "calib_s404", 404, "0.75", 14, close=4),
        "cost": "expensive",
        "what": "the phone rig: calibrate as docs/phone_rig.md now asks (4 close poses per phone), seed 404, at 810 x 1440 (0.75 of a phone's video)",
    },
    "phone_rig_e2e": {
        "argv": _phone_rig("e2e", "e2e_s7", 7, "0.3", 10),
        "cost": "expensive",
        "what": "the phone rig end to end: phones -> calibrate, handles, extract, fit, export-blender-cloth on Cycles "
        "renders, against the same fit given the true cameras and manipulation",
    },
    "phone_rig_e2e_close": {
        "argv": _phone_rig("e2e", "e2e_s7c", 7, "0.3", 10, close=4),
        "cost": "expensive",
        "what": "the phone rig end to end as docs/phone_rig.md now asks: the e2e rig of seed 7 with the board also held "
        "close before each phone (4 poses)",
    },
    "phone_rig_e2e_s8": {
        "argv": _phone_rig("e2e", "e2e_s8", 8, "0.75", 10, close=4),
        "cost": "expensive",
        "what": "the phone rig end to end on a rig not seen before (seed 8) at 810 x 1440 (0.75 of a phone's video), the "
        "board held close before each phone as docs/phone_rig.md asks",
    },
    "phone_rig_e2e_s9": {
        "argv": _phone_rig("e2e", "e2e_s9", 9, "0.75", 10, close=4),
        "cost": "expensive",
        "what": "the phone rig end to end on a rig not seen before (seed 9, a second) at 810 x 1440 (0.75 of a phone's video), the "
        "board held close before each phone as docs/phone_rig.md asks",
    },
    "phone_rig_e2e_s10": {
        "argv": _phone_rig("e2e", "e2e_s10", 10, "0.75", 10, close=4),
        "cost": "expensive",
        "what": "the phone rig end to end on a third rig at 810 x 1440 not seen before (seed 10; about 65 min of renders "
        "on an idle 2-core machine)",
    },
    "phone_rig_e2e_s11": {
        "argv": _phone_rig("e2e", "e2e_s11", 11, "0.75", 10, close=4),
        "cost": "expensive",
        "what": "the phone rig end to end on a fourth rig at 810 x 1440, not seen before, the first with the fit's 0.7 mm clip "
        "box from the start (seed 11; about 65 min of renders on an idle 2-core machine)",
    },
    "phone_rig_sensitivity": {
        "argv": [
            "{py}",
            "lab/phone_rig.py",
            "sensitivity",
            "--seed",
            "7",
            "--frames",
            "15",
            "--e2e",
            "out/phone_rig/e2e_s7",
            "--json",
            "{out}",
        ],
        "cost": "expensive",
        "what": "the phone rig: the true settings replayed under the clips phone_rig_e2e measured, and under clips moved "
        "by 1 mm per axis: how far the clips alone move the cloth (needs that run's folder)",
    },
    "phone_rig_spread_s8": {
        "argv": _spread(8),
        "cost": "expensive",
        "what": "the phone rig: the seed 8 rig's three fits over fit seeds 0-4, and the true settings scored with the "
        "clips as measured and at their true points (needs phone_rig_e2e_s8's folder; about 20 min)",
    },
    "phone_rig_spread_s9": {
        "argv": _spread(9),
        "cost": "expensive",
        "what": "the phone rig: the seed 9 rig's three fits over fit seeds 0-4, and the true settings scored with the "
        "clips as measured and at their true points (needs phone_rig_e2e_s9's folder; about 20 min)",
    },
    "phone_rig_spread_s9_box07": {
        "argv": _spread(9, box=0.0007),
        "cost": "expensive",
        "what": "the phone rig: the seed 9 rig's uncertain fit over fit seeds 0-4 with every clip's box at 0.7 mm "
        "(the capture's: 1.3-1.5 mm), beside the fit given the truth (needs phone_rig_e2e_s9's folder; about 15 min)",
    },
    "phone_rig_spread_s8_box07": {
        "argv": _spread(8, box=0.0007),
        "cost": "expensive",
        "what": "the phone rig: the seed 8 rig's uncertain fit over fit seeds 0-4 with every clip's box at 0.7 mm "
        "(the capture's: 1.7-1.8 mm), beside the fit given the truth (needs phone_rig_e2e_s8's folder; about 15 min)",
    },
    "phone_rig_spread_s10": {
        "argv": _spread(10),
        "cost": "expensive",
        "what": "the phone rig: the unseen seed 10 rig's three fits over fit seeds 0-4, and the true settings scored with "
        "the clips as measured and at their true points (needs phone_rig_e2e_s10's folder; about 20 min)",
    },
    "phone_rig_spread_s10_box07": {
        "argv": _spread(10, box=0.0007),
        "cost": "expensive",
        "what": "the phone rig: the unseen seed 10 rig's uncertain fit over fit seeds 0-4 with every clip's box at the "
        "0.7 mm chosen on the seed 8 and 9 rigs (the capture's: 1.6-1.7 mm), beside the fit given the truth (needs "
        "phone_rig_e2e_s10's folder; about 15 min)",
    },
    "phone_rig_spread_s8_polish": {
        "argv": _spread(8, uncertain_only=True),
        "cost": "expensive",
        "what": "the phone rig: the seed 8 rig's uncertain fit over fit seeds 0-4 since the offsets' polish and the replay "
        "at the fitted offsets (commit e0330c9), beside the fit given the truth (needs phone_rig_e2e_s8's folder; "
        "about 12 min)",
    },
    "phone_rig_spread_s9_polish": {
        "argv": _spread(9, uncertain_only=True),
        "cost": "expensive",
        "what": "the phone rig: the seed 9 rig's uncertain fit over fit seeds 0-4 since the offsets' polish and the replay "
        "at the fitted offsets (commit e0330c9), beside the fit given the truth (needs phone_rig_e2e_s9's folder; "
        "about 12 min)",
    },
    "phone_rig_spread_s8_staged": {
        "argv": _spread(8, optimizer="cma-staged"),
        "cost": "expensive",
        "what": "the phone rig: the seed 8 rig's uncertain fit over fit seeds 0-4 with cma-staged (the three settings and "
        "the time offset first, the clips held where clicked; then everything), beside the fit given the truth "
        "(needs phone_rig_e2e_s8's folder; about 12 min)",
    },
    "phone_rig_spread_s9_staged": {
        "argv": _spread(9, optimizer="cma-staged"),
        "cost": "expensive",
        "what": "the phone rig: the seed 9 rig's uncertain fit over fit seeds 0-4 with cma-staged (the three settings and "
        "the time offset first, the clips held where clicked; then everything), beside the fit given the truth "
        "(needs phone_rig_e2e_s9's folder; about 12 min)",
    },
    "phone_rig_spread_s10_staged": {
        "argv": _spread(10, optimizer="cma-staged"),
        "cost": "expensive",
        "what": "the phone rig: the seed 10 rig's uncertain fit over fit seeds 0-4 with cma-staged (the three settings and "
        "the time offset first, the clips held where clicked; then everything), beside the fit given the truth "
        "(needs phone_rig_e2e_s10's folder; about 12 min)",
    },
    "phone_rig_spread_s11": {
        "argv": _spread(11, uncertain_only=True),
        "cost": "expensive",
        "what": "the phone rig: the unseen seed 11 rig's uncertain fit (in the capture's 0.7 mm clip boxes, the default) over "
        "fit seeds 0-4, beside the fit given the truth (needs phone_rig_e2e_s11's folder; about 8 min)",
    },
    "fit_goals_offsets_polish": {
        "argv": _offsets_with(),
        "cost": "expensive",
        "what": "the offsets goal with the default fit since the offsets' polish and the replay at the fitted "
        "offsets (commit e0330c9), one fit (about 2 min)",
    },
    "blender_scene_fit": {
        "argv": ["{py}", "lab/blender_scene_fit.py", "all", "--out", "out/scene_fit"],
        "output": "out/scene_fit/summary.json",
        "cost": "expensive",
        "what": "the --backend blender fit: a cloth dropped onto a box, fitted with Blender's own solver on Ray",
    },
}


def _fmt_argv(argv):
    return " ".join("python" if a == sys.executable else shlex.quote(a) for a in argv)


def source_argv(name, out_path):
    s = SOURCES[name]
    return [a.replace("{py}", sys.executable).replace("{out}", out_path) for a in s["argv"]]


def source_steps(name):
    """A multi-step source: [argv, ...] run in order; its output is {key: JSON of each file}."""
    return [[a.replace("{py}", sys.executable) for a in step] for step in SOURCES[name]["steps"]]


def source_output(name):
    s = SOURCES[name]
    return os.path.join(ROOT, s.get("output", os.path.join("out", "figures", f"{name}.json")))


def git_state():
    """(short commit, dirty) of the repository: dirty when the code (addon/, tools/, demo_blend/, rigs/;
    not the docs tools) has uncommitted changes."""
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "--short=7", "HEAD"], cwd=ROOT, capture_output=True, text=True, check=True
        ).stdout.strip()
        st = subprocess.run(
            [
                "git",
                "status",
                "--porcelain",
                "--",
                "addon",
                "tools",
                "lab",
                "demo_blend",
                "rigs",
                ":!tools/figures.py",
                ":!tools/docs_check.py",
                ":!tools/docs_views.py",
            ],
            cwd=ROOT,
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown", True
    return commit, bool(st)


def _load1():
    try:
        return round(os.getloadavg()[0], 2)
    except OSError:
        return None


def figures_path(name):
    return os.path.join(FIG_DIR, f"{name}.json")


def load_recording(name):
    path = figures_path(name)
    if not os.path.isfile(path):
        raise SystemExit(
            f"error: no recording {os.path.relpath(path, ROOT)}: run `python tools/figures.py record {name}`"
        )
    with open(path) as f:
        rec = json.load(f)
    if rec.get("format") != FORMAT:
        raise SystemExit(
            f"error: {os.path.relpath(path, ROOT)} is not a figures recording (format {rec.get('format')!r})"
        )
    return rec


def write_recording(name, data, argv_display, commit, dirty, seconds, load_before, load_after, started):
    rec = {
        "format": FORMAT,
        "version": 1,
        "name": name,
        "what": SOURCES[name]["what"],
        "command": argv_display,
        "commit": commit,
        "dirty": dirty,
        "recorded_at": started,
        "seconds": None if seconds is None else round(seconds, 1),
        "cpus": os.cpu_count(),
        "load_1min_before": load_before,
        "load_1min_after": load_after,
        "data": data,
    }
    os.makedirs(FIG_DIR, exist_ok=True)
    path = figures_path(name)
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        json.dump(rec, f, indent=1)
        f.write("\n")
    os.replace(tmp, path)
    return path


def run_source(name, out_path=None, log=None):
    """Run the source's command; returns (argv, seconds, load before, load after, started, output path)."""
    out_path = out_path or source_output(name)
    os.makedirs(os.path.dirname(out_path), exist_ok=True)
    if os.path.isfile(out_path):  # the previous run's output: the command writes it anew (and refuses to replace it)
        os.remove(out_path)
    argv = source_argv(name, out_path)
    started = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    l0 = _load1()
    t0 = time.perf_counter()
    print(f"[figures] {name}: {_fmt_argv(argv)}", flush=True)
    r = subprocess.run(argv, check=False, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT if log else None)
    seconds = time.perf_counter() - t0
    if r.returncode != 0:
        raise SystemExit(f"error: {name}: `{_fmt_argv(argv)}` exited with {r.returncode}")
    if not os.path.isfile(out_path):
        raise SystemExit(f"error: {name}: the command wrote no {os.path.relpath(out_path, ROOT)}")
    return argv, seconds, l0, _load1(), started, out_path


def run_steps(name):
    """Run a multi-step source; returns (command text, seconds, load before, after, started, data)."""
    steps = source_steps(name)
    started = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    l0 = _load1()
    t0 = time.perf_counter()
    for argv in steps:
        print(f"[figures] {name}: {_fmt_argv(argv)}", flush=True)
        r = subprocess.run(argv, check=False, cwd=ROOT)
        if r.returncode != 0:
            raise SystemExit(f"error: {name}: `{_fmt_argv(argv)}` exited with {r.returncode}")
    seconds = time.perf_counter() - t0
    data = {}
    for key, rel in SOURCES[name]["outputs"].items():
        with open(os.path.join(ROOT, rel)) as f:
            data[key] = json.load(f)
    return " && ".join(_fmt_argv(a) for a in steps), seconds, l0, _load1(), started, data


def record(name, from_file=None):
    if name not in SOURCES:
        raise SystemExit(f"error: unknown source {name!r}; known: {', '.join(SOURCES)}")
    commit, dirty = git_state()
    if "steps" in SOURCES[name]:
        cmd, seconds, l0, l1, started, data = run_steps(name)
        path = write_recording(name, data, cmd, commit, dirty, seconds, l0, l1, started)
        print(f"[figures] recorded {os.path.relpath(path, ROOT)} (commit {commit}{', dirty' if dirty else ''})")
        return path
    if from_file:
        out_path = os.path.abspath(from_file)
        argv = source_argv(name, os.path.relpath(out_path, ROOT))
        seconds = l0 = l1 = None
        started = datetime.datetime.fromtimestamp(os.path.getmtime(out_path), datetime.UTC).strftime(
            "%Y-%m-%dT%H:%M:%SZ"
        )
        meta = out_path + ".run.json"  # written by `tools/figures.py run`: the run's own commit
        if os.path.isfile(meta):
            with open(meta) as f:
                m = json.load(f)
            commit, dirty, seconds, l0, l1, started = (
                m["commit"],
                m["dirty"],
                m["seconds"],
                m["load_1min_before"],
                m["load_1min_after"],
                m["started"],
            )
    else:
        os.makedirs(RUN_DIR, exist_ok=True)
        argv, seconds, l0, l1, started, out_path = run_source(name)
    with open(out_path) as f:
        data = json.load(f)
    shown = [a if a != out_path else os.path.relpath(out_path, ROOT) for a in argv]
    path = write_recording(name, data, _fmt_argv(shown), commit, dirty, seconds, l0, l1, started)
    print(f"[figures] recorded {os.path.relpath(path, ROOT)} (commit {commit}{', dirty' if dirty else ''})")
    return path


def run_only(name):
    """Run the command and leave its output plus a ``.run.json`` beside it (record it later with --from)."""
    commit, dirty = git_state()
    argv, seconds, l0, l1, started, out_path = run_source(name)
    with open(out_path + ".run.json", "w") as f:
        json.dump(
            {
                "commit": commit,
                "dirty": dirty,
                "seconds": round(seconds, 1),
                "load_1min_before": l0,
                "load_1min_after": l1,
                "started": started,
                "argv": _fmt_argv(argv),
            },
            f,
            indent=1,
        )
    return out_path


# ------------------------------------------------------------------ rerun: is the recording still true?


def _timing_key(path):
    leaf = path.lower()
    return any(fnmatch.fnmatch(leaf, p) for p in TIMING)


def compare(old, new, rtol=0.0, atol=0.0, path=""):
    """Differences between two JSON values beyond the tolerance, timing keys skipped: list of strings."""
    if _timing_key(path):
        return []
    if isinstance(old, dict) and isinstance(new, dict):
        out = []
        for k in old:
            if k not in new:
                out.append(f"{path}.{k}: missing in the new output")
            else:
                out += compare(old[k], new[k], rtol, atol, f"{path}.{k}" if path else k)
        return out
    if isinstance(old, list) and isinstance(new, list):
        if len(old) != len(new):
            return [f"{path}: {len(old)} items recorded, {len(new)} now"]
        out = []
        for i, (a, b) in enumerate(zip(old, new)):
            out += compare(a, b, rtol, atol, f"{path}.{i}")
        return out
    if (
        isinstance(old, bool)
        or isinstance(new, bool)
        or not isinstance(old, (int, float))
        or not isinstance(new, (int, float))
    ):
        if isinstance(old, str) and isinstance(new, str) and (os.sep in old or old.startswith("/")):
            return []  # paths differ between runs (temporary folders)
        return [] if old == new else [f"{path}: recorded {old!r}, now {new!r}"]
    if old is None or new is None:
        return [] if old == new else [f"{path}: recorded {old!r}, now {new!r}"]
    if math.isnan(old) and math.isnan(new):
        return []
    if abs(new - old) <= atol + rtol * abs(old):
        return []
    return [f"{path}: recorded {old!r}, now {new!r}"]


def rerun(names):
    bad = 0
    for name in names:
        s = SOURCES[name]
        rec = load_recording(name)
        if "steps" in s:
            new = run_steps(name)[-1]
        else:
            with tempfile.TemporaryDirectory() as tmp:
                out_path = os.path.join(tmp, f"{name}.json") if "output" not in s else source_output(name)
                run_source(name, out_path)
                with open(out_path) as f:
                    new = json.load(f)
        diffs = compare(rec["data"], new, s.get("rtol", 0.0), s.get("atol", 0.0))
        if diffs:
            bad += 1
            print(f"{name}: {len(diffs)} figures differ from the recording (commit {rec['commit']}):")
            for d in diffs[:20]:
                print("   ", d)
        else:
            print(f"{name}: the same as recorded (timings not compared)")
    return 1 if bad else 0


DEMO_PICTURES = os.path.join(ROOT, "out", "demo", "pictures")
DOCS_IMG = os.path.join(ROOT, "docs", "img")


def _sha256(path):
    import hashlib

    with open(path, "rb") as f:
        return hashlib.sha256(f.read()).hexdigest()


def copy_pictures():
    """Copy the pictures of the recorded demo run (docs/figures/demo.json) from out/demo/pictures to
    docs/img, refusing any picture that is not the one that run made."""
    import shutil

    pics = load_recording("demo")["data"]["story"]["pictures"]
    for name, sha in pics.items():
        src = os.path.join(DEMO_PICTURES, name)
        if not os.path.isfile(src) or _sha256(src) != sha:
            raise SystemExit(
                f"error: {os.path.relpath(src, ROOT)} is not the picture of the recorded demo run "
                f"(docs/figures/demo.json): run `make docs-images` (demo + record + copy)"
            )
        shutil.copyfile(src, os.path.join(DOCS_IMG, name))
        print(f"[figures] docs/img/{name}")


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python tools/figures.py", description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    sub.add_parser("list", help="every source and its recording")
    r = sub.add_parser("record", help="run a source's command and record its output in docs/figures/")
    r.add_argument("names", nargs="+", help="source names (see list), or 'cheap'")
    r.add_argument(
        "--from", dest="from_file", help="record this file (written by the source's command) instead of running it"
    )
    r = sub.add_parser("run", help="run a source's command, keep its output for `record --from` (long runs)")
    r.add_argument("names", nargs="+")
    sub.add_parser("pictures", help="copy the recorded demo run's pictures to docs/img")
    r = sub.add_parser("rerun", help="run the cheap sources again and compare with their recordings")
    r.add_argument("names", nargs="*", help="default: every cheap source")
    a = ap.parse_args(argv)
    if a.cmd == "list":
        for name, s in SOURCES.items():
            p = figures_path(name)
            if os.path.isfile(p):
                rec = load_recording(name)
                state = f"recorded {rec['recorded_at']} at {rec['commit']}{' (dirty)' if rec['dirty'] else ''}"
            else:
                state = "not recorded"
            cmd = (
                " && ".join(_fmt_argv(a) for a in source_steps(name))
                if "steps" in s
                else _fmt_argv(source_argv(name, "out/figures/" + name + ".json"))
            )
            print(f"{name:24s} {s['cost']:9s} {state}\n    {cmd}")
        return 0
    if a.cmd == "pictures":
        copy_pictures()
        return 0
    names = a.names if a.cmd != "rerun" or a.names else [n for n, s in SOURCES.items() if s["cost"] == "cheap"]
    if names == ["cheap"]:
        names = [n for n, s in SOURCES.items() if s["cost"] == "cheap"]
    for n in names:
        if n not in SOURCES:
            raise SystemExit(f"error: unknown source {n!r}; known: {', '.join(SOURCES)}")
    if a.cmd == "record":
        if a.from_file and len(names) != 1:
            raise SystemExit("error: --from records one source")
        for n in names:
            record(n, a.from_file)
        return 0
    if a.cmd == "run":
        for n in names:
            run_only(n)
        return 0
    return rerun(names)


if __name__ == "__main__":
    sys.exit(main())
