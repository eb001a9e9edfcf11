"""Backgrounds that teach the network the robot, not the scene (structured domain randomisation).

A backdrop is either a box-shaped room (floor, ceiling and four walls, each with a random
procedural or photographic texture, lit by the same light as the robot) seen from the
observer's camera, or a real photograph (the few that scikit-image ships, no download).
Everything here is host-side NumPy and a pure function of the random generator it is given.
"""

from __future__ import annotations

import dataclasses
import functools

import cv2
import numpy as np

from rhaml_jax.camera import R_ROBOT_OPTICAL

# scikit-image's bundled photographs (checked to load offline): scenes and objects for
# backdrops, textures for walls and floors.
PHOTOS = ("astronaut", "camera", "chelsea", "coffee", "coins", "rocket", "page", "text", "clock", "horse")
TEXTURES = ("brick", "grass", "gravel")


@dataclasses.dataclass(frozen=True)
class Light:
    """Lambertian light shared by the room and the robot.

    direction: (3,) unit vector towards the light, in the observer's robot frame.
    ambient, diffuse: shading = colour * (ambient + diffuse * max(0, n . l)).
    """

    direction: tuple[float, float, float]
    ambient: float
    diffuse: float

    def in_camera(self) -> np.ndarray:
        """The direction in the camera's optical frame (what the renderer takes)."""
        return np.asarray(self.direction) @ R_ROBOT_OPTICAL


def sample_light(rng: np.random.Generator) -> Light:
    az, el = rng.uniform(-np.pi, np.pi), rng.uniform(0.2, 1.4)
    d = (np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el))
    ambient = rng.uniform(0.25, 0.6)
    return Light(tuple(float(x) for x in d), float(ambient), float(rng.uniform(0.3, 1.0 - ambient + 0.3)))


@functools.lru_cache(maxsize=None)
def _skimage(name: str) -> np.ndarray:
    """(H, W, 3) float32 in [0, 1] of a scikit-image bundled image."""
    import skimage.data

    img = getattr(skimage.data, name)()
    if isinstance(img, tuple):  # stereo pairs: the left image
        img = img[0]
    img = np.asarray(img)
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    return img[..., :3].astype(np.float32) / 255.0


def photo(rng: np.random.Generator, width: int, height: int, names: tuple[str, ...] = PHOTOS) -> np.ndarray:
    """A random crop of a random bundled photograph (one of `names`), flipped and colour-shifted:
    (H, W, 3) in [0, 1]."""
    img = _skimage(names[rng.integers(len(names))])
    h, w = img.shape[:2]
    scale = rng.uniform(0.5, 1.0)
    ch, cw = int(h * scale), int(min(w, h * scale * width / height))
    y0, x0 = rng.integers(0, h - ch + 1), rng.integers(0, w - cw + 1)
    crop = cv2.resize(img[y0 : y0 + ch, x0 : x0 + cw], (width, height), interpolation=cv2.INTER_AREA)
    if rng.random() < 0.5:
        crop = crop[:, ::-1]
    gain = rng.uniform(0.6, 1.3, 3).astype(np.float32)
    return np.clip(crop * gain, 0.0, 1.0)


# ----------------------------------------------------------------------------- textures


