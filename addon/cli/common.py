"""What every command shares: the exit codes and output habits (``EPILOG``), the parser, the options
more than one command takes (model, cameras and times, search, farm), the converters of option text,
and the run-and-report path (messages to stderr, one JSON document on stdout)."""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import signal
import sys
import threading

from ..core import defaults as D
from ..core.errors import ClothFitError

PROG = "clothfit"
EXIT_FAILURE = 1  # an unexpected failure (a bug or the machine): one line, CLOTHFIT_DEBUG=1 for the traceback
EXIT_BAD_DATA = 2  # a ClothFitError: a file or value the command cannot use
EXIT_USAGE = 64  # the parser rejected the command line (sysexits.h EX_USAGE)
EXIT_INTERRUPTED = 130  # Ctrl-C (128 + SIGINT, the shells' convention)

EPILOG = f"""\
output:
  stdout carries one JSON document, the command's result, and nothing else (clothfit fit ... | jq .params);
  progress, tables and every other message for people go to stderr. Not JSON: `tables` (text tables),
  `export-blender-cloth --python` (Python), --help and --version.
exit codes:
  0 done; {EXIT_FAILURE} an unexpected failure (set CLOTHFIT_DEBUG=1 for the traceback); {EXIT_BAD_DATA} bad data: a file or
  value the command cannot use, one line naming it; {EXIT_USAGE} a command line the parser rejects (unknown command or
  option, missing or mistyped value); {EXIT_INTERRUPTED} interrupted by Ctrl-C: `fit` first writes its best result
  so far to --out and reports it on stdout."""


class Text(str):
    """A command result printed as text, not JSON (``tables``, ``export-blender-cloth --python``)."""


