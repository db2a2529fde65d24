"""The package: its version, stubs, errors, and the scenes, cameras and images it reads and
writes."""

import pathlib
import re
import threading
import time

import numpy as np
import pytest

import splat4d
from conftest import REPO, camera, random_fields


def test_the_version_is_the_crates():
    manifest = (REPO / "Cargo.toml").read_text()
    version = re.search(r'\[workspace\.package\]\s*version = "([^"]+)"', manifest).group(1)
    assert splat4d.__version__ == version


def test_the_package_ships_its_stubs_and_marker():
    package = pathlib.Path(splat4d.__file__).parent
    assert (package / "py.typed").exists()
    assert (package / "_native.pyi").exists()
    stub = (package / "_native.pyi").read_text()
    for name in ("class Scene", "class Camera", "def render(", "def render_and_backward(",
                 "def fit(", "def load_dataset(", "def save_image(", "def reference_render("):
        assert name in stub, name


def test_an_invalid_field_is_an_input_error_naming_item_and_field():
    fields = random_fields(3)
    fields["scales"][2, 1] = -0.5
    with pytest.raises(splat4d.InputError) as caught:
        splat4d.Scene(**fields)
    error = caught.value
    assert (error.origin, error.item, error.field) == ("<scene>", "kernel 2", "scale")
    assert "scale[1] = -0.5 must be > 0" in str(error)
    assert isinstance(error, ValueError) and isinstance(error, splat4d.Splat4dError)


def test_a_wrong_shape_is_a_usage_error_naming_the_array():
    fields = random_fields(3)
    fields["amplitudes"] = fields["amplitudes"][:, :2]
    with pytest.raises(splat4d.UsageError, match=r"amplitudes: shape \(8, 2\), expected \(8, 3\)"):
        splat4d.Scene(**fields)


def test_a_missing_file_names_it(tmp_path):
    missing = tmp_path / "missing.json"
    with pytest.raises(splat4d.InputError) as caught:
        splat4d.load_scene(missing)
    assert caught.value.origin == str(missing)
    assert str(missing) in str(caught.value)


def test_alpha_fields_need_the_alpha_blend():
    fields = random_fields(4, blend="alpha", sh_count=3)
    fields["blend"] = "additive"
    with pytest.raises(splat4d.InputError, match="fields of the alpha blend"):
        splat4d.Scene(**fields)


def test_scenes_round_trip_through_dicts_and_files(tmp_path):
    for fields in (random_fields(5), random_fields(6, blend="alpha", sh_count=8)):
        scene = splat4d.Scene(**fields)
        again = splat4d.Scene(**scene.to_dict())
        for name, value in scene.to_dict().items():
            np.testing.assert_array_equal(getattr(again, name), value)
        for suffix in ("json", "ply"):
            path = tmp_path / f"scene.{suffix}"
            splat4d.save_scene(scene, path)
            loaded = splat4d.load_scene(path)
            assert loaded.blend == scene.blend and len(loaded) == len(scene)
            np.testing.assert_array_equal(loaded.means, scene.means)
            if scene.blend == "alpha":
                np.testing.assert_array_equal(loaded.sh, scene.sh)


def test_three_dimensional_kernels_are_static():
    scene = splat4d.Scene(means=np.zeros((2, 3)), scales=np.full((2, 3), 0.1), amplitudes=np.ones((2, 3)))
    assert np.all(scene.means[:, 3] == 0) and np.all(scene.scales[:, 3] == 1e30)


def test_cameras_from_gsplat_arguments_and_files(tmp_path):
    cam = camera()
    again = splat4d.Camera.from_viewmat(cam.world_to_camera, cam.K, cam.width, cam.height)
    np.testing.assert_array_equal(again.world_to_camera, cam.world_to_camera)
    path = tmp_path / "camera.json"
    splat4d.save_camera(cam, path)
    loaded = splat4d.load_camera(path)
    assert (loaded.fx, loaded.cx, loaded.width) == (cam.fx, cam.cx, cam.width)
    as_dict = dict(width=cam.width, height=cam.height, fx=cam.fx, fy=cam.fy, cx=cam.cx, cy=cam.cy,
                   world_to_camera=cam.world_to_camera)
    scene = splat4d.Scene(**random_fields(7))
    np.testing.assert_array_equal(splat4d.render(scene, as_dict, 0.3), splat4d.render(scene, cam, 0.3))
    with pytest.raises(splat4d.UsageError, match="skew"):
        k = cam.K
        k[0, 1] = 0.1
        splat4d.Camera.from_viewmat(cam.world_to_camera, k, 8, 8)


def test_images_round_trip(tmp_path):
    image = splat4d.render(splat4d.Scene(**random_fields(8)), camera(), 0.5)
    splat4d.save_image(image, tmp_path / "frame.exr")
    np.testing.assert_array_equal(splat4d.load_image(tmp_path / "frame.exr"), image)
    splat4d.save_image(image, tmp_path / "frame.png", bits=16)
    levels = np.round(65535 * np.clip(image.astype(np.float64), 0, 1)) / 65535
    np.testing.assert_allclose(splat4d.load_image(tmp_path / "frame.png"), levels, atol=1e-7)


def test_rendering_releases_the_gil():
    scene = splat4d.Scene(**random_fields(9, n=400))
    big = camera(1024, 768)
    done = threading.Event()
    ticks = 0

    def work():
        for _ in range(3):
            splat4d.render(scene, big, 0.5, threads=1)
        done.set()

    thread = threading.Thread(target=work)
    started = time.perf_counter()
    thread.start()
    while not done.is_set():
        ticks += 1
        time.sleep(0.001)
    thread.join()
    elapsed = time.perf_counter() - started
    # Held, the GIL would stop this loop for whole renders.
    assert ticks > 0.25 * elapsed / 0.001 * 0.2, (ticks, elapsed)
