//! Pinhole cameras (SPEC §3): intrinsics, world→camera transform, look-at, conversions.
//!
//! Pixels: column `i`, row `j`, centre at `(i + 0.5, j + 0.5)`. Camera space uses OpenCV
//! axes (x right, y down, z forward): `p_cam = Rc p_world + tc`, and a point projects to
//! `u = fx x/z + cx`, `v = fy y/z + cy`. `Rc` is used exactly as given (it need not be
//! orthonormal); it must have `|det Rc| ≥ 1e-9`, the matrix's last row must be `(0, 0, 0, 1)`
//! and `0 < near < far`.
//!
//! Conversions are provided from the OpenGL camera-to-world convention of Blender and
//! D-NeRF (x right, y up, z backward). Files: [`crate::io::camera_file`].

use glam::{DMat4, DVec3, DVec4};
use serde::{Deserialize, Serialize};

use crate::model::error::{Error, Result, check_finite};

/// How far the last row of a camera-to-world matrix read from a file may be from
/// `(0, 0, 0, 1)` (rounding in the file, not a projective matrix).
pub const LAST_ROW_TOLERANCE: f64 = 1e-6;

/// Default near plane (SPEC §3).
pub const DEFAULT_NEAR: f64 = 0.01;
/// Default far plane (SPEC §3).
pub const DEFAULT_FAR: f64 = 1e6;
/// Largest frame, in pixels (16384², about 3 GB of render buffers): larger sizes are refused
/// at validation rather than failing to allocate.
pub const MAX_PIXELS: u64 = 1 << 28;

/// Smallest focal length, in units of the image's smaller side (a field of view just under
/// 180°).
pub const MIN_FOCAL_RATIO: f64 = 1e-4;

/// Largest focal length, in units of the image's larger side (a field of view of 1e-5 rad).
pub const MAX_FOCAL_RATIO: f64 = 1e5;

/// A validated pinhole camera. Build it with [`Camera::new`], [`Camera::look_at`],
/// [`Camera::from_opengl_camera_to_world`], or read one with [`crate::io::camera_file`].
///
/// SPEC §3: OpenCV axes (x right, y down, z forward), `u = fx x/z + cx`, pixel centres at
/// `i + ½`.
///
/// ```
/// use splat4d::Camera;
/// // eye, target, up, vertical field of view in degrees, width, height
/// let camera = Camera::look_at([0.0, 0.0, -3.0], [0.0; 3], [0.0, 1.0, 0.0], 40.0, 64, 48).unwrap();
/// assert_eq!((camera.width, camera.height), (64, 48));
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Camera {
    /// Image width in pixels (≥ 1).
    pub width: u32,
    /// Image height in pixels (≥ 1).
    pub height: u32,
    /// Focal length along x, pixels (> 0).
    pub fx: f64,
    /// Focal length along y, pixels (> 0).
    pub fy: f64,
    /// Principal point x, pixels.
    pub cx: f64,
    /// Principal point y, pixels.
    pub cy: f64,
    /// Row-major 4×4 world→camera matrix, OpenCV axes; last row `(0, 0, 0, 1)`.
    pub world_to_camera: [[f64; 4]; 4],
    /// Kernels whose slice centre has camera `z < near` are culled.
    #[serde(default = "default_near")]
    pub near: f64,
    /// Kernels whose slice centre has camera `z > far` are culled.
    #[serde(default = "default_far")]
    pub far: f64,
    /// The limits `[lim_x⁻, lim_x⁺, lim_y⁻, lim_y⁺]` of SPEC §4's clamp of `J` when they are
    /// not this camera's own: a window of a view keeps the view's
    /// ([`crate::model::View::cropped`]), so that its pixels are the view's. `None` (every
    /// camera a file describes): the limits of this camera's own size.
    #[serde(skip)]
    pub clamp: Option<[f64; 4]>,
}

fn default_near() -> f64 {
    DEFAULT_NEAR
}

fn default_far() -> f64 {
    DEFAULT_FAR
}

impl Camera {
    /// A camera from intrinsics and a world→camera matrix (OpenCV axes), validated, with the
    /// default near and far planes.
    pub fn new(
        width: u32,
        height: u32,
        [fx, fy, cx, cy]: [f64; 4],
        world_to_camera: [[f64; 4]; 4],
    ) -> Result<Self> {
        let camera = Camera {
            width,
            height,
            fx,
            fy,
            cx,
            cy,
            world_to_camera,
            near: DEFAULT_NEAR,
            far: DEFAULT_FAR,
            clamp: None,
        };
        camera.validate("<camera>")?;
        Ok(camera)
    }

