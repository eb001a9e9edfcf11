"""Robot models: built-in, URDF and mesh loaders, normalisation, simplification, the info CLI."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from rhaml_jax.errors import RhamlError
from rhaml_jax.robots import load_robot
from rhaml_jax.robots import silhouette_iou
from tests.conftest import shared_path


def test_builtin_pioneer_matches_published_size():
    m = load_robot("pioneer3dx")
    np.testing.assert_allclose(m.extents, [0.455, 0.381, 0.237], atol=0.01)
    assert m.bounds[0, 2] == 0.0
    assert len(set(map(tuple, m.face_colors))) >= 4, "per-part colours"
    assert m.vertices.dtype == np.float32 and m.faces.dtype == np.int32
    # Drive wheels on the axle at x = 0, touching the ground.
    wheel = m.vertices[np.unique(m.faces[m.face_parts == m.part_names.index("left_wheel")])]
    np.testing.assert_allclose([wheel[:, 0].mean(), wheel[:, 2].min(), wheel[:, 2].max()], [0.0, 0.0, 0.195], atol=2e-3)


def test_pioneer_urdf_extents_and_normals():
    m = load_robot(str(shared_path("robots/pioneer3dx/urdf/pioneer3dx.urdf")))
    np.testing.assert_allclose(m.extents, [0.45, 0.38, 0.24], atol=0.02)
    assert m.bounds[0, 2] == 0.0
    n = m.face_normals  # the STLs store zero normals: ours are recomputed from the winding
    lengths = np.linalg.norm(n, axis=1)
    assert np.mean(np.abs(lengths - 1) < 1e-4) > 0.99
    red = np.array([0.851, 0.0, 0.0], np.float32)
    assert np.any(np.all(np.isclose(m.face_colors, red, atol=1e-3), axis=1)), "URDF material colours"


def test_turtlebot_urdf_in_millimetres_with_namespace_arg():
    m = load_robot(str(shared_path("robots/turtlebot3_burger/urdf/turtlebot3_burger.main.urdf")))
    np.testing.assert_allclose(m.extents, [0.138, 0.178, 0.191], atol=0.01)
    assert m.bounds[0, 2] == 0.0 and len(m.faces) == 91104


def test_dae_mesh_loads_and_mm_warning():
    m = load_robot(str(shared_path("robots/pioneer2dx_gazebo/meshes/chassis.dae")))
    assert len(m.faces) > 0 and m.extents.max() < 1.0
    with pytest.warns(UserWarning, match="millimetres"):
        load_robot(str(shared_path("robots/turtlebot3_burger/gazebo_lowpoly/meshes/lds.dae")))


def test_xacro_gets_a_clear_error():
    with pytest.raises(RhamlError, match="xacro"):
        load_robot(str(shared_path("robots/pioneer3dx/urdf/pioneer3dx.urdf.xacro")))


def _write(path, text):
    path.write_text(text)
    return str(path)


def test_bad_inputs(tmp_path):
    with pytest.raises(RhamlError, match="missing.urdf: URDF file not found"):
        load_robot(str(tmp_path / "missing.urdf"))
    with pytest.raises(RhamlError, match="neither a built-in robot"):
        load_robot("pioneer9")
    with pytest.raises(RhamlError, match="not found"):
        load_robot(str(tmp_path / "missing.stl"))
    with pytest.raises(RhamlError, match="unknown robot file extension"):
        load_robot(_write(tmp_path / "robot.step", "x"))
    urdf = '<robot name="r"><link name="a"><visual><geometry><mesh filename="meshes/gone.stl"/></geometry></visual></link></robot>'
    with pytest.raises(RhamlError, match="gone.stl"):
        load_robot(_write(tmp_path / "r.urdf", urdf))
    with pytest.raises(RhamlError, match="empty"):
        load_robot(_write(tmp_path / "empty.obj", "# nothing\n"))
    with pytest.raises(RhamlError, match="non-finite"):
        load_robot(_write(tmp_path / "nan.obj", "v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n"))
    with pytest.raises(RhamlError, match="XML"):
        load_robot(_write(tmp_path / "broken.urdf", "<robot><link"))


def test_urdf_primitives_origins_and_package_paths(tmp_path):
    pkg = tmp_path / "my_robot"
    (pkg / "urdf").mkdir(parents=True)
    (pkg / "meshes").mkdir()
    import trimesh

    trimesh.creation.box(extents=(0.2, 0.2, 0.2)).export(pkg / "meshes" / "cube.stl")
    urdf = """<robot name="r">
      <material name="blue"><color rgba="0 0 1 1"/></material>
      <link name="base"><visual><origin xyz="0 0 0.1"/><geometry><box size="0.4 0.2 0.2"/></geometry>
        <material name="blue"/></visual></link>
      <link name="top"><visual><geometry><mesh filename="package://my_robot/meshes/cube.stl" scale="0.5 0.5 0.5"/></geometry></visual></link>
      <link name="wheel"><visual><origin rpy="1.5707963 0 0"/><geometry><cylinder radius="0.1" length="0.05"/></geometry></visual></link>
      <joint name="j1" type="fixed"><parent link="base"/><child link="top"/><origin xyz="0.1 0 0.3"/></joint>
      <joint name="j2" type="continuous"><parent link="base"/><child link="wheel"/><origin xyz="0 0.2 0.1"/></joint>
    </robot>"""
    m = load_robot(_write(pkg / "urdf" / "r.urdf", urdf))
    # base box z in [0, 0.2]; top cube 0.1 wide centred at z 0.3 -> up to 0.35; wheel (axis along y) x in [-0.1, 0.1]
    np.testing.assert_allclose(m.bounds, [[-0.2, -0.1, 0.0], [0.2, 0.225, 0.35]], atol=1e-6)
    blue = m.face_colors[m.face_parts == m.part_names.index("base")]
    np.testing.assert_allclose(blue, np.tile([0, 0, 1], (len(blue), 1)))


def test_sample_surface_is_uniform_by_area():
    m = load_robot("pioneer3dx")
    pts = m.sample_surface(20000, seed=3)
    assert pts.shape == (20000, 3) and pts.dtype == np.float32
    np.testing.assert_array_equal(pts, m.sample_surface(20000, seed=3))
    # Uniform by area <=> the sample mean converges to the area-weighted centroid of the surface
    # (standard error here about 0.7 mm), and the points lie on the faces' planes.
    centroid = (m.face_areas[:, None] * m.vertices[m.faces].mean(axis=1)).sum(0) / m.face_areas.sum()
    np.testing.assert_allclose(pts.mean(0), centroid, atol=3e-3)
    vertex_mean = m.vertices.mean(0)
    assert np.abs(vertex_mean - centroid).max() > 3e-3 * 2, "the test must tell area- from vertex-weighting"


def test_mirror_asymmetry_tells_symmetric_robots_from_others():
    import dataclasses

    m = load_robot("pioneer3dx")
    shape, colour = m.mirror_asymmetry()
    assert abs(shape) < 2e-3 and abs(colour) < 0.02  # symmetric: only sampling noise
    # Origin 3 cm off the symmetry plane: the mirror image is ~6 cm off somewhere.
    off = dataclasses.replace(m, vertices=m.vertices + np.float32([0.0, 0.03, 0.0]))
    assert off.mirror_asymmetry()[0] > 0.04
    # The same shape with its left half painted red.
    left = m.vertices[m.faces].mean(1)[:, 1] > 0
    red = dataclasses.replace(m, face_colors=np.where(left[:, None], np.float32([1, 0, 0]), m.face_colors))
    shape, colour = red.mirror_asymmetry()
    assert abs(shape) < 2e-3 and colour > 0.3


def test_pioneer_urdf_is_mirror_symmetric():
    urdf = load_robot(str(shared_path("robots/pioneer3dx/urdf/pioneer3dx.urdf")))
    shape, colour = urdf.mirror_asymmetry()
    assert abs(shape) < 2e-3 and abs(colour) < 0.02


def test_simplify_respects_budget_and_keeps_silhouette():
    m = load_robot(str(shared_path("robots/pioneer3dx/urdf/pioneer3dx.urdf")))
    s = load_robot(str(shared_path("robots/pioneer3dx/urdf/pioneer3dx.urdf")), max_faces=2000)
    assert len(s.faces) <= 2000 and s.bounds[0, 2] == 0.0
    assert np.all(s.bounds[0] >= m.bounds[0] - 1e-6) and np.all(s.bounds[1] <= m.bounds[1] + 1e-6)
    iou = silhouette_iou(m, s, n_views=10)
    assert iou.mean() > 0.95 and iou.min() > 0.9, iou


def _info(*args):
    return subprocess.run([sys.executable, "-m", "rhaml_jax.info", *args], capture_output=True, text=True, timeout=300)


def test_info_cli_and_errors(tmp_path):
    r = _info("--robot", str(shared_path("robots/pioneer3dx/urdf/pioneer3dx.urdf")))
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)
    assert {"name", "vertices", "faces", "extents_m", "min_z"} <= set(d) and d["min_z"] == 0.0
    missing_mesh = '<robot name="r"><link name="a"><visual><geometry><mesh filename="gone.stl"/></geometry></visual></link></robot>'
    cases = {
        str(tmp_path / "none.stl"): "none.stl",  # missing file
        _write(tmp_path / "x.foo", ""): "unknown robot file extension",
        _write(tmp_path / "r.urdf", missing_mesh): "gone.stl",
        _write(tmp_path / "empty.obj", "# nothing\n"): "empty",
        _write(tmp_path / "nan.obj", "v 0 0 0\nv 1 0 inf\nv 0 1 0\nf 1 2 3\n"): "non-finite",
    }
    for bad, culprit in cases.items():
        r = _info("--robot", bad)
        assert r.returncode == 2 and "Traceback" not in r.stderr, (bad, r.stderr)
        assert len(r.stderr.strip().splitlines()) == 1 and r.stderr.startswith("error: ") and culprit in r.stderr, r.stderr


def test_fingerprint_ignores_paint_and_ply_round_trips_but_not_size(tmp_path):
    """The same geometry repainted, or written to a BOP ply (mm) and read back, is the same robot;
    the robot scaled by 10 % or a TurtleBot-sized box is not; a pre-fingerprint record (name and
    extents only) is compared on its extents."""
    import dataclasses

    from rhaml_jax.camera import DEFAULT_CAMERA
    from rhaml_jax.data import load_bop_model, write_dataset_header
    from rhaml_jax.robots import RobotFingerprint, check_same_robot, fingerprint

    m = load_robot("pioneer3dx")
    fp = fingerprint(m)
    blue = dataclasses.replace(m, face_colors=np.tile(np.float32([0.1, 0.2, 0.9]), (len(m.faces), 1)))
    assert fingerprint(blue) == fp
    write_dataset_header(tmp_path, m, DEFAULT_CAMERA)
    back = fingerprint(load_bop_model(tmp_path))
    assert back.same_robot(fp) and back.geometry_hash == fp.geometry_hash and back.name == "obj_000001"
    big = dataclasses.replace(m, vertices=m.vertices * 1.1)
    assert not fingerprint(big).same_robot(fp)
    assert RobotFingerprint.from_dict(fp.to_dict()) == fp
    legacy = {"name": "pioneer3dx", "extents_m": list(fp.extents_m)}
    check_same_robot(legacy, m, "refiner", "the data set")
    with pytest.raises(RhamlError, match=r"refiner was made for robot 'pioneer3dx' \(45.5 x 38.1 x 23.7 cm\), but the "
                                         r"data set is robot 'pioneer3dx' \(50.\d x 41.9"):
        check_same_robot(legacy, big, "refiner", "the data set")
    with pytest.raises(RhamlError, match="not a robot fingerprint"):
        RobotFingerprint.from_dict({"name": "x", "extents_m": [1, 2]})


def test_fingerprint_tells_the_turtlebot_from_the_pioneer():
    urdf = shared_path("robots", "turtlebot3_burger", "urdf", "turtlebot3_burger.main.urdf")
    from rhaml_jax.robots import fingerprint

    tb, pi = fingerprint(load_robot(str(urdf))), fingerprint(load_robot("pioneer3dx"))
    assert not tb.same_robot(pi) and tb.geometry_hash != pi.geometry_hash
    np.testing.assert_allclose(tb.extents_m, (0.138, 0.178, 0.191), atol=2e-3)
