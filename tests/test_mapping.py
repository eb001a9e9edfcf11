"""rhaml_jax.mapping: map_server files, resampling and merging, lidar ray casting, log-odds updates."""

from __future__ import annotations

import cv2
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from rhaml_jax.errors import RhamlError
from rhaml_jax.mapping import (GridSpec, LidarConfig, OccupancyMap, beam_angles, cast_rays, integrate_scans, merge_maps,
                               random_field, read_map, read_pgm, resample, true_map, write_map)


def _yaml(path, image, **fields):
    doc = {"image": image, "resolution": 0.05, "origin": [1.0, -2.0, 0.0], "negate": 0, "occupied_thresh": 0.65,
           "free_thresh": 0.196} | fields
    lines = [f"{k}: {v}" for k, v in doc.items() if v is not None]
    path.write_text("\n".join(lines) + "\n")
    return path


# ----------------------------------------------------------------------------- files


def test_round_trip_keeps_classes_origin_and_orientation(tmp_path):
    rng = np.random.default_rng(0)
    occ = rng.choice([0.0, 1.0, np.nan], size=(13, 17), p=[0.6, 0.2, 0.2]).astype(np.float32)
    m = OccupancyMap(occ, 0.05, (1.5, -2.25, 0.1))
    write_map(tmp_path / "m.yaml", m)
    back = read_map(tmp_path / "m.yaml")
    assert back.shape == m.shape and back.resolution == 0.05 and back.origin == pytest.approx(m.origin)
    np.testing.assert_array_equal(back.occupied, m.occupied)
    np.testing.assert_array_equal(back.free, m.free)
    np.testing.assert_array_equal(back.known, m.known)
    # map_saver's image: row 0 of the file is the top (largest y)
    img = read_pgm(tmp_path / "m.pgm")
    assert img[0, 0] == {0.0: 254, 1.0: 0}.get(float(occ[-1, 0]), 205)


def test_negate_trinary_scale_raw(tmp_path):
    # grey levels: 0 black, 128 Cartographer's unknown, 200 light grey, 254 white; one row, four cells
    img = np.array([[0, 128, 200, 254]], np.uint8)
    cv2.imwrite(str(tmp_path / "g.png"), img)
    tri = read_map(_yaml(tmp_path / "t.yaml", "g.png"))
    np.testing.assert_array_equal(tri.occupancy, np.array([[1.0, np.nan, np.nan, 0.0]], np.float32))
    neg = read_map(_yaml(tmp_path / "n.yaml", "g.png", negate=1))  # white is occupied
    np.testing.assert_array_equal(neg.occupancy[0, [0, 3]], [0.0, 1.0])
    sc = read_map(_yaml(tmp_path / "s.yaml", "g.png", mode="scale"))
    p = (255 - np.array([128.0, 200.0])) / 255  # between the thresholds: scaled as nav2 does
    np.testing.assert_allclose(sc.occupancy[0, 1:3], (p - 0.196) / (0.65 - 0.196), rtol=1e-5)
    raw = read_map(_yaml(tmp_path / "r.yaml", "raw.png", mode="raw")) if cv2.imwrite(
        str(tmp_path / "raw.png"), np.array([[0, 50, 100, 255]], np.uint8)) else None
    np.testing.assert_allclose(raw.occupancy, [[0.0, 0.5, 1.0, np.nan]])


