"""splat4d's frame against gsplat's own torch reference, where the two models coincide.

gsplat (installed from PyPI, no CUDA) keeps a pure-torch twin of its CUDA stages in
``gsplat.cuda._torch_impl``. Its covariance (``_quat_scale_to_covar_preci``), projection to
2D means, conics and depths (``_fully_fused_projection``) and SH colours
(``_spherical_harmonics``, then ``+ 0.5`` clamped at 0 as its ``rasterization()`` does) run on
the CPU; its last stage (``_rasterize_to_pixels``) asks its CUDA module for the pairs and
nerfacc for the sums, so here the pixels are composited densely by gsplat's rule (α =
min(0.999, o·exp(-σ)), skipped under 1/255, front to back by depth until T falls to 1e-4).

The models coincide for static kernels (no time), the alpha blend, opacities under 0.99
(splat4d clamps at 0.99, gsplat at 0.999) and every kernel's α ≥ 1/255 ellipse inside gsplat's
3.33σ box (true for any opacity ≤ 1). There the two frames agree to float32 rounding:

    python python/examples/compare_gsplat.py            # prints the largest difference
    python python/examples/compare_gsplat.py --quick    # the same (CI); exits 1 above 1e-5
"""

import argparse
import sys

import numpy as np
import torch

from splat4d.torch import rasterization

TOLERANCE = 1e-5


def gaussians(seed: int, n: int = 40, sh_degree: int = 3):
    g = torch.Generator().manual_seed(seed)
    return {
        "means": (torch.rand(n, 3, generator=g, dtype=torch.float64) - 0.5) * 1.6,
        "quats": torch.randn(n, 4, generator=g, dtype=torch.float64),
        "scales": 0.05 + 0.15 * torch.rand(n, 3, generator=g, dtype=torch.float64),
        "opacities": 0.1 + 0.8 * torch.rand(n, generator=g, dtype=torch.float64),
        "colors": 0.5 * torch.randn(n, (sh_degree + 1) ** 2, 3, generator=g, dtype=torch.float64),
    }


def cameras(width: int, height: int):
    viewmats, Ks = [], []
    for k, angle in enumerate((0.0, 0.7, -1.1)):
        eye = np.array([3.0 * np.sin(angle), 0.3 * k, -3.0 * np.cos(angle)])
        forward = -eye / np.linalg.norm(eye)
        right = np.cross(forward, [0.0, 1.0, 0.0])
        right /= np.linalg.norm(right)
        down = np.cross(forward, right)
        w2c = np.eye(4)
        w2c[:3, :3] = np.stack([right, down, forward])
        w2c[:3, 3] = -w2c[:3, :3] @ eye
        viewmats.append(w2c)
        f = 0.5 * height / np.tan(np.radians(20))
        Ks.append([[f, 0, width / 2 + 1.5 * k], [0, f * 1.05, height / 2], [0, 0, 1]])
    return torch.tensor(np.array(viewmats)), torch.tensor(Ks, dtype=torch.float64)


def gsplat_frames(g, viewmats, Ks, width, height, sh_degree):
    """gsplat's torch stages, then its compositing rule per pixel (float64)."""
    from gsplat.cuda._torch_impl import (
        _fully_fused_projection,
        _quat_scale_to_covar_preci,
        _spherical_harmonics,
    )

    covars, _ = _quat_scale_to_covar_preci(g["quats"], g["scales"], compute_preci=False)
    radii, means2d, depths, conics, _ = _fully_fused_projection(
        g["means"], covars, viewmats, Ks, width, height, eps2d=0.3, near_plane=0.01, far_plane=1e10,
    )
    frames = []
    for c in range(viewmats.shape[0]):
        centre = torch.linalg.inv(viewmats[c])[:3, 3]
        colours = _spherical_harmonics(sh_degree, g["means"] - centre, g["colors"])
        colours = torch.clamp_min(colours + 0.5, 0.0)
        jj, ii = torch.meshgrid(torch.arange(height), torch.arange(width), indexing="ij")
        px = torch.stack([ii.reshape(-1), jj.reshape(-1)], 1).to(torch.float64) + 0.5
        image = torch.zeros(px.shape[0], 3, dtype=torch.float64)
        transmittance = torch.ones(px.shape[0], dtype=torch.float64)
        done = torch.zeros(px.shape[0], dtype=torch.bool)
        for i in torch.argsort(depths[c], stable=True).tolist():
            if (radii[c, i] <= 0).all():
                continue
            d = px - means2d[c, i]
            a, b, cc = conics[c, i]
            sigma = 0.5 * (a * d[:, 0] ** 2 + cc * d[:, 1] ** 2) + b * d[:, 0] * d[:, 1]
            alpha = torch.clamp_max(g["opacities"][i] * torch.exp(-sigma), 0.999)
            take = (alpha >= 1 / 255) & ~done
            after = transmittance * (1 - alpha)
            stop = take & (after <= 1e-4)
            done |= stop
            take &= ~stop
            image += torch.where(take[:, None], colours[i] * (alpha * transmittance)[:, None], 0.0)
            transmittance = torch.where(take, after, transmittance)
        frames.append(image.reshape(height, width, 3))
    return torch.stack(frames)


def compare(seed: int = 0, width: int = 64, height: int = 48, sh_degree: int = 3) -> float:
    """The largest difference between the two frames of one seeded scene and three cameras."""
    g = gaussians(seed, sh_degree=sh_degree)
    viewmats, Ks = cameras(width, height)
    ours, _, _ = rasterization(g["means"], g["quats"], g["scales"], g["opacities"], g["colors"],
                               viewmats, Ks, width, height, sh_degree=sh_degree)
    theirs = gsplat_frames(g, viewmats, Ks, width, height, sh_degree)
    assert theirs.abs().max() > 0.2, "the scene is in view"
    return float((ours - theirs).abs().max())


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="one scene per SH degree (CI)")
    args = parser.parse_args()
    try:
        import gsplat  # noqa: F401
    except ImportError:
        print("gsplat is not installed (pip install gsplat): nothing to compare")
        return 0
    worst = 0.0
    for seed in range(1 if args.quick else 4):
        for degree in range(4):
            error = compare(seed, sh_degree=degree)
            worst = max(worst, error)
            print(f"seed {seed}, SH degree {degree}: max |splat4d - gsplat| = {error:.2e}")
    print(f"largest difference {worst:.2e} (tolerance {TOLERANCE:g})")
    return 0 if worst <= TOLERANCE else 1


if __name__ == "__main__":
    sys.exit(main())
