//! Filling arrays, and summing, in parallel with results that do not depend on the thread
//! count.
//!
//! Every per-kernel stage (loading, slicing, projecting, binning) writes one value per index
//! into fresh or reused arrays. Done serially, a first large frame also pays the operating
//! system's first touch of every new page on one thread, and compaction through `push` grows
//! its arrays by copying. These helpers write the slots in parallel, straight into the arrays'
//! spare capacity (once each; a pass that keeps some values, [`keep_in_parallel`], writes
//! each chunk's at the start of its stretch and [`gather_kept`] moves them together): index
//! `i`'s value is computed from `i` alone, so the output is the same for any number of
//! threads.

use rayon::prelude::*;

use crate::model::error::Result;
use crate::model::scene::{Kernel, Scene};

/// What [`fill_and_drain_in_order`] hands its values to, in order: the offset of the first
/// value in the virtual buffer, and the values.
pub type Drain<'a, E> = dyn FnMut(usize, &[f32]) -> std::result::Result<(), E> + Send + 'a;

/// Two group buffers of [`fill_and_drain_in_order`], kept between calls.
#[derive(Debug, Default)]
pub struct GroupBuffers([Vec<f32>; 2]);

/// Computes the `chunk`-long pieces of a virtual buffer of `total` values (the last piece
/// may be shorter) and hands them to `drain` in order, never holding more than two groups of
/// `group` pieces: piece `i` is computed by `fill(i, piece)`, in parallel within a group, and
/// while `drain` takes one group (its offset into the virtual buffer and its values) the
/// next is filled. On a pool of one thread, where nothing would overlap, groups are of one
/// piece and one buffer is used. Returns the sum of `fill`'s results, or `drain`'s first
/// error, after which nothing more is drained.
///
/// Why: a frame written to a file need not exist whole. Its rows go to the encoder as they
/// are made, so a large image costs two groups of fresh pages, not the image's, and the
/// encoder's serial work overlaps the rendering of the next rows. `fill` must write every
/// value of its piece (the buffers are reused unchanged); the values drained are then the
/// same whatever the thread count.
pub fn fill_and_drain_in_order<E: Send>(
    (total, chunk, group): (usize, usize, usize),
    GroupBuffers([current, next]): &mut GroupBuffers,
    fill: impl Fn(usize, &mut [f32]) -> u64 + Sync,
    drain: &mut Drain<E>,
) -> std::result::Result<u64, E> {
    let one_thread = rayon::current_num_threads() == 1;
    let chunk = chunk.max(1);
    let group = if one_thread { 1 } else { group.max(1) };
    let group_values = chunk.saturating_mul(group).min(total);
    let buffers = if one_thread { 1 } else { 2 };
    for buffer in [&mut *current, &mut *next].into_iter().take(buffers) {
        if buffer.len() < group_values {
            *buffer = vec![0.0; group_values];
        }
    }
    let range = |g: usize| {
        let start = g * group_values;
        start..total.min(start + group_values)
    };
    let fill_group = |g: usize, buffer: &mut [f32]| -> u64 {
        buffer[..range(g).len()]
            .par_chunks_mut(chunk)
            .enumerate()
            .map(|(k, piece)| fill(g * group + k, piece))
            .sum()
    };
    let groups = total.div_ceil(group_values.max(1));
    if one_thread {
        let mut sum = 0;
        for g in 0..groups {
            sum += fill_group(g, current);
            drain(range(g).start, &current[..range(g).len()])?;
        }
        return Ok(sum);
    }
    let mut sum = if groups > 0 {
        fill_group(0, current)
    } else {
        0
    };
    for g in 0..groups {
        let values = &current[..range(g).len()];
        let drained = if g + 1 < groups {
            let (drained, filled) =
                rayon::join(|| drain(range(g).start, values), || fill_group(g + 1, next));
            sum += filled;
            drained
        } else {
            drain(range(g).start, values)
        };
        drained?;
        std::mem::swap(current, next);
    }
    Ok(sum)
}

