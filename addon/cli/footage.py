"""The footage commands: extract, calibrate, import-cameras, export-cameras, handles."""

from __future__ import annotations

import os
import sys

from ..core import defaults as D
from ..core.errors import ClothFitError
from .common import add_command, floats, force_arg, pair, refuse_existing, refuse_filled_folder
from .points import add_points


def add_extract_arguments(parser):
    """Arguments of ``clothfit extract`` (run by :func:`cmd_extract`)."""
    _extract_input_args(parser)
    _extract_mask_args(parser)
    return parser


def _extract_input_args(parser):
    """``extract``'s inputs and output: footage, videos, sync, calibration, times, scenario."""
    parser.add_argument(
        "footage",
        nargs="?",
        help="footage folder: <camera>/background*.png + frames, optional footage.json (or --videos)",
    )
    parser.add_argument("--videos", help="folder of videos, one per camera: <camera>.<mp4|mov|mkv|avi>")
    parser.add_argument(
        "--plates",
        help="with --videos: background plates <camera>.<png|jpg> or a video of the empty scene (median frame)",
    )
    parser.add_argument("--sync", help="with --videos: JSON {camera: video time [s] at t = 0}")
    parser.add_argument(
        "--find-sync",
        choices=["flash"],
        help="with --videos: find the sync times from a flash seen by every camera (written to --sync if given)",
    )
    parser.add_argument(
        "--flash-time", type=float, default=0.0, help="capture time [s] of the flash (default: %(default)s)"
    )
    parser.add_argument("-o", "--out", required=True, help="capture folder to write (new or empty unless --force)")
    force_arg(parser, "the files of a capture already in --out")
    parser.add_argument(
        "--cameras",
        help="calibration: our cameras JSON, OpenCV YAML/JSON/XML file or folder, COLMAP "
        "model folder (default: footage.json's, else a cameras.* or "
        "calibration.* file in the footage folder)",
    )
    parser.add_argument("--times", help="frame times [s], comma separated (default: footage.json's)")
    parser.add_argument(
        "--scenario",
        help="JSON with the scenario (cloth + handles), e.g. a capture.json "
        "(default: footage.json's, else the paper's scenario)",
    )
    parser.add_argument("--cloth-mass", type=float, help="weighed cloth mass [kg] (default: footage.json's, if any)")
    parser.add_argument(
        "--uncertain",
        help="the capture's uncertain bounds, time_offset=S,handles=M (seconds, metres) "
        "or none (default: the --scenario file's, else footage.json's, else with "
        "--videos one frame period for the time)",
    )


def _extract_mask_args(parser):
    """``extract``'s silhouette options: threshold, clean-up, empty, undistort, cameras, debug."""
    from ..core.footage.extract import ExtractOptions

    parser.add_argument(
        "--threshold", default="auto", help="difference threshold: auto, otsu, noise or a number (default: %(default)s)"
    )
    parser.add_argument(
        "--camera-threshold",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="threshold of one camera, overriding --threshold (repeatable)",
    )
    parser.add_argument(
        "--luma-weight",
        type=float,
        default=ExtractOptions.luma_weight,
        help="weight of the luma difference against chroma, against shadows (default: %(default)s)",
    )
    parser.add_argument(
        "--shadow-min",
        type=float,
        default=ExtractOptions.shadow_min,
        help="background dimmed down to this brightness ratio counts as shadow, 1 = off (default: %(default)s)",
    )
    parser.add_argument(
        "--noise-k",
        type=float,
        default=ExtractOptions.noise_k,
        help="noise threshold = median + this factor x robust sigma (default: %(default)s)",
    )
    parser.add_argument(
        "--blur",
        type=float,
        default=ExtractOptions.blur,
        help="Gaussian sigma [px] on both images before differencing, 0 = off (default: %(default)s)",
    )
    parser.add_argument(
        "--open",
        type=int,
        default=ExtractOptions.open_radius,
        dest="open_radius",
        help="morphological opening radius [px], 0 = off (default: %(default)s)",
    )
    parser.add_argument(
        "--close",
        type=int,
        default=ExtractOptions.close_radius,
        dest="close_radius",
        help="morphological closing radius [px], 0 = off (default: %(default)s)",
    )
    parser.add_argument("--no-largest", action="store_true", help="keep every component (default: only the largest)")
    parser.add_argument(
        "--no-fill-holes", action="store_true", help="keep holes inside the silhouette (default: filled)"
    )
    parser.add_argument(
        "--refine",
        type=int,
        default=ExtractOptions.refine_radius,
        dest="refine_radius",
        help="boundary refinement radius [px], 0 = off (default: %(default)s)",
    )
    parser.add_argument(
        "--min-area",
        type=int,
        default=ExtractOptions.min_area,
        help="a silhouette smaller than this [px] counts as nothing found (default: %(default)s)",
    )
    parser.add_argument(
        "--allow-empty",
        action="store_true",
        help="nothing found = a warning and an empty silhouette (default: an error)",
    )
    parser.add_argument(
        "--undistort", action="store_true", help="undistort silhouettes, write cameras without distortion"
    )
    parser.add_argument(
        "--camera",
        action="append",
        dest="camera_names",
        help="extract only this camera (repeatable; default: every camera)",
    )
    parser.add_argument("--debug", dest="debug_dir", help="write debug images of every step here")


