"""gsplat's ``rasterization()`` on any CPU, with time: a differentiable torch operator.

:func:`rasterization` takes gsplat's arguments, with its names, shapes and activations
(``scales`` after ``exp``, ``opacities`` after ``sigmoid``, quaternions ``wxyz`` of any
length, ``colors`` as RGB or SH coefficients with ``sh_degree``), and returns what gsplat
returns: ``(render_colors [C, H, W, 3], render_alphas [C, H, W, 1], meta)``. Its kernels
may live in time (SPEC §1): ``means`` [N, 4] with t, ``scales`` [N, 4] with σt, or
``times``, ``time_scales`` and ``velocities`` beside 3D ones; ``t`` is the time rendered.
Kernels without time are static (σt = 1e30, SPEC §8).

The frame is splat4d's (SPEC §2–5 and §8), its gradient the exact one of SPEC §6 and §8,
through ``torch.library.custom_op`` with ``register_autograd``: ``splat4d::rasterize``.
Where gsplat's model differs: an opacity is clamped at 0.99 (graphdeco's rasterizer; gsplat
0.999), a pixel takes every kernel whose α ≥ 1/255 (gsplat stops at a 3σ radius too), a
colour is clamped at 0 (SH and RGB alike), and there is no gradient for the cameras
(``viewmats``, ``Ks``). torch is imported with this module only.
"""

import math
from typing import Any, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np
import torch
from torch import Tensor

from . import _native
from ._errors import UsageError

__all__ = ["rasterization"]

#: Real SH of degree 0 (graphdeco's ``C0``): amplitude = C0 · f_dc + 0.5 (SPEC §8).
SH_C0 = 0.28209479177387814
#: σt of a static kernel (SPEC §8: w = 1 to f64 precision at any time).
STATIC_TIME_SCALE = 1e30


def _array(x: Tensor) -> np.ndarray:
    """``x`` as a C-contiguous float64 array (no copy when it is one already)."""
    return np.ascontiguousarray(x.detach().to(device="cpu", dtype=torch.float64).numpy())


def _scene(
    means: Tensor,
    scales: Tensor,
    quats: Tensor,
    opacities: Tensor,
    amplitudes: Tensor,
    sh: Tensor,
    velocities: Tensor,
    background: Tensor,
    alpha: bool,
) -> "_native.Scene":
    fields: Dict[str, Any] = dict(
        means=_array(means),
        scales=_array(scales),
        amplitudes=_array(amplitudes),
        rotations=_array(quats),
        velocities=_array(velocities),
        background=_array(background),
    )
    if alpha:
        fields.update(blend="alpha", opacities=_array(opacities), sh=_array(sh))
    else:
        fields.update(blend="additive")
    return _native.Scene(**fields)


def _frames(
    means: Tensor,
    scales: Tensor,
    quats: Tensor,
    opacities: Tensor,
    amplitudes: Tensor,
    sh: Tensor,
    velocities: Tensor,
    viewmats: Tensor,
    Ks: Tensor,
    backgrounds: Tensor,
    ts: Tensor,
    width: int,
    height: int,
    near: float,
    far: float,
    alpha: bool,
):
    """Each camera's scene, camera and time (per-camera colours and backgrounds)."""
    cameras = viewmats.shape[0]
    per_camera = amplitudes.dim() == 3
    shared = None
    for c in range(cameras):
        if per_camera or shared is None or backgrounds.shape[0] > 1:
            scene = _scene(
                means,
                scales,
                quats,
                opacities,
                amplitudes[c] if per_camera else amplitudes,
                sh[c] if per_camera else sh,
                velocities,
                backgrounds[c],
                alpha,
            )
            shared = scene
        camera = _native.Camera.from_viewmat(
            _array(viewmats[c]), _array(Ks[c]), width, height, near=near, far=far
        )
        yield shared, camera, float(ts[c])


