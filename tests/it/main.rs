//! The integration tests, one binary (one link of the crate), one module per promise.

/// Seeded hard scenes, the test camera, the f32 error bound, finite differences, the
/// reference cases in `tests/data/reference`.
mod common;

/// The alpha blend of SPEC §8 against its f64 twin; alpha files.
mod alpha;
/// Malformed and invalid inputs are refused with messages naming file, item and field.
mod bad_input;
/// Every count bounded and every decode shared; special files refused at once; one GIF
/// screen.
mod bounds;
/// Captures as shipped: float sizes, lens distortion, COLMAP text and binary, point clouds,
/// masks, missing frames.
mod captures;
/// The `splat4d` binary, run as a user runs it: every subcommand, its outputs and errors.
mod cli;
/// Synthetic datasets: splits, cameras, times, and D-NeRF files read back.
mod dataset;
/// Datasets as other tools write them (RGBA, nerfstudio, static, JPEG, rounded matrices), fitted with the default command.
mod dataset_variants;
/// The same bits for every thread count.
mod determinism;
/// The manual against the executable: the commands reference, the version.
mod docs;
/// Nothing non-finite leaves with exit 0; absurd inputs are refused naming their field.
mod finite_outputs;
/// Fitting recovers known scenes; adaptive fits find the kernels they need.
mod fit;
/// The alpha fit recovers occluding scenes.
mod fit_alpha;
/// Every `fit` flag acts on the chosen blend's fit or is refused naming its blend.
mod fit_flags;
/// Every other command's flags act or are refused naming the flag and why.
mod flags_elsewhere;
/// Seeded byte-level fuzzing of every loader: errors, never panics.
mod fuzz_loaders;
/// 3DGS PLYs both ways: graphdeco files read, exports drawn by a minimal 3DGS compositor.
mod gaussians_3d;
/// glTF import on the Khronos samples: animation, cameras, colours.
mod gltf;
/// Imported animations measured from renders over time.
mod gltf_motion;
/// The backward pass against the f64 backward, finite differences and independent vectors.
mod gradients;
/// Numerically hard scenes against the f64 reference, forward and backward.
mod hard_cases;
/// Every import in src/ respects the layer order of src/lib.rs.
mod layers;
/// Each fast stage against its f64 twin, and whole renders against independent vectors.
mod matches_reference;
/// The memory rule: estimates above the available memory or --max-memory are refused first.
mod memory;
/// Messages of the fourth attack round: values cut, the file's own property named, extreme
/// times kept finite or refused.
mod messages;
/// Acceleration and angular velocity (SPEC §9): renders, gradients of every field, files.
mod motion;
/// `mpirun -n N splat4d fit` gives the one-process scene (cargo feature `mpi`).
#[cfg(feature = "mpi")]
mod mpi;
/// Neural 3D Video rigs: poses_bounds.npy with extracted frames or videos.
mod n3v;
/// The output rule: only a command's own earlier output is replaced, never an input.
mod outputs;
/// PLY: 3DGS slices read by an independent parser, 4D scenes round-tripped.
mod ply;
/// Property tests (proptest, fixed seed) on random cameras and scenes.
mod properties;
/// The CLI writes the same bytes as before the layered move (issue 15).
mod recorded;
/// `--shard I/N` and `--assemble`: a batch scheduler's array job gives one run's bytes.
mod shards;
/// Each fast stage against its f64 twin, one stage at a time on the same input.
mod stages;
/// The temporal index renders exactly what a plain render does.
mod temporal_index;
/// Binning lists exactly the tiles each ellipse reaches.
mod tiles;
/// Videos: frames, GIFs, the MP4 path through a stand-in ffmpeg.
mod video;
/// `splat4d view` in headless Chromium: drawing, orbiting, scrubbing, comparing, speed.
mod view;
/// Eq. 1 volumes against the f64 evaluation.
mod volume;