/// Smallest number of indices a worker takes at once.
const MIN_CHUNK: usize = 1024;

/// Replaces the contents of `values` with `value(0..count)`, computed in parallel, without
/// filling the buffer serially first.
pub fn fill_in_parallel<T: Send>(
    values: &mut Vec<T>,
    count: usize,
    value: impl Fn(usize) -> T + Sync,
) {
    values.clear();
    values.reserve(count);
    values.spare_capacity_mut()[..count]
        .par_iter_mut()
        .enumerate()
        .with_min_len(MIN_CHUNK)
        .for_each(|(k, slot)| {
            slot.write(value(k));
        });
    // SAFETY: the loop above initialised every one of the first `count` slots (`reserve`
    // made room for them), and `T` values are only read after this.
    unsafe { values.set_len(count) };
}

/// Indices a chunk of a kept-values pass covers ([`keep_in_parallel`]).
const KEEP_CHUNK: usize = MIN_CHUNK;

/// `column` emptied, with room for `count` values, as the chunks of a kept-values pass
/// ([`keep_in_parallel`]) write into it: chunk `c` is the stretch `c·KEEP_CHUNK ..` of its
/// spare capacity.
pub fn keep_chunks<T: Send>(
    column: &mut Vec<T>,
    count: usize,
) -> rayon::slice::ChunksMut<'_, std::mem::MaybeUninit<T>> {
    column.clear();
    column.reserve(count);
    column.spare_capacity_mut()[..count].par_chunks_mut(KEEP_CHUNK)
}

/// A kept-values pass over indices `0..count`: the indices are taken a chunk at a time in
/// parallel, and chunk `c` (the `c`-th item of `chunks`: [`keep_chunks`] of each output
/// column, zipped) computes `value(k)` for its indices in order and writes each `Some` with
/// `write(chunk, at, k, value)` at the next slot `at` of its own stretch. Returns how many
/// each chunk kept, for [`gather_kept`]. One pass writes the outputs directly, so the kept
/// values are never copied out of a scratch array (the slice and the projection: 120 and
/// 72 bytes a kernel that a frame no longer writes, reads and first touches).
pub fn keep_in_parallel<C: Send, R>(
    count: usize,
    chunks: impl IndexedParallelIterator<Item = C>,
    value: impl Fn(usize) -> Option<R> + Sync,
    write: impl Fn(&mut C, usize, usize, R) + Sync,
) -> Vec<usize> {
    keep_and_tally_in_parallel(count, chunks, |k, _| value(k), write).0
}

/// [`keep_in_parallel`] whose `value(k, tally)` may also count on its chunk's tally (a
/// count of something other than what it keeps: the slice and projection in one pass count
/// the kernels alive after the slice); returns the kept counts and the tallies' sum.
pub fn keep_and_tally_in_parallel<C: Send, R>(
    count: usize,
    chunks: impl IndexedParallelIterator<Item = C>,
    value: impl Fn(usize, &mut usize) -> Option<R> + Sync,
    write: impl Fn(&mut C, usize, usize, R) + Sync,
) -> (Vec<usize>, usize) {
    let chunk_counts: Vec<(usize, usize)> = chunks
        .enumerate()
        .map(|(c, mut chunk)| {
            let first = c * KEEP_CHUNK;
            let (mut len, mut tally) = (0, 0);
            for k in first..count.min(first + KEEP_CHUNK) {
                if let Some(v) = value(k, &mut tally) {
                    write(&mut chunk, len, k, v);
                    len += 1;
                }
            }
            (len, tally)
        })
        .collect();
    let tally = chunk_counts.iter().map(|&(_, tally)| tally).sum();
    (
        chunk_counts.into_iter().map(|(len, _)| len).collect(),
        tally,
    )
}

