//! The command line: clap flags → a task's request → one call into
//! [`splat4d::tasks`] → its summary printed. One file per subcommand; no defaults or
//! automatic choices live here (the fit's are in `splat4d::fit::plan`).

pub mod allocator;
mod args;
mod bench;
#[cfg(test)]
mod commands_reference;
mod dataset;
mod export_ply;
mod fit;
pub mod flags;
mod grad;
mod import_gltf;
#[cfg(feature = "mpi")]
pub mod mpi;
mod progress;
mod render;
mod report;
mod toy;
mod video;
mod view;
mod volume;

use clap::{Parser, Subcommand};

/// Prints a task's summary to stdout. A closed stdout (`splat4d … | head`) is not an
/// error: the work is done and written, only the summary has no reader.
fn print(summary: impl std::fmt::Display) {
    use std::io::Write as _;
    let _ = writeln!(std::io::stdout().lock(), "{summary}");
}

/// Runs a long task with progress on stderr ([`progress::Bars`]), then prints its summary.
fn with_progress<S: std::fmt::Display>(
    task: impl FnOnce(&mut progress::Bars) -> splat4d::Result<S>,
) -> splat4d::Result<()> {
    let mut bars = progress::Bars::new();
    let summary = task(&mut bars)?;
    bars.finish();
    print(summary);
    Ok(())
}

/// splat4d: render and fit dynamic scenes of 4D Gaussian kernels on the CPU.
///
/// Without a subcommand, runs the seed paper's experiment and writes `out/report.md`.
#[derive(Debug, Parser)]
#[command(name = "splat4d", version = env!("SPLAT4D_VERSION"), about, long_about = None)]
pub struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
    /// Refuse work estimated to need more memory than this (e.g. 8G, 512MiB); the machine's
    /// available memory is always a bound.
    #[arg(long, global = true, value_parser = splat4d::io::memory::parse_bytes)]
    max_memory: Option<u64>,
}

// `defer`: each subcommand's flags are defined only when it is used (`splat4d --version`
// 1.6–1.7 → 1.2–1.3 ms). `cli::flags` defines the one it names flags of when it needs them.
#[derive(Debug, Subcommand)]
#[command(defer = true)]
enum Command {
    /// Render a scene through a camera at one time into a PNG or EXR image.
    Render(render::RenderArgs),
    /// The MSE of a render against a target image, and its gradient per kernel, as JSON.
    Grad(grad::GradArgs),
    /// Render a multi-view dataset (D-NeRF / Blender layout) of a scene.
    Dataset(dataset::DatasetArgs),
    /// Fit kernels to a multi-view dataset with Adam.
    Fit(Box<fit::FitArgs>),
    /// Write the seed paper's toy scene: its point data, or the continuous blob.
    Toy(toy::ToyArgs),
    /// Evaluate the Eq. 1 sum on a 3D grid; write slices through its peak and print max/min per time.
    Volume(volume::VolumeArgs),
    /// Sample a glTF 2.0 model (.gltf or .glb) and its node animation into 4D kernels.
    ImportGltf(import_gltf::ImportGltfArgs),
    /// Write the 3D Gaussian Splatting PLY of a scene's slice at one time, for splat viewers.
    ExportPly(export_ply::ExportPlyArgs),
    /// Render videos along camera paths: orbits at fixed times, a spiral, or a path file.
    Video(video::VideoArgs),
    /// Look at a scene in a web browser: orbit, scrub time, compare with a dataset's views,
    /// place camera paths.
    View(view::ViewArgs),
    /// Measure forward-render speed, with the error against the f64 reference.
    Bench(bench::BenchArgs),
    /// Run the seed paper's experiment (toy data → dataset → fits → baselines → ablation →
    /// volumes) and write `report.md` with its charts.
    Report(report::ReportArgs),
}

/// Runs the parsed command line.
pub fn run(cli: Cli) -> splat4d::Result<()> {
    if let Some(bytes) = cli.max_memory {
        splat4d::io::memory::set_limit(bytes);
    }
    if splat4d::fit::spread::ranks().is_some() && !matches!(cli.command, Some(Command::Fit(_))) {
        return Err(splat4d::Error::usage(
            "only `splat4d fit` is spread over MPI ranks: run other commands as one process (renders share their frames with `--shard I/N` and `--assemble`)",
        ));
    }
    match cli.command {
        None => report::run(&report::ReportArgs::default()),
        Some(Command::Render(args)) => render::run(&args),
        Some(Command::Grad(args)) => grad::run(&args),
        Some(Command::Dataset(args)) => dataset::run(&args),
        Some(Command::Fit(args)) => fit::run(&args),
        Some(Command::Toy(args)) => toy::run(&args),
        Some(Command::Volume(args)) => volume::run(&args),
        Some(Command::Report(args)) => report::run(&args),
        Some(Command::Video(args)) => video::run(&args),
        Some(Command::Bench(args)) => bench::run(&args),
        Some(Command::View(args)) => view::run(&args),
        Some(Command::ExportPly(args)) => export_ply::run(&args),
        Some(Command::ImportGltf(args)) => import_gltf::run(&args),
    }
}

#[cfg(test)]
mod tests {
    /// A flag left out is `None` to the library, which holds its default; the help states
    /// that default as `[default: …]`, and it is the library's.
    #[test]
    fn defaults_the_help_states_are_the_librarys() {
        use splat4d::tasks::{bench, scene_files, video};
        let cases = [
            (
                "toy",
                "seed",
                splat4d::scenes::toy::DEFAULT_SEED.to_string(),
            ),
            (
                "import-gltf",
                "tolerance",
                scene_files::DEFAULT_TOLERANCE.to_string(),
            ),
            ("render", "bit-depth", "8".to_owned()),
            (
                "video",
                "size",
                format!("{}x{}", video::DEFAULT_SIZE.0, video::DEFAULT_SIZE.1),
            ),
            ("video", "fov", video::DEFAULT_FOV.to_string()),
            (
                "bench",
                "size",
                format!("{}x{}", bench::DEFAULT_SIZE.0, bench::DEFAULT_SIZE.1),
            ),
            ("bench", "frames", bench::DEFAULT_FRAMES.to_string()),
            ("bench", "samples", bench::DEFAULT_SAMPLES.to_string()),
            ("bench", "time", bench::DEFAULT_TIME.to_string()),
            (
                "bench",
                "dilation",
                splat4d::render::DEFAULT_DILATION.to_string(),
            ),
            (
                "bench",
                "cutoff",
                splat4d::render::DEFAULT_CUTOFF.to_string(),
            ),
            ("bench", "exp", splat4d::simd::ExpMode::Poly.to_string()),
            ("bench", "out", bench::DEFAULT_SWEEP_OUT.to_owned()),
            ("bench", "blend", splat4d::Blend::default().to_string()),
        ];
        assert_eq!(
            splat4d::io::image_file::BitDepth::default(),
            splat4d::io::image_file::BitDepth::Eight
        );
        let command = <super::Cli as clap::CommandFactory>::command();
        for (name, flag, value) in cases {
            let mut sub = command.find_subcommand(name).unwrap().clone();
            sub.build();
            let arg = sub
                .get_arguments()
                .find(|a| a.get_long() == Some(flag))
                .unwrap();
            let help = arg.get_help().unwrap().to_string();
            assert!(
                help.contains(&format!("[default: {value}]")),
                "{name} --{flag}: {help}"
            );
        }
    }
}
