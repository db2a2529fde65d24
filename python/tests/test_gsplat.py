"""splat4d's frame against gsplat's own torch reference (python/examples/compare_gsplat.py),
where the two models coincide: static kernels, the alpha blend, opacities under 0.99."""

import importlib.util

import pytest

from conftest import REPO

pytest.importorskip("torch")
pytest.importorskip("gsplat")


def test_frames_agree_with_gsplats_torch_reference():
    path = REPO / "python/examples/compare_gsplat.py"
    spec = importlib.util.spec_from_file_location("compare_gsplat", path)
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    for degree in (0, 3):
        assert example.compare(seed=5, width=40, height=30, sh_degree=degree) <= example.TOLERANCE
