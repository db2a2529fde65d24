"""The numpy interface against splat4d's float64 twin: frames (SPEC §5, §8) and gradients
(SPEC §6; the alpha blend's against central differences of the twin's frame)."""

import numpy as np
import pytest

import splat4d
import splat4d.reference
from conftest import REPO, close, random_fields

#: The frame's error against the f64 twin: the per-pixel loop is f32 (SPEC §5, precision).
FRAME_ATOL = 2e-6


@pytest.mark.parametrize("blend,sh_count", [("additive", 0), ("alpha", 0), ("alpha", 3), ("alpha", 8), ("alpha", 15)])
@pytest.mark.parametrize("t", [0.0, 0.4])
def test_frames_match_the_f64_twin(blend, sh_count, t, cam):
    scene = splat4d.Scene(**random_fields(10 + sh_count, blend=blend, sh_count=sh_count))
    image = splat4d.render(scene, cam, t)
    assert image.shape == (cam.height, cam.width, 3) and image.dtype == np.float32
    reference, uncertain = splat4d.reference.render(scene, cam, t, uncertain=True)
    assert uncertain.mean() < 0.05
    error = np.abs(image - reference)[~uncertain]
    assert error.max() <= FRAME_ATOL, error.max()
    assert np.abs(reference).max() > 0.1


def test_the_shipped_scene_renders():
    scene = splat4d.load_scene(REPO / "data/blob.json")
    blob_camera = splat4d.load_camera(REPO / "data/blob_camera.json")
    image = splat4d.render(scene, blob_camera, 0.5)
    reference = splat4d.reference.render(scene, blob_camera, 0.5)
    assert np.abs(image - reference).max() <= FRAME_ATOL


def test_additive_gradients_match_the_f64_twin(additive_scene, cam):
    target = np.random.default_rng(0).uniform(0, 0.5, size=(cam.height, cam.width, 3)).astype(np.float32)
    image = splat4d.render(additive_scene, cam, 0.3)
    dL_dimage = 2 * (image.astype(np.float64) - target) / image.size
    grads = splat4d.render_and_backward(additive_scene, cam, 0.3, dL_dimage)
    _, expected = splat4d.reference.loss_and_gradients(additive_scene, cam, 0.3, target)
    assert sorted(grads) == sorted(expected)
    for name in grads:
        close(grads[name], expected[name], 1e-4, name)


def fields_with(fields, name, index, delta):
    moved = {k: (np.array(v, dtype=np.float64) if not isinstance(v, str) else v) for k, v in fields.items()}
    moved[name][index] += delta
    return moved


@pytest.mark.parametrize("blend,sh_count", [("additive", 0), ("alpha", 3)])
def test_every_gradient_matches_central_differences_of_the_twin(blend, sh_count, cam):
    fields = random_fields(20, n=4, blend=blend, sh_count=sh_count)
    t, cutoff = 0.35, 0.0   # no cut-off: every pair stays a pair while differencing
    weights = np.random.default_rng(1).normal(size=(cam.height, cam.width, 3))

    def loss(f):
        return float((splat4d.reference.render(f, cam, t, cutoff=cutoff) * weights).sum())

    grads = splat4d.render_and_backward(fields, cam, t, weights, cutoff=cutoff)
    names = ["means", "scales", "amplitudes", "rotations", "velocities", "background"]
    if blend == "alpha":
        names += ["opacities", "sh"]
    h = 1e-6
    for name in names:
        expected = np.zeros_like(np.asarray(fields[name], dtype=np.float64))
        for index in np.ndindex(expected.shape):
            expected[index] = (loss(fields_with(fields, name, index, h))
                               - loss(fields_with(fields, name, index, -h))) / (2 * h)
        close(grads[name], expected, 2e-4, name)


def test_opacity_gradients_through_alphas(cam):
    fields = random_fields(21, n=4, blend="alpha", sh_count=0)
    weights = np.random.default_rng(2).normal(size=(cam.height, cam.width))
    ones = dict(fields, amplitudes=np.ones_like(fields["amplitudes"]), background=np.zeros(3))
    # 1 - T is the frame of colour 1 on black: its gradient is that frame's.
    with_alphas = splat4d.render_and_backward(fields, cam, 0.5, np.zeros((cam.height, cam.width, 3)), dL_dalphas=weights, cutoff=0)
    as_colour = splat4d.render_and_backward(ones, cam, 0.5, np.stack([weights, 0 * weights, 0 * weights], -1), cutoff=0)
    for name in ("means", "scales", "rotations", "velocities", "opacities"):
        close(with_alphas[name], as_colour[name], 1e-12, name)


def test_a_blend_can_be_asked_for(cam):
    fields = random_fields(22)
    as_alpha = splat4d.render(fields, cam, 0.5, blend="alpha")
    explicit = splat4d.render(dict(fields, blend="alpha", opacities=np.ones(8)), cam, 0.5)
    np.testing.assert_array_equal(as_alpha, explicit)
    with pytest.raises(splat4d.UsageError, match="blend"):
        splat4d.render(fields, cam, 0.5, blend="over")


def test_the_thread_count_changes_nothing(alpha_scene, cam):
    one = splat4d.render(alpha_scene, cam, 0.2, threads=1)
    np.testing.assert_array_equal(one, splat4d.render(alpha_scene, cam, 0.2, threads=2))
