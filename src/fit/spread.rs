//! A fit spread over several processes (MPI ranks, `mpirun -n N splat4d fit …`), with the
//! scene of one process, bit for bit, for any number of ranks and threads.
//!
//! The library knows the ranks only through [`Ranks`] (how many, which one is this, an
//! all-gather of `f64`s, a stop of every rank); the binary sets one ([`set_ranks`]) when it
//! runs under an MPI launcher (`src/cli/mpi.rs`, cargo feature `mpi`). Without one, or with a
//! single rank, nothing here runs.
//!
//! **Why the same bits.** One process sums a step's gradient view by view in the batch's
//! order (the training loop's `batch_gradients`): `g = ((g₀ + g₁) + g₂) + …`, one term per kernel and field.
//! Spread over `N` ranks, rank `r` renders and differentiates the views at the batch
//! positions `p` with `p mod N = r` (balanced: every rank renders ⌈B/N⌉ or ⌊B/N⌋ views
//! whatever views the seeded draw picked), and packs each view's MSE, its (pixel, kernel)
//! pairs, its gradient and its screen-space gradients (`pack_view`). One all-gather hands
//! every rank every view's record; every rank then adds them in batch order exactly as one
//! process does, feeds the density statistics in that order, and takes the same Adam step:
//! the scenes of all ranks stay identical, and equal to the one-process scene, without any
//! further message. The held-out and density evaluations are spread the same way: per-view
//! MSEs gathered and summed in view order; so are the pruning by score's contributions,
//! each view's `(kernel, Σ α̂ T)` pairs gathered and added per kernel in view order
//! (`view_terms`). A record carries only the kernels whose gradient is not `+0.0` in
//! every field (a view sees part of the scene); the receiver adds the dense gradient, zeros
//! elsewhere, so `-0.0 + 0.0` comes out as one process has it.
//!
//! **What a step sends.** Each rank receives the records of the views it did not render:
//! `(B - B/N) · 8 · (8 + (1 + F) · k_seen + 3 · k_projected)` bytes a step: `F` numbers per
//! kernel (18 additive; alpha 19 + 3 per SH triplet), `k_seen` the kernels whose gradient in
//! the view is not zero, `k_projected` those it projected (their screen gradients, for the
//! density statistics). `docs/performance.md` measures it.
//!
//! **Why every rank reads every training view.** The draw is the one-process fit's seeded
//! shuffle, so a batch's views are anywhere in the training set; a rank that held only its
//! share would render the views it holds, and a batch of 4 over 2 ranks would split 3–1 or
//! 4–0 half the time (the step waits for the busier rank: 1.4× on average). Balance needs any
//! rank able to render any view, so each rank reads the whole dataset from the shared file
//! system (images never cross the network).

use std::sync::OnceLock;

use rayon::prelude::*;

use crate::backward::Gradients;
use crate::fit::loss::view_mse;
use crate::model::View;
use crate::model::error::{Error, Result};
use crate::model::scene::Scene;
use crate::render::{RenderContext, RenderOptions};

/// The processes a fit is spread over.
pub trait Ranks: Send + Sync {
    /// How many ranks there are (at least 1).
    fn size(&self) -> usize;
    /// This rank, from 0.
    fn rank(&self) -> usize;
    /// Every rank's `mine`, in rank order (every rank calls it, in the same order).
    fn all_gather(&self, mine: &[f64]) -> Vec<Vec<f64>>;
}

static RANKS: OnceLock<Box<dyn Ranks>> = OnceLock::new();

/// Spreads every later fit of this process over `ranks` (set once, by the binary).
pub fn set_ranks(ranks: Box<dyn Ranks>) {
    let _ = RANKS.set(ranks);
}

/// The ranks of this process's fits, when there are more than one.
#[must_use]
pub fn ranks() -> Option<&'static dyn Ranks> {
    RANKS.get().map(|r| r.as_ref()).filter(|r| r.size() > 1)
}

/// Whether this process writes the outputs, logs and progress: the only one, or rank 0.
#[must_use]
pub fn is_leader() -> bool {
    ranks().is_none_or(|r| r.rank() == 0)
}

