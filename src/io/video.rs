//! Video files from frames rendered by the caller: numbered 8-bit PNG frames (`DIR/NAME/frame_0000.png`, ...), an
//! animated GIF (`DIR/NAME.gif`, looping) and, when `ffmpeg` is on `PATH`, an MP4
//! (`DIR/NAME.mp4`, H.264, yuv420p).
//!
//! Frames are asked for (rendered above this layer) one at a time, in order, and written
//! (PNG, GIF frame) on a second thread while the next one renders — the PNG's quantisation
//! and deflate no longer add to every frame's render — so memory holds two frames whatever
//! the video's length. Every file is written atomically; the GIF and MP4 appear only once
//! complete.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::mpsc;

use image::codecs::gif::{GifEncoder, Repeat};
use image::{Delay, Frame, RgbaImage};

use crate::io::image_file::{BitDepth, save_image};
use crate::io::write_atomically;
use crate::model::image::quantize_all;
use crate::model::{Error, Image, Result};

/// Largest side of a GIF frame (the format stores sides in 16 bits).
pub const MAX_GIF_SIDE: u32 = 65_535;

/// What was written for one video.
#[derive(Clone, Debug, PartialEq)]
pub struct VideoFiles {
    /// The folder of numbered frames.
    pub frames_dir: PathBuf,
    /// Number of frames.
    pub frames: usize,
    /// The GIF, if written.
    pub gif: Option<PathBuf>,
    /// The MP4, if `ffmpeg` was found and succeeded.
    pub mp4: Option<PathBuf>,
    /// Why there is no MP4, when there is none.
    pub mp4_note: Option<String>,
}

/// Options of [`write_video`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VideoOptions {
    /// Frames per second of the GIF and MP4.
    pub fps: u32,
    /// Write the GIF.
    pub gif: bool,
    /// Try `ffmpeg` for an MP4.
    pub mp4: bool,
}

impl Default for VideoOptions {
    fn default() -> Self {
        VideoOptions {
            fps: 25,
            gif: true,
            mp4: true,
        }
    }
}

/// The frame as the GIF encoder's RGBA, quantised a band at a time (no whole-frame copy of
/// the levels beside the RGBA one: 3 bytes a pixel less at the peak).
fn to_rgba8(image: &Image) -> RgbaImage {
    const BAND: usize = 3 << 14;
    let mut data = Vec::with_capacity(image.pixels.len() / 3 * 4);
    for band in image.pixels.chunks(BAND) {
        let levels: Vec<u8> = quantize_all(band);
        data.extend(levels.chunks_exact(3).flat_map(|p| [p[0], p[1], p[2], 255]));
    }
    RgbaImage::from_raw(image.width, image.height, data).expect("sizes match")
}