def extract_options(args):
    """The ExtractOptions of parsed ``extract`` arguments."""
    from ..core.footage.extract import ExtractOptions

    per = {}
    for item in args.camera_threshold or []:
        if "=" not in item:
            raise ClothFitError(f"--camera-threshold {item!r}: expected NAME=VALUE")
        n, v = item.split("=", 1)
        try:
            per[n.strip()] = float(v)
        except ValueError:
            raise ClothFitError(f"--camera-threshold {item!r}: {v!r} is not a number") from None
    return ExtractOptions(
        threshold=args.threshold,
        thresholds=per,
        luma_weight=args.luma_weight,
        shadow_min=args.shadow_min,
        noise_k=args.noise_k,
        blur=args.blur,
        open_radius=args.open_radius,
        close_radius=args.close_radius,
        keep_largest=not args.no_largest,
        fill_holes=not args.no_fill_holes,
        refine_radius=args.refine_radius,
        min_area=args.min_area,
        allow_empty=args.allow_empty,
        undistort=args.undistort,
        debug_dir=args.debug_dir,
    ).check()


def cmd_extract(args):
    """Run an extraction from parsed :func:`add_extract_arguments` arguments; prints a summary (for people)
    and returns the report."""
    from ..core.footage.extract import extract_capture, format_report

    times = None
    if args.times:
        try:
            times = [float(t) for t in args.times.split(",") if t.strip()]
        except ValueError:
            raise ClothFitError(f"--times {args.times!r}: not a comma-separated list of numbers") from None
    extract_options(args)  # a bad option is named before the folder is looked at
    refuse_filled_folder(args.out, getattr(args, "force", False))
    if args.videos:
        rep = _run_videos(args, times)
    else:
        if not args.footage:
            raise ClothFitError("extract: give a footage folder, or --videos DIR --plates DIR --sync SYNC.json")
        rep = extract_capture(
            args.footage,
            args.out,
            cameras=args.cameras,
            frame_times=times,
            scenario=args.scenario,
            cloth_mass=args.cloth_mass,
            options=extract_options(args),
            camera_names=args.camera_names,
            uncertain=getattr(args, "uncertain", None),
        )
    print(format_report(rep))
    print(f"wrote capture {args.out} ({len(rep['cameras'])} cameras x {len(rep['frame_times'])} frames)")
    return rep


