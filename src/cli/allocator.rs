//! The binary's allocator: the system's, except that blocks of [`LARGE`] bytes and more
//! (images, per-kernel arrays, tile lists) are mapped on their own, 2 MiB-aligned, and
//! marked for transparent huge pages (`madvise(MADV_HUGEPAGE)`, which Linux honours when
//! `/sys/kernel/mm/transparent_hugepage/enabled` is `always` or `madvise`).
//!
//! Why: a command's buffers are fresh memory, and the first touch of every 4 KiB page is a
//! page fault. On the 2-core VM of `docs/performance.md` a fault costs 1.5–3 µs, so a
//! 512×512 frame (a 3 MiB image) paid ~1.5 ms of faults and a first frame of 100k kernels
//! at 1080p (~100 MB of buffers) ~60 ms of CPU; one fault per 2 MiB page costs the zeroing
//! of 2 MiB instead (~0.1 ms). Nothing an allocation returns depends on this: outputs are
//! the same bits. Where huge pages are off (`never`) or not Linux, blocks are still mapped
//! this way or go to the system allocator, and behave as before.

use std::alloc::{GlobalAlloc, Layout, System};

/// Blocks of at least this many bytes are mapped whole (`LARGE` itself: a huge page).
const LARGE: usize = 2 << 20;

/// Keeps the blocks below [`LARGE`] that the program frees for its next allocations (glibc:
/// `mallopt`; elsewhere nothing). Call first thing in `main`.
///
/// Why: glibc maps blocks of 128 KiB and more on their own and unmaps them when freed, and
/// gives the top of its heap back beyond 128 KiB free, so each phase of a command (the
/// file read, the slice, the projection, the bins) got fresh pages, a page fault and a
/// zeroing each, where the previous phase's freed blocks would have done: a 10k-kernel
/// 512×512 render took 2270 faults, 2020 with this. Blocks of [`LARGE`] and more are this
/// allocator's own, and still go back when freed; each glibc arena (one per thread that
/// allocates, at most a few) keeps at most `KEEP_FREE` free at its top, so what a command
/// holds after a peak is bounded by that peak.
pub fn keep_freed_blocks() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: `mallopt` only sets glibc's allocation parameters (a value out of range is
    // refused, as the mmap threshold above 512 KiB is on 32-bit systems, and changes
    // nothing).
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, LARGE as libc::c_int);
        libc::mallopt(libc::M_TRIM_THRESHOLD, KEEP_FREE as libc::c_int);
    }
}

/// The free memory glibc's heap may keep at its top before giving it back.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
const KEEP_FREE: usize = 64 << 20;

/// The system allocator, with large blocks on huge pages.
pub struct HugePages;

#[cfg(target_os = "linux")]
mod map {
    use super::LARGE;

    /// `bytes` rounded up to whole huge pages.
    pub fn length(bytes: usize) -> usize {
        bytes.div_ceil(LARGE) * LARGE
    }

    /// A fresh zeroed mapping of `length(bytes)` bytes at a multiple of [`LARGE`], marked
    /// for huge pages; null when the system refuses.
    pub fn map(bytes: usize) -> *mut u8 {
        let len = length(bytes);
        let Some(padded) = len.checked_add(LARGE) else {
            return std::ptr::null_mut();
        };
        // SAFETY: an anonymous private mapping at an address of the kernel's choice.
        let raw = unsafe {
            libc::mmap(
                std::ptr::null_mut(),
                padded,
                libc::PROT_READ | libc::PROT_WRITE,
                libc::MAP_PRIVATE | libc::MAP_ANONYMOUS,
                -1,
                0,
            )
        };
        if raw == libc::MAP_FAILED {
            return std::ptr::null_mut();
        }
        let start = raw as usize;
        let aligned = start.next_multiple_of(LARGE);
        // SAFETY: the head before `aligned` and the tail after `aligned + len` lie inside
        // the mapping just made (`padded = len + LARGE`), and nothing refers to them.
        unsafe {
            if aligned > start {
                libc::munmap(raw, aligned - start);
            }
            let tail = start + padded - (aligned + len);
            if tail > 0 {
                libc::munmap((aligned + len) as *mut libc::c_void, tail);
            }
            // A hint: without huge pages the mapping works as ordinary pages.
            libc::madvise(aligned as *mut libc::c_void, len, libc::MADV_HUGEPAGE);
        }
        aligned as *mut u8
    }

    /// Unmaps a block of `bytes` that [`map`] returned.
    ///
    /// # Safety
    /// `ptr` came from [`map`] (or [`resize`]) with the same `bytes`, and is not used after.
    pub unsafe fn unmap(ptr: *mut u8, bytes: usize) {
        // SAFETY: the caller's promise: exactly the mapping `map` made.
        unsafe { libc::munmap(ptr.cast(), length(bytes)) };
    }

