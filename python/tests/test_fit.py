"""Datasets and fits: a dataset folder read as views, and `splat4d fit` from Python with
its options, defaults, messages and a progress callback."""

import numpy as np
import pytest

import splat4d
from conftest import random_fields, write_dataset


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    truth = splat4d.Scene(**random_fields(30, n=3))
    return write_dataset(tmp_path_factory.mktemp("views"), truth), truth


def test_a_dataset_reads_as_cameras_times_and_images(dataset):
    folder, truth = dataset
    views = splat4d.load_dataset(folder)
    assert [len(views[s]) for s in ("train", "val", "test")] == [16, 1, 1]
    view = views["train"][0]
    assert view["image"].shape == (18, 24, 3) and view["image"].dtype == np.float32
    np.testing.assert_array_equal(view["image"], splat4d.render(truth, view["camera"], view["time"]))
    halves = splat4d.load_dataset(folder, downscale=2)
    assert halves["train"][0]["image"].shape == (9, 12, 3)


def test_a_fit_lowers_its_loss_and_reports_each_step(dataset, tmp_path):
    folder, _ = dataset
    records = []
    scene, summary = splat4d.fit(
        folder, blend="additive", init="random:20", steps=40, seed=1, eval_every=0,
        out=tmp_path / "fit.json", progress=records.append, threads=1,
    )
    assert [r["step"] for r in records] == list(range(1, 41))
    assert records[-1]["loss"] < records[0]["loss"]
    assert summary["steps"] == 40 and summary["kernels"] == len(scene) == 20
    assert set(summary["splits"]) == {"train", "val", "test"}
    assert splat4d.load_scene(tmp_path / "fit.json").blend == "additive"


def test_an_exception_in_the_callback_stops_the_fit(dataset):
    folder, _ = dataset
    seen = []

    def stop(record):
        seen.append(record["step"])
        if record["step"] == 3:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        splat4d.fit(folder, blend="additive", init="random:5", steps=100, progress=stop)
    assert seen == [1, 2, 3]


def test_options_are_the_flags_and_refused_by_name(dataset):
    folder, _ = dataset
    with pytest.raises(splat4d.UsageError, match="no option `lr_means`"):
        splat4d.fit(folder, lr_means=1e-3)
    with pytest.raises(splat4d.UsageError) as caught:
        splat4d.fit(folder, blend="additive", sh=3)
    assert caught.value.settings == ["sh"] and "`sh`" in str(caught.value)
    with pytest.raises(splat4d.UsageError, match="`lr_mean` NaN is not finite"):
        splat4d.fit(folder, lr_mean=float("nan"))
    assert "lr_mean" in splat4d.FIT_OPTIONS and "box" in splat4d.FIT_OPTIONS
