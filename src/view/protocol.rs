//! The page ↔ server messages.
//!
//! The page sends JSON text:
//!
//! | `type` | fields | answer |
//! |---|---|---|
//! | `frame` | `id`, `c2w` (16 numbers, row-major OpenGL camera-to-world), `fov` (vertical, degrees), `width`, `height`, `time`, `lossless` (optional) | a binary frame |
//! | `compare` | `id`, `view` (index into the hello's `views`) | a binary comparison: render, ground truth, error image, PSNR |
//! | `path` | `keyframes` (`c2w`, `fov`, `time` each), `fps`, `seconds`, `width`, `height` | `path`: the interpolated frames and the `camera_path.json` to save |
//!
//! The server sends JSON text (`hello` on connecting, `path`, `live`, `error`) and binary
//! messages: a 4-byte little-endian header length, the header as JSON (with `parts`: the
//! name, MIME type and byte count of each image that follows), then the images' bytes.
//! Anything malformed is answered with `{"type": "error", "message": …}` naming the field.

use std::io::Cursor;

use serde::Deserialize;

use crate::io::path_file::keyframes_file_json;
use crate::model::{Camera, Error, Result};
use crate::scenes::keyframes::{Keyframe, Pose, check_keyframes, interpolate};
use crate::view::MAX_SIDE;

/// Most frames a page's path may ask for.
pub const MAX_PAGE_PATH_FRAMES: f64 = 10_000.0;

/// JPEG quality of frames (lossy ones).
pub const JPEG_QUALITY: u8 = 90;

/// A message from the page.
#[derive(Debug, Deserialize)]
#[serde(tag = "type", rename_all = "lowercase")]
pub enum Request {
    /// Render a frame.
    Frame(FrameRequest),
    /// Compare with a dataset view.
    Compare {
        /// The page's request number.
        id: u64,
        /// Index of the view.
        view: usize,
    },
    /// Interpolate a path through keyframes.
    Path(PathRequest),
}

/// A frame the page asks for.
#[derive(Clone, Debug, Deserialize)]
pub struct FrameRequest {
    /// The page's request number, echoed in the frame.
    pub id: u64,
    /// Row-major OpenGL camera-to-world matrix.
    pub c2w: Vec<f64>,
    /// Vertical field of view, degrees.
    pub fov: f64,
    /// Frame width, pixels.
    pub width: u32,
    /// Frame height, pixels.
    pub height: u32,
    /// Scene time.
    pub time: f64,
    /// PNG instead of JPEG.
    #[serde(default)]
    pub lossless: bool,
}

/// A keyframe placed on the page.
#[derive(Clone, Debug, Deserialize)]
pub struct PageKeyframe {
    /// Row-major OpenGL camera-to-world matrix.
    pub c2w: Vec<f64>,
    /// Vertical field of view, degrees.
    pub fov: f64,
    /// Scene time.
    pub time: f64,
}

/// A path the page asks to interpolate.
#[derive(Clone, Debug, Deserialize)]
pub struct PathRequest {
    /// The keyframes, in order.
    pub keyframes: Vec<PageKeyframe>,
    /// Frames per second.
    pub fps: f64,
    /// Duration, seconds.
    pub seconds: f64,
    /// Frame width of the saved path, pixels.
    pub width: u32,
    /// Frame height of the saved path, pixels.
    pub height: u32,
}

const ORIGIN: &str = "<page message>";

/// Parses a page's message.
pub fn parse_request(text: &str) -> Result<Request> {
    serde_json::from_str(text).map_err(|e| Error::invalid(ORIGIN, "message", "json", e.to_string()))
}

fn matrix(values: &[f64], item: &str) -> Result<[[f64; 4]; 4]> {
    if values.len() != 16 || values.iter().any(|v| !v.is_finite()) {
        return Err(Error::invalid(
            ORIGIN,
            item,
            "c2w",
            "16 finite numbers are required",
        ));
    }
    Ok(std::array::from_fn(|r| {
        std::array::from_fn(|c| values[4 * r + c])
    }))
}

