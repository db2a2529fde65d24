//! The `splat4d grad` file: `{"loss": L, "kernels": [{"mean": [4], "amplitude": [3],
//! "velocity": [3]}]}`, kernels in scene order; numbers read back exactly. Alpha scenes
//! (SPEC §8) add every other field per kernel: `"scale": [4]`, `"rotation": [4]` (of the
//! stored quaternion), `"opacity": o` and, with SH, `"sh": [[r, g, b], …]`. Scenes with
//! SPEC §9 fields add `"acceleration": [3]` and `"angular_velocity": [4]` per kernel (each
//! when the scene has it).

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
    #[serde(default, skip_serializing_if = "Option::is_none")]
    acceleration: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    angular_velocity: Option<[f64; 4]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    scale: Option<[f64; 4]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    rotation: Option<[f64; 4]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    opacity: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    sh: Option<Vec<[f64; 3]>>,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct GradientFile {
    loss: f64,
    kernels: Vec<KernelGradientEntry>,
}

/// The gradient file of `grads` and `loss` (every field when `grads` are an alpha scene's:
/// [`Gradients::for_scene`]).
#[must_use]
pub fn gradients_to_json(grads: &Gradients, loss: f64) -> String {
    let alpha = grads.v_opacities.len() == grads.len() && !grads.is_empty();
    let sh_count = if alpha {
        grads.v_sh.len() / grads.len()
    } else {
        0
    };
    let file = GradientFile {
        loss,
        kernels: (0..grads.len())
            .map(|i| KernelGradientEntry {
                mean: grads.v_means[i],
                amplitude: grads.v_amplitudes[i],
                velocity: grads.v_velocities[i],
                acceleration: grads.v_accelerations.get(i).copied(),
                angular_velocity: grads.v_angular_velocities.get(i).copied(),
                scale: alpha.then(|| grads.v_scales[i]),
                rotation: alpha.then(|| grads.v_rotations[i]),
                opacity: alpha.then(|| grads.v_opacities[i]),
                sh: (sh_count > 0).then(|| grads.v_sh[i * sh_count..(i + 1) * sh_count].to_vec()),
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
        grads.v_scales[i] = k.scale.unwrap_or_default();
        grads.v_rotations[i] = k.rotation.unwrap_or_default();
        if let Some(opacity) = k.opacity {
            grads.v_opacities.resize(file.kernels.len(), 0.0);
            grads.v_opacities[i] = opacity;
        }
        grads.v_sh.extend(k.sh.iter().flatten());
        if let Some(acceleration) = k.acceleration {
            grads.v_accelerations.resize(file.kernels.len(), [0.0; 3]);
            grads.v_accelerations[i] = acceleration;
        }
        if let Some(angular_velocity) = k.angular_velocity {
            grads
                .v_angular_velocities
                .resize(file.kernels.len(), [0.0; 4]);
            grads.v_angular_velocities[i] = angular_velocity;
        }
    }
    Ok((file.loss, grads))
}