/// After [`keep_in_parallel`]: moves each chunk's `kept[c]` values together in chunk order
/// and sets `column`'s length to their count.
///
/// # Safety
/// `column` was [`keep_chunks`] of the pass (empty, its spare capacity split into the
/// pass's chunks), and chunk `c` wrote its first `kept[c]` slots.
pub unsafe fn gather_kept<T: Copy>(column: &mut Vec<T>, kept: &[usize]) {
    let slots = column.spare_capacity_mut();
    let mut len = 0;
    for (c, &n) in kept.iter().enumerate() {
        let from = c * KEEP_CHUNK;
        if len != from && n > 0 {
            slots.copy_within(from..from + n, len);
        }
        len += n;
    }
    // SAFETY: the caller's promise: the first `len` slots now hold the written values of
    // the chunks, in order, within the room `keep_chunks` reserved. The values are `Copy`:
    // the stale copies past `len` need no drop.
    unsafe { column.set_len(len) };
}

/// Appends `count` kernels to `scene`: kernel `kernel(i)`, checked and normalised by
/// [`Kernel::checked`] as kernel number `first + i` of `origin`, for `i` in `0..count`, in
/// parallel. On an error (the one of the lowest index) the scene is left as it was.
pub fn extend_scene(
    scene: &mut Scene,
    count: usize,
    first: usize,
    kernel: impl Fn(usize) -> Kernel + Sync,
    origin: &str,
) -> Result<()> {
    let len = scene.len();
    scene.reserve(count);
    let slots = scene.means.spare_capacity_mut()[..count]
        .par_chunks_mut(MIN_CHUNK)
        .zip(scene.scales.spare_capacity_mut()[..count].par_chunks_mut(MIN_CHUNK))
        .zip(scene.amplitudes.spare_capacity_mut()[..count].par_chunks_mut(MIN_CHUNK))
        .zip(scene.rotations.spare_capacity_mut()[..count].par_chunks_mut(MIN_CHUNK))
        .zip(scene.velocities.spare_capacity_mut()[..count].par_chunks_mut(MIN_CHUNK));
    // Each chunk also lists its kernels with a SPEC §9 field (few or none), applied after.
    type Motion = (usize, [f64; 3], [f64; 4]);
    let outcomes: Vec<Result<Vec<Motion>>> = slots
        .enumerate()
        .map(
            |(c, ((((means, scales), amplitudes), rotations), velocities))| {
                let mut motion = Vec::new();
                for j in 0..means.len() {
                    let i = c * MIN_CHUNK + j;
                    let k = kernel(i).checked(first + i, origin)?;
                    means[j].write(k.mean);
                    scales[j].write(k.scale);
                    amplitudes[j].write(k.amplitude);
                    rotations[j].write(k.rotation);
                    velocities[j].write(k.velocity);
                    if k.acceleration != [0.0; 3] || k.turns() {
                        motion.push((len + i, k.acceleration, k.angular_velocity));
                    }
                }
                Ok(motion)
            },
        )
        .collect();
    let motion = outcomes.into_iter().collect::<Result<Vec<_>>>()?;
    // SAFETY: every chunk succeeded, so each of the `count` slots past `len` in the five
    // arrays was written (the chunks cover `0..count`), and `reserve` made room for them.
    unsafe {
        scene.means.set_len(len + count);
        scene.scales.set_len(len + count);
        scene.amplitudes.set_len(len + count);
        scene.rotations.set_len(len + count);
        scene.velocities.set_len(len + count);
    }
    for (i, acceleration, angular_velocity) in motion.into_iter().flatten() {
        if acceleration != [0.0; 3] {
            scene.accelerations.resize(len + count, [0.0; 3]);
            scene.accelerations[i] = acceleration;
        }
        if angular_velocity != [0.0; 4] {
            scene.angular_velocities.resize(len + count, [0.0; 4]);
            scene.angular_velocities[i] = angular_velocity;
        }
    }
    if !scene.accelerations.is_empty() {
        scene.accelerations.resize(len + count, [0.0; 3]);
    }
    if !scene.angular_velocities.is_empty() {
        scene.angular_velocities.resize(len + count, [0.0; 4]);
    }
    Ok(())
}

