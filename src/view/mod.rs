//! The viewer behind `splat4d view` and `splat4d fit --view`: a page in the browser that
//! draws the scene as the server renders it, frame by frame.
//!
//! - [`server`]: the HTTP listener (the page's assets, compiled in) and one WebSocket per
//!   page, at most [`server::MAX_CONNECTIONS`] connections at once; it reads the page's
//!   requests and sends back encoded frames.
//! - [`access`]: who may connect: a `Host` naming the server, the viewer's own `Origin`, the
//!   run's secret token (the address printed carries it); 403 otherwise.
//! - [`render_thread`]: the one thread that renders, owning the [`crate::RenderContext`];
//!   each page's newest request replaces its pending one (latest wins, no stale queue).
//! - [`protocol`]: the messages, checked field by field (a malformed message is answered
//!   with an error and never ends the server), and the encoding of frames.
//! - [`live`]: what a running fit shares with the viewer: a snapshot of its scene every few
//!   seconds and its loss, held-out PSNR and kernel count per step.
//!
//! Camera paths placed on the page are interpolated here by
//! [`crate::scenes::keyframes`], the interpolation `splat4d video --path` uses.

pub mod access;
pub mod live;
pub mod protocol;
pub mod render_thread;
pub mod server;

use std::sync::Arc;

use crate::model::{Scene, View};
use crate::render::RenderOptions;

pub use live::Live;
pub use server::Server;

/// Largest frame side a page may ask for, pixels (requests are clamped to it).
pub const MAX_SIDE: u32 = 4096;

/// What the viewer shows: a scene (fixed, or a running fit's [`Live`] snapshots), the
/// dataset views to compare with, and how to render.
#[derive(Clone, Debug)]
pub struct Showing {
    /// What the page's title says (the scene file).
    pub title: String,
    /// The scene at start (a fit's start scene in live mode).
    pub scene: Arc<Scene>,
    /// Dataset views the page lists (may be empty).
    pub views: Arc<Vec<View>>,
    /// Rendering options of every frame.
    pub options: RenderOptions,
    /// A running fit's shared state, in live mode.
    pub live: Option<Arc<Live>>,
    /// Rendering may take at most this share of the time (1: no limit; a fit's viewer
    /// leaves the cores to the fit).
    pub duty: f64,
}
