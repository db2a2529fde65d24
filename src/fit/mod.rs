//! Fitting kernels to images (SPEC §6, §8): the loss, one Adam over a table of parameter
//! groups ([`adam`]), one training loop ([`train`]) and the density rules ([`density`]) for
//! both blends, each blend's table and options ([`additive`], [`alpha`]), the starts
//! ([`init`], [`alpha_start`], [`hull`], [`stereo`], [`rig_start`]), the defaults ([`defaults`]) and the
//! policy that chooses among them ([`plan`], from the caller's [`settings`]), and the
//! estimate of a running fit's time left ([`time_left`]).

pub mod adam;
pub mod additive;
pub mod alpha;
pub mod alpha_start;
pub mod defaults;
pub mod density;
pub mod hull;
pub mod init;
pub mod loss;
pub mod plan;
pub mod rig_start;
pub mod settings;
pub mod stereo;
pub mod time_left;
pub mod train;
