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
//! | [`fit_options::FIT_OPTIONS`] | `fit`'s flags as named options (the Python package's) |
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
pub mod fit_options;
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
    /// This thread as a one-thread pool, built on first use and kept (rayon cannot take a
    /// thread back out of a pool that uses it).
    static THIS_THREAD: std::cell::OnceCell<Option<rayon::ThreadPool>> =
        const { std::cell::OnceCell::new() };
}

/// `work` on a pool whose one thread is the calling thread (or, where rayon cannot make
/// one, on a pool of one started thread).
fn on_this_thread<T: Send>(work: impl FnOnce() -> T + Send) -> Result<T> {
    let local = THIS_THREAD.with(|cell| {
        cell.get_or_init(|| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(1)
                .use_current_thread()
                .build()
                .ok()
        })
        .as_ref()
        .map(|pool| pool.current_thread_index().is_some())
    });
    if local == Some(true) {
        return Ok(work());
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .map_err(|e| Error::usage(format!("cannot start a worker thread: {e}")))?;
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
/// core) when `None`. One thread is the calling thread itself (no thread is started: a
/// small command pays nothing for a pool), and work already running on a pool of `threads`
/// stays there (no second pool). Results do not depend on the thread count.
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
        Some(1) => on_this_thread(work),
        Some(n) => {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .map_err(|e| Error::usage(format!("cannot start {n} worker threads: {e}")))?;
            Ok(pool.install(work))
        }
    }
}