/// Appends to `out` one view's record: its MSE, whether it saw a kernel, its gradient's
/// non-zero kernels (index, then every field of `grads` for it) and background, and its
/// screen gradients `(kernel, ∂L/∂m2)`.
pub(crate) fn pack_view(
    out: &mut Vec<f64>,
    (mse, pairs): (f64, u64),
    sees: bool,
    grads: &Gradients,
    screen: impl Iterator<Item = (usize, [f64; 2])>,
) {
    out.push(mse);
    // Exact: a view's pairs are far below 2⁵³.
    out.push(pairs as f64);
    out.push(f64::from(u8::from(sees)));
    let count_at = out.len();
    out.push(0.0);
    let mut rows = 0_u64;
    let mut row = Vec::with_capacity(64);
    for k in 0..grads.v_means.len() {
        row.clear();
        kernel_row(grads, k, &mut row);
        if row.iter().any(|v| v.to_bits() != 0) {
            out.push(k as f64);
            out.extend_from_slice(&row);
            rows += 1;
        }
    }
    out[count_at] = rows as f64;
    out.extend_from_slice(&grads.v_background);
    let screen_at = out.len();
    out.push(0.0);
    let mut seen = 0_u64;
    for (k, [x, y]) in screen {
        out.extend_from_slice(&[k as f64, x, y]);
        seen += 1;
    }
    out[screen_at] = seen as f64;
}

/// SH triplets per kernel of `grads`.
fn sh_per_kernel(grads: &Gradients) -> usize {
    grads
        .v_sh
        .len()
        .checked_div(grads.v_means.len())
        .unwrap_or(0)
}

/// Every field of kernel `k`'s gradient, in a fixed order.
fn kernel_row(grads: &Gradients, k: usize, row: &mut Vec<f64>) {
    row.extend_from_slice(&grads.v_means[k]);
    row.extend_from_slice(&grads.v_amplitudes[k]);
    row.extend_from_slice(&grads.v_velocities[k]);
    row.extend_from_slice(&grads.v_scales[k]);
    row.extend_from_slice(&grads.v_rotations[k]);
    if let Some(a) = grads.v_accelerations.get(k) {
        row.extend_from_slice(a);
    }
    if let Some(w) = grads.v_angular_velocities.get(k) {
        row.extend_from_slice(w);
    }
    if let Some(o) = grads.v_opacities.get(k) {
        row.push(*o);
    }
    let sh = sh_per_kernel(grads);
    for triplet in &grads.v_sh[k * sh..(k + 1) * sh] {
        row.extend_from_slice(triplet);
    }
}

/// The numbers of one kernel's row ([`kernel_row`]).
fn row_width(grads: &Gradients) -> usize {
    18 + 3 * usize::from(!grads.v_accelerations.is_empty())
        + 4 * usize::from(!grads.v_angular_velocities.is_empty())
        + usize::from(!grads.v_opacities.is_empty())
        + 3 * sh_per_kernel(grads)
}

/// Adds `row` ([`kernel_row`]'s order) to kernel `k`'s gradient in `grads`, field by
/// field: what [`Gradients::add`] does for that kernel.
fn add_kernel_row(grads: &mut Gradients, k: usize, row: &[f64]) {
    let mut at = 0;
    let mut take = |into: &mut [f64]| {
        let n = into.len();
        for (total, part) in into.iter_mut().zip(&row[at..at + n]) {
            *total += part;
        }
        at += n;
    };
    take(&mut grads.v_means[k]);
    take(&mut grads.v_amplitudes[k]);
    take(&mut grads.v_velocities[k]);
    take(&mut grads.v_scales[k]);
    take(&mut grads.v_rotations[k]);
    if let Some(a) = grads.v_accelerations.get_mut(k) {
        take(a);
    }
    if let Some(w) = grads.v_angular_velocities.get_mut(k) {
        take(w);
    }
    if let Some(o) = grads.v_opacities.get_mut(k) {
        take(std::slice::from_mut(o));
    }
    let sh = sh_per_kernel(grads);
    for triplet in &mut grads.v_sh[k * sh..(k + 1) * sh] {
        take(triplet);
    }
}

