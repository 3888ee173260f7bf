# SPDX-License-Identifier: GPL-3.0-or-later
"""All scene state of Cloth Fit: one PropertyGroup at ``scene.clothfit`` (saved with the .blend).

Defaults come from ``core/defaults.py`` (the paper's scenario and ground truth). Blender stores
float properties in single precision: the fit's exact numbers are in the result JSON.
"""

from __future__ import annotations

import bpy
from bpy.props import (
    BoolProperty,
    CollectionProperty,
    EnumProperty,
    FloatProperty,
    IntProperty,
    PointerProperty,
    StringProperty,
)

from ..core import defaults as D
from ..core.footage.extract import ExtractOptions

OPTIMIZERS = [
    ("auto", "Auto", f"{D.BLENDER_OPTIMIZER} on Blender's cloth with weak settings free, else {D.DEFAULT_OPTIMIZER}"),
    ("spx-mgg", "SPX + MGG", "Real-coded GA: simplex crossover, minimal generation gap (the paper's)"),
    ("cma-es", "CMA-ES", "Covariance matrix adaptation evolution strategy"),
    (
        "cma-staged",
        "CMA-ES, strong first",
        "Blender's cloth: tension, shear, bending and air first, then every setting",
    ),
]
RESOLUTIONS = [
    ("FULL", "Full", "Fit at the capture's resolution"),
    ("240x320", "240 x 320", "Fit at 240 x 320 (H x W)"),
    ("120x160", "120 x 160", "Fit at 120 x 160 (H x W)"),
    ("60x80", "60 x 80", "Fit at 60 x 80 (H x W)"),
]


# Blender 4.5 warns about "//" paths unless the property says it supports them (option new in 4.5)
PATH_OPTIONS = {"PATH_SUPPORTS_BLEND_RELATIVE"} if bpy.app.version >= (4, 5, 0) else set()


def _times_default():
    t = D.FRAME_TIMES
    step = round(t[1] - t[0], 6)
    return f"{t[0]:g}:{t[-1]:g}:{step:g}"


def _view_frame_update(self, context):
    from . import api

    try:
        api.show_observations(context.scene, self.view_frame)
    except api.ClothFitError as e:  # an update callback cannot report: say it on the console
        print(f"Cloth Fit: cannot show capture frame {self.view_frame}: {e}")


def _is_empty(self, obj):
    return obj.type == "EMPTY"


class ClothFitHandleLink(bpy.types.PropertyGroup):
    """One handle of the Empties manipulation: grid vertex (row, column) follows an empty."""

    empty: PointerProperty(
        name="Empty",
        type=bpy.types.Object,
        poll=_is_empty,
        description="Empty whose world position (animated or not) the grid vertex follows",
    )
    row: IntProperty(
        name="Row",
        default=0,
        min=0,
        max=1023,
        description="Grid row of the vertex (vertex index = row x grid columns + column)",
    )
    column: IntProperty(name="Column", default=0, min=0, max=1023, description="Grid column of the vertex")
    use_release: BoolProperty(
        name="Release", default=False, description="Let the vertex go at the release time (free after it)"
    )
    release_time: FloatProperty(
        name="Release Time",
        default=0.0,
        unit="TIME_ABSOLUTE",
        description="Time [s] at which the vertex is released (t = 0 ends the settling)",
    )


class ClothFitTake(bpy.types.PropertyGroup):
    """Another take of the same cloth (a capture folder), fitted together with the loaded capture"""

    directory: StringProperty(
        name="Capture",
        subtype="DIR_PATH",
        options=PATH_OPTIONS,
        default="",
        description="The take's capture folder (capture.json, cameras.json, silhouettes)",
    )


class ClothFitTakeResult(bpy.types.PropertyGroup):
    """One take of the last fit of several takes: its name (``name``), verdict and frame rate"""

    verdict: StringProperty(name="Verdict", default="", description="The take's verdict in one line")
    verdict_kind: StringProperty(name="Verdict kind", default="", description="at_floor, far_above, ...")
    fps: FloatProperty(name="Frame Rate", default=0.0, description="The frame rate the take was fitted at")


