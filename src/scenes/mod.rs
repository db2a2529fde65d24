//! Scenes and cameras made in code: seeded synthetic scenes and camera sets, the seed
//! paper's toy scene (SPEC §7), camera paths (orbits, spirals, keyframe interpolation) and the framing that sizes
//! them to a scene, and synthetic multi-view datasets rendered from a scene.

pub mod animation;
pub mod dataset;
pub mod keyframes;
pub mod motion;
pub mod motion_sampling;
pub mod paths;
pub mod surfels;
pub mod synthetic;
pub mod time_samples;
pub mod toy;