@torch.library.custom_op("splat4d::rasterize", mutates_args=(), device_types="cpu")
def _rasterize(
    means: Tensor,
    scales: Tensor,
    quats: Tensor,
    opacities: Tensor,
    amplitudes: Tensor,
    sh: Tensor,
    velocities: Tensor,
    viewmats: Tensor,
    Ks: Tensor,
    backgrounds: Tensor,
    ts: Tensor,
    width: int,
    height: int,
    near: float,
    far: float,
    eps2d: float,
    cutoff: float,
    alpha: bool,
    threads: int,
) -> Tuple[Tensor, Tensor]:
    """splat4d's frame of each camera, in splat4d's parameters: means [N, 4], scales [N, 4]
    (standard deviations), quats [N, 4], opacities [N], amplitudes [(C,) N, 3], sh
    [(C,) N, K, 3], velocities [N, 3]; viewmats [C, 4, 4], Ks [C, 3, 3], backgrounds
    [C or 1, 3], ts [C]. Returns colours [C, H, W, 3] and opacities 1 - T [C, H, W, 1]."""
    colours: List[Tensor] = []
    alphas: List[Tensor] = []
    frames = _frames(
        means, scales, quats, opacities, amplitudes, sh, velocities,
        viewmats, Ks, backgrounds, ts, width, height, near, far, alpha,
    )
    for scene, camera, t in frames:
        image, opacity = _native.render(
            scene, camera, t, dilation=eps2d, cutoff=cutoff,
            threads=threads if threads > 0 else None, alphas=True,
        )
        colours.append(torch.from_numpy(image))
        alphas.append(torch.from_numpy(opacity))
    dtype = means.dtype
    return torch.stack(colours).to(dtype), torch.stack(alphas).to(dtype)


@_rasterize.register_fake
def _(means, scales, quats, opacities, amplitudes, sh, velocities, viewmats, Ks,
      backgrounds, ts, width, height, near, far, eps2d, cutoff, alpha, threads):
    cameras = viewmats.shape[0]
    colours = means.new_empty((cameras, height, width, 3))
    return colours, means.new_empty((cameras, height, width, 1))


def _setup_context(ctx, inputs, output) -> None:
    (means, scales, quats, opacities, amplitudes, sh, velocities, viewmats, Ks,
     backgrounds, ts, width, height, near, far, eps2d, cutoff, alpha, threads) = inputs
    ctx.save_for_backward(means, scales, quats, opacities, amplitudes, sh, velocities,
                          viewmats, Ks, backgrounds, ts)
    ctx.settings = (width, height, near, far, eps2d, cutoff, alpha, threads)


def _backward(ctx, v_colours: Tensor, v_alphas: Tensor):
    (means, scales, quats, opacities, amplitudes, sh, velocities, viewmats, Ks,
     backgrounds, ts) = ctx.saved_tensors
    width, height, near, far, eps2d, cutoff, alpha, threads = ctx.settings
    per_camera = amplitudes.dim() == 3
    totals: Dict[str, np.ndarray] = {}
    v_amplitudes: List[np.ndarray] = []
    v_sh: List[np.ndarray] = []
    v_backgrounds: List[np.ndarray] = []
    frames = _frames(
        means, scales, quats, opacities, amplitudes, sh, velocities,
        viewmats, Ks, backgrounds, ts, width, height, near, far, alpha,
    )
    for c, (scene, camera, t) in enumerate(frames):
        grads = _native.render_and_backward(
            scene, camera, t,
            v_colours[c].detach().to(dtype=torch.float32).contiguous().numpy(),
            v_alphas=v_alphas[c].detach().to(dtype=torch.float32).contiguous().numpy(),
            dilation=eps2d, cutoff=cutoff, threads=threads if threads > 0 else None,
        )
        for name in ("means", "scales", "rotations", "velocities", "opacities"):
            if name in grads:
                totals[name] = totals[name] + grads[name] if name in totals else grads[name]
        v_amplitudes.append(grads["amplitudes"])
        v_sh.append(grads.get("sh", np.zeros(sh.shape[-3:] if sh.dim() else (0,))))
        v_backgrounds.append(grads["background"])

    def tensor(a: Any, like: Tensor) -> Tensor:
        return torch.as_tensor(np.asarray(a), dtype=like.dtype).reshape(like.shape)

    if per_camera:
        g_amplitudes = tensor(np.stack(v_amplitudes), amplitudes)
        g_sh = tensor(np.stack(v_sh), sh)
    else:
        g_amplitudes = tensor(np.sum(v_amplitudes, axis=0), amplitudes)
        g_sh = tensor(np.sum(v_sh, axis=0), sh)
    g_backgrounds = np.stack(v_backgrounds)
    if backgrounds.shape[0] == 1:
        g_backgrounds = g_backgrounds.sum(axis=0, keepdims=True)
    zeros = torch.zeros_like
    return (
        tensor(totals["means"], means),
        tensor(totals["scales"], scales),
        tensor(totals["rotations"], quats),
        tensor(totals["opacities"], opacities) if "opacities" in totals else zeros(opacities),
        g_amplitudes,
        g_sh,
        tensor(totals["velocities"], velocities),
        None,
        None,
        tensor(g_backgrounds, backgrounds),
        None,
        None, None, None, None, None, None, None, None,
    )