fn side(value: u32, item: &str, field: &str) -> Result<u32> {
    if value == 0 {
        return Err(Error::invalid(
            ORIGIN,
            item,
            field,
            "at least 1 pixel is required",
        ));
    }
    Ok(value.min(MAX_SIDE))
}

impl FrameRequest {
    /// The camera and time of the frame; sides are clamped to [`MAX_SIDE`].
    pub fn camera(&self) -> Result<(Camera, f64)> {
        let item = "frame";
        let (width, height) = (
            side(self.width, item, "width")?,
            side(self.height, item, "height")?,
        );
        if !(self.fov > 0.0 && self.fov < 180.0) {
            return Err(Error::invalid(
                ORIGIN,
                item,
                "fov",
                "degrees in (0, 180) are required",
            ));
        }
        if !self.time.is_finite() {
            return Err(Error::invalid(
                ORIGIN,
                item,
                "time",
                "a finite number is required",
            ));
        }
        let camera = Camera::from_opengl_camera_to_world(
            width,
            height,
            Camera::centred_intrinsics(width, height, self.fov.to_radians()),
            matrix(&self.c2w, item)?,
        )?;
        Ok((camera, self.time))
    }
}

impl PathRequest {
    /// The `path` answer: the interpolated frames (`c2w`, `fov`, `time`) and the nerfstudio
    /// `camera_path.json` of the path. Every number in it is finite: keyframes too far apart
    /// for the interpolation in doubles (times of ±1e308, say) are refused, naming the field,
    /// rather than answered with numbers JSON can only write as `null`.
    pub fn answer(&self) -> Result<serde_json::Value> {
        let keyframes = self
            .keyframes
            .iter()
            .enumerate()
            .map(|(i, k)| {
                Ok(Keyframe {
                    camera_to_world: matrix(&k.c2w, &format!("keyframes[{i}]"))?,
                    fov_y_degrees: k.fov,
                    time: Some(k.time),
                })
            })
            .collect::<Result<Vec<_>>>()?;
        check_keyframes(&keyframes, ORIGIN)?;
        let item = "path";
        let (width, height) = (
            side(self.width, item, "width")?,
            side(self.height, item, "height")?,
        );
        let frames = (self.fps * self.seconds).round();
        if !(self.fps.is_finite()
            && self.fps > 0.0
            && (1.0..=MAX_PAGE_PATH_FRAMES).contains(&frames))
        {
            return Err(Error::invalid(
                ORIGIN,
                item,
                "seconds",
                format!("fps × seconds must give 1 to {MAX_PAGE_PATH_FRAMES} frames"),
            ));
        }
        let poses = interpolate(&keyframes, frames as usize);
        check_poses(&poses)?;
        let seconds = frames / self.fps;
        if !seconds.is_finite() {
            return Err(Error::invalid(
                ORIGIN,
                item,
                "fps",
                format!(
                    "{frames} frames at {} frames per second last longer than a double holds",
                    self.fps
                ),
            ));
        }
        let list: Vec<serde_json::Value> = poses
            .iter()
            .map(|p| {
                serde_json::json!({
                    "c2w": p.camera_to_world.iter().flatten().collect::<Vec<_>>(),
                    "fov": p.fov_y_degrees,
                    "time": p.time,
                })
            })
            .collect();
        Ok(serde_json::json!({
            "type": "path",
            "frames": list,
            "file": keyframes_file_json(&keyframes, &poses, [width, height], self.fps),
        }))
    }
}

/// Errors naming the first pose with a number that is not finite (the keyframes' times or
/// positions are too far apart for the interpolation's arithmetic).
fn check_poses(poses: &[Pose]) -> Result<()> {
    for (k, pose) in poses.iter().enumerate() {
        let item = format!("path frame {k}");
        let apart = |what: &str| {
            format!(
                "is not finite: the keyframes' {what} are too far apart to interpolate in double precision"
            )
        };
        if pose
            .camera_to_world
            .iter()
            .flatten()
            .any(|v| !v.is_finite())
        {
            return Err(Error::invalid(ORIGIN, item, "c2w", apart("positions")));
        }
        if !pose.fov_y_degrees.is_finite() {
            return Err(Error::invalid(ORIGIN, item, "fov", apart("fields of view")));
        }
        if pose.time.is_some_and(|t| !t.is_finite()) {
            return Err(Error::invalid(ORIGIN, item, "time", apart("times")));
        }
    }
    Ok(())
}