/// Values summed per block by [`sum_in_blocks`].
const SUM_BLOCK: usize = 1 << 16;

/// `Σ block(range)` (element-wise) over the ranges `0..len` cut into blocks of 2¹⁶, the
/// blocks in parallel and their sums added in block order: the same bits for any thread
/// count. With [`lane_sum`] inside a block, a sum in a fixed order that neither waits on each
/// addition nor depends on the threads (losses, the background's gradient).
pub fn sum_in_blocks<const N: usize>(
    len: usize,
    block: impl Fn(std::ops::Range<usize>) -> [f64; N] + Sync,
) -> [f64; N] {
    let blocks = len.div_ceil(SUM_BLOCK);
    if blocks <= 1 {
        return block(0..len);
    }
    let sums: Vec<[f64; N]> = (0..blocks)
        .into_par_iter()
        .map(|b| block(b * SUM_BLOCK..((b + 1) * SUM_BLOCK).min(len)))
        .collect();
    let mut total = [0.0; N];
    for sum in sums {
        for (total, s) in total.iter_mut().zip(sum) {
            *total += s;
        }
    }
    total
}

/// `Σ term(i)` for `i < len` in a fixed order that does not wait on each addition: term `i`
/// goes to accumulator `i mod 8`, and the eight are added pairwise ([`add_lanes`]). One
/// chain of additions is bound by their latency (a 512×512 loss took 0.65 ms); eight are
/// not.
#[inline(always)]
pub fn lane_sum(len: usize, term: impl Fn(usize) -> f64) -> f64 {
    let mut s = [0.0_f64; 8];
    let whole = len - len % 8;
    for group in 0..whole / 8 {
        for (lane, sum) in s.iter_mut().enumerate() {
            *sum += term(8 * group + lane);
        }
    }
    for (sum, i) in s.iter_mut().zip(whole..len) {
        *sum += term(i);
    }
    add_lanes(s)
}

