//! Fitting kernels to images (SPEC §6): the loss, Adam, and the training loop.

pub mod loss;