def _run_videos(args, times):
    import time

    from ..core.footage import calib_io, video
    from ..core.footage.extract import extract_videos

    if args.footage:
        raise ClothFitError(f"extract: a footage folder ({args.footage}) and --videos exclude each other")
    if not args.plates:
        raise ClothFitError("extract --videos needs --plates DIR (background plate per camera)")
    if not args.cameras:
        raise ClothFitError("extract --videos needs --cameras (the calibration)")
    sizes = video.video_sizes(args.videos) if calib_io.detect_format(args.cameras) == "easymocap" else None
    cams = calib_io.import_cameras(args.cameras, sizes=sizes)
    if args.camera_names:
        cams = [c for c in cams if c.name in args.camera_names]
    if args.find_sync:
        sync = video.flash_sync(args.videos, [c.name for c in cams], args.flash_time, args.sync)
        print("sync from the flash: " + ", ".join(f"{k} {v:.4f} s" for k, v in sync.items()))
    elif args.sync:
        sync = args.sync
    else:
        raise ClothFitError("extract --videos needs --sync SYNC.json (or --find-sync flash)")
    tty = sys.stderr.isatty() or os.environ.get("CLOTHFIT_PROGRESS") == "1"
    t0 = time.time()

    def progress(done, total, text):
        if tty:
            n = int(30 * done / max(total, 1))
            sys.stderr.write(f"\r[{'#' * n}{'.' * (30 - n)}] {text:<24} {time.time() - t0:.0f}s ")
            sys.stderr.flush()

    try:
        return extract_videos(
            args.videos,
            args.plates,
            sync,
            args.out,
            cams,
            times,
            scenario=args.scenario,
            cloth_mass=args.cloth_mass,
            options=extract_options(args),
            progress=progress,
            uncertain=getattr(args, "uncertain", None),
        )
    finally:
        if tty:
            sys.stderr.write("\n")


def add_cameras_arguments(p, cmd):
    """Arguments of ``clothfit import-cameras`` / ``clothfit export-cameras`` (``cmd``); run by :func:`cmd_cameras`."""
    from ..core.footage.calib_io import FORMATS

    if cmd == "import-cameras":
        p.add_argument(
            "src",
            help="calibration file or folder: OpenCV YAML/JSON/XML, a folder of those, a COLMAP "
            "model folder, EasyMocap intri/extri, or our cameras JSON",
        )
        p.add_argument("-o", "--out", required=True, help="cameras JSON to write (our format)")
        p.add_argument(
            "--format",
            default="auto",
            choices=FORMATS,
            help="format of SRC; auto: by file extension and folder contents (default: %(default)s)",
        )
    else:
        p.add_argument(
            "src",
            help="cameras to export: our cameras JSON, a capture (folder or capture.json) or any "
            "calibration import-cameras reads",
        )
        p.add_argument("-o", "--out", required=True, help="file or folder to write (opencv-dir and colmap: a folder)")
        p.add_argument(
            "--format",
            default="auto",
            choices=[f for f in FORMATS if f != "easymocap"],
            help="format to write; auto: by the extension of --out, .json = json, .yml/.yaml/.xml = "
            "opencv, anything else (a folder) = colmap (default: %(default)s)",
        )
    p.add_argument("--width", type=int, help="image width [px] when the OpenCV file has none")
    p.add_argument("--height", type=int, help="image height [px] when the OpenCV file has none")
    force_arg(p, "--out")
    p.set_defaults(cameras_cmd=cmd)
    return p


def cmd_cameras(a):
    """Run ``import-cameras`` / ``export-cameras`` from parsed :func:`add_cameras_arguments` arguments: prints a
    table of the cameras (for people) and returns ``{"command", "out", "cameras": [names]}``."""
    from ..core.footage.calib_io import cameras_from_any, describe, export_cameras, import_cameras

    refuse_existing(a.out, a.force)
    if a.cameras_cmd == "import-cameras":
        cams = import_cameras(a.src, a.format, a.width, a.height)
        export_cameras(cams, a.out, "json")
    else:
        cams = cameras_from_any(a.src, "auto", a.width, a.height)
        export_cameras(cams, a.out, a.format)
    print(describe(cams))
    print(f"{'imported' if a.cameras_cmd == 'import-cameras' else 'exported'} {len(cams)} cameras -> {a.out}")
    return {"command": a.cameras_cmd, "out": a.out, "cameras": [c.name for c in cams]}


