//! The `splat4d grad` file: `{"loss": L, "kernels": [{"mean": [4], "amplitude": [3],
//! "velocity": [3]}]}`, kernels in scene order; numbers read back exactly.

use serde::{Deserialize, Serialize};

use crate::backward::Gradients;
use crate::io::json::parse_json;
use crate::model::Result;

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct KernelGradientEntry {
    mean: [f64; 4],
    amplitude: [f64; 3],
    velocity: [f64; 3],
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct GradientFile {
    loss: f64,
    kernels: Vec<KernelGradientEntry>,
}

/// The gradient file of `grads` and `loss`.
#[must_use]
pub fn gradients_to_json(grads: &Gradients, loss: f64) -> String {
    let file = GradientFile {
        loss,
        kernels: (0..grads.len())
            .map(|i| KernelGradientEntry {
                mean: grads.v_means[i],
                amplitude: grads.v_amplitudes[i],
                velocity: grads.v_velocities[i],
            })
            .collect(),
    };
    serde_json::to_string_pretty(&file).expect("finite numbers serialise")
}

/// Parses a gradient file into the loss and the gradients.
pub fn gradients_from_json(text: &str, origin: &str) -> Result<(f64, Gradients)> {
    let file: GradientFile = parse_json(text, origin, "gradients")?;
    let mut grads = Gradients::zeros(file.kernels.len());
    for (i, k) in file.kernels.iter().enumerate() {
        grads.v_means[i] = k.mean;
        grads.v_amplitudes[i] = k.amplitude;
        grads.v_velocities[i] = k.velocity;
    }
    Ok((file.loss, grads))
}
