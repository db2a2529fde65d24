//! Videos read through ffmpeg, run as a subprocess (it is never linked): `ffprobe` tells a
//! video's size and frame count from its packets (nothing decoded), and `ffmpeg` decodes its
//! first frames to raw 8-bit RGB through a pipe, scaled on the way when asked (`-vf scale`,
//! `flags=area`: the mean over each block, as `downscale` does for photos), one frame held
//! at a time. Without ffmpeg on `PATH` the error names it and the alternative: the frames
//! extracted as images.

use std::io::Read;
use std::path::Path;
use std::process::{Child, ChildStdout, Command, Stdio};
use std::thread::JoinHandle;

use crate::model::Image;
use crate::model::error::{Error, Result};

/// A video's first video stream as `ffprobe` counts it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct VideoInfo {
    pub width: u32,
    pub height: u32,
    /// Frames (packets of the stream: one per frame in MP4, H.264 and the like).
    pub frames: usize,
}

/// Most characters of ffmpeg's own messages quoted in an error.
const STDERR_QUOTE: usize = 600;

/// The error of a video that cannot be read because `tool` cannot be run.
fn tool_missing(path: &Path, tool: &str, e: &std::io::Error) -> Error {
    Error::malformed(
        &path.display().to_string(),
        format!(
            "reading a video needs ffmpeg: `{tool}` cannot be run ({e}); install ffmpeg (Debian: apt-get install ffmpeg), or extract the frames as images beside poses_bounds.npy, camNN/images/0000.png ... (ffmpeg -i camNN.mp4 camNN/images/%04d.png)"
        ),
    )
}

/// The size and frame count of the video `path`.
pub(super) fn probe(path: &Path) -> Result<VideoInfo> {
    let output = Command::new("ffprobe")
        .args(["-v", "error", "-select_streams", "v:0", "-count_packets"])
        .args(["-show_entries", "stream=width,height,nb_read_packets"])
        .args(["-of", "default=noprint_wrappers=1"])
        .arg(path)
        .stdin(Stdio::null())
        .output()
        .map_err(|e| tool_missing(path, "ffprobe", &e))?;
    let origin = path.display().to_string();
    let text = String::from_utf8_lossy(&output.stdout);
    let value = |key: &str| {
        text.lines()
            .find_map(|line| line.strip_prefix(key)?.strip_prefix('='))
            .and_then(|v| v.trim().parse::<usize>().ok())
    };
    match (value("width"), value("height"), value("nb_read_packets")) {
        (Some(w), Some(h), Some(frames)) if output.status.success() && w > 0 && h > 0 => {
            let size = |v: usize| u32::try_from(v).unwrap_or(u32::MAX);
            Ok(VideoInfo {
                width: size(w),
                height: size(h),
                frames,
            })
        }
        _ => Err(Error::malformed(
            &origin,
            format!(
                "not a video ffprobe can read: {}",
                crate::model::error::cut(
                    String::from_utf8_lossy(&output.stderr).trim(),
                    STDERR_QUOTE
                )
            ),
        )),
    }
}

/// A video being decoded by an `ffmpeg` subprocess, one frame at a time.
pub(super) struct Decoder {
    child: Child,
    stdout: ChildStdout,
    stderr: Option<JoinHandle<String>>,
    /// The frames' size as decoded.
    pub size: (u32, u32),
    /// Frames read so far.
    pub read: usize,
    origin: String,
}

impl Decoder {
    /// Starts decoding the first `frames` frames of `path`, scaled to `size` when it is not
    /// the video's own `native` size.
    pub fn start(path: &Path, native: (u32, u32), size: (u32, u32), frames: usize) -> Result<Self> {
        let mut command = Command::new("ffmpeg");
        command
            .args(["-nostdin", "-v", "error", "-i"])
            .arg(path)
            .args(["-map", "0:v:0", "-vsync", "passthrough"])
            .args(["-frames:v", &frames.to_string()]);
        if size != native {
            command.args(["-vf", &format!("scale={}:{}:flags=area", size.0, size.1)]);
        }
        command
            .args(["-f", "rawvideo", "-pix_fmt", "rgb24", "pipe:1"])
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped());
        let mut child = command
            .spawn()
            .map_err(|e| tool_missing(path, "ffmpeg", &e))?;
        let stdout = child.stdout.take().expect("stdout is piped");
        let stderr = child.stderr.take().map(|mut stderr| {
            std::thread::spawn(move || {
                let mut text = String::new();
                let _ = stderr.read_to_string(&mut text);
                text
            })
        });
        Ok(Decoder {
            child,
            stdout,
            stderr,
            size,
            read: 0,
            origin: path.display().to_string(),
        })
    }

    /// The next frame, linear RGB (8-bit values `v` read as `v / 255`, as photos are),
    /// or `None` at the end of the stream.
    pub fn next_frame(&mut self) -> Result<Option<Image>> {
        let (w, h) = self.size;
        let mut bytes = vec![0_u8; 3 * w as usize * h as usize];
        let mut filled = 0;
        while filled < bytes.len() {
            match self.stdout.read(&mut bytes[filled..]) {
                Ok(0) => break,
                Ok(n) => filled += n,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => {
                    return Err(Error::read(
                        Path::new(&self.origin),
                        "reading ffmpeg's output",
                        e,
                    ));
                }
            }
        }
        if filled == 0 {
            return Ok(None);
        }
        if filled < bytes.len() {
            return Err(Error::malformed(
                &self.origin,
                format!(
                    "ffmpeg stopped within frame {}: {filled} of its {} bytes",
                    self.read,
                    bytes.len()
                ),
            ));
        }
        self.read += 1;
        let u8f = |v: u8| (f64::from(u16::from(v) * 257) / 65535.0) as f32;
        Ok(Some(Image {
            width: w,
            height: h,
            pixels: bytes.into_iter().map(u8f).collect(),
        }))
    }

    /// Waits for ffmpeg to end; an error quoting its messages when it failed.
    pub fn finish(mut self) -> Result<()> {
        let mut rest = Vec::new();
        let _ = self.stdout.read_to_end(&mut rest);
        let status = self
            .child
            .wait()
            .map_err(|e| Error::read(Path::new(&self.origin), "waiting for ffmpeg", e))?;
        let stderr = self
            .stderr
            .take()
            .and_then(|t| t.join().ok())
            .unwrap_or_default();
        if !status.success() {
            return Err(Error::malformed(
                &self.origin,
                format!(
                    "ffmpeg could not decode it ({status}): {}",
                    crate::model::error::cut(stderr.trim(), STDERR_QUOTE)
                ),
            ));
        }
        Ok(())
    }
}

impl Drop for Decoder {
    fn drop(&mut self) {
        // A decoder dropped before its end (an error elsewhere) stops its own subprocess.
        if matches!(self.child.try_wait(), Ok(None)) {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}
