//! Fitting kernels to images (SPEC §6, §8): the loss, Adam, initial scenes, the training
//! loops of both blends, their defaults ([`defaults`]) and the policy that chooses them
//! ([`plan`]).

pub mod adam;
pub mod adaptive;
pub mod alpha;
pub mod defaults;
pub mod hull;
pub mod init;
pub mod loss;
pub mod plan;
pub mod settings;
pub mod stereo;
pub mod train;
