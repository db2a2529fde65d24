//! Camera paths for videos: a sequence of (camera, time).
//!
//! - [`orbit`]: `frames` cameras evenly around a circle of `radius` about `centre` at a fixed
//!   `elevation` (degrees above the plane perpendicular to the circle's [`Up`] axis, +y by
//!   default; Blender and D-NeRF scenes are +z up), looking at the centre, all at one time
//!   ("frozen time"). With +y up the first camera is on the +z side and the azimuth advances
//!   from +z towards +x; with another axis up, [`Up::basis`] names the two directions.
//! - [`spiral`]: one turn like the orbit while time advances evenly from `t0` to `t1` and the
//!   elevation rises from `-elevation` to `+elevation`.
//! - A path file: `[{"camera": {camera JSON}, "time": t}, ...]` ([`crate::io::path_file`]).

pub use crate::model::Up;
use crate::model::{Camera, Error, Result, Scene};
use crate::volume::scene_sphere;

/// Most frames one camera path may have: an orbit's or a spiral's `frames`, and a
/// keyframed path file's `fps × seconds` ([`crate::io::path_file`]). Every frame is a
/// camera kept in memory and an image written: a count from a flag or a file is checked
/// against this before anything is sized by it.
pub const MAX_PATH_FRAMES: usize = 100_000;

/// One frame of a path.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PathFrame {
    /// The camera.
    pub camera: Camera,
    /// Scene time.
    pub time: f64,
}

/// The look of every generated camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Lens {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Vertical field of view, degrees.
    pub fov_y_degrees: f64,
}

/// A circle of cameras around a centre.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Circle {
    /// What the cameras look at.
    pub centre: [f64; 3],
    /// Distance from the centre.
    pub radius: f64,
    /// Degrees above the horizontal plane.
    pub elevation_degrees: f64,
    /// Number of frames.
    pub frames: usize,
    /// The axis the circle turns about, and the cameras' up.
    pub up: Up,
}

/// `x + (y - x) s`, or `x (1 - s) + y s` where `y - x` overflows (ends of ±1e308): finite
/// for finite ends and `s` in `[0, 1]`.
#[must_use]
pub fn lerp(x: f64, y: f64, s: f64) -> f64 {
    let span = y - x;
    if span.is_finite() {
        x + span * s
    } else {
        x * (1.0 - s) + y * s
    }
}

/// `n` times evenly over `[t0, t1]`, ends included (`t0` alone when `n = 1`):
/// `t_k = t0 + (t1 - t0) k / (n - 1)` ([`lerp`]).
#[must_use]
pub fn even_times([t0, t1]: [f64; 2], n: usize) -> Vec<f64> {
    (0..n)
        .map(|k| {
            if n == 1 {
                t0
            } else {
                lerp(t0, t1, k as f64 / (n - 1) as f64)
            }
        })
        .collect()
}

/// Distance from a ball of `radius` at which a camera with `lens` sees all of it with a 5%
/// margin: `1.05 r / sin(half)`, with `half` half the narrower of the vertical and the
/// horizontal field of view. Every framing in the crate (orbits, spirals, dataset cameras,
/// bench cameras) uses this one rule.
#[must_use]
pub fn framing_distance(radius: f64, lens: &Lens) -> f64 {
    let half = 0.5
        * lens
            .fov_y_degrees
            .to_radians()
            .min(2.0 * (f64::from(lens.width) / f64::from(lens.height)).atan());
    1.05 * radius / half.sin()
}

/// The circle about `up` that frames the sphere a fitted scene records
/// ([`Scene::framing`]), else every kernel of `scene` alive at `times` (slice centres ± 3σ,
/// at cut-off `cutoff`): centred on it at [`framing_distance`], 20° above the plane, 60
/// frames. A scene with nothing alive gets the unit ball at the origin.
#[must_use]
pub fn framing_circle(scene: &Scene, times: &[f64], cutoff: f64, lens: &Lens, up: Up) -> Circle {
    // A fitted scene is framed on what its data's cameras looked at (its kernels may reach
    // far beyond the object: faint or dark ones the images never showed).
    let (centre, r) = scene
        .framing
        .or_else(|| scene_sphere(scene, times, cutoff))
        .unwrap_or(([0.0; 3], 3f64.sqrt()));
    Circle {
        centre,
        radius: framing_distance(r, lens),
        elevation_degrees: 20.0,
        frames: 60,
        up,
    }
}

/// The times a video of the scene shows by default: the time range of the data it was
/// fitted to when it records one, else the range `[t0, t1]` of its kernels' time means
/// (`[0, 0]` for an empty scene).
#[must_use]
pub fn time_range(scene: &Scene) -> [f64; 2] {
    if let Some(range) = scene.time_range {
        return range;
    }
    if scene.is_empty() {
        return [0.0; 2];
    }
    scene
        .means
        .iter()
        .fold([f64::INFINITY, f64::NEG_INFINITY], |[lo, hi], m| {
            [lo.min(m[3]), hi.max(m[3])]
        })
}

fn camera_at(circle: &Circle, lens: &Lens, azimuth: f64, elevation_degrees: f64) -> Result<Camera> {
    let e = elevation_degrees.to_radians();
    let c = circle.centre;
    let (up, side, front) = circle.up.basis();
    // Written term by term so that +y up gives exactly the numbers it always gave.
    let eye: [f64; 3] = std::array::from_fn(|k| {
        c[k] + circle.radius * e.cos() * azimuth.sin() * side[k]
            + circle.radius * e.sin() * up[k]
            + circle.radius * e.cos() * azimuth.cos() * front[k]
    });
    Camera::look_at(eye, c, up, lens.fov_y_degrees, lens.width, lens.height)
}