def cmd_handles(a):
    from ..core.footage import handles as H

    refuse_existing(a.out, a.force)
    size = pair(a.size, "--size")
    grid = None
    if a.grid:
        grid = pair(a.grid, "--grid", int) if "x" in a.grid.lower() else None
        if grid is None:
            try:
                grid = int(a.grid)
            except ValueError:
                raise ClothFitError(
                    f"--grid {a.grid!r} must be a count (vertices along the longer side) or COLUMNSxROWS"
                ) from None
    opts = H.HandleOptions(
        clip_size=a.clip_size,
        mark_sigma=a.mark_sigma,
        max_residual=a.max_residual,
        fb_max=a.fb_max,
        departure_min=a.departure_min / 1000.0,
        max_pin_offset=a.max_pin_offset / 1000.0,
        smooth=a.smooth,
        levels=a.levels,
        settle_time=a.settle,
    )
    tty = sys.stderr.isatty() or os.environ.get("CLOTHFIT_PROGRESS") == "1"

    def progress(i, n, text):
        if tty:
            print(f"[{i}/{n}] {text}", file=sys.stderr)

    doc = H.run(
        a.out,
        a.marks,
        size,
        footage=a.footage,
        videos=a.videos,
        sync=a.sync,
        find_sync=a.find_sync == "flash",
        flash_time=a.flash_time,
        cameras=a.cameras,
        times=floats(a.times),
        fps=a.fps,
        start=a.start,
        frames=a.frames,
        grid=grid,
        options=opts,
        progress=progress,
    )
    print(H.format_report(doc["report"]))
    print(f"wrote {a.out}: the scenario for `clothfit extract --scenario {a.out}`")
    return dict(doc["report"], out=a.out, uncertain=doc["uncertain"])


def _gravity(text):
    """--gravity CAMERA:GX,GY,GZ -> (camera, (gx, gy, gz))."""
    if not text:
        return None
    cam, sep, vec = text.rpartition(":")
    if not sep or not cam:
        raise ClothFitError(f"--gravity {text!r}: expected CAMERA:GX,GY,GZ (gravity in that camera's axes)")
    v = floats(vec, "--gravity")
    if not v or len(v) != 3:
        raise ClothFitError(f"--gravity {text!r}: expected three numbers after the camera name")
    return cam, tuple(v)


def cmd_calibrate(a):
    from ..core.footage import calibrate as CB

    board = CB.parse_board(a.board, a.legacy_board)
    if a.make_board:
        if a.folder:
            raise ClothFitError("--make-board writes a board to print: give no FOLDER")
        stem = os.path.splitext(a.out)[0] if a.out.lower().endswith((".png", ".pdf")) else a.out
        for path in (stem + ".png", stem + ".pdf"):
            refuse_existing(path, a.force, "board")
        r = CB.make_board(board, stem + ".png", stem + ".pdf", a.dpi, a.margin)
        print(
            f"wrote {r['png']} ({r['png_px'][0]} x {r['png_px'][1]} px at {r['png_dpi']:.1f} dpi) and {r['pdf']} "
            f"({r['pdf_page_mm'][0]:.1f} x {r['pdf_page_mm'][1]:.1f} mm): print at 100 %, then measure a square "
            f"({board.square_m * 1000:g} mm)"
        )
        return r
    if not a.folder:
        raise ClothFitError("calibrate needs FOLDER (one folder of images or one video per camera), or --make-board")
    for path, what in ((a.out, "--out"), (a.export, "--export"), (a.report, "--report")):
        refuse_existing(path, a.force, what)
    fixed = {}
    if a.intrinsics:
        from ..core.footage.calib_io import import_cameras

        fixed = {c.name: c for c in import_cameras(a.intrinsics)}
    opts = CB.Options(
        distortion=a.distortion,
        square_pixels=not a.free_aspect,
        shared=a.shared_intrinsics,
        fixed=fixed,
        world=a.world,
        level=a.level,
        gravity=_gravity(a.gravity),
        min_views=a.min_views,
        min_corners=a.min_corners,
        blur_ratio=a.blur_ratio,
    ).check()
    sync = None
    if a.sync or a.find_sync:
        src = CB.find_source(a.folder)
        if src.kind != "videos":
            raise ClothFitError(f"--sync / --find-sync are for videos; {a.folder} holds camera folders of images")
        from ..core.footage import video

        if a.find_sync:
            sync = video.flash_sync(a.folder, src.cameras, a.flash_time)
            print("sync from the flash: " + ", ".join(f"{k} {v:.4f} s" for k, v in sync.items()))
        else:
            sync = video.read_sync(a.sync, src.cameras)
    elif a.every is not None or a.times:
        raise ClothFitError("--every and --times sample videos: they need --sync FILE or --find-sync flash")
    res, det, src = CB.calibrate_folder(
        a.folder,
        board,
        opts,
        sync=sync,
        every=a.every,
        times=floats(a.times) if a.times else None,
        debug_dir=a.debug,
        log=lambda s: print(s),
    )
    written = CB.write_outputs(res, a.out, a.export, a.format, a.report)
    for c in res.report["cameras"]:
        print(
            f"{c['name']:<12} RMS {c['rms_px']:.3f} px  views {c['views_used']} ({c['views_shared']} shared)  "
            f"fx {c['fx']:.1f}  centre {[round(x, 3) for x in c['centre_m']]} m  (spread: rotation "
            f"{c['rotation_sd_deg']:.2f} deg, centre {c['centre_sd_mm']:.1f} mm, principal point "
            f"{c['principal_point_sd_px']:.1f} px)"
        )
    print(
        f"overall RMS {res.report['rms_px']:.3f} px over {res.report['corners']} corners, "
        f"{res.report['moments']} moments; world: board at {res.report['world']['moment']}, up from "
        f"{res.report['world']['up']}"
    )
    print("wrote " + ", ".join(written.values()))
    return dict(res.report, written=written)


