"""splat4d from Python: render and fit dynamic scenes of 4D Gaussian kernels on the CPU.

The numpy interface (this module) and, in :mod:`splat4d.torch`, gsplat's
``rasterization()`` as a differentiable torch operator. The math is the project's
``SPEC.md``: §1 the kernel, §5 the additive blend, §8 the alpha blend, §6 the gradients.

>>> import numpy as np, splat4d
>>> scene = splat4d.Scene(means=[[0, 0, 0, 0]], scales=[[0.2, 0.2, 0.2, 1]], amplitudes=[[1, 0.5, 0.2]])
>>> camera = splat4d.Camera.look_at([0, 0, -3], [0, 0, 0], [0, 1, 0], 40.0, 64, 48)
>>> image = splat4d.render(scene, camera, 0.0)            # (48, 64, 3) float32, linear RGB
>>> grads = splat4d.render_and_backward(scene, camera, 0.0, 2 * image / image.size)
>>> sorted(grads)                                         # d(mean of image²)/d(every field)
['amplitudes', 'background', 'means', 'rotations', 'scales', 'velocities']

Arrays go in as any array-like (C-contiguous float64 is read in place) and come out as
numpy arrays; the GIL is released while the library works; errors are :class:`Splat4dError`
subclasses carrying the library's messages.
"""

from typing import Any, Callable, Dict, Mapping, Optional, Tuple, Union
import os

import numpy as np

from . import _native
from ._errors import InputError, NumericError, OutputError, Splat4dError, UsageError
from ._native import Camera, Scene

__version__: str = _native.__version__

__all__ = [
    "Camera",
    "InputError",
    "NumericError",
    "OutputError",
    "Scene",
    "Splat4dError",
    "UsageError",
    "fit",
    "load_camera",
    "load_dataset",
    "load_scene",
    "render",
    "render_and_backward",
    "save_camera",
    "save_scene",
    "__version__",
]

SceneLike = Union[Scene, Mapping[str, Any]]
CameraLike = Union[Camera, Mapping[str, Any]]
PathLike = Union[str, "os.PathLike[str]"]

#: The default dilation ``s`` of SPEC §4, px² (gsplat's ``eps2d``).
DEFAULT_DILATION = 0.3
#: The default cut-off ε of SPEC §5.
DEFAULT_CUTOFF = 1.0 / 255.0


def as_scene(scene: SceneLike) -> Scene:
    """``scene`` as a :class:`Scene`: a ``Scene``, or a mapping of its keyword arguments."""
    if isinstance(scene, Scene):
        return scene
    if isinstance(scene, Mapping):
        return Scene(**scene)
    raise TypeError(f"scene: expected a splat4d.Scene or a dict of arrays, got {type(scene).__name__}")


def as_camera(camera: CameraLike) -> Camera:
    """``camera`` as a :class:`Camera`: a ``Camera``, or a mapping of its keyword arguments
    (the fields of a camera JSON file: width, height, fx, fy, cx, cy, world_to_camera, near,
    far)."""
    if isinstance(camera, Camera):
        return camera
    if isinstance(camera, Mapping):
        return Camera(**camera)
    raise TypeError(f"camera: expected a splat4d.Camera or a dict, got {type(camera).__name__}")


def load_scene(path: PathLike) -> Scene:
    """Reads a scene file: splat4d JSON, 4D PLY, or a graphdeco 3DGS PLY (static alpha kernels)."""
    return Scene.load(os.fspath(path))


def save_scene(scene: SceneLike, path: PathLike) -> None:
    """Writes a scene: 4D PLY for ``.ply``, JSON otherwise (atomically: the old file or the
    new one, never a mix)."""
    as_scene(scene).save(os.fspath(path))


def load_camera(path: PathLike) -> Camera:
    """Reads a camera JSON file (``docs/formats.md``)."""
    return Camera.load(os.fspath(path))


def save_camera(camera: CameraLike, path: PathLike) -> None:
    """Writes a camera JSON file."""
    as_camera(camera).save(os.fspath(path))


def load_dataset(
    views: PathLike,
    *,
    downscale: int = 1,
    background: Optional[Tuple[float, float, float]] = None,
    strict: bool = False,
    allow_outside_images: bool = False,
) -> Dict[str, Any]:
    """Reads a dataset folder as ``splat4d fit --views`` does (D-NeRF / Blender, nerfstudio or
    instant-ngp ``transforms.json``, COLMAP): ``{"train": [view, …], "val": […], "test": […],
    "blend": "additive" | "alpha" | None, "notes": [str, …]}``. Each view is a dict:
    ``camera`` (:class:`Camera`), ``time`` (float), ``image`` ((H, W, 3) float32, linear
    RGB), ``name`` and ``weights`` ((H, W) float32 loss weights, or None). RGBA images are
    composited over ``background`` (default black); ``downscale`` averages N×N blocks."""
    return _native.load_dataset(
        os.fspath(views),
        downscale=downscale,
        background=background,
        strict=strict,
        allow_outside_images=allow_outside_images,
    )


