//! Every `fit` flag acts on the chosen blend's fit or is refused naming the flag and the
//! blend it belongs to (`src/fit/settings.rs`): run through the binary on a small alpha
//! dataset, each flag against the same command without it.

use crate::common::run_limited;
use std::path::Path;

/// A 4-camera, 2-time, 16×16 dataset of the occluding scene (an alpha scene: the dataset
/// records the alpha blend, the default blend of its fits).
fn occluding_dataset(dir: &Path) {
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/images/occluding_scene.json");
    let output = run_limited(
        &[
            "dataset",
            "--scene",
            scene.to_str().unwrap(),
            "--views",
            "4",
            "--times",
            "2",
            "--size",
            "16x16",
            "--out",
            "ds",
        ],
        dir,
    );
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
}

/// Density rounds from the first step, every step: so that the rounds' flags act within
/// the few steps of a test.
const BASE: [&str; 11] = [
    "fit",
    "--views",
    "ds",
    "--steps",
    "4",
    "--init",
    "random:20",
    "--densify-every",
    "1",
    "--densify-from",
    "0",
];

/// Runs `fit` with `BASE` (its `--init` replaced when `extra` gives one, its
/// `--densify-every` when `extra` gives one) and `extra`; the scene and log written, or the
/// failed output.
fn fit(dir: &Path, name: &str, extra: &[&str]) -> Result<(Vec<u8>, Vec<u8>), String> {
    let mut args: Vec<String> = Vec::new();
    let mut base = BASE.iter();
    while let Some(arg) = base.next() {
        if arg.starts_with("--") && extra.contains(arg) {
            base.next();
            continue;
        }
        args.push((*arg).to_owned());
    }
    args.extend(extra.iter().map(|a| (*a).to_owned()));
    let (out, log) = (format!("{name}.json"), format!("{name}.log"));
    args.extend(["--out".into(), out.clone(), "--log".into(), log.clone()]);
    let output = run_limited(&args, dir);
    if !output.status.success() {
        return Err(format!(
            "exit {:?}: {}",
            output.status.code(),
            String::from_utf8_lossy(&output.stderr)
        ));
    }
    Ok((
        std::fs::read(dir.join(out)).unwrap(),
        std::fs::read(dir.join(log)).unwrap(),
    ))
}

/// The log without its wall-clock `seconds`.
fn without_seconds(log: &[u8]) -> Vec<serde_json::Value> {
    String::from_utf8_lossy(log)
        .lines()
        .map(|line| {
            let mut record: serde_json::Value = serde_json::from_str(line).unwrap();
            record.as_object_mut().unwrap().remove("seconds");
            record
        })
        .collect()
}

