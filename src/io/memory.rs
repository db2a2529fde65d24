//! The memory rule: a command estimates what it will hold (images, kernels × buffers,
//! output) before the work and refuses, with the estimate and the bound named, when that is
//! more than the memory it may take ([`room`]) or the `--max-memory` the user set
//! ([`set_limit`]).
//!
//! The memory it may take is the least of: the machine's available memory (`MemAvailable`
//! of `/proc/meminfo`); what the process's control group (a container's memory limit,
//! cgroup v2 `memory.max` or v1 `memory.limit_in_bytes`, of its own group and those above
//! it) leaves, counting reclaimable file pages as free as `MemAvailable` does; under strict
//! overcommit (`vm.overcommit_memory = 2`, where an allocation beyond the commit limit
//! fails and the process aborts) the commit limit less what is committed; and the
//! address-space limit (`ulimit -v`) less the address space in use. Each of these, passed,
//! ends a run by an abort or a kill in place of an error.

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

/// Bytes `splat4d dataset` holds per pixel of its views: a render's
/// ([`RENDER_BYTES_PER_PIXEL`]) and the 16-bit PNG encoded in memory before it is written
/// (at most its scanlines stored, 6 bytes a pixel; the EXR streams to its file). Measured
/// peak at 16384² (one kernel, 4 views): 6.7 GB, 25 bytes a pixel.
pub const DATASET_VIEW_BYTES_PER_PIXEL: u64 = RENDER_BYTES_PER_PIXEL + 6;

/// Bytes `splat4d video` holds per pixel of its frames without a GIF: a render's
/// ([`RENDER_BYTES_PER_PIXEL`]), the frame the writer thread writes while the next renders
/// (f32 RGB, 12) and its 8-bit PNG encoded in memory (at most 3 stored).
pub const VIDEO_BYTES_PER_PIXEL: u64 = RENDER_BYTES_PER_PIXEL + 12 + 3;

/// Bytes a GIF frame adds per pixel to [`VIDEO_BYTES_PER_PIXEL`]: the RGBA copy the
/// encoder quantises (4), its palette indices (1) and their LZW code (at most 2). Measured
/// peak of a GIF video at 16384² (2000 kernels, two frames): 8.0 GB, 30 bytes a pixel.
pub const GIF_BYTES_PER_PIXEL: u64 = 7;

/// Bytes one decoded dataset pixel takes: the decoded file (at most 16 bytes, RGBA f32)
/// and the linear RGB f32 copy kept.
pub const DATASET_BYTES_PER_PIXEL: u64 = 28;

/// Sets the bound `--max-memory` gives, in bytes.
pub fn set_limit(bytes: u64) {
    LIMIT.store(bytes, Ordering::Relaxed);
}

/// The memory a command may take ([`room`]), in bytes (`None` where nothing tells).
#[must_use]
pub fn available() -> Option<u64> {
    room().map(|r| r.bytes)
}

/// What bounds the memory a command may take: the bytes, and what they are, for messages.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Room {
    /// Bytes the command may still take.
    pub bytes: u64,
    /// What bounds them: "this machine has available", "the control group's memory limit
    /// leaves", "the commit limit leaves (strict overcommit)", "the address-space limit
    /// (ulimit -v) leaves".
    pub bound: &'static str,
}

/// The least of the bounds in the module docs (`None` where none can be read). A reading
/// is reused for [`READING_KEPT`]: a command's checks follow each other within milliseconds
/// (a `render` checks its scene file and then its frame), and the kernel composes the whole
/// of `/proc/meminfo` for each read.
#[must_use]
pub fn room() -> Option<Room> {
    static LAST: std::sync::Mutex<Option<(std::time::Instant, Option<Room>)>> =
        std::sync::Mutex::new(None);
    let mut last = LAST
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    if let Some((at, bytes)) = *last
        && at.elapsed() < READING_KEPT
    {
        return bytes;
    }
    let bytes = read_room();
    *last = Some((std::time::Instant::now(), bytes));
    bytes
}