def test_nav2_saver_map_keeps_unknown(tmp_path):
    """nav2's map_saver (and slam_toolbox) write unknown as 205 beside free_thresh 0.25, which nav2's
    loader reads as free; an image of only the saver's three levels keeps 205 unknown."""
    (tmp_path / "s.pgm").write_bytes(b"P5\n# CREATOR: map_saver 0.050 m/pix\n3 1\n255\n" + bytes([0, 205, 254]))
    m = read_map(_yaml(tmp_path / "s.yaml", "s.pgm", mode="trinary", free_thresh=0.25))
    np.testing.assert_array_equal(m.occupancy, np.array([[1.0, np.nan, 0.0]], np.float32))
    # a grey map (Cartographer-like) with the same thresholds is read as nav2 reads it: 205 is free
    (tmp_path / "c.pgm").write_bytes(b"P5\n3 1\n255\n" + bytes([0, 205, 128]))
    m = read_map(_yaml(tmp_path / "c.yaml", "c.pgm", free_thresh=0.25))
    np.testing.assert_array_equal(m.occupancy, np.array([[1.0, 0.0, np.nan]], np.float32))


def test_scale_mode_transparent_pixels_are_unknown(tmp_path):
    bgra = np.zeros((1, 3, 4), np.uint8)
    bgra[..., :3] = 254
    bgra[..., 3] = [255, 0, 255]
    cv2.imwrite(str(tmp_path / "a.png"), bgra)
    m = read_map(_yaml(tmp_path / "a.yaml", "a.png", mode="scale"))
    np.testing.assert_array_equal(m.known, [[True, False, True]])


def test_pgm_with_comments_ascii_and_16_bit(tmp_path):
    (tmp_path / "c.pgm").write_bytes(b"P5\n# Cartographer map; 0.05 m/pixel\n3 1\n255\n" + bytes([0, 128, 254]))
    np.testing.assert_array_equal(read_pgm(tmp_path / "c.pgm"), [[0, 128, 254]])
    (tmp_path / "a.pgm").write_text("P2\n# ascii\n3 1\n15\n0 8 15\n")
    np.testing.assert_array_equal(read_pgm(tmp_path / "a.pgm"), [[0, 136, 255]])
    (tmp_path / "w.pgm").write_bytes(b"P5 2 1 65535\n" + np.array([0, 65535], ">u2").tobytes())
    np.testing.assert_array_equal(read_pgm(tmp_path / "w.pgm"), [[0, 255]])


@pytest.mark.parametrize("drop,message", [("resolution", "'resolution' is missing"), ("origin", "'origin' is missing")])
def test_yaml_missing_fields(tmp_path, drop, message):
    cv2.imwrite(str(tmp_path / "g.png"), np.zeros((2, 2), np.uint8))
    with pytest.raises(RhamlError, match=message):
        read_map(_yaml(tmp_path / "m.yaml", "g.png", **{drop: None}))


def test_yaml_image_missing(tmp_path):
    with pytest.raises(RhamlError, match="points to .*nothere.pgm, which does not exist"):
        read_map(_yaml(tmp_path / "m.yaml", "nothere.pgm"))


# ----------------------------------------------------------------------------- resampling and merging


def test_identity_and_whole_cell_translation_are_exact():
    rng = np.random.default_rng(1)
    occ = rng.choice([0.0, 1.0, np.nan], size=(20, 30)).astype(np.float32)
    b = OccupancyMap(occ, 0.1, (0.0, 0.0, 0.0))
    a = OccupancyMap(np.full((5, 5), np.nan, np.float32), 0.1)
    for interp in ("nearest", "linear"):
        m, rep = merge_maps(a, b, (0.7, -0.3, 0.0), interp)  # 7 and -3 cells
        r, c = rep.offset_cells
        # B's cell (i, j) lands at A's cell (i - 3, j + 7)
        got = m.occupancy[r - 3 : r - 3 + 20, c + 7 : c + 7 + 30]
        np.testing.assert_array_equal(np.isnan(got), np.isnan(occ))
        np.testing.assert_allclose(got[~np.isnan(got)], occ[~np.isnan(occ)], atol=1e-6)  # linear: fractions of 1e-15


