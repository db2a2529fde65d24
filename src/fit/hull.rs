//! A start made from the images: a visual hull by
//! voting, for views whose background is one flat colour (renders over a colour, photos
//! with alpha composited over one, as D-NeRF ships them).
//!
//! The box the cameras look at is cut into a grid of `HULL_GRID³` cells. A cell centre `p`
//! is *seen* by a view when it projects in front of the camera into the image, on a pixel
//! that counts in the loss (weight > 0); it is *covered* there when that pixel differs from
//! the background by more than [`FOREGROUND_THRESHOLD`] in some channel. A cell is kept
//! when at least [`MIN_VIEWS`] views see it and at least [`HULL_VOTE`] of them cover it:
//! the strict hull (covered in every view) of a moving object keeps only what never moves,
//! a vote keeps what is there for much of the time. The kept cells' colour is the mean of
//! the covered pixels. A scene is started from them by [`crate::fit::alpha_start`]; the vote is
//! a start, not a model: the fit moves, prunes and densifies from there.
//!
//! Whether the background is flat is itself measured ([`flat_background`]): at least
//! [`FLAT_SHARE`] of the training images' border pixels within the threshold of the
//! background. Photos of a room are not, and start elsewhere.

use rayon::prelude::*;

use crate::fit::defaults::FOREGROUND_THRESHOLD;
use crate::fit::init::SpaceTimeBox;
use crate::model::{DatasetPoint, View};

/// Cells per side of the hull's grid.
pub const HULL_GRID: usize = 64;
/// Share of the views seeing a cell that must cover it.
pub const HULL_VOTE: f64 = 0.5;
/// Views that must see a cell for it to be judged.
pub const MIN_VIEWS: usize = 2;
/// Share of the border pixels that must be the background for it to count as flat.
pub const FLAT_SHARE: f64 = 0.9;

/// Whether `pixel` (RGB) differs from `background` by more than [`FOREGROUND_THRESHOLD`] in
/// some channel: the foreground test of the hull and of the start's colour
/// ([`crate::fit::plan::start_amplitude`]).
pub fn is_foreground(pixel: &[f32], background: [f32; 3]) -> bool {
    (0..3).any(|c| (pixel[c] - background[c]).abs() > FOREGROUND_THRESHOLD)
}

/// Whether the training images' border pixels are (at least [`FLAT_SHARE`] of them) the
/// background colour.
#[must_use]
pub fn flat_background(views: &[View], background: [f64; 3]) -> bool {
    let b = background.map(|v| v as f32);
    let (mut flat, mut all) = (0_u64, 0_u64);
    for pixel in views.iter().flat_map(|view| view.image.border_pixels()) {
        all += 1;
        flat += u64::from(!is_foreground(&pixel, b));
    }
    all > 0 && flat as f64 >= FLAT_SHARE * all as f64
}

/// The kept cells of the voting hull of `views` over `background` in `bounds`: their
/// centres and mean covered colours, in grid order (x fastest), and the cell's side per axis.
#[must_use]
pub fn visual_hull(
    views: &[View],
    background: [f64; 3],
    bounds: &SpaceTimeBox,
) -> (Vec<DatasetPoint>, [f64; 3]) {
    let b = background.map(|v| v as f32);
    let side: [f64; 3] =
        std::array::from_fn(|a| (bounds.max[a] - bounds.min[a]) / HULL_GRID as f64);
    let cells = HULL_GRID * HULL_GRID * HULL_GRID;
    let points = (0..cells)
        .into_par_iter()
        .filter_map(|cell| {
            let index = [
                cell % HULL_GRID,
                (cell / HULL_GRID) % HULL_GRID,
                cell / (HULL_GRID * HULL_GRID),
            ];
            let centre: [f64; 3] =
                std::array::from_fn(|a| bounds.min[a] + (index[a] as f64 + 0.5) * side[a]);
            vote(views, b, centre)
        })
        .collect();
    (points, side)
}

