//! Windows: a fit's steps on one window of each drawn view instead of the whole view
//! (SPEC §3, §6).
//!
//! A step's cost grows with the pixels it renders, and late in a fit, at full size, most of
//! a step is the per-pixel compositing and its backward. With a window side `s`, a view of
//! `W × H` pixels is cut into a grid of `c × r` windows of (nearly) equal size, `c =
//! max(1, round(W/s))` and `r = max(1, round(H/s))` (so a window's sides lie between about
//! ⅔ s and 1.5 s) — the column edges at `⌊i W / c⌋`, the rows' likewise — and each time the
//! view is drawn one window of the grid is drawn, uniformly and seeded. Pixel `(i, j)` of the window is pixel
//! `(left + i, top + j)` of the view, the same ray: the window's camera is the view's with
//! its principal point moved by `(-left, -top)` ([`View::cropped`]), so every pixel the step
//! renders has the value it has in the whole view.
//!
//! The step's loss is each window's mean (SPEC §6). Every pixel of a view lies in exactly
//! one window of its grid and the windows are drawn with equal probability, so over the
//! draws each pixel weighs `1 / (cells × |window|)`: the whole view's mean where the windows
//! are of equal size (within a pixel of each other otherwise). A view smaller than 1.5 s on
//! either side is its own single window. Coarse stages ([`crate::fit::coarse`]) apply first:
//! a ½-size view of 200 pixels is whole under `s = 200`.

use crate::model::View;
use crate::model::random::seeded_rng;
use rand::RngExt;
use rand_chacha::ChaCha8Rng;

/// Draws one window of each view a step draws, and holds the windows while the step runs.
pub struct Windows {
    side: u32,
    rng: ChaCha8Rng,
    views: Vec<View>,
    positions: Vec<usize>,
}

impl Windows {
    /// Windows of about `side × side` pixels (`side ≥ 1`), drawn with the seed `seed`.
    #[must_use]
    pub fn new(side: u32, seed: u64) -> Self {
        Windows {
            side: side.max(1),
            rng: seeded_rng(seed),
            views: Vec::new(),
            positions: Vec::new(),
        }
    }

    /// One window of each of the views `drawn` (indices into `train`), drawn in the order
    /// of `drawn`, and their indices into the slice returned (`0, 1, …`).
    pub fn draw(&mut self, train: &[View], drawn: &[usize]) -> (&[View], &[usize]) {
        self.views.clear();
        for &v in drawn {
            let view = &train[v];
            let [left, top, width, height] = self.drawn_cell(view.image.width, view.image.height);
            let window = view
                .cropped(left, top, width, height)
                .expect("a grid cell lies inside its view");
            self.views.push(window);
        }
        self.positions.clear();
        self.positions.extend(0..drawn.len());
        (&self.views, &self.positions)
    }

    /// A cell of the grid of a `width × height` view, drawn uniformly: `[left, top, width,
    /// height]`.
    fn drawn_cell(&mut self, width: u32, height: u32) -> [u32; 4] {
        let [columns, rows] = grid(self.side, width, height);
        let cell = self.rng.random_range(0..columns * rows);
        let (column, row) = (cell % columns, cell / columns);
        let [left, right] = [column, column + 1].map(|i| grid_edge(i, width, columns));
        let [top, bottom] = [row, row + 1].map(|i| grid_edge(i, height, rows));
        [left, top, right - left, bottom - top]
    }
}

/// The columns and rows of the grid of windows of side about `side` that cut a `width ×
/// height` view: `max(1, round(width / side))`, the rows likewise.
fn grid(side: u32, width: u32, height: u32) -> [u32; 2] {
    let side = side.max(1);
    [width, height].map(|length| ((length + side / 2) / side).max(1))
}

/// The grid of windows of side `side` with the most cells over `views`, and the
/// `[width, height]` of the view it cuts; `None` without views. It has one cell when every
/// view stays whole.
#[must_use]
pub fn finest_grid(side: u32, views: &[View]) -> Option<([u32; 2], [u32; 2])> {
    views
        .iter()
        .map(|v| {
            let size = [v.camera.width, v.camera.height];
            (grid(side, size[0], size[1]), size)
        })
        .max_by_key(|([columns, rows], _)| u64::from(*columns) * u64::from(*rows))
}

/// The `i`-th of the `cells + 1` edges cutting `length` pixels into `cells` nearly equal
/// parts: `⌊i length / cells⌋`.
fn grid_edge(i: u32, length: u32, cells: u32) -> u32 {
    (u64::from(i) * u64::from(length) / u64::from(cells)) as u32
}

/// The fraction of a `width × height` view's pixels that a window of side `side` (`None`:
/// the whole view) renders, as drawn on average: one cell of its grid.
#[must_use]
pub fn pixel_fraction(side: Option<u32>, width: u32, height: u32) -> f64 {
    side.map_or(1.0, |side| {
        let [columns, rows] = grid(side, width, height);
        1.0 / f64::from(columns * rows)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_grid_cuts_a_view_into_nearly_equal_windows_that_cover_it_once() {
        for (width, height, side, cells) in [
            (400, 400, 200, 4),
            (270, 480, 200, 2),
            (37, 5, 8, 5),
            (5, 5, 9, 1),
            (299, 100, 200, 1),
            (300, 100, 200, 2),
        ] {
            let mut windows = Windows::new(side, 3);
            let mut covered = vec![0_u32; (width * height) as usize];
            let mut seen = std::collections::BTreeSet::new();
            for _ in 0..2000 {
                let [left, top, w, h] = windows.drawn_cell(width, height);
                assert!(w >= 1 && h >= 1 && w < 2 * side && h < 2 * side);
                assert!(left + w <= width && top + h <= height);
                if seen.insert((left, top)) {
                    for j in top..top + h {
                        for i in left..left + w {
                            covered[(j * width + i) as usize] += 1;
                        }
                    }
                }
            }
            assert_eq!(seen.len() as u32, cells, "every cell is drawn");
            assert!(covered.iter().all(|&c| c == 1), "every pixel in one cell");
            assert_eq!(
                pixel_fraction(Some(side), width, height),
                1.0 / f64::from(cells)
            );
        }
    }

    #[test]
    fn the_same_seed_draws_the_same_windows() {
        let draw = |seed| {
            let mut windows = Windows::new(16, seed);
            (0..50)
                .map(|_| windows.drawn_cell(100, 60))
                .collect::<Vec<_>>()
        };
        assert_eq!(draw(1), draw(1));
        assert_ne!(draw(1), draw(2));
    }
}
