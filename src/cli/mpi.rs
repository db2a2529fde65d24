//! `mpirun -n N splat4d fit …` (cargo feature `mpi`): the MPI ranks a fit is spread over
//! ([`splat4d::fit::spread`], which holds the rule that gives every rank count the
//! one-process scene).
//!
//! MPI is started only when the process was launched by an MPI launcher (Open MPI's
//! `mpirun`, MPICH's Hydra, a PMIx launcher such as Slurm's `srun --mpi=pmix`): a plain
//! `splat4d` stays a plain process. The fit runs on a thread of the worker pool, so MPI is
//! asked for `MPI_THREAD_SERIALIZED`: only that thread calls MPI, one call at a time (a lock
//! here makes sure). A rank whose command fails prints its message and aborts every rank
//! (`MPI_Abort`, with the command's exit status), so that no rank waits for it forever.

use std::sync::{Mutex, OnceLock};

use mpi::datatype::PartitionMut;
use mpi::environment::Universe;
use mpi::topology::SimpleCommunicator;
use mpi::traits::*;

/// The world communicator, behind a lock (MPI is serialized).
struct World {
    comm: Mutex<SimpleCommunicator>,
    size: usize,
    rank: usize,
    /// All-gathers, bytes received from the other ranks, seconds in the all-gathers.
    traffic: Mutex<(u64, u64, f64)>,
}

// SAFETY: the communicator is a handle that MPI lets any thread use when the calls are
// serialized (`MPI_THREAD_SERIALIZED`); every use goes through the lock.
unsafe impl Send for World {}
// SAFETY: as above: shared use is serialized by the lock.
unsafe impl Sync for World {}

static WORLD: OnceLock<&'static World> = OnceLock::new();

impl splat4d::fit::spread::Ranks for &'static World {
    fn size(&self) -> usize {
        self.size
    }

    fn rank(&self) -> usize {
        self.rank
    }

    fn all_gather(&self, mine: &[f64]) -> Vec<Vec<f64>> {
        let comm = self.comm.lock().unwrap_or_else(|e| e.into_inner());
        let start = std::time::Instant::now();
        let count = i32::try_from(mine.len()).expect("a rank sends fewer than 2³¹ numbers");
        let mut counts = vec![0_i32; self.size];
        mpi::request::scope(|scope| {
            wait(comm.immediate_all_gather_into(scope, &count, &mut counts[..]));
        });
        let displs: Vec<i32> = counts
            .iter()
            .scan(0_i32, |at, &c| {
                let start = *at;
                *at += c;
                Some(start)
            })
            .collect();
        let total: usize = counts.iter().map(|&c| c as usize).sum();
        let mut all = vec![0.0_f64; total];
        {
            // Blocking: every rank is here already (the counts' gather waited for the last),
            // so its polling is the transfer itself, which moves a fragment per poll.
            let mut partition = PartitionMut::new(&mut all[..], &counts[..], &displs[..]);
            comm.all_gather_varcount_into(mine, &mut partition);
        }
        let mut traffic = self.traffic.lock().unwrap_or_else(|e| e.into_inner());
        traffic.0 += 1;
        traffic.1 += 8 * (total - mine.len()) as u64;
        traffic.2 += start.elapsed().as_secs_f64();
        counts
            .iter()
            .zip(&displs)
            .map(|(&c, &d)| all[d as usize..(d + c) as usize].to_vec())
            .collect()
    }
}

/// Waits for `request`, sleeping between tests once the first few find it unfinished: a
/// rank waiting for a slower one leaves the core to it (on a machine whose cores are all
/// busy, a blocking collective's polling took a third of the fit's time). Only for the
/// small gather that waits for the ranks: a large one's fragments move one per test, and
/// sleeps between them made the transfer 10× slower.
fn wait<'a, R: ?Sized, S: mpi::request::Scope<'a>>(mut request: mpi::request::Request<'a, R, S>) {
    let mut tries = 0_u32;
    loop {
        match request.test() {
            Ok(_) => return,
            Err(pending) => request = pending,
        }
        tries += 1;
        if tries < 64 {
            std::hint::spin_loop();
        } else {
            std::thread::sleep(std::time::Duration::from_micros(20));
        }
    }
}

/// MPI, while it runs: finalized when dropped (with `SPLAT4D_MPI_TRAFFIC` set, each rank
/// first prints its all-gathers, the bytes it received and the seconds they took).
pub struct Session {
    _universe: Universe,
}

impl Drop for Session {
    fn drop(&mut self) {
        if let Some(world) = WORLD.get()
            && std::env::var_os("SPLAT4D_MPI_TRAFFIC").is_some()
        {
            let (gathers, bytes, seconds) =
                *world.traffic.lock().unwrap_or_else(|e| e.into_inner());
            eprintln!(
                "mpi: rank {} of {}: {gathers} all-gathers, {bytes} bytes received, {seconds:.3} s in them",
                world.rank, world.size
            );
        }
    }
}

/// Whether an MPI launcher started this process.
fn launched() -> bool {
    ["OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_RANK"]
        .iter()
        .any(|name| std::env::var_os(name).is_some())
}

/// Starts MPI when launched by an MPI launcher, and hands the library its ranks.
pub fn start() -> Option<Session> {
    if !launched() {
        return None;
    }
    let (universe, _) = mpi::initialize_with_threading(mpi::Threading::Serialized)?;
    let comm = universe.world();
    let (size, rank) = (comm.size() as usize, comm.rank() as usize);
    let world: &'static World = Box::leak(Box::new(World {
        comm: Mutex::new(comm),
        size,
        rank,
        traffic: Mutex::new((0, 0, 0.0)),
    }));
    let _ = WORLD.set(world);
    splat4d::fit::spread::set_ranks(Box::new(world));
    Some(Session {
        _universe: universe,
    })
}

/// This rank and the rank count, when there are several.
pub fn spread() -> Option<(usize, usize)> {
    WORLD.get().filter(|w| w.size > 1).map(|w| (w.rank, w.size))
}

/// Stops every rank with exit status `code` (this rank failed and said why): `MPI_Abort`.
pub fn stop_all(code: u8) {
    if let Some(world) = WORLD.get().filter(|w| w.size > 1) {
        let comm = world.comm.lock().unwrap_or_else(|e| e.into_inner());
        comm.abort(i32::from(code));
    }
}
