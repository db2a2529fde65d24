//! `volume`: the Eq. 1 sum on a 3D grid at several times, as slice figures and a table.

use std::fmt;
use std::path::PathBuf;
use std::time::Instant;

use crate::io::image_file::save_rgb8_png;
use crate::io::scene_file::load_scene;
use crate::model::Blend;
use crate::model::{Error, Result, check_non_negative_setting};
use crate::report::charts::volume_slices_figure;
use crate::tasks::with_threads;
use crate::volume::{Grid, evaluate_volume, scene_bounds};

/// `splat4d volume`.
#[derive(Clone, Debug, PartialEq)]
pub struct VolumeRequest {
    /// Scene file.
    pub scene: PathBuf,
    /// Grid cells per axis.
    pub res: usize,
    /// Times.
    pub times: Vec<f64>,
    /// Output folder for the slice images.
    pub out: PathBuf,
    /// Cut-off ε per kernel (SPEC §5 applied in 3D); 0 sums every kernel everywhere.
    pub cutoff: f64,
    /// Worker threads (`None`: one per core).
    pub threads: Option<usize>,
}

/// What [`write_volumes`] measured: the grid and `(τ, max, min, seconds)` per time.
#[derive(Clone, Debug, PartialEq)]
pub struct VolumeSummary {
    name: String,
    grid: Grid,
    /// What the grid holds: Eq. 1's intensity, or an alpha scene's opacity density.
    quantity: &'static str,
    /// `(τ, max, min, seconds)` per time.
    pub rows: Vec<(f64, f32, f32, f64)>,
}

impl fmt::Display for VolumeSummary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let (min, max) = (self.grid.min, self.grid.max);
        writeln!(
            f,
            "{}: {} on a {}³ grid over [{:.3}, {:.3}] × [{:.3}, {:.3}] × [{:.3}, {:.3}]",
            self.name, self.quantity, self.grid.res, min[0], max[0], min[1], max[1], min[2], max[2]
        )?;
        write!(f, "{:>8} {:>10} {:>10} {:>10}", "t", "max", "min", "ms")?;
        for (tau, hi, lo, seconds) in &self.rows {
            write!(
                f,
                "\n{tau:>8} {hi:>10.4} {lo:>10.4} {:>10.1}",
                1e3 * seconds
            )?;
        }
        Ok(())
    }
}

/// Evaluates the volume at every time and writes slices through each one's peak.
pub fn write_volumes(request: &VolumeRequest) -> Result<VolumeSummary> {
    check_non_negative_setting("cutoff", request.cutoff)?;
    let scene = load_scene(&request.scene)?;
    let (min, max) = scene_bounds(&scene, &request.times, request.cutoff).ok_or_else(|| {
        Error::usage(format!(
            "{}: no kernel is alive at the requested times",
            request.scene.display()
        ))
    })?;
    let grid = Grid {
        min,
        max,
        res: request.res,
    };
    let name = request
        .scene
        .file_stem()
        .map_or("scene".into(), |s| s.to_string_lossy().into_owned());
    // Times that round to one label get distinct files; none may be an input.
    let files = crate::io::output::unique_names(
        &request
            .times
            .iter()
            .map(|tau| {
                crate::io::output::sanitize_label(
                    &format!("{name}_volume_t{}", crate::io::output::time_label(*tau)),
                    "volume",
                )
            })
            .collect::<Vec<_>>(),
    );
    let mut outputs = crate::io::output::Outputs::new();
    outputs.input(&request.scene);
    for file in &files {
        outputs.file(&request.out.join(format!("{file}.png")));
    }
    outputs.check()?;
    let mut volumes = Vec::new();
    for &tau in &request.times {
        let start = Instant::now();
        let volume = with_threads(request.threads, || {
            evaluate_volume(&scene, tau, &grid, request.cutoff)
        })?;
        if !volume.values.iter().all(|v| v.is_finite()) {
            return Err(Error::Numeric(format!(
                "{}: the volume at t = {tau} is not finite in f32 (amplitudes or scales too extreme to evaluate)",
                request.scene.display()
            )));
        }
        volumes.push((tau, volume, start.elapsed().as_secs_f64()));
    }
    let vmax = volumes
        .iter()
        .map(|(_, v, _)| v.range().0)
        .fold(0.0, f32::max);
    let mut rows = Vec::new();
    for ((tau, volume, seconds), file) in volumes.iter().zip(&files) {
        let path = request.out.join(format!("{file}.png"));
        let file = format!("{file}.png");
        let figure = volume_slices_figure(&file, &name, *tau, volume, vmax)?;
        save_rgb8_png(&path, figure.width, figure.height, &figure.rgb)?;
        let (hi, lo) = volume.range();
        rows.push((*tau, hi, lo, *seconds));
    }
    let quantity = match scene.blend {
        Blend::Additive => "intensity (Eq. 1, mean of the channels)",
        Blend::Alpha => "opacity density Σ o(τ) G (alpha blend)",
    };
    Ok(VolumeSummary {
        name,
        grid,
        quantity,
        rows,
    })
}
