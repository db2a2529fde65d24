//! Fitting kernels to images (SPEC §6, §8): the loss ([`loss`]; the 3DGS loss, [`ssim`]), one Adam over a table of parameter
//! groups ([`adam`]), one training loop ([`train`]) with its coarse-to-fine stages
//! ([`coarse`]), its windows ([`window`]) and the density rules ([`density`]) for both blends, each blend's table and
//! options ([`additive`], [`alpha`]), the starts ([`init`], [`alpha_start`], [`hull`],
//! [`stereo`], [`rig_start`], and [`shell`] for what they leave unexplained), the defaults ([`defaults`]) and the policy that chooses among
//! them ([`plan`], from the caller's [`settings`]), the estimate of a running fit's time left
//! ([`time_left`]), and a fit spread over MPI ranks with the one-process scene ([`spread`]).

pub mod adam;
pub mod additive;
pub mod alpha;
pub mod alpha_start;
pub mod coarse;
pub mod defaults;
pub mod density;
pub mod hull;
pub mod init;
pub mod loss;
pub mod plan;
pub mod regularise;
pub mod rig_start;
pub mod settings;
pub mod shell;
pub mod spread;
pub mod ssim;
pub mod stereo;
pub mod time_left;
pub mod train;
pub mod window;