def test_nearest_keeps_thin_walls_connected_linear_breaks_them():
    """Why nearest is the default: a one-cell wall rotated by 0.3 rad stays one 8-connected line."""
    from scipy.ndimage import label

    occ = np.zeros((100, 100), np.float32)
    occ[50, 10:90] = 1.0
    b = OccupancyMap(occ, 0.05)
    a = OccupancyMap(np.full((4, 4), np.nan, np.float32), 0.05)
    pieces = {}
    for interp in ("nearest", "linear"):
        m, _ = merge_maps(a, b, (1.0, 0.5, 0.3), interp)
        pieces[interp] = label(m.occupied, structure=np.ones((3, 3)))[1]
    assert pieces["nearest"] == 1
    assert pieces["linear"] > 5


def test_linear_treats_unknown_as_missing_not_half():
    occ = np.array([[0.0, np.nan]], np.float32)
    m = OccupancyMap(occ, 1.0)
    # 0.3 of the way to the unknown cell: known weight 0.7 -> the free value, not pulled towards 0.5
    v = resample(m, np.array([[0.8, 0.5]]), "linear")
    assert v[0] == pytest.approx(0.0)
    assert np.isnan(resample(m, np.array([[1.3, 0.5]]), "linear")[0])  # mostly unknown -> unknown


def test_union_keeps_occupied_over_free():
    a = OccupancyMap(np.array([[0.0, 0.0], [1.0, np.nan]], np.float32), 1.0)
    b = OccupancyMap(np.array([[1.0, np.nan], [0.0, 0.0]], np.float32), 1.0)
    m, rep = merge_maps(a, b, (0.0, 0.0, 0.0))
    r, c = rep.offset_cells
    np.testing.assert_array_equal(m.occupancy[r : r + 2, c : c + 2], [[1.0, 0.0], [1.0, 0.0]])
    assert rep.overlap_cells == 2


def test_rotated_filled_maps_merge_to_the_truth():
    f = random_field(3)
    t = true_map(f, 0.05, supersample=1)
    T = np.array([3.3, 1.7, 2.1])
    b = true_map(f, 0.05, frame=T, supersample=1)
    m, rep = merge_maps(t.replace(occupancy=np.full(t.shape, np.nan, np.float32)), b, T)
    r, c = rep.offset_cells
    got = m.occupied[r : r + t.shape[0], c : c + t.shape[1]]
    iou = (got & t.occupied).sum() / (got | t.occupied).sum()
    assert iou > 0.93


# ----------------------------------------------------------------------------- lidar


def _reference_ranges(segments, origin, angles, max_range):
    """Independent reference: trimesh's ray-triangle intersection against the segments extruded
    into vertical walls."""
    import trimesh

    v, faces = [], []
    for a, b in segments:
        k = len(v)
        v += [[a[0], a[1], -1.0], [b[0], b[1], -1.0], [b[0], b[1], 1.0], [a[0], a[1], 1.0]]
        faces += [[k, k + 1, k + 2], [k, k + 2, k + 3]]
    mesh = trimesh.Trimesh(np.array(v), np.array(faces), process=False)
    dirs = np.stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)], 1)
    orig = np.tile([origin[0], origin[1], 0.0], (len(angles), 1))
    out = np.full(len(angles), max_range)
    locs, ray, _ = trimesh.ray.ray_triangle.RayMeshIntersector(mesh).intersects_location(orig, dirs, multiple_hits=True)
    d = np.linalg.norm(locs - orig[ray], axis=1)
    np.minimum.at(out, ray, d)
    return out


@settings(max_examples=8, deadline=None)
@given(seed=st.integers(0, 10_000), x=st.floats(0.5, 9.5), y=st.floats(0.5, 6.5), psi=st.floats(-3.1, 3.1))
def test_ray_casting_matches_an_independent_reference(seed, x, y, psi):
    f = random_field(seed)
    assume(not f.occupied(np.array([[x, y]]))[0])  # a lidar outside every obstacle
    cfg = LidarConfig(beams=90, max_range=6.0)
    ang = psi + beam_angles(cfg)
    d = np.stack([np.cos(ang), np.sin(ang)], -1)
    got = np.asarray(cast_rays(jnp.asarray(f.segments), jnp.asarray([[x, y]]), jnp.asarray(d[None]), cfg.max_range))[0]
    ref = _reference_ranges(f.segments, (x, y), ang, cfg.max_range)
    np.testing.assert_allclose(got, ref, atol=2e-4)


