//! The render thread: one render at a time, owning the [`RenderContext`] and the scene's
//! temporal index. Pages submit jobs to a [`Queue`]; a page's newest job replaces its pending
//! one, so a page that asks faster than frames are made gets the latest view, never a queue
//! of stale ones. A job's answer goes to the [`Reply`] it came with (the page's connection
//! wakes on it: no one polls for finished frames).

use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use crate::fit::loss::{mse, psnr};
use crate::model::{Camera, Error, Image, Result, Scene};
use crate::render::RenderContext;
use crate::slice::TemporalIndex;
use crate::view::Showing;
use crate::view::protocol::Rgb8;

/// A job from a page.
#[derive(Clone, Debug)]
pub enum Job {
    /// A frame through `camera` at `time`.
    Frame {
        /// The page's request number.
        id: u64,
        /// The camera.
        camera: Box<Camera>,
        /// Scene time.
        time: f64,
        /// PNG instead of JPEG.
        lossless: bool,
    },
    /// The render of dataset view `view` beside its image.
    Compare {
        /// The page's request number.
        id: u64,
        /// Index of the view.
        view: usize,
    },
}

/// What the render thread made.
#[derive(Debug)]
pub enum Output {
    /// A frame.
    Frame {
        /// The page's request number.
        id: u64,
        /// The pixels.
        image: Rgb8,
        /// Scene time.
        time: f64,
        /// Kernels alive at `time` (after temporal and amplitude culling).
        alive: usize,
        /// Kernels in the scene.
        kernels: usize,
        /// PNG instead of JPEG.
        lossless: bool,
        /// Milliseconds the render took (quantisation included).
        render_ms: f64,
    },
    /// A comparison with a dataset view.
    Compare {
        /// The page's request number.
        id: u64,
        /// Index of the view.
        view: usize,
        /// The render of the view's camera at its time.
        render: Rgb8,
        /// The view's image.
        truth: Rgb8,
        /// `min(1, 4 |render − truth|)` per channel.
        error: Rgb8,
        /// PSNR of the render against the image, dB.
        psnr: f64,
    },
    /// The job could not be done (its message names why).
    Failed {
        /// The page's request number.
        id: u64,
        /// Why.
        message: String,
    },
}

/// Where a job's output goes (called once, on the render thread; it must not block).
pub type Reply = Box<dyn FnOnce(Output) + Send>;

struct Pending {
    page: u64,
    job: Job,
    reply: Reply,
}

#[derive(Default)]
struct Slots {
    pending: Vec<Pending>,
    stopped: bool,
}

/// The jobs waiting for the render thread, at most one per page.
#[derive(Default)]
pub struct Queue {
    slots: Mutex<Slots>,
    ready: Condvar,
}

impl Queue {
    fn lock(&self) -> MutexGuard<'_, Slots> {
        self.slots
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Submits `page`'s job, replacing its pending one.
    pub fn submit(&self, page: u64, job: Job, reply: Reply) {
        let mut slots = self.lock();
        slots.pending.retain(|p| p.page != page);
        slots.pending.push(Pending { page, job, reply });
        self.ready.notify_one();
    }

    /// Drops `page`'s pending job (the page left).
    pub fn forget(&self, page: u64) {
        self.lock().pending.retain(|p| p.page != page);
    }

    /// Ends the render thread after its current job.
    pub fn stop(&self) {
        self.lock().stopped = true;
        self.ready.notify_all();
    }

    /// The oldest pending job; `None` once stopped.
    fn take(&self) -> Option<Pending> {
        let mut slots = self.lock();
        loop {
            if slots.stopped {
                return None;
            }
            if !slots.pending.is_empty() {
                return Some(slots.pending.remove(0));
            }
            slots = self
                .ready
                .wait(slots)
                .unwrap_or_else(std::sync::PoisonError::into_inner);
        }
    }
}

/// The render thread's state.
struct Renderer {
    showing: Showing,
    scene: Arc<Scene>,
    version: u64,
    index: TemporalIndex,
    context: RenderContext,
}

