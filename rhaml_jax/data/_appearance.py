"""Appearance randomisation (data v2) and the held-out appearance benchmark's settings.

`AppearanceConfig` lists every appearance factor of the v2 training data with its range, in one
place; `HeldoutConfig` lists the held-out benchmark's settings, chosen OUTSIDE those ranges:

- lighting model: training lights the scene with ambient + a directional "sun" (+ often a point
  "flash" near the camera) and Blinn-Phong highlights; held-out uses a hemisphere (sky/ground)
  light, which training never samples, and more strongly coloured light (saturation 0.45-0.65
  against training's at most 0.3).
- part colouring: every robot part teal/cyan (hue 165-195 deg, saturation >= 0.45); training never
  gives a part with saturation >= 0.2 a hue within 155-205 deg.
- texture family: rooms of Voronoi cells (`voronoi`) and the `stereo_motorcycle` photograph, a
  texture family and a photograph training never samples (for walls or as a backdrop).

The held-out camera effects are training's, milder (`MILD_CAMERA`): they are not held out.

`OOD_VALIDATION` is a second set of the same kind for choosing designs, thresholds and
checkpoints (the held-out set may only be reported): its settings lie outside training's AND
apart from the held-out set's (`check_apart`), so that a choice that transfers to it is likely to
transfer to looks nobody has seen:

- lighting model "lamps": two or three ceiling lamps (point lights 2.4-3.2 m up, anywhere from
  2 m behind to 8 m ahead of the camera, inverse-square falloff) over a dim ambient, strongly
  coloured (saturation 0.7-0.9);
- robot colouring and material: its own colours under a grey checker livery painted in its body
  frame (cells of 5-12 cm; training paints every part in one colour, the held-out set teal), and
  glossy (highlights of strength 1-2, exponent 256-1024; training's at most 0.5 and 128, the
  held-out set's none);
- texture family: rooms of hexagonal tiles (`hexagons`) and the `retina` photograph.

Everything sampled here is a pure function of (seed, index): `sample_look` draws from its own
stream, independent of the geometry's, so the factors of an image can be listed without
rendering it (what the tests do). Host-side NumPy / OpenCV only.
"""

from __future__ import annotations

import colorsys
import contextlib
import dataclasses
import math

import cv2
import numpy as np

from rhaml_jax.camera import R_ROBOT_OPTICAL
from rhaml_jax.data._backdrop import PHOTOS, TEXTURES, ROOM_NORMALS, Texture, sample_texture
from rhaml_jax.errors import RhamlError

Range = tuple[float, float]

TRAINING_LIGHTING = ("sun", "sun+flash")  # what v2 training samples
OOD_LIGHTING = ("hemisphere", "lamps")  # models for out-of-training sets only
_STREAM_LOOK, _STREAM_HELDOUT = 0x4C4F4F4B, 0x48454C44  # independent SeedSequence streams
_DEFERRED = [False]


@contextlib.contextmanager
def deferred_checks():
    """Configs made inside skip their checks (a CLI parser that would reformat the error);
    call `.validate()` on them afterwards."""
    _DEFERRED[0] = True
    try:
        yield
    finally:
        _DEFERRED[0] = False


