"""Fits a small dynamic scene with torch's Adam over ``splat4d.torch.rasterization``, on the CPU.

A ground truth of moving, turning kernels (SPEC §1, the alpha blend of §8) is rendered by
splat4d into a D-NeRF folder: 8 cameras around it at 5 times, one camera held out. The
package reads it back (``splat4d.load_dataset``) and a model of kernels in space-time —
means, times, velocities, log scales, log σt, quaternions, logit opacities and SH of degree
1, in gsplat's parameterisation — is fitted to the training views with Adam, 4 views a step.
The held-out camera's PSNR is printed before and after.

    python python/examples/train_torch.py            # 400 steps, about 10 s
    python python/examples/train_torch.py --quick    # 50 steps (CI): exits 1 unless the loss fell
"""

import argparse
import json
import math
import pathlib
import tempfile
import time

import numpy as np
import torch

import splat4d
from splat4d.torch import rasterization


def truth(seed: int = 7, n: int = 6) -> splat4d.Scene:
    """Kernels in the unit box that move, turn and fade in time, with view-dependent colour."""
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(n, 4))
    return splat4d.Scene(
        means=np.column_stack([rng.uniform(-0.5, 0.5, (n, 3)), rng.uniform(0, 1, n)]),
        scales=np.column_stack([rng.uniform(0.1, 0.3, (n, 3)), rng.uniform(0.5, 1.5, n)]),
        amplitudes=rng.uniform(0.2, 0.9, (n, 3)),
        rotations=q / np.linalg.norm(q, axis=1, keepdims=True),
        velocities=rng.uniform(-0.4, 0.4, (n, 3)),
        opacities=rng.uniform(0.5, 0.9, n),
        sh=rng.normal(scale=0.15, size=(n, 3, 3)),
    )


def write_views(folder: pathlib.Path, scene: splat4d.Scene, size=(40, 30)) -> None:
    """The D-NeRF layout ``splat4d fit --views`` reads: camera 0 held out as ``test``."""
    splits = {"train": [], "test": []}
    for k in range(8):
        angle = 2 * math.pi * k / 8
        eye = [3.2 * math.sin(angle), 0.5, -3.2 * math.cos(angle)]
        camera = splat4d.Camera.look_at(eye, [0, 0, 0], [0, 1, 0], 45.0, *size)
        # D-NeRF stores camera-to-world matrices with OpenGL axes (y up, z backward).
        c2w = np.linalg.inv(camera.world_to_camera) @ np.diag([1.0, -1.0, -1.0, 1.0])
        for t in np.linspace(0, 1, 5):
            split = "test" if k == 0 else "train"
            name = f"{split}/r_{len(splits[split]):03d}"
            splat4d.save_image(splat4d.render(scene, camera, t), folder / f"{name}.exr")
            splits[split].append({"file_path": f"./{name}", "time": float(t), "transform_matrix": c2w.tolist(),
                                  "fl_x": camera.fx, "fl_y": camera.fy, "w": size[0], "h": size[1]})
    for split, frames in splits.items():
        (folder / f"transforms_{split}.json").write_text(json.dumps({"frames": frames}))


def batch(views, indices):
    """Cameras, times and images of some views, as tensors."""
    chosen = [views[i] for i in indices]
    viewmats = torch.tensor(np.stack([v["camera"].world_to_camera for v in chosen]), dtype=torch.float32)
    Ks = torch.tensor(np.stack([v["camera"].K for v in chosen]), dtype=torch.float32)
    times = torch.tensor([v["time"] for v in chosen], dtype=torch.float64)
    images = torch.tensor(np.stack([v["image"] for v in chosen]))
    return viewmats, Ks, times, images


class Model(torch.nn.Module):
    """Kernels in space-time, stored as gsplat stores them (log scales, logit opacities)."""

    def __init__(self, n: int, seed: int = 0):
        super().__init__()
        g = torch.Generator().manual_seed(seed)
        self.means = torch.nn.Parameter(torch.rand(n, 3, generator=g) - 0.5)
        self.times = torch.nn.Parameter(torch.rand(n, generator=g))
        self.velocities = torch.nn.Parameter(torch.zeros(n, 3))
        self.log_scales = torch.nn.Parameter(torch.full((n, 3), math.log(0.15)))
        self.log_time_scales = torch.nn.Parameter(torch.zeros(n))
        self.quats = torch.nn.Parameter(torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(n, 1))
        self.logit_opacities = torch.nn.Parameter(torch.zeros(n))
        self.sh = torch.nn.Parameter(torch.zeros(n, 4, 3))

    def render(self, viewmats, Ks, times, width, height):
        colours, _, _ = rasterization(
            self.means, self.quats, torch.exp(self.log_scales), torch.sigmoid(self.logit_opacities),
            self.sh, viewmats, Ks, width, height, sh_degree=1,
            times=self.times, time_scales=torch.exp(self.log_time_scales), velocities=self.velocities,
            t=times,
        )
        return colours


def psnr(model, views) -> float:
    with torch.no_grad():
        viewmats, Ks, times, images = batch(views, range(len(views)))
        frames = model.render(viewmats, Ks, times, images.shape[2], images.shape[1])
        return -10 * math.log10(torch.mean((frames - images) ** 2).item())


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="50 steps, and check that the loss fell")
    parser.add_argument("--steps", type=int, default=400)
    parser.add_argument("--kernels", type=int, default=24)
    args = parser.parse_args()
    steps = 50 if args.quick else args.steps
    with tempfile.TemporaryDirectory() as tmp:
        write_views(pathlib.Path(tmp), truth())
        dataset = splat4d.load_dataset(tmp)
    train, test = dataset["train"], dataset["test"]
    height, width, _ = train[0]["image"].shape
    model = Model(args.kernels)
    optimiser = torch.optim.Adam([
        {"params": [model.means, model.velocities], "lr": 0.01},
        {"params": [model.times, model.log_scales, model.log_time_scales, model.quats], "lr": 0.02},
        {"params": [model.logit_opacities, model.sh], "lr": 0.05},
    ])
    rng = np.random.default_rng(0)
    print(f"{len(train)} training views, {len(test)} held out, {width}×{height}; {args.kernels} kernels; "
          f"held-out PSNR {psnr(model, test):.2f} dB at the start")
    losses = []
    started = time.perf_counter()
    for step in range(1, steps + 1):
        viewmats, Ks, times, images = batch(train, rng.choice(len(train), size=4, replace=False))
        loss = torch.mean((model.render(viewmats, Ks, times, width, height) - images) ** 2)
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        with torch.no_grad():
            model.quats.div_(model.quats.norm(dim=1, keepdim=True))
        losses.append(loss.item())
        if step % max(1, steps // 10) == 0:
            print(f"step {step:4d}: loss {np.mean(losses[-10:]):.3e}")
    seconds = time.perf_counter() - started
    print(f"{steps} steps in {seconds:.1f} s ({1000 * seconds / steps:.1f} ms a step); "
          f"held-out PSNR {psnr(model, test):.2f} dB")
    fell = np.mean(losses[-10:]) < 0.7 * np.mean(losses[:10])
    if args.quick and not fell:
        print(f"the loss did not fall: {np.mean(losses[:10]):.3e} → {np.mean(losses[-10:]):.3e}")
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