/// The eight accumulators of [`lane_sum`] added pairwise: `((s0 + s4) + (s2 + s6)) +
/// ((s1 + s5) + (s3 + s7))`.
pub fn add_lanes(s: [f64; 8]) -> f64 {
    ((s[0] + s[4]) + (s[2] + s[6])) + ((s[1] + s[5]) + (s[3] + s[7]))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fills_and_selects_the_same_for_any_thread_count() {
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                let mut values = vec![7_u64; 3];
                fill_in_parallel(&mut values, 10_000, |k| (k as u64) * 3);
                // Chunks keeping all, some or none of their values (1024 a chunk): what is
                // kept moves down behind the previous chunks (by one slot, over itself, for
                // the second chunk), or stays where it is.
                let keep =
                    |k: usize| ((k < 2048 && k != 3) || k % 7 == 3) && !(5000..7000).contains(&k);
                let mut kept = vec![(5, 5.0)];
                let lens = keep_in_parallel(
                    10_000,
                    keep_chunks(&mut kept, 10_000),
                    |k| keep(k).then_some(k as f64 * 0.5),
                    |chunk, at, k, v| {
                        chunk[at].write((k as u32, v));
                    },
                );
                // SAFETY: `kept` is the pass's column and each chunk wrote its kept values.
                unsafe { gather_kept(&mut kept, &lens) };
                (values, kept)
            })
        };
        let (values, kept) = run(1);
        assert_eq!(values.len(), 10_000);
        assert!(values.iter().enumerate().all(|(k, &v)| v == 3 * k as u64));
        let expected: Vec<(u32, f64)> = (0..10_000_u32)
            .filter(|&k| ((k < 2048 && k != 3) || k % 7 == 3) && !(5000..7000).contains(&k))
            .map(|k| (k, f64::from(k) * 0.5))
            .collect();
        assert_eq!(kept, expected);
        assert_eq!(run(3), (values, kept));
    }

    #[test]
    fn drains_every_piece_in_order_once_and_stops_at_the_first_error() {
        // 10 pieces of 7 values and a last of 3 (73 values), groups of 4: piece i holds
        // 1000 i + its position; `fill` returns i, so the sum is 0 + 1 + … + 10.
        let fill = |i: usize, piece: &mut [f32]| {
            for (k, v) in piece.iter_mut().enumerate() {
                *v = (1000 * i + k) as f32;
            }
            i as u64
        };
        let expected: Vec<f32> = (0..73).map(|k| (1000 * (k / 7) + k % 7) as f32).collect();
        for threads in [1, 2, 3] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let mut buffers = GroupBuffers::default();
            // Stale values in reused buffers are overwritten.
            for round in 0..2 {
                let mut drained = Vec::new();
                let mut offsets = Vec::new();
                let mut drain = |offset: usize, values: &[f32]| -> std::result::Result<(), ()> {
                    assert_eq!(offset, drained.len(), "{threads} threads, in order");
                    offsets.push(offset);
                    drained.extend_from_slice(values);
                    Ok(())
                };
                let sum = pool.install(|| {
                    fill_and_drain_in_order((73, 7, 4), &mut buffers, fill, &mut drain)
                });
                assert_eq!(sum, Ok(55), "{threads} threads, round {round}");
                assert_eq!(drained, expected, "{threads} threads, round {round}");
                let groups = if threads == 1 { 11 } else { 3 };
                assert_eq!(offsets.len(), groups, "{threads} threads");
            }
            // An error stops the draining: nothing after the failed group is drained.
            let mut calls = 0;
            let mut failing = |offset: usize, _: &[f32]| -> std::result::Result<(), usize> {
                calls += 1;
                if offset >= 28 { Err(offset) } else { Ok(()) }
            };
            let result = pool
                .install(|| fill_and_drain_in_order((73, 7, 4), &mut buffers, fill, &mut failing));
            let (failed_at, calls_expected) = if threads == 1 { (28, 5) } else { (28, 2) };
            assert_eq!(result, Err(failed_at), "{threads} threads");
            assert_eq!(calls, calls_expected, "{threads} threads");
            // Nothing at all: no call.
            let mut never =
                |_: usize, _: &[f32]| -> std::result::Result<(), ()> { panic!("nothing to drain") };
            let empty =
                pool.install(|| fill_and_drain_in_order((0, 7, 4), &mut buffers, fill, &mut never));
            assert_eq!(empty, Ok(0));
        }
    }

    #[test]
    fn extending_a_scene_checks_every_kernel_and_reports_the_first_bad_one() {
        let good = |i: usize| {
            let mut k = Kernel::new([i as f64, 0.0, 0.0, 0.0], [1.0; 4], [1.0; 3]);
            k.rotation = [2.0, 0.0, 0.0, 0.0];
            k
        };
        let mut scene = Scene::from_kernels(&[good(0)], [0.0; 3], "<test>").unwrap();
        extend_scene(&mut scene, 5000, 1, good, "<test>").unwrap();
        assert_eq!(scene.len(), 5001);
        assert_eq!(scene.means[4000][0], 3999.0);
        assert_eq!(scene.rotations[4000], [1.0, 0.0, 0.0, 0.0]);
        let serial: Vec<Kernel> = (0..5001)
            .map(|i| if i == 0 { good(0) } else { good(i - 1) })
            .collect();
        assert_eq!(
            scene,
            Scene::from_kernels(&serial, [0.0; 3], "<test>").unwrap()
        );
        // Two bad kernels in different chunks: the lower index is named, nothing is added.
        let bad = |i: usize| {
            let mut k = good(i);
            if i == 3000 || i == 1500 {
                k.scale[2] = -1.0;
            }
            k
        };
        let message = extend_scene(&mut scene, 4000, 10, bad, "x.ply")
            .unwrap_err()
            .to_string();
        assert!(
            message.contains("kernel 1510") && message.contains("scale"),
            "{message}"
        );
        assert_eq!(scene.len(), 5001);
    }
}
