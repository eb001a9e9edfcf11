"""The built-in Pioneer-3DX-like robot, built from primitives to the published dimensions.

Published size: 455 mm long (sonar ring to sonar ring), 381 mm wide (over the wheels),
237 mm tall (top plate). Drive wheels 195 mm in diameter on the axle at x = 0, a rear caster,
a red body, a black top plate and yellow sonar arrays front and back. Colours as in the
amr_robots_description URDF.
"""

from __future__ import annotations

import numpy as np

from rhaml_jax.robots._model import RobotModel

LENGTH, WIDTH, HEIGHT = 0.455, 0.381, 0.237
WHEEL_RADIUS, WHEEL_WIDTH = 0.0975, 0.0475
FRONT_X, REAR_X = 0.19, -0.265  # sonar-ring extremes; LENGTH = FRONT_X - REAR_X

RED = (0.851, 0.0, 0.0)
BLACK = (0.038, 0.038, 0.038)
SONAR_YELLOW = (0.715, 0.583, 0.210)
HUBCAP_YELLOW = (1.0, 0.811, 0.151)
WHEEL_BLACK = (0.117, 0.117, 0.117)
GREY = (0.5, 0.5, 0.5)


def _box(lo, hi):
    import trimesh

    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    m = trimesh.creation.box(extents=hi - lo)
    return np.asarray(m.vertices) + (lo + hi) / 2, np.asarray(m.faces)


def _y_cylinder(center, radius, width, sections=32):
    """A cylinder with its axis along y (a wheel)."""
    import trimesh

    T = np.eye(4)
    T[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]  # z axis -> y axis
    T[:3, 3] = center
    m = trimesh.creation.cylinder(radius=radius, height=width, sections=sections, transform=T)
    return np.asarray(m.vertices), np.asarray(m.faces)


def _prism(outline_xy, z0, z1):
    """Convex prism over a convex outline (N, 2) between heights z0 and z1."""
    import trimesh

    xy = np.asarray(outline_xy, float)
    pts = np.concatenate([np.c_[xy, np.full(len(xy), z0)], np.c_[xy, np.full(len(xy), z1)]])
    m = trimesh.convex.convex_hull(pts)
    return np.asarray(m.vertices), np.asarray(m.faces)


def _arc(cx, rx, ry, a0, a1, n):
    """Points on the ellipse arc around (cx, 0) with radii rx, ry from angle a0 to a1."""
    a = np.linspace(a0, a1, n)
    return np.c_[cx + rx * np.cos(a), ry * np.sin(a)]


def pioneer3dx() -> RobotModel:
    body_half_w = 0.135  # inside the wheels (wheel inner face at 0.143)
    wheel_y = WIDTH / 2 - WHEEL_WIDTH / 2
    parts = [
        ("chassis", *_box((-0.225, -body_half_w, 0.065), (0.150, body_half_w, 0.205)), RED),
        # Sonar arrays: half-octagonal rings in front of and behind the body.
        ("front_sonar", *_prism(_arc(0.150, FRONT_X - 0.150, body_half_w, -np.pi / 2, np.pi / 2, 9), 0.140, 0.200), SONAR_YELLOW),
        ("back_sonar", *_prism(_arc(-0.225, 0.225 + REAR_X, body_half_w, -np.pi / 2, np.pi / 2, 9), 0.140, 0.200), SONAR_YELLOW),
        # Top plate: an octagon-ish slab over the body, 32 mm thick up to the published height.
        (
            "top_plate",
            *_prism(
                np.concatenate([_arc(0.080, 0.100, 0.160, -np.pi / 2, np.pi / 2, 7), _arc(-0.150, 0.100, 0.160, np.pi / 2, 3 * np.pi / 2, 7)]),
                0.205,
                HEIGHT,
            ),
            BLACK,
        ),
        ("left_wheel", *_y_cylinder((0.0, wheel_y, WHEEL_RADIUS), WHEEL_RADIUS, WHEEL_WIDTH), WHEEL_BLACK),
        ("right_wheel", *_y_cylinder((0.0, -wheel_y, WHEEL_RADIUS), WHEEL_RADIUS, WHEEL_WIDTH), WHEEL_BLACK),
        ("left_hubcap", *_y_cylinder((0.0, WIDTH / 2 - 0.005, WHEEL_RADIUS), 0.055, 0.010, 16), HUBCAP_YELLOW),
        ("right_hubcap", *_y_cylinder((0.0, -WIDTH / 2 + 0.005, WHEEL_RADIUS), 0.055, 0.010, 16), HUBCAP_YELLOW),
        # Rear caster: a swivel block under the body and a small wheel touching the ground.
        ("caster_swivel", *_box((-0.215, -0.025, 0.045), (-0.175, 0.025, 0.065)), GREY),
        ("caster_wheel", *_y_cylinder((-0.200, 0.0, 0.0375), 0.0375, 0.025, 20), WHEEL_BLACK),
    ]
    return RobotModel.from_parts("pioneer3dx", parts).normalized()


BUILTIN = {"pioneer3dx": pioneer3dx}