/// One view's record, read back ([`pack_view`]): its gradient kept sparse, as sent.
pub(crate) struct ViewRecord {
    pub(crate) mse: f64,
    /// The (pixel, kernel) pairs its render composited.
    pub(crate) pairs: u64,
    pub(crate) sees: bool,
    /// `(kernel, start in `values`)` of each kernel sent, in kernel order.
    rows: Vec<(usize, usize)>,
    values: Vec<f64>,
    background: [f64; 3],
    pub(crate) screen: Vec<(usize, [f64; 2])>,
}

impl ViewRecord {
    pub(crate) fn new() -> Self {
        ViewRecord {
            mse: 0.0,
            pairs: 0,
            sees: false,
            rows: Vec::new(),
            values: Vec::new(),
            background: [0.0; 3],
            screen: Vec::new(),
        }
    }

    /// Reads the record at `data[*at..]` for the kernels of `grads` (sized for the scene),
    /// and moves `at` past it.
    fn unpack(&mut self, grads: &Gradients, data: &[f64], at: &mut usize) -> Result<()> {
        let broken = || Error::Numeric("a rank's view record is cut short".into());
        let mut next = |n: usize| -> Result<&[f64]> {
            let part = data.get(*at..*at + n).ok_or_else(broken)?;
            *at += n;
            Ok(part)
        };
        let head = next(4)?;
        let (mse, pairs, sees, rows) = (head[0], head[1] as u64, head[2] != 0.0, head[3] as usize);
        let width = row_width(grads);
        self.rows.clear();
        self.values.clear();
        let mut last = None;
        for _ in 0..rows {
            let part = next(1 + width)?;
            let k = part[0] as usize;
            if k >= grads.v_means.len() || last.is_some_and(|l| l >= k) {
                return Err(broken());
            }
            last = Some(k);
            self.rows.push((k, self.values.len()));
            self.values.extend_from_slice(&part[1..]);
        }
        self.background.copy_from_slice(next(3)?);
        let seen = next(1)?[0] as usize;
        let part = next(3 * seen)?;
        self.screen.clear();
        self.screen
            .extend(part.chunks_exact(3).map(|c| (c[0] as usize, [c[1], c[2]])));
        self.mse = mse;
        self.pairs = pairs;
        self.sees = sees;
        Ok(())
    }

    /// Adds the view's gradient to `grads` as [`Gradients::add`] adds the dense one: the
    /// kernels sent their rows, every other kernel `+0.0` in every field (which turns a
    /// `-0.0` sum into `+0.0`, as the dense sum does).
    fn add_to(&self, grads: &mut Gradients) {
        let width = row_width(grads);
        let zeros = vec![0.0; width];
        let mut rows = self.rows.iter().peekable();
        for k in 0..grads.v_means.len() {
            match rows.next_if(|&&(kernel, _)| kernel == k) {
                Some(&(_, start)) => {
                    add_kernel_row(grads, k, &self.values[start..start + width]);
                }
                None => add_kernel_row(grads, k, &zeros),
            }
        }
        for (total, part) in grads.v_background.iter_mut().zip(self.background) {
            *total += part;
        }
    }
}

/// The batch positions of `count` that rank `rank` of `size` handles: `p mod size = rank`.
fn positions(count: usize, ranks: &dyn Ranks) -> Vec<usize> {
    let (size, rank) = (ranks.size(), ranks.rank());
    (rank..count).step_by(size).collect()
}

/// Every rank's records, and a reader that hands them back in position order: position
/// `p` is the `(p / N)`-th record of rank `p mod N`.
pub(crate) struct Gathered {
    data: Vec<Vec<f64>>,
    at: Vec<usize>,
}

impl Gathered {
    /// Gathers `mine` (this rank's records, in its positions' order) from every rank.
    pub(crate) fn new(ranks: &dyn Ranks, mine: &[f64]) -> Self {
        let data = ranks.all_gather(mine);
        let at = vec![0; data.len()];
        Gathered { data, at }
    }

    /// Reads position `p`'s record into `record`.
    pub(crate) fn read(
        &mut self,
        p: usize,
        grads: &Gradients,
        record: &mut ViewRecord,
    ) -> Result<()> {
        let rank = p % self.data.len();
        record.unpack(grads, &self.data[rank], &mut self.at[rank])
    }

