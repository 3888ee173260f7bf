"""Captures as segmenters write them: palette / greyscale label PNGs (silhouette_ids, ignore_ids),
alpha mattes, ignore masks; pixels of unknown truth leave eq. 6 in both backends, in evaluate and
in the overlays."""

import json
import os

import numpy as np
import pytest
from clothfit.core import defaults as D
from clothfit.core.errors import ClothFitError
from clothfit.core.fitting.evaluate import evaluate
from clothfit.core.fitting.objective import SilhouetteObjective
from clothfit.core.observation import camera as C
from clothfit.core.observation import overlay, raster
from clothfit.core.observation.capture import load_capture, write_capture
from clothfit.core.observation.png import decode_label_png, read_label_png
from clothfit.core.physics import jit
from clothfit.core.physics.models import simulate
from clothfit.core.physics.scenario import paper_scenario

Image = pytest.importorskip("PIL.Image")

GT = dict(D.GT_PARAMS)
GT_ROW = [GT["m"], GT["k"], GT["l"], GT["d"]]
K10_ROW = [GT["m"], GT["k"] * 1.1, GT["l"], GT["d"]]
H, W = 120, 160
DAVIS_PALETTE = [0, 0, 0, 128, 0, 0, 0, 128, 0, 128, 128, 0, 0, 0, 128, 128, 0, 128]  # DAVIS' first colours
needs_numba = pytest.mark.skipif(not jit.available(), reason="numba not importable: no second backend")


def save_palette_png(path, idx, palette=DAVIS_PALETTE, **kw):
    """The way SAM 2 / XMem / DAVIS tooling writes masks: PIL mode 'P' + putpalette."""
    im = Image.fromarray(idx.astype(np.uint8), mode="P")
    im.putpalette(palette)
    os.makedirs(os.path.dirname(path), exist_ok=True)
    im.save(path, **kw)


# ------------------------------------------------------------------ the PNG reader


@pytest.mark.parametrize("kw", [{}, {"bits": 4, "optimize": True}, {"transparency": 0}, {"interlace": 1}])
def test_palette_png_gives_the_indices(tmp_path, kw):
    rng = np.random.default_rng(1)
    idx = rng.integers(0, 6, (37, 53))
    p = str(tmp_path / "m.png")
    save_palette_png(p, idx, **kw)
    assert np.array_equal(read_label_png(p), idx)


def test_grey_label_png_and_16_bit(tmp_path):
    idx = np.random.default_rng(2).integers(0, 300, (20, 30))
    p = str(tmp_path / "g16.png")
    Image.fromarray(idx.astype(np.uint16)).save(p)
    assert np.array_equal(read_label_png(p), idx)
    p8 = str(tmp_path / "g8.png")
    Image.fromarray((idx % 7).astype(np.uint8), mode="L").save(p8)
    assert np.array_equal(read_label_png(p8), idx % 7)


def test_label_png_refuses_colour_and_junk(tmp_path):
    p = str(tmp_path / "rgb.png")
    Image.fromarray(np.zeros((5, 5, 3), np.uint8)).save(p)
    with pytest.raises(ClothFitError, match="rgb.png.*palette .*or greyscale PNG.*RGB"):
        read_label_png(p)
    with pytest.raises(ClothFitError, match="not a PNG"):
        decode_label_png(b"GIF89a....", "x.gif")
    with pytest.raises(ClothFitError, match="empty"):
        decode_label_png(b"", "e.png")


# ------------------------------------------------------------------ captures of label images


@pytest.fixture(scope="module")
def truth():
    rig = C.load_rig("lab18")
    cams = [rig[i].resized(H, W) for i in (0, 9, 16)]
    sc = paper_scenario(frame_times=[0.1, 0.3, 0.5, 0.8])
    X = simulate(sc, [GT], backend="numpy", safety=D.TRUTH_DT_SAFETY).positions[0]
    sils = [[raster.silhouette(c, X[f], sc.grid.triangles) for f in range(4)] for c in cams]
    return sc, cams, X, sils


def occluder(cam_i, f, shape):
    """A post (vertical bar) and a hand (disc) per image."""
    yy, xx = np.mgrid[0 : shape[0], 0 : shape[1]]
    post = (xx >= 60 + 7 * cam_i) & (xx < 72 + 7 * cam_i)
    hand = (yy - 40 - 5 * f) ** 2 + (xx - 100) ** 2 < 15**2
    return post, hand


