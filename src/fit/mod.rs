//! Fitting kernels to images (SPEC §6): the loss, Adam, initial scenes and the training loop.

pub mod adam;
pub mod adaptive;
pub mod alpha;
pub mod init;
pub mod loss;
pub mod plan;
pub mod train;
