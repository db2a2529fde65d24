//! splat4d: dynamic scenes as 4D Gaussian kernels over (x, y, z, t), rendered and fitted on
//! the CPU. The math is fixed by `SPEC.md` (shared with independent implementations).
//!
//! # Example: load a scene, render a frame, write it
//!
//! ```
//! use splat4d::io::{camera_file::load_camera, image_file::{BitDepth, save_image}, scene_file::load_scene};
//! use splat4d::{RenderOptions, render};
//! # let dir = tempfile::tempdir().unwrap();
//! # let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
//! // the seed paper's moving blob and a camera on its path (shipped in `data/`)
//! let scene = load_scene(&root.join("data/blob.json"))?;
//! let camera = load_camera(&root.join("data/blob_camera.json"))?;
//! let image = render(&scene, &camera, 0.5, &RenderOptions::default())?;
//! save_image(&image, &dir.path().join("blob.png"), BitDepth::Eight)?; // or .exr: float32, linear
//! # assert!(dir.path().join("blob.png").exists());
//! # Ok::<(), splat4d::Error>(())
//! ```
//!
//! A scene can be built in code as well ([`Kernel`], [`Scene::from_kernels`], [`Camera::look_at`]);
//! to render many frames reuse a [`RenderContext`] (it owns every stage's buffers):
//!
//! ```
//! use splat4d::{Camera, Kernel, RenderOptions, Scene, render};
//! let blob = Kernel::new([0.0, 0.0, 0.0, 0.0], [0.1, 0.1, 0.1, 1.0], [1.0, 1.0, 1.0]);
//! let scene = Scene::from_kernels(&[blob], [0.0; 3], "<example>").unwrap();
//! let camera = Camera::look_at([0.0, 0.0, -3.0], [0.0; 3], [0.0, 1.0, 0.0], 40.0, 64, 48).unwrap();
//! let image = render(&scene, &camera, 0.0, &RenderOptions::default()).unwrap();
//! assert!(image.pixel(32, 24)[0] > 0.9);
//! ```
//!
//! The command line and its manual: `README.md` and `docs/` in the repository.
//!
//! # Layers
//!
//! Each layer imports only from the layers above it in this list (a test, `layers`, checks
//! every `crate::` path in `src/`, and that no folder has an import cycle among its files):
//!
//! | layer | modules | what |
//! |---|---|---|
//! | model | [`model`] | [`Scene`]/[`Kernel`], [`Camera`], [`Image`], views, errors, seeded randomness: data and math, no files |
//! | | [`parallel`] | arrays filled in parallel, the same for any thread count |
//! | stages | [`slice`](mod@slice) → [`project`] → [`tiles`] → [`raster`] | the forward render, one function per stage from plain data to plain data |
//! | | [`simd`] | what stage 4 of either blend and its backward share, the same bits on every instruction-set path: the paths, `exp(-½ q)`, the row forms, the tile set-up; portable loops compiled for each path |
//! | | [`colour`], [`composite`] | alpha scenes (SPEC §8): SH colour and depth order per kernel; front-to-back compositing per pixel |
//! | | [`backward`] | the exact gradient (SPEC §6, §8), the stages mirrored in reverse |
//! | | [`render`](mod@render), [`overlay`], [`volume`] | the [`RenderContext`] that runs the stages and owns their buffers; a debug overlay; Eq. 1 on a 3D grid |
//! | reference | [`reference`](mod@reference) | the f64 twin of every stage, the dense baseline, and the renderer's error bound |
//! | bench | [`bench`](mod@bench) | measurement: the ceiling probes of both blends, timing with the error against the reference, the speed-against-error sweep, their tables |
//! | fit | [`fit`] | loss, Adam, initial scenes, adaptive density, the training loop, and [`fit::plan`]: every fit default |
//! | scenes | [`scenes`] | synthetic and toy scenes, camera paths and framing, synthetic datasets; node animation, motion sampling and surfels (the glTF import's math, on plain data) |
//! | io | [`io`] | every file format (reading, checking, handing plain data over); atomic writes |
//! | report | [`report`] | the seed experiment, metrics, charts, markdown |
//! | view | [`view`] | the viewer's server: the page, its WebSockets, the render thread |
//! | tasks | [`tasks`] | one call per subcommand: read, compute, write, summarise |
//!
//! The binary (`src/main.rs`, `src/cli/`) only parses flags into a task's request, and shows
//! the fields a library error names as the flags the user gave (`cli::flags`).
//!
//! # Data flow
//!
//! ```text
//!              io (JSON, PLY, glTF, D-NeRF) ──► Scene, Camera, View
//!                                                  │
//!   Scene ─slice(τ)─► SlicedKernels ─project─► ProjectedKernels ─tiles─► TileBins ─raster─► Image ─► io (PNG, EXR, video)
//!     ▲                    ▲                         ▲                                   │
//!     │                 backward ◄──────────────── backward ◄──────────── ∂L/∂C ◄── fit::loss(Image, View)
//!     └──── fit (Adam, densify/prune) ◄── Gradients                                    │
//!                                                                     report (metrics, charts, markdown)
//! ```
//!

pub mod model;
pub mod parallel;

pub mod backward;
pub mod colour;
pub mod composite;
pub mod overlay;
pub mod project;
pub mod raster;
pub mod render;
pub mod simd;
pub mod slice;
pub mod tiles;
pub mod volume;

pub mod bench;
pub mod fit;
pub mod io;
pub mod reference;
pub mod report;
pub mod scenes;
pub mod tasks;
pub mod view;

pub use backward::Gradients;
pub use model::{Blend, Camera, Error, ErrorKind, Image, Kernel, Result, Scene};
pub use render::{RenderContext, RenderOptions, RenderStats, render};