def _calibrate_args(s):
    _calibrate_board_args(s)
    _calibrate_solve_args(s)
    return s


def _calibrate_board_args(s):
    """``calibrate``'s input, board, output and world options."""
    s.add_argument(
        "folder",
        nargs="?",
        help="one folder per camera (named after it) of images named by moment, the same name in every "
        "camera = the same moment; or one video per camera, <camera>.<mp4|mov|mkv|avi>",
    )
    s.add_argument(
        "--board",
        required=True,
        help="SQUARES_X,SQUARES_Y,SQUARE_M,MARKER_M,DICTIONARY in OpenCV's CharucoBoard layout, e.g. "
        "9,7,0.04,0.03,DICT_5X5_100 (sizes in metres: measure the print)",
    )
    s.add_argument(
        "--legacy-board",
        action="store_true",
        help="the board was made by OpenCV before 4.6 (differs only for an even number of rows)",
    )
    s.add_argument(
        "--out",
        required=True,
        help="cameras JSON to write (our format); with --make-board: the board's file name, .png and .pdf are written",
    )
    force_arg(s, "--out, --export and --report (or the board's files)")
    s.add_argument(
        "--make-board",
        action="store_true",
        help="write a printable board (PNG and vector PDF at the stated square size) instead",
    )
    s.add_argument(
        "--dpi",
        type=float,
        default=D.CALIB_BOARD_DPI,
        help="--make-board: PNG resolution [pixels per inch] (default: %(default)s)",
    )
    s.add_argument(
        "--margin",
        type=float,
        default=D.CALIB_BOARD_MARGIN_M,
        help="--make-board: white margin round the board [m] (default: %(default)s)",
    )
    s.add_argument(
        "--world",
        metavar="MOMENT",
        help="the moment whose board pose is the world: origin at the chessboard's centre, X along "
        "its squares_x side, Z up out of the face (default: the first moment seen)",
    )
    up = s.add_mutually_exclusive_group()
    up.add_argument(
        "--level",
        metavar="MOMENT",
        help="a moment where the board lies level: its normal is up (when the world board is not level)",
    )
    up.add_argument(
        "--gravity",
        metavar="CAMERA:GX,GY,GZ",
        help="the direction gravity pulls, in that camera's axes (x right, y down, z forward in its "
        "images), e.g. from the phone's accelerometer (default: the world board's normal is up)",
    )


