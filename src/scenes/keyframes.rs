//! Camera paths through keyframes: the one interpolation of `splat4d video --path` (a
//! nerfstudio `camera_path.json` holding only `keyframes`) and of the viewer's path
//! playback.
//!
//! A path of `n` frames through `K` keyframes gives each segment between consecutive
//! keyframes the same share of the frames: frame `k` sits at `s = k (K - 1) / (n - 1)`, so the
//! first frame is keyframe 0 and the last the last keyframe. Along a segment:
//!
//! - positions follow a centripetal Catmull–Rom spline (knot spacing `|ΔP|^½`, Barry and
//!   Goldman's pyramid), with the missing neighbours at the ends mirrored
//!   (`P₋₁ = 2P₀ − P₁`);
//! - orientations are slerped between the keyframes' rotations (shortest arc);
//! - the vertical field of view and the time are linear.
//!
//! Keyframes are OpenGL camera-to-world matrices (x right, y up, z backward), as nerfstudio
//! and [`crate::model::Camera::opengl_camera_to_world`] write them.

use glam::{DMat3, DQuat, DVec3};

use crate::model::{Camera, Error, Result};
use crate::scenes::paths::{PathFrame, lerp};

/// One keyframe: a pose, a field of view and (optionally) a scene time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Keyframe {
    /// Row-major OpenGL camera-to-world matrix.
    pub camera_to_world: [[f64; 4]; 4],
    /// Vertical field of view, degrees, in (0, 180).
    pub fov_y_degrees: f64,
    /// Scene time; `None` when the keyframe has none (the caller chooses).
    pub time: Option<f64>,
}

/// One interpolated pose.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    /// Row-major OpenGL camera-to-world matrix (orthonormal rotation).
    pub camera_to_world: [[f64; 4]; 4],
    /// Vertical field of view, degrees.
    pub fov_y_degrees: f64,
    /// Scene time, when every keyframe has one.
    pub time: Option<f64>,
}

impl Keyframe {
    fn position(&self) -> DVec3 {
        let m = &self.camera_to_world;
        DVec3::new(m[0][3], m[1][3], m[2][3])
    }

    /// The rotation of the matrix, its columns normalised (a scaled pose keeps its turn).
    fn rotation(&self) -> DQuat {
        let m = &self.camera_to_world;
        let column = |c: usize| DVec3::new(m[0][c], m[1][c], m[2][c]).normalize_or_zero();
        DQuat::from_mat3(&DMat3::from_cols(column(0), column(1), column(2))).normalize()
    }
}

/// Checks that every keyframe is usable: finite numbers, an invertible rotation, a field of
/// view in (0, 180) degrees, a finite time. Errors name the keyframe and field.
pub fn check_keyframes(keyframes: &[Keyframe], origin: &str) -> Result<()> {
    if keyframes.is_empty() {
        return Err(Error::invalid(
            origin,
            "camera path",
            "keyframes",
            "at least one keyframe is required",
        ));
    }
    for (i, key) in keyframes.iter().enumerate() {
        let item = format!("keyframes[{i}]");
        let bad = |field: &str, message: &str| Error::invalid(origin, &item, field, message);
        if key.camera_to_world.iter().flatten().any(|v| !v.is_finite()) {
            return Err(bad("matrix", "16 finite numbers are required"));
        }
        let m = &key.camera_to_world;
        let det = DMat3::from_cols_array_2d(&[
            [m[0][0], m[1][0], m[2][0]],
            [m[0][1], m[1][1], m[2][1]],
            [m[0][2], m[1][2], m[2][2]],
        ])
        .determinant();
        if det.abs() < 1e-9 {
            return Err(bad("matrix", "the rotation part is not invertible"));
        }
        if !(key.fov_y_degrees > 0.0 && key.fov_y_degrees < 180.0) {
            return Err(bad(
                "fov",
                "a vertical field of view in (0, 180) degrees is required",
            ));
        }
        if key.time.is_some_and(|t| !t.is_finite()) {
            return Err(bad("time", "a finite number is required"));
        }
        // The spline's knots are distances between neighbours: they must not overflow.
        if let Some(previous) = i.checked_sub(1).map(|p| &keyframes[p])
            && !(key.position() - previous.position()).length().is_finite()
        {
            return Err(bad(
                "matrix",
                &format!(
                    "the position is too far from keyframes[{}]'s to interpolate between them (their distance overflows)",
                    i - 1
                ),
            ));
        }
    }
    Ok(())
}

