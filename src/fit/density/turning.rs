//! The alpha fit's second trigger of SPEC §9 motion where needed: a kernel whose velocity
//! gradient keeps turning over its life (the first, a kernel that keeps splitting in time,
//! is in [`super::alpha`]).
//!
//! A kernel without fitted motion (`a = 0`, `ω = 0`) seen by a view at time τ, `d = τ - t`,
//! gets from it the velocity gradient `∂L/∂v|τ = d ∂L/∂m(τ)` and the acceleration gradient
//! `∂L/∂a|τ = ½ d² ∂L/∂m(τ) = ½ d ∂L/∂v|τ` (SPEC §9). Summed over the views,
//!
//! ```text
//!     g = Σ_τ ∂L/∂a|τ = ½ Σ_τ d ∂L/∂v|τ
//! ```
//!
//! is the first moment in time of the velocity gradient: zero when the views before the
//! kernel's time mean and those after it pull its velocity the same way (a straight path
//! fits), and along the turn when the later views pull it round from where the earlier ones
//! do, as they do for a kernel on a parabola or a circle whose one velocity fits neither
//! end. The backward computes `g` for every kernel whenever the acceleration is fitted
//! somewhere; for a kernel without motion the training loop records it
//! ([`super::DensityStats::keep_motion_to_moving_kernels`]) before holding it at zero.
//!
//! Over each interval between two density rounds the loop adds every step's `g` to two
//! sums per kernel, `S = Σ g` and `Q = Σ |g|²` ([`Pull`]). At a round the interval's pull
//! is **steady** when
//!
//! ```text
//!     z = |S| / √Q  ≥  min_steadiness
//! ```
//!
//! `z` is `√n` for `n` steps that pull the same way and about 1 for `n` steps of noise of
//! mean zero (`E|S|² = Q` then), whatever the gradient's size: it tells a kernel whose path
//! the views keep bending from one that sits at its best straight path and only feels the
//! batches' noise, with no magnitude threshold. A kernel **keeps turning** when its pull
//! was steady in `rounds` consecutive intervals, each pointing within the angle
//! `cos θ = S_prev · S / (|S_prev| |S|) ≥ min_cosine` of the one before ([`Turning`]; an
//! unsteady interval or a pull that swings further starts the count again): then it is
//! given fitted SPEC §9 motion (the state the first trigger sets, kept by its children).
//! A kernel's count follows it through a round as its optimiser moments do: the kernel
//! kept (or given motion) keeps it, a clone's copy and the children of a split start at
//! zero. Without a fitted acceleration (its rate 0) there is no `g` and the trigger never
//! acts. The pull is the loss's, not the kernel's own: a still kernel that a misfitted
//! moving one crosses in the views feels that misfit as a steady pull too, and is given
//! motion with it.

/// The thresholds of the turning trigger (see the module docs). Defaults in
/// [`crate::fit::defaults`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TurningRule {
    /// A pull is steady when `|Σ g| / √(Σ |g|²)` is at least this.
    pub min_steadiness: f64,
    /// Two consecutive steady pulls continue a count when the cosine between them is at
    /// least this.
    pub min_cosine: f64,
    /// Consecutive steady intervals after which a kernel is given motion (at least 1).
    pub rounds: u32,
}

/// A kernel's acceleration gradients `g` (the first moment in time of its velocity
/// gradients) over one interval between rounds: `Σ g` and `Σ |g|²`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Pull {
    sum: [f64; 3],
    square_sum: f64,
}

impl Pull {
    /// Adds one step's `g`.
    pub fn add(&mut self, g: [f64; 3]) {
        for (acc, v) in self.sum.iter_mut().zip(g) {
            *acc += v;
        }
        self.square_sum += g.iter().map(|v| v * v).sum::<f64>();
    }

    /// `Σ g`.
    #[must_use]
    pub fn sum(&self) -> [f64; 3] {
        self.sum
    }

    /// `z = |Σ g| / √(Σ |g|²)`: 0 without a gradient.
    #[must_use]
    pub fn steadiness(&self) -> f64 {
        if self.square_sum > 0.0 {
            norm(self.sum) / self.square_sum.sqrt()
        } else {
            0.0
        }
    }
}

/// A kernel's turning state as of the last round: its steady pull over the interval before
/// it (`None`: that pull was not steady) and the consecutive steady intervals, each within
/// the rule's angle of the one before, that ended there.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Turning {
    previous: Option<[f64; 3]>,
    rounds: u32,
}

impl Turning {
    /// Consecutive steady intervals.
    #[must_use]
    pub fn rounds(&self) -> u32 {
        self.rounds
    }
}

impl TurningRule {
    /// The state after a round whose interval's pull was `now`, from the state `before`.
    #[must_use]
    pub fn after_round(&self, before: Turning, now: &Pull) -> Turning {
        if now.steadiness() < self.min_steadiness {
            return Turning::default();
        }
        let continued = before
            .previous
            .is_some_and(|previous| cosine(previous, now.sum) >= self.min_cosine);
        Turning {
            previous: Some(now.sum),
            rounds: if continued { before.rounds + 1 } else { 1 },
        }
    }

    /// Whether a kernel in state `turning` keeps turning: its pull steady in `rounds`
    /// consecutive intervals.
    #[must_use]
    pub fn keeps_turning(&self, turning: Turning) -> bool {
        turning.rounds >= self.rounds.max(1)
    }
}

