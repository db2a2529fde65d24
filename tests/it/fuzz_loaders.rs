//! Byte-level fuzzing of every loader: seeded mutations (byte flips, insertions, deletions,
//! truncations) of valid files must load or be refused with an error, never panic. The
//! number of executions per loader is stated in each test (and in README).

use std::panic::{AssertUnwindSafe, catch_unwind};

use rand::RngExt;
use rand_chacha::ChaCha8Rng;
use splat4d::model::random::seeded_rng;

fn mutate(rng: &mut ChaCha8Rng, good: &[u8]) -> Vec<u8> {
    let mut bytes = good.to_vec();
    for _ in 0..rng.random_range(1..5) {
        if bytes.is_empty() {
            break;
        }
        let k = rng.random_range(0..bytes.len());
        match rng.random_range(0..5) {
            0 => bytes[k] = rng.random(),
            1 => bytes.insert(k, rng.random()),
            2 => {
                bytes.remove(k);
            }
            3 => bytes[k] = b"0123456789-+.eE,:[]{}\"nul"[rng.random_range(0..25)],
            _ => bytes.truncate(k),
        }
    }
    bytes
}

/// Runs `load` on `runs` mutations of `good`; panics (with the input's seed) if any load
/// panics. Returns how many were refused.
fn fuzz(name: &str, good: &[u8], runs: usize, seed: u64, load: impl Fn(&[u8]) -> bool) -> usize {
    let mut rng = seeded_rng(seed);
    let mut refused = 0;
    for run in 0..runs {
        let bytes = mutate(&mut rng, good);
        match catch_unwind(AssertUnwindSafe(|| load(&bytes))) {
            Ok(true) => {}
            Ok(false) => refused += 1,
            Err(_) => panic!(
                "{name}: run {run} panicked on {:?}",
                String::from_utf8_lossy(&bytes)
            ),
        }
    }
    println!("{name}: {runs} mutated inputs, {refused} refused, none panicked");
    refused
}

#[test]
fn scene_and_camera_json() {
    let camera = crate::common::test_camera(16, 12);
    let scene = crate::common::hard_random_scene(&camera, 1, 3);
    let text = splat4d::io::scene_file::scene_to_json(&scene);
    let refused = fuzz("scene JSON", text.as_bytes(), 20_000, 1, |b| {
        splat4d::io::scene_file::scene_from_json(&String::from_utf8_lossy(b), "fuzz.json").is_ok()
    });
    assert!(refused > 1000);
    let text = splat4d::io::camera_file::camera_to_json(&camera);
    let refused = fuzz("camera JSON", text.as_bytes(), 20_000, 2, |b| {
        splat4d::io::camera_file::camera_from_json(&String::from_utf8_lossy(b), "fuzz.json").is_ok()
    });
    assert!(refused > 1000);
}

#[test]
fn images_png_and_exr() {
    let dir = tempfile::tempdir().unwrap();
    let image = splat4d::Image::filled(9, 7, [0.3, 0.6, 0.9]);
    for (name, runs) in [("i.png", 4000), ("i.exr", 4000)] {
        let path = dir.path().join(name);
        splat4d::io::image_file::save_image(
            &image,
            &path,
            splat4d::io::image_file::BitDepth::Sixteen,
        )
        .unwrap();
        let good = std::fs::read(&path).unwrap();
        let target = dir.path().join(format!("m_{name}"));
        fuzz(name, &good, runs, 3, |b| {
            std::fs::write(&target, b).unwrap();
            splat4d::io::image_file::load_image(&target, [0.0; 3]).is_ok()
        });
    }
}

#[test]
fn gltf_and_glb() {
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/gltf/BoxAnimated.gltf");
    let good = std::fs::read(&path).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let target = dir.path().join("m.gltf");
    fuzz("glTF", &good, 1500, 4, |b| {
        std::fs::write(&target, b).unwrap();
        let scene = splat4d::io::gltf_import::import_scene(&target, 20, 3, 0).is_ok();
        let camera = splat4d::io::gltf_import::load_camera(&target, 0, Some((8, 8))).is_ok();
        scene || camera
    });
}

#[test]
fn dataset_transforms() {
    let dir = tempfile::tempdir().unwrap();
    let scene = splat4d::scenes::toy::blob_scene();
    let spec = splat4d::scenes::dataset::DatasetSpec {
        views: 2,
        times: 2,
        width: 8,
        height: 8,
        ..Default::default()
    };
    let data = splat4d::scenes::dataset::render_dataset(
        &scene,
        &spec,
        &splat4d::RenderOptions::default(),
        || {},
    )
    .unwrap();
    splat4d::io::dataset::write_split(dir.path(), "train", &data.train, false).unwrap();
    let transforms = dir.path().join("transforms_train.json");
    let good = std::fs::read(&transforms).unwrap();
    fuzz("transforms_train.json", &good, 3000, 5, |b| {
        std::fs::write(&transforms, b).unwrap();
        splat4d::io::dataset::load_dataset(dir.path(), &Default::default()).is_ok()
    });
}