def render(
    scene: SceneLike,
    camera: CameraLike,
    t: float,
    *,
    blend: Optional[str] = None,
    dilation: float = DEFAULT_DILATION,
    cutoff: float = DEFAULT_CUTOFF,
    exp: str = "poly",
    threads: Optional[int] = None,
) -> np.ndarray:
    """Renders ``scene`` through ``camera`` at time ``t``: an (H, W, 3) float32 array, linear
    RGB (SPEC §5; §8 for the alpha blend), the same bits as ``splat4d render``.

    ``blend`` renders in the other blend than the scene's (``"additive"`` or ``"alpha"``; an
    additive scene as alpha has opacity 1 and no SH). ``dilation`` (px²) and ``cutoff`` are
    SPEC §4–5's; ``exp`` is ``"poly"`` or ``"std"``; ``threads`` defaults to one per core
    (the image does not depend on it)."""
    return _native.render(
        as_scene(scene),
        as_camera(camera),
        float(t),
        blend=blend,
        dilation=dilation,
        cutoff=cutoff,
        exp=exp,
        threads=threads,
    )


def render_and_backward(
    scene: SceneLike,
    camera: CameraLike,
    t: float,
    dL_dimage: Any,
    *,
    dL_dalphas: Any = None,
    blend: Optional[str] = None,
    dilation: float = DEFAULT_DILATION,
    cutoff: float = DEFAULT_CUTOFF,
    exp: str = "poly",
    threads: Optional[int] = None,
) -> Dict[str, np.ndarray]:
    """The gradient of a loss L with respect to every field of ``scene``, given
    ``dL_dimage`` = ∂L/∂C, (H, W, 3), for the frame :func:`render` makes (SPEC §6 and §8: the
    exact derivative, pairs, depth order and stops held constant).

    Returns float64 arrays named like the scene's fields: ``means`` (N, 4), ``scales`` (N, 4),
    ``amplitudes`` (N, 3), ``rotations`` (N, 4: of the quaternions as given, through their
    normalisation), ``velocities`` (N, 3), ``background`` (3,) and, for alpha scenes,
    ``opacities`` (N,) and ``sh`` (N, K, 3). ``dL_dalphas`` (H, W), for alpha scenes, adds
    the gradient of a loss on the pixels' opacities 1 - T."""
    return _native.render_and_backward(
        as_scene(scene),
        as_camera(camera),
        float(t),
        dL_dimage,
        v_alphas=dL_dalphas,
        blend=blend,
        dilation=dilation,
        cutoff=cutoff,
        exp=exp,
        threads=threads,
    )


def fit(
    views: PathLike,
    *,
    out: Optional[PathLike] = None,
    progress: Optional[Callable[[Dict[str, Any]], None]] = None,
    **options: Any,
) -> Tuple[Scene, Dict[str, Any]]:
    """Fits a scene to the dataset folder ``views``, as ``splat4d fit --views`` does, with the
    same plan and defaults: each keyword option is one of its flags (``--lr-mean`` is
    ``lr_mean``, ``--box`` is ``box``; ``splat4d help fit`` and ``docs/commands.md`` list
    them, all but ``--views``, ``--out`` and ``--max-memory``), taking what the flag takes:
    its text, or a number, a list of numbers, ``True`` for a switch, ``None`` for the
    default. A value the flag refuses, and an option the fit cannot act on (another blend's,
    ``window`` larger than every view, …), raise the command line's ``UsageError`` naming it.

    ``progress`` is called after every step with ``{"step", "steps", "seconds", "loss",
    "heldout_psnr", "kernels", "pairs", "seconds_left"}`` (``pairs``: the (pixel, kernel)
    pairs the step's training renders composited); an exception it raises (or Ctrl-C) stops the fit and is
    raised here. Notes go to ``sys.stderr`` as ``note: …``. With ``out`` the scene is written
    there too. Returns ``(scene, summary)``; ``summary`` has ``kernels``, ``steps``,
    ``seconds``, ``blend``, ``splits`` (per split: ``views``, ``mse``, ``psnr``) and
    ``text`` (what the command line prints)."""
    return _native.fit(
        os.fspath(views),
        out=None if out is None else os.fspath(out),
        progress=progress,
        **options,
    )


#: The keyword options of :func:`fit` (the command line's flags of ``splat4d fit``).
FIT_OPTIONS: Tuple[str, ...] = tuple(_native.FIT_OPTIONS)


def save_image(image: Any, path: PathLike, *, bits: int = 8) -> None:
    """Writes an (H, W, 3) image, linear RGB: ``.exr`` as float32, else a PNG of ``bits`` 8 or
    16 per channel storing ``round(levels · clamp(C, 0, 1))`` (SPEC §5), as the command line
    writes renders."""
    _native.save_image(image, os.fspath(path), bits=bits)


def load_image(path: PathLike, *, background: Tuple[float, float, float] = (0.0, 0.0, 0.0)) -> np.ndarray:
    """Reads an image file (EXR, PNG, JPEG) as (H, W, 3) float32, ``value / (2^bits − 1)``
    (linear, no sRGB curve); RGBA pixels are composited over ``background``."""
    return _native.load_image(os.fspath(path), background=background)


__all__ += ["save_image", "load_image", "FIT_OPTIONS", "as_scene", "as_camera"]