class Interrupted(Exception):
    """Ctrl-C after a command kept its work: ``result`` is still reported, then exit code 130."""

    def __init__(self, message, result=None):
        super().__init__(message)
        self.result = result


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Descriptions and epilogs keep their line breaks; option help is wrapped as usual."""


class ArgumentParser(argparse.ArgumentParser):
    """argparse with the CLI's habits: a usage error exits with EXIT_USAGE (64), not argparse's 2,
    which is the code of bad data here."""

    def __init__(self, *args, **kw):
        kw.setdefault("formatter_class", HelpFormatter)
        super().__init__(*args, **kw)

    def error(self, message):
        self.print_usage(sys.stderr)
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message}\n")


def floats(s, what="--times"):
    if not s:
        return None
    try:
        return [float(x) for x in s.split(",") if x.strip()]
    except ValueError:
        raise ClothFitError(f"{what} {s!r} must be a comma-separated list of numbers") from None


def res(s):
    if not s:
        return None
    from ..core.fitting.config import check_resolution

    try:
        h, w = (int(x) for x in s.lower().split("x"))
    except ValueError:
        raise ClothFitError(f"resolution {s!r} must look like HxW, e.g. 120x160") from None
    return check_resolution([h, w], f"resolution {s!r}")


def params_arg(args, default=None):
    if getattr(args, "params", None):
        d = json_arg(args.params, "--params")
        if "params" in d and not d.get("params") and not d.get("blender_cloth"):
            raise ClothFitError(f"--params {args.params}: 'params' is empty (a fit that never evaluated?)")
        return d
    if default is not None:
        return default
    return dict(D.GT_PARAMS)


def model_spec(a):
    """--model/--fps/--quality/--bending-model -> a model dict (None: not asked for)."""
    name = getattr(a, "model", None)
    given = lambda k: getattr(a, k, None) is not None and not (k == "quality" and getattr(a, k) == "auto")  # noqa: E731
    if name is None:
        if any(given(k) for k in ("fps", "quality", "bending_model")):
            name = "blender"
        else:
            return None
    spec = {"name": name}
    if name == "blender":
        for k in ("fps", "quality", "bending_model"):
            if given(k):
                spec[k] = getattr(a, k)
    elif any(given(k) for k in ("fps", "quality", "bending_model")):
        raise ClothFitError("--fps, --quality and --bending-model belong to --model blender")
    return spec


def capture_truth(cap):
    """The parameters a synthetic capture was made with (for evaluate/overlay without --params)."""
    meta = cap.meta or {}
    if meta.get("true_blender_cloth"):
        return {
            "model": meta.get("true_model") or "blender",
            "blender_cloth": meta["true_blender_cloth"],
            "blender_scene": {"fps": (meta.get("true_model") or {}).get("fps", D.BLENDER_FPS)},
        }
    return None


def camera_selection(capture, spec):
    """Camera selection: None = all; "n:4" = 4 spread cameras; "0,3,5" indices; names allowed."""
    from ..core.observation.camera import select_training

    if not spec:
        return None
    if spec.startswith(("n:", "spread:", "heldout:")):
        try:
            n = int(spec.split(":")[1])
        except ValueError:
            raise ClothFitError(f"--cameras {spec!r}: the count after ':' must be an integer") from None
        train, held = select_training(capture.cameras, n)
        return held if spec.startswith("heldout:") else train
    out = []
    for tok in spec.split(","):
        tok = tok.strip()
        if tok.isdigit():
            c = int(tok)
            if not 0 <= c < len(capture.cameras):
                raise ClothFitError(f"--cameras: index {c} outside 0..{len(capture.cameras) - 1}")
            out.append(c)
        else:
            out.append(capture.camera_index(tok))
    return out


def time_selection(spec, capture=None):
    """--times: None = all; 'train' / 'test'; 'even' / 'odd' (every other frame of ``capture``: the first,
    third... / the second, fourth..., whatever its frame rate); else a comma list of times [s]."""
    if not spec:
        return None
    if spec in ("even", "odd"):
        if capture is None:
            raise ClothFitError(f"--times {spec}: needs a capture")
        return [float(t) for t in capture.frame_times[(0 if spec == "even" else 1) :: 2]]
    if spec == "train":
        return list(D.TRAIN_TIMES)
    if spec == "test":
        return list(D.TEST_TIMES)
    return floats(spec)


def name_list(spec):
    return [x.strip() for x in spec.split(",") if x.strip()] if spec else None


def json_arg(text, what):
    """An option that takes JSON or a JSON file."""
    if not text:
        return None
    from ..core.jsonio import read_json

    if os.path.isfile(text):
        d = read_json(text, what)
    else:
        try:
            d = json.loads(text)
        except json.JSONDecodeError:
            raise ClothFitError(f"{what} {text!r} is neither a file nor JSON") from None
    if not isinstance(d, dict):
        raise ClothFitError(f"{what} must be a JSON object")
    return d


def pair(text, what, kind=float):
    """``AxB`` -> (a, b)."""
    try:
        a_, b_ = (kind(x) for x in text.lower().replace("×", "x").split("x"))
    except ValueError:
        raise ClothFitError(f"{what} {text!r} must look like {'0.30x0.40' if kind is float else '16x21'}") from None
    return a_, b_


def _quality_arg(text):
    if str(text).strip().lower() == "auto":
        return "auto"
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number of steps per frame or 'auto'") from None


def model_args(s, default_text="the capture's, else paper"):
    from ..core.physics import blender as B

    s.add_argument(
        "--model",
        choices=["paper", "blender"],
        default=None,
        help=f"cloth model: the paper's mass-spring sheet or Blender's cloth solver (default: {default_text})",
    )
    s.add_argument(
        "--fps",
        type=float,
        default=None,
        help="blender model: scene frame rate [frames/s] the settings are for (default: a fit takes the rate its "
        f"capture declares, else the one its frame times are spaced at, else {D.BLENDER_FPS}; synth {D.BLENDER_FPS})",
    )
    s.add_argument(
        "--quality",
        type=_quality_arg,
        default=None,
        help="blender model: solver steps per frame, or 'auto' (default: the capture's, else the fit "
        f"chooses from {', '.join(map(str, D.QUALITY_LADDER))} starting at {B.DEFAULTS['quality']}, "
        "Blender's; --backend blender: the scene's, one rung above it tried)",
    )
    s.add_argument(
        "--bending-model",
        choices=list(B.BENDING_MODELS),
        default=None,
        help=f"blender model: Blender's bending model (default: {B.DEFAULTS['bending_model']})",
    )


def selection_args(s, what="fit"):
    """--cameras / --times: which cameras and frames a command uses."""
    s.add_argument(
        "--cameras",
        help=f"cameras to {what}: 'n:16' (16 spread round the cloth by the spread rule), "
        "'heldout:16' (the others), indices or names, comma separated (default: all)",
    )
    s.add_argument(
        "--times",
        help=f"frame times to {what}: 'train' (0.1, 0.2 ... 1.5 s), 'test' (0.05, 0.15 ... "
        "1.45 s), 'even' / 'odd' (every other frame of each capture, from its first / second), or a comma list "
        "of times [s] (default: every frame of the capture)",
    )


def search_args(s):
    """Options of fit and fit-many: the optimiser and the fit's budget and scale."""
    s.add_argument(
        "--optimizer",
        default=D.FIT_OPTIMIZER,
        help="cma-es, spx-mgg (the paper's real-coded GA), cma-portfolio, cma-staged (Blender's cloth: "
        "tension, shear, bending and air damping first, then every setting; docs/search.md), or auto "
        f"({D.BLENDER_OPTIMIZER} on Blender's cloth when weak settings are free too, else {D.DEFAULT_OPTIMIZER}) "
        "(default: %(default)s)",
    )
    s.add_argument("--seed", type=int, default=0, help="random seed of the optimiser (default: %(default)s)")
    s.add_argument(
        "--max-evaluations",
        type=int,
        default=None,
        help=f"budget: at most this many simulated candidates (default: {D.FIT_EVALUATIONS}; with "
        f"--resume the checkpoint's)",
    )
    s.add_argument(
        "--population", type=int, default=None, help="optimiser population (default: GA 7n = 21, CMA-ES 4 + 3 ln n = 7)"
    )
    s.add_argument(
        "--searches",
        type=int,
        default=None,
        help=f"searches at most: a search that ends above the floor its own jitter allows searches again from another "
        f"seed, adding its budget (default: {D.FIT_SEARCHES}; 1: never; fits of under "
        f"{D.SEARCH_AGAIN_MIN_BUDGET} evaluations search once)",
    )
    s.add_argument(
        "--search",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="an optimiser setting, repeatable: sigma0, cma_active (true/false), tolx, tolfun_per_image, "
        "staged_second_warm (true/false), staged_restart_grid (true/false), ga_eps, ga_stall, portfolio_runs, staged_restart_step, ... (FitConfig's search options; default: the "
        "optimiser's)",
    )
    s.add_argument(
        "--uncertain",
        default=None,
        help="what the manipulation could not measure, estimated with the cloth: 'time_offset=S,handles=M' "
        "(bounds in seconds and metres; true time = capture time - time_offset_s), with ',time_scale=F' the "
        "frame interval known only to a factor F >= 1 (frames and handle paths stretched alike), or 'none' "
        "(default: the capture's 'uncertain' block)",
    )
    s.add_argument(
        "--no-intervals",
        dest="intervals",
        action="store_false",
        help="skip the last stage, each setting's 90 %% interval (a few hundred evaluations: docs/intervals.md; "
        "intervals estimated: %(default)s)",
    )
    s.add_argument(
        "--resolution", help="fit at HxW [px], e.g. 120x160; silhouettes area-resampled (default: the capture's)"
    )
    s.add_argument(
        "--cloth-mass",
        type=float,
        default=None,
        help="total cloth mass [kg]: fixes m, which silhouettes cannot identify (default: the "
        "capture's cloth_mass, else a vertex mass flagged in the result: paper 1e-5 kg, blender "
        "Blender's 0.3 kg, --backend blender the scene's)",
    )


