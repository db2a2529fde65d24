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
use crate::simd::ExpMode;
use crate::volume::scene_sphere;

/// `splat4d bench`. Each setting is `None` (or empty, or `false`) where the caller left it
/// to the default; one given where the chosen measurement cannot use it is refused, naming
/// it ([`BenchRequest::check`]).
#[derive(Clone, Debug, PartialEq)]
pub struct BenchRequest {
    /// Built-in scenes by kernel count (`10k`, `1m`, `2500`) or scene files (default: `10k`
    /// and `100k`).
    pub scenes: Vec<String>,
    /// Camera file for scene files (default: a look-at camera framing the scene).
    pub camera: Option<PathBuf>,
    /// Frame size of the built-in scenes, and of scene files without `camera` (default:
    /// [`DEFAULT_SIZE`]).
    pub size: Option<(u32, u32)>,
    /// Worker threads (default: 1, and one per core).
    pub threads: Option<usize>,
    /// Timed frames per configuration (default: [`DEFAULT_FRAMES`]).
    pub frames: Option<usize>,
    /// Pixels sampled for the error (default: [`DEFAULT_SAMPLES`]).
    pub samples: Option<usize>,
    /// Scene time τ (default: [`DEFAULT_TIME`]).
    pub time: Option<f64>,
    /// Dilation, px² (default: [`DEFAULT_DILATION`]).
    pub dilation: Option<f64>,
    /// Cut-off ε (default: [`DEFAULT_CUTOFF`]).
    pub cutoff: Option<f64>,
    /// How the exp is evaluated (default: [`ExpMode::Poly`]).
    pub exp: Option<ExpMode>,
    /// Time the dense baseline: `Some(true)` always, `Some(false)` never, `None` when
    /// kernels × pixels ≤ 3·10⁹.
    pub dense: Option<bool>,
    /// Sweep speed against error on the one scene, writing `sweep.md` and `sweep.png`
    /// to `out`.
    pub sweep: bool,
    /// Only measure the ceiling probes of both blends ([`crate::bench::ceiling`]).
    pub ceiling: bool,
    /// Output folder of the sweep (default: [`DEFAULT_SWEEP_OUT`]).
    pub out: Option<PathBuf>,
    /// Blend of the built-in scenes (alpha: every kernel at opacity 0.5; default additive).
    pub blend: Option<Blend>,
}

/// Frame size of the built-in scenes unless one is given.
pub const DEFAULT_SIZE: (u32, u32) = (512, 512);
/// Timed frames per configuration unless a count is given.
pub const DEFAULT_FRAMES: usize = 10;
/// Pixels sampled for the error unless a count is given.
pub const DEFAULT_SAMPLES: usize = 400;
/// Scene time unless one is given.
pub const DEFAULT_TIME: f64 = 0.5;
/// Output folder of the sweep unless one is given.
pub const DEFAULT_SWEEP_OUT: &str = "out/bench";

impl BenchRequest {
    /// The rendering options.
    #[must_use]
    pub fn options(&self) -> RenderOptions {
        RenderOptions {
            dilation: self.dilation.unwrap_or(DEFAULT_DILATION),
            cutoff: self.cutoff.unwrap_or(DEFAULT_CUTOFF),
            exp: self.exp.unwrap_or(ExpMode::Poly),
        }
    }

    fn size(&self) -> (u32, u32) {
        self.size.unwrap_or(DEFAULT_SIZE)
    }

    fn time(&self) -> f64 {
        self.time.unwrap_or(DEFAULT_TIME)
    }

    fn samples(&self) -> usize {
        self.samples.unwrap_or(DEFAULT_SAMPLES)
    }

    fn out(&self) -> PathBuf {
        self.out
            .clone()
            .unwrap_or_else(|| PathBuf::from(DEFAULT_SWEEP_OUT))
    }

