"""Stubs of the native module ``splat4d._native`` (Rust, PyO3): what ``splat4d`` wraps."""

from os import PathLike
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple, Union, overload

import numpy as np
import numpy.typing as npt

_Path = Union[str, PathLike[str]]
_Array = npt.ArrayLike

__version__: str
FIT_OPTIONS: List[str]

class Scene:
    """A scene of 4D Gaussian kernels (SPEC §1, §8), validated once, immutable."""

    def __init__(
        self,
        means: _Array,
        scales: _Array,
        amplitudes: _Array,
        *,
        rotations: Optional[_Array] = None,
        velocities: Optional[_Array] = None,
        background: Optional[_Array] = None,
        blend: Optional[str] = None,
        opacities: Optional[_Array] = None,
        sh: Optional[_Array] = None,
    ) -> None: ...
    @staticmethod
    def load(path: _Path) -> Scene: ...
    def save(self, path: _Path) -> None: ...
    def __len__(self) -> int: ...
    @property
    def means(self) -> npt.NDArray[np.float64]: ...
    @property
    def scales(self) -> npt.NDArray[np.float64]: ...
    @property
    def amplitudes(self) -> npt.NDArray[np.float64]: ...
    @property
    def rotations(self) -> npt.NDArray[np.float64]: ...
    @property
    def velocities(self) -> npt.NDArray[np.float64]: ...
    @property
    def background(self) -> npt.NDArray[np.float64]: ...
    @property
    def blend(self) -> str: ...
    @property
    def opacities(self) -> Optional[npt.NDArray[np.float64]]: ...
    @property
    def sh(self) -> Optional[npt.NDArray[np.float64]]: ...
    def to_dict(self) -> Dict[str, Any]: ...

class Camera:
    """A pinhole camera (SPEC §3, OpenCV axes), validated once, immutable."""

    def __init__(
        self,
        width: int,
        height: int,
        fx: float,
        fy: float,
        cx: float,
        cy: float,
        world_to_camera: _Array,
        *,
        near: float = 0.01,
        far: float = 1e6,
    ) -> None: ...
    @staticmethod
    def look_at(
        eye: Sequence[float],
        target: Sequence[float],
        up: Sequence[float],
        fov_y_degrees: float,
        width: int,
        height: int,
        *,
        near: float = 0.01,
        far: float = 1e6,
    ) -> Camera: ...
    @staticmethod
    def from_viewmat(
        viewmat: _Array, K: _Array, width: int, height: int, *, near: float = 0.01, far: float = 1e6
    ) -> Camera: ...
    @staticmethod
    def load(path: _Path) -> Camera: ...
    def save(self, path: _Path) -> None: ...
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    near: float
    far: float
    @property
    def world_to_camera(self) -> npt.NDArray[np.float64]: ...
    @property
    def K(self) -> npt.NDArray[np.float64]: ...
    @property
    def centre(self) -> npt.NDArray[np.float64]: ...

@overload
def render(
    scene: Scene, camera: Camera, t: float, *, blend: Optional[str] = ..., dilation: float = ...,
    cutoff: float = ..., exp: str = ..., threads: Optional[int] = ..., alphas: bool = False,
) -> npt.NDArray[np.float32]: ...
@overload
def render(
    scene: Scene, camera: Camera, t: float, *, blend: Optional[str] = ..., dilation: float = ...,
    cutoff: float = ..., exp: str = ..., threads: Optional[int] = ..., alphas: bool = True,
) -> Tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]: ...
def render_and_backward(
    scene: Scene, camera: Camera, t: float, v_image: _Array, *, v_alphas: Optional[_Array] = None,
    blend: Optional[str] = None, dilation: float = 0.3, cutoff: float = 1 / 255, exp: str = "poly",
    threads: Optional[int] = None,
) -> Dict[str, npt.NDArray[np.float64]]: ...
def reference_render(
    scene: Scene, camera: Camera, t: float, *, blend: Optional[str] = None, dilation: float = 0.3,
    cutoff: float = 1 / 255, uncertain: bool = False,
) -> Any: ...
def reference_loss_and_gradients(
    scene: Scene, camera: Camera, t: float, target: _Array, *, dilation: float = 0.3, cutoff: float = 1 / 255,
) -> Tuple[float, Dict[str, npt.NDArray[np.float64]]]: ...
def save_image(image: _Array, path: _Path, *, bits: int = 8) -> None: ...
def load_image(path: _Path, *, background: Sequence[float] = ...) -> npt.NDArray[np.float32]: ...
def load_dataset(
    views: _Path, *, downscale: int = 1, background: Optional[Sequence[float]] = None,
    strict: bool = False, allow_outside_images: bool = False,
) -> Dict[str, Any]: ...
def fit(
    views: _Path, *, out: Optional[_Path] = None,
    progress: Optional[Callable[[Dict[str, Any]], None]] = None, **options: Any,
) -> Tuple[Scene, Dict[str, Any]]: ...