    /// The block `ptr` of `old` bytes resized to `new` bytes (both at least [`LARGE`]),
    /// its contents kept, without copying: within its huge pages it stays; a larger one
    /// gets a fresh aligned mapping into whose start the old pages are moved (`mremap`);
    /// a smaller one gives its tail back. Null (the old block untouched) when the system
    /// refuses.
    ///
    /// # Safety
    /// `ptr` came from [`map`] (or this) with `old` bytes.
    pub unsafe fn resize(ptr: *mut u8, old: usize, new: usize) -> *mut u8 {
        let (old_len, new_len) = (length(old), length(new));
        if new_len == old_len {
            return ptr;
        }
        if new_len < old_len {
            // SAFETY: the tail is part of the caller's block and is given up.
            unsafe { libc::munmap(ptr.add(new_len).cast(), old_len - new_len) };
            return ptr;
        }
        let fresh = map(new);
        if fresh.is_null() {
            return fresh;
        }
        // SAFETY: both ranges are whole mappings of ours; `MREMAP_FIXED` replaces the
        // first `old_len` bytes of the fresh one with the old pages and unmaps the old.
        let moved = unsafe {
            libc::mremap(
                ptr.cast(),
                old_len,
                old_len,
                libc::MREMAP_MAYMOVE | libc::MREMAP_FIXED,
                fresh.cast::<libc::c_void>(),
            )
        };
        if moved == libc::MAP_FAILED {
            // SAFETY: the fresh mapping is ours and unused; copy instead.
            unsafe {
                std::ptr::copy_nonoverlapping(ptr, fresh, old);
                libc::munmap(ptr.cast(), old_len);
            }
        }
        fresh
    }
}

impl HugePages {
    /// Whether a block of `layout` is mapped by this allocator rather than the system's.
    fn mapped(layout: Layout) -> bool {
        cfg!(target_os = "linux") && layout.size() >= LARGE && layout.align() <= LARGE
    }
}

// SAFETY: every block comes from exactly one of the two allocators, decided by its layout
// alone (`mapped`), which `dealloc` and `realloc` are given unchanged; mapped blocks are
// zeroed, at least `size` long and aligned to `LARGE`, which is at least their alignment.
unsafe impl GlobalAlloc for HugePages {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        #[cfg(target_os = "linux")]
        if Self::mapped(layout) {
            return map::map(layout.size());
        }
        // SAFETY: forwarded with the caller's promises.
        unsafe { System.alloc(layout) }
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        #[cfg(target_os = "linux")]
        if Self::mapped(layout) {
            // Fresh anonymous mappings are zero.
            return map::map(layout.size());
        }
        // SAFETY: forwarded with the caller's promises.
        unsafe { System.alloc_zeroed(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        #[cfg(target_os = "linux")]
        if Self::mapped(layout) {
            // SAFETY: `alloc` mapped it with this size.
            return unsafe { map::unmap(ptr, layout.size()) };
        }
        // SAFETY: forwarded with the caller's promises.
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        // SAFETY: the caller promises that `new_size` with this alignment is a valid layout.
        let new_layout = unsafe { Layout::from_size_align_unchecked(new_size, layout.align()) };
        match (Self::mapped(layout), Self::mapped(new_layout)) {
            #[cfg(target_os = "linux")]
            // SAFETY: mapped with `layout.size()` bytes.
            (true, true) => unsafe { map::resize(ptr, layout.size(), new_size) },
            // SAFETY: both blocks belong to the system allocator.
            (false, false) => unsafe { System.realloc(ptr, layout, new_size) },
            _ => {
                // SAFETY: a fresh block of the new layout, the common prefix copied, then the
                // old block freed by its own allocator.
                unsafe {
                    let fresh = self.alloc(new_layout);
                    if !fresh.is_null() {
                        std::ptr::copy_nonoverlapping(ptr, fresh, layout.size().min(new_size));
                        self.dealloc(ptr, layout);
                    }
                    fresh
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blocks_of_every_size_keep_their_contents_through_growth_and_shrinking() {
        let a = HugePages;
        for align in [8, 64, 4096] {
            // Small → large → larger → smaller large → small, contents checked each time.
            let sizes = [1000, LARGE + 5, 3 * LARGE + 1, 2 * LARGE, LARGE, 4000];
            let layout = Layout::from_size_align(sizes[0], align).unwrap();
            // SAFETY: layouts are valid and non-zero; each pointer is used with its size.
            unsafe {
                let mut ptr = a.alloc(layout);
                assert!(!ptr.is_null() && (ptr as usize).is_multiple_of(align));
                for i in 0..sizes[0] {
                    *ptr.add(i) = (i % 251) as u8;
                }
                let mut size = sizes[0];
                for &next in &sizes[1..] {
                    ptr = a.realloc(ptr, Layout::from_size_align(size, align).unwrap(), next);
                    assert!(!ptr.is_null() && (ptr as usize).is_multiple_of(align));
                    for i in 0..size.min(next).min(sizes[0]) {
                        assert_eq!(*ptr.add(i), (i % 251) as u8);
                    }
                    // Write the whole block: every byte of it is usable.
                    for i in sizes[0]..next {
                        *ptr.add(i) = 7;
                    }
                    size = next;
                }
                a.dealloc(ptr, Layout::from_size_align(size, align).unwrap());
                let zeroed = Layout::from_size_align(3 * LARGE, align).unwrap();
                let block = a.alloc_zeroed(zeroed);
                assert!((0..3 * LARGE).step_by(4093).all(|i| *block.add(i) == 0));
                a.dealloc(block, zeroed);
            }
        }
    }
}
