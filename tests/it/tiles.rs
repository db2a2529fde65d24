//! Tile binning against brute force: every tile holding a pixel centre where the ellipse's
//! padded cut-off holds (q evaluated in f64 per pixel) lists the kernel, and the exact
//! ellipse–tile test lists fewer tiles than the bounding boxes would.

use splat4d::tiles::{TILE_SIZE, padded_qmax};
use splat4d::{RenderContext, RenderOptions};

/// Checks the bins of the frame last rendered in `context` against brute force; returns
/// (tile entries, entries the bounding boxes would give).
fn check_bins(context: &RenderContext, what: &str) -> (usize, usize) {
    let (proj, bins) = (&context.projected, &context.bins);
    let mut box_entries = 0;
    for p in 0..proj.len() {
        let [x0, x1, y0, y1] = bins.pixel_bounds[p];
        if x0 < x1 && y0 < y1 {
            box_entries += ((x1.div_ceil(TILE_SIZE) - x0 / TILE_SIZE)
                * (y1.div_ceil(TILE_SIZE) - y0 / TILE_SIZE)) as usize;
        }
        let [mx, my] = proj.means[p];
        let [a, b, c] = proj.conics[p];
        let q_reach = padded_qmax(proj.qmax[p]);
        for j in 0..bins.height {
            for i in 0..bins.width {
                let (du, dv) = (f64::from(i) + 0.5 - mx, f64::from(j) + 0.5 - my);
                let q = a * du * du + 2.0 * b * du * dv + c * dv * dv;
                // Margin for the rounding of the plain form against the sum of squares.
                if q <= q_reach * (1.0 - 1e-9) - 1e-9 {
                    let t = (j / TILE_SIZE * bins.tiles_x + i / TILE_SIZE) as usize;
                    assert!(
                        bins.tile_entries(t).contains(&(p as u32)),
                        "{what}: kernel {p} reaches pixel ({i}, {j}) (q = {q}, reach {q_reach}) \
                         but tile {t} does not list it"
                    );
                }
            }
        }
    }
    (bins.proj_from_entry.len(), box_entries)
}

#[test]
fn bins_hold_every_reachable_tile_and_skip_corners_of_tilted_ellipses() {
    let camera = crate::common::test_camera(150, 110);
    let mut total = (0, 0);
    for (seed, dilation, cutoff) in [
        (1, 0.3, 1.0 / 255.0),
        (2, 0.0, 1.0 / 255.0),
        (3, 0.0, 1e-6),
        (4, 0.3, 0.05),
        (5, 0.0, 0.0),
    ] {
        let scene = crate::common::hard_random_scene(&camera, seed, 200);
        let options = RenderOptions {
            dilation,
            cutoff,
            ..RenderOptions::default()
        };
        let mut context = RenderContext::new();
        context.render(&scene, &camera, 0.5, &options).unwrap();
        let (entries, boxes) = check_bins(&context, &format!("seed {seed}"));
        assert!(entries <= boxes, "seed {seed}: {entries} entries > {boxes}");
        total = (total.0 + entries, total.1 + boxes);
    }
    // The random rotations make many ellipses tilted: the exact test must save entries.
    assert!(
        (total.0 as f64) < 0.95 * total.1 as f64,
        "exact binning lists {} entries, boxes {}",
        total.0,
        total.1
    );
}
