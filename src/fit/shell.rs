//! What a photo start explains, and a far shell for the rest (3D Gaussian splatting's
//! kernels on a far sphere for unbounded scenes, placed only where the views need them).
//!
//! **Coverage.** A start kernel (static, isotropic σ) explains the pixels of a view inside
//! the disc it projects to: radius `max(1, COVER_SIGMAS · σ f / z)` pixels around its
//! projection, `f = max(fx, fy)`, `z` its camera depth ([`coverage`]).
//!
//! **The shell.** A training pixel is *unexplained* when no start kernel covers it, its
//! loss weight is above 0 and, where the views' background is flat
//! ([`crate::fit::hull::flat_background`]), it is foreground to the visual hull
//! ([`crate::fit::hull::is_foreground`]: off the background by more than 1/255 in some
//! channel; a flat background needs no kernel). With `U`
//! unexplained pixels over all views (the shell acts only when they are at least
//! [`MIN_UNEXPLAINED_SHARE`] of the pixels), `U₁` in the view with the most, and a budget of
//! `N` kernels, each view is visited on a grid of stride `s = ⌈√(U₁ / N)⌉` (pixels
//! `(s/2 + a s, s/2 + b s)`, the first at most half the view's side in), views in order, and `s` is widened until at most `N` points are
//! placed (a view's own grid spans what it alone sees; views that see the same background
//! add little). A grid pixel still unexplained gets a kernel where its ray `o + λ d` (`o` the camera
//! centre, `d` the unit direction through the pixel's centre) meets the sphere
//! `|X − c| = r` from inside, `c` the centre of the cameras' box and `r = SHELL_RADIUS · m`,
//! `m` the largest distance of a camera to `c` (every camera is inside):
//!
//! ```text
//! λ = −b + √(b² − (|o − c|² − r²)),   b = d · (o − c)
//! ```
//!
//! Its spacing is the grid's at its camera depth `z`, `s z / f`, so the start kernel made of
//! it (spatial σ half the spacing: a disc of `1.5 s` pixels in that view) overlaps its
//! neighbours; its colour is the pixel's. The points a view placed are painted into every
//! later view's coverage before that view is visited, so a direction two views share gets
//! one kernel, not one a view. Everything is in the order of the views and their pixels: the same kernels
//! for any thread count.

use glam::DVec3;

use crate::fit::hull::{flat_background, is_foreground};
use crate::fit::init::SpaceTimeBox;
use crate::fit::stereo::{camera_to_world, pixel_point};
use crate::model::scene::Kernel;
use crate::model::{Camera, View};

/// Radius of a start kernel's footprint, in its σ.
pub const COVER_SIGMAS: f64 = 3.0;

/// The shell's radius in the largest camera distance from the centre of the cameras' box
/// (every camera inside). Measured on the DSLR-like proxy started from its cloud without a
/// sweep (`docs/fitting.md`): 33.69 dB held out (the cloud alone 26.82 dB); with the radius
/// in median camera distances instead, 3 gave 27.87 dB and 1.5 gave 35.18 dB: the proxy's
/// table and backdrop are nearer the smaller sphere, so the fit has less far to move them.
pub const SHELL_RADIUS: f64 = 1.5;

/// The share of the training pixels that must be unexplained for the shell to act: fewer,
/// scattered ones are left to densification.
pub const MIN_UNEXPLAINED_SHARE: f64 = 0.01;

/// The pixels of `camera` (row-major) inside some kernel's footprint (module doc).
#[must_use]
pub fn coverage(camera: &Camera, kernels: &[Kernel]) -> Vec<bool> {
    let mut mask = vec![false; camera.pixel_count()];
    for kernel in kernels {
        let [x, y, z, _] = kernel.mean;
        let sigma = kernel.scale[0].max(kernel.scale[1]).max(kernel.scale[2]);
        paint(&mut mask, camera, [x, y, z], sigma);
    }
    mask
}