THRESHOLD_MODES = [
    ("AUTO", "Auto", "Noise-model threshold per camera, never below 2 levels (default)"),
    ("OTSU", "Otsu", "Otsu's threshold on each camera's difference histogram"),
    ("NOISE", "Noise", "Noise-model threshold without the floor"),
    ("NUMBER", "Number", "One fixed threshold (difference units, 0..255 scale)"),
]
CAMERA_FORMATS = [
    ("OPENCV", "OpenCV YAML", "One OpenCV FileStorage file (.yml/.yaml/.json/.xml) with every camera"),
    ("OPENCV_DIR", "OpenCV Folder", "A folder with one OpenCV .yml file per camera"),
    ("COLMAP", "COLMAP", "A COLMAP text model folder (cameras.txt, images.txt, points3D.txt)"),
    ("JSON", "Cloth Fit JSON", "Our cameras JSON (the capture format's cameras.json)"),
]


class ClothFitProperties(bpy.types.PropertyGroup):
    """Cloth Fit's settings and results for this scene"""

    # ------------------------------------------------------------------ rig
    rig_source: EnumProperty(
        name="Rig",
        items=[
            ("PRESET", "Preset", "A camera rig file from rigs/ (or a path to a cameras JSON)"),
            ("RING", "Ring", "A parametric ring of cameras around the cloth"),
        ],
        default="PRESET",
        description="Where Build Rig takes its cameras from",
    )
    rig_preset: StringProperty(
        name="Preset",
        default=D.DEFAULT_RIG,
        subtype="FILE_PATH",
        options=PATH_OPTIONS,
        description="Rig preset name in rigs/ (lab18, ring8) or a path to a cameras JSON",
    )
    cameras_file: StringProperty(
        name="Calibration",
        subtype="FILE_PATH",
        options=PATH_OPTIONS,
        default="",
        description="Calibrated cameras to import: OpenCV FileStorage YAML/JSON/XML file, "
        "a folder of them, or a COLMAP text model folder",
    )
    cameras_export_path: StringProperty(
        name="Export To",
        subtype="FILE_PATH",
        options=PATH_OPTIONS,
        default="",
        description="Where Export Cameras writes: a .yml/.json/.xml file or a folder",
    )
    cameras_export_format: EnumProperty(
        name="Format", items=CAMERA_FORMATS, default="OPENCV", description="File format Export Cameras writes"
    )
    rig_cameras_json: StringProperty(
        name="Exact Cameras",
        default="",
        description="The rig's cameras as imported or loaded (OpenCV K, R, t, lens "
        "distortion; JSON): what export and rendering use while the "
        "Blender cameras still show them",
    )
    ring_cameras: IntProperty(name="Cameras", default=8, min=1, max=64, description="Cameras on the ring")
    ring_elevation: FloatProperty(
        name="Elevation",
        default=25.0,
        min=-89.0,
        max=89.0,
        description="Elevation of the ring above the target [degrees]",
    )
    ring_distance: FloatProperty(
        name="Distance", default=0.5, min=0.01, unit="LENGTH", description="Distance of every camera from the target"
    )
    ring_target_z: FloatProperty(
        name="Target Height", default=0.06, unit="LENGTH", description="Height of the point the cameras look at"
    )
    ring_fx: FloatProperty(name="Focal (px)", default=1000.0, min=1.0, description="Focal length in pixels (fx = fy)")
    ring_width: IntProperty(name="Width", default=D.IMAGE_W, min=4, max=16384, description="Image width [px]")
    ring_height: IntProperty(name="Height", default=D.IMAGE_H, min=4, max=16384, description="Image height [px]")

    # ---------------------------------------------------------------- cloth
    cloth_nx: IntProperty(name="Grid", default=D.GRID_N, min=2, max=128, description="Point masses per side")
    cloth_side: FloatProperty(
        name="Side",
        default=D.CLOTH_SIDE,
        min=1e-4,
        unit="LENGTH",
        precision=4,
        description="Side length of the square cloth",
    )
    cloth_height: FloatProperty(
        name="Height", default=D.CLOTH_HEIGHT, unit="LENGTH", precision=4, description="Height of the held corners"
    )
    scenario_source: EnumProperty(
        name="Manipulation",
        items=[
            ("SETTINGS", "Paper", "All four corners held, one released at t = 0 (the settings here)"),
            ("CAPTURE", "Capture", "The loaded capture's handles, settling and cloth (set by Load Capture)"),
            ("EMPTIES", "Empties", "Grid vertices follow the linked empties (keyframe them to move the cloth)"),
        ],
        default="SETTINGS",
        description="How the cloth is held and moved",
    )
    released_corner: IntProperty(
        name="Released Corner",
        default=D.RELEASED_CORNER,
        min=0,
        max=3,
        description="Corner released at t = 0 (0..3; the other three stay held)",
    )
    capture_releases: StringProperty(
        name="Releases",
        default="",
        description="The loaded capture's released handles and their times (all of them are replayed)",
    )
    cloth_object: PointerProperty(name="Cloth", type=bpy.types.Object, description="The cloth mesh Build Cloth made")
    handles: CollectionProperty(
        name="Handles", type=ClothFitHandleLink, description="Empties manipulation: grid vertices linked to empties"
    )
    handles_index: IntProperty(name="Active Handle", default=0, min=0, description="The handle selected in the list")
    new_handle_row: IntProperty(
        name="Row", default=0, min=0, max=1023, description="Grid row of the vertex Add Handle Empty links"
    )
    new_handle_column: IntProperty(
        name="Column", default=0, min=0, max=1023, description="Grid column of the vertex Add Handle Empty links"
    )

    # ----------------------------------------------------------- simulation
    m: FloatProperty(
        name="m", default=D.GT_PARAMS["m"], min=1e-12, precision=6, unit="MASS", description="Point mass [kg]"
    )
    k: FloatProperty(name="k", default=D.GT_PARAMS["k"], min=1e-9, precision=4, description="Spring coefficient [N/m]")
    l: FloatProperty(
        name="l",
        default=D.GT_PARAMS["l"],
        min=1e-9,
        precision=5,
        unit="LENGTH",
        description="Natural length of the grid springs [m] (diagonals: sqrt(2) l)",
    )
    d: FloatProperty(name="d", default=D.GT_PARAMS["d"], min=0.0, precision=6, description="Viscous damping [N s/m]")
    settle_time: FloatProperty(
        name="Settle",
        default=D.SETTLE_TIME,
        min=0.0,
        unit="TIME_ABSOLUTE",
        description="Settling time before t = 0, all handles held",
    )
    frame_times: StringProperty(
        name="Times", default=_times_default(), description="Capture times in seconds: start:stop:step or a comma list"
    )

    # --------------------------------------------------------- observations
    capture_dir: StringProperty(
        name="Capture",
        subtype="DIR_PATH",
        options=PATH_OPTIONS,
        default="//clothfit_capture/",
        description="Capture directory (capture.json, cameras.json, sil/...)",
    )
    noise: FloatProperty(
        name="Noise",
        default=D.NOISE_FRACTION,
        min=0.0,
        max=1.0,
        precision=3,
        description="Fraction of boundary pixels flipped in rendered silhouettes",
    )
    noise_seed: IntProperty(
        name="Noise Seed", default=0, min=0, description="Seed of the boundary noise (same seed, same silhouettes)"
    )
    render_engine: EnumProperty(
        name="Engine",
        items=[
            ("WORKBENCH", "Workbench", "Flat Workbench render, anti-aliasing off (occluders drawn black = holdout)"),
            ("EEVEE", "Eevee", "Eevee, one sample, zero pixel filter (occluders as real holdouts)"),
        ],
        default="WORKBENCH",
        description="Renderer of the silhouettes. Objects in the collection 'Occluders' hide the cloth and are "
        "written as ignore masks (pixels of unknown truth)",
    )
    footage_kind: EnumProperty(
        name="Footage",
        items=[
            ("IMAGES", "Images", "Per camera a folder with background plates and the frames"),
            ("VIDEOS", "Videos", "One video per camera (<camera>.mp4|mov|mkv|avi), plates, a sync file"),
        ],
        default="IMAGES",
        description="What the footage folder holds",
    )
    footage_dir: StringProperty(
        name="Footage",
        subtype="DIR_PATH",
        options=PATH_OPTIONS,
        default="",
        description="Footage folder: <camera>/background*.png and frames per camera, "
        "optional footage.json and calibration; for videos: the videos folder",
    )
    footage_plates: StringProperty(
        name="Plates",
        subtype="DIR_PATH",
        options=PATH_OPTIONS,
        default="",
        description="Videos: background plate per camera, <camera>.png|jpg or a video "
        "of the empty scene (median frame)",
    )
    footage_sync: StringProperty(
        name="Sync",
        subtype="FILE_PATH",
        options=PATH_OPTIONS,
        default="",
        description="Videos: JSON {camera: video time [s] at t = 0} (written here when found from a flash)",
    )
    footage_find_sync: BoolProperty(
        name="Sync from Flash",
        default=False,
        description="Videos: find the sync times from a flash seen by every camera",
    )
    footage_flash_time: FloatProperty(
        name="Flash Time", default=0.0, unit="TIME_ABSOLUTE", description="Videos: capture time of the flash [s]"
    )
    extract_calibration: StringProperty(
        name="Calibration",
        subtype="FILE_PATH",
        options=PATH_OPTIONS,
        default="",
        description="Calibrated cameras (empty: the footage's footage.json / "
        "cameras.* / COLMAP folder, else the imported rig cameras)",
    )
    extract_times: StringProperty(
        name="Times", default="", description="Frame times of the footage frames (empty: footage.json's)"
    )
    extract_capture_dir: StringProperty(
        name="Output",
        subtype="DIR_PATH",
        options=PATH_OPTIONS,
        default="",
        description="Capture directory to write (empty: the Capture directory above)",
    )
    extract_threshold_mode: EnumProperty(
        name="Threshold",
        items=THRESHOLD_MODES,
        default="AUTO",
        description="How each camera's foreground threshold is chosen",
    )
    extract_threshold: FloatProperty(
        name="Value",
        default=10.0,
        min=0.01,
        max=255.0,
        precision=2,
        description="Fixed threshold (difference units, 0..255 scale)",
    )
    extract_camera_thresholds: StringProperty(
        name="Per Camera", default="", description="Per-camera threshold overrides, e.g. cam03=9.5, cam07=12"
    )
    extract_luma_weight: FloatProperty(
        name="Luma Weight",
        default=ExtractOptions.luma_weight,
        min=0.0,
        max=10.0,
        precision=2,
        description="Weight of the luma difference against chroma (low = shadows count less)",
    )
    extract_shadow_min: FloatProperty(
        name="Shadow Min",
        default=ExtractOptions.shadow_min,
        min=0.01,
        max=1.0,
        precision=2,
        description="Background dimmed down to this brightness ratio counts as shadow (1 = no shadow model)",
    )
    extract_debug: BoolProperty(
        name="Debug Images", default=False, description="Write images of every extraction step into <output>/debug"
    )
    extract_status: StringProperty(name="Extraction", default="", description="Summary of the last extraction")
    fit_takes: CollectionProperty(
        name="Other Takes",
        type=ClothFitTake,
        description="Other takes of the same cloth, fitted together with the loaded capture (one set of settings)",
    )
    fit_takes_index: IntProperty(name="Active Take", default=0, min=0, description="The take selected in the list")
    view_frame: IntProperty(
        name="Show Frame",
        default=0,
        min=0,
        update=_view_frame_update,
        description="Capture frame whose silhouettes the cameras show as background",
    )

    # -------------------------------------------------------------- fitting
    train_cameras: IntProperty(
        name="Training Cameras",
        default=8,
        min=1,
        max=64,
        description="Cameras used for fitting (spread around the rig); the rest are held out",
    )
    train_times: EnumProperty(
        name="Training Times",
        items=[
            ("PAPER", "Paper", "t = 0.10, 0.20, ... (those present in the capture)"),
            ("ALL", "All", "Every frame of the capture"),
        ],
        default="PAPER",
        description="Capture times the fit compares",
    )
    optimizer: EnumProperty(
        name="Optimiser", items=OPTIMIZERS, default=D.FIT_OPTIMIZER, description="Search method of the fit"
    )
    seed: IntProperty(name="Seed", default=0, min=0, description="Seed of the optimiser (same seed, same fit)")
    max_evaluations: IntProperty(
        name="Budget", default=D.FIT_EVALUATIONS, min=1, description="Maximum number of model evaluations"
    )
    fit_resolution: EnumProperty(
        name="Resolution",
        items=RESOLUTIONS,
        default="FULL",
        description="Image size the fit compares silhouettes at (smaller: faster)",
    )
    fit_model: EnumProperty(
        name="Model",
        items=[
            ("PAPER", "Paper Sheet", "The paper's mass-spring sheet: m, k, l, d"),
            (
                "BLENDER",
                "Blender Cloth",
                "Blender's own cloth solver: fits Cloth modifier settings for the scene's "
                "frame rate, applied with Apply Blender Cloth",
            ),
        ],
        default="PAPER",
        description="The cloth model whose parameters the fit finds",
    )
    fit_quality: IntProperty(
        name="Quality",
        default=5,
        min=1,
        max=80,
        description="Blender model: the Cloth modifier's quality (solver steps per frame)",
    )
    fit_bending_model: EnumProperty(
        name="Bending",
        items=[
            ("ANGULAR", "Angular", "Blender's default bending model"),
            ("LINEAR", "Linear", "Blender's linear bending model"),
        ],
        default="ANGULAR",
        description="Blender model: the Cloth modifier's bending model",
    )
    fit_cloth_mass: FloatProperty(
        name="Cloth Mass",
        default=0.0,
        min=0.0,
        unit="MASS",
        precision=6,
        description="Weighed cloth mass (0 = the capture's); fixes m, since only k/m, d/m and l are observable",
    )

    # --------------------------------------------------- live status/results
    fit_running: BoolProperty(name="Running", default=False, description="A fit is running in this scene")
    fit_progress: FloatProperty(
        name="Progress",
        default=0.0,
        min=0.0,
        max=1.0,
        subtype="FACTOR",
        description="Share of the fit's evaluation budget used",
    )
    fit_generation: IntProperty(name="Generation", default=0, description="Optimiser generations done")
    fit_evaluations: IntProperty(name="Evaluations", default=0, description="Model evaluations done")
    fit_best_error: FloatProperty(
        name="Best E_all",
        default=0.0,
        precision=5,
        description="Best total silhouette error so far (sum over the training images)",
    )
    fit_best_pct: FloatProperty(
        name="Mean E_sil %", default=0.0, precision=4, description="Best mean silhouette error per image so far [%]"
    )
    fit_has_result: BoolProperty(name="Has Result", default=False, description="The fit found parameters")
    fit_best_m: FloatProperty(name="m", default=0.0, precision=6, unit="MASS", description="Fitted point mass [kg]")
    fit_best_k: FloatProperty(name="k", default=0.0, precision=4, description="Fitted spring coefficient [N/m]")
    fit_best_l: FloatProperty(
        name="l", default=0.0, precision=5, unit="LENGTH", description="Fitted natural spring length"
    )
    fit_best_d: FloatProperty(name="d", default=0.0, precision=6, description="Fitted damping [N s/m]")
    fit_best_blender: StringProperty(
        name="Fitted Blender Cloth", default="", description="ClothSettings of the best Blender-model fit (JSON)"
    )
    fit_status: StringProperty(name="Status", default="", description="What the fit is doing or how it ended")
    fit_verdict: StringProperty(
        name="Verdict", default="", description="The finished fit in one line: at its floor, or why not"
    )
    fit_verdict_kind: StringProperty(name="Verdict kind", default="", description="at_floor, far_above, ...")
    fit_intervals: StringProperty(
        name="Intervals",
        default="",
        description="How sure each fitted setting is: value, 90 % interval, UNDETERMINED where the capture cannot tell it",
    )
    fit_take_results: CollectionProperty(
        name="Fitted Takes",
        type=ClothFitTakeResult,
        description="Each take of the last fit of several takes, with its verdict",
    )
    apply_take: StringProperty(
        name="Take",
        default="",
        description="The take of the fit Apply Blender Cloth replays and whose frame rate it sets "
        "(empty: the loaded capture's)",
    )
    result_path: StringProperty(
        name="Result",
        subtype="FILE_PATH",
        options=PATH_OPTIONS,
        default="",
        description="The fit's result JSON (Apply Fit reads it)",
    )
    overlay_source: EnumProperty(
        name="Model",
        items=[
            ("BLENDER", "Blender", "Model silhouettes rendered by Blender from the baked cloth"),
            ("CORE", "Core", "Model silhouettes from the core rasteriser (fast)"),
        ],
        default="BLENDER",
        description="Where Overlays takes the model's silhouettes from",
    )
    overlay_dir: StringProperty(
        name="Overlays", subtype="DIR_PATH", options=PATH_OPTIONS, default="", description="Folder of the last overlays"
    )
    overlay_error: FloatProperty(
        name="Overlay E_sil %", default=0.0, precision=4, description="Mean silhouette error of the last overlays [%]"
    )


CLASSES = (ClothFitHandleLink, ClothFitTake, ClothFitTakeResult, ClothFitProperties)


def register_scene_property():
    bpy.types.Scene.clothfit = PointerProperty(type=ClothFitProperties)


def unregister_scene_property():
    if hasattr(bpy.types.Scene, "clothfit"):
        del bpy.types.Scene.clothfit