/// Writes `frame_count` frames into `dir/name/`, `dir/name.gif` and `dir/name.mp4`, and the
/// frame folder's [`MARKER`](crate::io::output::MARKER) recording the GIF, the MP4 and the
/// files of `beside` (written into `dir` by the caller for this video, such as its camera
/// path). `dir` is a staging folder ([`crate::io::output::Staging`]) that the caller moves
/// into place, `shown` the folder it will be moved to (the paths returned are there).
/// `next_frame(k, image)` fills `image` with frame `k`; it is called once per frame, in
/// order, on the calling thread.
///
/// Frame `k` is written (its PNG, its GIF frame) on a second thread while frame `k + 1` is
/// rendered: the files are the same bytes as when written in turn, at the cost of one more
/// frame in memory (the channel between the two holds none: the render waits until the
/// writer takes its frame). The first error wins: a failed frame stops the writer, a failed
/// write stops the renders; either way the staging folder holds no GIF or MP4 of the video.
pub fn write_video(
    frame_count: usize,
    dir: &Path,
    shown: &Path,
    name: &str,
    options: &VideoOptions,
    beside: &[PathBuf],
    mut next_frame: impl FnMut(usize, &mut Image) -> Result<()>,
) -> Result<VideoFiles> {
    if options.fps == 0 {
        return Err(Error::setting(&["fps"], "`fps` must be at least 1"));
    }
    let frames_dir = dir.join(name);
    std::fs::create_dir(&frames_dir)
        .map_err(|e| Error::write(&shown.join(name), "cannot create the frame folder", e))?;
    let gif_path = options.gif.then(|| dir.join(format!("{name}.gif")));
    std::thread::scope(|scope| {
        let (to_writer, frames) = mpsc::sync_channel::<(usize, Image)>(0);
        let (to_renderer, spare) = mpsc::channel::<Image>();
        let writer = scope.spawn(|| {
            write_frames(
                frames,
                to_renderer,
                frame_count,
                &frames_dir,
                gif_path.as_deref(),
                options.fps,
            )
        });
        let rendered = (|| {
            let mut screen = None;
            for k in 0..frame_count {
                let mut image = spare.try_recv().unwrap_or_default();
                next_frame(k, &mut image)?;
                // A GIF has one screen, the first frame's: a frame of another size would
                // lie outside it.
                let (w0, h0) = *screen.get_or_insert((image.width, image.height));
                if options.gif && (image.width, image.height) != (w0, h0) {
                    return Err(Error::setting(
                        &["gif"],
                        format!(
                            "frame {k} is {}×{} but frame 0 is {w0}×{h0}: a GIF has one screen size; give every frame one size or no GIF",
                            image.width, image.height
                        ),
                    ));
                }
                if options.gif && (image.width > MAX_GIF_SIDE || image.height > MAX_GIF_SIDE) {
                    return Err(Error::setting(
                        &["size", "gif"],
                        format!(
                            "{}×{} frames do not fit a GIF (at most {MAX_GIF_SIDE} pixels a side): give a smaller `size` or no GIF",
                            image.width, image.height
                        ),
                    ));
                }
                if to_writer.send((k, image)).is_err() {
                    // The writer stopped on an error: it is returned below.
                    break;
                }
            }
            Ok(())
        })();
        // No more frames: the writer finishes (or, short of frames, fails).
        drop(to_writer);
        let written = writer
            .join()
            .unwrap_or_else(|panic| std::panic::resume_unwind(panic));
        rendered.and(written)
    })?;
    let (mp4, mp4_note) = if options.mp4 {
        encode_mp4(&frames_dir, dir, name, options.fps)
    } else {
        (None, None)
    };
    // What a later run may replace or remove as this run's: the files and their stamps.
    let mut recorded: Vec<PathBuf> = gif_path.iter().chain(&mp4).cloned().collect();
    recorded.extend(beside.iter().cloned());
    crate::io::output::write_marker(&frames_dir, "video", &recorded)?;
    let at = |path: &Path| shown.join(path.file_name().unwrap_or_default());
    Ok(VideoFiles {
        frames_dir: shown.join(name),
        frames: frame_count,
        gif: gif_path.as_deref().map(at),
        mp4: mp4.as_deref().map(at),
        mp4_note,
    })
}

/// The writer's side of [`write_video`]: each frame received is written to
/// `folder/frame_KKKK.png` and appended to the GIF at `gif` (when given), then handed back
/// to the renderer for reuse. The GIF is renamed into place only once all `frame_count`
/// frames are in; a renderer that stops early leaves no GIF.
fn write_frames(
    frames: mpsc::Receiver<(usize, Image)>,
    spare: mpsc::Sender<Image>,
    frame_count: usize,
    folder: &Path,
    gif: Option<&Path>,
    fps: u32,
) -> Result<()> {
    let write_png = |k: usize, image: &Image| {
        save_image(
            image,
            &folder.join(format!("frame_{k:04}.png")),
            BitDepth::Eight,
        )
    };
    let Some(gif) = gif else {
        for (k, image) in frames {
            write_png(k, &image)?;
            // A renderer that has stopped takes no more frames back.
            let _ = spare.send(image);
        }
        return Ok(());
    };
    let delay = Delay::from_numer_denom_ms(1000, fps);
    let mut failure = None;
    let written = write_atomically(gif, |w| {
        let mut encoder = GifEncoder::new_with_speed(w, 10);
        encoder
            .set_repeat(Repeat::Infinite)
            .map_err(std::io::Error::other)?;
        let mut received = 0;
        for (k, image) in &frames {
            if let Err(e) = write_png(k, &image) {
                failure = Some(e);
                return Err(std::io::Error::other("a frame failed"));
            }
            let rgba = to_rgba8(&image);
            let _ = spare.send(image);
            encoder
                .encode_frame(Frame::from_parts(rgba, 0, 0, delay))
                .map_err(std::io::Error::other)?;
            received += 1;
        }
        if received < frame_count {
            // The renderer failed: its error is the one reported.
            return Err(std::io::Error::other("the frames stopped early"));
        }
        Ok(())
    });
    if let Some(e) = failure {
        return Err(e);
    }
    written
}

