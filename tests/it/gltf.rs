//! glTF on the Khronos samples in tests/data/gltf: an animated box's kernels follow the
//! file's own keyframes, a model's camera frames it, vertex colours carry over, and skins,
//! morph targets and orthographic cameras are refused clearly.

use std::path::PathBuf;

use splat4d::io::gltf::Spacing;
use splat4d::io::gltf::{import_scene, load_camera};

const ADAPTIVE: Spacing = Spacing::Adaptive { tolerance: 1e-3 };
use crate::common::run_limited;
use splat4d::slice::{SlicedKernels, slice};
use splat4d::{RenderOptions, render};
use std::path::Path;
use std::process::Command;

fn sample(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/gltf")
        .join(name)
}

/// The translation keyframes of BoxAnimated's animated node, read from the file with the
/// gltf crate's own accessors (not through splat4d's sampler).
fn translation_keys() -> Vec<(f64, [f64; 3])> {
    let (document, buffers) = {
        let gltf = gltf::Gltf::open(sample("BoxAnimated.gltf")).unwrap();
        let uri = match gltf.buffers().next().unwrap().source() {
            gltf::buffer::Source::Uri(u) => u.to_owned(),
            gltf::buffer::Source::Bin => unreachable!(),
        };
        use base64::Engine;
        let data = base64::engine::general_purpose::STANDARD
            .decode(uri.split_once(',').unwrap().1)
            .unwrap();
        (gltf.document, vec![data])
    };
    let animation = document
        .animations()
        .find(|a| {
            a.channels()
                .any(|c| c.target().property() == gltf::animation::Property::Translation)
        })
        .unwrap();
    let channel = animation.channels().next().unwrap();
    let reader = channel.reader(|b| Some(buffers[b.index()].as_slice()));
    let times: Vec<f32> = reader.read_inputs().unwrap().collect();
    let values: Vec<[f32; 3]> = match reader.read_outputs().unwrap() {
        gltf::animation::util::ReadOutputs::Translations(it) => it.collect(),
        _ => unreachable!(),
    };
    times
        .iter()
        .zip(values)
        .map(|(&t, v)| (f64::from(t), v.map(f64::from)))
        .collect()
}

fn expected_translation(keys: &[(f64, [f64; 3])], t: f64) -> [f64; 3] {
    let k = keys
        .iter()
        .rposition(|(kt, _)| *kt <= t)
        .unwrap()
        .min(keys.len() - 2);
    let s = ((t - keys[k].0) / (keys[k + 1].0 - keys[k].0)).clamp(0.0, 1.0);
    std::array::from_fn(|a| keys[k].1[a] + s * (keys[k + 1].1[a] - keys[k].1[a]))
}

