"""`metrics.flips_by_view`: which side of the observed robot faces the camera, and the flips per view."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from rhaml_jax.metrics import VIEWS_DEG, flips_by_view, view_deg

bearings = st.floats(-1.2, 1.2)  # inside any camera's view
ranges = st.floats(1.0, 8.0)


@given(bearings, ranges)
def test_a_robot_driving_away_shows_its_back(b, r):
    """Heading along the line of sight from the camera: its back faces it (0 deg); the other way
    its front (180 deg); across it, its side (90 deg)."""
    at = np.array([r * np.cos(b), r * np.sin(b)])
    poses = np.array([[*at, b], [*at, b + np.pi], [*at, b + np.pi / 2], [*at, b - np.pi / 2]])
    np.testing.assert_allclose(view_deg(poses), [0.0, 180.0, 90.0, 90.0], atol=1e-6)


@given(bearings, ranges)
def test_flips_are_counted_in_the_view_of_the_truth(b, r):
    at = [r * np.cos(b), r * np.sin(b)]
    gt = np.array([[*at, b], [*at, b], [*at, b + np.pi], [*at, b + 1.0]])  # back, back, front, side
    est = np.array([b + np.pi, b + 0.1, b + np.pi, b + 1.0 + np.pi])      # flipped, kept, kept, flipped
    assert flips_by_view(est, gt) == {"back": [1, 2], "side": [1, 1], "front": [0, 1]}


def test_views_cover_every_angle_once():
    edges = sorted(v for lohi in VIEWS_DEG.values() for v in lohi)
    assert edges[0] == 0.0 and edges[-1] == 180.0 and all(a == b for a, b in zip(edges[1::2], edges[2::2]))
    assert flips_by_view(np.zeros(0), np.zeros((0, 3))) == {k: [0, 0] for k in VIEWS_DEG}