def farm_args(s, what, workers_help=None, address_help=None, executor_help=None):
    """--workers / --address / --executor: where the work runs (fit --backend blender, fit-many, paper);
    a command may word the help its own way."""
    s.add_argument(
        "--workers", type=int, default=None, help=workers_help or f"{what}: worker processes (default: the cores)"
    )
    s.add_argument(
        "--address",
        default=None,
        help=address_help
        or f"{what}: a running Ray cluster (auto, ray://host:port); default: a local Ray instance started for the run",
    )
    s.add_argument(
        "--executor",
        default="auto",
        choices=["auto", "ray", "process"],
        help=executor_help
        or f"{what}: Ray actors or spawned processes; auto = Ray when installed (default: %(default)s)",
    )


def refuse_existing(path, force, what="--out"):
    """Nothing a user made is replaced without --force: an existing file (or a folder that holds
    files) is refused in one line naming it, before anything is written."""
    if path and os.path.isdir(path):
        refuse_filled_folder(path, force, what)
    elif path and os.path.lexists(path) and not force:
        raise ClothFitError(f"{what} {path} exists: --force overwrites it")


def refuse_filled_folder(path, force, what="--out"):
    """A folder a command writes into must be new or empty unless --force (then files of the same
    names are replaced, others kept)."""
    if not path or force or not os.path.lexists(path):
        return
    if not os.path.isdir(path):
        raise ClothFitError(f"{what} {path} exists and is not a folder: --force overwrites it")
    names = sorted(os.listdir(path))
    if names:
        shown = ", ".join(names[:3]) + (", ..." if len(names) > 3 else "")
        raise ClothFitError(f"{what} {path} already holds {len(names)} file(s) ({shown}): --force writes over them")


