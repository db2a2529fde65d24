//! The bench's tables as a user reads them: one row per measured configuration (with its
//! share of the ceiling), one line per ceiling probe, and the sweep as markdown.

use crate::simd::SimdPath;

use super::ceiling::Ceiling;
use super::measure::BenchRow;
use super::sweep::SweepPoint;

/// The sweep as a markdown table, fastest first.
#[must_use]
pub fn sweep_table(points: &[SweepPoint]) -> String {
    let mut sorted: Vec<&SweepPoint> = points.iter().collect();
    sorted.sort_by(|a, b| a.ms_per_frame.total_cmp(&b.ms_per_frame));
    let mut out = String::from(
        "| ε | dilation | exp | ms/frame | pairs/frame | max error vs exact | mean error vs exact | /bound (own options) | Pareto |\n\
         |---:|---:|---|---:|---:|---:|---:|---:|:---:|\n",
    );
    for p in sorted {
        out.push_str(&format!(
            "| {:.3e} | {} | {} | {:.2} | {} | {:.3e} | {:.3e} | {:.3} | {} |\n",
            p.options.cutoff,
            p.options.dilation,
            p.options.exp,
            p.ms_per_frame,
            p.pairs,
            p.model_error,
            p.mean_model_error,
            p.bound_ratio,
            if p.pareto { "★" } else { "" }
        ));
    }
    out
}

/// The rows as a table a user can read.
#[must_use]
pub fn format_table(rows: &[BenchRow]) -> String {
    let mut out = format!(
        "{:<18} {:>9} {:>11} {:>7} {:>6} {:>10} {:>12} {:>12} {:>8} {:>10} {:>10} {:>7} {:>9}\n",
        "scene",
        "kernels",
        "size",
        "threads",
        "method",
        "ms/frame",
        "pairs/frame",
        "pairs/s",
        "ceiling",
        "max-err",
        "mean-err",
        "/bound",
        "speed-up"
    );
    for r in rows {
        out.push_str(&format!(
            "{:<18} {:>9} {:>11} {:>7} {:>6} {:>10.2} {:>12} {:>12.3e} {:>8} {:>10.2e} {:>10.2e} {:>7.3} {:>9}\n",
            r.scene,
            r.kernels,
            format!("{}x{}", r.size.0, r.size.1),
            r.threads,
            r.renderer.to_string(),
            r.ms_per_frame,
            r.pairs,
            r.pairs_per_second,
            r.efficiency
                .map_or("-".to_owned(), |e| format!("{:.1}%", 100.0 * e)),
            r.max_error,
            r.mean_error,
            r.bound_ratio,
            r.speedup.map_or("-".to_owned(), |x| format!("{x:.1}x"))
        ));
    }
    out
}

/// One line per probe and thread count: its pairs per second and the SIMD path it ran on.
#[must_use]
pub fn ceiling_lines(ceilings: &[Ceiling]) -> String {
    ceilings
        .iter()
        .map(|c| {
            format!(
                "{} ({} path, {} thread{}): {:.3e} pairs/s",
                c.probe,
                SimdPath::detect(),
                c.threads,
                if c.threads == 1 { "" } else { "s" },
                c.pairs_per_second
            )
        })
        .collect::<Vec<_>>()
        .join("\n")
}