/// The vote of `views` on the cell centred at `centre`: its point when kept.
fn vote(views: &[View], background: [f32; 3], centre: [f64; 3]) -> Option<DatasetPoint> {
    let (mut seen, mut covered) = (0_usize, 0_usize);
    let mut colour = [0.0_f64; 3];
    for view in views {
        let [u, v, z] = view.camera.project_point(centre);
        let (w, h) = (view.image.width, view.image.height);
        if !(z > 0.0 && u >= 0.0 && v >= 0.0 && u < f64::from(w) && v < f64::from(h)) {
            continue;
        }
        let pixel = v as usize * w as usize + u as usize;
        if view.weights.as_ref().is_some_and(|w| w[pixel] <= 0.0) {
            continue;
        }
        seen += 1;
        let rgb = &view.image.pixels[3 * pixel..3 * pixel + 3];
        if is_foreground(rgb, background) {
            covered += 1;
            for (sum, &c) in colour.iter_mut().zip(rgb) {
                *sum += f64::from(c);
            }
        }
    }
    let kept = seen >= MIN_VIEWS && covered as f64 >= HULL_VOTE * seen as f64;
    kept.then(|| DatasetPoint {
        position: centre,
        colour: colour.map(|c| (c / covered as f64) as f32),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{Camera, Image};

    /// A white ball of radius 0.3 at the origin seen over black from six directions, as a
    /// silhouette (the pixels whose ray passes within 0.3 of the origin).
    fn ball_views() -> Vec<View> {
        let directions = [
            [3.0, 0.0, 0.0],
            [-3.0, 0.0, 0.0],
            [0.0, 3.0, 0.01],
            [0.0, -3.0, 0.01],
            [0.0, 0.0, 3.0],
            [0.0, 0.0, -3.0],
        ];
        directions
            .iter()
            .map(|&eye| {
                let camera = Camera::look_at(eye, [0.0; 3], [0.0, 1.0, 0.0], 40.0, 32, 32).unwrap();
                let mut image = Image::filled(32, 32, [0.0; 3]);
                for y in 0..32 {
                    for x in 0..32 {
                        // The ray through the pixel centre: nearest approach to the origin.
                        let near = camera.to_camera_space([0.0; 3]);
                        let ray = [
                            (x as f64 + 0.5 - camera.cx) / camera.fx,
                            (y as f64 + 0.5 - camera.cy) / camera.fy,
                            1.0,
                        ];
                        let len2: f64 = ray.iter().map(|r| r * r).sum();
                        let along: f64 =
                            ray.iter().zip(near).map(|(r, n)| r * n).sum::<f64>() / len2;
                        let gap2: f64 = (0..3).map(|a| (near[a] - along * ray[a]).powi(2)).sum();
                        if gap2 < 0.09 {
                            image.pixels[3 * (y * 32 + x)..][..3].copy_from_slice(&[1.0; 3]);
                        }
                    }
                }
                View {
                    camera,
                    time: 0.0,
                    image: std::sync::Arc::new(image),
                    name: "ball".into(),
                    weights: None,
                }
            })
            .collect()
    }

    #[test]
    fn the_hull_of_a_ball_holds_the_ball_and_little_else() {
        let views = ball_views();
        assert!(flat_background(&views, [0.0; 3]));
        assert!(!flat_background(&views, [0.5; 3]));
        let bounds = SpaceTimeBox {
            min: [-1.0; 3],
            max: [1.0; 3],
            time: [0.0, 1.0],
        };
        let (points, side) = visual_hull(&views, [0.0; 3], &bounds);
        let ball_cells = 4.0 / 3.0 * std::f64::consts::PI * 0.3_f64.powi(3) / side[0].powi(3);
        let radius = |p: &DatasetPoint| p.position.iter().map(|c| c * c).sum::<f64>().sqrt();
        let inside = points.iter().filter(|p| radius(p) < 0.3).count();
        // Every cell of the ball is kept; six silhouettes leave some cells beyond it
        // (corners of the cube they cut), none far.
        assert!(
            inside as f64 > 0.9 * ball_cells,
            "{inside} of {ball_cells:.0}"
        );
        assert!(
            points
                .iter()
                .all(|p| radius(p) < 0.3 * 3.0_f64.sqrt() + side[0])
        );
        assert!((points.len() as f64) < 2.0 * ball_cells, "{}", points.len());
        assert!(points.iter().all(|p| p.colour == [1.0; 3]));
    }
}