def force_arg(s, what="the output files"):
    """``--force``: replace what is there (a command refuses to overwrite without it)."""
    s.add_argument("--force", action="store_true", help=f"overwrite {what} (without it an existing one is refused)")


def add_command(sub, name, fn, help, output):
    """One subcommand: ``help`` in the command list and as its description, ``output`` in its epilog."""
    s = sub.add_parser(
        name,
        help=help,
        description=help[0].upper() + help[1:] + ".",
        epilog=f"output: {output}; messages for people on stderr.\nexit codes: 0 done, "
        f"{EXIT_BAD_DATA} bad data, {EXIT_USAGE} usage, {EXIT_INTERRUPTED} Ctrl-C "
        f"(see {PROG} --help).",
    )
    s.set_defaults(fn=fn)
    return s


DEBUG_ENV = "CLOTHFIT_DEBUG"


def one_line(text, limit=1500):
    text = " ".join(str(text).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


@contextlib.contextmanager
def sigint_deferred():
    """Ctrl-C inside waits until the block is done (a result being written is not cut short)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    got = []
    old = signal.signal(signal.SIGINT, lambda *_: got.append(True))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)
    if got and callable(old):
        old(signal.SIGINT, None)


@contextlib.contextmanager
def messages_to_stderr():
    """Inside: whatever the command writes to stdout goes to stderr, at the file-descriptor level too
    (Blender, Ray and other libraries print from C or from threads); the result goes to the real
    stdout afterwards. Without file descriptors (stdout replaced in-process) ``sys.stdout`` alone
    is redirected."""
    try:
        out_fd, err_fd = sys.stdout.fileno(), sys.stderr.fileno()
    except (AttributeError, OSError, ValueError):
        with contextlib.redirect_stdout(sys.stderr):
            yield
        return
    sys.stdout.flush()
    saved = os.dup(out_fd)
    line_buffering = getattr(sys.stdout, "line_buffering", None)
    os.dup2(err_fd, out_fd)
    if line_buffering is False and hasattr(sys.stdout, "reconfigure"):
        sys.stdout.reconfigure(line_buffering=True)  # in order with stderr's lines
    try:
        yield
    finally:
        with contextlib.suppress(OSError, ValueError):
            sys.stdout.flush()
        os.dup2(saved, out_fd)
        os.close(saved)
        if line_buffering is False and hasattr(sys.stdout, "reconfigure"):
            sys.stdout.reconfigure(line_buffering=False)


def _finite(o):
    """NaN and infinities as null: stdout is strict JSON (jq and other parsers refuse NaN)."""
    if isinstance(o, float) and not math.isfinite(o):
        return None
    if isinstance(o, dict):
        return {k: _finite(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_finite(v) for v in o]
    return o


def emit(result):
    """Write a command's result to stdout: text as it is, anything else as one JSON document."""
    if result is None:
        return
    from ..core.jsonio import dumps

    text = result if isinstance(result, Text) else dumps(_finite(json.loads(dumps(result))), strict=True)
    sys.stdout.write(text.rstrip("\n") + "\n")
    sys.stdout.flush()
