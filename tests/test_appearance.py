"""Appearance randomisation (data v2), the held-out appearance benchmark and the OOD validation
set: every factor is a pure function of (seed, index) inside its documented range; the held-out
and validation settings never occur in training draws, nor the validation's in held-out draws;
bad ranges and overlapping settings fail with one line (exit 2)."""

from __future__ import annotations

import dataclasses
import hashlib
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from rhaml_jax import data
from rhaml_jax.camera import DEFAULT_CAMERA
from rhaml_jax.data._appearance import TRAINING_LIGHTING, color_groups, rgb_to_hsv
from rhaml_jax.errors import RhamlError
from rhaml_jax.render import as_mesh
from rhaml_jax.robots import load_robot

SMALL = DEFAULT_CAMERA.resized(160, 120)
CFG, HELD = data.AppearanceConfig(), data.HeldoutConfig()
GROUPS = color_groups(load_robot("pioneer3dx").face_colors)[0]  # the built-in robot's 6 part colours
N_DRAWS = 3000


def _looks(seed: int, n: int):
    return [data.sample_look(CFG, seed, i, GROUPS) for i in range(n)]


def _same(a: data.Look, b: data.Look) -> bool:
    return all(np.array_equal(np.asarray(x), np.asarray(y)) if not isinstance(x, tuple) else x == y
               for x, y in zip(dataclasses.astuple(a), dataclasses.astuple(b)))


def _inside(v, r, tol=1e-9):
    return r[0] - tol <= v <= r[1] + tol


def _light(rgb):
    """(strength, saturation) of a light colour hsv(h, s, 1) * strength."""
    hi = float(np.max(rgb))
    return hi, (1.0 - float(np.min(rgb)) / hi) if hi > 0 else 0.0


def _in_heldout_band(hsv, held: data.HeldoutConfig) -> np.ndarray:
    """(...,) whether colours (..., 3) are of the held-out part colouring (hue band, saturation)."""
    h, s = hsv[..., 0] % 360, hsv[..., 1]
    return (h >= held.part_hue_deg[0]) & (h <= held.part_hue_deg[1]) & (s >= held.part_saturation[0])


def test_every_factor_is_pure_and_inside_its_range():
    looks = _looks(11, N_DRAWS)
    again = [data.sample_look(CFG, 11, i, GROUPS) for i in (0, 7, N_DRAWS - 1)]
    assert all(_same(a, looks[i]) for a, i in zip(again, (0, 7, N_DRAWS - 1)))
    assert not _same(looks[0], looks[1]) and not _same(looks[0], data.sample_look(CFG, 12, 0, GROUPS))
    for lk in looks:
        assert lk.part_hsv.shape == (len(GROUPS), 3)
        assert np.all((lk.part_hsv[:, 1:] >= 0) & (lk.part_hsv[:, 1:] <= 1))
        assert lk.lighting in CFG.lighting
        for rgb, r in ((lk.ambient_rgb, CFG.ambient), (lk.sun_rgb, CFG.sun)):
            strength, sat = _light(rgb)
            assert _inside(strength, r) and (strength == 0 or _inside(sat, CFG.light_saturation))
        strength, sat = _light(lk.flash_rgb)
        assert strength == 0 or (lk.lighting == "sun+flash" and _inside(strength, CFG.flash) and _inside(sat, CFG.light_saturation))
        assert _inside(np.arcsin(lk.sun_dir[2]), CFG.sun_elevation_rad) and np.isclose(np.linalg.norm(lk.sun_dir), 1)
        assert all(_inside(v, CFG.flash_offset_m) for v in lk.flash_offset) and _inside(lk.flash_falloff, CFG.flash_falloff)
        assert _inside(lk.specular, CFG.specular) and _inside(lk.shininess, CFG.shininess)
        assert lk.shadow_strength == 0 or _inside(lk.shadow_strength, CFG.shadow_strength)
        assert _inside(lk.shadow_blur_px, CFG.shadow_blur_px) and _inside(lk.contact_strength, CFG.contact_strength)
        assert _inside(lk.exposure_stops, CFG.exposure_stops) and all(_inside(g, CFG.white_balance) for g in lk.white_balance)
        assert _inside(lk.gamma, CFG.gamma) and _inside(lk.vignette, CFG.vignette) and _inside(lk.noise, CFG.noise)
        assert lk.defocus_px == 0 or _inside(lk.defocus_px, CFG.defocus_px)
        assert lk.motion_px == 0 or _inside(lk.motion_px, CFG.motion_px)
        assert lk.jpeg_quality == 0 or _inside(lk.jpeg_quality, CFG.jpeg_quality)
        assert all(t.kind in CFG.texture_kinds and t.photo in CFG.texture_photos for t in lk.textures)
        assert lk.backdrop_photo in CFG.backdrop_photos
    # The probabilities show up as frequencies (each factor is actually drawn).
    coloured = data._appearance.rgb_to_hsv(GROUPS)[:, 1] > 0  # the red and yellow parts (the others are grey)
    grey = np.mean([np.mean(lk.part_hsv[coloured, 1] == 0) for lk in looks])
    assert abs(grey - CFG.part_grey_prob) < 0.03
    assert abs(np.mean([lk.jpeg_quality > 0 for lk in looks]) - CFG.jpeg_prob) < 0.05
    assert abs(np.mean([lk.shadow_strength > 0 for lk in looks]) - CFG.shadow_prob) < 0.05
    assert {t.kind for lk in looks for t in lk.textures} == set(CFG.texture_kinds)