@dataclasses.dataclass(frozen=True)
class Texture:
    """A procedural texture over surface coordinates (s, t) in metres.

    kind: solid | checker | stripes | tiles | noise | photo | wood | dots | marble | voronoi |
    hexagons; colors: (2, 3) in [0, 1];
    period: pattern size (m); angle: stripe direction (rad); photo: scikit-image name;
    seed: for the noise lattice.
    """

    kind: str
    colors: tuple
    period: float
    angle: float
    photo: str
    seed: int

    def __call__(self, s: np.ndarray, t: np.ndarray) -> np.ndarray:
        c0, c1 = np.asarray(self.colors[0], np.float32), np.asarray(self.colors[1], np.float32)
        p = self.period
        if self.kind == "solid":
            w = np.zeros_like(s)
        elif self.kind == "checker":
            w = ((np.floor(s / p) + np.floor(t / p)) % 2).astype(np.float32)
        elif self.kind == "stripes":
            u = s * np.cos(self.angle) + t * np.sin(self.angle)
            w = (np.floor(u / p) % 2).astype(np.float32)
        elif self.kind == "tiles":  # light grout lines between tiles
            fs, ft = (s / p) % 1.0, (t / p) % 1.0
            w = ((fs < 0.06) | (ft < 0.06)).astype(np.float32)
        elif self.kind == "noise":  # smooth value noise on a lattice of `period` m
            lattice = np.random.default_rng(self.seed).random((64, 64)).astype(np.float32)
            gs, gt = s / p, t / p
            i0, j0 = np.floor(gs).astype(np.int64), np.floor(gt).astype(np.int64)
            fs, ft = gs - i0, gt - j0
            L = lambda i, j: lattice[i % 64, j % 64]  # noqa: E731
            w = (L(i0, j0) * (1 - fs) + L(i0 + 1, j0) * fs) * (1 - ft) + (L(i0, j0 + 1) * (1 - fs) + L(i0 + 1, j0 + 1) * fs) * ft
        elif self.kind == "wood":  # rings around a far centre, wobbled by a sine
            u = s * np.cos(self.angle) + t * np.sin(self.angle)
            r = np.hypot(u + 7.0 * p, 0.3 * (t * np.cos(self.angle) - s * np.sin(self.angle)))
            w = (0.5 + 0.5 * np.sin(2 * np.pi * (r / (0.2 * p)) + 2.0 * np.sin(u / p))).astype(np.float32)
        elif self.kind == "dots":  # polka dots on a square lattice
            fs, ft = (s / p) % 1.0 - 0.5, (t / p) % 1.0 - 0.5
            w = (np.hypot(fs, ft) < 0.3).astype(np.float32)
        elif self.kind == "marble":  # veins: a sine of a coordinate plus lattice noise
            g = np.random.default_rng(self.seed).random((32, 32)).astype(np.float32)
            turb = g[(s / p * 4).astype(np.int64) % 32, (t / p * 4).astype(np.int64) % 32]
            u = s * np.cos(self.angle) + t * np.sin(self.angle)
            w = (np.abs(np.sin(np.pi * (u / p + 1.5 * turb))) ** 0.3).astype(np.float32)
        elif self.kind == "voronoi":  # cells of the nearest random site (Worley), one colour mix per cell
            rng = np.random.default_rng(self.seed)
            site, mix = rng.random((64, 64, 2)).astype(np.float32), rng.random((64, 64)).astype(np.float32)
            gs, gt = s / p, t / p
            i0, j0 = np.floor(gs).astype(np.int64), np.floor(gt).astype(np.int64)
            best = np.full(s.shape, np.inf, np.float32)
            w = np.zeros(s.shape, np.float32)
            for di in (-1, 0, 1):
                for dj in (-1, 0, 1):
                    i, j = (i0 + di) % 64, (j0 + dj) % 64
                    d = (i0 + di + site[i, j, 0] - gs) ** 2 + (j0 + dj + site[i, j, 1] - gt) ** 2
                    closer = d < best
                    best, w = np.where(closer, d, best), np.where(closer, mix[i, j], w)
        elif self.kind == "hexagons":  # hexagonal tiles of `period` m, one colour mix per tile, dark grout
            x, y = s / p, t / p
            q, r = 2.0 / 3.0 * x, -1.0 / 3.0 * x + np.sqrt(3.0) / 3.0 * y  # axial coordinates (flat-top)
            cube = np.stack([q, -q - r, r])
            rc = np.round(cube)
            err = np.abs(rc - cube)  # cube rounding: fix the coordinate that rounded worst
            worst = np.argmax(err, axis=0)
            for k in range(3):
                others = [j for j in range(3) if j != k]
                rc[k] = np.where(worst == k, -rc[others[0]] - rc[others[1]], rc[k])
            mix = np.random.default_rng(self.seed).random((64, 64)).astype(np.float32)
            w = mix[rc[0].astype(np.int64) % 64, rc[2].astype(np.int64) % 64]
            d = cube - rc
            edge = np.max(np.abs(d - np.roll(d, 1, axis=0)), axis=0)  # 0 at a tile's centre, 1 on its rim
            w = np.where(edge > 0.88, 0.0, w).astype(np.float32)
        elif self.kind == "photo":
            img = _skimage(self.photo)
            h, w_ = img.shape[:2]
            scale = max(h, w_) / p  # the image spans `period` metres
            rgb = img[(t * scale).astype(np.int64) % h, (s * scale).astype(np.int64) % w_]
            return rgb * (0.5 + c0)  # tinted
        else:
            raise ValueError(self.kind)
        return c0 * (1 - w[..., None]) + c1 * w[..., None]


KINDS = ("solid", "checker", "stripes", "tiles", "noise", "photo")  # what the v1 data draws


def sample_texture(rng: np.random.Generator, kinds: tuple[str, ...] = KINDS, photos: tuple[str, ...] = TEXTURES) -> Texture:
    """A random texture of one of `kinds`; a photo texture shows one of `photos` (the defaults
    are the v1 data's, whose draws they reproduce)."""
    colors = rng.uniform(0.05, 0.95, (2, 3))
    if rng.random() < 0.5:  # often muted, like real rooms
        colors = 0.5 * colors + 0.5 * colors.mean(axis=1, keepdims=True)
    return Texture(
        kind=kinds[rng.integers(len(kinds))],
        colors=tuple(map(tuple, colors.astype(float))),
        period=float(np.exp(rng.uniform(np.log(0.1), np.log(2.0)))),
        angle=float(rng.uniform(0, np.pi)),
        photo=photos[rng.integers(len(photos))],
        seed=int(rng.integers(2**31)),
    )