#[test]
fn the_animated_box_follows_its_keyframes() {
    let keys = translation_keys();
    assert_eq!(keys.len(), 4);
    let imported = import_scene(&sample("BoxAnimated.gltf"), 1500, ADAPTIVE, 1).unwrap();
    let times = imported.times;
    let scene = &imported.scene;
    assert_eq!(imported.time_range, [0.0, keys[3].0]);
    // The inner box's points are those whose kernels move (the outer box is static).
    let moving: Vec<bool> = (0..imported.points)
        .map(|p| (0..times).any(|k| scene.velocities[p * times + k] != [0.0; 3]))
        .collect();
    let inner_points = moving.iter().filter(|&&m| m).count();
    assert!(
        inner_points > 300 && inner_points < 1200,
        "{inner_points} moving points"
    );
    let centroid = |tau: f64| {
        let mut sliced = SlicedKernels::default();
        slice(scene, tau, 0.0, &mut sliced);
        let (mut sum, mut weight) = ([0.0; 3], 0.0);
        for s in 0..sliced.len() {
            let i = sliced.kernel_from_slice[s] as usize;
            if moving[i / times] {
                let w = sliced.amplitudes[s].iter().sum::<f64>();
                for (total, m) in sum.iter_mut().zip(sliced.means[s]) {
                    *total += w * m;
                }
                weight += w;
            }
        }
        sum.map(|v| v / weight)
    };
    let origin = centroid(0.0);
    let offset = |tau: f64| -> [f64; 3] {
        let (c, e) = (centroid(tau), expected_translation(&keys, tau));
        std::array::from_fn(|a| c[a] - e[a])
    };
    let norm = |v: [f64; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    let rest = offset(0.0);
    assert!(
        norm(rest) < 0.05,
        "the sampled points' centroid is near the box centre: {rest:?}"
    );
    // Away from the keyframes' corners (more than 3 σt = 3 Δt ≈ 0.18 s from 1.25 and 2.5).
    for tau in [0.3, 0.625, 1.0, 1.9, 3.1, 3.5] {
        let d = offset(tau);
        if tau <= 1.25 {
            // Before the spin (which starts at 1.25 s) the points translate rigidly.
            for a in 0..3 {
                assert!(
                    (d[a] - rest[a]).abs() < 0.01,
                    "t = {tau}: axis {a}: off the keyframes by {} (at rest {})",
                    d[a],
                    rest[a]
                );
            }
        }
        // The spin is about the box centre: the centroid keeps its distance to it.
        assert!(
            (norm(d) - norm(rest)).abs() < 0.01,
            "t = {tau}: centroid {:?} is {} from the keyframed centre, {} at rest",
            centroid(tau),
            norm(d),
            norm(rest)
        );
    }
    // At the corners of the path too (ladders of narrow kernels on both sides of a key).
    for tau in [1.25, 2.5] {
        let d = offset(tau);
        assert!(
            (norm(d) - norm(rest)).abs() < 0.01,
            "corner t = {tau}: {} vs {} at rest",
            norm(d),
            norm(rest)
        );
    }
    // Rendered: at the top of its path the inner box lights up where it should, and that
    // place is dark at t = 0.
    let camera = splat4d::Camera::look_at(
        [6.0, 1.5, 6.0],
        [0.0, 1.2, 0.0],
        [0.0, 1.0, 0.0],
        45.0,
        96,
        96,
    )
    .unwrap();
    let top = [origin[0], origin[1] + 2.52, origin[2]];
    let [u, v, _] = camera.project_point(top);
    let (u, v) = (u as u32, v as u32);
    let bright = |tau: f64| {
        render(scene, &camera, tau, &RenderOptions::default())
            .unwrap()
            .pixel(u, v)
            .iter()
            .sum::<f32>()
    };
    assert!(
        bright(1.9) > 0.5,
        "the box at its top, pixel ({u}, {v}): {}",
        bright(1.9)
    );
    assert!(
        bright(0.0) < 0.05,
        "nothing there at t = 0: {}",
        bright(0.0)
    );
}

#[test]
fn a_models_own_camera_frames_it() {
    let camera = load_camera(&sample("Cameras.gltf"), 0, Some((128, 128))).unwrap();
    assert!(
        (camera.fy - 64.0 / (0.5 * f64::from(0.7_f32)).tan()).abs() < 1e-9
            && camera.fx == camera.fy
    );
    assert_eq!((camera.near, camera.far), (0.01_f32 as f64, 100.0));
    let centre = camera.centre();
    assert!(
        (centre[0] - 0.5).abs() < 1e-6
            && (centre[1] - 0.5).abs() < 1e-6
            && (centre[2] - 3.0).abs() < 1e-6
    );
    let imported = import_scene(&sample("Cameras.gltf"), 3000, Spacing::Even(1), 2).unwrap();
    let image = render(&imported.scene, &camera, 0.0, &RenderOptions::default()).unwrap();
    // The quad's corners, (0,0,0), (1,0,0), (0,1,0), (1,1,0) turned -45° about x, projected.
    let tilt = 2.0 * 0.383_f64.atan2(0.92375);
    let corners = [[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]]
        .map(|[x, y]: [f64; 2]| [x, y * tilt.cos(), -y * tilt.sin()]);
    let projected: Vec<(f64, f64)> = corners
        .iter()
        .map(|&p| {
            let [u, v, _] = camera.project_point(p);
            (u, v)
        })
        .collect();
    let (lo_u, hi_u) = projected
        .iter()
        .fold((f64::MAX, f64::MIN), |(l, h), p| (l.min(p.0), h.max(p.0)));
    let (lo_v, hi_v) = projected
        .iter()
        .fold((f64::MAX, f64::MIN), |(l, h), p| (l.min(p.1), h.max(p.1)));
    assert!(
        lo_u > 0.0 && hi_u < 128.0 && lo_v > 0.0 && hi_v < 128.0,
        "the quad is inside the frame"
    );
    let (mut box_lo, mut box_hi) = ((u32::MAX, u32::MAX), (0, 0));
    for j in 0..128 {
        for i in 0..128 {
            if image.pixel(i, j)[0] > 0.3 {
                box_lo = (box_lo.0.min(i), box_lo.1.min(j));
                box_hi = (box_hi.0.max(i), box_hi.1.max(j));
            }
        }
    }
    for (got, want) in [
        (box_lo.0, lo_u),
        (box_hi.0, hi_u),
        (box_lo.1, lo_v),
        (box_hi.1, hi_v),
    ] {
        assert!(
            (f64::from(got) - want).abs() < 4.0,
            "lit region {box_lo:?}–{box_hi:?} vs projected quad u {lo_u:.1}–{hi_u:.1}, v {lo_v:.1}–{hi_v:.1}"
        );
    }
    let message = load_camera(&sample("Cameras.gltf"), 1, None)
        .unwrap_err()
        .to_string();
    assert!(message.contains("orthographic"), "{message}");
    let message = load_camera(&sample("Cameras.gltf"), 2, None)
        .unwrap_err()
        .to_string();
    assert!(
        message.contains("#2") && message.contains("2 camera nodes"),
        "{message}"
    );
}

#[test]
fn vertex_colours_carry_over() {
    // BoxVertexColors: COLOR_0 equals the vertex position on the unit cube.
    let imported = import_scene(&sample("BoxVertexColors.gltf"), 500, Spacing::Even(1), 3).unwrap();
    let scene = &imported.scene;
    let gain = scene
        .amplitudes
        .iter()
        .flatten()
        .cloned()
        .fold(0.0, f64::max);
    // Surfels at σ = spacing sum to 2π times their amplitude: the gain is 1/(2π), reached
    // on the faces whose colour channel is 1.
    assert!(
        (gain - 1.0 / std::f64::consts::TAU).abs() < 1e-6,
        "gain {gain}"
    );
    for i in 0..scene.len() {
        for a in 0..3 {
            let colour = scene.amplitudes[i][a] / gain;
            assert!(
                (colour - scene.means[i][a]).abs() < 0.02,
                "kernel {i}: colour {colour} at {}",
                scene.means[i][a]
            );
        }
    }
    let box_scene = import_scene(&sample("Box.gltf"), 200, Spacing::Even(8), 0).unwrap();
    assert_eq!(
        (box_scene.times, box_scene.scene.len()),
        (1, 200),
        "a static model gives one kernel per point"
    );
}

#[test]
fn skins_and_morph_targets_are_refused() {
    let text = std::fs::read_to_string(sample("Box.gltf")).unwrap();
    let mut json: serde_json::Value = serde_json::from_str(&text).unwrap();
    let position = json["meshes"][0]["primitives"][0]["attributes"]["POSITION"].clone();
    let dir = tempfile::tempdir().unwrap();
    let mut morph = json.clone();
    morph["meshes"][0]["primitives"][0]["targets"] = serde_json::json!([{"POSITION": position}]);
    std::fs::write(dir.path().join("morph.gltf"), morph.to_string()).unwrap();
    let message = import_scene(&dir.path().join("morph.gltf"), 10, Spacing::Even(1), 0)
        .unwrap_err()
        .to_string();
    assert!(
        message.contains("morph.gltf") && message.contains("morph targets are not supported"),
        "{message}"
    );
    let mesh_node = json["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .position(|n| n.get("mesh").is_some())
        .unwrap();
    json["nodes"][mesh_node]["skin"] = serde_json::json!(0);
    json["skins"] = serde_json::json!([{"joints": [mesh_node]}]);
    std::fs::write(dir.path().join("skin.gltf"), json.to_string()).unwrap();
    let message = import_scene(&dir.path().join("skin.gltf"), 10, Spacing::Even(1), 0)
        .unwrap_err()
        .to_string();
    assert!(
        message.contains("skin.gltf") && message.contains("skinned meshes are not supported"),
        "{message}"
    );
    std::fs::write(dir.path().join("broken.gltf"), "{\"asset\": 3}").unwrap();
    let message = import_scene(&dir.path().join("broken.gltf"), 10, Spacing::Even(1), 0)
        .unwrap_err()
        .to_string();
    assert!(
        message.contains("broken.gltf") && message.contains("glTF"),
        "{message}"
    );
}

#[test]
fn a_glb_imports_like_its_gltf() {
    use base64::Engine;
    let text = std::fs::read_to_string(sample("Box.gltf")).unwrap();
    let mut json: serde_json::Value = serde_json::from_str(&text).unwrap();
    let uri = json["buffers"][0]["uri"].as_str().unwrap().to_owned();
    let mut bin = base64::engine::general_purpose::STANDARD
        .decode(uri.split_once(',').unwrap().1)
        .unwrap();
    json["buffers"][0].as_object_mut().unwrap().remove("uri");
    let mut json_bytes = json.to_string().into_bytes();
    while !json_bytes.len().is_multiple_of(4) {
        json_bytes.push(b' ');
    }
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let total = 12 + 8 + json_bytes.len() + 8 + bin.len();
    let mut glb = Vec::new();
    glb.extend_from_slice(b"glTF");
    glb.extend_from_slice(&2u32.to_le_bytes());
    glb.extend_from_slice(&(total as u32).to_le_bytes());
    glb.extend_from_slice(&(json_bytes.len() as u32).to_le_bytes());
    glb.extend_from_slice(b"JSON");
    glb.extend_from_slice(&json_bytes);
    glb.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    glb.extend_from_slice(b"BIN\0");
    glb.extend_from_slice(&bin);
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("box.glb"), glb).unwrap();
    let from_glb = import_scene(&dir.path().join("box.glb"), 300, Spacing::Even(1), 4).unwrap();
    let from_gltf = import_scene(&sample("Box.gltf"), 300, Spacing::Even(1), 4).unwrap();
    assert_eq!(from_glb.scene, from_gltf.scene);
}

/// `import-gltf --blend alpha` makes opaque surfaces: the animated box's outer box hides
/// what is behind its front faces (the inner box, the back faces, the background), where the
/// additive import shows them through.
#[test]
fn an_alpha_import_closes_its_surfaces() {
    use splat4d::io::gltf::Spacing;
    use splat4d::io::gltf::import_scene;
    let path = sample("BoxAnimated.gltf");
    let imported = import_scene(&path, 3000, Spacing::Even(3), 0).unwrap();
    let additive = imported.scene.clone();
    let alpha = imported.into_alpha("<test>").unwrap().scene;
    assert_eq!(alpha.blend, splat4d::Blend::Alpha);
    let camera = splat4d::Camera::look_at(
        [2.2, 1.6, 2.8],
        [0.0, 0.3, 0.0],
        [0.0, 1.0, 0.0],
        40.0,
        96,
        72,
    )
    .unwrap();
    // The light that passes a surface is what a background change shows through it.
    let through = |scene: &splat4d::Scene| {
        let render = |background: f64| {
            let mut lit = scene.clone();
            lit.background = [background; 3];
            splat4d::render(&lit, &camera, 1.2, &splat4d::RenderOptions::default()).unwrap()
        };
        let (dark, bright) = (render(0.0), render(1.0));
        // The box's middle, 5×5 pixels around the image centre.
        let mut worst = 0.0_f32;
        for j in 34..39 {
            for i in 46..51 {
                worst = worst.max(bright.pixel(i, j)[0] - dark.pixel(i, j)[0]);
            }
        }
        worst
    };
    let alpha_through = through(&alpha);
    let additive_through = through(&additive);
    assert!(
        alpha_through < 1e-3,
        "alpha surfaces let {alpha_through} through"
    );
    assert!(
        additive_through > 0.99,
        "additive surfels add: {additive_through}"
    );
}

// Limits through the executable (from the former limits.rs): refused quickly, with a
// message and exit status, never a panic, a hang or an unbounded allocation.

/// A change to a glTF document.
type Mutation = Box<dyn Fn(&mut serde_json::Value)>;

#[test]
fn gltf_files_that_break_the_crates_walkers_are_refused_with_their_json_path() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let source = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/gltf/BoxAnimated.gltf");
    let original: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(source).unwrap()).unwrap();
    let cases: Vec<(&str, Mutation, &str)> = vec![
        (
            "cycle",
            Box::new(|g| g["nodes"][0]["children"] = serde_json::json!([1, 0])),
            "nodes[0]",
        ),
        (
            "two parents",
            Box::new(|g| g["nodes"][3]["children"] = serde_json::json!([2])),
            "two parents",
        ),
        (
            "root and child",
            Box::new(|g| g["nodes"][1]["children"] = serde_json::json!([2, 3])),
            "a root of the scene",
        ),
        (
            "dangling channel",
            Box::new(|g| {
                g["animations"][0]["channels"][0]["target"]["node"] = serde_json::json!(99)
            }),
            "target.node",
        ),
        (
            "camera without object",
            Box::new(|g| g["cameras"] = serde_json::json!([{"type": "perspective"}])),
            "cameras[0]",
        ),
        (
            "no accessors",
            Box::new(|g| g["accessors"] = serde_json::json!([])),
            "out of range",
        ),
        (
            "float indices",
            Box::new(|g| {
                let i = g["meshes"][0]["primitives"][0]["indices"].as_u64().unwrap() as usize;
                g["accessors"][i]["componentType"] = serde_json::json!(5126);
            }),
            "indices",
        ),
        (
            "small stride",
            Box::new(|g| {
                let a = g["meshes"][0]["primitives"][0]["attributes"]["POSITION"]
                    .as_u64()
                    .unwrap() as usize;
                let v = g["accessors"][a]["bufferView"].as_u64().unwrap() as usize;
                g["bufferViews"][v]["byteStride"] = serde_json::json!(4);
            }),
            "byteStride",
        ),
        (
            "huge count",
            Box::new(|g| g["accessors"][0]["count"] = serde_json::json!(1_000_000_000u64)),
            "accessors[0]",
        ),
        (
            "view past its buffer",
            Box::new(|g| g["bufferViews"][0]["byteLength"] = serde_json::json!(100_000_000u64)),
            "bufferViews[0]",
        ),
        (
            "dangling material",
            Box::new(|g| g["meshes"][0]["primitives"][0]["material"] = serde_json::json!(99)),
            "material",
        ),
        (
            "dangling skin",
            Box::new(|g| g["nodes"][2]["skin"] = serde_json::json!(99)),
            "skin",
        ),
    ];
    for (name, mutate, needle) in cases {
        let mut gltf = original.clone();
        mutate(&mut gltf);
        let path = d.join(format!("{}.gltf", name.replace(' ', "_")));
        std::fs::write(&path, gltf.to_string()).unwrap();
        let file = path.to_str().unwrap();
        let output = run_limited(
            &[
                "import-gltf",
                file,
                "--kernels",
                "50",
                "--times",
                "3",
                "--out",
                "m.json",
            ],
            d,
        );
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(2), "{name}: {stderr}");
        assert!(stderr.contains(needle), "{name}: {stderr}");
        let camera = format!("{file}#0");
        let render = [
            "render",
            "--scene",
            "m.json",
            "--camera-from",
            &camera,
            "--time",
            "0",
            "--out",
            "r.png",
        ];
        let output = run_limited(&render, d);
        assert_ne!(
            output.status.code(),
            Some(101),
            "{name}: {}",
            String::from_utf8_lossy(&output.stderr)
        );
    }
    assert!(!d.join("m.json").exists());
}