    /// The limits `[lim_x⁻, lim_x⁺, lim_y⁻, lim_y⁺]` of SPEC §4's clamp of `J`: those kept
    /// of the view this camera is a window of ([`Camera::clamp`]), else its own:
    /// `lim_x⁻ = cx/fx + 0.15 W/fx`, `lim_x⁺ = (W - cx)/fx + 0.15 W/fx` (y likewise).
    #[must_use]
    pub fn clamp_limits(&self) -> [f64; 4] {
        if let Some(limits) = self.clamp {
            return limits;
        }
        let (w, h) = (f64::from(self.width), f64::from(self.height));
        let margin_x = 0.3 * 0.5 * w / self.fx;
        let margin_y = 0.3 * 0.5 * h / self.fy;
        [
            self.cx / self.fx + margin_x,
            (w - self.cx) / self.fx + margin_x,
            self.cy / self.fy + margin_y,
            (h - self.cy) / self.fy + margin_y,
        ]
    }

    /// Intrinsics `[fx, fy, cx, cy]` of square pixels seeing a vertical field of view of
    /// `fov_y` radians on a `width × height` image, principal point at the centre:
    /// `fx = fy = ½ height / tan(½ fov_y)`.
    #[must_use]
    pub fn centred_intrinsics(width: u32, height: u32, fov_y: f64) -> [f64; 4] {
        let focal = 0.5 * f64::from(height) / (0.5 * fov_y).tan();
        [
            focal,
            focal,
            0.5 * f64::from(width),
            0.5 * f64::from(height),
        ]
    }

    /// A camera at `eye` looking at `target`, with `up` pointing up in the image, a vertical
    /// field of view in degrees and the principal point at the image centre.
    pub fn look_at(
        eye: [f64; 3],
        target: [f64; 3],
        up: [f64; 3],
        fov_y_degrees: f64,
        width: u32,
        height: u32,
    ) -> Result<Self> {
        let origin = "<look-at camera>";
        let (eye, target, up) = (DVec3::from(eye), DVec3::from(target), DVec3::from(up));
        let forward = (target - eye).normalize_or_zero();
        let right = forward.cross(up).normalize_or_zero();
        if forward == DVec3::ZERO || right == DVec3::ZERO {
            return Err(Error::invalid(
                origin,
                "camera",
                "up",
                "eye equals target, or up is parallel to the viewing direction",
            ));
        }
        if !(fov_y_degrees > 0.0 && fov_y_degrees < 180.0) {
            return Err(Error::invalid(
                origin,
                "camera",
                "fov_y",
                format!("{fov_y_degrees} degrees is not in (0, 180)"),
            ));
        }
        let down = forward.cross(right);
        let rows = [right, down, forward];
        let mut m = [[0.0; 4]; 4];
        for (r, axis) in rows.iter().enumerate() {
            m[r] = [axis.x, axis.y, axis.z, -axis.dot(eye)];
        }
        m[3] = [0.0, 0.0, 0.0, 1.0];
        Camera::new(
            width,
            height,
            Camera::centred_intrinsics(width, height, fov_y_degrees.to_radians()),
            m,
        )
    }

    /// A camera from an OpenGL camera-to-world matrix (Blender, D-NeRF `transform_matrix`:
    /// x right, y up, z backward), row-major, with the given intrinsics.
    ///
    /// Files carry rounding: the matrix's last row must be `(0, 0, 0, 1)` within
    /// [`LAST_ROW_TOLERANCE`], and is then taken as exactly that; the inverse's last row is
    /// set exactly too (SPEC §3 checks it exactly). The 3×3 part may be any invertible
    /// matrix (scaled or sheared rotations keep working).
    pub fn from_opengl_camera_to_world(
        width: u32,
        height: u32,
        intrinsics: [f64; 4],
        camera_to_world: [[f64; 4]; 4],
    ) -> Result<Self> {
        let origin = "<camera-to-world matrix>";
        for (r, row) in camera_to_world.iter().enumerate() {
            check_finite(origin, "camera", &format!("camera_to_world[{r}]"), row)?;
        }
        let last = camera_to_world[3];
        if (0..4).any(|k| (last[k] - [0.0, 0.0, 0.0, 1.0][k]).abs() > LAST_ROW_TOLERANCE) {
            return Err(Error::invalid(
                origin,
                "camera",
                "camera_to_world",
                format!("the last row is {last:?}, not [0, 0, 0, 1]"),
            ));
        }
        let mut exact = camera_to_world;
        exact[3] = [0.0, 0.0, 0.0, 1.0];
        let c2w = DMat4::from_cols_array_2d(&exact).transpose();
        let flip = DMat4::from_diagonal(DVec4::new(1.0, -1.0, -1.0, 1.0));
        let mut w2c = (flip * c2w.inverse()).transpose().to_cols_array_2d();
        w2c[3] = [0.0, 0.0, 0.0, 1.0];
        Camera::new(width, height, intrinsics, w2c)
    }

