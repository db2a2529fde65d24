//! Held-out PSNR against wall time of fits, from their `--log` files, as a PNG line chart
//! (the time-to-quality charts of `docs/fitting.md`).
//!
//! `cargo run --release -p splat4d-benches --example fit_curves -- OUT.png TITLE LABEL=LOG.jsonl…`

use splat4d::report::charts::{Colour, Series, line_chart};

/// The `(seconds, held-out PSNR)` of every evaluated step of a `fit --log` file.
fn heldout_curve(path: &str) -> Vec<(f64, f64)> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{path}: {e}"));
    text.lines()
        .filter_map(|line| {
            let record: serde_json::Value = serde_json::from_str(line).ok()?;
            Some((
                record["seconds"].as_f64()?,
                record["heldout_psnr"].as_f64()?,
            ))
        })
        .collect()
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [out, title, logs @ ..] = &args[..] else {
        panic!("usage: fit_curves OUT.png TITLE LABEL=LOG.jsonl…");
    };
    let series: Vec<Series> = logs
        .iter()
        .map(|arg| {
            let (label, path) = arg.split_once('=').expect("LABEL=LOG.jsonl");
            Series {
                label: label.to_string(),
                colour: Colour::ByPosition,
                points: heldout_curve(path),
                markers: false,
            }
        })
        .collect();
    let picture = line_chart(out, title, "seconds", "held-out PSNR (dB)", &series).unwrap();
    splat4d::io::image_file::save_rgb8_png(
        std::path::Path::new(out),
        picture.width,
        picture.height,
        &picture.rgb,
    )
    .unwrap();
}