def test_heldout_settings_never_occur_in_training():
    groups = np.concatenate([GROUPS, [[0.1, 0.8, 0.8], [0.0, 0.7, 0.6]]])  # also a robot painted cyan / teal
    train = [data.sample_look(CFG, s, i, groups) for s in (0, 1) for i in range(N_DRAWS // 2)]
    held = [data.sample_heldout_look(HELD, s, i, GROUPS) for s in (0, 1) for i in range(200)]
    # The held-out looks are what the definition says ...
    assert all(lk.lighting == HELD.lighting and np.all(_in_heldout_band(lk.part_hsv, HELD)) for lk in held)
    assert all(_inside(_light(lk.sky_rgb)[1], HELD.light_saturation) for lk in held)
    assert all(t.kind in HELD.texture_kinds and (t.kind != "photo" or t.photo in HELD.texture_photos) for lk in held for t in lk.textures)
    # Only the stated factors are held out: the camera's ranges lie inside training's, and its draws inside them.
    for f in ("exposure_stops", "white_balance", "gamma", "vignette", "defocus_px", "motion_px", "noise", "jpeg_quality"):
        assert _inside(getattr(HELD.camera, f)[0], getattr(CFG, f)) and _inside(getattr(HELD.camera, f)[1], getattr(CFG, f)), f
    assert all(_inside(lk.exposure_stops, HELD.camera.exposure_stops) and _inside(lk.gamma, HELD.camera.gamma) for lk in held)
    assert all(lk.defocus_px == 0 or _inside(lk.defocus_px, HELD.camera.defocus_px) for lk in held)
    # ... and no training draw has any of them: lighting model, light saturation, part colouring,
    # texture family, photographs (walls or backdrops), robot-like distractors' colours.
    for lk in train:
        assert lk.lighting != HELD.lighting and lk.lighting in TRAINING_LIGHTING
        assert all(_light(c)[1] < HELD.light_saturation[0] for c in (lk.ambient_rgb, lk.sun_rgb, lk.flash_rgb))
        assert not np.any(_in_heldout_band(lk.part_hsv, HELD)) and not np.any(_in_heldout_band(lk.distractor_hsv, HELD))
        assert not any(t.kind in set(HELD.texture_kinds) - {"photo"} or t.photo in HELD.texture_photos for t in lk.textures)
        assert lk.backdrop_photo not in HELD.backdrop_photos
    # The cyan parts of the model were moved out of the band, not kept.
    assert any(np.any(lk.part_hsv[-2:, 1] > 0.5) for lk in train)


def test_ood_validation_settings_are_outside_training_and_apart_from_the_heldout_set():
    """OOD_VALIDATION's looks are what it says (ceiling lamps of saturation 0.7-0.9, the robot's own
    colours under a grey checker livery, highlights outside training's, hexagon and `retina`
    rooms); no training draw and no held-out draw has any of them."""
    V = data.OOD_VALIDATION
    data.check_heldout(CFG, V), data.check_apart(V, HELD)
    val = [data.sample_heldout_look(V, s, i, GROUPS) for s in (0, 1) for i in range(200)]
    assert _same(val[207], data.sample_heldout_look(V, 1, 7, GROUPS))  # pure in (seed, index)
    for lk in val:
        assert lk.lighting == "lamps" and 2 <= len(lk.lamp_pos) <= 3 and np.all(lk.lamp_pos[:, 2] >= 2.4)
        assert all(_inside(_light(c)[1], V.light_saturation, 1e-6) and _inside(_light(c)[0], V.lamp, 1e-6) for c in lk.lamp_rgb)
        np.testing.assert_allclose(lk.part_hsv, rgb_to_hsv(GROUPS))  # its own colours
        assert _inside(lk.specular, V.specular) and _inside(lk.shininess, V.shininess, 1e-6)
        assert _inside(lk.livery_period, V.livery_period_m) and np.ptp(lk.livery_rgb) == 0 and _inside(lk.livery_rgb[0], V.livery_value)
        assert all(t.kind in V.texture_kinds and (t.kind != "photo" or t.photo in V.texture_photos) for t in lk.textures)
        assert lk.backdrop_photo in V.backdrop_photos
    assert {t.kind for lk in val for t in lk.textures} == set(V.texture_kinds)
    train = _looks(3, N_DRAWS // 2)
    held = [data.sample_heldout_look(HELD, 0, i, GROUPS) for i in range(200)]
    for lk in train + held:
        assert lk.lighting != "lamps" and len(lk.lamp_pos) == 0 and lk.livery_period == 0
        assert lk.specular < V.specular[0] and lk.shininess < V.shininess[0]
        assert all(_light(c)[1] < V.light_saturation[0] for c in (lk.ambient_rgb, lk.sun_rgb, lk.flash_rgb, lk.sky_rgb, lk.ground_rgb))
        assert not any(t.kind == "hexagons" or t.photo in V.texture_photos for t in lk.textures)
        assert lk.backdrop_photo not in V.backdrop_photos


def test_the_livery_is_painted_in_the_robots_body_frame():
    """The checker livery moves with the robot: the same layer seen with camera and robot both
    turned and shifted paints the same pixels; without a body frame nothing is painted."""
    from rhaml_jax.data._appearance import shade_layer

    rng = np.random.default_rng(0)
    H = W = 16
    depth = rng.uniform(1.0, 3.0, (H, W))
    K = np.array([[10.0, 0, 7.55], [0, 10.0, 7.55], [0, 0, 1]])  # no ray on a cell boundary (x or y exactly 0)
    albedo, mask, fid = np.full((H, W, 3), 0.3), np.ones((H, W), bool), np.zeros((H, W), int)
    flat = dict(lighting="hemisphere", sky_rgb=np.ones(3), ground_rgb=np.ones(3), specular=0.0)  # light 1 everywhere
    look = dataclasses.replace(data.sample_heldout_look(data.OOD_VALIDATION, 0, 0, GROUPS), livery_rgb=np.full(3, 0.9), **flat)
    c, s_ = np.cos(0.7), np.sin(0.7)
    R, t = np.array([[c, -s_, 0], [s_, c, 0], [0, 0, 1]]), np.array([2.0, -1.0, 0.3])

    def shade(R, t, body=True):
        return shade_layer(albedo, mask, depth, fid, np.array([[0.0, 0.0, 1.0]]), K, (R, t), look, body=(R, t) if body else None)

    a = shade(np.eye(3), np.zeros(3))
    np.testing.assert_allclose(shade(R, t), a, atol=1e-5)
    assert np.any(np.isclose(a, 0.9)) and np.any(np.isclose(a, 0.3))
    np.testing.assert_allclose(shade(np.eye(3), np.zeros(3), body=False), 0.3, atol=1e-6)


@pytest.mark.parametrize("change,msg", [
    ({"lighting": "hemisphere"}, "OOD_VALIDATION.lighting and HeldoutConfig.lighting: both 'hemisphere'"),
    ({"light_saturation": (0.6, 0.9)}, "OOD_VALIDATION.light_saturation"),
    ({"texture_kinds": ("hexagons", "voronoi")}, "OOD_VALIDATION.texture_kinds and HeldoutConfig.texture_kinds: ['voronoi'] in both"),
    ({"backdrop_photos": ("retina", "stereo_motorcycle")}, "['stereo_motorcycle'] in both"),
])
def test_a_validation_set_that_previews_the_heldout_set_is_rejected(change, msg):
    with pytest.raises(RhamlError) as e:
        data.check_apart(dataclasses.replace(data.OOD_VALIDATION, **change), HELD)
    assert msg in str(e.value) and "\n" not in str(e.value)


def test_repaint_recolours_every_part_outside_the_heldout_band():
    """repaint_prob = 1: no part keeps its own colour (hue within part_hue_shift_deg of its
    own, saturation >= part_saturation_scale[0] of its own) more often than a random new colour
    lands there; and repainting never gives a part the held-out colouring."""
    base = data._appearance.rgb_to_hsv(GROUPS)
    coloured = base[:, 1] > 0

    def kept(cfg):
        looks = [data.sample_look(cfg, 3, i, GROUPS) for i in range(1000)]
        hsv = np.stack([lk.part_hsv[coloured] for lk in looks])
        dh = np.abs((hsv[..., 0] - base[coloured, 0] + 180) % 360 - 180)
        return np.mean((dh <= CFG.part_hue_shift_deg[1]) & (hsv[..., 1] >= CFG.part_saturation_scale[0] * base[coloured, 1] - 1e-9)), looks

    k0, _ = kept(CFG)
    k1, looks = kept(dataclasses.replace(CFG, repaint_prob=1.0))
    assert k0 > 0.45 and k1 < 0.2, (k0, k1)  # 50 of 310 allowed hue degrees, times the saturation's chance
    assert not any(np.any(_in_heldout_band(lk.part_hsv, HELD)) for lk in looks)
    half = dataclasses.replace(CFG, repaint_prob=0.5)
    assert _same(data.sample_look(half, 3, 5, GROUPS), data.sample_look(half, 3, 5, GROUPS))


@pytest.mark.parametrize("field,value,msg", [
    ("ambient", (0.7, 0.1), "AppearanceConfig.ambient: range (0.7, 0.1) is inverted"),
    ("texture_kinds", (), "AppearanceConfig.texture_kinds: expected a non-empty list"),
    ("part_value", (0.0, 1.5), "AppearanceConfig.part_value: range (0.0, 1.5) leaves its bounds"),
    ("jpeg_prob", 1.5, "AppearanceConfig.jpeg_prob: 1.5 is not a probability"),
    ("texture_kinds", ("solid", "velvet"), "unknown texture kind(s) ['velvet']"),
    ("gamma", (float("nan"), 1.0), "AppearanceConfig.gamma: expected a range (lo, hi) of two finite numbers"),
])
def test_bad_ranges_raise_one_line(field, value, msg):
    with pytest.raises(RhamlError, match=None) as e:
        data.AppearanceConfig(**{field: value})
    assert msg in str(e.value) and "\n" not in str(e.value)


@pytest.mark.parametrize("train,held,msg", [
    ({}, {"part_hue_deg": (140.0, 180.0)}, "HeldoutConfig.part_hue_deg"),
    ({"hue_exclude_deg": (170.0, 180.0)}, {}, "HeldoutConfig.part_hue_deg"),
    ({}, {"part_saturation": (0.1, 0.9)}, "HeldoutConfig.part_saturation"),
    ({"light_saturation": (0.0, 0.5)}, {}, "HeldoutConfig.light_saturation"),
    ({"texture_kinds": ("solid", "voronoi")}, {}, "HeldoutConfig.texture_kinds: ['voronoi']"),
    ({"backdrop_photos": ("astronaut", "stereo_motorcycle")}, {}, "HeldoutConfig.texture_photos: ['stereo_motorcycle']"),
    ({"lighting": ("sun",)}, {"lighting": "sun"}, "HeldoutConfig.lighting: 'sun' is a training lighting model"),
])
def test_heldout_overlapping_training_is_rejected(train, held, msg):
    with pytest.raises(RhamlError) as e:
        data.check_heldout(data.AppearanceConfig(**train), data.HeldoutConfig(**held))
    assert msg in str(e.value) and "\n" not in str(e.value)
    data.check_heldout(CFG, HELD)  # the defaults are disjoint


@pytest.mark.parametrize("flags,msg", [
    (["--ranges.gamma", "1.2", "0.9"], "AppearanceConfig.gamma: range (1.2, 0.9) is inverted"),
    (["--heldout", "--heldout-ranges.part-hue-deg", "100", "180"], "HeldoutConfig.part_hue_deg"),
    (["--ood-validation", "--heldout-ranges.texture-kinds", "hexagons"], "['hexagons'] in both"),
    (["--ood-validation", "--heldout"], "--heldout and --ood-validation: choose one"),
])
def test_generate_rejects_bad_appearance_with_exit_2(tmp_path, flags, msg):
    r = subprocess.run([sys.executable, "-m", "rhaml_jax.generate", "--out", str(tmp_path / "x"), *flags],
                       capture_output=True, text=True, cwd=Path(__file__).parents[1])
    assert r.returncode == 2 and msg in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "Traceback" not in r.stderr and not (tmp_path / "x").exists()


def test_v2_images_are_pure_and_v1_images_unchanged():
    mesh = as_mesh(load_robot("pioneer3dx"))
    a = data.training_sample(mesh, SMALL, 5, 2)
    b = data.training_sample(mesh, SMALL, 5, 2)
    assert np.array_equal(a.rgb, b.rgb) and np.array_equal(a.mask_visib, b.mask_visib) and a.observed
    # v1 (the shipped checkpoints' data): the pixels main makes without data v2 (checked at 392354e).
    v1 = data.SynthConfig(appearance=None)
    h = hashlib.sha1()
    for i in range(3):
        s = data.training_sample(mesh, SMALL, 7, i, cfg=v1)
        h.update(s.rgb.tobytes()), h.update(s.mask_visib.tobytes())
    assert h.hexdigest() == V1_DIGEST


V1_DIGEST = "8adf93c594e071e41885e502d861b94edb4977bc"  # sha1 of 3 images at 160 x 120 (seed 7), computed on main at 392354e


def test_heldout_benchmark_layout(tmp_path):
    out = data.write_heldout(tmp_path / "h", "pioneer3dx", SMALL, seed=3, frames=4, random=3, background=2, workers=1)
    assert set(out["parts"]) == {"circle", "sine", "background", "random"}
    counts = {k: [f.observed for f in data.read_bop(tmp_path / "h" / k, None)] for k in out["parts"]}
    assert len(counts["circle"]) == len(counts["sine"]) == 4 and counts["background"] == [False, False]
    assert counts["random"] == [True] * 3
    assert {f.split for f in data.read_bop(tmp_path / "h" / "random", None)} == {"test"}
    assert (tmp_path / "h" / "circle" / "test" / "000000" / "observed_odometry.txt").exists()


def test_robot_like_distractors_have_their_documented_sizes():
    from rhaml_jax.data._synth import distractor_mesh_v2

    colors = np.zeros((4, 2, 3))
    seen = 0
    for i in range(40):
        rng = np.random.default_rng(i)
        v, f, c = distractor_mesh_v2(rng, 4, 4, None, 0.3, (1.0, 6.0, -3.0, 3.0), colors, 1.0, CFG.cart_length_m)
        assert v.shape == distractor_mesh_v2(np.random.default_rng(99), 0, 4, None, 0.3, (1.0, 6.0, -3.0, 3.0), colors, 1.0,
                                             CFG.cart_length_m)[0].shape  # one shape: one compilation
        used = v[v[:, 0] > -100]
        assert np.array_equal(v, distractor_mesh_v2(np.random.default_rng(i), 4, 4, None, 0.3, (1.0, 6.0, -3.0, 3.0), colors, 1.0,
                                                    CFG.cart_length_m)[0])  # a pure function of the generator
        per_slot = len(v) // 4
        for k in range(4):
            s = v[k * per_slot:(k + 1) * per_slot]
            s = s[s[:, 0] > -100]
            if len(s):
                seen += 1
                assert s[:, 2].min() >= -1e-6  # on the floor
                d = np.linalg.norm(s[:, None, :2] - s[None, :, :2], axis=-1).max()  # footprint diameter, any yaw
                # body length L in cart_length_m; wheels reach 1.3 L x 1.2 L at most
                assert CFG.cart_length_m[0] - 1e-6 <= d <= np.hypot(1.3, 1.2) * CFG.cart_length_m[1] + 1e-6
        assert len(used)
    assert seen > 100


def test_heldout_rendezvous_is_two_scenes_in_the_heldout_look(tmp_path):
    """`generate --heldout --scenario rendezvous`: the two-robot sequence (one scene per camera)
    under the held-out settings; circle and sine stay part of the whole benchmark."""
    from rhaml_jax.generate import Args, generate

    generate(Args(out=tmp_path / "r", heldout=True, scenario="rendezvous", frames=4, width=160, height=120, workers=1))
    frames = data.read_bop(tmp_path / "r", None)
    assert sorted({f.scene_id for f in frames}) == [0, 1] and len(frames) == 8
    plain = tmp_path / "p"
    generate(Args(out=plain, scenario="rendezvous", frames=4, width=160, height=120, workers=1))
    a = data.load_rgb(frames[0].rgb)
    b = data.load_rgb(data.read_bop(plain, None)[0].rgb)
    assert a.shape == b.shape and np.abs(a.astype(int) - b.astype(int)).mean() > 5  # another look
    with pytest.raises(RhamlError, match="drop --scenario"):
        generate(Args(out=tmp_path / "c", heldout=True, scenario="circle"))


def test_camouflage_is_drawn_last_inside_its_range_and_never_in_the_heldout_band():
    """camouflage_prob: t inside `camouflage` as often as the probability says, drawn after every
    other factor (a set without camouflage keeps its draws); a robot recoloured towards teal
    surroundings never takes the held-out colouring."""
    camo = dataclasses.replace(CFG, camouflage_prob=0.5)
    plain, looks = _looks(4, 400), [data.sample_look(camo, 4, i, GROUPS) for i in range(400)]
    assert all(_same(dataclasses.replace(lk, camouflage=0.0), p) for lk, p in zip(looks, plain))
    t = np.array([lk.camouflage for lk in looks])
    assert abs(np.mean(t > 0) - 0.5) < 0.07 and np.all((t == 0) | ((t >= CFG.camouflage[0]) & (t <= CFG.camouflage[1])))
    assert np.all([p.camouflage == 0 for p in plain])
    rng = np.random.default_rng(0)
    for _ in range(200):
        parts, robot, around = rng.uniform(0, 1, (6, 3)), rng.uniform(0.05, 1, 3), rng.uniform(0.05, 1, 3)
        around = np.array([0.1, 0.7, 0.65]) * around[0] if rng.random() < 0.5 else around  # teal surroundings
        new = data._appearance.camouflaged(parts, robot, around, float(rng.uniform(0.5, 1.0)), CFG)
        assert new.shape == parts.shape and np.all((new >= 0) & (new <= 1))
        assert not np.any(_in_heldout_band(rgb_to_hsv(new), HELD))
    # t = 1 with nothing clipped: the robot takes its surroundings' mean colour exactly
    parts, robot, around = np.full((2, 3), 0.4), np.array([0.2, 0.3, 0.4]), np.array([0.3, 0.2, 0.1])
    assert np.allclose(data._appearance.camouflaged(parts, robot, around, 1.0, CFG), parts * around / robot)


def test_monochrome_paints_every_part_one_hue_drawn_last_and_never_the_heldout_colouring():
    """monochrome_prob: as often as the probability says, every part shares one hue (outside the
    held-out band) with its own saturation and value inside their ranges; drawn after every other
    factor, so a set without it keeps its draws; pure in (seed, index)."""
    mono = dataclasses.replace(CFG, monochrome_prob=0.5)
    plain, looks = _looks(6, 400), [data.sample_look(mono, 6, i, GROUPS) for i in range(400)]
    painted = [not np.array_equal(lk.part_hsv, p.part_hsv) for lk, p in zip(looks, plain)]
    assert abs(np.mean(painted) - 0.5) < 0.07
    assert all(_same(dataclasses.replace(lk, part_hsv=p.part_hsv), p) for lk, p in zip(looks, plain))
    hsv = np.stack([lk.part_hsv for lk, m in zip(looks, painted) if m])  # (N, 6, 3)
    assert np.all(np.ptp(hsv[..., 0], axis=1) == 0)
    assert np.all((hsv[..., 2] >= CFG.part_value[0] - 1e-9) & (hsv[..., 2] <= 1.0)) and np.all((hsv[..., 1] >= 0) & (hsv[..., 1] <= 1))
    assert np.std(hsv[..., 2], axis=1).mean() > 0.1  # each part its own value: no dark part marks an end
    assert not np.any(_in_heldout_band(hsv, HELD))
    assert _same(data.sample_look(mono, 6, 7, GROUPS), data.sample_look(mono, 6, 7, GROUPS))


def test_a_camouflaged_robot_is_closer_to_its_surroundings():
    """In rendered images, the robot's mean colour moves towards the scene's around it."""
    mesh = as_mesh(load_robot("pioneer3dx"))
    gaps = {}
    for p in (0.0, 1.0):
        cfg = data.SynthConfig(appearance=dataclasses.replace(CFG, camouflage_prob=p, camouflage=(1.0, 1.0)))
        gaps[p] = []
        for i in range(6):
            s = data.training_sample(mesh, SMALL, 9, i, negative=False, cfg=cfg)
            box, outside = data._appearance.surroundings(s.mask_visib.astype(bool))
            rgb = s.rgb[box].astype(np.float64)
            gaps[p].append(np.abs(rgb[~outside].mean(0) - rgb[outside].mean(0)).sum())
    assert np.mean(gaps[1.0]) < 0.5 * np.mean(gaps[0.0]), gaps


def test_dim_room_inside_its_ranges_keeps_dark_parts_dark_and_dims_the_backdrop_only():
    """dim_room_prob: a gain inside `dim_room` as often as the probability says, and then every
    part's lift inside `dim_room_lift` (dark parts stay dark); pure in (seed, index); in a rendered
    image it darkens the room around the robot by that gain and leaves the robot's pixels as the
    same look without the gain renders them."""
    dim = dataclasses.replace(CFG, dim_room_prob=0.5)
    looks = [data.sample_look(dim, 8, i, GROUPS) for i in range(400)]
    assert _same(looks[7], data.sample_look(dim, 8, 7, GROUPS))
    g = np.array([lk.room_gain for lk in looks])
    assert abs(np.mean(g < 1) - 0.5) < 0.07 and np.all((g == 1) | ((g >= CFG.dim_room[0]) & (g <= CFG.dim_room[1])))
    kept = dataclasses.replace(dim, part_grey_prob=0.0, part_recolour_prob=0.0)  # each part its own value, then lifted
    v0 = rgb_to_hsv(GROUPS)[:, 2]
    can = v0 < 1  # the parts a lift can change
    for lk in (data.sample_look(kept, 8, i, GROUPS) for i in range(200)):
        lift = (lk.part_hsv[can, 2] - v0[can]) / (1.0 - v0[can])
        lo, hi = CFG.dim_room_lift if lk.room_gain < 1 else CFG.dark_lift
        assert np.all((lift >= lo - 1e-9) & (lift <= hi + 1e-9)), (lk.room_gain, lift)
    mesh = as_mesh(load_robot("pioneer3dx"))
    quiet = dict(noise=(0.0, 0.0), jpeg_prob=0.0, defocus_prob=0.0, motion_prob=0.0, vignette=(0.0, 0.0), gamma=(1.0, 1.0),
                 exposure_stops=(0.0, 0.0), white_balance=(1.0, 1.0), cart_prob=0.0)
    base = dataclasses.replace(CFG, **quiet)
    for i in range(3):
        a = data.training_sample(mesh, SMALL, 11, i, negative=False, cfg=data.SynthConfig(
            appearance=dataclasses.replace(base, dim_room_prob=1.0, dim_room=(1.0, 1.0))))  # the same draws at gain 1
        b = data.training_sample(mesh, SMALL, 11, i, negative=False, cfg=data.SynthConfig(
            appearance=dataclasses.replace(base, dim_room_prob=1.0, dim_room=(0.25, 0.25))))
        robot = b.mask_visib.astype(bool)
        assert np.array_equal(robot, a.mask_visib.astype(bool)) and robot.any()
        assert np.array_equal(a.rgb[robot], b.rgb[robot])
        ra, rb = a.rgb[~robot].astype(np.float64), b.rgb[~robot].astype(np.float64)
        lit = ra > 40  # the room's pixels (distractors, not dimmed, are few), away from 8-bit rounding
        assert abs(np.median(rb[lit] / ra[lit]) - 0.25) < 0.02, np.median(rb[lit] / ra[lit])
