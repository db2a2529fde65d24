//! `report` (and `splat4d` alone): the seed paper's experiment, written as `report.md` with
//! its charts ([`crate::report`]).

use std::fmt;
use std::path::{Path, PathBuf};

use crate::io::image_file::save_rgb8_png;
use crate::io::output::{Staging, check_beside, check_replaceable};
use crate::io::scene_file::save_scene;
use crate::io::video::{VideoOptions, write_video};
use crate::io::write_bytes_atomically;
use crate::model::{Error, Progress, Result};
use crate::report::experiment::{ExperimentConfig, ExperimentResults, run_experiment};
use crate::report::markdown::{ANIMATION, Content, ReportFile, report_files, report_names};

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

/// Checks, before the experiment, that the report may be written into `out`: no name it
/// writes ([`report_names`]) is a folder, except the animation's frame folder, which must be
/// an earlier video's (or absent); an existing GIF of the animation must be the one that video
/// recorded ([`check_beside`]). Other files of those names are replaced, as any file an
/// output names.
fn check_report_out(config: &ExperimentConfig, out: &Path) -> Result<()> {
    let frames = out.join(ANIMATION);
    for name in report_names(config) {
        let path = out.join(&name);
        if name == ANIMATION {
            check_replaceable(&path, "video")?;
        } else if name == format!("{ANIMATION}.gif") {
            check_beside(&frames, &path, "video")?;
        } else if std::fs::symlink_metadata(&path).is_ok_and(|m| m.is_dir()) {
            return Err(Error::usage(format!(
                "{}: is a folder, and the report writes a file of that name; name another folder for the report, or move that one away yourself",
                path.display()
            )));
        }
    }
    Ok(())
}

/// Runs the experiment of `config` and writes the report to `out`; `command` is the
/// command line that reproduces it, quoted in the report.
///
/// The folder is checked before the experiment (`check_report_out`), and the report is
/// written into a temporary folder inside it, moved into place whole at the end
/// (`report.md` last): a run that fails — a full disk, a kill — leaves nothing but what was
/// there.
pub fn write_report(
    config: &ExperimentConfig,
    out: &Path,
    command: &str,
    progress: &mut dyn Progress,
) -> Result<ReportSummary> {
    check_report_out(config, out)?;
    let staging = Staging::new(out)?;
    let results = run_experiment(config, progress)?;
    for file in report_files(&results, command)? {
        write_file(staging.path(), out, &file)?;
    }
    staging.commit(&["report.md"])?;
    Ok(ReportSummary {
        path: out.join("report.md"),
        results,
    })
}

/// Writes one of the report's files into the staging folder `dir` of the report's folder
/// `out`.
fn write_file(dir: &Path, out: &Path, file: &ReportFile) -> Result<()> {
    let path = dir.join(&file.name);
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
            write_video(
                frames.len(),
                dir,
                out,
                &file.name,
                &options,
                &[],
                |k, image| {
                    image.clone_from(&frames[k]);
                    Ok(())
                },
            )?;
            Ok(())
        }
    }
}
