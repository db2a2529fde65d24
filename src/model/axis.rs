//! The world's up direction: one of the six signed axes.
//!
//! Orbits and spirals (`scenes::paths`) turn about it; a scene fitted from a dataset carries
//! the axis nearest its training cameras' mean up (image up, the camera's -y in OpenCV axes,
//! SPEC §3), so that videos of it stand the right way without a flag.

use serde::{Deserialize, Serialize};

/// A world axis with its sign: the up direction of orbits and spirals.
///
/// Not part of SPEC's math: a world's convention beside SPEC §3's camera axes. In a scene file
/// it is the key `up` (`"z"`, `"-y"`, …).
///
/// ```
/// use splat4d::model::Up;
/// let (up, _side, _front) = Up::Z.basis();
/// assert_eq!(up, [0.0, 0.0, 1.0]);
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(try_from = "String", into = "String")]
pub enum Up {
    /// +x.
    X,
    /// +y (OpenGL, glTF, the project's own scenes).
    #[default]
    Y,
    /// +z (Blender, D-NeRF, nerfstudio).
    Z,
    /// -x.
    NegX,
    /// -y (OpenCV camera conventions).
    NegY,
    /// -z.
    NegZ,
}

impl Up {
    /// `(up, side, front)`: the first camera of an orbit sits along `front` from the
    /// centre, and the azimuth turns it towards `side`. For +y: (+y, +x, +z).
    #[must_use]
    pub fn basis(self) -> ([f64; 3], [f64; 3], [f64; 3]) {
        let axis = |k: usize, sign: f64| {
            let mut v = [0.0; 3];
            v[k] = sign;
            v
        };
        let (k, sign) = match self {
            Up::X => (0, 1.0),
            Up::Y => (1, 1.0),
            Up::Z => (2, 1.0),
            Up::NegX => (0, -1.0),
            Up::NegY => (1, -1.0),
            Up::NegZ => (2, -1.0),
        };
        (
            axis(k, sign),
            axis((k + 2) % 3, 1.0),
            axis((k + 1) % 3, 1.0),
        )
    }
}

impl std::str::FromStr for Up {
    type Err = String;
    fn from_str(text: &str) -> std::result::Result<Self, String> {
        match text.trim_start_matches('+') {
            "x" => Ok(Up::X),
            "y" => Ok(Up::Y),
            "z" => Ok(Up::Z),
            "-x" => Ok(Up::NegX),
            "-y" => Ok(Up::NegY),
            "-z" => Ok(Up::NegZ),
            _ => Err(format!(
                "`{text}` is not an axis: use x, y, z, -x, -y or -z"
            )),
        }
    }
}

impl Up {
    /// The name `--up` and scene files use: `x`, `y`, `z`, `-x`, `-y` or `-z`.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Up::X => "x",
            Up::Y => "y",
            Up::Z => "z",
            Up::NegX => "-x",
            Up::NegY => "-y",
            Up::NegZ => "-z",
        }
    }

    /// The signed axis nearest the direction `v`; `None` when `v` is zero or not finite.
    #[must_use]
    pub fn nearest(v: [f64; 3]) -> Option<Up> {
        if !v.iter().all(|x| x.is_finite()) {
            return None;
        }
        let (axis, value) = v
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.abs().total_cmp(&b.1.abs()))?;
        if *value == 0.0 {
            return None;
        }
        Some(match (axis, *value > 0.0) {
            (0, true) => Up::X,
            (0, false) => Up::NegX,
            (1, true) => Up::Y,
            (1, false) => Up::NegY,
            (2, true) => Up::Z,
            _ => Up::NegZ,
        })
    }
}

impl TryFrom<String> for Up {
    type Error = String;
    fn try_from(text: String) -> std::result::Result<Self, String> {
        text.parse()
    }
}

impl From<Up> for String {
    fn from(up: Up) -> String {
        up.name().to_owned()
    }
}

impl std::fmt::Display for Up {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

#[cfg(test)]
mod tests {
    use super::Up;

    #[test]
    fn names_parse_back_and_the_nearest_axis_keeps_its_sign() {
        for up in [Up::X, Up::Y, Up::Z, Up::NegX, Up::NegY, Up::NegZ] {
            assert_eq!(up.name().parse::<Up>(), Ok(up));
            let (axis, _, _) = up.basis();
            assert_eq!(Up::nearest(axis), Some(up));
        }
        assert_eq!(Up::nearest([0.1, -0.3, 0.2]), Some(Up::NegY));
        assert_eq!(Up::nearest([0.0; 3]), None);
        assert_eq!(Up::nearest([f64::NAN, 1.0, 0.0]), None);
    }
}
