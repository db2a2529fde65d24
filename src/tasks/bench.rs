//! `bench`: forward-render speed with the error against the f64 reference, per scene and
//! thread count, or a sweep of speed against error over the cut-off, dilation and exp.

use std::fmt;
use std::path::{Path, PathBuf};

use crate::bench::{
    BenchSettings, Ceiling, Probe, Renderer, SWEEP_ROUNDS, SweepGrid, SweepPoint, bench_render,
    ceiling_lines, fill_efficiencies, fill_speedups, format_table, measure_ceiling, sweep,
    sweep_table,
};
use crate::io::camera_file::load_camera;
use crate::io::image_file::save_rgb8_png;
use crate::io::scene_file::load_scene;
use crate::io::write_bytes_atomically;
use crate::model::{Blend, Camera, Error, Progress, Result, Scene};
use crate::reference::ERROR_BOUND;
use crate::render::{DEFAULT_CUTOFF, DEFAULT_DILATION, RenderOptions};
use crate::report::charts::{TradeOffPoint, pareto_chart};
use crate::scenes::paths::{Lens, framing_distance};
use crate::scenes::synthetic::{bench_camera, bench_scene};
use crate::volume::scene_sphere;

/// `splat4d bench`.
#[derive(Clone, Debug, PartialEq)]
pub struct BenchRequest {
    /// Built-in scenes by kernel count (`10k`, `1m`, `2500`) or scene files (default: `10k`
    /// and `100k`).
    pub scenes: Vec<String>,
    /// Camera file for scene files (default: a look-at camera framing the scene).
    pub camera: Option<PathBuf>,
    /// Frame size (ignored with `camera`).
    pub size: (u32, u32),
    /// Worker threads (default: 1, and one per core).
    pub threads: Option<usize>,
    /// Timed frames per configuration.
    pub frames: usize,
    /// Pixels sampled for the error.
    pub samples: usize,
    /// Scene time τ.
    pub time: f64,
    /// Rendering options.
    pub options: RenderOptions,
    /// Time the dense baseline: `Some(true)` always, `Some(false)` never, `None` when
    /// kernels × pixels ≤ 3·10⁹.
    pub dense: Option<bool>,
    /// Sweep speed against error on the first scene, writing `sweep.md` and `sweep.png`
    /// to `out`.
    pub sweep: bool,
    /// Only measure the ceiling probes of both blends ([`crate::bench::ceiling`]).
    pub ceiling: bool,
    /// Output folder of the sweep.
    pub out: PathBuf,
    /// Blend of the built-in scenes (alpha: every kernel at opacity 0.5).
    pub blend: Blend,
}

/// Opacity of the built-in scenes' kernels with the alpha blend.
pub const BENCH_OPACITY: f64 = 0.5;

/// What [`bench()`] measured: a table, or the sweep's table and files.
#[derive(Clone, Debug, PartialEq)]
pub struct BenchSummary {
    text: String,
}

impl fmt::Display for BenchSummary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.text)
    }
}

/// A bench scene named by its kernel count (`10k`, `1m`, `2500`), if `text` is one.
fn builtin_scene_size(text: &str) -> Option<usize> {
    let lower = text.to_ascii_lowercase();
    let (digits, unit) = match lower.strip_suffix('k') {
        Some(d) => (d, 1_000),
        None => match lower.strip_suffix('m') {
            Some(d) => (d, 1_000_000),
            None => (lower.as_str(), 1),
        },
    };
    digits
        .parse::<usize>()
        .ok()
        .and_then(|n| n.checked_mul(unit))
        .filter(|&n| n > 0)
}