#[test]
fn every_fit_flag_acts_on_the_alpha_fit_or_is_refused_naming_its_blend() {
    let dir = tempfile::tempdir().unwrap();
    occluding_dataset(dir.path());
    let (base_scene, base_log) = fit(dir.path(), "base", &[]).expect("the base fit");
    // Flags both blends act on, and the alpha fit's own: each changes the scene or the log.
    let acting: &[&[&str]] = &[
        &["--steps", "5"],
        &["--batch", "1"],
        &["--init", "auto", "--start-kernels", "50"],
        &["--max-kernels", "21"],
        &["--eval-every", "1"],
        &["--seed", "7"],
        &["--background", "0.5,0.5,0.5"],
        &["--lr-mean", "0.01"],
        &["--lr-time", "0.01"],
        &["--lr-amplitude", "0.05"],
        &["--lr-velocity", "0.01"],
        &["--lr-scale", "0.05"],
        &["--lr-final", "0.5"],
        &["--freeze-mean"],
        &["--freeze-time"],
        &["--freeze-amplitude"],
        &["--densify-every", "2"],
        &["--densify-from", "0.5"],
        &["--densify-until", "0.1"],
        &["--densify-threshold", "1e9"],
        &["--max-growth", "0.5"],
        &["--prune-below", "0.2"],
        &["--sh", "8"],
        &["--sh-raise-every", "1"],
        &["--sh-raise-every", "1", "--lr-sh", "0.05"],
        &["--lr-opacity", "0.2"],
        &["--lr-rotation", "0.05"],
        &["--opacity-reset-every", "2"],
        &["--percent-dense", "0.5"],
        &["--coarse-to-fine", "4"],
        &["--lr-acceleration", "0.01"],
        &["--lr-angular-velocity", "0.01"],
        &["--cutoff", "0.01"],
        &["--dilation", "0.5"],
        &["--prune-fraction", "0"],
        &["--prune-rounds", "2"],
        &["--opacity-regulariser", "0.5"],
        &["--scale-regulariser", "0.5"],
    ];
    let mut reference: Option<(Vec<u8>, Vec<u8>)> = None;
    for extra in acting {
        let (scene, log) =
            fit(dir.path(), "acting", extra).unwrap_or_else(|e| panic!("{extra:?}: {e}"));
        // `--lr-sh` is compared with `--sh-raise-every 1` alone, which it extends.
        let (against_scene, against_log) = match extra {
            [_, _, "--lr-sh", _] => reference.as_ref().expect("--sh-raise-every ran first"),
            _ => &(base_scene.clone(), base_log.clone()),
        };
        assert!(
            scene != *against_scene || without_seconds(&log) != without_seconds(against_log),
            "{extra:?} changed neither the scene nor the log"
        );
        if extra == &["--sh-raise-every", "1"] {
            reference = Some((scene, log));
        }
    }
    // The split in time needs kernels that move: a start of the base fit's kernels
    // unpruned (the rounds grow 5 % of the visible kernels: at least one of 21, none of
    // 10), each sent across the box within its σt.
    let (unpruned, _) = fit(dir.path(), "unpruned", &["--prune-fraction", "0"]).unwrap();
    let mut moving: serde_json::Value = serde_json::from_slice(&unpruned).unwrap();
    for kernel in moving["kernels"].as_array_mut().unwrap() {
        kernel["velocity"] = serde_json::json!([8.0, 0.0, 0.0]);
    }
    std::fs::write(dir.path().join("moving.json"), moving.to_string()).unwrap();
    let moving_start = ["--init", "moving.json"];
    let (split, _) = fit(dir.path(), "split", &moving_start).unwrap();
    let mut never = moving_start.to_vec();
    never.extend(["--time-split-fraction", "1e9"]);
    let (unsplit, _) = fit(dir.path(), "unsplit", &never).unwrap();
    assert_ne!(split, unsplit, "--time-split-fraction changed nothing");

    // Flags of the additive fit only: refused with the alpha blend, naming the flag.
    let additive_only: &[&[&str]] = &[
        &["--mode", "paper"],
        &["--fit-velocity"],
        &["--fit-scale"],
        &["--adaptive"],
        &["--min-improvement", "0.1"],
        &["--merge-tolerance", "0.2"],
        &["--min-scale", "0.1"],
        &["--box", "0,0,0,1,1,1"],
        &["--time-range", "0,1"],
        &["--init-scale", "0.1,0.1,0.1,0.5"],
        &["--init-amplitude", "0.5"],
        &["--lr-background", "0.01"],
        &["--freeze-background"],
    ];
    for extra in additive_only {
        let error = fit(dir.path(), "refused", extra).expect_err("refused");
        assert!(
            error.starts_with("exit Some(2)")
                && error.contains(&format!("{} acts on the additive blend", extra[0]))
                && error.contains("--blend additive")
                && !error.contains("panicked"),
            "{extra:?}: {error}"
        );
        assert!(!dir.path().join("refused.json").exists());
    }
    // The alpha fit's own flags are refused with the additive blend.
    for extra in [
        &["--sh", "8"][..],
        &["--sh-raise-every", "1"],
        &["--lr-opacity", "0.2"],
        &["--lr-rotation", "0.05"],
        &["--lr-sh", "0.05"],
        &["--opacity-reset-every", "2"],
        &["--percent-dense", "0.5"],
        &["--time-split-fraction", "0.01"],
        &["--coarse-to-fine", "off"],
        &["--lr-acceleration", "0.01"],
        &["--lr-angular-velocity", "0.01"],
        &["--early-stop", "off"],
        &["--prune-fraction", "0.3"],
        &["--prune-rounds", "2"],
        &["--opacity-regulariser", "0.01"],
        &["--scale-regulariser", "0.01"],
    ] {
        let mut args = vec!["--blend", "additive"];
        args.extend_from_slice(extra);
        let error = fit(dir.path(), "refused", &args).expect_err("refused");
        assert!(
            error.starts_with("exit Some(2)")
                && error.contains(&format!("{} acts on the alpha blend", extra[0])),
            "{extra:?}: {error}"
        );
    }
    // Rounds of no pruning, and a fraction that would remove every kernel.
    let error = fit(
        dir.path(),
        "refused",
        &["--prune-fraction", "0", "--prune-rounds", "2"],
    )
    .expect_err("refused");
    assert!(
        error.starts_with("exit Some(2)") && error.contains("--prune-rounds spreads"),
        "{error}"
    );
    let error = fit(dir.path(), "refused", &["--prune-fraction", "1"]).expect_err("refused");
    assert!(
        error.starts_with("exit Some(2)")
            && error.contains("--prune-fraction 1 must lie in [0, 1)"),
        "{error}"
    );
    // A start count with a start that has its own.
    let error = fit(dir.path(), "refused", &["--start-kernels", "50"]).expect_err("refused");
    assert!(
        error.contains("--start-kernels sizes an `auto` start"),
        "{error}"
    );
}