    /// Reads position `p`'s single number.
    fn number(&mut self, p: usize) -> Result<f64> {
        Ok(self.numbers(p, 1)?[0])
    }

    /// Reads the next `n` numbers of position `p`'s record.
    fn numbers(&mut self, p: usize, n: usize) -> Result<&[f64]> {
        let rank = p % self.data.len();
        let at = &mut self.at[rank];
        let numbers = self.data[rank]
            .get(*at..at.saturating_add(n))
            .ok_or_else(|| Error::Numeric("a rank's numbers are cut short".into()))?;
        *at += n;
        Ok(numbers)
    }
}

/// This rank's share of the batch positions `0..count`, rendered with `run` side by side
/// (one per slot, `slots` of them) and packed in position order with `pack`.
pub(crate) fn run_share<S: Send, R: Send>(
    ranks: &dyn Ranks,
    count: usize,
    slots: &mut [S],
    run: impl Fn(&mut S, usize) -> Result<R> + Sync,
    mut pack: impl FnMut(&mut Vec<f64>, &S, R),
) -> Result<Vec<f64>> {
    let mine = positions(count, ranks);
    let mut out = Vec::new();
    for group in mine.chunks(slots.len().max(1)) {
        let results: Vec<Result<R>> = slots
            .par_iter_mut()
            .zip(group)
            .map(|(slot, &p)| run(slot, p))
            .collect();
        for (slot, result) in slots.iter().zip(results) {
            pack(&mut out, slot, result?);
        }
    }
    Ok(out)
}

/// A step's batch of `count` views spread over `ranks`: this rank's share run with `run`
/// in `slots` and packed with `pack` ([`pack_view`]), every record gathered, and in batch
/// order each view's `weight · MSE` added to the loss, its gradient to `grads` and its sight
/// handed to `each_view` (whether it saw a kernel, its screen gradients): the one-process
/// sums, bit for bit. Returns the loss and the pairs.
#[allow(clippy::too_many_arguments)]
pub(crate) fn batch<S: Send>(
    ranks: &dyn Ranks,
    slots: &mut [S],
    count: usize,
    weight: f64,
    grads: &mut Gradients,
    mut each_view: impl FnMut(bool, &mut dyn Iterator<Item = (usize, [f64; 2])>),
    run: impl Fn(&mut S, usize) -> Result<f64> + Sync,
    pack: impl FnMut(&mut Vec<f64>, &S, f64),
) -> Result<BatchTotals> {
    let mine = run_share(ranks, count, slots, run, pack)?;
    let mut gathered = Gathered::new(ranks, &mine);
    let mut record = ViewRecord::new();
    let mut totals = BatchTotals::default();
    for p in 0..count {
        gathered.read(p, grads, &mut record)?;
        totals.loss += weight * record.mse;
        totals.pairs += record.pairs;
        record.add_to(grads);
        each_view(record.sees, &mut record.screen.iter().copied());
    }
    Ok(totals)
}

/// What a step's batch adds up to besides its gradient.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct BatchTotals {
    /// The loss: the views' MSEs times their weight, summed in batch order.
    pub(crate) loss: f64,
    /// The (pixel, kernel) pairs the views' renders composited (SPEC §5).
    pub(crate) pairs: u64,
}

/// Mean MSE of `scene` over `views`, the views spread over `ranks` (each rank renders its
/// share with `contexts` side by side); the per-view MSEs are gathered and summed in view
/// order, as one process sums them.
pub(crate) fn evaluate(
    ranks: &dyn Ranks,
    scene: &Scene,
    views: &[View],
    options: &RenderOptions,
    contexts: &mut [&mut RenderContext],
) -> Result<f64> {
    let mine = run_share(
        ranks,
        views.len(),
        contexts,
        |context, p| {
            let view = &views[p];
            context.render(scene, &view.camera, view.time, options)?;
            Ok(view_mse(context.image(), view))
        },
        |out, _, mse| out.push(mse),
    )?;
    let mut gathered = Gathered::new(ranks, &mine);
    let mut total = 0.0;
    for p in 0..views.len() {
        total += gathered.number(p)?;
    }
    Ok(total / views.len().max(1) as f64)
}

