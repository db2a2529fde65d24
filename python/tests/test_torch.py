"""`splat4d.torch.rasterization` against an independent float64 twin of SPEC written in
torch (spec_twin.py): frames, opacities and the gradients of every input, for both blends,
RGB and SH colours, batches of cameras, and kernels in time; torch's gradcheck; a training
loop."""

import math

import numpy as np
import pytest

torch = pytest.importorskip("torch")

import splat4d  # noqa: E402
import splat4d.reference  # noqa: E402
from splat4d.torch import SH_C0, rasterization  # noqa: E402
import spec_twin  # noqa: E402
from conftest import camera, close, random_fields  # noqa: E402

W, H = 24, 18


def cameras(count=2):
    cams = [camera(W, H, eye=(0.4 * k - 0.2, -0.2, -4.0)) for k in range(count)]
    viewmats = torch.tensor(np.stack([c.world_to_camera for c in cams]))
    Ks = torch.tensor(np.stack([c.K for c in cams]))
    return viewmats, Ks


def gaussians(seed, n=6, sh_degree=None, four_d=False):
    """gsplat's inputs (after activation), f64, requiring gradients."""
    f = random_fields(seed, n=n, blend="alpha", sh_count=0)
    rng = np.random.default_rng(seed)
    inputs = {
        "means": f["means"] if four_d else f["means"][:, :3],
        "quats": f["rotations"],
        "scales": f["scales"] if four_d else f["scales"][:, :3],
        "opacities": f["opacities"],
        "colors": (rng.normal(scale=0.6, size=(n, (sh_degree + 1) ** 2, 3)) if sh_degree is not None
                   else f["amplitudes"]),
    }
    if four_d:
        inputs["velocities"] = f["velocities"]
    return {k: torch.tensor(v, dtype=torch.float64, requires_grad=True) for k, v in inputs.items()}


def twin_frames(g, viewmats, Ks, t, *, sh_degree=None, backgrounds=None, blend="alpha", cutoff=1 / 255):
    """The twin's [C, H, W, 3] and [C, H, W, 1], in gsplat's parameters."""
    n = g["means"].shape[0]
    means = g["means"] if g["means"].shape[1] == 4 else torch.cat([g["means"], torch.zeros(n, 1, dtype=torch.float64)], 1)
    scales = g["scales"] if g["scales"].shape[1] == 4 else torch.cat([g["scales"], torch.full((n, 1), 1e30, dtype=torch.float64)], 1)
    velocities = g.get("velocities", torch.zeros(n, 3, dtype=torch.float64))
    if sh_degree is None:
        amplitudes, sh = g["colors"], None
    else:
        amplitudes = SH_C0 * g["colors"][:, 0] + 0.5
        sh = g["colors"][:, 1:(sh_degree + 1) ** 2]
    colours, alphas = [], []
    for c in range(viewmats.shape[0]):
        bg = torch.zeros(3, dtype=torch.float64) if backgrounds is None else backgrounds[c]
        image, alpha = spec_twin.render(
            means, scales, g["quats"], amplitudes, velocities, bg, viewmats[c], Ks[c], W, H, t,
            blend=blend, opacities=g["opacities"], sh=sh, far=1e10, cutoff=cutoff,
        )
        colours.append(image)
        alphas.append(torch.zeros(H, W, dtype=torch.float64) if alpha is None else alpha)
    return torch.stack(colours), torch.stack(alphas)[..., None]


def loss_of(colours, alphas, seed=3):
    rng = np.random.default_rng(seed)
    wc = torch.tensor(rng.normal(size=tuple(colours.shape)))
    wa = torch.tensor(rng.normal(size=tuple(alphas.shape)))
    return (colours * wc).sum() + (alphas * wa).sum()


def gradients(g, loss):
    for v in g.values():
        v.grad = None
    loss.backward()
    return {k: v.grad.clone() for k, v in g.items()}