/// How long [`available`] reuses a reading.
pub const READING_KEPT: std::time::Duration = std::time::Duration::from_millis(100);

/// A `/proc` or `/sys` file's text (`None` when it cannot be read).
fn read_text(path: &str) -> Option<String> {
    use std::io::Read;
    // Room for the whole file first: `/proc` files report no size, so reading into an
    // empty string took nine reads of growing size where this takes two.
    let mut text = String::with_capacity(8192);
    std::fs::File::open(path)
        .ok()?
        .read_to_string(&mut text)
        .ok()?;
    Some(text)
}

/// The value of `key` in a `key value [kB]` listing (`/proc/meminfo`, `memory.stat`), in
/// bytes when `scale` is 1024 (kB) or as it is.
fn field(text: &str, key: &str, scale: u64) -> Option<u64> {
    let line = text
        .lines()
        .find(|l| l.split([':', ' ']).next() == Some(key))?;
    let value: u64 = line
        .trim_start_matches(key)
        .trim_start_matches(':')
        .split_whitespace()
        .next()?
        .parse()
        .ok()?;
    value.checked_mul(scale)
}

/// The bounds of the module docs, read now; the least of them.
fn read_room() -> Option<Room> {
    let meminfo = read_text("/proc/meminfo");
    let mut bounds = Vec::new();
    if let Some(text) = &meminfo {
        if let Some(bytes) = field(text, "MemAvailable", 1024) {
            bounds.push(Room {
                bytes,
                bound: "this machine has available",
            });
        }
        let strict = read_text("/proc/sys/vm/overcommit_memory").is_some_and(|m| m.trim() == "2");
        if strict
            && let (Some(limit), Some(committed)) = (
                field(text, "CommitLimit", 1024),
                field(text, "Committed_AS", 1024),
            )
        {
            bounds.push(Room {
                bytes: limit.saturating_sub(committed),
                bound: "the commit limit leaves (strict overcommit, vm.overcommit_memory = 2)",
            });
        }
    }
    if let Some(bytes) = cgroup_room() {
        bounds.push(Room {
            bytes,
            bound: "the control group's memory limit leaves (a container's limit)",
        });
    }
    if let Some(bytes) = address_space_room() {
        bounds.push(Room {
            bytes,
            bound: "the address-space limit leaves (ulimit -v)",
        });
    }
    bounds.into_iter().min_by_key(|r| r.bytes)
}

/// What the memory limits of this process's control group and those above it leave: per
/// group with a limit, the limit less its use, file pages counted as free (they are
/// reclaimed before the group runs out); the least of them. cgroup v2 (`memory.max`,
/// `memory.current`, `inactive_file` of `memory.stat`) or v1 (`memory.limit_in_bytes`,
/// `memory.usage_in_bytes`, `total_inactive_file`).
fn cgroup_room() -> Option<u64> {
    cgroup_room_in(
        &read_text("/proc/self/cgroup")?,
        std::path::Path::new("/sys/fs/cgroup"),
    )
}

