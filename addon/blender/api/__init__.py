# SPDX-License-Identifier: GPL-3.0-or-later
"""Scripting facade of the Blender layer: what the operators call, usable from any script.

Every function takes the scene (its ``scene.clothfit`` properties hold the settings) and raises
``ClothFitError`` on bad input; the operators turn that into a report. Typical pipeline::

    from addon.blender import api            # or bl_ext.<repo>.silhouette_cloth_fit.addon.blender
    api.build_rig(scene); api.build_cloth(scene); api.simulate(scene)
    cap = api.render_silhouettes(scene, "out/capture")
    result = api.run_fit(scene); api.apply_fit(scene); api.make_overlays(scene)

This file only hands names on. The work lives by concern: ``reading`` (the scene read once into
core objects: ``read_scene``), ``cameras`` (rig, import/export), ``building`` (cloth, handles,
simulate), ``rendering`` (Render Silhouettes), ``footage`` (extract, load a capture, camera
backgrounds), ``fitting`` (fit session, run, apply), ``takes`` (other takes of the cloth fitted together with the
loaded capture, the take Apply replays), ``overlays``; ``steps`` cuts long calls into
steps for the modal operators (``render_steps``, ``simulate_steps``, ``extract_steps``).
"""

from ...core.errors import ClothFitError  # noqa: F401
from ...core.fitting.result import FitResult  # noqa: F401 (what run_fit and load_result return)
from .. import render as R  # noqa: F401
from .. import scene as S  # noqa: F401
from .building import (  # noqa: F401
    HANDLE_COLLECTION,
    add_handle_empty,
    build_cloth,
    remove_handle,
    simulate,
    simulate_steps,
)
from .cameras import EXPORT_FORMATS, build_rig, export_cameras, import_cameras, set_rig  # noqa: F401
from .fitting import (  # noqa: F401
    BLENDER_CLOTH_NAME,
    RESULT_JSON,
    RESULT_JSON_BLENDER,
    FitSession,
    apply_blender_cloth,
    apply_fit,
    finish_fit,
    fit_config,
    fit_step,
    fit_tick,
    load_result,
    run_fit,
    show_verdict,
    start_fit,
    take_scenario,
    take_settings,
)
from .footage import (  # noqa: F401
    EXTRACT_GENERATOR,
    OVERLAY_DIR,
    THRESHOLD_MODES,
    extract_silhouettes,
    extract_steps,
    load_capture,
    overlay_path,
    parse_camera_thresholds,
    show_background,
    show_observations,
)
from .overlays import make_overlays, model_masks_blender, model_masks_core  # noqa: F401
from .reading import (  # noqa: F401
    EXACT_MATCH_TOL,
    PAR_APPROX_LIMIT,
    SceneInputs,
    abspath,
    blender_view_cameras,
    cameras_from_json,
    cameras_to_json,
    capture_dir,
    capture_scenario,
    cloth_object,
    empties_scenario,
    exact_rig_cameras,
    grid_from_props,
    handle_links,
    params_from_scene,
    params_to_scene,
    parse_times,
    props,
    read_scene,
    refuse_foreign_capture,
    rig_cameras,
    rig_from_props,
    scenario_for,
    scene_grid,
    scene_scenario,
)
from .rendering import (  # noqa: F401
    BAKE_TOL,
    GENERATOR_PREFIX,
    check_bake_follows_handles,
    render_silhouettes,
    render_steps,
)
from .steps import Steps  # noqa: F401
from .takes import add_take, chosen_take, remove_take, show_take_verdicts, take_captures  # noqa: F401