/// Marks in `mask` the pixels of `camera` in the footprint of a kernel at `position` with
/// spatial σ `sigma`.
fn paint(mask: &mut [bool], camera: &Camera, position: [f64; 3], sigma: f64) {
    let (w, h) = (camera.width as usize, camera.height as usize);
    let [u, v, depth] = camera.project_point(position);
    if !(depth > 0.0 && u.is_finite() && v.is_finite()) {
        return;
    }
    let radius = (COVER_SIGMAS * sigma * camera.fx.max(camera.fy) / depth).max(1.0);
    let rows = (v - radius).floor().max(0.0)..=(v + radius).ceil().min(h as f64 - 1.0);
    let columns = (u - radius).floor().max(0.0)..=(u + radius).ceil().min(w as f64 - 1.0);
    if rows.is_empty() || columns.is_empty() {
        return;
    }
    for j in *rows.start() as usize..=*rows.end() as usize {
        for i in *columns.start() as usize..=*columns.end() as usize {
            let (du, dv) = (i as f64 + 0.5 - u, j as f64 + 0.5 - v);
            if du * du + dv * dv <= radius * radius {
                mask[j * w + i] = true;
            }
        }
    }
}

/// A point of the far shell: where a start kernel goes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShellPoint {
    /// World position.
    pub position: [f64; 3],
    /// The colour of the pixel it was placed for (linear RGB).
    pub colour: [f64; 3],
    /// The grid's spacing at its depth, world units: its kernel's σ is half of it.
    pub spacing: f64,
}

/// The far shell's points for the pixels of `views` that `kernels` leave unexplained
/// against `background` (module doc): at most `budget` of them.
#[must_use]
pub fn far_shell_points(
    kernels: &[Kernel],
    views: &[View],
    bounds: &SpaceTimeBox,
    background: [f64; 3],
    budget: usize,
) -> Vec<ShellPoint> {
    let placement = Placement {
        views,
        masks: views
            .iter()
            .map(|view| coverage(&view.camera, kernels))
            .collect(),
        background: flat_background(views, background).then_some(background.map(|b| b as f32)),
        shell: Shell::around(views, bounds),
    };
    let counts = placement.unexplained_counts();
    let (total, largest) = (
        counts.iter().sum::<usize>(),
        counts.iter().copied().max().unwrap_or(0),
    );
    let pixels: usize = views.iter().map(|view| view.camera.pixel_count()).sum();
    if total == 0 || (total as f64) < MIN_UNEXPLAINED_SHARE * pixels as f64 || budget == 0 {
        return Vec::new();
    }
    // At the widest stride every view's grid is its centre pixel alone.
    let widest = views
        .iter()
        .map(|view| view.camera.width.max(view.camera.height) as usize)
        .max()
        .unwrap_or(1);
    let mut stride = stride_for(largest, budget).min(widest);
    loop {
        let placed = placement.place(stride);
        if placed.len() <= budget || stride >= widest {
            return placed.into_iter().take(budget).collect();
        }
        let spread = placed.len().saturating_mul(stride).saturating_mul(stride);
        stride = stride_for(spread, budget).max(stride + 1).min(widest);
    }
}

/// The grid stride that spreads about `budget` points over `pixels` pixels.
fn stride_for(pixels: usize, budget: usize) -> usize {
    ((pixels as f64 / budget as f64).sqrt().ceil() as usize).max(1)
}

/// What placing the shell's points reads: the views, what the start covers in each, the
/// flat background if there is one, and the sphere.
struct Placement<'a> {
    views: &'a [View],
    masks: Vec<Vec<bool>>,
    background: Option<[f32; 3]>,
    shell: Shell,
}

