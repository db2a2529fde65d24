//! The binary's allocator: the system's, except that blocks of [`LARGE`] bytes and more
//! (images, per-kernel arrays, tile lists) are mapped on their own, 2 MiB-aligned, and
//! marked for transparent huge pages (`madvise(MADV_HUGEPAGE)`, which Linux honours when
//! `/sys/kernel/mm/transparent_hugepage/enabled` is `always` or `madvise`).
//!
//! Why: a command's buffers are fresh memory, and the first touch of every 4 KiB page is a
//! page fault. On the 2-core VM of `docs/performance.md` a fault costs 1.2–3 µs, so a
//! 512×512 frame (a 3 MiB image) paid ~1.5 ms of faults and a first frame of 100k kernels
//! at 1080p (~100 MB of buffers) ~60 ms of CPU; one fault per 2 MiB page costs the zeroing
//! of 2 MiB instead (~0.1 ms). Nothing an allocation returns depends on this: outputs are
//! the same bits. Where huge pages are off (`never`) or not Linux, blocks are still mapped
//! this way or go to the system allocator, and behave as before.

use std::alloc::{GlobalAlloc, Layout, System};

/// Blocks of at least this many bytes are mapped whole (`LARGE` itself: a huge page).
const LARGE: usize = 2 << 20;

/// Sets glibc's heap up for a command's allocations (glibc: `mallopt`; elsewhere nothing).
/// Call first thing in `main`. Three settings, each measured on the 2-core VM of
/// `docs/performance.md` (whole `splat4d render` processes):
///
/// - **Freed blocks are kept** for the next allocations. glibc maps blocks of 128 KiB and
///   more on their own and unmaps them when freed, and gives the top of its heap back beyond
///   128 KiB free, so each phase of a command (the file read, the slice, the projection, the
///   bins) got fresh pages, a page fault and a zeroing each, where the previous phase's freed
///   blocks would have done: a 10k-kernel 512×512 render took 2270 faults, 2020 with this.
///   Blocks of [`LARGE`] and more are this allocator's own, and still go back when freed; the
///   heap keeps at most `KEEP_FREE` free at its top, so what a command holds after a peak is
///   bounded by that peak.
/// - **The heap is marked for huge pages as it grows** (`M_TOP_PAD`: it grows
///   [`HEAP_GROWTH`] at a time, reserving addresses, not memory; this allocator marks each
///   stretch `madvise(MADV_HUGEPAGE)` after the allocation that grew it, [`heap`]). A fault
///   costs ~1.2 µs a 4 KiB page and ~40–190 µs a 2 MiB huge page, so the per-kernel arrays
///   of a small frame (10k kernels: ~6 MB of blocks below [`LARGE`]) cost a few huge pages
///   instead of ~1500 faults: 1970 → 366 faults at 10k@512² on one thread, the whole
///   process 20.6 → 17.0 ms. A command that touches less than ~300 KiB of a 2 MiB stretch
///   pays more than it would have. A zeroed block carved from that reserve is cleared by
///   glibc by hand (it cannot tell the reserve is still fresh), as reused blocks always
///   were; the figures count it.
/// - **One arena for every thread** (`M_ARENA_MAX`). A render's work runs on the thread
///   pool, so its arrays were allocated in the workers' own glibc arenas (mapped apart from
///   the heap, on 4 KiB pages, each keeping its own freed blocks): with two threads the
///   huge-page heap went unused (2050 faults). With one arena: 2057 → 606 faults, the whole
///   process 16.5 → 13.5 ms. Threads share the arena's lock for blocks their per-thread
///   cache does not hold; the loops allocate per phase, not per pair, and fits measured the
///   same or faster (two threads; see `docs/performance.md`).
///
/// Nothing an allocation returns depends on this: outputs are the same bits.
pub fn tune_heap() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: `mallopt` only sets glibc's allocation parameters (a value out of range is
    // refused, as the mmap threshold above 512 KiB is on 32-bit systems, and changes
    // nothing).
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, LARGE as libc::c_int);
        libc::mallopt(libc::M_TRIM_THRESHOLD, KEEP_FREE as libc::c_int);
        libc::mallopt(libc::M_TOP_PAD, HEAP_GROWTH as libc::c_int);
        libc::mallopt(libc::M_ARENA_MAX, 1);
        heap::start_marking();
    }
}

/// How much glibc's heap grows at a time once [`tune_heap`] ran: addresses, backed by
/// memory only where touched.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
const HEAP_GROWTH: usize = 32 << 20;

/// Marks glibc's heap for huge pages as it grows: after each allocation of at least a page
/// from glibc, the whole huge pages between the last mark and the program break are marked
/// `MADV_HUGEPAGE`, before the caller writes to its block. (Marking ahead of the growth is
/// not possible, `madvise` needs a mapping.) What glibc wrote while growing the heap (block
/// and top headers, a `realloc`'s copy) may already sit on 4 KiB pages, and a stretch that
/// another thread's allocation grew stays unmarked until the next allocation of a page or
/// more. The marks are hints: whatever they miss or mark in vain changes no byte, only
/// which pages back the heap.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
mod heap {
    use std::sync::atomic::{AtomicUsize, Ordering};

    use super::LARGE;

    /// The address up to which the heap is marked; 0 until [`start_marking`].
    static MARKED_UP_TO: AtomicUsize = AtomicUsize::new(0);

    /// The program break, `None` where `sbrk` fails.
    fn program_break() -> Option<usize> {
        // SAFETY: `sbrk(0)` only reads the program break (glibc's cached `__curbrk`: a word
        // read while another thread's `malloc` may move it; a stale value only marks less or
        // later).
        let brk = unsafe { libc::sbrk(0) };
        (brk as isize != -1).then_some(brk as usize)
    }

