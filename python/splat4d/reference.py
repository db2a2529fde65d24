"""splat4d's f64 twin (``splat4d::reference``): every kernel against every pixel in float64,
SPEC §2–6 and §8 as written, no tiles, no bounds. What the fast renderer and its gradient
are tested against; slow (pixels × kernels), for small frames."""

from typing import Any, Dict, Optional, Tuple, Union

import numpy as np

from . import DEFAULT_CUTOFF, DEFAULT_DILATION, CameraLike, SceneLike, _native, as_camera, as_scene


def render(
    scene: SceneLike,
    camera: CameraLike,
    t: float,
    *,
    blend: Optional[str] = None,
    dilation: float = DEFAULT_DILATION,
    cutoff: float = DEFAULT_CUTOFF,
    uncertain: bool = False,
) -> Union[np.ndarray, Tuple[np.ndarray, np.ndarray]]:
    """The frame in float64, (H, W, 3). With ``uncertain``, also the (H, W) bool mask of the
    pixels where SPEC lets implementations differ: a pair within the cut-off band
    (``|q - qmax| ≤ 1e-4 · max(1, qmax)``, §5), or a stop within ``1e-6 · T'`` of
    ``T_stop`` (§8)."""
    return _native.reference_render(
        as_scene(scene), as_camera(camera), float(t),
        blend=blend, dilation=dilation, cutoff=cutoff, uncertain=uncertain,
    )


def loss_and_gradients(
    scene: SceneLike,
    camera: CameraLike,
    t: float,
    target: Any,
    *,
    dilation: float = DEFAULT_DILATION,
    cutoff: float = DEFAULT_CUTOFF,
) -> Tuple[float, Dict[str, np.ndarray]]:
    """The MSE of the float64 frame against ``target`` (H, W, 3) and its exact gradient
    (SPEC §6), named like :func:`splat4d.render_and_backward`'s; additive scenes only."""
    return _native.reference_loss_and_gradients(
        as_scene(scene), as_camera(camera), float(t), target, dilation=dilation, cutoff=cutoff,
    )
