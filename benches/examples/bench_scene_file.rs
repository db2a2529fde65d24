//! Writes a seeded bench scene and its camera as files, for timing whole `splat4d render`
//! processes:
//! `cargo run --release -p splat4d-benches --example bench_scene_file -- KERNELS WIDTH HEIGHT SCENE.ply CAMERA.json [OPACITY]`;
//! with `OPACITY` the same kernels as an alpha scene of that opacity (as `bench --blend alpha`).

use splat4d::scenes::synthetic::{bench_camera, bench_scene};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (args, opacity) = match args.as_slice() {
        [first @ .., opacity] if args.len() == 6 => (first, Some(opacity.parse::<f64>()?)),
        all => (all, None),
    };
    let [kernels, width, height, scene_path, camera_path] = args else {
        return Err(
            "usage: bench_scene_file KERNELS WIDTH HEIGHT SCENE.ply CAMERA.json [OPACITY]".into(),
        );
    };
    let kernels: usize = kernels.parse()?;
    let scene = bench_scene(kernels, 42);
    let scene = match opacity {
        Some(o) => scene.into_alpha(vec![o; kernels], 0, Vec::new(), "<bench>")?,
        None => scene,
    };
    let camera = bench_camera(width.parse()?, height.parse()?);
    splat4d::io::scene_file::save_scene(&scene, std::path::Path::new(scene_path))?;
    std::fs::write(
        camera_path,
        splat4d::io::camera_file::camera_to_json(&camera),
    )?;
    Ok(())
}
