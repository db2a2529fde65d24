//! `splat4d report` (and `splat4d` alone): the seed paper's experiment and its report.

use std::path::PathBuf;

use splat4d::Result;
use splat4d::report::experiment::ExperimentConfig;
use splat4d::tasks::report::write_report;

use super::args::parse_size;

#[derive(Debug, clap::Args)]
pub struct ReportArgs {
    /// Output folder for report.md and its charts.
    #[arg(long, default_value = "out")]
    out: PathBuf,
    /// A small, fast configuration (for smoke tests): fewer views, steps and kernels.
    #[arg(long)]
    quick: bool,
    /// Kernels of the 4D model (overrides the default or --quick).
    #[arg(long)]
    kernels: Option<usize>,
    /// Adam steps of the 4D model and of each ablation fit.
    #[arg(long)]
    steps: Option<usize>,
    /// Image size `WxH` of the dataset.
    #[arg(long, value_parser = parse_size)]
    size: Option<(u32, u32)>,
}

impl Default for ReportArgs {
    fn default() -> Self {
        ReportArgs {
            out: PathBuf::from("out"),
            quick: false,
            kernels: None,
            steps: None,
            size: None,
        }
    }
}

pub fn run(args: &ReportArgs) -> Result<()> {
    let mut config = if args.quick {
        ExperimentConfig::quick()
    } else {
        ExperimentConfig::default()
    };
    let mut command = format!("splat4d report --out {}", args.out.display());
    if args.quick {
        command.push_str(" --quick");
    }
    if let Some(n) = args.kernels {
        let most = splat4d::fit::plan::MAX_START_KERNELS;
        if !(1..=most).contains(&n) {
            return Err(splat4d::Error::usage(format!(
                "--kernels {n} must be from 1 to {most} (as fit's --init random:N)"
            )));
        }
        splat4d::io::memory::check(
            (n as u64).saturating_mul(splat4d::io::memory::FIT_BYTES_PER_KERNEL),
            &format!("fitting {n} kernels"),
        )?;
        config.model_kernels = n;
        command.push_str(&format!(" --kernels {n}"));
    }
    if let Some(n) = args.steps {
        config.model_steps = n;
        command.push_str(&format!(" --steps {n}"));
    }
    if let Some((w, h)) = args.size {
        // Checked before the experiment, not when its video is written at the end: the
        // video puts the truth and the three methods side by side, 2-pixel gaps between.
        let most = u64::from(splat4d::io::video::MAX_GIF_SIDE);
        let video_width = 4 * (u64::from(w) + 2) - 2;
        if video_width > most || u64::from(h) > most {
            return Err(splat4d::Error::usage(format!(
                "--size {w}x{h}: the report's video shows 4 views side by side ({video_width}×{h}), and a GIF holds at most {most} pixels a side; give a smaller --size"
            )));
        }
        splat4d::io::memory::check(
            (u64::from(w) * u64::from(h))
                .saturating_mul(splat4d::io::memory::RENDER_BYTES_PER_PIXEL),
            &format!("{w}×{h} views"),
        )?;
        (config.dataset.width, config.dataset.height) = (w, h);
        command.push_str(&format!(" --size {w}x{h}"));
    }
    super::with_progress(|bars| write_report(&config, &args.out, &command, bars))
}