    /// Starts marking from the current program break.
    pub fn start_marking() {
        if let Some(brk) = program_break() {
            MARKED_UP_TO.store(brk, Ordering::Relaxed);
        }
    }

    /// Called after glibc returned a block of `bytes`.
    #[inline]
    pub fn mark_growth(bytes: usize) {
        if bytes < 4096 {
            return;
        }
        let Some(brk) = program_break() else {
            return;
        };
        let mut marked = MARKED_UP_TO.load(Ordering::Relaxed);
        while marked != 0 {
            let Some((up_to, stretch)) = next_mark(marked, brk) else {
                return;
            };
            match MARKED_UP_TO.compare_exchange_weak(
                marked,
                up_to,
                Ordering::Relaxed,
                Ordering::Relaxed,
            ) {
                Ok(_) => {
                    if let Some((start, end)) = stretch {
                        // SAFETY: `madvise(MADV_HUGEPAGE)` is a hint about which pages back
                        // the range, and changes no byte of it; on a range that is not (or
                        // no longer) mapped it fails, and nothing happens.
                        unsafe {
                            libc::madvise(
                                start as *mut libc::c_void,
                                end - start,
                                libc::MADV_HUGEPAGE,
                            )
                        };
                    }
                    return;
                }
                Err(current) => marked = current,
            }
        }
    }

    /// With the heap marked up to `marked` and the program break at `brk`: the new mark and
    /// the stretch of whole huge pages to mark, or `None` when nothing changes. A break
    /// below the mark means the heap was trimmed: what grows back is unmarked, so the mark
    /// goes back with it (a trim and a regrowth between two calls go unseen; glibc trims
    /// only beyond 64 MiB free, `KEEP_FREE`).
    pub fn next_mark(marked: usize, brk: usize) -> Option<(usize, Option<(usize, usize)>)> {
        if brk < marked {
            return Some((brk, None));
        }
        let (start, end) = (marked.next_multiple_of(LARGE), brk - brk % LARGE);
        (end > start).then_some((end, Some((start, end))))
    }
}

/// [`heap::mark_growth`] where it exists.
#[inline]
fn after_system_alloc(bytes: usize) {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    heap::mark_growth(bytes);
    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    let _ = bytes;
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
        let block = unsafe { System.alloc(layout) };
        after_system_alloc(layout.size());
        block
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        #[cfg(target_os = "linux")]
        if Self::mapped(layout) {
            // Fresh anonymous mappings are zero.
            return map::map(layout.size());
        }
        // SAFETY: forwarded with the caller's promises.
        let block = unsafe { System.alloc_zeroed(layout) };
        after_system_alloc(layout.size());
        block
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
            (false, false) => {
                // SAFETY: both blocks belong to the system allocator.
                let block = unsafe { System.realloc(ptr, layout, new_size) };
                after_system_alloc(new_size);
                block
            }
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

    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    #[test]
    fn successive_growths_mark_every_whole_huge_page_once() {
        use heap::next_mark;
        let page = LARGE;
        // A heap starting mid-page, growing by uneven steps (some within one page).
        let first = 0x5555_0000_1000_usize;
        let mut marked = first;
        let mut stretches = Vec::new();
        let mut brk = first;
        for step in [100 << 10, 33 << 20, 5000, 3 << 20, 1, 64 << 20, 700 << 10] {
            brk += step;
            if let Some((up_to, stretch)) = next_mark(marked, brk) {
                assert!(up_to <= brk && up_to.is_multiple_of(page));
                stretches.extend(stretch);
                marked = up_to;
            }
        }
        // Back to back, from the first whole page to the last below the break.
        assert_eq!(stretches.first().unwrap().0, first.next_multiple_of(page));
        assert_eq!(stretches.last().unwrap().1, brk - brk % page);
        for pair in stretches.windows(2) {
            assert_eq!(pair[0].1, pair[1].0, "{stretches:x?}");
        }
        assert!(
            stretches
                .iter()
                .all(|&(s, e)| s < e && s.is_multiple_of(page))
        );
        // Nothing while the break stays within a page; a trimmed heap moves the mark back.
        assert_eq!(next_mark(3 * page, 3 * page + 5), None);
        assert_eq!(
            next_mark(5 * page, 4 * page + 7),
            Some((4 * page + 7, None))
        );
        assert_eq!(
            next_mark(4 * page + 7, 7 * page + 1),
            Some((7 * page, Some((5 * page, 7 * page))))
        );
    }

    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    #[test]
    fn blocks_keep_their_contents_once_the_heap_is_tuned() {
        // Blocks below `LARGE`, ~48 MB in all (more than one `HEAP_GROWTH`), with the heap
        // tuned (for this whole test process: glibc's settings change speed, not results),
        // each written whole and checked after the others came. (libtest's thread may
        // allocate from an arena of its own, off the heap, so the marking itself is tested
        // above, on its arithmetic.)
        tune_heap();
        let a = HugePages;
        let layout = Layout::from_size_align(LARGE / 2 + 123, 16).unwrap();
        // SAFETY: a valid non-zero layout; every block is used within its size and freed.
        unsafe {
            let blocks: Vec<*mut u8> = (0..48)
                .map(|b| {
                    let block = a.alloc(layout);
                    assert!(!block.is_null());
                    std::ptr::write_bytes(block, b as u8, layout.size());
                    block
                })
                .collect();
            for (b, &block) in blocks.iter().enumerate() {
                assert!(
                    (0..layout.size())
                        .step_by(997)
                        .all(|i| *block.add(i) == b as u8)
                );
                a.dealloc(block, layout);
            }
        }
    }
}