@dataclasses.dataclass(frozen=True)
class AppearanceConfig:
    """The v2 training data's appearance factors and their ranges (lo, hi), sampled uniformly
    (shininess log-uniformly). Pixel sizes are for a 640-px-wide image and scale with the width.

    Robot parts (each group of faces sharing a colour in the model):
      part_grey_prob: a part becomes grey (saturation 0) of value in part_value;
      part_recolour_prob: a part gets a new hue (any hue outside hue_exclude_deg), saturation in
        (0, 1) and value in part_value; otherwise it keeps its hue shifted by part_hue_shift_deg,
        its saturation scaled by part_saturation_scale;
      repaint_prob: the whole robot repainted: every part grey or recoloured as above, none keeps
        its own colour (the issue-18 control: a blue body or grey tyres moved the old networks
        by metres); 0 in the v2 sets (which it leaves as they were: no draw at 0);
      monochrome_prob: the whole robot in one paint (drawn after the rest, in place of the parts'
        colours above): one hue for every part (outside hue_exclude_deg), each part its own
        saturation in (0, 1) and value in part_value, then dark_lift: no part's hue or darkness
        marks the front or the back (a robot painted one colour; the held-out flips read a
        one-hue robot's back as its front, BENCHMARKS.md "Where the held-out flips are");
        0 in the v2 and v3 sets (no draw at 0);
      dark_lift: every part's value v -> v + lift (1 - v) (dark parts rendered lighter);
      hue_exclude_deg, exclude_min_saturation: no part (and no robot-like distractor) with at
        least that saturation ever has a hue in this band (it is the held-out colouring's).
    Lighting (models `TRAINING_LIGHTING`), in units of the albedo:
      ambient; sun (directional) with elevation sun_elevation_rad (any azimuth); with flash_prob a
      point light at the camera offset by flash_offset_m on each axis, of strength flash at 3 m,
      falling off as (3 m / distance) ** flash_falloff (at most 2x); each light coloured with
      saturation light_saturation (any hue); Blinn-Phong highlights of strength specular and
      exponent shininess (roughness).
    Shadows on the floor (rooms only): with shadow_prob, the robot's and distractors' shadow along
      the sun, darkening by shadow_strength, blurred by shadow_blur_px; a contact shadow under
      them darkening by contact_strength.
    Camera: exposure_stops; per-channel white_balance gains; gamma; vignette (darkening at the
      corners); with defocus_prob a Gaussian blur of defocus_px; with motion_prob a linear motion
      blur of motion_px (any direction); Gaussian noise of sigma noise; with jpeg_prob JPEG
      compression at quality jpeg_quality. None of them depends on the robot's range (no size cue).
    Rooms: surfaces of texture_kinds (photo textures from texture_photos), photograph backdrops
      from backdrop_photos.
    Distractors: each slot is a robot-like cart (a box on four wheels, length cart_length_m, other
      colours and sizes than the robot: no size cue from a robot-like shape) with cart_prob.
    Camouflage (a robot as hard to see as its surroundings make it, as the far robots IML misses
      on the OOD validation sine are: BENCHMARKS.md, "What IML misses"): with camouflage_prob, every part's colour is
      multiplied per channel by (m_around / m_robot) ** t, t in camouflage, where m_robot is the
      robot's mean shaded colour and m_around the scene's mean colour around it (its bounding box
      grown by half its size on each side, the robot's own pixels left out). At t = 1 the robot
      takes its surroundings' mean colour and brightness; its shading and the contrast between
      its parts stay, so its shape is what remains to see. Parts are clipped to [0, 1] and kept
      out of hue_exclude_deg. 0 in the v2 and v3 sets (which it leaves as they were: no draw at 0).
    Dim surroundings (a robot lit brighter than the room around it, as under ceiling lamps): with
      dim_room_prob, the room or photograph behind the robot (with its floor shadows) is
      multiplied by a gain drawn log-uniformly from dim_room; the robot and the distractors are
      lit as before, and the robot's parts take their dark_lift from dim_room_lift, so that its
      dark parts (tyres) stay about as dark as the room around them. Aimed at the long ranges on
      dark surroundings, which come from the dark parts' lost contrast; as a fine-tune it did
      not remove them (BENCHMARKS.md, "Dim rooms in training do not take the long range away").
      0 in the v2 and v3 sets (no draw at 0).
    """

    part_grey_prob: float = 0.15
    part_recolour_prob: float = 0.35
    repaint_prob: float = 0.0
    part_hue_shift_deg: Range = (-25.0, 25.0)
    part_saturation_scale: Range = (0.3, 1.2)
    part_value: Range = (0.04, 1.0)
    dark_lift: Range = (0.0, 0.45)
    hue_exclude_deg: Range = (155.0, 205.0)
    exclude_min_saturation: float = 0.2
    lighting: tuple[str, ...] = TRAINING_LIGHTING
    ambient: Range = (0.2, 0.8)
    sun: Range = (0.0, 1.0)
    sun_elevation_rad: Range = (0.15, 1.45)
    flash_prob: float = 0.5
    flash: Range = (0.2, 1.0)
    flash_offset_m: Range = (-0.3, 0.3)
    flash_falloff: Range = (0.0, 2.0)
    light_saturation: Range = (0.0, 0.3)
    specular: Range = (0.0, 0.5)
    shininess: Range = (4.0, 128.0)
    shadow_prob: float = 0.7
    shadow_strength: Range = (0.2, 0.8)
    shadow_blur_px: Range = (0.5, 4.0)
    contact_strength: Range = (0.0, 0.5)
    exposure_stops: Range = (-1.0, 1.0)
    white_balance: Range = (0.8, 1.2)
    gamma: Range = (0.8, 1.25)
    vignette: Range = (0.0, 0.5)
    defocus_prob: float = 0.3
    defocus_px: Range = (0.3, 2.0)
    motion_prob: float = 0.2
    motion_px: Range = (1.0, 8.0)
    noise: Range = (0.0, 0.03)
    jpeg_prob: float = 0.4
    jpeg_quality: Range = (30.0, 95.0)
    texture_kinds: tuple[str, ...] = ("solid", "checker", "stripes", "tiles", "noise", "photo", "wood", "dots", "marble")
    texture_photos: tuple[str, ...] = TEXTURES + ("moon", "cell", "coins", "text")
    backdrop_photos: tuple[str, ...] = PHOTOS + ("cat", "hubble_deep_field", "immunohistochemistry", "colorwheel")
    cart_prob: float = 0.4
    cart_length_m: Range = (0.2, 0.9)
    camouflage_prob: float = 0.0
    camouflage: Range = (0.5, 1.0)
    monochrome_prob: float = 0.0
    dim_room_prob: float = 0.0
    dim_room: Range = (0.05, 0.5)
    dim_room_lift: Range = (0.0, 0.05)

    def __post_init__(self):
        if not _DEFERRED[0]:
            self.validate()

    def validate(self) -> None:
        """RhamlError (one line naming the field) for an empty, inverted or out-of-bounds range."""
        bounds = {"part_value": (0, 1), "part_saturation_scale": (0, None), "dark_lift": (0, 1), "hue_exclude_deg": (0, 360),
                  "ambient": (0, None), "sun": (0, None), "sun_elevation_rad": (0.05, math.pi / 2), "flash": (0, None),
                  "flash_falloff": (0, None), "light_saturation": (0, 1), "specular": (0, None), "shininess": (1, None),
                  "shadow_strength": (0, 1), "shadow_blur_px": (0, None), "contact_strength": (0, 1), "white_balance": (0, None),
                  "gamma": (0.1, None), "vignette": (0, 1), "defocus_px": (0, None), "motion_px": (0, None), "noise": (0, None),
                  "jpeg_quality": (1, 100), "cart_length_m": (0.05, None), "camouflage": (0, 1),
                  "dim_room": (0.001, 1), "dim_room_lift": (0, 1)}
        _check_fields(self, bounds)
        unknown = [k for k in self.texture_kinds if k not in _KNOWN_KINDS]
        if unknown:
            raise RhamlError(f"AppearanceConfig.texture_kinds: unknown texture kind(s) {unknown} (known: {', '.join(_KNOWN_KINDS)})")
        if any(m not in TRAINING_LIGHTING for m in self.lighting):
            raise RhamlError(f"AppearanceConfig.lighting: {list(self.lighting)}: training samples {' and '.join(TRAINING_LIGHTING)} only")