    /// The OpenGL camera-to-world matrix (row-major) of this camera: the inverse of
    /// [`Camera::from_opengl_camera_to_world`].
    #[must_use]
    pub fn opengl_camera_to_world(&self) -> [[f64; 4]; 4] {
        let w2c = DMat4::from_cols_array_2d(&self.world_to_camera).transpose();
        let flip = DMat4::from_diagonal(DVec4::new(1.0, -1.0, -1.0, 1.0));
        (w2c.inverse() * flip).transpose().to_cols_array_2d()
    }

    /// `Rc`, the upper-left 3×3 of the world→camera matrix (row-major).
    #[must_use]
    pub fn rotation(&self) -> [[f64; 3]; 3] {
        let m = &self.world_to_camera;
        [
            [m[0][0], m[0][1], m[0][2]],
            [m[1][0], m[1][1], m[1][2]],
            [m[2][0], m[2][1], m[2][2]],
        ]
    }

    /// `tc`, the translation column of the world→camera matrix.
    #[must_use]
    pub fn translation(&self) -> [f64; 3] {
        let m = &self.world_to_camera;
        [m[0][3], m[1][3], m[2][3]]
    }

    /// The camera centre in world space, `-Rc⁻¹ tc`.
    #[must_use]
    pub fn centre(&self) -> [f64; 3] {
        let w2c = DMat4::from_cols_array_2d(&self.world_to_camera).transpose();
        w2c.inverse().w_axis.truncate().into()
    }

    /// The optical axis in world space, a unit vector: the direction `Rc⁻¹ (0, 0, 1)` of the
    /// ray through the principal point, along which the camera depth grows. By the
    /// adjugate it is `(r₀ × r₁) / det Rc` for `Rc`'s rows `r₀ r₁ r₂`: the third row itself
    /// only when `Rc` is a rotation (SPEC §3 allows any invertible `Rc`), and when it is one
    /// to 1e-6 in `Rc Rcᵀ` (rotations from files written to 7 digits or more) the third row,
    /// normalised, is taken. Zero when `Rc` is singular or not finite (a loaded camera is
    /// neither).
    #[must_use]
    pub fn optical_axis(&self) -> [f64; 3] {
        let [r0, r1, r2] = self.rotation().map(DVec3::from);
        let across = r0.cross(r1);
        let det = across.dot(r2);
        let axis = if self.has_orthonormal_rotation() {
            r2
        } else {
            across * det.signum()
        };
        let norm = axis.length();
        if det == 0.0 || !(norm.is_finite() && norm > 0.0) {
            return [0.0; 3];
        }
        (axis / norm).into()
    }

    /// Whether `Rc`'s rows are orthonormal to 1e-6 in `Rc Rcᵀ` (rotations, and reflections,
    /// from files written to 7 digits or more): then `Rcᵀ` may stand for `Rc⁻¹`.
    #[must_use]
    pub fn has_orthonormal_rotation(&self) -> bool {
        let rows = self.rotation();
        (0..3).all(|a| {
            (0..3).all(|b| {
                let dot: f64 = (0..3).map(|k| rows[a][k] * rows[b][k]).sum();
                (dot - f64::from(u8::from(a == b))).abs() <= 1e-6
            })
        })
    }

    /// A world point in camera space, `Rc p + tc` (OpenCV axes).
    #[must_use]
    pub fn to_camera_space(&self, p: [f64; 3]) -> [f64; 3] {
        let m = &self.world_to_camera;
        std::array::from_fn(|r| m[r][0] * p[0] + m[r][1] * p[1] + m[r][2] * p[2] + m[r][3])
    }