fn check(circle: &Circle) -> Result<()> {
    let origin = "<camera path>";
    if !(1..=MAX_PATH_FRAMES).contains(&circle.frames) {
        return Err(Error::invalid(
            origin,
            "path",
            "frames",
            format!(
                "{} frames; from 1 to {MAX_PATH_FRAMES} are allowed",
                circle.frames
            ),
        ));
    }
    if !(circle.radius.is_finite() && circle.radius > 0.0) {
        return Err(Error::invalid(
            origin,
            "path",
            "radius",
            format!("{} must be finite and > 0", circle.radius),
        ));
    }
    if circle.elevation_degrees.is_nan() || circle.elevation_degrees.abs() >= 90.0 {
        return Err(Error::invalid(
            origin,
            "path",
            "elevation",
            format!(
                "{} must be strictly between -90 and 90 degrees",
                circle.elevation_degrees
            ),
        ));
    }
    Ok(())
}

/// An orbit at a fixed `time`.
pub fn orbit(circle: &Circle, lens: &Lens, time: f64) -> Result<Vec<PathFrame>> {
    check(circle)?;
    (0..circle.frames)
        .map(|k| {
            let azimuth = std::f64::consts::TAU * k as f64 / circle.frames as f64;
            Ok(PathFrame {
                camera: camera_at(circle, lens, azimuth, circle.elevation_degrees)?,
                time,
            })
        })
        .collect()
}

/// A spiral: one turn while time goes from `t0` to `t1` (both included) and the elevation
/// rises from `-elevation` to `+elevation`.
pub fn spiral(circle: &Circle, lens: &Lens, [t0, t1]: [f64; 2]) -> Result<Vec<PathFrame>> {
    check(circle)?;
    let n = circle.frames;
    (0..n)
        .map(|k| {
            let s = if n > 1 {
                k as f64 / (n - 1) as f64
            } else {
                0.0
            };
            let azimuth = std::f64::consts::TAU * s;
            let elevation = circle.elevation_degrees * (2.0 * s - 1.0);
            Ok(PathFrame {
                camera: camera_at(circle, lens, azimuth, elevation)?,
                time: lerp(t0, t1, s),
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn orbit_cameras_circle_the_centre_and_look_at_it() {
        let circle = Circle {
            centre: [1.0, 2.0, 3.0],
            radius: 4.0,
            elevation_degrees: 30.0,
            frames: 8,
            up: Default::default(),
        };
        let lens = Lens {
            width: 64,
            height: 48,
            fov_y_degrees: 40.0,
        };
        let frames = orbit(&circle, &lens, 0.25).unwrap();
        assert_eq!(frames.len(), 8);
        for f in &frames {
            let eye = f.camera.centre();
            let d: Vec<f64> = (0..3).map(|a| eye[a] - circle.centre[a]).collect();
            assert!(((d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() - 4.0).abs() < 1e-9);
            assert!((d[1] - 4.0 * 0.5).abs() < 1e-9, "elevation 30°");
            // The centre projects to the principal point.
            let m = f.camera.world_to_camera;
            let p: Vec<f64> = (0..3)
                .map(|r| (0..3).map(|c| m[r][c] * circle.centre[c]).sum::<f64>() + m[r][3])
                .collect();
            assert!(p[0].abs() < 1e-9 && p[1].abs() < 1e-9 && p[2] > 0.0);
            assert_eq!(f.time, 0.25);
        }
        let s = spiral(&circle, &lens, [0.0, 1.0]).unwrap();
        assert_eq!((s[0].time, s[7].time), (0.0, 1.0));
        assert!(
            s[0].camera.centre()[1] < circle.centre[1]
                && s[7].camera.centre()[1] > circle.centre[1]
        );
        assert!(
            orbit(
                &Circle {
                    frames: 0,
                    ..circle
                },
                &lens,
                0.0
            )
            .is_err()
        );
        assert!(
            orbit(
                &Circle {
                    elevation_degrees: 90.0,
                    ..circle
                },
                &lens,
                0.0
            )
            .is_err()
        );
    }

    #[test]
    fn orbits_turn_about_the_up_axis_they_are_given() {
        let lens = Lens {
            width: 32,
            height: 24,
            fov_y_degrees: 40.0,
        };
        for (up, axis, sign) in [(Up::Z, 2, 1.0), (Up::NegY, 1, -1.0), (Up::X, 0, 1.0)] {
            let circle = Circle {
                centre: [1.0, 2.0, 3.0],
                radius: 4.0,
                elevation_degrees: 30.0,
                frames: 12,
                up,
            };
            for frame in orbit(&circle, &lens, 0.0).unwrap() {
                let eye = frame.camera.centre();
                // Every eye is 2 units (r sin 30°) above the centre along the up axis...
                let height = sign * (eye[axis] - circle.centre[axis]);
                assert!((height - 2.0).abs() < 1e-9, "{up:?}: {eye:?}");
                // ...and image-up (camera -y, OpenCV) leans towards the up axis.
                let down = frame.camera.rotation()[1];
                assert!(sign * down[axis] < -0.5, "{up:?}: camera y {down:?}");
            }
        }
        assert_eq!("-z".parse::<Up>().unwrap(), Up::NegZ);
        assert_eq!("+x".parse::<Up>().unwrap(), Up::X);
        assert!("w".parse::<Up>().is_err());
    }
}