# The held-out benchmark's camera: the training effects, milder (each range inside training's).
with deferred_checks():  # checked at the end of the module, where the checks are defined
    MILD_CAMERA = AppearanceConfig(exposure_stops=(-0.3, 0.3), gamma=(0.95, 1.05), vignette=(0.0, 0.2), defocus_prob=0.2,
                                   defocus_px=(0.3, 0.8), motion_prob=0.1, motion_px=(1.0, 3.0), noise=(0.0, 0.01),
                                   jpeg_prob=0.3, jpeg_quality=(75.0, 95.0))


@dataclasses.dataclass(frozen=True)
class HeldoutConfig:
    """The held-out appearance benchmark's settings (see the module docstring), each outside
    every training range (`check_heldout`).

    lighting: "hemisphere": sky light of strength sky from above, ground light of strength ground
      from below, blended by the surface normal's up component; "lamps": n_lamps ceiling point
      lights of strength lamp (at 3 m) over an ambient of strength ambient. Both coloured with
      saturation light_saturation. part_hue_deg, part_saturation, part_value: every robot part's
      colour (part_hue_deg None: the robot's own colours). livery_period_m, livery_value: a
      checker livery over the robot in its body frame, cells of that size, its second colour a
      grey of that value (period 0: none). specular, shininess: the robot's highlights (0: none).
    texture_kinds: room surfaces ("photo" means one of texture_photos); backdrop_photos:
    photograph backdrops. camera: the camera effects' ranges (not held out: `MILD_CAMERA`, a
    typical camera inside the training ranges, so that a scenario's single draw of its camera
    does not decide the benchmark).
    """

    lighting: str = "hemisphere"
    sky: Range = (0.7, 1.2)
    ground: Range = (0.15, 0.4)
    n_lamps: Range = (2.0, 3.0)
    lamp: Range = (0.5, 1.0)
    ambient: Range = (0.05, 0.15)
    light_saturation: Range = (0.45, 0.65)
    part_hue_deg: Range | None = (165.0, 195.0)
    part_saturation: Range = (0.45, 0.9)
    part_value: Range = (0.25, 0.85)
    livery_period_m: Range = (0.0, 0.0)
    livery_value: Range = (0.05, 0.95)
    specular: Range = (0.0, 0.0)
    shininess: Range = (1.0, 1.0)
    texture_kinds: tuple[str, ...] = ("voronoi", "photo")
    texture_photos: tuple[str, ...] = ("stereo_motorcycle",)
    backdrop_photos: tuple[str, ...] = ("stereo_motorcycle",)
    camera: AppearanceConfig = MILD_CAMERA

    def __post_init__(self):
        if not _DEFERRED[0]:
            self.validate()

    def validate(self) -> None:
        """RhamlError (one line naming the field) for an empty, inverted or out-of-bounds setting."""
        if self.lighting not in OOD_LIGHTING and self.lighting not in TRAINING_LIGHTING:
            raise RhamlError(f"HeldoutConfig.lighting: unknown lighting model {self.lighting!r} "
                             f"({', '.join(OOD_LIGHTING + TRAINING_LIGHTING)})")
        self.camera.validate()
        _check_fields(self, {"sky": (0, None), "ground": (0, None), "n_lamps": (1, 8), "lamp": (0, None), "ambient": (0, None),
                             "light_saturation": (0, 1), "part_hue_deg": (0, 360), "part_saturation": (0, 1), "part_value": (0, 1),
                             "livery_period_m": (0, None), "livery_value": (0, 1),
                             "specular": (0, None), "shininess": (1, None)})
        unknown = [k for k in self.texture_kinds if k not in _KNOWN_KINDS]
        if unknown:
            raise RhamlError(f"HeldoutConfig.texture_kinds: unknown texture kind(s) {unknown} (known: {', '.join(_KNOWN_KINDS)})")


_KNOWN_KINDS = ("solid", "checker", "stripes", "tiles", "noise", "photo", "wood", "dots", "marble", "voronoi", "hexagons")


def _check_fields(cfg, bounds: dict) -> None:
    """Ranges: two finite numbers lo <= hi within their physical bounds; probabilities in
    [0, 1]; name lists non-empty. RhamlError naming the field otherwise."""
    name = type(cfg).__name__
    for f in dataclasses.fields(cfg):
        v = getattr(cfg, f.name)
        if f.name.endswith("_prob") or f.name == "exclude_min_saturation":
            if not (isinstance(v, (int, float)) and 0.0 <= v <= 1.0):
                raise RhamlError(f"{name}.{f.name}: {v!r} is not a probability in [0, 1]")
        elif f.type in ("Range | None",) and v is None:
            continue
        elif f.type in ("Range", Range, "Range | None"):
            if not (isinstance(v, (tuple, list)) and len(v) == 2 and all(isinstance(x, (int, float)) and math.isfinite(x) for x in v)):
                raise RhamlError(f"{name}.{f.name}: expected a range (lo, hi) of two finite numbers, got {v!r}")
            lo, hi = v
            if lo > hi:
                raise RhamlError(f"{name}.{f.name}: range ({lo}, {hi}) is inverted (lo > hi)")
            blo, bhi = bounds.get(f.name, (None, None))
            if (blo is not None and lo < blo) or (bhi is not None and hi > bhi):
                raise RhamlError(f"{name}.{f.name}: range ({lo}, {hi}) leaves its bounds [{blo}, {'inf' if bhi is None else bhi}]")
        elif isinstance(v, (tuple, list)):
            if not v or not all(isinstance(x, str) for x in v):
                raise RhamlError(f"{name}.{f.name}: expected a non-empty list of names, got {v!r}")