    /// A world point's pixel coordinates and depth `[u, v, z]` (SPEC §3: `u = fx x/z + cx`,
    /// `v = fy y/z + cy`; the point is in front of the camera when `z > 0`).
    #[must_use]
    pub fn project_point(&self, p: [f64; 3]) -> [f64; 3] {
        let [x, y, z] = self.to_camera_space(p);
        [self.fx * x / z + self.cx, self.fy * y / z + self.cy, z]
    }

    /// Number of pixels.
    #[must_use]
    pub fn pixel_count(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// Checks the SPEC §3 conditions; `origin` names the camera in error messages.
    pub fn validate(&self, origin: &str) -> Result<()> {
        let item = "camera";
        for (field, value) in [("width", self.width), ("height", self.height)] {
            if value == 0 {
                return Err(Error::invalid(
                    origin,
                    item,
                    field,
                    "must be at least 1 pixel",
                ));
            }
        }
        let pixels = u64::from(self.width) * u64::from(self.height);
        if pixels > MAX_PIXELS {
            return Err(Error::invalid(
                origin,
                item,
                "width",
                format!(
                    "{}×{} is {pixels} pixels, more than the {MAX_PIXELS} (16384²) a frame may have",
                    self.width, self.height
                ),
            ));
        }
        for (field, value) in [("fx", self.fx), ("fy", self.fy)] {
            check_finite(origin, item, field, &[value])?;
            if value <= 0.0 {
                return Err(Error::invalid(
                    origin,
                    item,
                    field,
                    format!("{value} must be > 0"),
                ));
            }
        }
        // A focal length far outside any lens makes the work non-finite (a subnormal one
        // divides to inf, 1e30 squares past f64): refused here, where the field is named.
        let (small, side) = (
            f64::from(self.width.min(self.height)),
            f64::from(self.width.max(self.height)),
        );
        for (field, value) in [("fx", self.fx), ("fy", self.fy)] {
            if !(MIN_FOCAL_RATIO * small..=MAX_FOCAL_RATIO * side).contains(&value) {
                return Err(Error::invalid(
                    origin,
                    item,
                    field,
                    format!(
                        "{value:e} pixels is outside {MIN_FOCAL_RATIO:e} times the image's smaller side ({small}) to {MAX_FOCAL_RATIO:e} times its larger side ({side}): no lens has it"
                    ),
                ));
            }
        }
        check_finite(origin, item, "cx", &[self.cx])?;
        check_finite(origin, item, "cy", &[self.cy])?;
        for (r, row) in self.world_to_camera.iter().enumerate() {
            check_finite(origin, item, &format!("world_to_camera[{r}]"), row)?;
        }
        if self.world_to_camera[3] != [0.0, 0.0, 0.0, 1.0] {
            return Err(Error::invalid(
                origin,
                item,
                "world_to_camera",
                format!(
                    "the last row is {:?}, not [0, 0, 0, 1]",
                    self.world_to_camera[3]
                ),
            ));
        }
        let det = glam::DMat3::from_cols_array_2d(&self.rotation()).determinant();
        if det.abs() < 1e-9 {
            return Err(Error::invalid(
                origin,
                item,
                "world_to_camera",
                format!(
                    "the rotation part is not invertible (|det| = {:e} < 1e-9)",
                    det.abs()
                ),
            ));
        }
        check_finite(origin, item, "near", &[self.near])?;
        check_finite(origin, item, "far", &[self.far])?;
        if !(0.0 < self.near && self.near < self.far) {
            return Err(Error::invalid(
                origin,
                item,
                "near",
                format!(
                    "need 0 < near < far, got near = {}, far = {}",
                    self.near, self.far
                ),
            ));
        }
        Ok(())
    }
}

/// Test support: the camera with its `Rc` (and `tc`) scaled row by row and sheared, no longer
/// orthonormal (SPEC §3 allows any invertible `Rc`).
#[cfg(test)]
impl Camera {
    pub(crate) fn sheared(&self) -> Camera {
        let mut sheared = *self;
        for (r, factor) in [(0, 1.7), (1, 0.6), (2, 1.3)] {
            for c in 0..4 {
                sheared.world_to_camera[r][c] *= factor;
            }
        }
        sheared.world_to_camera[0][1] += 0.3;
        sheared
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 64×48 camera at (1, 2, 3) looking at (0, 0.5, 0), y up, 60° vertically.
    fn looking_at_target() -> Camera {
        Camera::look_at(
            [1.0, 2.0, 3.0],
            [0.0, 0.5, 0.0],
            [0.0, 1.0, 0.0],
            60.0,
            64,
            48,
        )
        .unwrap()
    }

    /// The optical axis is the ray through the principal point: points along it from the
    /// centre project onto `(cx, cy)` at growing depth, for a rotation and for an `Rc` whose
    /// third row is not orthogonal to the others (a shear: SPEC §3 allows any invertible
    /// `Rc`), where the third row is not the axis.
    #[test]
    fn the_optical_axis_is_the_ray_through_the_principal_point() {
        let mut camera = looking_at_target();
        let looking: [f64; 3] = std::array::from_fn(|a| [0.0, 0.5, 0.0][a] - [1.0, 2.0, 3.0][a]);
        let norm = looking.iter().map(|v| v * v).sum::<f64>().sqrt();
        let axis = camera.optical_axis();
        for a in 0..3 {
            assert!((axis[a] - looking[a] / norm).abs() < 1e-12, "{axis:?}");
        }
        // Shear the third row towards the first (and scale it): Rc stays invertible.
        for b in 0..4 {
            camera.world_to_camera[2][b] =
                1.7 * camera.world_to_camera[2][b] + 0.6 * camera.world_to_camera[0][b];
        }
        let axis = camera.optical_axis();
        let row = camera.rotation()[2];
        let row_norm = row.iter().map(|v| v * v).sum::<f64>().sqrt();
        assert!((0..3).any(|a| (axis[a] - row[a] / row_norm).abs() > 0.1));
        let centre = camera.centre();
        for (k, distance) in [0.5, 2.0].into_iter().enumerate() {
            let point: [f64; 3] = std::array::from_fn(|a| centre[a] + distance * axis[a]);
            let [u, v, z] = camera.project_point(point);
            assert!(
                (u - camera.cx).abs() < 1e-9 && (v - camera.cy).abs() < 1e-9,
                "{k}: {u} {v}"
            );
            assert!(z > 0.0, "{k}: in front");
        }
        assert!((axis.iter().map(|v| v * v).sum::<f64>() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn look_at_puts_the_target_at_the_centre_with_up_up() {
        let camera = looking_at_target();
        let [u, v, z] = camera.project_point([0.0, 0.5, 0.0]);
        assert!((u - 32.0).abs() < 1e-12 && (v - 24.0).abs() < 1e-12 && z > 0.0);
        // A point above the target appears higher in the image (smaller v: y is down).
        assert!(camera.project_point([0.0, 0.6, 0.0])[1] < 24.0);
        // The vertical field of view: a point at the top edge of the frustum maps to v = 0.
        assert!((camera.fy - 24.0 / 30f64.to_radians().tan()).abs() < 1e-12);
        let centre = camera.centre();
        assert!(
            centre
                .iter()
                .zip([1.0, 2.0, 3.0])
                .all(|(a, b)| (a - b).abs() < 1e-12)
        );
    }

    #[test]
    fn opengl_camera_to_world_round_trips() {
        let camera = Camera::look_at(
            [0.3, -2.0, 1.5],
            [0.1, 0.2, -0.4],
            [0.0, 0.0, 1.0],
            40.0,
            32,
            32,
        )
        .unwrap();
        let c2w = camera.opengl_camera_to_world();
        // OpenGL: the camera looks down its -z axis, so -z (third column, negated) points at the target.
        let forward = [-c2w[0][2], -c2w[1][2], -c2w[2][2]];
        let to_target = [0.1 - 0.3, 0.2 + 2.0, -0.4 - 1.5];
        let n = to_target.iter().map(|v| v * v).sum::<f64>().sqrt();
        assert!(
            forward
                .iter()
                .zip(to_target)
                .all(|(f, t)| (f - t / n).abs() < 1e-12)
        );
        let back = Camera::from_opengl_camera_to_world(
            32,
            32,
            [camera.fx, camera.fy, camera.cx, camera.cy],
            c2w,
        )
        .unwrap();
        for (a, b) in back
            .world_to_camera
            .iter()
            .flatten()
            .zip(camera.world_to_camera.iter().flatten())
        {
            assert!((a - b).abs() < 1e-12, "{a} vs {b}");
        }
    }
}
