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
    assert all(isinstance(r["pairs"], int) for r in records) and records[0]["pairs"] > 0
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


def alpha_fit(folder, **options):
    """A short alpha fit of the test dataset from 30 random kernels: a few milliseconds."""
    settings = dict(blend="alpha", init="random:30", steps=8, seed=1, eval_every=0, threads=1)
    settings.update(options)
    return splat4d.fit(folder, **settings)


def train_mse(summary):
    return summary["splits"]["train"]["mse"]


def test_the_alpha_fits_options_act(dataset, tmp_path):
    folder, _ = dataset
    base, summary = alpha_fit(folder)
    # `window` 16 cuts the 24×18 views into 2×1 windows; `off` is the default on views
    # this small (under 1.5 × 200 pixels).
    _, windows = alpha_fit(folder, window=16)
    assert train_mse(windows) != train_mse(summary)
    assert train_mse(alpha_fit(folder, window="off")[1]) == train_mse(summary)
    _, mse = alpha_fit(folder, loss="mse")
    assert train_mse(mse) != train_mse(summary)
    still, _ = alpha_fit(folder, motion="off")
    assert len(still) == len(base) and not np.array_equal(still.means, base.means)
    # The pruning by score keeps the share of the kernels the fraction leaves.
    counts = [alpha_fit(folder, prune_fraction=f)[1]["kernels"] for f in (0, 0.5, 0.9)]
    assert counts == [30, 15, 3]
    _, spread = alpha_fit(folder, prune_fraction=0.5, prune_rounds=2, densify_every=2)
    _, once = alpha_fit(folder, prune_fraction=0.5, densify_every=2)
    assert train_mse(spread) != train_mse(once)
    # Values as the flags take them: text, numbers, lists and paths.
    text, _ = alpha_fit(folder, lr_mean="1e-3", background="0.1,0.1,0.1", log=str(tmp_path / "a"))
    numbers, _ = alpha_fit(folder, lr_mean=1e-3, background=np.full(3, 0.1), log=tmp_path / "b")
    np.testing.assert_array_equal(text.means, numbers.means)
    assert not np.array_equal(text.means, base.means)
    assert (tmp_path / "a").read_text().count("\n") == (tmp_path / "b").read_text().count("\n") == 8


def test_options_that_cannot_act_are_refused_by_name(dataset, tmp_path):
    folder, _ = dataset
    refusals = [
        (dict(blend="additive", early_stop=0.2), "`early_stop` acts on the alpha blend"),
        (dict(blend="additive", window=16), "`window` acts on the alpha blend"),
        # No training view is 1.5 × 64 pixels: every step would fit whole views.
        (dict(window=64), "`window` 64 cuts only views of 1.5×64 pixels or more"),
        (dict(prune_fraction=0, prune_rounds=2), "`prune_rounds` spreads the pruning"),
        (dict(prune_fraction=1), "`prune_fraction` 1 must lie in [0, 1)"),
        (dict(loss="mse", dssim_weight=0.3), "`dssim_weight` weighs the D-SSIM term"),
        (dict(motion_after_splits=2), "`motion_after_splits` acts when `motion` is auto"),
        (dict(motion="off", lr_acceleration=0.01), "`lr_acceleration` fits SPEC §9 motion"),
        # Values the flags refuse, refused the same way.
        (dict(window=8), "`window` `8`: give `off` or a window side"),
        (dict(coarse_to_fine=0), "`coarse_to_fine` `0`: give `off`"),
        (dict(early_stop=2), "`early_stop` `2`: give `off` or a fraction"),
        (dict(loss="l2"), "`loss` `l2`: unknown loss"),
        (dict(background=[1, 2]), "`background` expected 3 comma-separated numbers, got 2"),
        (dict(steps=[5]), "`steps` takes one value, not a list"),
        (dict(steps=True), "`steps` takes a value, not true or false"),
        (dict(adaptive="yes"), "`adaptive` is a switch"),
        (dict(downscale=0), "`downscale` 0 must be between 1 and"),
    ]
    for options, says in refusals:
        with pytest.raises(splat4d.UsageError) as caught:
            alpha_fit(folder, out=tmp_path / "refused.json", **options)
        message = str(caught.value)
        # The option the message starts its sentence with is the one refused.
        named = says.split("`")[1]
        assert says in message and caught.value.settings == [named], (options, message)
        assert not (tmp_path / "refused.json").exists()


def test_every_flag_of_fit_is_an_option(dataset):
    """The flags `docs/commands.md` lists for `splat4d fit` (from the command's definition)
    against this build's options."""
    import inspect
    import re
    from conftest import REPO

    text = (REPO / "docs" / "commands.md").read_text(encoding="utf-8")
    section = text.split("## `splat4d fit`")[1].split("\n## ")[0]
    flags = {m.replace("-", "_") for m in re.findall(r"^\s+--([a-z0-9-]+)", section, re.M)}
    arguments = set(inspect.signature(splat4d.fit).parameters)  # views, out, progress
    # `--max-memory` bounds the whole process, a global flag of every command.
    command_line_only = {"max_memory"}
    assert flags - set(splat4d.FIT_OPTIONS) - arguments == command_line_only
    assert set(splat4d.FIT_OPTIONS) <= flags
