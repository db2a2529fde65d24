//! `report` (and `splat4d` alone): the seed paper's experiment, written as `report.md` with
//! its charts ([`crate::report`]).

use std::fmt;
use std::path::{Path, PathBuf};

use crate::io::image_file::save_rgb8_png;
use crate::io::scene_file::save_scene;
use crate::io::video::{VideoOptions, write_video};
use crate::io::write_bytes_atomically;
use crate::model::{Progress, Result};
use crate::report::experiment::{ExperimentConfig, ExperimentResults, run_experiment};
use crate::report::markdown::{Content, ReportFile, report_files};

/// What [`write_report`] wrote: the path of `report.md` and the results behind it.
#[derive(Clone, Debug)]
pub struct ReportSummary {
    /// `report.md`.
    pub path: PathBuf,
    /// Every number of the report.
    pub results: ExperimentResults,
}

impl fmt::Display for ReportSummary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "{:<16} {:>8} {:>8} {:>12} {:>12} {:>12} {:>11}",
            "method", "params", "fit s", "train", "held-out t", "held-out v+t", "roughness"
        )?;
        for m in &self.results.methods {
            let [a, b, t] = m.psnr_splits;
            writeln!(
                f,
                "{:<16} {:>8} {:>8.1} {a:>9.2} dB {b:>9.2} dB {t:>9.2} dB {:>11.2e}",
                m.method, m.parameters, m.fit_seconds, m.roughness
            )?;
        }
        writeln!(
            f,
            "{:<16} {:>8} {:>8} {:>12} {:>12} {:>12} {:>11.2e}",
            "ground truth", "", "", "", "", "", self.results.ground_truth_roughness
        )?;
        write!(
            f,
            "report: {} ({:.0} s)",
            self.path.display(),
            self.results.seconds
        )
    }
}

/// Runs the experiment of `config` and writes the report to `out`; `command` is the
/// command line that reproduces it, quoted in the report.
pub fn write_report(
    config: &ExperimentConfig,
    out: &Path,
    command: &str,
    progress: &mut dyn Progress,
) -> Result<ReportSummary> {
    let results = run_experiment(config, progress)?;
    for file in report_files(&results, command)? {
        write_file(out, &file)?;
    }
    Ok(ReportSummary {
        path: out.join("report.md"),
        results,
    })
}

/// Writes one of the report's files into `out`.
fn write_file(out: &Path, file: &ReportFile) -> Result<()> {
    let path = out.join(&file.name);
    match &file.content {
        Content::Markdown(text) => write_bytes_atomically(&path, text.as_bytes()),
        Content::Picture(p) => save_rgb8_png(&path, p.width, p.height, &p.rgb),
        Content::Scene(scene) => save_scene(scene, &path),
        Content::Animation { frames, fps } => {
            let options = VideoOptions {
                fps: *fps,
                gif: true,
                mp4: false,
            };
            write_video(frames.len(), out, &file.name, &options, |k, image| {
                image.clone_from(&frames[k]);
                Ok(())
            })?;
            Ok(())
        }
    }
}
