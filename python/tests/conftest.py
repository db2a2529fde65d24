"""Shared scenes and cameras of the Python tests: small seeded scenes in front of a small
camera, so that the float64 twins (every kernel at every pixel) stay quick."""

import json
import pathlib
import sys

import numpy as np
import pytest

import splat4d

sys.path.insert(0, str(pathlib.Path(__file__).parent))

REPO = pathlib.Path(__file__).resolve().parents[2]

WIDTH, HEIGHT = 32, 24


def random_rotations(rng, n):
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True) * rng.uniform(0.5, 2.0, size=(n, 1))


def random_fields(seed, n=8, blend="additive", sh_count=0):
    """Keyword arguments of splat4d.Scene: kernels in front of `camera()`, in time, turned,
    moving; alpha scenes with opacities ≤ 0.6 (no pixel nears T_stop, none is clamped)."""
    rng = np.random.default_rng(seed)
    fields = dict(
        means=np.column_stack([rng.uniform(-0.6, 0.6, size=(n, 3)), rng.uniform(0, 1, size=n)]),
        scales=np.column_stack([rng.uniform(0.08, 0.25, size=(n, 3)), rng.uniform(0.4, 1.0, size=n)]),
        amplitudes=rng.uniform(0.1, 1.0, size=(n, 3)),
        rotations=random_rotations(rng, n),
        velocities=rng.uniform(-0.3, 0.3, size=(n, 3)),
        background=rng.uniform(0, 0.2, size=3),
    )
    if blend == "alpha":
        fields.update(
            blend="alpha",
            opacities=rng.uniform(0.2, 0.6, size=n),
            sh=rng.normal(scale=0.2, size=(n, sh_count, 3)),
        )
    return fields


def camera(width=WIDTH, height=HEIGHT, eye=(0.3, -0.2, -4.0)):
    return splat4d.Camera.look_at(list(eye), [0, 0, 0], [0, 1, 0], 40.0, width, height)


def opengl_camera_to_world(cam):
    """The D-NeRF `transform_matrix` of a camera (OpenGL axes: y up, z backward)."""
    c2w = np.linalg.inv(cam.world_to_camera)
    return (c2w @ np.diag([1.0, -1.0, -1.0, 1.0])).tolist()


def write_dataset(folder, scene, times=(0.0, 0.5, 1.0), views=6, size=(24, 18)):
    """A D-NeRF folder of `scene` rendered from `views` cameras around it at `times`: the
    train split, and every third view at the middle time as val and test."""
    folder = pathlib.Path(folder)
    splits = {"train": [], "val": [], "test": []}
    for k in range(views):
        angle = 2 * np.pi * k / views
        eye = [3.5 * np.sin(angle), 0.4, -3.5 * np.cos(angle)]
        cam = splat4d.Camera.look_at(eye, [0, 0, 0], [0, 1, 0], 45.0, *size)
        for t in times:
            split = "train" if k % 3 or t != times[len(times) // 2] else ("val" if k % 2 else "test")
            name = f"{split}/r_{len(splits[split]):03d}"
            splat4d.save_image(splat4d.render(scene, cam, t), folder / f"{name}.exr")
            splits[split].append({"file_path": f"./{name}", "time": t,
                                  "transform_matrix": opengl_camera_to_world(cam),
                                  "fl_x": cam.fx, "fl_y": cam.fy, "cx": cam.cx, "cy": cam.cy,
                                  "w": size[0], "h": size[1]})
    for split, frames in splits.items():
        (folder / f"transforms_{split}.json").write_text(json.dumps({"frames": frames}))
    return folder


@pytest.fixture
def additive_scene():
    return splat4d.Scene(**random_fields(1))


@pytest.fixture
def alpha_scene():
    return splat4d.Scene(**random_fields(2, blend="alpha", sh_count=3))


@pytest.fixture
def cam():
    return camera()


def close(actual, expected, rtol, what=""):
    """`|actual - expected| ≤ rtol · max|expected|` (the field's scale), naming the worst."""
    actual, expected = np.asarray(actual, dtype=np.float64), np.asarray(expected, dtype=np.float64)
    scale = max(np.abs(expected).max(), 1e-12)
    error = np.abs(actual - expected)
    worst = np.unravel_index(np.argmax(error), error.shape) if error.size else ()
    assert error.max(initial=0) <= rtol * scale, (
        f"{what}: |Δ| {error.max():.3e} at {worst} (actual {actual[worst]:.6e}, expected "
        f"{expected[worst]:.6e}) > {rtol:g} · {scale:.3e}"
    )
