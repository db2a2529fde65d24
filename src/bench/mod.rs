//! Measurement of the renderer (`splat4d bench`): forward-render speed with its error against
//! the f64 reference, the share of the machine's ceiling that speed is, and speed against
//! error over the rendering options.
//!
//! - [`ceiling`]: the ideal inner loop of each blend (additive: `acc += a exp(-½ q)`; alpha:
//!   `C += colour α̂ T`, `T ← T (1 - α̂)`), compiled per SIMD path, and its pairs per second;
//! - [`measure`]: one configuration timed (median of warm renders) with its error at seeded
//!   pixels against the reference, as a ratio to [`crate::reference::ERROR_BOUND`];
//! - [`sweep`](mod@sweep): speed against error over cut-off, dilation and exp, with its Pareto front;
//! - [`table`]: the rows, the probes' lines and the sweep as text.
//!
//! Stage modules ([`crate::raster`], [`crate::composite`]) keep only what rendering needs.

pub mod ceiling;
pub mod measure;
pub mod sweep;
pub mod table;

pub use ceiling::{
    Ceiling, Probe, alpha_ceiling_probe, ceiling_probe, fill_efficiencies, measure_ceiling,
};
pub use measure::{BenchRow, BenchSettings, Renderer, bench_render, fill_speedups};
pub use sweep::{SWEEP_ROUNDS, SweepGrid, SweepPoint, mark_pareto_front, sweep};
pub use table::{ceiling_lines, format_table, sweep_table};