def _calibrate_solve_args(s):
    """``calibrate``'s estimation, video, debug and export options."""
    from ..core.footage import calibrate as CB
    from ..core.footage.calib_io import FORMATS

    s.add_argument(
        "--distortion",
        default=D.CALIB_DISTORTION,
        choices=list(CB.DISTORTION_MODELS),
        help="the distortion coefficients estimated (OpenCV's k1, k2, p1, p2, k3) (default: %(default)s)",
    )
    s.add_argument(
        "--free-aspect", action="store_true", help="estimate fx and fy separately (default: square pixels, fx = fy)"
    )
    s.add_argument(
        "--intrinsics",
        metavar="FILE",
        help="hold these cameras' intrinsics and distortion fixed (matched by name; any file "
        "import-cameras reads); only their poses are estimated",
    )
    s.add_argument(
        "--shared-intrinsics",
        action="store_true",
        help="one set of intrinsics for every estimated camera (the same phone model and zoom)",
    )
    s.add_argument(
        "--min-views",
        type=int,
        default=D.CALIB_MIN_VIEWS,
        help="usable views a camera needs for its own intrinsics (default: %(default)s)",
    )
    s.add_argument(
        "--min-corners",
        type=int,
        default=D.CALIB_MIN_CORNERS,
        help="ChArUco corners a view needs (default: %(default)s)",
    )
    s.add_argument(
        "--blur-ratio",
        type=float,
        default=D.CALIB_BLUR_RATIO,
        help="skip a frame whose board sharpness is below this fraction of its camera's median, "
        "0 = keep all (default: %(default)s)",
    )
    s.add_argument("--sync", help="videos: JSON {camera: video time [s] at capture time 0}")
    s.add_argument("--find-sync", choices=["flash"], help="videos: the sync from a flash every camera saw")
    s.add_argument(
        "--flash-time", type=float, default=0.0, help="videos: capture time [s] of the flash (default: %(default)s)"
    )
    s.add_argument(
        "--every",
        type=float,
        default=None,
        help=f"videos: one moment every this many seconds over the span all videos cover "
        f"(default: {D.CALIB_VIDEO_EVERY_S})",
    )
    s.add_argument("--times", help="videos: the capture times [s] to use, comma separated (default: --every)")
    s.add_argument(
        "--debug",
        metavar="DIR",
        help="draw the detected markers and corners (and the calibration's reprojections) per camera "
        "and moment into DIR/<camera>/<moment>.jpg, also when the calibration fails",
    )
    s.add_argument("--export", metavar="PATH", help="also write the cameras in another format (see --format)")
    s.add_argument(
        "--format",
        default="auto",
        choices=[f for f in FORMATS if f != "easymocap"],
        help="format of --export; auto: by its extension, .json ours, .yml/.yaml/.xml OpenCV, "
        "anything else a COLMAP folder (default: %(default)s)",
    )
    s.add_argument("--report", metavar="FILE", help="also write the full report (stdout's JSON) to this file")


def _add_calibration(sub):
    """``extract``, ``calibrate``, ``import-cameras``, ``export-cameras``."""
    add_extract_arguments(
        add_command(
            sub,
            "extract",
            cmd_extract,
            "silhouettes from camera images or videos: background difference, automatic "
            "threshold, clean-up; writes a capture",
            "the extraction report as JSON",
        )
    )
    _calibrate_args(
        add_command(
            sub,
            "calibrate",
            cmd_calibrate,
            "calibrate cameras from a ChArUco board: intrinsics, distortion and poses, "
            "world = the board on the table, Z up",
            "the calibration report as JSON (per camera the "
            "reprojection RMS, the views used, every view's RMS), or the board written with "
            "--make-board",
        )
    )
    add_cameras_arguments(
        add_command(
            sub,
            "import-cameras",
            cmd_cameras,
            "read a calibration (OpenCV YAML/JSON/XML, COLMAP, EasyMocap) into our cameras JSON",
            "the command, --out and the camera names as JSON",
        ),
        "import-cameras",
    )
    add_cameras_arguments(
        add_command(
            sub,
            "export-cameras",
            cmd_cameras,
            "write cameras (ours, a capture's or any calibration) as OpenCV YAML/JSON/XML, "
            "OpenCV files per camera or a COLMAP text model",
            "the command, --out and the camera names as JSON",
        ),
        "export-cameras",
    )