impl Placement<'_> {
    /// Per view, its unexplained pixels.
    fn unexplained_counts(&self) -> Vec<usize> {
        self.views
            .iter()
            .zip(&self.masks)
            .map(|(view, mask)| {
                (0..mask.len())
                    .filter(|&p| unexplained(view, mask, p, self.background))
                    .count()
            })
            .collect()
    }

    /// The points on a grid of `stride` (module doc): a view's unexplained grid pixels,
    /// after the points of the views before it are painted into its coverage.
    fn place(&self, stride: usize) -> Vec<ShellPoint> {
        let mut placed: Vec<ShellPoint> = Vec::new();
        for (view, start) in self.views.iter().zip(&self.masks) {
            let camera = &view.camera;
            let to_world = camera_to_world(camera);
            let mut mask = start.clone();
            for point in &placed {
                paint(&mut mask, camera, point.position, 0.5 * point.spacing);
            }
            let (w, h) = (camera.width as usize, camera.height as usize);
            for j in ((stride / 2).min(h / 2)..h).step_by(stride) {
                for i in ((stride / 2).min(w / 2)..w).step_by(stride) {
                    if !unexplained(view, &mask, j * w + i, self.background) {
                        continue;
                    }
                    let Some((position, depth)) = self.shell.meet(camera, &to_world, i, j) else {
                        continue;
                    };
                    placed.push(ShellPoint {
                        position,
                        colour: view.image.pixel(i as u32, j as u32).map(f64::from),
                        spacing: stride as f64 * depth / camera.fx.max(camera.fy),
                    });
                }
            }
        }
        placed
    }
}

/// Pixel `p` of `view` is outside `mask`, counts in the loss and is not the flat
/// `background` (when there is one).
fn unexplained(view: &View, mask: &[bool], p: usize, background: Option<[f32; 3]>) -> bool {
    if mask[p] || view.weights.as_ref().is_some_and(|w| w[p] <= 0.0) {
        return false;
    }
    let colour = &view.image.pixels[3 * p..3 * p + 3];
    background.is_none_or(|b| is_foreground(colour, b))
}

/// The shell's sphere: its centre and radius (module doc).
struct Shell {
    centre: [f64; 3],
    radius: f64,
}

impl Shell {
    /// The sphere of [`SHELL_RADIUS`] times the largest camera distance around the box's
    /// centre (1 when no distance is finite).
    fn around(views: &[View], bounds: &SpaceTimeBox) -> Shell {
        let centre: [f64; 3] = std::array::from_fn(|a| 0.5 * (bounds.min[a] + bounds.max[a]));
        let farthest = views
            .iter()
            .map(|view| distance(view.camera.centre(), centre))
            .filter(|d| d.is_finite())
            .fold(None, |most: Option<f64>, d| {
                Some(most.map_or(d, |m| m.max(d)))
            })
            .unwrap_or(1.0);
        Shell {
            centre,
            radius: SHELL_RADIUS * farthest,
        }
    }

    /// Where pixel `(i, j)`'s ray from `camera` (inside the sphere) leaves it, and that
    /// point's camera depth; `None` when the numbers are not finite. `to_world` is the
    /// camera's [`camera_to_world`] (the plane sweep's: any invertible `Rc`, SPEC §3).
    fn meet(
        &self,
        camera: &Camera,
        to_world: &([[f64; 3]; 3], [f64; 3]),
        i: usize,
        j: usize,
    ) -> Option<([f64; 3], f64)> {
        let origin = DVec3::from(to_world.1);
        let direction =
            (DVec3::from(pixel_point(camera, to_world, i, j, 1.0)) - origin).normalize();
        let offset = origin - DVec3::from(self.centre);
        let b = direction.dot(offset);
        let along = -b + (b * b - (offset.length_squared() - self.radius * self.radius)).sqrt();
        let position: [f64; 3] = (origin + along * direction).into();
        let depth = camera.to_camera_space(position)[2];
        (position.iter().all(|v| v.is_finite()) && depth.is_finite() && depth > 0.0)
            .then_some((position, depth))
    }
}

