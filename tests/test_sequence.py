"""sequence.load_scene refuses bad scenes with one line naming the file at fault."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from rhaml_jax.camera import DEFAULT_CAMERA
from rhaml_jax.data import BopFrame, write_tum
from rhaml_jax.errors import RhamlError
from rhaml_jax.sequence import load_scene


def _scene(tmp_path, n=3, size=(64, 48), K=None, odometry_lines=None):
    folder = tmp_path / "test" / "000000"
    (folder / "rgb").mkdir(parents=True)
    K = np.asarray(DEFAULT_CAMERA.resized(*size).K if K is None else K)
    frames = []
    for i in range(n):
        path = folder / "rgb" / f"{i:06d}.png"
        cv2.imwrite(str(path), np.zeros((size[1], size[0], 3), np.uint8))
        frames.append(BopFrame("test", 0, i, path, None, K, np.eye(4), None))
    m = n if odometry_lines is None else odometry_lines
    for name in ("observer_odometry.txt", "observed_odometry.txt"):
        write_tum(folder / name, np.zeros((m, 3)))
    return frames, folder


def test_a_good_scene_loads(tmp_path):
    frames, _ = _scene(tmp_path)
    data = load_scene(frames, length=5)
    assert data.seq.images.shape == (5, 48, 64, 3) and data.seq.valid.tolist() == [True] * 3 + [False] * 2


def test_odometry_shorter_than_the_images(tmp_path):
    frames, folder = _scene(tmp_path, odometry_lines=2)
    with pytest.raises(RhamlError, match="observer_odometry.txt: 2 lines.*odometry shorter than the image list"):
        load_scene(frames)


def test_missing_odometry(tmp_path):
    frames, folder = _scene(tmp_path)
    (folder / "observed_odometry.txt").unlink()
    with pytest.raises(RhamlError, match="observed_odometry.txt: not found"):
        load_scene(frames)
    load_scene(frames, need_odometry=False)  # without the pgo module the odometry is not read


def test_intrinsics_of_another_image_size(tmp_path):
    frames, _ = _scene(tmp_path, K=DEFAULT_CAMERA.K)  # 640 x 480 intrinsics on 64 x 48 images
    with pytest.raises(RhamlError, match="a 64x48 image, but its cam_K"):
        load_scene(frames)
