//! Byte-level fuzzing of every loader: seeded mutations (byte flips, insertions, deletions,
//! truncations) of valid files must load or be refused with an input error, never panic.
//! Each test states the number of executions per loader (and README), checks that the
//! unmutated file loads, and asserts how many mutated inputs reached the parser (differ from
//! the valid file) and how many it refused: a harness whose bytes never reached the parser
//! would load every input and fail.

use std::panic::{AssertUnwindSafe, catch_unwind};

use rand::RngExt;
use rand_chacha::ChaCha8Rng;
use splat4d::io::image_file::{BitDepth, ImageKind};
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

/// What [`fuzz`] counted.
#[derive(Debug)]
struct Fuzzed {
    /// Mutated inputs tried.
    runs: usize,
    /// Mutated inputs that differ from the valid file (the others are the file itself).
    changed: usize,
    /// Of those, the ones the loader refused (every refusal an input error).
    refused: usize,
}

/// Runs `load` on `runs` mutations of `good` (which must load); panics (with the input) if
/// any load panics or fails with anything but an input error. Returns the counts.
fn fuzz(
    name: &str,
    good: &[u8],
    runs: usize,
    seed: u64,
    load: impl Fn(&[u8]) -> splat4d::Result<()>,
) -> Fuzzed {
    if let Err(e) = load(good) {
        panic!("{name}: the valid file does not load: {e}");
    }
    let mut rng = seeded_rng(seed);
    let (mut changed, mut refused) = (0, 0);
    for run in 0..runs {
        let bytes = mutate(&mut rng, good);
        let differs = bytes != good;
        changed += usize::from(differs);
        match catch_unwind(AssertUnwindSafe(|| load(&bytes))) {
            Ok(Ok(())) => {}
            Ok(Err(e)) => {
                assert_eq!(
                    e.kind(),
                    splat4d::ErrorKind::Input,
                    "{name}: run {run}: {e}"
                );
                assert!(differs, "{name}: run {run}: the valid file refused: {e}");
                refused += 1;
            }
            Err(_) => panic!(
                "{name}: run {run} panicked on {:?}",
                String::from_utf8_lossy(&bytes)
            ),
        }
    }
    println!("{name}: {runs} mutated inputs, {changed} changed, {refused} refused, none panicked");
    Fuzzed {
        runs,
        changed,
        refused,
    }
}

/// Asserts that 99 % of the mutated inputs differed from the valid file (reached the
/// parser as a new input) and that the loader refused at least `refused_share` of all
/// inputs (each test's share is below the one its seed gives, quoted there).
fn assert_reached(name: &str, fuzzed: &Fuzzed, refused_share: f64) {
    let runs = fuzzed.runs as f64;
    assert!(
        fuzzed.changed as f64 >= 0.99 * runs && fuzzed.refused as f64 >= refused_share * runs,
        "{name}: {fuzzed:?}, expected 99 % changed and {:.0} % refused",
        100.0 * refused_share
    );
}

#[test]
fn scene_and_camera_json() {
    let camera = crate::common::test_camera(16, 12);
    let scene = crate::common::hard_random_scene(&camera, 1, 3);
    let text = splat4d::io::scene_file::scene_to_json(&scene);
    let fuzzed = fuzz("scene JSON", text.as_bytes(), 20_000, 1, |b| {
        splat4d::io::scene_file::scene_from_json(&String::from_utf8_lossy(b), "fuzz.json").map(drop)
    });
    // Measured: 19 972 changed, 18 573 refused.
    assert_reached("scene JSON", &fuzzed, 0.85);
    let text = splat4d::io::camera_file::camera_to_json(&camera);
    let fuzzed = fuzz("camera JSON", text.as_bytes(), 20_000, 2, |b| {
        splat4d::io::camera_file::camera_from_json(&String::from_utf8_lossy(b), "fuzz.json")
            .map(drop)
    });
    // Measured: 19 970 changed, 18 746 refused.
    assert_reached("camera JSON", &fuzzed, 0.85);
}

#[test]
fn images_png_and_exr() {
    let dir = tempfile::tempdir().unwrap();
    let image = splat4d::Image::filled(9, 7, [0.3, 0.6, 0.9]);
    // Each file in its own format (the PNG was once an EXR named .png, so the PNG decoder
    // was never fuzzed). Measured: PNG 4000 changed, 3927 refused; EXR 4000 changed,
    // 3541 refused.
    for (name, kind, depth, runs, share) in [
        ("i.png", ImageKind::Png, BitDepth::Sixteen, 4000, 0.9),
        ("i.exr", ImageKind::Exr, BitDepth::Sixteen, 4000, 0.8),
    ] {
        let path = dir.path().join(name);
        let mut bytes = std::io::Cursor::new(Vec::new());
        splat4d::io::image_file::encode_image(&image, kind, depth, &mut bytes).unwrap();
        std::fs::write(&path, bytes.into_inner()).unwrap();
        let good = std::fs::read(&path).unwrap();
        let target = dir.path().join(format!("m_{name}"));
        let fuzzed = fuzz(name, &good, runs, 3, |b| {
            std::fs::write(&target, b).unwrap();
            splat4d::io::image_file::load_image(&target, [0.0; 3]).map(drop)
        });
        assert_reached(name, &fuzzed, share);
    }
}

