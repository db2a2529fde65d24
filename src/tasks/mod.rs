//! Tasks: what each subcommand does, as one library call that reads its inputs, computes
//! and writes its outputs, and returns a summary to print. The command line turns flags
//! into a task's request and calls it; every default and automatic choice lives below
//! (the fit's in [`crate::fit::plan`], framing in [`crate::scenes::paths`]).
//!
//! | task | subcommand |
//! |---|---|
//! | [`render::render`] | `render` |
//! | [`render::grad`] | `grad` |
//! | [`dataset::write_dataset`] | `dataset` |
//! | [`fit::fit_dataset`] | `fit` |
//! | [`scene_files::write_toy`] | `toy` |
//! | [`scene_files::import_gltf`] | `import-gltf` |
//! | [`scene_files::export_ply`] | `export-ply` |
//! | [`volume::write_volumes`] | `volume` |
//! | [`video::write_videos`] | `video` |
//! | [`view::view_scene`] | `view` |
//! | [`bench::bench`] | `bench` |
//! | [`report::write_report`] | `report`, and `splat4d` alone |
//!
//! Every summary implements `Display`: the lines the command prints.

pub mod bench;
pub mod dataset;
pub mod fit;
pub mod render;
pub mod report;
pub mod scene_files;
pub mod video;
pub mod view;
pub mod volume;

use crate::model::{Error, Result};

/// Work below this many pixel-kernel units (`pixels × (1 + kernels)`) runs on the calling
/// thread when no thread count was asked for: starting a pool costs more than it saves.
pub const SMALL_WORK: f64 = 2e6;

/// The threads for work of `units` ([`SMALL_WORK`]): the ones asked for, else one for
/// small work, else the global pool.
#[must_use]
pub fn threads_for(asked: Option<usize>, units: f64) -> Option<usize> {
    asked.or((units < SMALL_WORK).then_some(1))
}

thread_local! {
    /// The pool this thread is the first thread of, and its size: built on first use and
    /// kept (rayon cannot take a thread back out of a pool that uses it).
    static THIS_THREAD: std::cell::OnceCell<Option<(usize, rayon::ThreadPool)>> =
        const { std::cell::OnceCell::new() };
}

/// `work` on a pool of `n` threads whose first is the calling thread, so that `n - 1` are
/// started (none for one thread), and the calling thread works instead of waiting. A thread
/// can be in one such pool only: where it already is in one of another size, or rayon cannot
/// make one, `work` runs on a pool of `n` started threads.
fn on_this_and_started_threads<T: Send>(n: usize, work: impl FnOnce() -> T + Send) -> Result<T> {
    let local = THIS_THREAD.with(|cell| {
        cell.get_or_init(|| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .use_current_thread()
                .build()
                .ok()
                .map(|pool| (n, pool))
        })
        .as_ref()
        .is_some_and(|(size, pool)| *size == n && pool.current_thread_index().is_some())
    });
    if local {
        return Ok(work());
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(n)
        .build()
        .map_err(|e| Error::usage(format!("cannot start {n} worker threads: {e}")))?;
    Ok(pool.install(work))
}

/// [`with_threads`], except that without a thread count `work` runs on a thread of rayon's
/// global pool, the calling thread waiting for it (`rayon::scope`; on a pool's thread
/// already: in place), instead of on the calling thread. Parallel loops started from a
/// thread outside the pool each hand their work over to the pool and wait for it: a
/// 10k-kernel 512×512 frame makes about 25 such loops, and a whole `render` took 0.47 ms
/// longer without a thread count than with `--threads 2` (10.40 against 9.93 ms, medians of
/// 31). Only for work that does not wait on other threads' rayon work from inside, and
/// that no other thread needs the global pool during: with one worker, busy with `work`
/// from start to end, the pool would have no thread left for them
/// ([`with_threads_on_pool_unless_shared`]).
pub fn with_threads_on_pool<T: Send>(
    threads: Option<usize>,
    work: impl FnOnce() -> T + Send,
) -> Result<T> {
    match threads {
        None => Ok(rayon::scope(|_| work())),
        threads => with_threads(threads, work),
    }
}

/// [`with_threads_on_pool`], unless `shared`: another thread runs parallel loops on the
/// global pool while `work` runs (a live viewer renders there), and a global pool of one
/// thread, busy with `work` from start to end, would never serve them; then
/// [`with_threads`], whose loops take turns with the other thread's on the pool.
pub fn with_threads_on_pool_unless_shared<T: Send>(
    threads: Option<usize>,
    shared: bool,
    work: impl FnOnce() -> T + Send,
) -> Result<T> {
    if shared {
        with_threads(threads, work)
    } else {
        with_threads_on_pool(threads, work)
    }
}

/// Most worker threads a task starts.
pub const MAX_THREADS: usize = 1024;

/// Runs `work` on a pool of `threads` threads, or on rayon's global pool (one thread per
/// core) when `None`. The pool's first thread is the calling thread itself, which works
/// rather than waits: `threads - 1` are started (none for one thread: a small command pays
/// nothing for a pool), and work already running on a pool of `threads` stays there (no
/// second pool). The calling thread stays in that pool afterwards (rayon cannot take it
/// out): a later call with the same count starts nothing, and parallel loops the thread
/// starts outside `with_threads` run there too. Results do not depend on the thread count.
pub fn with_threads<T: Send>(threads: Option<usize>, work: impl FnOnce() -> T + Send) -> Result<T> {
    match threads {
        None => Ok(work()),
        Some(n) if n == 0 || n > MAX_THREADS => Err(Error::setting(
            &["threads"],
            format!("`threads` {n} must be between 1 and {MAX_THREADS}"),
        )),
        Some(n) if rayon::current_thread_index().is_some() && rayon::current_num_threads() == n => {
            Ok(work())
        }
        Some(n) => on_this_and_started_threads(n, work),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rayon::prelude::*;

    /// Where `work` ran: its index in its pool, the pool's size, and whether on this thread.
    fn placement(threads: Option<usize>) -> (Option<usize>, usize, bool) {
        let caller = std::thread::current().id();
        with_threads(threads, || {
            (
                rayon::current_thread_index(),
                rayon::current_num_threads(),
                std::thread::current().id() == caller,
            )
        })
        .unwrap()
    }

    #[test]
    fn a_pool_s_first_thread_is_the_calling_thread_once_per_thread() {
        // A test runs on a thread of its own: in no pool yet.
        std::thread::spawn(|| {
            assert_eq!(placement(Some(2)), (Some(0), 2, true));
            assert_eq!(placement(Some(2)), (Some(0), 2, true));
            // Another count: a pool of started threads, this thread waiting.
            let (_, threads, here) = placement(Some(3));
            assert_eq!((threads, here), (3, false));
            let (_, threads, here) = placement(Some(1));
            assert_eq!((threads, here), (1, false));
            // The same sums on every count.
            let sum = |threads| {
                with_threads(Some(threads), || {
                    (0..100_000_u64).into_par_iter().map(|k| k * k).sum::<u64>()
                })
                .unwrap()
            };
            assert!([1, 2, 3].iter().all(|&n| sum(n) == sum(2)));
        })
        .join()
        .unwrap();
        std::thread::spawn(|| assert_eq!(placement(Some(1)), (Some(0), 1, true)))
            .join()
            .unwrap();
        assert!(with_threads(Some(0), || ()).is_err());
    }
}