_rasterize.register_autograd(_backward, setup_context=_setup_context)


def _refuse(name: str, value: Any, supported: Any) -> None:
    if value != supported:
        raise UsageError(f"rasterization: `{name}` {value!r} is not supported (only {supported!r})")


def rasterization(
    means: Tensor,
    quats: Tensor,
    scales: Tensor,
    opacities: Optional[Tensor],
    colors: Tensor,
    viewmats: Tensor,
    Ks: Tensor,
    width: int,
    height: int,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    radius_clip: float = 0.0,
    eps2d: float = 0.3,
    sh_degree: Optional[int] = None,
    packed: bool = True,
    tile_size: int = 16,
    backgrounds: Optional[Tensor] = None,
    render_mode: str = "RGB",
    sparse_grad: bool = False,
    absgrad: bool = False,
    rasterize_mode: str = "classic",
    channel_chunk: int = 32,
    distributed: bool = False,
    camera_model: str = "pinhole",
    segmented: bool = False,
    covars: Optional[Tensor] = None,
    *,
    times: Optional[Tensor] = None,
    time_scales: Optional[Tensor] = None,
    velocities: Optional[Tensor] = None,
    t: Union[float, Sequence[float], Tensor] = 0.0,
    blend: str = "alpha",
    cutoff: float = 1.0 / 255.0,
    threads: Optional[int] = None,
) -> Tuple[Tensor, Tensor, Dict[str, Any]]:
    """Rasterizes N Gaussian kernels to C images, as gsplat's ``rasterization()`` does, on
    the CPU, differentiably (every kernel input; not the cameras).

    Args (gsplat's):
        means: [N, 3] centres, or [N, 4] with the kernels' times.
        quats: [N, 4] quaternions, wxyz, of any non-zero length.
        scales: [N, 3] standard deviations (after ``exp``), or [N, 4] with σt.
        opacities: [N] in [0, 1] (after ``sigmoid``); ``None`` for ``blend="additive"``.
        colors: [(C,) N, 3] RGB, or with ``sh_degree`` [(C,) N, K, 3] SH coefficients,
            (sh_degree + 1)² ≤ K (degree ≤ 3).
        viewmats: [C, 4, 4] world→camera (OpenCV axes). Ks: [C, 3, 3] intrinsics.
        width, height: the images' size in pixels.
        near_plane, far_plane: kernels whose centre's camera z lies outside are culled.
        eps2d: the dilation added to each 2D covariance, px² (SPEC §4).
        backgrounds: [C, 3] colours behind the kernels (default black).
        packed, tile_size, channel_chunk, segmented: accepted; they change nothing here.
        radius_clip (0), render_mode ("RGB"), rasterize_mode ("classic"), camera_model
        ("pinhole"), sparse_grad, absgrad, distributed (False), covars (None): only these
        values are supported.

    Args (splat4d's):
        times: [N] the kernels' times (with 3D ``means``); time_scales: [N] σt (with 3D
            ``scales``); velocities: [N, 3] world units per time unit.
        t: the time rendered: one for every camera, or [C].
        blend: ``"alpha"`` (SPEC §8, gsplat's compositing) or ``"additive"`` (SPEC §5: the
            colours summed, no opacity, ``render_alphas`` 0).
        cutoff: ε of SPEC §5 (a pair needs α ≥ ε); 0 takes every pixel.
        threads: worker threads (default one per core; the images do not depend on it).

    Returns:
        render_colors [C, H, W, 3], render_alphas [C, H, W, 1] (1 - T, SPEC §8), and meta
        (``width``, ``height``, ``t``, ``blend``).
    """
    for name, value, supported in (
        ("radius_clip", radius_clip, 0.0),
        ("render_mode", render_mode, "RGB"),
        ("rasterize_mode", rasterize_mode, "classic"),
        ("camera_model", camera_model, "pinhole"),
        ("sparse_grad", sparse_grad, False),
        ("absgrad", absgrad, False),
        ("distributed", distributed, False),
        ("covars", covars, None),
    ):
        _refuse(name, value, supported)
    if blend not in ("alpha", "additive"):
        raise UsageError(f"rasterization: blend {blend!r} (expected 'alpha' or 'additive')")
    alpha = blend == "alpha"
    if means.dim() != 2 or means.shape[-1] not in (3, 4):
        raise UsageError(f"rasterization: means {tuple(means.shape)}, expected [N, 3] or [N, 4] (no batch dimensions)")
    n = means.shape[0]
    dtype, device = means.dtype, means.device

    def check(name: str, x: Tensor, shape: Tuple[int, ...]) -> None:
        if tuple(x.shape) != shape:
            raise UsageError(f"rasterization: {name} {tuple(x.shape)}, expected {list(shape)}")

    # Space-time means and scales (SPEC §1).
    if means.shape[-1] == 4:
        if times is not None:
            raise UsageError("rasterization: `times` with [N, 4] means: give the time once")
        means4 = means
    else:
        kernel_times = means.new_zeros(n) if times is None else times
        check("times", kernel_times, (n,))
        means4 = torch.cat([means, kernel_times[:, None].to(dtype)], dim=1)
    if scales.dim() != 2 or scales.shape != (n, scales.shape[-1]) or scales.shape[-1] not in (3, 4):
        raise UsageError(f"rasterization: scales {tuple(scales.shape)}, expected [{n}, 3] or [{n}, 4]")
    if scales.shape[-1] == 4:
        if time_scales is not None:
            raise UsageError("rasterization: `time_scales` with [N, 4] scales: give σt once")
        scales4 = scales
    else:
        st = means.new_full((n,), STATIC_TIME_SCALE) if time_scales is None else time_scales
        check("time_scales", st, (n,))
        scales4 = torch.cat([scales, st[:, None].to(dtype)], dim=1)
    check("quats", quats, (n, 4))
    v = means.new_zeros((n, 3)) if velocities is None else velocities
    check("velocities", v, (n, 3))
    if alpha:
        if opacities is None:
            raise UsageError("rasterization: the alpha blend needs `opacities` [N]")
        check("opacities", opacities, (n,))
        o = opacities
    else:
        if opacities is not None:
            raise UsageError("rasterization: the additive blend has no opacity: pass opacities=None")
        o = means.new_zeros(n)

    if viewmats.dim() != 3 or viewmats.shape[1:] != (4, 4):
        raise UsageError(f"rasterization: viewmats {tuple(viewmats.shape)}, expected [C, 4, 4]")
    cameras = viewmats.shape[0]
    check("Ks", Ks, (cameras, 3, 3))

    # Colours: RGB, or SH with its degree-0 band as the amplitude (SPEC §8).
    if sh_degree is None:
        if colors.shape[-2:] != (n, 3) or colors.dim() not in (2, 3):
            raise UsageError(
                f"rasterization: colors {tuple(colors.shape)}, expected [{n}, 3] or [C, {n}, 3] "
                "(RGB only: D = 3)"
            )
        amplitudes = colors
        sh = colors.new_zeros(colors.shape[:-1] + (0, 3))
    else:
        if not 0 <= sh_degree <= 3:
            raise UsageError(f"rasterization: sh_degree {sh_degree} (0 to 3)")
        bands = (sh_degree + 1) ** 2
        if colors.dim() not in (3, 4) or colors.shape[-1] != 3 or colors.shape[-3] != n or colors.shape[-2] < bands:
            raise UsageError(
                f"rasterization: colors {tuple(colors.shape)}, expected [(C,) {n}, K, 3] with K ≥ {bands}"
            )
        amplitudes = SH_C0 * colors[..., 0, :] + 0.5
        sh = colors[..., 1:bands, :]
    if colors.dim() == (4 if sh_degree is not None else 3) and colors.shape[0] != cameras:
        raise UsageError(f"rasterization: colors for {colors.shape[0]} cameras, viewmats for {cameras}")
    if not alpha and sh.shape[-2] > 0:
        raise UsageError("rasterization: the additive blend has no SH: sh_degree=0 or RGB colours")

    if backgrounds is None:
        bg = means.new_zeros((1, 3))
    else:
        bg = backgrounds
        check("backgrounds", bg, (cameras, 3))
    if isinstance(t, Tensor):
        ts = t.detach().to(dtype=torch.float64).reshape(-1)
    else:
        ts = torch.as_tensor(np.atleast_1d(np.asarray(t, dtype=np.float64)))
    if ts.numel() == 1:
        ts = ts.expand(cameras)
    check("t", ts, (cameras,))

    colours, alphas = _rasterize(
        means4, scales4, quats, o, amplitudes, sh, v.to(dtype),
        viewmats.detach(), Ks.detach(), bg, ts.contiguous(),
        int(width), int(height), float(near_plane), float(far_plane), float(eps2d),
        float(cutoff), alpha, int(threads or 0),
    )
    meta = {"width": int(width), "height": int(height), "t": ts, "blend": blend}
    return colours.to(device), alphas.to(device), meta