#[test]
fn gltf_and_glb() {
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/gltf/BoxAnimated.gltf");
    let good = std::fs::read(&path).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let target = dir.path().join("m.gltf");
    // Refused: the import and the camera both refuse it (the first error is counted).
    let fuzzed = fuzz("glTF", &good, 1500, 4, |b| {
        std::fs::write(&target, b).unwrap();
        let scene =
            splat4d::io::gltf::import_scene(&target, 20, splat4d::io::gltf::Spacing::Even(3), 0);
        let camera = splat4d::io::gltf::load_camera(&target, 0, Some((8, 8)));
        match (scene, camera) {
            (Err(e), Err(_)) => Err(e),
            _ => Ok(()),
        }
    });
    // Measured: 1499 changed, 1406 refused.
    assert_reached("glTF", &fuzzed, 0.85);
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
    let fuzzed = fuzz("transforms_train.json", &good, 3000, 5, |b| {
        std::fs::write(&transforms, b).unwrap();
        splat4d::io::dataset::load_dataset(dir.path(), &Default::default()).map(drop)
    });
    // Measured: 2999 changed, 2785 refused.
    assert_reached("transforms_train.json", &fuzzed, 0.85);
}

#[test]
fn n3v_poses_bounds() {
    let dir = tempfile::tempdir().unwrap();
    let cameras = crate::n3v::rig(2);
    crate::n3v::write_frames(dir.path(), &cameras, 2);
    crate::n3v::write_poses(dir.path(), &cameras, 1.0);
    let poses = dir.path().join("poses_bounds.npy");
    let good = std::fs::read(&poses).unwrap();
    let fuzzed = fuzz("poses_bounds.npy", &good, 1000, 6, |b| {
        std::fs::write(&poses, b).unwrap();
        splat4d::io::dataset::load_dataset(dir.path(), &Default::default()).map(drop)
    });
    // Measured: 1000 changed, 902 refused.
    assert_reached("poses_bounds.npy", &fuzzed, 0.85);
}

/// Every JSON path to a number, string or array in `value` (object keys and array indices).
fn paths(value: &serde_json::Value, at: &mut Vec<String>, out: &mut Vec<Vec<String>>) {
    match value {
        serde_json::Value::Object(map) => {
            for (key, v) in map {
                at.push(key.clone());
                out.push(at.clone());
                paths(v, at, out);
                at.pop();
            }
        }
        serde_json::Value::Array(items) => {
            for (i, v) in items.iter().enumerate() {
                at.push(i.to_string());
                out.push(at.clone());
                paths(v, at, out);
                at.pop();
            }
        }
        _ => {}
    }
}

/// The value at `path`, if an earlier mutation left it there.
fn at_path<'a>(
    value: &'a mut serde_json::Value,
    path: &[String],
) -> Option<&'a mut serde_json::Value> {
    path.iter().try_fold(value, |v, key| match v {
        serde_json::Value::Array(items) => items.get_mut(key.parse::<usize>().ok()?),
        serde_json::Value::Object(map) => map.get_mut(key),
        _ => None,
    })
}