def write_label_capture(root, truth, extra=None, ids=(1,), post_id=2, hand_id=3):
    sc, cams, X, sils = truth
    cap = write_capture(root, cams, sc, sils, shapes=X)  # cameras.json, capture.json (binary)
    for ci, cam in enumerate(cams):
        for fi in range(sc.frame_times.size):
            post, hand = occluder(ci, fi, (cam.height, cam.width))
            idx = np.where(sils[ci][fi], ids[0], 0)
            idx[post] = post_id
            idx[hand] = hand_id
            save_palette_png(os.path.join(root, "masks", cam.name, f"{fi:05d}.png"), idx)
    d = json.load(open(os.path.join(root, "capture.json")))
    d["silhouettes"] = "masks/{camera}/{frame:05d}.png"
    d["silhouette_ids"] = list(ids)
    d["ignore_ids"] = [post_id, hand_id]
    d.update(extra or {})
    json.dump(d, open(os.path.join(root, "capture.json"), "w"))
    return cap


def test_label_capture_reads_cloth_and_occluders(tmp_path, truth):
    sc, cams, X, sils = truth
    root = str(tmp_path / "cap")
    write_label_capture(root, truth)
    cap = load_capture(root, validate=True)
    assert cap.has_ignore and cap.masks["silhouette_ids"] == [1]
    for ci in range(3):
        for fi in range(4):
            m, g = cap.load_observation(ci, fi)
            post, hand = occluder(ci, fi, (H, W))
            assert np.array_equal(g, post | hand)
            assert np.array_equal(m, sils[ci][fi] & ~(post | hand))
    assert json.load(open(os.path.join(root, "capture.json")))["ignore_ids"] == [2, 3]
    sub = cap.subset([1], [2])
    assert np.array_equal(sub.load_observation(0, 0)[1], cap.load_observation(1, 2)[1])


def test_label_capture_without_cloth_label_names_the_file(tmp_path, truth):
    root = str(tmp_path / "cap")
    write_label_capture(root, truth, extra={"silhouette_ids": [5]})
    cap = load_capture(root)
    with pytest.raises(ClothFitError) as e:
        cap.load_silhouette(1, 2)
    msg = str(e.value)
    assert "masks/cam09/00002.png" in msg.replace(os.sep, "/") and "no cloth label" in msg and "[5]" in msg
    assert "\n" not in msg


def test_bad_mask_keys(tmp_path, truth):
    root = str(tmp_path / "cap")
    write_label_capture(root, truth)
    p = os.path.join(root, "capture.json")
    d0 = json.load(open(p))
    for change, text in [
        ({"silhouette_ids": []}, "silhouette_ids"),
        ({"silhouette_ids": ["1"]}, "silhouette_ids"),
        ({"ignore_ids": [1]}, "both"),
        ({"matte_threshold": 0.5}, "exclude"),
        ({"silhouette_ids": None}, "needs 'silhouette_ids'"),
        ({"ignore": "ign/{frame}.png"}, "{camera}"),
    ]:
        d = dict(d0)
        d.update(change)
        json.dump(d, open(p, "w"))
        with pytest.raises(ClothFitError, match=text.replace("{", r"\{").replace("}", r"\}")):
            load_capture(root)


def test_alpha_matte_capture(tmp_path, truth):
    sc, cams, X, sils = truth
    root = str(tmp_path / "cap")
    write_capture(root, cams, sc, sils)
    for ci, cam in enumerate(cams):
        for fi in range(4):
            rgba = np.zeros((H, W, 4), np.uint8)
            rgba[..., :3] = 200  # colour is not the matte
            soft = sils[ci][fi].astype(np.float32) * 230
            rgba[..., 3] = soft.astype(np.uint8)
            rgba[0, 0, 3] = 100  # a soft pixel below the threshold: background
            Image.fromarray(rgba, mode="RGBA").save(os.path.join(root, "sil", cam.name, f"{fi:03d}.png"))
    d = json.load(open(os.path.join(root, "capture.json")))
    d["matte_threshold"] = 0.5
    json.dump(d, open(os.path.join(root, "capture.json"), "w"))
    cap = load_capture(root, validate=True)
    assert np.array_equal(cap.load_silhouette(2, 3), sils[2][3])


def test_write_capture_with_ignore_masks(tmp_path, truth):
    sc, cams, X, sils = truth
    ign = [[(lambda p, h: p | h)(*occluder(ci, fi, (H, W))) for fi in range(4)] for ci in range(3)]
    ign[0][0] = None
    cap = write_capture(str(tmp_path / "c"), cams, sc, sils, ignore=ign)
    cap = load_capture(cap.root, validate=True)
    m, g = cap.load_observation(1, 1)
    assert np.array_equal(g, ign[1][1]) and np.array_equal(m, sils[1][1] & ~ign[1][1])
    assert not cap.load_observation(0, 0)[1].any()
    os.remove(cap.ignore_path(2, 3))
    with pytest.raises(ClothFitError, match="ignore mask .*file not found"):
        cap.load_observation(2, 3)


