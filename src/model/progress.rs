//! Progress of long work, reported through a trait so the library knows nothing of
//! terminals: the command line shows a bar (or log lines when piped), tests stay silent.

/// Progress of a long run: phases of known length.
///
/// Not part of SPEC: how long runs (fits, the report) tell a caller where they are.
pub trait Progress: Send {
    /// A phase of `total` ticks begins.
    fn start(&mut self, phase: &str, total: usize);
    /// One tick of the current phase is done.
    fn tick(&mut self);
    /// Something the user should know now (a key ignored in an input, a choice made from
    /// the data); the default drops it.
    fn note(&mut self, _text: &str) {}
}

/// Progress reported nowhere.
///
/// ```
/// use splat4d::model::{Progress, Silent};
/// let mut progress = Silent;
/// progress.start("fit", 10);
/// progress.tick();
/// ```
pub struct Silent;

impl Progress for Silent {
    fn start(&mut self, _: &str, _: usize) {}
    fn tick(&mut self) {}
}