#[test]
fn the_issues_example_lr_flags_now_change_the_default_fit() {
    let dir = tempfile::tempdir().unwrap();
    occluding_dataset(dir.path());
    let a = fit(dir.path(), "a", &["--steps", "3"]).unwrap();
    let b = fit(
        dir.path(),
        "b",
        &["--steps", "3", "--lr-mean", "0.5", "--lr-amplitude", "0.5"],
    )
    .unwrap();
    assert_ne!(a.0, b.0);
    let error = fit(dir.path(), "c", &["--steps", "3", "--mode", "paper"]).expect_err("refused");
    assert!(
        error.contains("--mode acts on the additive blend"),
        "{error}"
    );
}

/// A flag that the start leaves without effect is refused naming it: the additive density
/// rounds' flags without `--adaptive` from a random start, the random start's shape with a
/// scene start, the rates of groups the additive mode does not fit, the SH's rate and
/// schedule without SH.
#[test]
fn flags_the_start_or_mode_leaves_without_effect_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    occluding_dataset(dir.path());
    let additive = |extra: &[&'static str]| -> Vec<&'static str> {
        let mut args = vec!["--blend", "additive", "--init", "random:20"];
        args.extend_from_slice(extra);
        args
    };
    // BASE gives --densify-every and --densify-from: an additive random start runs rounds
    // only with --adaptive, so these are refused there and act with it.
    let error = fit(dir.path(), "r", &additive(&[])).expect_err("refused");
    assert!(
        error.contains("--densify-every acts on the density rounds")
            && error.contains("add --adaptive"),
        "{error}"
    );
    fit(dir.path(), "r", &additive(&["--adaptive"])).expect("rounds run with --adaptive");
    let cases: &[(&[&str], &str)] = &[
        (
            &["--adaptive", "--lr-velocity", "0.01"],
            "--lr-velocity acts when the velocities",
        ),
        (
            &["--adaptive", "--lr-scale", "0.01"],
            "--lr-scale acts when the scales",
        ),
        (
            &["--blend", "alpha", "--sh", "0", "--lr-sh", "0.01"],
            "--lr-sh acts on the SH",
        ),
        (
            &["--blend", "alpha", "--sh", "0", "--sh-raise-every", "1"],
            "--sh-raise-every acts",
        ),
    ];
    for (extra, needle) in cases {
        let args = if extra[0] == "--blend" {
            extra.to_vec()
        } else {
            additive(extra)
        };
        let error = fit(dir.path(), "r", &args).expect_err("refused");
        assert!(
            error.starts_with("exit Some(2)") && error.contains(needle),
            "{extra:?}: {error}"
        );
    }
    // The modes that fit those groups take the same rates.
    for extra in [
        &["--adaptive", "--fit-velocity", "--lr-velocity", "0.01"][..],
        &["--adaptive", "--mode", "static", "--lr-scale", "0.01"],
    ] {
        fit(dir.path(), "r", &additive(extra)).unwrap_or_else(|e| panic!("{extra:?}: {e}"));
    }
    // A scene start has no random start to shape.
    let (additive_start, _) = fit(dir.path(), "r", &additive(&["--adaptive"])).unwrap();
    std::fs::write(dir.path().join("additive_start.json"), additive_start).unwrap();
    let from_scene = [
        "--blend",
        "additive",
        "--init",
        "additive_start.json",
        "--box",
        "0,0,0,1,1,1",
    ];
    let error = fit(dir.path(), "r", &from_scene).expect_err("refused");
    assert!(
        error.contains("--box shapes a random or `auto` start"),
        "{error}"
    );
}

/// `--early-stop` reads the held-out PSNR: with no `val` or `test` views it could not act,
/// and is refused naming it, where the default fit runs.
#[test]
fn an_early_stop_without_heldout_views_is_refused_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    occluding_dataset(dir.path());
    for split in ["val", "test"] {
        std::fs::remove_file(dir.path().join(format!("ds/transforms_{split}.json"))).unwrap();
    }
    let error = fit(dir.path(), "refused", &["--early-stop", "0.5"]).expect_err("refused");
    assert!(
        error.starts_with("exit Some(2)")
            && error.contains("--early-stop reads the held-out PSNR")
            && !error.contains("panicked"),
        "{error}"
    );
    assert!(!dir.path().join("refused.json").exists());
    fit(dir.path(), "plain", &[]).expect("the fit without --early-stop");
}