def _overlap(a: Range, b: Range) -> bool:
    return a[0] <= b[1] and b[0] <= a[1]


def check_heldout(train: AppearanceConfig, held: HeldoutConfig) -> None:
    """RhamlError (one line) when a held-out setting overlaps what training samples."""
    if held.lighting in train.lighting:
        raise RhamlError(f"HeldoutConfig.lighting: {held.lighting!r} is a training lighting model ({', '.join(train.lighting)})")
    if _overlap(held.light_saturation, train.light_saturation):
        raise RhamlError(f"HeldoutConfig.light_saturation: {held.light_saturation} overlaps training's {train.light_saturation}")
    lo, hi = train.hue_exclude_deg
    if held.part_hue_deg is not None and not (lo <= held.part_hue_deg[0] and held.part_hue_deg[1] <= hi):
        raise RhamlError(f"HeldoutConfig.part_hue_deg: {held.part_hue_deg} is not inside the band training never samples "
                         f"(AppearanceConfig.hue_exclude_deg {train.hue_exclude_deg})")
    if held.part_hue_deg is not None and held.part_saturation[0] < train.exclude_min_saturation:
        raise RhamlError(f"HeldoutConfig.part_saturation: {held.part_saturation} reaches below "
                         f"AppearanceConfig.exclude_min_saturation {train.exclude_min_saturation}, where training samples every hue")
    if held.specular[1] > 0:  # highlights are a held-out factor only outside training's material
        for field in ("specular", "shininess"):
            if _overlap(getattr(held, field), getattr(train, field)):
                raise RhamlError(f"HeldoutConfig.{field}: {getattr(held, field)} overlaps training's {getattr(train, field)}")
    both = sorted(set(held.texture_kinds) - {"photo"} & set(train.texture_kinds))
    if both:
        raise RhamlError(f"HeldoutConfig.texture_kinds: {both} also in AppearanceConfig.texture_kinds")
    train_photos = set(train.texture_photos) | set(train.backdrop_photos)
    for field in ("texture_photos", "backdrop_photos"):
        both = sorted(set(getattr(held, field)) & train_photos)
        if both:
            raise RhamlError(f"HeldoutConfig.{field}: {both} also sampled by training (texture_photos or backdrop_photos)")


def check_apart(a: HeldoutConfig, b: HeldoutConfig, names=("OOD_VALIDATION", "HeldoutConfig")) -> None:
    """RhamlError (one line) unless two out-of-training sets share no lighting model, light
    saturation, robot colouring, material, texture family or photograph (a validation set must
    not preview the held-out set)."""
    def fail(field, why):
        raise RhamlError(f"{names[0]}.{field} and {names[1]}.{field}: {why}; the two sets must be apart")

    if a.lighting == b.lighting:
        fail("lighting", f"both {a.lighting!r}")
    if _overlap(a.light_saturation, b.light_saturation):
        fail("light_saturation", f"{a.light_saturation} overlaps {b.light_saturation}")
    if a.part_hue_deg is not None and b.part_hue_deg is not None and _overlap(a.part_hue_deg, b.part_hue_deg):
        fail("part_hue_deg", f"{a.part_hue_deg} overlaps {b.part_hue_deg}")
    if a.specular[1] > 0 and b.specular[1] > 0 and _overlap(a.specular, b.specular):
        fail("specular", f"{a.specular} overlaps {b.specular}")
    if a.livery_period_m[1] > 0 and b.livery_period_m[1] > 0:
        fail("livery_period_m", "both paint a livery")
    kinds = sorted(set(a.texture_kinds) & set(b.texture_kinds) - {"photo"})
    if kinds:
        fail("texture_kinds", f"{kinds} in both")
    photos = sorted((set(a.texture_photos) | set(a.backdrop_photos)) & (set(b.texture_photos) | set(b.backdrop_photos)))
    if photos:
        fail("texture_photos", f"{photos} in both")


# ----------------------------------------------------------------------------- one image's look


@dataclasses.dataclass(frozen=True)
class Look:
    """The appearance of one image (or one scenario): concrete values, not ranges.

    part_hsv: (G, 3) hue (deg), saturation, value of each colour group (see `color_groups`);
    lighting: a TRAINING_LIGHTING or OOD_LIGHTING model; *_rgb: (3,) light colour x strength;
    sun_dir: (3,) towards the sun, observer's robot frame; flash_offset: (3,) point light's
    offset from the camera, robot frame (m); textures: the room's six; backdrop_photo: the
    photograph a photo backdrop shows; distractor_hsv: (slots, 2, 3) body and wheel colours.
    """

    part_hsv: np.ndarray
    lighting: str
    ambient_rgb: np.ndarray
    sun_rgb: np.ndarray
    sun_dir: np.ndarray
    flash_rgb: np.ndarray
    flash_offset: np.ndarray
    flash_falloff: float
    specular: float
    shininess: float
    sky_rgb: np.ndarray
    ground_rgb: np.ndarray
    shadow_strength: float
    shadow_blur_px: float
    contact_strength: float
    exposure_stops: float
    white_balance: np.ndarray
    gamma: float
    vignette: float
    defocus_px: float
    motion_px: float
    motion_angle: float
    noise: float
    jpeg_quality: int
    noise_seed: int
    textures: tuple[Texture, ...]
    backdrop_photo: str
    distractor_hsv: np.ndarray
    lamp_pos: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 3)))  # (L, 3) world (m)
    lamp_rgb: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 3)))  # (L, 3) at 3 m
    livery_period: float = 0.0  # checker cell size in the robot's body frame (m; 0: no livery)
    livery_rgb: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(3))  # its second colour
    camouflage: float = 0.0  # t of AppearanceConfig.camouflage (0: none)
    room_gain: float = 1.0  # the backdrop's brightness factor (AppearanceConfig.dim_room; 1: as lit)

    @property
    def part_rgb(self) -> np.ndarray:
        return hsv_to_rgb(self.part_hsv)