# ------------------------------------------------------------------ eq. 6 with pixels of unknown truth


def brute_esil(obs, mod, ign):
    keep = ~ign
    return np.count_nonzero((obs ^ mod) & keep) / np.count_nonzero(obs & keep)


@pytest.mark.parametrize("backend", ["numpy", pytest.param("numba", marks=needs_numba)])
def test_objective_leaves_ignored_pixels_out(truth, backend):
    sc, cams, X, sils = truth
    ign = [[(lambda p, h: p | h)(*occluder(ci, fi, (H, W))) for fi in range(4)] for ci in range(3)]
    ign[1][2] = None
    obs = [[s.copy() for s in row] for row in sils]
    obs[0][1][ign[0][1]] = True  # whatever the silhouette says under the occluder is ignored
    P = np.array([GT_ROW, K10_ROW])
    esil, _ = SilhouetteObjective(sc, cams, obs, backend=backend, ignore=ign).per_image(P)
    sim = simulate(sc, P, backend="numpy")
    for p in range(2):
        for ci, cam in enumerate(cams):
            for fi in range(4):
                mod = raster.silhouette(cam, sim.positions[p][fi], sc.grid.triangles)
                g = ign[ci][fi] if ign[ci][fi] is not None else np.zeros((H, W), bool)
                assert esil[p, ci, fi] == pytest.approx(brute_esil(obs[ci][fi], mod, g), abs=1e-12)
    # without the ignore masks the same images score differently (the occluders count)
    plain, _ = SilhouetteObjective(
        sc,
        cams,
        [[o & ~(g if g is not None else False) for o, g in zip(oc, gc)] for oc, gc in zip(obs, ign)],
        backend=backend,
    ).per_image(P)
    assert np.abs(plain - esil).max() > 0.01


def test_blender_model_path_uses_ignore(truth):
    """The per-position scoring path (models simulated on their own) takes the same ignore masks."""
    sc, cams, X, sils = truth
    ign = [[(lambda p, h: p | h)(*occluder(ci, fi, (H, W))) for fi in range(4)] for ci in range(3)]
    obj = SilhouetteObjective(sc, cams, sils, backend="numba" if jit.available() else "numpy", ignore=ign)

    class Fixed:  # a "model" whose simulation is the truth's positions
        row_names = ("a",)

        def simulate(self, scenario, rows, backend="auto"):
            class S:
                pass

            s = S()
            s.positions = np.repeat(X[None], len(rows), 0)
            s.exploded = np.zeros(len(rows), bool)
            return s

    obj.model, obj.paper = Fixed(), False
    esil, _ = obj.per_image(np.zeros((1, 1)))
    assert esil.max() == 0.0


def test_evaluate_and_overlay_grey(tmp_path, truth):
    root = str(tmp_path / "cap")
    write_label_capture(root, truth)
    cap = load_capture(root)
    r = evaluate(cap, GT)
    assert r["silhouette_error_pct"] < 0.5  # the truth fits where it is seen
    paths = overlay.capture_overlays(cap, GT, str(tmp_path / "ov"), cameras=[0], times=[0.1])
    import cv2

    img = cv2.imread(paths[0])[..., ::-1]
    post, hand = occluder(0, 0, (H, W))
    g = img[post | hand]
    assert np.all(g[:, 0] == g[:, 1]) and set(np.unique(g[:, 0])) <= {70, 110}


def test_study_occluders_hide_part_of_the_cloth_in_every_view():
    """The occlusion study's post and hand (studies/occlusion.py) hide some, never all, of the cloth."""
    from clothfit.core.studies.occlusion import occluder_masks

    rig = [c.resized(120, 160) for c in C.load_rig("lab18")]
    sc = paper_scenario(frame_times=[0.1, 0.5, 1.0, 1.5])
    X = simulate(sc, [GT], backend="numpy").positions[0]
    for cam in rig:
        post, hand = occluder_masks(cam, X, sc)
        for f in range(4):
            s = raster.silhouette(cam, X[f], sc.grid.triangles)
            hidden = np.count_nonzero(s & (post | hand)) / np.count_nonzero(s)
            assert 0.0 < hidden < 0.9, (cam.name, f, hidden)