/// The scenes `bench` measures: built-in ones by size, or files with their cameras.
fn bench_scenes(request: &BenchRequest) -> Result<Vec<(String, Scene, Camera)>> {
    let (w, h) = request.size;
    let names = if request.scenes.is_empty() {
        vec!["10k".to_owned(), "100k".to_owned()]
    } else {
        request.scenes.clone()
    };
    let mut scenes = Vec::new();
    for name in &names {
        let path = Path::new(name);
        if let (false, Some(n)) = (path.exists(), builtin_scene_size(name)) {
            let scene = match request.blend {
                Blend::Additive => bench_scene(n, 42),
                Blend::Alpha => {
                    bench_scene(n, 42).into_alpha(vec![BENCH_OPACITY; n], 0, Vec::new(), name)?
                }
            };
            scenes.push((
                match request.blend {
                    Blend::Additive => format!("bench-{}", name.to_ascii_lowercase()),
                    Blend::Alpha => format!("bench-{}-alpha", name.to_ascii_lowercase()),
                },
                scene,
                bench_camera(w, h),
            ));
            continue;
        }
        let scene = load_scene(path)?;
        let camera = match &request.camera {
            Some(c) => load_camera(c)?,
            None => {
                let cutoff = request.options.cutoff;
                let (centre, r) =
                    scene_sphere(&scene, &[request.time], cutoff).ok_or_else(|| {
                        Error::usage(format!(
                            "{}: no kernel is alive at t = {}",
                            path.display(),
                            request.time
                        ))
                    })?;
                let lens = Lens {
                    width: w,
                    height: h,
                    fov_y_degrees: 40.0,
                };
                let distance = framing_distance(r, &lens);
                let eye = [
                    centre[0] + 0.6 * distance,
                    centre[1] + 0.35 * distance,
                    centre[2] + 0.72 * distance,
                ];
                Camera::look_at(eye, centre, [0.0, 1.0, 0.0], lens.fov_y_degrees, w, h)?
            }
        };
        let file_name = path
            .file_name()
            .map_or("scene".into(), |n| n.to_string_lossy().into_owned());
        scenes.push((file_name, scene, camera));
    }
    Ok(scenes)
}

/// Each of `probes` on each of `threads`, in that order.
fn ceilings(
    probes: &[Probe],
    threads: &[usize],
    progress: &mut dyn Progress,
) -> Result<Vec<Ceiling>> {
    progress.start("ceiling", probes.len() * threads.len());
    let mut ceilings = Vec::new();
    for &probe in probes {
        for &t in threads {
            ceilings.push(Ceiling {
                probe,
                threads: t,
                pairs_per_second: measure_ceiling(probe, t)?,
            });
            progress.tick();
        }
    }
    Ok(ceilings)
}

/// Measures the renderer as `request` asks.
pub fn bench(request: &BenchRequest, progress: &mut dyn Progress) -> Result<BenchSummary> {
    request.options.validate()?;
    let cores = std::thread::available_parallelism().map_or(1, usize::from);
    let threads: Vec<usize> = match request.threads {
        Some(n) => vec![n],
        None if cores > 1 => vec![1, cores],
        None => vec![1],
    };
    if request.ceiling {
        let ceilings = ceilings(&Probe::ALL, &threads, progress)?;
        return Ok(BenchSummary {
            text: ceiling_lines(&ceilings),
        });
    }
    if request.sweep {
        // Before any work: the sweep's table and chart are none of the files read.
        let mut outputs = crate::io::output::Outputs::new();
        for name in &request.scenes {
            outputs.input(Path::new(name));
        }
        if let Some(camera) = &request.camera {
            outputs.input(camera);
        }
        outputs
            .file(&request.out.join("sweep.md"))
            .file(&request.out.join("sweep.png"));
        outputs.check()?;
    }
    let scenes = bench_scenes(request)?;
    let settings = |threads: usize| BenchSettings {
        tau: request.time,
        options: request.options,
        threads,
        frames: request.frames,
        samples: request.samples,
    };
    if request.sweep {
        let (name, scene, camera) = &scenes[0];
        let grid = SweepGrid::default();
        let count = grid.cutoffs.len() * grid.dilations.len() * grid.exps.len() * SWEEP_ROUNDS;
        let settings = settings(*threads.last().unwrap_or(&1));
        progress.start("sweep", count);
        let points = sweep(scene, camera, &settings, &grid, || progress.tick())?;
        let text = write_sweep(request, name, camera, settings.threads, &grid, &points)?;
        return Ok(BenchSummary { text });
    }
    // The dense baseline sums (SPEC §5): it has no alpha counterpart.
    let dense_for = |scene: &Scene, camera: &Camera| {
        scene.blend == Blend::Additive
            && request.dense.unwrap_or_else(|| {
                scene.len() as f64 * f64::from(camera.width) * f64::from(camera.height) <= 3e9
            })
    };
    let jobs: usize = scenes
        .iter()
        .map(|(_, s, c)| threads.len() * if dense_for(s, c) { 2 } else { 1 })
        .sum();
    progress.start("bench", jobs);
    let mut rows = Vec::new();
    for (name, scene, camera) in &scenes {
        for &t in &threads {
            rows.push(bench_render(
                name,
                scene,
                camera,
                &settings(t),
                Renderer::Tiles,
            )?);
            progress.tick();
            if dense_for(scene, camera) {
                rows.push(bench_render(
                    name,
                    scene,
                    camera,
                    &settings(t),
                    Renderer::Dense,
                )?);
                progress.tick();
            }
        }
    }
    fill_speedups(&mut rows);
    // Each row against its own blend's probe: only the probes of the blends measured.
    let probes: Vec<Probe> = Probe::ALL
        .into_iter()
        .filter(|&p| scenes.iter().any(|(_, s, _)| Probe::of(s.blend) == p))
        .collect();
    let ceilings = ceilings(&probes, &threads, progress)?;
    fill_efficiencies(&mut rows, &ceilings);
    let text = format!(
        "{}\n{}\nColumns: ceiling = pairs/s over the {} on the same threads in this run; \
         max-err, mean-err = |render - f64 reference| at {} seeded pixels; /bound = largest ratio \
         to {ERROR_BOUND}; speed-up = dense ms / tiles ms.",
        format_table(&rows).trim_end(),
        ceiling_lines(&ceilings),
        match probes[..] {
            [Probe::Alpha] => "alpha ceiling probe's",
            [Probe::Additive, Probe::Alpha] => {
                "ceiling probe's of the row's blend (additive or alpha)"
            }
            _ => "ceiling probe's",
        },
        request.samples
    );
    Ok(BenchSummary { text })
}

