"""An independent float64 twin of SPEC §2–5 and §8 in torch, differentiable by autograd:
every kernel against every pixel, written from SPEC.md alone (it shares no code with
splat4d). The tests hold splat4d.render and splat4d.torch.rasterization, and their
gradients, against it.
"""

import math

import torch

C1 = 0.4886025119029199
C2 = [1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396]
C3 = [-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
      -0.4570457994644658, 1.445305721320277, -0.5900435899266435]
T_STOP = 1e-4 * (1 + 1e-5)


def sh_basis(d):
    """SPEC §8's real SH beyond degree 0 at unit directions d [N, 3]: [N, 15]."""
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    xx, yy, zz = x * x, y * y, z * z
    return torch.stack([
        -C1 * y, C1 * z, -C1 * x,
        C2[0] * x * y, C2[1] * y * z, C2[2] * (2 * zz - xx - yy), C2[3] * x * z, C2[4] * (xx - yy),
        C3[0] * y * (3 * xx - yy), C3[1] * x * y * z, C3[2] * y * (4 * zz - xx - yy),
        C3[3] * z * (2 * zz - 3 * xx - 3 * yy), C3[4] * x * (4 * zz - xx - yy),
        C3[5] * z * (xx - yy), C3[6] * x * (xx - 3 * yy),
    ], dim=1)


def rotation(q):
    """Rotation matrices [N, 3, 3] of quaternions wxyz [N, 4], normalised."""
    q = q / q.norm(dim=1, keepdim=True)
    w, x, y, z = q.unbind(1)
    return torch.stack([
        torch.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], 1),
        torch.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], 1),
        torch.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], 1),
    ], 1)


def render(means, scales, quats, amplitudes, velocities, background, viewmat, K, width, height, t,
           *, blend="additive", opacities=None, sh=None, near=0.01, far=1e6, dilation=0.3,
           cutoff=1 / 255):
    """The frame [H, W, 3] and, for the alpha blend, the opacities 1 - T [H, W]."""
    dt = t - means[:, 3]
    d = dt / scales[:, 3]
    w = torch.exp(-0.5 * d * d)
    m = means[:, :3] + velocities * dt[:, None]                        # §2
    r = rotation(quats)
    s2 = torch.diag_embed(scales[:, :3] ** 2)
    sigma3 = r @ s2 @ r.transpose(1, 2)
    rc, tc = viewmat[:3, :3], viewmat[:3, 3]
    p = m @ rc.T + tc                                                   # §3
    x, y, z = p.unbind(1)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    sigma_c = rc @ sigma3 @ rc.T                                        # §4
    lxp = (width - cx) / fx + 0.3 * 0.5 * width / fx
    lxm = cx / fx + 0.3 * 0.5 * width / fx
    lyp = (height - cy) / fy + 0.3 * 0.5 * height / fy
    lym = cy / fy + 0.3 * 0.5 * height / fy
    tx = z * torch.maximum(torch.minimum(x / z, lxp), -lxm)
    ty = z * torch.maximum(torch.minimum(y / z, lyp), -lym)
    zero = torch.zeros_like(z)
    jac = torch.stack([
        torch.stack([fx / z, zero, -fx * tx / z ** 2], 1),
        torch.stack([zero, fy / z, -fy * ty / z ** 2], 1),
    ], 1)
    sigma2 = jac @ sigma_c @ jac.transpose(1, 2) + dilation * torch.eye(2, dtype=z.dtype)
    det = sigma2[:, 0, 0] * sigma2[:, 1, 1] - sigma2[:, 0, 1] * sigma2[:, 1, 0]
    conic = torch.linalg.inv(sigma2)
    m2 = torch.stack([fx * x / z + cx, fy * y / z + cy], 1)
    alive = (z >= near) & (z <= far) & (det > 0)
    if blend == "additive":
        peak = amplitudes.abs().max(dim=1).values
        level = peak
        colour = amplitudes * w[:, None]
    else:
        level = opacities
        centre = -rc.T @ tc
        direction = m - centre
        direction = direction / direction.norm(dim=1, keepdim=True)
        k = 0 if sh is None else sh.shape[1]
        view = amplitudes
        if k:
            view = amplitudes + torch.einsum("nk,nkc->nc", sh_basis(direction)[:, :k], sh)
        colour = torch.clamp_min(view, 0.0)
    if cutoff > 0:
        qmax = 2 * (torch.log(level) - 0.5 * d * d - math.log(cutoff))
        alive = alive & (qmax > 0)
    else:
        qmax = torch.full_like(z, math.inf)
    jj, ii = torch.meshgrid(torch.arange(height, dtype=z.dtype), torch.arange(width, dtype=z.dtype), indexing="ij")
    pixels = torch.stack([ii.reshape(-1) + 0.5, jj.reshape(-1) + 0.5], 1)   # [P, 2]
    delta = pixels[:, None, :] - m2[None, :, :]                              # [P, N, 2]
    q = torch.einsum("pni,nij,pnj->pn", delta, conic, delta)
    pair = (q <= qmax[None, :]) & alive[None, :]
    g = torch.exp(-0.5 * q)
    if blend == "additive":                                                 # §5
        image = background + torch.einsum("pn,nc->pc", torch.where(pair, g, torch.zeros_like(g)), colour)
        return image.reshape(height, width, 3), None
    alpha = torch.where(pair, (opacities * w)[None, :] * g, torch.zeros_like(g))   # §8
    alpha = torch.clamp_max(alpha, 0.99)
    order = sorted(range(len(z)), key=lambda i: (float(z[i].detach()), i))
    transmittance = torch.ones(pixels.shape[0], dtype=z.dtype)
    stopped = torch.zeros(pixels.shape[0], dtype=torch.bool)
    image = torch.zeros(pixels.shape[0], 3, dtype=z.dtype)
    for i in order:
        a = alpha[:, i]
        after = transmittance * (1 - a)
        stopped = stopped | (pair[:, i] & (after < T_STOP))
        take = pair[:, i] & ~stopped
        image = image + torch.where(take[:, None], colour[i][None, :] * (a * transmittance)[:, None], torch.zeros_like(image))
        transmittance = torch.where(take, after, transmittance)
    image = image + transmittance[:, None] * background
    return image.reshape(height, width, 3), (1 - transmittance).reshape(height, width)
