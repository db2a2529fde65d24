//! The fit's estimate of its time left (`splat4d::fit::time_left`), replayed over the
//! `--log` of a finished alpha fit with the default settings but those given: at 10, 15,
//! … 90 % of the run, the estimate against the time that was left, and the worst error.
//!
//! `cargo run --release -p splat4d-benches --example time_left -- LOG.jsonl WIDTHxHEIGHT
//! [--loss mse|l1-dssim] [--window N|off] [--max-growth G] [--prune-fraction F]
//! [--densify-every N] [--growth-target K] [--max-kernels M] [--sparse-photos]` (`G` the
//! growth a round the fit took, or with `--growth-target` the largest it could take; `K` the
//! kernels its budget grew towards: the note `kernel budget: growing towards K kernels … by
//! at most G % …` gives both; `M` the count growth stopped at, as the note `sparse views: …
//! growth stops at M kernels` gives it, and `--sparse-photos` the estimate such a fit makes,
//! `TimeLeft::for_sparse_photos`; photos take `--prune-fraction 0`; renders of an object
//! with the default 12 000 steps `--densify-every 200`)
//!
//! The run's steps are the log's; its coarse stages are read from the log's `downscale`
//! column; `WIDTHxHEIGHT` is the first training view's size at full size.

use splat4d::fit::coarse::SizeStage;
use splat4d::fit::defaults::{DEFAULT_ALPHA, DEFAULT_DSSIM_WEIGHT};
use splat4d::fit::density::{DensityRules, GrowthTarget};
use splat4d::fit::init::SpaceTimeBox;
use splat4d::fit::ssim::L1Dssim;
use splat4d::fit::time_left::{TimeLeft, replay};
use splat4d::fit::train::{StepRecord, TrainingLoss};

/// Every step record of a `fit --log` file.
fn records(path: &str) -> Vec<StepRecord> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{path}: {e}"));
    text.lines()
        .map(|line| {
            let r: serde_json::Value = serde_json::from_str(line).expect("a JSON line");
            StepRecord {
                step: r["step"].as_u64().expect("step") as usize,
                seconds: r["seconds"].as_f64().expect("seconds"),
                train_loss: 0.0,
                heldout_psnr: None,
                kernels: r["kernels"].as_u64().expect("kernels") as usize,
                pairs: r["pairs"].as_u64().unwrap_or(0),
                downscale: r["downscale"].as_u64().unwrap_or(1) as u32,
            }
        })
        .collect()
}

/// The coarse stages the records ran: each downscale above 1 until its last step.
fn stages(records: &[StepRecord]) -> Vec<SizeStage> {
    let mut stages: Vec<SizeStage> = Vec::new();
    for (i, record) in records.iter().enumerate() {
        if record.downscale < 2 {
            continue;
        }
        let until = (i + 1) as f64 / records.len() as f64;
        match stages.last_mut() {
            Some(stage) if stage.downscale == record.downscale => stage.until = until,
            _ => stages.push(SizeStage {
                downscale: record.downscale,
                until,
            }),
        }
    }
    stages
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [log, size, options @ ..] = &args[..] else {
        panic!(
            "usage: time_left LOG.jsonl WIDTHxHEIGHT [--loss mse|l1-dssim] [--window N|off] [--max-growth G] [--prune-fraction F] [--densify-every N] [--growth-target K] [--max-kernels M] [--sparse-photos]"
        );
    };
    let (width, height) = size.split_once('x').expect("WIDTHxHEIGHT");
    let view_size = [width.parse().unwrap(), height.parse().unwrap()];
    let mut options_of_fit = DEFAULT_ALPHA;
    let (mut max_growth, mut growth_target) = (None, None);
    let sparse_photos = options.iter().any(|option| option == "--sparse-photos");
    let options: Vec<&str> = options
        .iter()
        .map(String::as_str)
        .filter(|&option| option != "--sparse-photos")
        .collect();
    for pair in options.chunks(2) {
        match (pair[0], pair.get(1).copied()) {
            ("--loss", Some("mse")) => options_of_fit.loss = TrainingLoss::Mse,
            ("--loss", Some("l1-dssim")) => {
                options_of_fit.loss = TrainingLoss::L1Dssim(L1Dssim {
                    dssim_weight: DEFAULT_DSSIM_WEIGHT,
                });
            }
            ("--window", Some("off")) => options_of_fit.window = None,
            ("--window", Some(side)) => options_of_fit.window = Some(side.parse().unwrap()),
            ("--prune-fraction", Some(share)) => {
                options_of_fit.prune_fraction = share.parse().unwrap();
            }
            ("--max-growth", Some(share)) => max_growth = Some(share.parse().unwrap()),
            ("--growth-target", Some(kernels)) => growth_target = Some(kernels.parse().unwrap()),
            ("--max-kernels", Some(kernels)) => {
                options_of_fit.max_kernels = kernels.parse().unwrap();
            }
            ("--densify-every", Some(steps)) => {
                options_of_fit.densify_every = steps.parse().unwrap();
            }
            _ => panic!("unknown option {pair:?}"),
        }
    }
    let records = records(log);
    options_of_fit.steps = records.len();
    let bounds = SpaceTimeBox {
        min: [-1.0; 3],
        max: [1.0; 3],
        time: [0.0, 1.0],
    };
    if growth_target.is_none()
        && let Some(share) = max_growth
    {
        options_of_fit.densify_fraction = share;
    }
    let mut training = options_of_fit.training(&bounds);
    if let (Some(kernels), Some(DensityRules::Alpha(rules))) =
        (growth_target, &mut training.density)
    {
        rules.growth_target = Some(GrowthTarget {
            kernels,
            max_share: max_growth.unwrap_or(0.15),
        });
    }
    training.coarse = stages(&records);
    let fractions: Vec<f64> = (2..=18).map(|i| f64::from(i) * 0.05).collect();
    let estimate = TimeLeft::new(&training, view_size).for_sparse_photos(sparse_photos);
    let points = replay(estimate, &records, &fractions);
    // A straight line through the time so far, for comparison.
    let line_error = |steps: usize, truth: f64| {
        let so_far = records[steps - 1].seconds;
        so_far / steps as f64 * (records.len() - steps) as f64 / truth - 1.0
    };
    for point in &points {
        println!(
            "{:3.0} % step {:5}: {:7.1} s estimated, {:7.1} s left, {:+4.0} % (straight line {:+4.0} %)",
            100.0 * point.steps as f64 / records.len() as f64,
            point.steps,
            point.estimate,
            point.truth,
            100.0 * point.error(),
            100.0 * line_error(point.steps, point.truth)
        );
    }
    let errors: Vec<f64> = points.iter().map(|p| p.error()).collect();
    let lines: Vec<f64> = points
        .iter()
        .map(|p| line_error(p.steps, p.truth))
        .collect();
    let worst = errors
        .iter()
        .fold(0.0_f64, |w, &e| if e.abs() > w.abs() { e } else { w });
    println!(
        "from 10 %: {} (worst {:+.0} %), straight line {}; {} steps, {:.1} s",
        range(&errors),
        100.0 * worst,
        range(&lines),
        records.len(),
        records[records.len() - 1].seconds
    );
}

/// `"low % to high %"` of relative errors.
fn range(errors: &[f64]) -> String {
    let low = errors.iter().copied().fold(f64::INFINITY, f64::min);
    let high = errors.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    format!("{:+.0} % to {:+.0} %", 100.0 * low, 100.0 * high)
}