@pytest.mark.parametrize("sh_degree", [None, 0, 1, 2, 3])
def test_frames_and_every_gradient_match_the_twin(sh_degree):
    viewmats, Ks = cameras()
    g = gaussians(40 + (sh_degree or 0), sh_degree=sh_degree)
    backgrounds = torch.tensor([[0.1, 0.2, 0.3], [0.0, 0.05, 0.1]], dtype=torch.float64, requires_grad=True)
    colours, alphas, meta = rasterization(
        g["means"], g["quats"], g["scales"], g["opacities"], g["colors"], viewmats, Ks, W, H,
        sh_degree=sh_degree, backgrounds=backgrounds, cutoff=0.0,
    )
    assert colours.shape == (2, H, W, 3) and alphas.shape == (2, H, W, 1) and meta["width"] == W
    twin = twin_frames(g | {}, viewmats, Ks, 0.0, sh_degree=sh_degree, backgrounds=backgrounds, cutoff=0.0)
    close(colours.detach(), twin[0].detach(), 2e-6, "colours")
    close(alphas.detach(), twin[1].detach(), 2e-6, "alphas")
    ours = gradients(g | {"backgrounds": backgrounds}, loss_of(colours, alphas))
    expected = gradients(g | {"backgrounds": backgrounds}, loss_of(*twin))
    for name in ours:
        close(ours[name], expected[name], 2e-4, name)


@pytest.mark.parametrize("blend", ["alpha", "additive"])
def test_kernels_in_time_match_the_twin(blend):
    viewmats, Ks = cameras(1)
    g = gaussians(50, four_d=True)
    if blend == "additive":
        g.pop("opacities")
    opacities = g.get("opacities")
    colours, alphas, _ = rasterization(
        g["means"], g["quats"], g["scales"], opacities, g["colors"], viewmats, Ks, W, H,
        velocities=g["velocities"], t=0.7, blend=blend,
    )
    twin = twin_frames(dict(g, opacities=opacities), viewmats, Ks, 0.7, blend=blend)
    close(colours.detach(), twin[0].detach(), 2e-6, "colours")
    ours = gradients(g, loss_of(colours, alphas))
    expected = gradients(g, loss_of(*twin))
    for name in ours:
        close(ours[name], expected[name], 2e-4, name)


def test_times_and_time_scales_beside_3d_kernels():
    viewmats, Ks = cameras(1)
    g = gaussians(60)
    n = g["means"].shape[0]
    times = torch.linspace(0, 1, n, dtype=torch.float64, requires_grad=True)
    time_scales = torch.full((n,), 0.5, dtype=torch.float64, requires_grad=True)
    colours, _, _ = rasterization(
        g["means"], g["quats"], g["scales"], g["opacities"], g["colors"], viewmats, Ks, W, H,
        times=times, time_scales=time_scales, t=0.4,
    )
    as_4d = dict(g, means=torch.cat([g["means"], times[:, None]], 1),
                 scales=torch.cat([g["scales"], time_scales[:, None]], 1))
    twin, _ = twin_frames(as_4d, viewmats, Ks, 0.4)
    close(colours.detach(), twin.detach(), 2e-6, "colours")
    (colours * colours).sum().backward()
    assert times.grad.abs().max() > 0 and time_scales.grad.abs().max() > 0


def test_the_frame_is_the_numpy_interfaces_and_near_the_f64_twin():
    viewmats, Ks = cameras(1)
    g = gaussians(70, sh_degree=1)
    colours, _, _ = rasterization(g["means"], g["quats"], g["scales"], g["opacities"], g["colors"],
                                  viewmats, Ks, W, H, sh_degree=1)
    d = {k: v.detach().numpy() for k, v in g.items()}
    scene = splat4d.Scene(means=d["means"], scales=d["scales"], rotations=d["quats"],
                          amplitudes=SH_C0 * d["colors"][:, 0] + 0.5, sh=d["colors"][:, 1:],
                          opacities=d["opacities"])
    cam = splat4d.Camera.from_viewmat(viewmats[0].numpy(), Ks[0].numpy(), W, H, far=1e10)
    np.testing.assert_array_equal(colours[0].detach().numpy().astype(np.float32), splat4d.render(scene, cam, 0.0))
    reference, uncertain = splat4d.reference.render(scene, cam, 0.0, uncertain=True)
    assert np.abs(colours[0].detach().numpy() - reference)[~uncertain].max() <= 2e-6