/// Structural mutations of a glTF document, the kinds that broke the gltf crate's walkers:
/// dangling and self-referencing indices (node cycles, children that point up), wrong
/// component types and strides, counts and offsets past their views, URIs that leave the
/// model's folder or name devices, values of the wrong JSON type, removed keys.
fn mutate_gltf(rng: &mut ChaCha8Rng, good: &serde_json::Value) -> serde_json::Value {
    let mut doc = good.clone();
    let mut all = Vec::new();
    paths(&doc, &mut Vec::new(), &mut all);
    for _ in 0..rng.random_range(1..4) {
        let path = &all[rng.random_range(0..all.len())];
        let last = path.last().unwrap().as_str();
        let replacement = match (last, rng.random_range(0..12)) {
            ("uri", k) => serde_json::json!(
                [
                    "/etc/passwd",
                    "../../../../etc/passwd",
                    "/dev/zero",
                    "%2e%2e/x.bin",
                    "data:application/octet-stream;base64,AAAA",
                    "data:,",
                    "missing.bin",
                    "",
                    ".",
                    "/proc/self/cmdline",
                    "a/../../b.bin",
                    "BoxAnimated0.bin"
                ][k]
            ),
            ("componentType", k) => {
                serde_json::json!(
                    [
                        5120, 5121, 5122, 5123, 5125, 5126, 5124, 0, 1, 9999, 5126, 5123
                    ][k]
                )
            }
            ("type", k) => serde_json::json!(
                [
                    "SCALAR", "VEC2", "VEC3", "VEC4", "MAT4", "MAT2", "VEC9", "", "scalar", "VEC3",
                    "MAT3", "X"
                ][k]
            ),
            (_, 0) => serde_json::json!(0),
            (_, 1) => serde_json::json!(99),
            (_, 2) => serde_json::json!(-1),
            (_, 3) => serde_json::json!(4_294_967_295_u64),
            (_, 4) => serde_json::json!(1e300),
            (_, 5) => serde_json::json!(0.5),
            (_, 6) => serde_json::json!("x"),
            (_, 7) => serde_json::Value::Null,
            (_, 8) => serde_json::json!([0, 0, 1]),
            (_, 9) => serde_json::json!([]),
            (_, 10) => serde_json::json!({}),
            _ => serde_json::json!(rng.random_range(0..4)),
        };
        if let Some(slot) = at_path(&mut doc, path) {
            *slot = replacement;
        }
    }
    // Sometimes a node cycle: a node lists itself or its parent among its children.
    if rng.random_range(0..4) == 0
        && let Some(nodes) = doc["nodes"].as_array_mut()
        && !nodes.is_empty()
    {
        let n = nodes.len();
        let (a, b) = (rng.random_range(0..n), rng.random_range(0..n));
        if let Some(node) = nodes[a].as_object_mut() {
            node.insert("children".into(), serde_json::json!([b, a]));
        }
    }
    doc
}

#[test]
fn gltf_structural_mutations() {
    let source =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/gltf/BoxAnimated.gltf");
    let good: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&source).unwrap()).unwrap();
    let dir = tempfile::tempdir().unwrap();
    // The model's buffer beside it, so that unmutated URIs resolve.
    for entry in std::fs::read_dir(source.parent().unwrap()).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "bin") {
            std::fs::copy(&path, dir.path().join(path.file_name().unwrap())).unwrap();
        }
    }
    let target = dir.path().join("m.gltf");
    let mut rng = seeded_rng(6);
    let (runs, mut refused) = (5000, 0);
    for run in 0..runs {
        let doc = mutate_gltf(&mut rng, &good);
        std::fs::write(&target, doc.to_string()).unwrap();
        let start = std::time::Instant::now();
        let outcome = catch_unwind(AssertUnwindSafe(|| {
            let scene = splat4d::io::gltf::import_scene(
                &target,
                20,
                splat4d::io::gltf::Spacing::Adaptive { tolerance: 1e-3 },
                0,
            );
            let camera = splat4d::io::gltf::load_camera(&target, 0, Some((8, 8)));
            (scene.is_ok(), camera.is_ok())
        }));
        match outcome {
            Ok((true, _)) => {}
            Ok((false, _)) => refused += 1,
            Err(_) => panic!("glTF structure: run {run} panicked on {doc}"),
        }
        assert!(
            start.elapsed() < std::time::Duration::from_secs(5),
            "glTF structure: run {run} took {:?} on {doc}",
            start.elapsed()
        );
    }
    println!("glTF structure: {runs} mutated documents, {refused} refused, none panicked");
    // Measured: 4374 refused.
    assert!(
        refused >= 4000,
        "{refused} refused: the mutations should break most documents"
    );
}

/// Float images with NaN or ±∞ at a random pixel and channel: always refused, the message
/// naming the file and that pixel.
#[test]
fn non_finite_pixels_are_refused_naming_the_pixel() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("t.exr");
    let mut rng = seeded_rng(7);
    for run in 0..200 {
        let (w, h) = (rng.random_range(1..24_u32), rng.random_range(1..24_u32));
        let mut image = splat4d::Image::filled(w, h, [0.5; 3]);
        let (x, y, c) = (
            rng.random_range(0..w),
            rng.random_range(0..h),
            rng.random_range(0..3_usize),
        );
        let bad = [f32::NAN, f32::INFINITY, f32::NEG_INFINITY][run % 3];
        image.pixels[3 * (y * w + x) as usize + c] = bad;
        // Encoded directly: `save_image` itself refuses to write a non-finite pixel.
        let mut bytes = std::io::Cursor::new(Vec::new());
        splat4d::io::image_file::encode_image(
            &image,
            splat4d::io::image_file::ImageKind::Exr,
            splat4d::io::image_file::BitDepth::Sixteen,
            &mut bytes,
        )
        .unwrap();
        std::fs::write(&path, bytes.into_inner()).unwrap();
        let error = splat4d::io::image_file::load_image(&path, [0.0; 3])
            .expect_err("a non-finite pixel is refused")
            .to_string();
        assert!(
            error.contains("t.exr") && error.contains(&format!("({x}, {y})")),
            "run {run}: {bad} at ({x}, {y}) channel {c}: {error}"
        );
    }
}