/// `|a − b|`.
fn distance(a: [f64; 3], b: [f64; 3]) -> f64 {
    (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>().sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::Image;

    /// A view of the origin from `eye` (45°, 40×30) seeing a uniform `colour`.
    fn view(eye: [f64; 3], colour: [f32; 3]) -> View {
        View {
            camera: Camera::look_at(eye, [0.0; 3], [0.0, 1.0, 0.0], 45.0, 40, 30).unwrap(),
            time: 0.0,
            image: Image::filled(40, 30, colour).into(),
            name: "v".into(),
            weights: None,
        }
    }

    fn bounds() -> SpaceTimeBox {
        SpaceTimeBox {
            min: [-0.5; 3],
            max: [0.5; 3],
            time: [0.0, 1.0],
        }
    }

    #[test]
    fn the_shell_starts_every_unexplained_pixel_on_its_sphere_within_the_budget() {
        let views: Vec<View> = (0..5)
            .map(|k| {
                let angle = (-10.0 + 5.0 * f64::from(k)).to_radians();
                view([4.0 * angle.sin(), 0.0, 4.0 * angle.cos()], [0.6, 0.4, 0.2])
            })
            .collect();
        let points = far_shell_points(&[], &views, &bounds(), [0.0; 3], 300);
        assert!((100..=300).contains(&points.len()), "{}", points.len());
        // The sphere: 1.5 times the largest camera distance (4) around the origin.
        for p in &points {
            let r = distance(p.position, [0.0; 3]);
            assert!((r - SHELL_RADIUS * 4.0).abs() < 1e-9, "{r}");
            assert_eq!(p.colour, [0.6f32, 0.4, 0.2].map(f64::from));
        }
        // Kernels of half their spacing leave no pixel of any view unexplained.
        let kernels: Vec<Kernel> = points
            .iter()
            .map(|p| {
                let [x, y, z] = p.position;
                let s = 0.5 * p.spacing;
                Kernel::new([x, y, z, 0.5], [s, s, s, 1.0], p.colour)
            })
            .collect();
        for view in &views {
            assert!(coverage(&view.camera, &kernels).iter().all(|c| *c));
        }
        // Views that see the same background share its points: five views add far fewer
        // than five times one view's.
        let one = far_shell_points(&[], &views[..1], &bounds(), [0.0; 3], 300);
        assert!(
            points.len() < 2 * one.len(),
            "{} {}",
            points.len(),
            one.len()
        );
        // The budget caps the count; the same input gives the same points.
        let capped = far_shell_points(&[], &views, &bounds(), [0.0; 3], 7);
        assert!((1..=7).contains(&capped.len()), "{}", capped.len());
        assert_eq!(
            points,
            far_shell_points(&[], &views, &bounds(), [0.0; 3], 300)
        );
    }

    #[test]
    fn explained_flat_background_and_weightless_pixels_get_no_shell() {
        let eye = [0.0, 0.0, 4.0];
        // A flat background the views show everywhere: nothing to start.
        let flat = [view(eye, [0.2; 3]), view([1.0, 0.0, 4.0], [0.2; 3])];
        assert!(far_shell_points(&[], &flat, &bounds(), [0.2; 3], 300).is_empty());
        // Every pixel's weight 0 (outside the photo): nothing.
        let mut weightless = view(eye, [0.9; 3]);
        weightless.weights = Some(vec![0.0; 40 * 30]);
        assert!(far_shell_points(&[], &[weightless], &bounds(), [0.0; 3], 300).is_empty());
        // One big kernel at the origin covering the whole view: nothing unexplained.
        let big = Kernel::new([0.0; 4], [2.0, 2.0, 2.0, 1.0], [0.5; 3]);
        let seen = [view(eye, [0.9; 3])];
        assert!(coverage(&seen[0].camera, &[big]).iter().all(|c| *c));
        assert!(far_shell_points(&[big], &seen, &bounds(), [0.0; 3], 300).is_empty());
        // Fewer than 1 % of the pixels unexplained (11 of 1200 weighted): left to
        // densification.
        let mut corner = seen[0].clone();
        let mut weights = vec![1.0; 40 * 30];
        weights[..1200 - 11].fill(0.0);
        corner.weights = Some(weights.clone());
        assert!(far_shell_points(&[], &[corner.clone()], &bounds(), [0.0; 3], 300).is_empty());
        // 12 of 1200 (1 %): started, only where the weights count.
        weights[1200 - 12] = 1.0;
        corner.weights = Some(weights);
        let started = far_shell_points(&[], &[corner], &bounds(), [0.0; 3], 300);
        assert!(!started.is_empty());
        for p in &started {
            let [u, v, _] = seen[0].camera.project_point(p.position);
            assert!(v > 29.0 && u > 40.0 - 12.0, "({u}, {v})");
        }
        // A budget of 0 places nothing.
        assert!(far_shell_points(&[], &seen, &bounds(), [0.0; 3], 0).is_empty());
    }

    #[test]
    fn a_flat_background_is_left_out_and_its_foreground_started_in_its_colour() {
        // A 10×10 red patch on a flat grey background.
        let mut seen = view([0.0, 0.0, 4.0], [0.2; 3]);
        let mut image = (*seen.image).clone();
        for j in 10..20 {
            for i in 15..25 {
                let k = 3 * (j * 40 + i);
                image.pixels[k..k + 3].copy_from_slice(&[0.9, 0.1, 0.1]);
            }
        }
        seen.image = image.into();
        let points = far_shell_points(&[], &[seen.clone()], &bounds(), [0.2; 3], 300);
        assert!(points.len() >= 4, "{}", points.len());
        for p in &points {
            assert_eq!(p.colour, [0.9f32, 0.1, 0.1].map(f64::from));
            let [u, v, _] = seen.camera.project_point(p.position);
            assert!(
                (15.0..25.0).contains(&u) && (10.0..20.0).contains(&v),
                "({u}, {v})"
            );
        }
    }

    #[test]
    fn a_budget_of_one_over_views_apart_still_places_one() {
        // Five views looking different ways (no two share a direction): a budget of 1.
        let views: Vec<View> = (0..5)
            .map(|k| {
                let angle = (72.0 * f64::from(k)).to_radians();
                view([4.0 * angle.sin(), 0.0, 4.0 * angle.cos()], [0.6; 3])
            })
            .collect();
        assert_eq!(
            far_shell_points(&[], &views, &bounds(), [0.0; 3], 1).len(),
            1
        );
        // A view 2000×100: rows are not lost to a stride past its height.
        let mut wide = view([0.0, 0.0, 4.0], [0.6; 3]);
        wide.camera =
            Camera::look_at([0.0, 0.0, 4.0], [0.0; 3], [0.0, 1.0, 0.0], 45.0, 2000, 100).unwrap();
        wide.image = Image::filled(2000, 100, [0.6; 3]).into();
        let placed = far_shell_points(&[], &[wide], &bounds(), [0.0; 3], 3);
        assert!((1..=3).contains(&placed.len()), "{}", placed.len());
    }

    #[test]
    fn a_pixels_shell_point_lies_on_the_sphere_and_projects_back_to_the_pixel() {
        let shell = Shell {
            centre: [0.1, -0.2, 0.3],
            radius: 7.0,
        };
        let orthonormal =
            Camera::look_at([1.0, 0.5, 4.0], [0.0; 3], [0.0, 1.0, 0.0], 45.0, 40, 30).unwrap();
        // Rc scaled and sheared (SPEC §3 allows any invertible Rc).
        let sheared = orthonormal.sheared();
        // At the sphere's centre.
        let centred = Camera::look_at(
            [0.1, -0.2, 0.3],
            [0.0, 0.0, -5.0],
            [0.0, 1.0, 0.0],
            45.0,
            40,
            30,
        )
        .unwrap();
        for camera in [orthonormal, sheared, centred] {
            let to_world = camera_to_world(&camera);
            for (i, j) in [(0, 0), (39, 29), (17, 11)] {
                let (position, depth) = shell.meet(&camera, &to_world, i, j).unwrap();
                assert!((distance(position, shell.centre) - 7.0).abs() < 1e-9);
                let [u, v, z] = camera.project_point(position);
                assert!((u - (i as f64 + 0.5)).abs() < 1e-9, "{u} for {i}");
                assert!((v - (j as f64 + 0.5)).abs() < 1e-9, "{v} for {j}");
                assert!((z - depth).abs() < 1e-9 * depth && depth > 0.0);
            }
        }
    }
}