/// Writes the sweep's table (sweep.md) and chart (sweep.png) to `request.out`; returns the
/// table and the names of the files.
fn write_sweep(
    request: &BenchRequest,
    name: &str,
    camera: &Camera,
    threads: usize,
    grid: &SweepGrid,
    points: &[SweepPoint],
) -> Result<String> {
    let out = &request.out;
    std::fs::create_dir_all(out)
        .map_err(|e| Error::write(out, "cannot create the output folder", e))?;
    let table = sweep_table(points);
    let heading = format!(
        "# Speed against error: {name}, {}x{}, {threads} threads, τ = {}\n\n\
         Error: |render - exact| at {} seeded pixels, exact = f64 reference without truncation \
         (ε = 0) at the default dilation {DEFAULT_DILATION}. /bound: the implementation's error \
         against the f64 reference with the point's own options, as a ratio to \
         {ERROR_BOUND}. ★: on the Pareto front of (ms/frame, max error).\n\n",
        camera.width, camera.height, request.time, request.samples
    );
    write_bytes_atomically(
        &out.join("sweep.md"),
        format!("{heading}{table}").as_bytes(),
    )?;
    let series: Vec<String> = grid
        .dilations
        .iter()
        .flat_map(|d| {
            grid.exps
                .iter()
                .map(move |e| format!("dilation {d}, exp {e}"))
        })
        .collect();
    let chart_points: Vec<TradeOffPoint> = points
        .iter()
        .map(|p| {
            let d = grid
                .dilations
                .iter()
                .position(|&d| d == p.options.dilation)
                .unwrap_or(0);
            let e = grid
                .exps
                .iter()
                .position(|&e| e == p.options.exp)
                .unwrap_or(0);
            TradeOffPoint {
                label: format!(
                    "ε {}, s {}, {}",
                    if p.options.cutoff == DEFAULT_CUTOFF {
                        "1/255".to_owned()
                    } else {
                        format!("{:.0e}", p.options.cutoff)
                    },
                    p.options.dilation,
                    p.options.exp
                ),
                cost: p.ms_per_frame,
                error: p.model_error,
                series: d * grid.exps.len() + e,
                front: p.pareto,
            }
        })
        .collect();
    let chart = out.join("sweep.png");
    let picture = pareto_chart(
        "sweep.png",
        &format!(
            "Speed against error: {name}, {}x{}, {threads} threads",
            camera.width, camera.height
        ),
        ("ms per frame", "max |render - exact| (log scale)"),
        &series,
        &chart_points,
    )?;
    save_rgb8_png(&chart, picture.width, picture.height, &picture.rgb)?;
    Ok(format!(
        "{}\nwrote {} and {}",
        table.trim_end(),
        out.join("sweep.md").display(),
        chart.display()
    ))
}