/// The GIF and MP4 of the `frame_count` frames already in `frames_dir` (as [`write_video`]
/// wrote them, `frame_KKKK.png`), written into `dir` (a staging folder moved to `shown` by
/// the caller): the same bytes as [`write_video`]'s from the images the frames were made of
/// (an 8-bit PNG holds the levels the GIF's frame is quantised to). The caller writes the
/// frame folder's marker once the files are in place.
pub fn encode_frames(
    frame_count: usize,
    frames_dir: &Path,
    dir: &Path,
    shown: &Path,
    name: &str,
    options: &VideoOptions,
) -> Result<VideoFiles> {
    if options.fps == 0 {
        return Err(Error::setting(&["fps"], "`fps` must be at least 1"));
    }
    let read_frame = |k: usize| -> Result<RgbaImage> {
        let path = frames_dir.join(format!("frame_{k:04}.png"));
        let image = image::ImageReader::open(&path)
            .map_err(|e| Error::read(&path, "cannot read the frame", e))?
            .decode()
            .map_err(|e| Error::read(&path, "cannot decode the frame", std::io::Error::other(e)))?;
        Ok(image.to_rgba8())
    };
    let gif_path = options.gif.then(|| dir.join(format!("{name}.gif")));
    if let Some(gif) = &gif_path {
        let delay = Delay::from_numer_denom_ms(1000, options.fps);
        let mut failure = None;
        let written = write_atomically(gif, |w| {
            let mut encoder = GifEncoder::new_with_speed(w, 10);
            encoder
                .set_repeat(Repeat::Infinite)
                .map_err(std::io::Error::other)?;
            let mut screen = None;
            for k in 0..frame_count {
                let rgba = match read_frame(k) {
                    Ok(rgba) => rgba,
                    Err(e) => {
                        failure = Some(e);
                        return Err(std::io::Error::other("a frame failed"));
                    }
                };
                let (w0, h0) = *screen.get_or_insert(rgba.dimensions());
                if rgba.dimensions() != (w0, h0) || w0 > MAX_GIF_SIDE || h0 > MAX_GIF_SIDE {
                    failure = Some(Error::setting(
                        &["gif"],
                        format!(
                            "frame {k} is {}×{} and frame 0 {w0}×{h0}: a GIF has one screen size of at most {MAX_GIF_SIDE} pixels a side; give every frame one size or no GIF",
                            rgba.width(),
                            rgba.height()
                        ),
                    ));
                    return Err(std::io::Error::other("a frame failed"));
                }
                encoder
                    .encode_frame(Frame::from_parts(rgba, 0, 0, delay))
                    .map_err(std::io::Error::other)?;
            }
            Ok(())
        });
        if let Some(e) = failure {
            return Err(e);
        }
        written?;
    }
    let (mp4, mp4_note) = if options.mp4 {
        encode_mp4(frames_dir, dir, name, options.fps)
    } else {
        (None, None)
    };
    let at = |path: &Path| shown.join(path.file_name().unwrap_or_default());
    Ok(VideoFiles {
        frames_dir: shown.join(name),
        frames: frame_count,
        gif: gif_path.as_deref().map(at),
        mp4: mp4.as_deref().map(at),
        mp4_note,
    })
}

/// Runs `ffmpeg` on the numbered frames, if it is on `PATH`.
fn encode_mp4(
    frames_dir: &Path,
    dir: &Path,
    name: &str,
    fps: u32,
) -> (Option<PathBuf>, Option<String>) {
    if Command::new("ffmpeg").arg("-version").output().is_err() {
        return (None, Some("ffmpeg is not on PATH: no MP4 written (install ffmpeg for one; frames and GIF are complete)".into()));
    }
    let path = dir.join(format!("{name}.mp4"));
    // ffmpeg writes into a temporary file of ours (locked: a run killed meanwhile leaves a
    // leftover the next run removes), renamed into place once complete.
    let partial = match crate::io::temp_file_in(dir, ".mp4") {
        Ok(partial) => partial,
        Err(e) => {
            return (
                None,
                Some(format!("cannot make the MP4's temporary file: {e}")),
            );
        }
    };
    let status = Command::new("ffmpeg")
        .args([
            "-y",
            "-loglevel",
            "error",
            "-framerate",
            &fps.to_string(),
            "-i",
        ])
        .arg(frames_dir.join("frame_%04d.png"))
        .args([
            "-c:v",
            "libx264",
            "-pix_fmt",
            "yuv420p",
            "-vf",
            "pad=ceil(iw/2)*2:ceil(ih/2)*2",
            // The index (`moov`) before the media data, so that players start before the
            // whole file has arrived.
            "-movflags",
            "+faststart",
        ])
        .arg(partial.path())
        .status();
    match status {
        Ok(s) if s.success() => match partial.persist(&path) {
            Ok(_) => (Some(path), None),
            Err(e) => (
                None,
                Some(format!("cannot move the MP4 into place: {}", e.error)),
            ),
        },
        // The temporary file goes with `partial`.
        other => (
            None,
            Some(format!("ffmpeg failed ({other:?}): no MP4 written")),
        ),
    }
}