#[test]
fn gltf_buffers_are_read_only_from_regular_files_beside_the_model() {
    use base64::Engine as _;
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let source = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/gltf/Box.gltf");
    let original: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(source).unwrap()).unwrap();
    // The embedded buffer as a file beside the model: read as before.
    let uri = original["buffers"][0]["uri"].as_str().unwrap().to_owned();
    let payload = base64::engine::general_purpose::STANDARD
        .decode(uri.split_once(',').unwrap().1)
        .unwrap();
    std::fs::create_dir(d.join("models")).unwrap();
    std::fs::write(d.join("models/box.bin"), &payload).unwrap();
    let with_uri = |uri: &str| {
        let mut gltf = original.clone();
        gltf["buffers"][0]["uri"] = serde_json::json!(uri);
        std::fs::write(d.join("models/m.gltf"), gltf.to_string()).unwrap();
        run_limited(
            &[
                "import-gltf",
                "models/m.gltf",
                "--kernels",
                "20",
                "--out",
                "m.json",
            ],
            d,
        )
    };
    let output = with_uri("box.bin");
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    std::fs::remove_file(d.join("m.json")).unwrap();
    #[cfg(unix)]
    assert!(
        Command::new("mkfifo")
            .arg(d.join("models/pipe"))
            .status()
            .unwrap()
            .success()
    );
    // A symlink beside the model to a file outside it (a real path check, not a lexical one).
    std::fs::write(d.join("secret.bin"), &payload).unwrap();
    #[cfg(unix)]
    std::os::unix::fs::symlink(d.join("secret.bin"), d.join("models/link.bin")).unwrap();
    for (uri, needle) in [
        ("/etc/passwd", "absolute"),
        ("../../../../etc/passwd", "leaves the model's folder"),
        ("%2e%2e/%2e%2e/etc/passwd", "leaves the model's folder"),
        ("/dev/zero", "absolute"),
        ("sub/../../x.bin", "leaves the model's folder"),
        ("pipe", "not a regular file"),
        (".", "not a regular file"),
        ("link.bin", "outside the model's folder"),
    ] {
        let output = with_uri(uri);
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(2), "{uri}: {stderr}");
        assert!(
            stderr.contains(needle) && stderr.contains("buffer 0"),
            "{uri}: {stderr}"
        );
    }
    assert!(!d.join("m.json").exists());
}