fn norm(v: [f64; 3]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
}

/// `a · b / (|a| |b|)`; 0 when either is zero.
fn cosine(a: [f64; 3], b: [f64; 3]) -> f64 {
    let n = norm(a) * norm(b);
    if n > 0.0 {
        a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>() / n
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const RULE: TurningRule = TurningRule {
        min_steadiness: 3.0,
        min_cosine: 0.5,
        rounds: 2,
    };

    /// An interval of `n` steps each pulling by `g`.
    fn steady(g: [f64; 3], n: usize) -> Pull {
        let mut pull = Pull::default();
        for _ in 0..n {
            pull.add(g);
        }
        pull
    }

    /// An interval of `n` steps of seeded noise of mean zero, each component uniform in
    /// `±size`, plus `bias` per step.
    fn noisy(size: f64, bias: [f64; 3], n: usize, seed: u64) -> Pull {
        use rand::RngExt;
        let mut rng = crate::model::random::seeded_rng(seed);
        let mut pull = Pull::default();
        for _ in 0..n {
            let g: [f64; 3] =
                std::array::from_fn(|a| bias[a] + size * (rng.random::<f64>() * 2.0 - 1.0));
            pull.add(g);
        }
        pull
    }

    /// The state after the rounds whose pulls are `pulls`, from a fresh kernel.
    fn after(rule: &TurningRule, pulls: &[Pull]) -> Turning {
        pulls.iter().fold(Turning::default(), |state, pull| {
            rule.after_round(state, pull)
        })
    }

    #[test]
    fn steadiness_is_root_n_for_one_direction_and_about_one_for_noise() {
        let one_way = steady([0.3, -0.4, 0.0], 100);
        assert!((one_way.steadiness() - 10.0).abs() < 1e-12);
        assert!((norm(one_way.sum()) - 50.0).abs() < 1e-9);
        let mean: f64 = (0..50)
            .map(|seed| noisy(1.0, [0.0; 3], 100, seed).steadiness().powi(2))
            .sum::<f64>()
            / 50.0;
        assert!((0.6..1.5).contains(&mean), "mean z² of noise {mean}");
        // The same noise scaled by 1e-9 is as unsteady: no magnitude threshold.
        let small = noisy(1e-9, [0.0; 3], 100, 7).steadiness();
        assert!((small - noisy(1.0, [0.0; 3], 100, 7).steadiness()).abs() < 1e-9);
        assert_eq!(Pull::default().steadiness(), 0.0);
    }

    #[test]
    fn a_steady_pull_in_consecutive_rounds_keeps_turning() {
        let same = [steady([1.0, 2.0, 3.0], 100); 3];
        assert_eq!(after(&RULE, &same[..1]).rounds(), 1);
        assert!(!RULE.keeps_turning(after(&RULE, &same[..1])));
        assert!(RULE.keeps_turning(after(&RULE, &same[..2])));
        assert_eq!(after(&RULE, &same).rounds(), 3);
        // Whatever its size, and under noise of mean zero up to twice its size.
        let tiny = [steady([0.0, 0.0, -1e-12], 20); 2];
        assert!(RULE.keeps_turning(after(&RULE, &tiny)));
        let noisy_pull = [
            noisy(1.0, [0.0, 0.5, 0.0], 100, 1),
            noisy(1.0, [0.0, 0.5, 0.0], 100, 2),
        ];
        assert!(RULE.keeps_turning(after(&RULE, &noisy_pull)));
        // A pull that wanders by 45° a round (cos 0.71) still counts.
        let wandering: Vec<Pull> = (0..2)
            .map(|k| {
                let angle = f64::from(k) * std::f64::consts::FRAC_PI_4;
                steady([angle.cos(), angle.sin(), 0.0], 100)
            })
            .collect();
        assert!(RULE.keeps_turning(after(&RULE, &wandering)));
    }

    #[test]
    fn a_pull_that_swings_round_starts_the_count_again() {
        // 90° a round (cos 0) and reversing (cos -1): one interval counted each time.
        for second in [[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]] {
            let pulls = [steady([1.0, 0.0, 0.0], 100), steady(second, 100)];
            assert_eq!(after(&RULE, &pulls).rounds(), 1, "{second:?}");
            assert!(!RULE.keeps_turning(after(&RULE, &pulls)));
        }
    }

    #[test]
    fn noise_of_any_size_is_no_pull_and_breaks_the_count() {
        // Pure noise is never steady: no count, at any size.
        for size in [1e-12, 1.0, 1e6] {
            let pulls: Vec<Pull> = (0..10)
                .map(|seed| noisy(size, [0.0; 3], 100, seed))
                .collect();
            for k in 1..=pulls.len() {
                assert!(
                    !RULE.keeps_turning(after(&RULE, &pulls[..k])),
                    "size {size}"
                );
            }
        }
        // A steady pull interrupted by an interval of noise starts over.
        let interrupted = [
            steady([1.0, 0.0, 0.0], 100),
            noisy(1.0, [0.0; 3], 100, 9),
            steady([1.0, 0.0, 0.0], 100),
        ];
        assert_eq!(after(&RULE, &interrupted).rounds(), 1);
        assert!(!RULE.keeps_turning(after(&RULE, &interrupted)));
        // A kernel the views never saw has no pull.
        let unseen = [Pull::default(); 4];
        assert_eq!(after(&RULE, &unseen), Turning::default());
    }
}