def hsv_to_rgb(hsv: np.ndarray) -> np.ndarray:
    """(..., 3) hue (deg), saturation, value -> RGB in [0, 1]."""
    hsv = np.asarray(hsv, np.float64)
    flat = hsv.reshape(-1, 3)
    return np.array([colorsys.hsv_to_rgb((h / 360.0) % 1.0, s, v) for h, s, v in flat]).reshape(hsv.shape)


def rgb_to_hsv(rgb: np.ndarray) -> np.ndarray:
    rgb = np.asarray(rgb, np.float64)
    out = np.array([colorsys.rgb_to_hsv(*c) for c in rgb.reshape(-1, 3)]).reshape(rgb.shape)
    out[..., 0] *= 360.0
    return out


def color_groups(face_colors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The model's parts as far as colour goes: (unique colours (G, 3), group of each face (F,))."""
    c = np.round(np.asarray(face_colors, np.float64), 4)
    groups, inverse = np.unique(c, axis=0, return_inverse=True)
    return groups, inverse.reshape(-1)


def _u(rng, r: Range) -> float:
    return float(rng.uniform(r[0], r[1]))


def _allowed_hue(rng, exclude: Range) -> float:
    """A hue uniform over the circle minus the band `exclude` (deg)."""
    lo, hi = exclude
    x = rng.uniform(0.0, 360.0 - (hi - lo))
    return float(x if x < lo else x + (hi - lo))


def _out_of_band(h: float, s: float, cfg: AppearanceConfig) -> float:
    """Moves a hue in the excluded band (of a colour saturated enough to show it) to the band's
    nearer edge: training never shows the held-out colouring."""
    lo, hi = cfg.hue_exclude_deg
    h = h % 360.0
    if s >= cfg.exclude_min_saturation and lo <= h <= hi:
        return lo - 1e-6 if h - lo < hi - h else hi + 1e-6
    return h


def _light_rgb(rng, sat: Range, strength: float) -> np.ndarray:
    return hsv_to_rgb(np.array([rng.uniform(0, 360), _u(rng, sat), 1.0])) * strength


def _camera(rng, cfg: AppearanceConfig) -> dict:
    return dict(
        exposure_stops=_u(rng, cfg.exposure_stops), white_balance=rng.uniform(*cfg.white_balance, 3), gamma=_u(rng, cfg.gamma),
        vignette=_u(rng, cfg.vignette), defocus_px=_u(rng, cfg.defocus_px) if rng.random() < cfg.defocus_prob else 0.0,
        motion_px=_u(rng, cfg.motion_px) if rng.random() < cfg.motion_prob else 0.0, motion_angle=float(rng.uniform(0, np.pi)),
        noise=_u(rng, cfg.noise), jpeg_quality=int(round(_u(rng, cfg.jpeg_quality))) if rng.random() < cfg.jpeg_prob else 0,
        noise_seed=int(rng.integers(2**31)))


def _part_hsv(rng, base_hsv: np.ndarray, cfg: AppearanceConfig, repaint: bool = False) -> np.ndarray:
    out = []
    for h, s, v in base_hsv:
        mode = rng.random() * ((cfg.part_grey_prob + cfg.part_recolour_prob) if repaint else 1.0)
        if mode < cfg.part_grey_prob:
            h, s, v = 0.0, 0.0, _u(rng, cfg.part_value)
        elif mode < cfg.part_grey_prob + cfg.part_recolour_prob:
            h, s, v = _allowed_hue(rng, cfg.hue_exclude_deg), float(rng.uniform(0, 1)), _u(rng, cfg.part_value)
        else:
            h, s = h + _u(rng, cfg.part_hue_shift_deg), min(1.0, s * _u(rng, cfg.part_saturation_scale))
        v = v + _u(rng, cfg.dark_lift) * (1.0 - v)
        out.append((_out_of_band(h, s, cfg), s, min(1.0, v)))
    return np.array(out, np.float64).reshape(-1, 3)


def sample_look(cfg: AppearanceConfig, seed: int, index: int, base_colors: np.ndarray, slots: int = 4) -> Look:
    """The v2 training look of image `index` of data set `seed`; base_colors: the model's
    colour groups (G, 3). A pure function of its arguments."""
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), int(index), _STREAM_LOOK]))
    repaint = cfg.repaint_prob > 0 and rng.random() < cfg.repaint_prob  # no draw at 0: older sets unchanged
    dim = cfg.dim_room_prob > 0 and rng.random() < cfg.dim_room_prob  # likewise; before the parts, whose lift it sets
    part = _part_hsv(rng, rgb_to_hsv(base_colors), dataclasses.replace(cfg, dark_lift=cfg.dim_room_lift) if dim else cfg, repaint)
    lighting = cfg.lighting[rng.integers(len(cfg.lighting))]
    az, el = rng.uniform(-np.pi, np.pi), _u(rng, cfg.sun_elevation_rad)
    flash = lighting == "sun+flash" and rng.random() < cfg.flash_prob
    distractors = np.stack([_part_hsv(rng, np.array([[0.0, 1.0, 0.8], [0.0, 0.0, 0.1]]), cfg) for _ in range(slots)])
    shadow = rng.random() < cfg.shadow_prob
    look = Look(
        part_hsv=part, lighting=lighting,
        ambient_rgb=_light_rgb(rng, cfg.light_saturation, _u(rng, cfg.ambient)),
        sun_rgb=_light_rgb(rng, cfg.light_saturation, _u(rng, cfg.sun)),
        sun_dir=np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)]),
        flash_rgb=_light_rgb(rng, cfg.light_saturation, _u(rng, cfg.flash)) * flash,
        flash_offset=rng.uniform(*cfg.flash_offset_m, 3), flash_falloff=_u(rng, cfg.flash_falloff),
        specular=_u(rng, cfg.specular), shininess=float(np.exp(rng.uniform(*np.log(cfg.shininess)))),
        sky_rgb=np.zeros(3), ground_rgb=np.zeros(3),
        shadow_strength=_u(rng, cfg.shadow_strength) if shadow else 0.0, shadow_blur_px=_u(rng, cfg.shadow_blur_px),
        contact_strength=_u(rng, cfg.contact_strength),
        **_camera(rng, cfg),
        textures=tuple(sample_texture(rng, cfg.texture_kinds, cfg.texture_photos) for _ in range(6)),
        backdrop_photo=cfg.backdrop_photos[rng.integers(len(cfg.backdrop_photos))],
        distractor_hsv=distractors,
    )
    if cfg.camouflage_prob > 0 and rng.random() < cfg.camouflage_prob:  # after the rest: no draw at 0, older sets unchanged
        look = dataclasses.replace(look, camouflage=_u(rng, cfg.camouflage))
    if cfg.monochrome_prob > 0 and rng.random() < cfg.monochrome_prob:  # likewise
        look = dataclasses.replace(look, part_hsv=_monochrome_hsv(rng, len(part), cfg))
    if dim:
        look = dataclasses.replace(look, room_gain=float(np.exp(rng.uniform(*np.log(cfg.dim_room)))))
    return look