/// Per-view terms of `count` views spread over `ranks`, handed back in view order: each
/// rank runs its share with `run` (side by side in `slots`) and sends each view's
/// `(kernel, term)` pairs as `terms` lists them; every rank then hands `each_view` every
/// view's position and pairs, in view order, as one process would list them. A kernel at
/// or past `kernels` in a record is refused as a broken record.
pub(crate) fn view_terms<S: Send>(
    ranks: &dyn Ranks,
    (count, kernels): (usize, usize),
    slots: &mut [S],
    run: impl Fn(&mut S, usize) -> Result<()> + Sync,
    terms: impl Fn(&S, &mut dyn FnMut(usize, f64)),
    mut each_view: impl FnMut(usize, &mut dyn Iterator<Item = (usize, f64)>),
) -> Result<()> {
    let mine = run_share(ranks, count, slots, run, |out, slot, ()| {
        let count_at = out.len();
        out.push(0.0);
        let mut listed = 0_u64;
        terms(slot, &mut |k, term| {
            out.extend_from_slice(&[k as f64, term]);
            listed += 1;
        });
        out[count_at] = listed as f64;
    })?;
    let mut gathered = Gathered::new(ranks, &mine);
    for p in 0..count {
        let listed = gathered.number(p)? as usize;
        let pairs = gathered.numbers(p, listed.saturating_mul(2))?;
        if pairs
            .chunks_exact(2)
            .any(|pair| pair[0] as usize >= kernels)
        {
            return Err(Error::Numeric(
                "a rank's view record names no kernel".into(),
            ));
        }
        each_view(
            p,
            &mut pairs
                .chunks_exact(2)
                .map(|pair| (pair[0] as usize, pair[1])),
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::{Arc, Barrier, Mutex};

    /// `n` ranks as threads of one process, gathering through shared memory.
    struct Threads {
        size: usize,
        rank: usize,
        shared: Arc<(Barrier, Mutex<Vec<Vec<f64>>>)>,
    }

    impl Ranks for Threads {
        fn size(&self) -> usize {
            self.size
        }
        fn rank(&self) -> usize {
            self.rank
        }
        fn all_gather(&self, mine: &[f64]) -> Vec<Vec<f64>> {
            let (barrier, slots) = &*self.shared;
            slots.lock().unwrap()[self.rank] = mine.to_vec();
            barrier.wait();
            let all = slots.lock().unwrap().clone();
            barrier.wait();
            all
        }
    }

    /// `run` on each of `size` ranks (threads of this process), their results in rank order.
    fn on_ranks<T: Send>(size: usize, run: impl Fn(&Threads) -> T + Sync) -> Vec<T> {
        let shared = Arc::new((Barrier::new(size), Mutex::new(vec![Vec::new(); size])));
        std::thread::scope(|s| {
            let handles: Vec<_> = (0..size)
                .map(|rank| {
                    let ranks = Threads {
                        size,
                        rank,
                        shared: Arc::clone(&shared),
                    };
                    let run = &run;
                    s.spawn(move || run(&ranks))
                })
                .collect();
            handles.into_iter().map(|h| h.join().unwrap()).collect()
        })
    }

    #[test]
    fn a_record_reads_back_bit_for_bit() {
        let mut scene = crate::scenes::toy::blob_scene();
        scene.means.extend(scene.means.clone());
        scene.scales.extend(scene.scales.clone());
        scene.amplitudes.extend(scene.amplitudes.clone());
        scene.rotations.extend(scene.rotations.clone());
        scene.velocities.extend(scene.velocities.clone());
        let mut grads = Gradients::for_scene(&scene);
        grads.v_means[1] = [-0.0, 1.5, f64::MIN_POSITIVE, -3.0];
        grads.v_background = [0.25, -0.0, 1.0];
        let mut out = Vec::new();
        pack_view(
            &mut out,
            (0.125, 7),
            true,
            &grads,
            [(1, [2.0, -1.0])].into_iter(),
        );
        // Kernel 0 is all +0.0: left out.
        assert_eq!(out.len(), 4 + (1 + 18) + 3 + 1 + 3);
        let mut record = ViewRecord::new();
        let mut at = 0;
        record.unpack(&grads, &out, &mut at).unwrap();
        assert_eq!(at, out.len());
        // Added to a sum holding -0.0 everywhere, as the dense gradient adds.
        let mut dense = Gradients::for_scene(&scene);
        let mut sparse = Gradients::for_scene(&scene);
        for g in [&mut dense, &mut sparse] {
            g.v_means.iter_mut().for_each(|m| *m = [-0.0; 4]);
            g.v_background = [-0.0; 3];
        }
        dense.add(&grads);
        record.add_to(&mut sparse);
        let bits = |g: &Gradients| {
            let mut row = Vec::new();
            for k in 0..2 {
                kernel_row(g, k, &mut row);
            }
            row.extend(g.v_background);
            row.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
        };
        assert_eq!(bits(&sparse), bits(&dense));
        assert_eq!(record.screen, [(1, [2.0, -1.0])]);
        assert!(record.sees && record.mse == 0.125 && record.pairs == 7);
    }

    #[test]
    fn a_spread_evaluation_sums_in_view_order() {
        let scene = crate::scenes::toy::blob_scene();
        let spec = crate::scenes::dataset::DatasetSpec {
            views: 5,
            times: 2,
            width: 24,
            height: 16,
            time_range: [0.0, 1.0],
            fov_y_degrees: 40.0,
            seed: 3,
            monocular: false,
        };
        let options = RenderOptions::default();
        let dataset =
            crate::scenes::dataset::render_dataset(&scene, &spec, &options, || {}).unwrap();
        let mut moved = scene.clone();
        moved.means[0][0] += 0.05;
        // One process: the MSEs summed one view after the other.
        let mut context = RenderContext::new();
        let mut total = 0.0;
        for view in &dataset.train {
            context
                .render(&moved, &view.camera, view.time, &options)
                .unwrap();
            total += view_mse(context.image(), view);
        }
        let one = total / dataset.train.len() as f64;
        for size in [2, 3] {
            let results = on_ranks(size, |ranks| {
                let mut context = RenderContext::new();
                evaluate(ranks, &moved, &dataset.train, &options, &mut [&mut context]).unwrap()
            });
            for mse in results {
                assert_eq!(mse.to_bits(), one.to_bits(), "{size} ranks");
            }
        }
    }

    /// Spread over 2 and 3 ranks (threads here), every rank is handed every view's terms in
    /// view order, each as the rank that ran it listed them; a record naming a kernel past
    /// the scene's is refused.
    #[test]
    fn spread_view_terms_come_back_in_view_order() {
        let count = 7;
        // View p lists p % 3 + 1 terms: kernel (p + j) % 5, term p + j / 4.
        let listed = |p: usize| -> Vec<(usize, f64)> {
            (0..p % 3 + 1)
                .map(|j| ((p + j) % 5, p as f64 + j as f64 / 4.0))
                .collect()
        };
        // Each view's position and terms, as `each_view` is handed them.
        type Seen = Vec<(usize, Vec<(usize, f64)>)>;
        let one: Seen = (0..count).map(|p| (p, listed(p))).collect();
        for (size, kernels) in [(2, 5), (3, 5), (2, 4)] {
            let results: Vec<Result<Seen>> = on_ranks(size, |ranks| {
                let mut slots = [usize::MAX; 2];
                let mut seen = Vec::new();
                view_terms(
                    ranks,
                    (count, kernels),
                    &mut slots,
                    |slot, p| {
                        *slot = p;
                        Ok(())
                    },
                    |&slot, term| listed(slot).into_iter().for_each(|(k, t)| term(k, t)),
                    |p, terms| seen.push((p, terms.collect())),
                )
                .map(|()| seen)
            });
            for result in results {
                if kernels == 5 {
                    assert_eq!(result.unwrap(), one, "{size} ranks");
                } else {
                    // View 2 names kernel 4, past the 4 kernels.
                    let error = result.unwrap_err().to_string();
                    assert!(error.contains("names no kernel"), "{error}");
                }
            }
        }
    }
}