def _add_handles(sub):
    """``handles``: the manipulation from footage."""
    s = add_command(
        sub,
        "handles",
        cmd_handles,
        "the manipulation from footage: marked clips triangulated, tracked, their release found, the "
        "cloth placed; writes the scenario for extract --scenario",
        "the report as JSON (per handle: vertex, residual px and mm, track length, release frame; the "
        "cloth's placement; the uncertain block)",
    )
    s.add_argument(
        "footage",
        nargs="?",
        help="footage folder: <camera>/ frames (background* files skipped), optional footage.json (or --videos)",
    )
    s.add_argument(
        "--marks",
        required=True,
        help="marks JSON: per handle its pixel in >= 2 cameras at one frame, "
        "'at' on the cloth, motion, released (docs/phone_rig.md, step 6)",
    )
    s.add_argument(
        "--size",
        required=True,
        help="the cloth's measured size WIDTHxHEIGHT [m], e.g. 0.30x0.40 (width "
        "= along grid columns, 'at' u; height = rows, 'at' v)",
    )
    s.add_argument("-o", "--out", required=True, help="scenario JSON to write (scenario + uncertain + report)")
    force_arg(s, "--out")
    s.add_argument(
        "--grid",
        help="vertices along the longer side (the other side's makes square cells), or "
        "COLUMNSxROWS (default: about 16, chosen so the clips' 'at' fall on vertices)",
    )
    s.add_argument(
        "--cameras",
        help="calibration: our cameras JSON, OpenCV, COLMAP or EasyMocap (default: the "
        "footage's footage.json / cameras.* / calibration.* / COLMAP folder)",
    )
    s.add_argument("--videos", help="folder of videos, one per camera: <camera>.<mp4|mov|mkv|avi>")
    s.add_argument("--sync", help="with --videos: JSON {camera: video time [s] at t = 0} (written with --find-sync)")
    s.add_argument("--find-sync", choices=["flash"], help="with --videos: sync times from a flash every camera sees")
    s.add_argument("--flash-time", type=float, default=0.0, help="capture time [s] of the flash (default: %(default)s)")
    s.add_argument("--times", help="frame times [s], comma separated (default: footage.json's, else --fps)")
    s.add_argument(
        "--fps",
        type=float,
        help="frames per second: frame k at START + k / FPS (every image of a folder; with --videos, --frames of them)",
    )
    s.add_argument(
        "--start", type=float, default=0.0, help="with --fps: time [s] of the first frame (default: %(default)s)"
    )
    s.add_argument("--frames", type=int, help="with --videos --fps: how many frames")
    s.add_argument(
        "--clip-size",
        type=float,
        default=D.HANDLE_CLIP_SIZE_M,
        help="a clip's size [m]: the tracking window is its size in each camera (default: %(default)s; "
        "'size' per handle in the marks)",
    )
    s.add_argument(
        "--mark-sigma",
        type=float,
        default=D.HANDLE_MARK_SIGMA_PX,
        help="pixel noise of a mark (a click), the floor of each handle's uncertainty (default: %(default)s)",
    )
    s.add_argument(
        "--max-residual",
        type=float,
        default=D.HANDLE_MAX_RESIDUAL_PX,
        help="a camera missing the triangulated point by more [px] is a wrong mark or a drifted track "
        "(default: %(default)s)",
    )
    s.add_argument(
        "--fb-max",
        type=float,
        default=D.HANDLE_FB_MAX_PX,
        help="forward-backward tracking error [px] beyond which a track is lost (default: %(default)s)",
    )
    s.add_argument(
        "--levels", type=int, default=D.HANDLE_LK_LEVELS, help="Lucas-Kanade pyramid levels (default: %(default)s)"
    )
    s.add_argument(
        "--departure-min",
        type=float,
        default=1000.0 * D.HANDLE_DEPARTURE_MIN_M,
        help="a released handle has left its pin when further than this [mm] (and 6x its held jitter) "
        "(default: %(default)s)",
    )
    s.add_argument(
        "--max-pin-offset",
        type=float,
        default=1000.0 * D.HANDLE_MAX_PIN_OFFSET_M,
        help="a clip further than this [mm] from its vertex of the placed cloth is an error (default: %(default)s)",
    )
    s.add_argument(
        "--smooth",
        type=int,
        default=D.HANDLE_SMOOTH_FRAMES,
        help="moving handles: local quadratic over +-this many frames, 0 = raw (default: %(default)s)",
    )
    s.add_argument(
        "--settle",
        type=float,
        default=D.FOOTAGE_SETTLE_TIME,
        help="seconds of settling before t = 0 written into the scenario (default: %(default)s)",
    )


def register(sub):
    """The footage family, in the order of ``--help``."""
    _add_calibration(sub)
    _add_handles(sub)
    add_points(sub)
