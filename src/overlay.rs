//! A debug overlay over a render, drawn with tiny-skia: the per-tile load as a heat map (red,
//! opacity up to 0.5 in proportion to the number of kernels listed in the tile, the work the
//! raster does there) and every projected ellipse's outline at its cut-off `q = qmax`
//! (SPEC §5; `q = 9`, three standard deviations, when nothing is truncated).
//!
//! The outline of `q = c` is the ellipse with semi-axes `√(c λ_k)` along the eigenvectors of
//! Σ2 (λ_k its eigenvalues), centred on `m2` (pixel centres at `i + ½`).

use tiny_skia::{Color, Paint, PathBuilder, Pixmap, Rect, Stroke, Transform};

use crate::model::error::{Error, Result};
use crate::model::image::quantize;
use crate::render::RenderContext;
use crate::tiles::TILE_SIZE;

/// Semi-axes `(a, b)` and the angle (radians) of axis `a` of the ellipse `dᵀ Σ⁻¹ d = c` for
/// `Σ = [xx, xy, yy]`.
#[must_use]
pub fn ellipse_axes([xx, xy, yy]: [f64; 3], c: f64) -> (f64, f64, f64) {
    let mean = 0.5 * (xx + yy);
    let spread = (0.25 * (xx - yy).powi(2) + xy * xy).sqrt();
    let (l1, l2) = (mean + spread, (mean - spread).max(0.0));
    let angle = 0.5 * (2.0 * xy).atan2(xx - yy);
    ((c * l1).sqrt(), (c * l2).sqrt(), angle)
}

/// Draws the overlay over the context's last render; returns 8-bit RGB bytes.
pub fn draw_overlay(context: &RenderContext) -> Result<(u32, u32, Vec<u8>)> {
    let image = context.image();
    let (w, h) = (image.width, image.height);
    let mut pixmap =
        Pixmap::new(w, h).ok_or_else(|| Error::Usage(format!("cannot draw a {w}×{h} overlay")))?;
    for (dst, src) in pixmap
        .data_mut()
        .chunks_exact_mut(4)
        .zip(image.pixels.chunks_exact(3))
    {
        dst.copy_from_slice(&[
            quantize(src[0], 255) as u8,
            quantize(src[1], 255) as u8,
            quantize(src[2], 255) as u8,
            255,
        ]);
    }
    // Heat map of the tile loads.
    let bins = &context.bins;
    let loads: Vec<usize> = (0..bins.tile_count())
        .map(|t| bins.tile_entries(t).len())
        .collect();
    let peak = loads.iter().copied().max().unwrap_or(0).max(1) as f32;
    let mut paint = Paint::default();
    for (t, &load) in loads.iter().enumerate() {
        if load == 0 {
            continue;
        }
        let [x0, x1, y0, y1] = bins.tile_rect(t);
        paint.set_color(
            Color::from_rgba(1.0, 0.1, 0.1, 0.5 * load as f32 / peak).expect("valid colour"),
        );
        if let Some(rect) = Rect::from_ltrb(x0 as f32, y0 as f32, x1 as f32, y1 as f32) {
            pixmap.fill_rect(rect, &paint, Transform::identity(), None);
        }
    }
    // Tile grid, faint.
    paint.set_color(Color::from_rgba(1.0, 1.0, 1.0, 0.12).expect("valid colour"));
    let grid = Stroke {
        width: 1.0,
        ..Stroke::default()
    };
    let mut lines = PathBuilder::new();
    for x in (0..w).step_by(TILE_SIZE as usize) {
        lines.move_to(x as f32 + 0.5, 0.0);
        lines.line_to(x as f32 + 0.5, h as f32);
    }
    for y in (0..h).step_by(TILE_SIZE as usize) {
        lines.move_to(0.0, y as f32 + 0.5);
        lines.line_to(w as f32, y as f32 + 0.5);
    }
    if let Some(path) = lines.finish() {
        pixmap.stroke_path(&path, &paint, &grid, Transform::identity(), None);
    }
    // Ellipse outlines at the cut-off.
    paint.set_color(Color::from_rgba(0.2, 1.0, 0.4, 0.7).expect("valid colour"));
    paint.anti_alias = true;
    let outline = Stroke {
        width: 1.0,
        ..Stroke::default()
    };
    let projected = &context.projected;
    for p in 0..projected.len() {
        let qmax = projected.qmax[p];
        let c = if qmax.is_finite() { qmax } else { 9.0 };
        let (a, b, angle) = ellipse_axes(projected.covariances[p], c);
        let [mx, my] = projected.means[p];
        let limit = 4.0 * f64::from(w.max(h));
        if !(a.is_finite() && b.is_finite()) || mx.abs() > limit || my.abs() > limit || a > limit {
            continue;
        }
        let (cx, cy) = (mx as f32, my as f32);
        let Some(oval) = Rect::from_xywh(
            cx - a as f32,
            cy - (b as f32).max(0.05),
            2.0 * a as f32,
            2.0 * (b as f32).max(0.05),
        ) else {
            continue;
        };
        let Some(path) = PathBuilder::from_oval(oval) else {
            continue;
        };
        let transform = Transform::from_rotate_at(angle.to_degrees() as f32, cx, cy);
        pixmap.stroke_path(&path, &paint, &outline, transform, None);
    }
    let rgb: Vec<u8> = pixmap
        .data()
        .chunks_exact(4)
        .flat_map(|p| [p[0], p[1], p[2]])
        .collect();
    Ok((w, h, rgb))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn axes_of_rotated_ellipses() {
        let (a, b, angle) = ellipse_axes([4.0, 0.0, 1.0], 1.0);
        assert!((a - 2.0).abs() < 1e-12 && (b - 1.0).abs() < 1e-12 && angle.abs() < 1e-12);
        // Σ = R diag(9, 1) Rᵀ with R a 30° rotation.
        let (s, c) = (30f64.to_radians().sin(), 30f64.to_radians().cos());
        let sigma = [
            9.0 * c * c + s * s,
            (9.0 - 1.0) * c * s,
            9.0 * s * s + c * c,
        ];
        let (a, b, angle) = ellipse_axes(sigma, 4.0);
        assert!(
            (a - 6.0).abs() < 1e-12
                && (b - 2.0).abs() < 1e-12
                && (angle - 30f64.to_radians()).abs() < 1e-12
        );
    }
}