/// [`cgroup_room`] for the groups listed in `groups` (the text of `/proc/self/cgroup`),
/// with the hierarchies mounted under `mount` (`/sys/fs/cgroup`).
fn cgroup_room_in(groups: &str, mount: &std::path::Path) -> Option<u64> {
    let mut least: Option<u64> = None;
    for line in groups.lines() {
        let mut parts = line.splitn(3, ':');
        let (Some(_), Some(controllers), Some(path)) = (parts.next(), parts.next(), parts.next())
        else {
            continue;
        };
        let (root, limit_file, usage_file, inactive) = if controllers.is_empty() {
            (
                mount.to_path_buf(),
                "memory.max",
                "memory.current",
                "inactive_file",
            )
        } else if controllers.split(',').any(|c| c == "memory") {
            (
                mount.join("memory"),
                "memory.limit_in_bytes",
                "memory.usage_in_bytes",
                "total_inactive_file",
            )
        } else {
            continue;
        };
        // The group and each above it up to the root of the hierarchy.
        let mut dir = root.join(path.trim().trim_start_matches('/'));
        loop {
            let read = |name: &str| read_text(&dir.join(name).to_string_lossy());
            if let Some(limit) = read(limit_file).and_then(|t| t.trim().parse::<u64>().ok())
                && let Some(usage) = read(usage_file).and_then(|t| t.trim().parse::<u64>().ok())
            {
                let reclaimable = read("memory.stat")
                    .and_then(|t| field(&t, inactive, 1))
                    .unwrap_or(0);
                let left = limit.saturating_sub(usage.saturating_sub(reclaimable));
                least = Some(least.map_or(left, |l| l.min(left)));
            }
            if dir == root || !dir.pop() || !dir.starts_with(&root) {
                break;
            }
        }
    }
    least
}

/// What the address-space limit (`RLIMIT_AS`, `ulimit -v`) leaves: the limit less this
/// process's address space (`VmSize`); `None` without a limit.
fn address_space_room() -> Option<u64> {
    #[cfg(target_os = "linux")]
    {
        let mut limit = libc::rlimit {
            rlim_cur: 0,
            rlim_max: 0,
        };
        // SAFETY: `getrlimit` writes the limit into the struct it is given.
        if unsafe { libc::getrlimit(libc::RLIMIT_AS, &mut limit) } != 0
            || limit.rlim_cur == libc::RLIM_INFINITY
        {
            return None;
        }
        let size = read_text("/proc/self/status").and_then(|t| field(&t, "VmSize", 1024))?;
        let limit: u64 = limit.rlim_cur;
        Some(limit.saturating_sub(size))
    }
    #[cfg(not(target_os = "linux"))]
    None
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
    if let Some(room) = room()
        && need > room.bytes
    {
        return Err(Error::usage(format!(
            "{what} needs about {} of memory, more than the {} {}; make it smaller (or free memory)",
            show(need),
            show(room.bytes),
            room.bound
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
    fn control_group_limits_bound_the_room_with_file_pages_counted_free() {
        let mount = tempfile::tempdir().unwrap();
        let m = mount.path();
        let write = |dir: &str, files: &[(&str, &str)]| {
            let dir = m.join(dir);
            std::fs::create_dir_all(&dir).unwrap();
            for (name, text) in files {
                std::fs::write(dir.join(name), text).unwrap();
            }
        };
        // v2: the group has no limit, its parent 8 GB with 5 GB used of which 1 GB is
        // inactive file pages; the root has no limit file.
        write(
            "a/b",
            &[("memory.max", "max\n"), ("memory.current", "100\n")],
        );
        write(
            "a",
            &[
                ("memory.max", "8000000000\n"),
                ("memory.current", "5000000000\n"),
                ("memory.stat", "anon 4000000000\ninactive_file 1000000000\n"),
            ],
        );
        assert_eq!(cgroup_room_in("0::/a/b\n", m), Some(4_000_000_000));
        // v1: the memory hierarchy's own mount.
        write(
            "memory/c",
            &[
                ("memory.limit_in_bytes", "2000000000\n"),
                ("memory.usage_in_bytes", "500000000\n"),
                ("memory.stat", "cache 10\ntotal_inactive_file 100000000\n"),
            ],
        );
        assert_eq!(
            cgroup_room_in("4:memory:/c\n1:cpu:/\n", m),
            Some(1_600_000_000)
        );
        // No group with a limit: nothing to bound.
        assert_eq!(cgroup_room_in("0::/\n", m), None);
        assert_eq!(
            field(
                "MemAvailable:   123 kB\nCommitLimit: 7 kB\n",
                "CommitLimit",
                1024
            ),
            Some(7168)
        );
        assert_eq!(field("VmSize:\t  12 kB\n", "VmSize", 1024), Some(12288));
    }

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