/// Starts the render thread for `showing`; it runs until [`Queue::stop`]. An error when the
/// operating system refuses a thread.
pub fn spawn(showing: Showing) -> Result<Arc<Queue>> {
    let queue = Arc::new(Queue::default());
    let jobs = Arc::clone(&queue);
    let started = std::thread::Builder::new()
        .name("splat4d-view-render".into())
        .spawn(move || {
            let scene = Arc::clone(&showing.scene);
            let index = TemporalIndex::new(&scene, showing.options.cutoff);
            let mut renderer = Renderer {
                showing,
                scene,
                version: 0,
                index,
                context: RenderContext::new(),
            };
            while let Some(pending) = jobs.take() {
                let start = Instant::now();
                renderer.refresh_scene();
                let output = renderer.run(pending.job);
                // A page that left drops its answers.
                (pending.reply)(output);
                std::thread::sleep(rest_after(start.elapsed(), renderer.showing.duty));
            }
        });
    started.map_err(|e| Error::usage(format!("cannot start the viewer's render thread: {e}")))?;
    Ok(queue)
}

impl Renderer {
    /// Takes a running fit's newest snapshot.
    fn refresh_scene(&mut self) {
        let Some(live) = &self.showing.live else {
            return;
        };
        if let Some((version, scene)) = live.scene_since(self.version) {
            self.index = TemporalIndex::new(&scene, self.showing.options.cutoff);
            self.scene = scene;
            self.version = version;
        }
    }

    fn run(&mut self, job: Job) -> Output {
        match job {
            Job::Frame {
                id,
                camera,
                time,
                lossless,
            } => {
                let start = Instant::now();
                match self.render(&camera, time) {
                    Ok(alive) => Output::Frame {
                        id,
                        image: Rgb8::from_image(self.context.image()),
                        time,
                        alive,
                        kernels: self.scene.len(),
                        lossless,
                        render_ms: start.elapsed().as_secs_f64() * 1e3,
                    },
                    Err(e) => Output::Failed {
                        id,
                        message: e.to_string(),
                    },
                }
            }
            Job::Compare { id, view } => self.compare(id, view),
        }
    }

    /// Renders into the context; returns the kernels alive.
    fn render(&mut self, camera: &Camera, time: f64) -> Result<usize> {
        let stats = self.context.render_indexed(
            &self.scene,
            &self.index,
            camera,
            time,
            &self.showing.options,
        )?;
        Ok(stats.sliced)
    }

    fn compare(&mut self, id: u64, index: usize) -> Output {
        let views = Arc::clone(&self.showing.views);
        let Some(view) = views.get(index) else {
            return Output::Failed {
                id,
                message: format!("there is no view {index} ({} views)", views.len()),
            };
        };
        if let Err(e) = self.render(&view.camera, view.time) {
            return Output::Failed {
                id,
                message: e.to_string(),
            };
        }
        let render = self.context.image();
        let truth: &Image = &view.image;
        if (render.width, render.height) != (truth.width, truth.height) {
            return Output::Failed {
                id,
                message: format!("{}: the image's size is not its camera's", view.name),
            };
        }
        let mut error = render.clone();
        for (e, t) in error.pixels.iter_mut().zip(&truth.pixels) {
            *e = (4.0 * (*e - t).abs()).min(1.0);
        }
        Output::Compare {
            id,
            view: index,
            render: Rgb8::from_image(render),
            truth: Rgb8::from_image(truth),
            error: Rgb8::from_image(&error),
            psnr: psnr(mse(render, truth)),
        }
    }
}

/// How long the render thread rests after a job that took `took`, so that rendering takes
/// at most the share `duty` of the time.
#[must_use]
pub fn rest_after(took: Duration, duty: f64) -> Duration {
    if duty >= 1.0 {
        Duration::ZERO
    } else {
        took.mul_f64(1.0 / duty.max(0.01) - 1.0)
    }
}