/// An 8-bit RGB image.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Rgb8 {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Row-major RGB bytes.
    pub bytes: Vec<u8>,
}

impl Rgb8 {
    /// The bytes a PNG of `image` stores (SPEC §5's quantisation, as `splat4d render`).
    #[must_use]
    pub fn from_image(image: &crate::model::Image) -> Self {
        Rgb8 {
            width: image.width,
            height: image.height,
            bytes: image
                .pixels
                .iter()
                .map(|&c| crate::model::image::quantize(c, 255) as u8)
                .collect(),
        }
    }

    /// Encodes as JPEG (`lossless`: PNG); returns the bytes and the MIME type.
    #[must_use]
    pub fn encode(&self, lossless: bool) -> (Vec<u8>, &'static str) {
        use image::ImageEncoder as _;
        let mut out = Cursor::new(Vec::with_capacity(self.bytes.len() / 8));
        let kind = image::ExtendedColorType::Rgb8;
        let (w, h) = (self.width, self.height);
        let (result, mime) = if lossless {
            let png = image::codecs::png::PngEncoder::new_with_quality(
                &mut out,
                image::codecs::png::CompressionType::Fast,
                image::codecs::png::FilterType::Sub,
            );
            (png.write_image(&self.bytes, w, h, kind), "image/png")
        } else {
            let mut bytes = out.into_inner();
            // Sides are at most MAX_SIDE, well within the format's 65535.
            let jpeg = jpeg_encoder::Encoder::new(&mut bytes, JPEG_QUALITY);
            jpeg.encode(
                &self.bytes,
                w as u16,
                h as u16,
                jpeg_encoder::ColorType::Rgb,
            )
            .expect("encoding an in-memory RGB image");
            return (bytes, "image/jpeg");
        };
        // In-memory encoding of a buffer of the right size cannot fail.
        result.expect("encoding an in-memory RGB image");
        (out.into_inner(), mime)
    }
}