/// Runs `fit` with `extra` (see [`fit`]) and checks that it is refused with exit status 2,
/// a message that `says` it, no panic and no scene written.
fn assert_refused(dir: &Path, extra: &[&str], says: &str) {
    let error = fit(dir, "refused", extra).expect_err("refused");
    assert!(
        error.starts_with("exit Some(2)") && error.contains(says) && !error.contains("panicked"),
        "{extra:?}: {error}"
    );
    assert!(!dir.join("refused.json").exists());
}

/// `--loss l1-dssim` changes the fit, `--dssim-weight` its weight; the reported loss stays
/// the MSE (the first step's, before any update, is the same under both losses); the fit
/// has the same bits on 1 and 3 threads; `--dssim-weight` is refused naming it where it
/// cannot act (with the mse loss, outside [0, 1]) and both flags with the additive blend.
#[test]
fn the_loss_flags_act_and_are_refused_naming_them_where_they_cannot() {
    let dir = tempfile::tempdir().unwrap();
    occluding_dataset(dir.path());
    let (mse_scene, mse_log) = fit(dir.path(), "mse", &["--loss", "mse"]).unwrap();
    let (ssim_scene, ssim_log) = fit(dir.path(), "ssim", &["--loss", "l1-dssim"]).unwrap();
    let (half_scene, _) = fit(
        dir.path(),
        "half",
        &["--loss", "l1-dssim", "--dssim-weight", "0.5"],
    )
    .unwrap();
    assert_ne!(mse_scene, ssim_scene, "--loss l1-dssim changed nothing");
    assert_ne!(ssim_scene, half_scene, "--dssim-weight changed nothing");
    let first = |log: &[u8]| without_seconds(log)[0]["train_loss"].clone();
    assert_eq!(first(&mse_log), first(&ssim_log));
    for threads in ["1", "3"] {
        let (scene, log) = fit(
            dir.path(),
            "threads",
            &["--loss", "l1-dssim", "--threads", threads],
        )
        .unwrap();
        assert_eq!(scene, ssim_scene, "{threads} threads");
        assert_eq!(without_seconds(&log), without_seconds(&ssim_log));
    }
    for (extra, says) in [
        (
            &["--loss", "mse", "--dssim-weight", "0.5"][..],
            "--dssim-weight weighs the D-SSIM term",
        ),
        (
            &["--loss", "l1-dssim", "--dssim-weight", "1.5"],
            "--dssim-weight 1.5 must lie in [0, 1]",
        ),
        (
            &["--blend", "additive", "--loss", "l1-dssim"],
            "--loss acts on the alpha blend",
        ),
        (
            &["--blend", "additive", "--dssim-weight", "0.5"],
            "--dssim-weight acts on the alpha blend",
        ),
    ] {
        assert_refused(dir.path(), extra, says);
    }
}

/// `--motion` acts, and `--motion`, `--motion-after-splits` and `--window` are refused naming them
/// where they cannot act: a SPEC §9 rate with `--motion off`, `--motion-after-splits`
/// without `--motion auto`, `--motion` with both SPEC §9 rates 0, a window side that cuts
/// no training view (16×16 here), and the alpha flags with the additive blend.
#[test]
fn the_motion_and_window_flags_act_and_are_refused_naming_them_where_they_cannot() {
    let dir = tempfile::tempdir().unwrap();
    occluding_dataset(dir.path());
    let rate = ["--lr-acceleration", "0.01", "--lr-angular-velocity", "0.01"];
    let with_rates = |extra: &[&'static str]| [&rate[..], extra].concat();
    let (off, _) = fit(dir.path(), "off", &["--motion", "off"]).unwrap();
    let (all, _) = fit(dir.path(), "all", &with_rates(&["--motion", "all"])).unwrap();
    assert_ne!(off, all, "--motion all changed nothing");
    for (extra, says) in [
        (
            with_rates(&["--motion", "off"]),
            "--lr-acceleration fits SPEC §9 motion, and --motion is off",
        ),
        (
            with_rates(&["--motion", "all", "--motion-after-splits", "2"]),
            "--motion-after-splits acts when --motion is auto",
        ),
        (
            vec![
                "--motion",
                "auto",
                "--lr-acceleration",
                "0",
                "--lr-angular-velocity",
                "0",
            ],
            "--motion gives kernels SPEC §9 motion, and both its rates",
        ),
        (
            vec!["--window", "16"],
            "--window 16 cuts only views of 1.5×16 pixels or more",
        ),
        (
            vec!["--blend", "additive", "--motion", "all"],
            "--motion acts on the alpha blend",
        ),
        (
            vec!["--blend", "additive", "--motion-after-splits", "1"],
            "--motion-after-splits acts on the alpha blend",
        ),
        (
            vec!["--blend", "additive", "--window", "off"],
            "--window acts on the alpha blend",
        ),
    ] {
        assert_refused(dir.path(), &extra, says);
    }
}