# ----------------------------------------------------------------------------- rooms


@dataclasses.dataclass(frozen=True)
class RoomLook:
    """A room's box [x0, x1] x [y0, y1] x [0, height] (world metres) and its six textures
    (floor, ceiling, wall x0, wall x1, wall y0, wall y1)."""

    bounds: tuple[float, float, float, float]
    height: float
    textures: tuple[Texture, ...]


def sample_room(rng: np.random.Generator, bounds, height: float | None = None) -> RoomLook:
    h = float(rng.uniform(2.2, 4.0)) if height is None else float(height)
    return RoomLook(tuple(float(b) for b in bounds), h, tuple(sample_texture(rng) for _ in range(6)))


def room_surfaces(room: RoomLook, K: np.ndarray, width: int, height: int, observer_xypsi, camera_height: float):
    """Where each pixel's ray leaves the room: (depth t (H, W) along the optical axis, face index
    (H, W) int8 into floor, ceiling, walls x0, x1, y0, y1, world points (px, py, pz) (H, W) each).

    The camera must be inside the room."""
    x0, x1, y0, y1 = room.bounds
    ox, oy, opsi = (float(v) for v in observer_xypsi)
    u = ((np.arange(width, dtype=np.float32) - K[0, 2]) / K[0, 0])[None, :]  # (1, W) optical x / z
    v = ((np.arange(height, dtype=np.float32) - K[1, 2]) / K[1, 1])[:, None]  # (H, 1) optical y / z
    c, s = np.float32(np.cos(opsi)), np.float32(np.sin(opsi))
    # World direction of the ray through each pixel, scaled so its optical depth is 1:
    # robot frame (x fwd, y left, z up) = (1, -u, -v), rotated by the observer's heading.
    dx = np.broadcast_to(c + s * u, (height, width))
    dy = np.broadcast_to(s - c * u, (height, width))
    dz = np.broadcast_to(-v, (height, width))
    o = (np.float32(ox), np.float32(oy), np.float32(camera_height))
    # Exit distance through each face of the box (the camera is inside): t = (plane - o) / d,
    # kept as a running minimum with the index of the face it came from.
    t = np.full((height, width), np.inf, np.float32)
    face = np.zeros((height, width), np.int8)
    planes = ((dz, 0.0, o[2], -1), (dz, room.height, o[2], 1), (dx, x0, o[0], -1), (dx, x1, o[0], 1), (dy, y0, o[1], -1), (dy, y1, o[1], 1))
    with np.errstate(divide="ignore", invalid="ignore"):
        for f, (d, plane, origin, sign) in enumerate(planes):
            tf = (np.float32(plane) - origin) / d
            better = (sign * d > 0) & (tf < t)
            t = np.where(better, tf, t)
            face = np.where(better, np.int8(f), face)
    return t, face, (o[0] + dx * t, o[1] + dy * t, o[2] + dz * t)


ROOM_NORMALS = np.array([[0, 0, 1], [0, 0, -1], [1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0]], np.float32)


def room_albedo(room: RoomLook, face: np.ndarray, points) -> np.ndarray:
    """The textures' colours at the surface points: (H, W, 3) float32 (unshaded)."""
    px, py, pz = points
    st = [(px, py), (px, py), (py, pz), (py, pz), (px, pz), (px, pz)]  # surface coordinates (m)
    out = np.zeros(face.shape + (3,), np.float32)
    for f in range(6):
        sel = face == f
        if np.any(sel):
            out[sel] = room.textures[f](st[f][0][sel], st[f][1][sel])
    return out


def room_image(room: RoomLook, light: Light, K: np.ndarray, width: int, height: int, observer_xypsi, camera_height: float):
    """The room seen by the observer's camera: (rgb (H, W, 3) float32 in [0, 1], depth (H, W) metres).

    Depth is along the optical axis, as the renderer's. The camera must be inside the room.
    """
    t, face, (px, py, pz) = room_surfaces(room, K, width, height, observer_xypsi, camera_height)
    normals = ROOM_NORMALS
    # Surface coordinates of each face, in metres.
    st = [(px, py), (px, py), (py, pz), (py, pz), (px, pz), (px, pz)]
    rgb = np.zeros((height, width, 3), np.float32)
    ldir = np.asarray(light.direction, np.float32)
    for f in range(6):
        sel = face == f
        if not np.any(sel):
            continue
        shade = light.ambient + light.diffuse * max(0.0, float(normals[f] @ ldir))
        rgb[sel] = room.textures[f](st[f][0][sel], st[f][1][sel]) * shade
    return np.clip(rgb, 0.0, 1.0), t  # t is the optical depth (rays have z = 1 in the optical frame)