def _monochrome_hsv(rng, n: int, cfg: AppearanceConfig) -> np.ndarray:
    """(n, 3) HSV of a robot in one paint: a hue shared by every part, saturation and value each
    part's own (`AppearanceConfig.monochrome_prob`)."""
    h = _allowed_hue(rng, cfg.hue_exclude_deg)  # outside the held-out band at any saturation
    out = []
    for _ in range(n):
        s, v = float(rng.uniform(0, 1)), _u(rng, cfg.part_value)
        out.append((h, s, min(1.0, v + _u(rng, cfg.dark_lift) * (1.0 - v))))
    return np.array(out, np.float64).reshape(-1, 3)


def sample_paint(rng: np.random.Generator, base_colors: np.ndarray, cfg: AppearanceConfig | None = None) -> np.ndarray:
    """(G, 3) RGB in [0, 1]: the model's colour groups `base_colors` (G, 3) repainted as training
    repaints the robot, half the time in one paint (`monochrome_prob`'s draw), else each part grey
    or recoloured (`repaint_prob`'s); hues outside the held-out band as every training draw. For
    renders that must not carry the robot's own paint (the scorer's `paint_prob`)."""
    cfg = cfg or AppearanceConfig()
    if rng.random() < 0.5:
        hsv = _monochrome_hsv(rng, len(base_colors), cfg)
    else:
        hsv = _part_hsv(rng, rgb_to_hsv(base_colors), cfg, repaint=True)
    return hsv_to_rgb(hsv)


def surroundings(mask: np.ndarray) -> tuple[tuple[slice, slice], np.ndarray]:
    """The robot's surroundings in an image: (box, around), box the slices of the mask's bounding
    box grown by half its size on each side (clipped to the image), around the (h, w) boolean of
    that box's pixels outside the mask. Camouflage matches the robot to them; the detection-miss
    study measures contrast against them."""
    ys, xs = np.nonzero(mask)
    gy, gx = (np.ptp(ys) + 2) // 2, (np.ptp(xs) + 2) // 2
    box = (slice(max(0, ys.min() - gy), ys.max() + 1 + gy), slice(max(0, xs.min() - gx), xs.max() + 1 + gx))
    return box, ~mask[box]


def camouflaged(part_rgb: np.ndarray, robot_mean: np.ndarray, around_mean: np.ndarray, t: float,
                cfg: AppearanceConfig) -> np.ndarray:
    """The parts' colours (G, 3) under camouflage t (see `AppearanceConfig`): each channel times
    (around_mean / robot_mean) ** t, clipped to [0, 1], hues kept out of cfg.hue_exclude_deg."""
    eps = 1e-3  # guard: a black robot or a black surround (the gain stays finite)
    gain = (np.maximum(around_mean, eps) / np.maximum(robot_mean, eps)) ** t
    hsv = rgb_to_hsv(np.clip(np.asarray(part_rgb, np.float64) * gain, 0.0, 1.0))
    hsv[:, 0] = [_out_of_band(h, s, cfg) for h, s, _ in hsv]
    return hsv_to_rgb(hsv)