/// `frames` poses through `keyframes` (see the module docs); frame 0 is keyframe 0. Times
/// are interpolated only when every keyframe has one. `keyframes` must have passed
/// [`check_keyframes`].
#[must_use]
pub fn interpolate(keyframes: &[Keyframe], frames: usize) -> Vec<Pose> {
    let last = keyframes.len().saturating_sub(1);
    let all_timed = keyframes.iter().all(|k| k.time.is_some());
    (0..frames)
        .map(|k| {
            let s = if frames > 1 {
                k as f64 * last as f64 / (frames - 1) as f64
            } else {
                0.0
            };
            let segment = (s.floor() as usize).min(last.saturating_sub(1));
            let u = (s - segment as f64).clamp(0.0, 1.0);
            pose_at(keyframes, segment, u, all_timed)
        })
        .collect()
}

/// The pose at fraction `u` of the segment from keyframe `i` to `i + 1`.
fn pose_at(keyframes: &[Keyframe], i: usize, u: f64, timed: bool) -> Pose {
    let a = &keyframes[i];
    let Some(b) = keyframes.get(i + 1) else {
        return Pose {
            camera_to_world: orthonormal(a.rotation(), a.position()),
            fov_y_degrees: a.fov_y_degrees,
            time: a.time,
        };
    };
    let point = |j: isize| -> DVec3 {
        let n = keyframes.len() as isize;
        if j < 0 {
            2.0 * keyframes[0].position() - keyframes[1].position()
        } else if j >= n {
            2.0 * keyframes[(n - 1) as usize].position() - keyframes[(n - 2) as usize].position()
        } else {
            keyframes[j as usize].position()
        }
    };
    let i = i as isize;
    let position = centripetal_catmull_rom([point(i - 1), point(i), point(i + 1), point(i + 2)], u);
    let (qa, mut qb) = (a.rotation(), b.rotation());
    if qa.dot(qb) < 0.0 {
        qb = -qb;
    }
    let lerp = |x: f64, y: f64| lerp(x, y, u);
    Pose {
        camera_to_world: orthonormal(qa.slerp(qb, u).normalize(), position),
        fov_y_degrees: lerp(a.fov_y_degrees, b.fov_y_degrees),
        time: match (timed, a.time, b.time) {
            (true, Some(ta), Some(tb)) => Some(lerp(ta, tb)),
            _ => None,
        },
    }
}

/// The centripetal Catmull–Rom spline through `p[1]` (at `u = 0`) and `p[2]` (at `u = 1`).
/// Coincident control points get a tiny knot spacing instead of a division by zero.
fn centripetal_catmull_rom(p: [DVec3; 4], u: f64) -> DVec3 {
    if u <= 0.0 {
        return p[1];
    }
    if u >= 1.0 {
        return p[2];
    }
    let scale = p[1].distance(p[2]).max(1e-12);
    let spacing = |x: DVec3, y: DVec3| x.distance(y).sqrt().max(1e-6 * scale.sqrt());
    let t0 = 0.0;
    let t1 = t0 + spacing(p[0], p[1]);
    let t2 = t1 + spacing(p[1], p[2]);
    let t3 = t2 + spacing(p[2], p[3]);
    let t = t1 + u * (t2 - t1);
    let mix =
        |a: DVec3, b: DVec3, ta: f64, tb: f64| (tb - t) / (tb - ta) * a + (t - ta) / (tb - ta) * b;
    let a1 = mix(p[0], p[1], t0, t1);
    let a2 = mix(p[1], p[2], t1, t2);
    let a3 = mix(p[2], p[3], t2, t3);
    let b1 = mix(a1, a2, t0, t2);
    let b2 = mix(a2, a3, t1, t3);
    mix(b1, b2, t1, t2)
}

/// The row-major camera-to-world matrix of a rotation and a position.
fn orthonormal(rotation: DQuat, position: DVec3) -> [[f64; 4]; 4] {
    let r = DMat3::from_quat(rotation);
    std::array::from_fn(|row| {
        if row == 3 {
            [0.0, 0.0, 0.0, 1.0]
        } else {
            [r.col(0)[row], r.col(1)[row], r.col(2)[row], position[row]]
        }
    })
}