    /// The name of `dense` as given (`dense` or `no_dense`), if given.
    fn dense_field(&self) -> Option<&'static str> {
        self.dense.map(|on| if on { "dense" } else { "no_dense" })
    }

    /// The scenes measured: those asked for (the default ones when none is), the first
    /// alone for the sweep.
    fn scene_names(&self) -> Vec<String> {
        let mut names = if self.scenes.is_empty() {
            vec!["10k".to_owned(), "100k".to_owned()]
        } else {
            self.scenes.clone()
        };
        if self.sweep {
            names.truncate(1);
        }
        names
    }

    /// An error naming the first setting given that the measurement asked for cannot use,
    /// or `Ok`:
    /// - `ceiling` runs only the ceiling probes, on `threads`: every other setting;
    /// - `sweep` measures one scene over its own grid of dilations, cut-offs and exps, tiles
    ///   only: a second scene, the dense baseline's settings, `dilation`, `exp`, and
    ///   `cutoff` unless it frames a scene file without `camera`;
    /// - without `sweep`, `out`;
    /// - `camera` with only built-in scenes, `size` with only scene files seen through
    ///   `camera`, `blend` with no built-in scene.
    ///
    /// (The dense baseline's settings with only alpha scenes are refused once the scenes'
    /// blends are read.)
    pub fn check(&self) -> Result<()> {
        let refuse = |field: &'static str, why: &str| {
            Err(Error::setting(&[field], format!("`{field}` {why}")))
        };
        if self.ceiling {
            return match self.given().into_iter().find(|&f| f != "threads") {
                Some(field) => refuse(
                    field,
                    "has no effect with `ceiling`, which runs only the ceiling probes (on `threads`): drop `ceiling`, or leave it out",
                ),
                None => Ok(()),
            };
        }
        let names = self.scene_names();
        let builtin = names.iter().any(|n| is_builtin(n));
        let file = names.iter().any(|n| !is_builtin(n));
        if self.sweep {
            if self.scenes.len() > 1 {
                return refuse(
                    "scene",
                    &format!(
                        "names {} scenes, and `sweep` measures one: give one, or drop `sweep`",
                        self.scenes.len()
                    ),
                );
            }
            if let Some(field) = self.dense_field() {
                return refuse(
                    field,
                    "chooses whether the dense baseline runs, and `sweep` never times it: drop `sweep`, or leave it out",
                );
            }
            let frames_a_file = file && self.camera.is_none();
            let grid = [
                ("dilation", self.dilation.is_some()),
                ("exp", self.exp.is_some()),
                ("cutoff", self.cutoff.is_some() && !frames_a_file),
            ];
            if let Some(&(field, _)) = grid.iter().find(|(_, given)| *given) {
                return refuse(
                    field,
                    "has no effect with `sweep`, which measures its own grid of dilations, cut-offs and exps: drop `sweep`, or leave it out",
                );
            }
        } else if self.out.is_some() {
            return refuse(
                "out",
                "is where `sweep` writes its table and chart: add `sweep`, or leave it out",
            );
        }
        if self.camera.is_some() && !file {
            return refuse(
                "camera",
                "frames scene files, and every `scene` here is a built-in one, with its own camera: leave it out",
            );
        }
        if self.size.is_some() && self.camera.is_some() && !builtin {
            return refuse(
                "size",
                "sizes the built-in scenes and scene files without `camera`, and every `scene` here is a file seen through `camera`: leave it out",
            );
        }
        if self.blend.is_some() && !builtin {
            return refuse(
                "blend",
                "is the built-in scenes' blend, and every `scene` here is a file, which keeps its own: leave it out",
            );
        }
        Ok(())
    }

    /// The settings given, by name (`scene` for any scene named).
    fn given(&self) -> Vec<&'static str> {
        let given = [
            ("scene", !self.scenes.is_empty()),
            ("camera", self.camera.is_some()),
            ("size", self.size.is_some()),
            ("threads", self.threads.is_some()),
            ("frames", self.frames.is_some()),
            ("samples", self.samples.is_some()),
            ("time", self.time.is_some()),
            ("dilation", self.dilation.is_some()),
            ("cutoff", self.cutoff.is_some()),
            ("exp", self.exp.is_some()),
            ("sweep", self.sweep),
            ("out", self.out.is_some()),
            ("blend", self.blend.is_some()),
        ];
        let mut names: Vec<&'static str> = given
            .iter()
            .filter(|(_, on)| *on)
            .map(|(name, _)| *name)
            .collect();
        names.extend(self.dense_field());
        names
    }
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

/// Whether `name` names a built-in scene (a kernel count that is not a file).
fn is_builtin(name: &str) -> bool {
    !Path::new(name).exists() && builtin_scene_size(name).is_some()
}