def sample_heldout_look(held: HeldoutConfig, seed: int, index: int, base_colors: np.ndarray, slots: int = 4) -> Look:
    """The held-out look of image (or scenario) `index` of benchmark `seed` (camera effects from
    held.camera's ranges). A pure function of its arguments."""
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), int(index), _STREAM_HELDOUT]))
    G = len(base_colors)
    hue = held.part_hue_deg or (0.0, 360.0)  # (None: replaced by the robot's own colours below)
    part = np.stack([rng.uniform(*hue, G), rng.uniform(*held.part_saturation, G), rng.uniform(*held.part_value, G)], 1)
    sky_hue = rng.uniform(0, 360)
    sky = hsv_to_rgb(np.array([sky_hue, _u(rng, held.light_saturation), 1.0])) * _u(rng, held.sky)
    ground = hsv_to_rgb(np.array([(sky_hue + rng.uniform(90, 270)) % 360, _u(rng, held.light_saturation), 1.0])) * _u(rng, held.ground)
    zero = np.zeros(3)
    look = Look(
        part_hsv=part, lighting=held.lighting, ambient_rgb=zero, sun_rgb=zero, sun_dir=np.array([0.0, 0.0, 1.0]), flash_rgb=zero,
        flash_offset=zero, flash_falloff=0.0, specular=0.0, shininess=1.0, sky_rgb=sky, ground_rgb=ground,
        shadow_strength=0.0, shadow_blur_px=1.0, contact_strength=float(rng.uniform(0.2, 0.5)),
        **_camera(rng, held.camera),
        textures=tuple(sample_texture(rng, held.texture_kinds, held.texture_photos) for _ in range(6)),
        backdrop_photo=held.backdrop_photos[rng.integers(len(held.backdrop_photos))],
        distractor_hsv=np.stack([rgb_to_hsv(rng.uniform(0.05, 0.95, (2, 3))) for _ in range(slots)]),
    )
    # drawn after the held-out set's own draws, which stay as they were
    extra = {}
    if held.part_hue_deg is None:
        extra["part_hsv"] = rgb_to_hsv(base_colors)
    if held.livery_period_m[1] > 0:
        extra.update(livery_period=_u(rng, held.livery_period_m), livery_rgb=np.full(3, _u(rng, held.livery_value)))
    if held.specular[1] > 0:
        extra.update(specular=_u(rng, held.specular), shininess=float(np.exp(rng.uniform(*np.log(held.shininess)))))
    if held.lighting == "lamps":
        n = int(rng.integers(round(held.n_lamps[0]), round(held.n_lamps[1]) + 1))
        extra.update(ambient_rgb=np.full(3, _u(rng, held.ambient)), sky_rgb=zero, ground_rgb=zero,
                     lamp_pos=np.stack([rng.uniform(-2.0, 8.0, n), rng.uniform(-4.0, 4.0, n), rng.uniform(2.4, 3.2, n)], 1),
                     lamp_rgb=np.stack([_light_rgb(rng, held.light_saturation, _u(rng, held.lamp)) for _ in range(n)]))
    return dataclasses.replace(look, **extra)


# ----------------------------------------------------------------------------- shading


def _lights(look: Look, points, normals, cam_pos, view_dir=None):
    """Diffuse (N, 3) and specular (N, 3) light at world points (N, 3) with unit normals (N, 3);
    view_dir (N, 3) unit vectors towards the camera (None: no highlights)."""
    if look.lighting == "hemisphere":
        up = normals[:, 2:3]
        return look.sky_rgb * (1 + up) / 2 + look.ground_rgb * (1 - up) / 2, np.zeros_like(points)
    if look.lighting == "lamps":  # lamp positions are relative to the camera's, height absolute
        diffuse, spec = np.broadcast_to(look.ambient_rgb, points.shape).copy(), np.zeros_like(points)
        for pos, rgb in zip(look.lamp_pos, look.lamp_rgb):
            to = np.array([cam_pos[0] + pos[0], cam_pos[1] + pos[1], pos[2]]) - points
            d = np.maximum(np.linalg.norm(to, axis=1, keepdims=True), 1e-3)  # guard: a point at the lamp
            ld, fall = to / d, np.minimum((3.0 / d) ** 2, 4.0)
            nl = np.maximum((normals * ld).sum(1, keepdims=True), 0.0)
            diffuse += rgb * fall * nl
            if view_dir is not None and look.specular > 0:
                hv = ld + view_dir
                hv /= np.maximum(np.linalg.norm(hv, axis=1, keepdims=True), 1e-9)  # guard: lamp opposite the eye
                spec += rgb * fall * (nl > 0) * np.maximum((normals * hv).sum(1, keepdims=True), 0.0) ** look.shininess
        return diffuse, spec * look.specular
    ndl = np.maximum(normals @ look.sun_dir, 0.0)[:, None]
    diffuse = look.ambient_rgb + look.sun_rgb * ndl
    spec = np.zeros_like(points)
    if view_dir is not None and look.specular > 0:
        hv = look.sun_dir + view_dir
        hv /= np.maximum(np.linalg.norm(hv, axis=1, keepdims=True), 1e-9)  # guard: light opposite the eye
        spec += look.sun_rgb * (ndl > 0) * np.maximum((normals * hv).sum(1, keepdims=True), 0.0) ** look.shininess
    if np.any(look.flash_rgb):
        to = np.asarray(cam_pos) + look.flash_offset - points
        d = np.maximum(np.linalg.norm(to, axis=1, keepdims=True), 1e-3)  # guard: a point at the light
        ld = to / d
        fall = np.minimum((3.0 / d) ** look.flash_falloff, 2.0)
        nfl = np.maximum((normals * ld).sum(1, keepdims=True), 0.0)
        diffuse = diffuse + look.flash_rgb * fall * nfl
        if view_dir is not None and look.specular > 0:
            hv = ld + view_dir
            hv /= np.maximum(np.linalg.norm(hv, axis=1, keepdims=True), 1e-9)
            spec += look.flash_rgb * fall * (nfl > 0) * np.maximum((normals * hv).sum(1, keepdims=True), 0.0) ** look.shininess
    return diffuse, spec * look.specular