/// The frames of a path of `poses` at `width × height`; a pose without a time takes
/// `fallback_time(frame index)`.
pub fn path_frames(
    poses: &[Pose],
    width: u32,
    height: u32,
    fallback_time: impl Fn(usize) -> f64,
) -> Result<Vec<PathFrame>> {
    poses
        .iter()
        .enumerate()
        .map(|(k, pose)| {
            let camera = Camera::from_opengl_camera_to_world(
                width,
                height,
                Camera::centred_intrinsics(width, height, pose.fov_y_degrees.to_radians()),
                pose.camera_to_world,
            )?;
            Ok(PathFrame {
                camera,
                time: pose.time.unwrap_or_else(|| fallback_time(k)),
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn key(x: f64, yaw: f64, fov: f64, time: f64) -> Keyframe {
        let (s, c) = yaw.sin_cos();
        Keyframe {
            camera_to_world: [
                [c, 0.0, s, x],
                [0.0, 1.0, 0.0, 0.0],
                [-s, 0.0, c, 5.0],
                [0.0, 0.0, 0.0, 1.0],
            ],
            fov_y_degrees: fov,
            time: Some(time),
        }
    }

    #[test]
    fn times_of_plus_minus_1e308_interpolate_to_finite_times() {
        let keys = [key(0.0, 0.0, 50.0, -1e308), key(1.0, 0.3, 50.0, 1e308)];
        check_keyframes(&keys, "path.json").unwrap();
        let poses = interpolate(&keys, 5);
        let times: Vec<f64> = poses.iter().map(|p| p.time.unwrap()).collect();
        assert!(times.iter().all(|t| t.is_finite()), "{times:?}");
        assert_eq!((times[0], times[2], times[4]), (-1e308, 0.0, 1e308));
    }

    #[test]
    fn keyframes_too_far_apart_to_interpolate_are_refused_naming_the_keyframe() {
        let keys = [key(-1e308, 0.0, 50.0, 0.0), key(1e308, 0.3, 50.0, 1.0)];
        let message = check_keyframes(&keys, "path.json").unwrap_err().to_string();
        assert!(
            message.contains("keyframes[1]") && message.contains("`matrix`"),
            "{message}"
        );
    }

    #[test]
    fn the_path_starts_and_ends_on_its_keyframes() {
        let keys = [
            key(0.0, 0.0, 40.0, 0.0),
            key(1.0, 0.5, 60.0, 1.0),
            key(3.0, 1.0, 50.0, 2.0),
        ];
        check_keyframes(&keys, "<test>").unwrap();
        let poses = interpolate(&keys, 9);
        assert_eq!(poses.len(), 9);
        for (pose, key) in [
            (&poses[0], &keys[0]),
            (&poses[4], &keys[1]),
            (&poses[8], &keys[2]),
        ] {
            for (a, b) in pose
                .camera_to_world
                .iter()
                .flatten()
                .zip(key.camera_to_world.iter().flatten())
            {
                assert!((a - b).abs() < 1e-12, "{a} vs {b}");
            }
            assert_eq!(pose.fov_y_degrees, key.fov_y_degrees);
            assert_eq!(pose.time, key.time);
        }
        // Halfway through the first segment: fov and time linear, yaw slerped.
        let half = interpolate(&keys, 5)[1];
        assert!((half.fov_y_degrees - 50.0).abs() < 1e-12);
        assert_eq!(half.time, Some(0.5));
        let yaw = half.camera_to_world[0][2].atan2(half.camera_to_world[0][0]);
        assert!((yaw - 0.25).abs() < 1e-12, "{yaw}");
    }

    #[test]
    fn collinear_evenly_spaced_keys_give_a_straight_path() {
        let keys = [
            key(0.0, 0.0, 40.0, 0.0),
            key(1.0, 0.0, 40.0, 1.0),
            key(2.0, 0.0, 40.0, 2.0),
        ];
        for pose in interpolate(&keys, 11) {
            let x = pose.camera_to_world[0][3];
            assert!((x - pose.time.unwrap()).abs() < 1e-9, "{x}");
        }
        // Repeated keyframes do not divide by zero.
        let still = [key(1.0, 0.0, 40.0, 0.0), key(1.0, 0.0, 40.0, 1.0)];
        assert!(
            interpolate(&still, 4)
                .iter()
                .all(|p| p.camera_to_world[0][3] == 1.0)
        );
    }
}