/// A binary message: header length, header JSON with `parts` added, then the parts' bytes.
#[must_use]
pub fn pack(mut header: serde_json::Value, parts: &[(&str, &str, &[u8])]) -> Vec<u8> {
    let described: Vec<serde_json::Value> = parts
        .iter()
        .map(|(name, mime, bytes)| serde_json::json!({"name": name, "mime": mime, "bytes": bytes.len()}))
        .collect();
    header["parts"] = serde_json::Value::Array(described);
    let text = header.to_string();
    let total = 4 + text.len() + parts.iter().map(|p| p.2.len()).sum::<usize>();
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(&(text.len() as u32).to_le_bytes());
    out.extend_from_slice(text.as_bytes());
    for (_, _, bytes) in parts {
        out.extend_from_slice(bytes);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn malformed_messages_are_errors() {
        // `\u{7b}`: an opening brace alone, an object never closed (escaped, so that the
        // file's braces stay balanced for tools that count them line by line).
        for text in ["", "\u{7b}", "[]", r#"{"type":"frame"}"#, r#"{"type":"x"}"#] {
            assert!(parse_request(text).is_err(), "{text}");
        }
    }

    /// A frame request of a camera `c2w` (row-major 4×4), `w` pixels wide, 9 high, at
    /// vertical field of view `fov`.
    fn frame(c2w: &str, w: u32, fov: f64) -> FrameRequest {
        let text = format!(
            r#"{{"type":"frame","id":1,"c2w":{c2w},"fov":{fov},"width":{w},"height":9,"time":0}}"#
        );
        let Request::Frame(frame) = parse_request(&text).unwrap() else {
            panic!("not a frame")
        };
        frame
    }

    /// A camera 3 units along +z, looking down -z.
    const IDENTITY: &str = "[1,0,0,0, 0,1,0,0, 0,0,1,3, 0,0,0,1]";

    #[test]
    fn a_frame_wider_than_the_largest_side_is_clamped() {
        let (camera, _) = frame(IDENTITY, 99_999, 40.0).camera().unwrap();
        assert_eq!(camera.width, MAX_SIDE, "clamped");
    }

    #[test]
    fn a_frame_with_a_bad_camera_is_an_error_naming_the_field() {
        for (c2w, w, fov, field) in [
            ("[1,2,3]", 8, 40.0, "c2w"),
            (IDENTITY, 0, 40.0, "width"),
            (IDENTITY, 8, 180.0, "fov"),
        ] {
            let message = frame(c2w, w, fov).camera().unwrap_err().to_string();
            assert!(message.contains(field), "{message}");
        }
    }

    /// Every number of a path's answer, `None` where JSON holds something else (`null`).
    fn numbers(value: &serde_json::Value, out: &mut Vec<Option<f64>>) {
        match value {
            serde_json::Value::Number(n) => out.push(n.as_f64()),
            serde_json::Value::Null => out.push(None),
            serde_json::Value::Array(a) => a.iter().for_each(|v| numbers(v, out)),
            serde_json::Value::Object(o) => o.values().for_each(|v| numbers(v, out)),
            _ => {}
        }
    }

    #[test]
    fn a_path_answer_holds_finite_numbers_or_is_refused_naming_the_field() {
        let key = |x: f64, t: f64| {
            json_value(&format!(
                r#"{{"c2w":[1,0,0,{x}, 0,1,0,0, 0,0,1,5, 0,0,0,1],"fov":40,"time":{t}}}"#
            ))
        };
        let path = |keys: Vec<serde_json::Value>, fps: f64, seconds: f64| {
            let text = serde_json::json!({"type": "path", "keyframes": keys, "fps": fps,
                "seconds": seconds, "width": 32, "height": 24})
            .to_string();
            let Request::Path(p) = parse_request(&text).unwrap() else {
                panic!("not a path")
            };
            p.answer()
        };
        // Times of ±1e308 interpolate to finite times (`paths::lerp`); positions whose
        // distance overflows are refused naming the keyframe, never `null`s.
        for keys in [
            vec![key(0.0, -1e308), key(1.0, 1e308)],
            vec![key(0.0, 1e308), key(1.0, -1e308), key(0.0, 1e308)],
        ] {
            let answer = path(keys, 10.0, 1.0).unwrap();
            let mut all = Vec::new();
            numbers(&answer, &mut all);
            assert!(
                all.iter().all(|v| v.is_some_and(f64::is_finite)),
                "{answer}"
            );
        }
        for keys in [
            vec![key(-1e308, 0.0), key(1e308, 1.0)],
            vec![key(-1e308, 0.0), key(1e308, 1.0), key(-1e308, 2.0)],
        ] {
            let message = path(keys, 10.0, 1.0).unwrap_err().to_string();
            assert!(
                message.contains("keyframes[1]") && message.contains("too far"),
                "{message}"
            );
        }
        // An fps so small that the path's length overflows.
        let message = path(vec![key(0.0, 0.0)], 3e-309, 1.7e308)
            .unwrap_err()
            .to_string();
        assert!(message.contains("fps"), "{message}");
        // A path that can be answered holds only finite numbers.
        let answer = path(vec![key(0.0, -1e300), key(1.0, 1e300)], 10.0, 1.0).unwrap();
        let mut all = Vec::new();
        numbers(&answer, &mut all);
        assert!(all.len() > 100);
        assert!(
            all.iter().all(|v| v.is_some_and(f64::is_finite)),
            "{answer}"
        );
    }

    fn json_value(text: &str) -> serde_json::Value {
        serde_json::from_str(text).unwrap()
    }

    #[test]
    fn packed_messages_list_their_parts() {
        let bytes = pack(
            serde_json::json!({"type": "frame"}),
            &[("frame", "image/png", &[1, 2, 3])],
        );
        let n = u32::from_le_bytes(bytes[..4].try_into().unwrap()) as usize;
        let header: serde_json::Value =
            serde_json::from_str(std::str::from_utf8(&bytes[4..4 + n]).unwrap()).unwrap();
        assert_eq!(header["parts"][0]["bytes"], 3);
        assert_eq!(&bytes[4 + n..], &[1, 2, 3]);
    }
}
