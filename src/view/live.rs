//! What a running fit shares with its viewer: a copy of the scene every few seconds (the fit
//! never waits for a render: it hands over a snapshot and goes on) and one point per step
//! for the loss and held-out PSNR chart.

use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use serde::Serialize;

use crate::model::Scene;

/// One fit step, as the page charts it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct StepPoint {
    /// Step number, from 1.
    pub step: usize,
    /// Seconds since the fit began.
    pub seconds: f64,
    /// Training loss (mean MSE of the step's batch).
    pub loss: f64,
    /// Held-out PSNR, dB, on the steps that measured it.
    pub heldout_psnr: Option<f64>,
    /// Kernels after the step.
    pub kernels: usize,
}

/// Most step points kept; beyond it every second point is dropped (the chart keeps its
/// shape, the memory stays bounded).
const MAX_POINTS: usize = 20_000;

#[derive(Debug, Default)]
struct State {
    scene: Option<Arc<Scene>>,
    version: u64,
    points: Vec<StepPoint>,
    /// Points dropped from the front of `points` by thinning, so readers' offsets stay valid.
    thinned: u64,
    steps: usize,
    done: bool,
    last_snapshot: Option<Instant>,
}

/// The shared state of a fit and its viewer.
#[derive(Debug)]
pub struct Live {
    state: Mutex<State>,
    every: Duration,
}

/// What the page has not seen yet.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct LiveUpdate {
    /// New points since the reader's last update.
    pub points: Vec<StepPoint>,
    /// The scene snapshot's version (it changes when a new snapshot arrives).
    pub version: u64,
    /// Steps the fit will run.
    pub steps: usize,
    /// Whether the fit has ended.
    pub done: bool,
}

impl Live {
    /// Shared state for a fit of `steps` steps that hands over its scene every `every`.
    #[must_use]
    pub fn new(steps: usize, every: Duration) -> Self {
        Live {
            state: Mutex::new(State {
                steps,
                ..State::default()
            }),
            every,
        }
    }

    fn lock(&self) -> MutexGuard<'_, State> {
        // A panic elsewhere leaves plain data behind: keep using it.
        self.state
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Records a step; when a snapshot is due (the first step, then every `every`), calls
    /// `snapshot` for a copy of the scene and hands it over.
    pub fn step(&self, point: StepPoint, snapshot: impl FnOnce() -> Scene) {
        let due = self
            .lock()
            .last_snapshot
            .is_none_or(|at| at.elapsed() >= self.every);
        // The copy is made outside the lock.
        let scene = due.then(|| Arc::new(snapshot()));
        let mut state = self.lock();
        if let Some(scene) = scene {
            state.scene = Some(scene);
            state.version += 1;
            state.last_snapshot = Some(Instant::now());
        }
        if state.points.len() >= MAX_POINTS {
            let before = state.points.len();
            let kept: Vec<StepPoint> = state.points.iter().step_by(2).copied().collect();
            state.thinned += (before - kept.len()) as u64;
            state.points = kept;
        }
        state.points.push(point);
    }

    /// Hands over the final scene and marks the fit ended.
    pub fn finish(&self, scene: Scene) {
        let mut state = self.lock();
        state.scene = Some(Arc::new(scene));
        state.version += 1;
        state.done = true;
    }

    /// The newest snapshot, if its version is not `seen`.
    #[must_use]
    pub fn scene_since(&self, seen: u64) -> Option<(u64, Arc<Scene>)> {
        let state = self.lock();
        match &state.scene {
            Some(scene) if state.version != seen => Some((state.version, Arc::clone(scene))),
            _ => None,
        }
    }

    /// The points after the reader's `cursor` (a count of points ever recorded), and the new
    /// cursor. After thinning, a reader behind it gets every point kept.
    #[must_use]
    pub fn update_since(&self, cursor: u64) -> (LiveUpdate, u64) {
        let state = self.lock();
        let total = state.thinned + state.points.len() as u64;
        let from = cursor
            .saturating_sub(state.thinned)
            .min(state.points.len() as u64) as usize;
        let update = LiveUpdate {
            points: state.points[from..].to_vec(),
            version: state.version,
            steps: state.steps,
            done: state.done,
        };
        (update, total)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(step: usize) -> StepPoint {
        StepPoint {
            step,
            seconds: step as f64,
            loss: 1.0 / step as f64,
            heldout_psnr: None,
            kernels: 3,
        }
    }

    #[test]
    fn snapshots_are_taken_when_due_and_points_are_read_once() {
        let live = Live::new(10, Duration::from_secs(3600));
        let scene = Scene::from_kernels(&[], [0.0; 3], "<test>").unwrap();
        let mut copies = 0;
        for step in 1..=4 {
            live.step(point(step), || {
                copies += 1;
                scene.clone()
            });
        }
        assert_eq!(copies, 1, "only the first step is due within an hour");
        let (version, _) = live.scene_since(0).unwrap();
        assert!(live.scene_since(version).is_none());
        let (update, cursor) = live.update_since(0);
        assert_eq!(update.points.len(), 4);
        let (update, _) = live.update_since(cursor);
        assert!(update.points.is_empty());
        live.finish(scene);
        assert!(live.update_since(cursor).0.done);
    }
}
