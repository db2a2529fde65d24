//! The memory rule: a command estimates what it will hold (images, kernels × buffers,
//! output) before the work and refuses, with the estimate and the bound named, when that is
//! more than the machine's available memory (`MemAvailable` of `/proc/meminfo`) or the
//! `--max-memory` the user set ([`set_limit`]).

use std::sync::atomic::{AtomicU64, Ordering};

use crate::model::{Error, Result};

/// The user's bound in bytes (`u64::MAX`: none given).
static LIMIT: AtomicU64 = AtomicU64::new(u64::MAX);

/// Bytes a fit holds per kernel: the parameters, gradients, Adam's two moments, the
/// densification statistics, the sliced and projected copies and the tile lists' share.
pub const FIT_BYTES_PER_KERNEL: u64 = 2048;

/// Bytes per kernel of each view a fit renders at once (one per worker thread, up to the
/// batch), beyond [`FIT_BYTES_PER_KERNEL`]: its own gradients, and its sliced, projected and
/// binned copies and tile lists, and the AVX-512 training step's `G` kept per (tile kernel,
/// row) for the backward (up to 1 KiB a kernel when one tile holds them all).
pub const VIEW_BYTES_PER_KERNEL: u64 = 2048;

/// Bytes a render holds per pixel: the f32 image, the raster's per-pixel work and the
/// encoder's copy.
pub const RENDER_BYTES_PER_PIXEL: u64 = 40;

/// Bytes one decoded dataset pixel takes: the decoded file (at most 16 bytes, RGBA f32)
/// and the linear RGB f32 copy kept.
pub const DATASET_BYTES_PER_PIXEL: u64 = 28;

/// Sets the bound `--max-memory` gives, in bytes.
pub fn set_limit(bytes: u64) {
    LIMIT.store(bytes, Ordering::Relaxed);
}

/// `MemAvailable` of `/proc/meminfo`, in bytes (`None` where there is none). A reading is
/// reused for [`READING_KEPT`]: a command's checks follow each other within milliseconds
/// (a `render` checks its scene file and then its frame), and the kernel composes the whole
/// file for each read.
#[must_use]
pub fn available() -> Option<u64> {
    static LAST: std::sync::Mutex<Option<(std::time::Instant, Option<u64>)>> =
        std::sync::Mutex::new(None);
    let mut last = LAST
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    if let Some((at, bytes)) = *last
        && at.elapsed() < READING_KEPT
    {
        return bytes;
    }
    let bytes = read_available();
    *last = Some((std::time::Instant::now(), bytes));
    bytes
}

/// How long [`available`] reuses a reading.
pub const READING_KEPT: std::time::Duration = std::time::Duration::from_millis(100);

/// `MemAvailable` read from `/proc/meminfo`.
fn read_available() -> Option<u64> {
    use std::io::Read;
    // Room for the whole file first: `/proc` files report no size, so reading into an
    // empty string took nine reads of growing size where this takes two.
    let mut text = String::with_capacity(8192);
    std::fs::File::open("/proc/meminfo")
        .ok()?
        .read_to_string(&mut text)
        .ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    kib.checked_mul(1024)
}

/// `bytes` for a message: `12.3 GB`.
#[must_use]
pub fn show(bytes: u64) -> String {
    format!("{:.1} GB", bytes as f64 / 1e9)
}

/// Refuses (usage error) work that needs about `need` bytes when that is more than the
/// user's `--max-memory` or the machine's available memory; `what` says what needs it.
pub fn check(need: u64, what: &str) -> Result<()> {
    let limit = LIMIT.load(Ordering::Relaxed);
    if need > limit {
        return Err(Error::setting(
            &["max_memory"],
            format!(
                "{what} needs about {} of memory, more than `max_memory` {}; make it smaller",
                show(need),
                show(limit)
            ),
        ));
    }
    if let Some(free) = available()
        && need > free
    {
        return Err(Error::usage(format!(
            "{what} needs about {} of memory, more than the {} this machine has available; make it smaller (or free memory)",
            show(need),
            show(free)
        )));
    }
    Ok(())
}

/// Parses a `--max-memory` value: bytes, or with a unit `K`, `M`, `G`, `T` (powers of 1000,
/// `KiB`/`MiB`/`GiB`/`TiB` powers of 1024), e.g. `8G`, `512MiB`.
pub fn parse_bytes(text: &str) -> std::result::Result<u64, String> {
    let text = text.trim();
    let split = text
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(text.len());
    let (number, unit) = text.split_at(split);
    let value: f64 = number
        .parse()
        .map_err(|_| format!("{text}: a size such as 8G or 512MiB"))?;
    let scale: f64 = match unit.trim().to_ascii_lowercase().as_str() {
        "" | "b" => 1.0,
        "k" | "kb" => 1e3,
        "m" | "mb" => 1e6,
        "g" | "gb" => 1e9,
        "t" | "tb" => 1e12,
        "kib" => 1024.0,
        "mib" => 1024.0 * 1024.0,
        "gib" => 1024.0 * 1024.0 * 1024.0,
        "tib" => 1024.0 * 1024.0 * 1024.0 * 1024.0,
        _ => {
            return Err(format!(
                "{text}: unknown unit (K, M, G, T, KiB, MiB, GiB, TiB)"
            ));
        }
    };
    let bytes = value * scale;
    if !(1.0..1.8e19).contains(&bytes) {
        return Err(format!("{text}: must be from 1 byte to 18 EB"));
    }
    Ok(bytes as u64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse_with_units() {
        assert_eq!(parse_bytes("8G"), Ok(8_000_000_000));
        assert_eq!(parse_bytes("512MiB"), Ok(512 << 20));
        assert_eq!(parse_bytes("1000"), Ok(1000));
        assert!(parse_bytes("8X").is_err());
        assert!(parse_bytes("-1G").is_err());
        assert!(parse_bytes("0").is_err());
    }
}