def test_gradcheck_on_a_small_case():
    viewmats, Ks = cameras(1)
    g = gaussians(80, n=2, sh_degree=1)
    names = ["means", "quats", "scales", "opacities", "colors"]

    def frame(*inputs):
        kw = dict(zip(names, inputs))
        colours, alphas, _ = rasterization(kw["means"], kw["quats"], kw["scales"], kw["opacities"],
                                           kw["colors"], viewmats, Ks, 12, 9, sh_degree=1, cutoff=0.0)
        return colours, alphas

    # The per-pixel loop is float32 (SPEC §5): differences of 1e-3 and a float32 tolerance.
    assert torch.autograd.gradcheck(frame, tuple(g[k] for k in names), eps=1e-3, atol=2e-4, rtol=2e-2)


def test_the_operator_is_registered_as_torch_asks():
    viewmats, Ks = cameras(1)
    g = gaussians(90, n=3)
    n = 3
    args = (
        torch.cat([g["means"], torch.zeros(n, 1, dtype=torch.float64)], 1).detach().requires_grad_(),
        torch.cat([g["scales"], torch.ones(n, 1, dtype=torch.float64)], 1).detach().requires_grad_(),
        g["quats"].detach().requires_grad_(), g["opacities"].detach().requires_grad_(),
        g["colors"].detach().requires_grad_(), torch.zeros(n, 0, 3, dtype=torch.float64),
        torch.zeros(n, 3, dtype=torch.float64), viewmats, Ks, torch.zeros(1, 3, dtype=torch.float64),
        torch.zeros(1, dtype=torch.float64), 8, 6, 0.01, 1e10, 0.3, 1 / 255, True, 0,
    )
    torch.library.opcheck(torch.ops.splat4d.rasterize.default, args,
                          test_utils=("test_schema", "test_autograd_registration", "test_faketensor"))


def test_unsupported_gsplat_options_are_refused():
    viewmats, Ks = cameras(1)
    g = gaussians(91, n=2)
    with pytest.raises(splat4d.UsageError, match="render_mode"):
        rasterization(g["means"], g["quats"], g["scales"], g["opacities"], g["colors"], viewmats, Ks, W, H,
                      render_mode="RGB+D")


def test_a_training_loop_lowers_its_loss():
    viewmats, Ks = cameras(2)
    truth = gaussians(100, n=5, sh_degree=1)
    with torch.no_grad():
        target, _, _ = rasterization(truth["means"], truth["quats"], truth["scales"], truth["opacities"],
                                     truth["colors"], viewmats, Ks, W, H, sh_degree=1)
    torch.manual_seed(0)
    params = {
        "means": (truth["means"].detach() + 0.1 * torch.randn(5, 3, dtype=torch.float64)).float().requires_grad_(),
        "quats": truth["quats"].detach().float().requires_grad_(),
        "log_scales": torch.log(truth["scales"].detach()).float().requires_grad_(),
        "logit_opacities": torch.zeros(5).requires_grad_(),
        "colors": torch.zeros(5, 4, 3).requires_grad_(),
    }
    optimiser = torch.optim.Adam(params.values(), lr=0.02)
    losses = []
    for _ in range(50):
        colours, _, _ = rasterization(params["means"], params["quats"], torch.exp(params["log_scales"]),
                                      torch.sigmoid(params["logit_opacities"]), params["colors"],
                                      viewmats.float(), Ks.float(), W, H, sh_degree=1)
        loss = torch.nn.functional.mse_loss(colours, target.float())
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        losses.append(loss.item())
    assert losses[-1] < 0.3 * losses[0], losses[::10]