def face_normals_world(vertices_world: np.ndarray, faces: np.ndarray, cam_pos) -> np.ndarray:
    """(F, 3) unit face normals turned towards the camera at cam_pos (world frame)."""
    v = vertices_world[faces]  # (F, 3, 3)
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)  # guard: degenerate faces
    flip = ((np.asarray(cam_pos) - v.mean(1)) * n).sum(1) < 0
    n[flip] *= -1
    return n


def shade_layer(albedo, mask, depth, face_id, normals_world, K, cam_pose, look: Look, highlights: bool = True,
                body=None) -> np.ndarray:
    """A rendered layer (albedo (H, W, 3), mask, depth, face_id) shaded by `look`'s lights:
    (H, W, 3) float32. cam_pose: (R_world_optical (3, 3), camera position (3,)); body: the
    robot's (R_world_body (3, 3), position (3,)), where `look` paints a livery (None: none)."""
    R, c = cam_pose
    out = np.zeros(albedo.shape, np.float32)
    ys, xs = np.nonzero(mask)
    if len(ys) == 0:
        return out
    rays = np.stack([(xs - K[0, 2]) / K[0, 0], (ys - K[1, 2]) / K[1, 1], np.ones(len(xs))], 1)
    pts = (rays * depth[ys, xs][:, None]) @ R.T + c  # world points (N, 3)
    n = normals_world[face_id[ys, xs]]
    view = c - pts
    view /= np.maximum(np.linalg.norm(view, axis=1, keepdims=True), 1e-9)  # guard: a point at the eye
    diffuse, spec = _lights(look, pts, n, c, view if highlights else None)
    a = albedo[ys, xs]
    if look.livery_period > 0 and body is not None:
        cell = np.floor(((pts - body[1]) @ body[0]) / look.livery_period).sum(1) % 2  # checker in the body frame
        a = np.where(cell[:, None] > 0, look.livery_rgb, a)
    out[ys, xs] = a * diffuse + spec
    return out


def shade_room(albedo, face, points, look: Look, cam_pos) -> np.ndarray:
    """The room's albedo (H, W, 3) under `look`'s lights (no highlights): (H, W, 3) float32."""
    H, W = face.shape
    pts = np.stack([p.reshape(-1) for p in points], 1).astype(np.float64)
    diffuse, _ = _lights(look, pts, ROOM_NORMALS[face.reshape(-1)].astype(np.float64), cam_pos)
    return (albedo.reshape(-1, 3) * diffuse).reshape(H, W, 3).astype(np.float32)


def darken(rgb: np.ndarray, mask: np.ndarray, strength: float, blur_px: float) -> np.ndarray:
    """rgb * (1 - strength * soft mask): a shadow of `mask` blurred by blur_px."""
    if strength <= 0 or not mask.any():
        return rgb
    m = mask.astype(np.float32)
    if blur_px > 0:
        m = cv2.GaussianBlur(m, (0, 0), blur_px)
    return rgb * (1.0 - strength * m)[..., None]


def camera_effects(rgb: np.ndarray, look: Look, scale: float = 1.0) -> np.ndarray:
    """The camera's rendering of a linear image (H, W, 3) float: blur, exposure, white balance,
    vignetting, noise, gamma, 8-bit quantisation and JPEG. scale: pixel sizes x scale. -> uint8."""
    img = np.asarray(rgb, np.float32)
    if look.defocus_px * scale > 0.05:
        img = cv2.GaussianBlur(img, (0, 0), look.defocus_px * scale)
    length = look.motion_px * scale
    if length >= 1.0:
        k = int(np.ceil(length)) | 1
        kern = np.zeros((k, k), np.float32)
        c = k // 2
        for t in np.linspace(-length / 2, length / 2, 4 * k):
            kern[int(round(c + t * np.sin(look.motion_angle))), int(round(c + t * np.cos(look.motion_angle)))] = 1.0
        img = cv2.filter2D(img, -1, kern / kern.sum(), borderType=cv2.BORDER_REFLECT)
    img = img * np.float32(2.0 ** look.exposure_stops) * look.white_balance.astype(np.float32)
    H, W = img.shape[:2]
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    r2 = ((xx - (W - 1) / 2) ** 2 + (yy - (H - 1) / 2) ** 2) / (((W - 1) / 2) ** 2 + ((H - 1) / 2) ** 2)
    img = img * (1.0 - look.vignette * r2)[..., None]
    if look.noise > 0:
        img = img + look.noise * np.random.default_rng(look.noise_seed).standard_normal(img.shape).astype(np.float32)
    img = np.clip(img, 0.0, 1.0) ** np.float32(1.0 / look.gamma)
    out = (img * 255 + 0.5).astype(np.uint8)
    if look.jpeg_quality > 0:
        ok, buf = cv2.imencode(".jpg", out[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, int(look.jpeg_quality)])
        out = np.ascontiguousarray(cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1])
    return out


def world_from_optical(camera_height: float, observer_xypsi=(0.0, 0.0, 0.0)):
    """(R_world_optical (3, 3), camera position (3,)) of the observer's camera."""
    x, y, psi = (float(v) for v in observer_xypsi)
    c, s = math.cos(psi), math.sin(psi)
    Rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return Rz @ R_ROBOT_OPTICAL, np.array([x, y, camera_height])


MILD_CAMERA.validate()

OOD_VALIDATION = HeldoutConfig(lighting="lamps", light_saturation=(0.7, 0.9), part_hue_deg=None,
                               livery_period_m=(0.05, 0.12), specular=(1.0, 2.0), shininess=(256.0, 1024.0),
                               texture_kinds=("hexagons", "photo"), texture_photos=("retina",), backdrop_photos=("retina",))
"""The out-of-distribution validation set's settings (module docstring): outside training's
ranges and apart from the held-out set's; choices are made on it, never on the held-out set."""