def test_log_odds_update_matches_a_per_beam_loop():
    """integrate_scans against a plain loop over beams and samples (one update per cell per scan)."""
    cfg = LidarConfig(beams=16, max_range=2.0)
    spec = GridSpec(-1.0, -1.5, 40, 50, 0.05)
    poses = np.array([[0.1, 0.2, 0.3], [0.4, -0.3, -1.0]])
    rng = np.random.default_rng(2)
    ranges = rng.uniform(0.3, 2.5, (2, cfg.beams)).clip(max=cfg.max_range)
    lo, seen = integrate_scans(jnp.zeros((50, 40), jnp.float32), jnp.asarray(poses), jnp.asarray(ranges), spec, cfg)
    ref = np.zeros((50, 40))
    step = spec.resolution / 2
    ts = (np.arange(int(np.ceil(cfg.max_range / step))) + 0.5) * step
    for pose, r in zip(poses, ranges):
        free, hit = set(), set()
        for a, rb in zip(pose[2] + beam_angles(cfg), r):
            d = np.array([np.cos(a), np.sin(a)])
            for t in ts:
                if t < rb - spec.resolution / 2:
                    p = pose[:2] + t * d
                    free.add((int(np.floor((p[1] - spec.y0) / 0.05)), int(np.floor((p[0] - spec.x0) / 0.05))))
            if rb < cfg.max_range:
                p = pose[:2] + rb * d
                hit.add((int(np.floor((p[1] - spec.y0) / 0.05)), int(np.floor((p[0] - spec.x0) / 0.05))))
        for c in free | hit:
            if 0 <= c[0] < 50 and 0 <= c[1] < 40:
                ref[c] = np.clip(ref[c] + (cfg.l_occ if c in hit else cfg.l_free), cfg.l_min, cfg.l_max)
    np.testing.assert_allclose(np.asarray(lo), ref, atol=1e-5)
    assert np.array_equal(np.asarray(seen), ref != 0)


@settings(max_examples=10, deadline=None)
@given(x=st.floats(-5, 5), y=st.floats(-5, 5), psi=st.floats(-3.14, 3.14), seed=st.integers(0, 1000))
def test_every_placed_occupied_cell_comes_from_an_occupied_cell_of_b(x, y, psi, seed):
    """Nearest placement: the centre of every occupied merged cell, taken back into B's frame by
    T^-1, lies inside an occupied cell of B; and B's occupied area is kept (to within cell
    quantisation)."""
    from rhaml_jax import planar
    from rhaml_jax.mapping import transform_points

    rng = np.random.default_rng(seed)
    occ = np.zeros((30, 30), np.float32)
    occ[rng.integers(0, 30, 12), rng.integers(0, 30, 12)] = 1.0
    b = OccupancyMap(occ, 0.1, (-1.0, 0.5, 0.0))
    a = OccupancyMap(np.full((3, 3), np.nan, np.float32), 0.1)
    T = np.array([x, y, psi])
    m, _ = merge_maps(a, b, T)
    c = m.cell_centres()[m.occupied]  # (K, 2) in A's frame
    back = transform_points(planar.inverse(T), c)
    g = (back - np.array(b.origin[:2])) / b.resolution  # continuous cell coordinates in B
    i, j = np.floor(g[:, 1]).astype(int), np.floor(g[:, 0]).astype(int)
    assert np.all(occ[i, j] == 1.0)
    n_b = int(occ.sum())
    assert 0.5 * n_b <= len(c) <= 2.0 * n_b