/// The scenes `bench` measures: built-in ones by size, or files with their cameras.
fn bench_scenes(request: &BenchRequest) -> Result<Vec<(String, Scene, Camera)>> {
    let (w, h) = request.size();
    let blend = request.blend.unwrap_or_default();
    let mut scenes = Vec::new();
    for name in &request.scene_names() {
        let path = Path::new(name);
        if let (false, Some(n)) = (path.exists(), builtin_scene_size(name)) {
            let scene = match blend {
                Blend::Additive => bench_scene(n, 42),
                Blend::Alpha => {
                    bench_scene(n, 42).into_alpha(vec![BENCH_OPACITY; n], 0, Vec::new(), name)?
                }
            };
            scenes.push((
                match blend {
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
                let cutoff = request.options().cutoff;
                let (centre, r) =
                    scene_sphere(&scene, &[request.time()], cutoff).ok_or_else(|| {
                        Error::usage(format!(
                            "{}: no kernel is alive at t = {}",
                            path.display(),
                            request.time()
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

/// Measures the renderer as `request` asks: the ceiling probes alone, the sweep, or the
/// table of every scene on every thread count.
pub fn bench(request: &BenchRequest, progress: &mut dyn Progress) -> Result<BenchSummary> {
    request.check()?;
    request.options().validate()?;
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
        let threads = *threads.last().unwrap_or(&1);
        return run_sweep(request, threads, progress).map(|text| BenchSummary { text });
    }
    let scenes = bench_scenes(request)?;
    // The dense baseline sums (SPEC §5): it has no alpha counterpart.
    if let Some(field) = request.dense_field()
        && scenes.iter().all(|(_, s, _)| s.blend == Blend::Alpha)
    {
        return Err(Error::setting(
            &[field],
            format!(
                "`{field}` chooses whether the additive sum's dense baseline runs, and every scene here is alpha, which has none: leave it out"
            ),
        ));
    }
    table(request, &scenes, &threads, progress).map(|text| BenchSummary { text })
}

/// The timing settings of `request` on `threads`.
fn settings(request: &BenchRequest, threads: usize) -> BenchSettings {
    BenchSettings {
        tau: request.time(),
        options: request.options(),
        threads,
        frames: request.frames.unwrap_or(DEFAULT_FRAMES),
        samples: request.samples(),
    }
}

/// The sweep over [`SweepGrid::default`] on the scene of `request`, on `threads`; writes its
/// files and returns its table.
fn run_sweep(
    request: &BenchRequest,
    threads: usize,
    progress: &mut dyn Progress,
) -> Result<String> {
    // Before any work: the sweep's table and chart are none of the files read.
    let out = request.out();
    let mut outputs = crate::io::output::Outputs::new();
    for name in &request.scenes {
        outputs.input(Path::new(name));
    }
    if let Some(camera) = &request.camera {
        outputs.input(camera);
    }
    outputs
        .file(&out.join("sweep.md"))
        .file(&out.join("sweep.png"));
    outputs.check()?;
    let scenes = bench_scenes(request)?;
    let (name, scene, camera) = &scenes[0];
    let grid = SweepGrid::default();
    let count = grid.cutoffs.len() * grid.dilations.len() * grid.exps.len() * SWEEP_ROUNDS;
    let settings = settings(request, threads);
    progress.start("sweep", count);
    let points = sweep(scene, camera, &settings, &grid, || progress.tick())?;
    write_sweep(request, name, camera, settings.threads, &grid, &points)
}

/// Times every scene on every thread count (the tiles, and the dense baseline where it
/// runs), then the ceiling probes of the blends measured; returns the table.
fn table(
    request: &BenchRequest,
    scenes: &[(String, Scene, Camera)],
    threads: &[usize],
    progress: &mut dyn Progress,
) -> Result<String> {
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
    for (name, scene, camera) in scenes {
        for &t in threads {
            let renderers = [Renderer::Tiles, Renderer::Dense];
            let count = if dense_for(scene, camera) { 2 } else { 1 };
            for renderer in &renderers[..count] {
                rows.push(bench_render(
                    name,
                    scene,
                    camera,
                    &settings(request, t),
                    *renderer,
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
    let ceilings = ceilings(&probes, threads, progress)?;
    fill_efficiencies(&mut rows, &ceilings);
    Ok(format!(
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
        request.samples()
    ))
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
    let out = &request.out();
    std::fs::create_dir_all(out)
        .map_err(|e| Error::write(out, "cannot create the output folder", e))?;
    let table = sweep_table(points);
    let heading = format!(
        "# Speed against error: {name}, {}x{}, {threads} threads, τ = {}\n\n\
         Error: |render - exact| at {} seeded pixels, exact = f64 reference without truncation \
         (ε = 0) at the default dilation {DEFAULT_DILATION}. /bound: the implementation's error \
         against the f64 reference with the point's own options, as a ratio to \
         {ERROR_BOUND}. ★: on the Pareto front of (ms/frame, max error).\n\n",
        camera.width,
        camera.height,
        request.time(),
        request.samples()
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
