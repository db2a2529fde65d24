//! PLY: 4D scenes round-trip exactly and load wherever a scene does; 3DGS slices carry the
//! standard layout; an independent parser (ply-rs) reads both; bad files are refused with a
//! clear error, never a panic, and never an allocation sized by an unchecked header.

use ply_rs_bw::parser::Parser;
use ply_rs_bw::ply::{DefaultElement, Property};
use splat4d::io::ply::{
    SCENE_PROPERTIES, SH_C0, SLICE_PROPERTIES, parse_scene_ply, write_slice_ply,
};
use splat4d::slice::{SlicedKernels, slice};
use splat4d::{RenderOptions, Scene};

fn independent_read(path: &std::path::Path) -> (Vec<String>, Vec<DefaultElement>) {
    let mut file = std::fs::File::open(path).unwrap();
    let ply = Parser::<DefaultElement>::new().read_ply(&mut file).unwrap();
    let names = ply.header.elements["vertex"]
        .properties
        .keys()
        .cloned()
        .collect();
    (names, ply.payload["vertex"].clone())
}

fn value(element: &DefaultElement, name: &str) -> f64 {
    match element[name] {
        Property::Double(v) => v,
        Property::Float(v) => f64::from(v),
        ref other => panic!("{name}: unexpected {other:?}"),
    }
}

fn scene() -> Scene {
    crate::common::hard_random_scene(&crate::common::test_camera(32, 32), 21, 200)
}

#[test]
fn scene_ply_round_trips_exactly_and_is_smaller_than_json() {
    let mut scene = scene();
    scene.up = Some(splat4d::model::Up::NegZ);
    let dir = tempfile::tempdir().unwrap();
    let (ply, json) = (dir.path().join("s.ply"), dir.path().join("s.json"));
    splat4d::io::scene_file::save_scene(&scene, &ply).unwrap();
    splat4d::io::scene_file::save_scene(&scene, &json).unwrap();
    assert_eq!(splat4d::io::scene_file::load_scene(&ply).unwrap(), scene);
    assert_eq!(splat4d::io::scene_file::load_scene(&json).unwrap(), scene);
    let (ply_size, json_size) = (
        std::fs::metadata(&ply).unwrap().len(),
        std::fs::metadata(&json).unwrap().len(),
    );
    assert!(
        ply_size * 3 < json_size,
        "PLY {ply_size} bytes vs JSON {json_size}"
    );
    // Everything that takes a scene takes the PLY: the renders are identical.
    let camera = crate::common::test_camera(32, 32);
    let a = splat4d::render(
        &splat4d::io::scene_file::load_scene(&ply).unwrap(),
        &camera,
        0.5,
        &RenderOptions::default(),
    )
    .unwrap();
    let b = splat4d::render(&scene, &camera, 0.5, &RenderOptions::default()).unwrap();
    assert_eq!(a, b);
}

#[test]
fn scenes_of_no_kernel_and_of_several_read_blocks_round_trip() {
    // The reader takes rows a block (256 KiB) at a time, the first ones carried over from
    // the header's read, and reads the next block while it decodes one: an empty body, a
    // body within that read, and one of several blocks and a partial last one all come
    // back as written, on one thread and on two.
    let dir = tempfile::tempdir().unwrap();
    let camera = crate::common::test_camera(32, 32);
    for (k, general) in [0, 3, 16_000].into_iter().enumerate() {
        let scene = if general == 0 {
            Scene {
                background: [0.25, 0.5, 0.75],
                ..Scene::default()
            }
        } else {
            crate::common::hard_random_scene(&camera, 40 + k as u64, general)
        };
        let path = dir.path().join(format!("s{k}.ply"));
        splat4d::io::scene_file::save_scene(&scene, &path).unwrap();
        if general > 1000 {
            assert!(
                std::fs::metadata(&path).unwrap().len() > 2 << 20,
                "{general}"
            );
        }
        for threads in [1, 2] {
            let loaded = crate::common::on_threads(threads, || {
                splat4d::io::scene_file::load_scene(&path).unwrap()
            });
            assert_eq!(loaded, scene, "{general} kernels, {threads} threads");
        }
    }
}

#[test]
fn a_bad_kernel_or_a_short_body_in_a_later_block_is_named() {
    // 16 000 kernels and more: a bad scale written into the fifth block is named, on one
    // thread and on two, while the next block is read; the same file, good, cut short in its
    // last block is refused before any row is read, naming the file.
    let dir = tempfile::tempdir().unwrap();
    let camera = crate::common::test_camera(32, 32);
    let scene = crate::common::hard_random_scene(&camera, 9, 16_000);
    let good = dir.path().join("good.ply");
    splat4d::io::scene_file::save_scene(&scene, &good).unwrap();
    let bytes = std::fs::read(&good).unwrap();
    let body = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .unwrap()
        + 11;
    let stride = (bytes.len() - body) / scene.len();
    assert_eq!(stride % SCENE_PROPERTIES.len(), 0);
    let size = stride / SCENE_PROPERTIES.len();
    // `sy`, the sixth property, of kernel 9000, as a double or a float.
    let at = body + 9000 * stride + 5 * size;
    let mut bad_bytes = bytes.clone();
    match size {
        8 => bad_bytes[at..at + 8].copy_from_slice(&(-1.0_f64).to_le_bytes()),
        4 => bad_bytes[at..at + 4].copy_from_slice(&(-1.0_f32).to_le_bytes()),
        other => panic!("{other}-byte properties"),
    }
    let bad = dir.path().join("bad.ply");
    std::fs::write(&bad, &bad_bytes).unwrap();
    let short = dir.path().join("short.ply");
    std::fs::write(&short, &bytes[..bytes.len() - 100]).unwrap();
    for threads in [1, 2] {
        let error = |file: &std::path::Path| {
            crate::common::on_threads(threads, || {
                splat4d::io::scene_file::load_scene(file)
                    .unwrap_err()
                    .to_string()
            })
        };
        let message = error(&bad);
        assert!(
            message.contains("kernel 9000") && message.contains("scale[1]"),
            "{threads} threads: {message}"
        );
        let message = error(&short);
        assert!(
            message.contains("short.ply") && message.contains("bytes of data"),
            "{threads} threads: {message}"
        );
    }
}

#[test]
fn an_independent_parser_reads_the_scene_ply() {
    let scene = scene();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("s.ply");
    splat4d::io::scene_file::save_scene(&scene, &path).unwrap();
    let (names, rows) = independent_read(&path);
    assert_eq!(names, SCENE_PROPERTIES);
    assert_eq!(rows.len(), scene.len());
    for (i, row) in rows.iter().enumerate() {
        let k = scene.kernel(i);
        let expected = [
            k.mean[0],
            k.mean[1],
            k.mean[2],
            k.mean[3],
            k.scale[0],
            k.scale[1],
            k.scale[2],
            k.scale[3],
            k.amplitude[0],
            k.amplitude[1],
            k.amplitude[2],
            k.rotation[0],
            k.rotation[1],
            k.rotation[2],
            k.rotation[3],
            k.velocity[0],
            k.velocity[1],
            k.velocity[2],
        ];
        for (name, e) in SCENE_PROPERTIES.iter().zip(expected) {
            assert_eq!(value(row, name), e, "kernel {i} {name}");
        }
    }
}

#[test]
fn the_3dgs_slice_has_the_standard_layout_and_values() {
    let scene = scene();
    let tau = 0.4;
    let cutoff = RenderOptions::default().cutoff;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("slice.ply");
    let n = write_slice_ply(&scene, tau, cutoff, false, &path).unwrap();
    let mut sliced = SlicedKernels::default();
    slice(&scene, tau, cutoff, &mut sliced);
    assert_eq!(n, sliced.len());
    assert!(n > 100 && n < scene.len(), "{n} of {} alive", scene.len());
    let (names, rows) = independent_read(&path);
    assert_eq!(names, SLICE_PROPERTIES);
    for (s, row) in rows.iter().enumerate() {
        let i = sliced.kernel_from_slice[s] as usize;
        let close = |name: &str, expected: f64| {
            let v = value(row, name);
            assert!(
                (v - expected).abs() <= 1e-6 * expected.abs().max(1.0),
                "splat {s} {name}: {v} vs {expected}"
            );
        };
        for a in 0..3 {
            close(["x", "y", "z"][a], sliced.means[s][a]);
            close(
                ["scale_0", "scale_1", "scale_2"][a],
                scene.scales[i][a].ln(),
            );
        }
        for (q, name) in ["rot_0", "rot_1", "rot_2", "rot_3"].iter().enumerate() {
            close(name, scene.rotations[i][q]);
        }
        // Opacity and colour reproduce the amplitude: α c = a (for |a| ≤ 0.99).
        let alpha = 1.0 / (1.0 + (-value(row, "opacity")).exp());
        for c in 0..3 {
            let colour = value(row, &format!("f_dc_{c}")) * SH_C0 + 0.5;
            let a = sliced.amplitudes[s][c];
            let peak = sliced.amplitudes[s]
                .iter()
                .fold(0.0_f64, |m, v| m.max(v.abs()));
            if (0.01..=0.99).contains(&peak) {
                assert!(
                    (alpha * colour - a).abs() < 1e-5,
                    "splat {s} channel {c}: α c = {} vs a = {a}",
                    alpha * colour
                );
            }
        }
    }
}

fn valid_bytes() -> Vec<u8> {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("s.ply");
    let scene = crate::common::hard_random_scene(&crate::common::test_camera(16, 16), 3, 5);
    splat4d::io::scene_file::save_scene(&scene, &path).unwrap();
    std::fs::read(path).unwrap()
}

#[test]
fn bad_scene_plys_are_refused_clearly() {
    let good = valid_bytes();
    let text = |b: &[u8]| String::from_utf8_lossy(b).into_owned();
    let header_end = text(&good).find("end_header\n").unwrap() + "end_header\n".len();
    let with_header = |from: &str, to: &str| {
        let mut bytes = text(&good[..header_end]).replacen(from, to, 1).into_bytes();
        bytes.extend_from_slice(&good[header_end..]);
        bytes
    };
    let cases: Vec<(Vec<u8>, &str)> = vec![
        (good[..good.len() - 3].to_vec(), "need"),
        (
            with_header("element vertex 125", "element vertex 99999999999999"),
            "need",
        ),
        (
            with_header("element vertex 125", "element vertex 18446744073709551615"),
            "overflow",
        ),
        (
            with_header("element vertex 125", "element vertex -1"),
            "not a whole number",
        ),
        (
            with_header("binary_little_endian", "ascii"),
            "not supported",
        ),
        (
            with_header("property double vz", "property double speed"),
            "missing property `vz`",
        ),
        (
            with_header("property double vz", "property int vz"),
            "type `int`",
        ),
        (with_header("ply\n", "plx\n"), "does not start with `ply`"),
        (
            b"ply\nformat binary_little_endian 1.0\n".to_vec(),
            "end_header",
        ),
        (with_header("end_header", "end_headers"), "end_header"),
    ];
    assert!(
        text(&good).contains("element vertex 125"),
        "the fixture has 125 kernels"
    );
    for (bytes, expected) in cases {
        let message = parse_scene_ply(&bytes, "bad.ply")
            .expect_err(expected)
            .to_string();
        assert!(
            message.contains("bad.ply") && message.contains(expected),
            "`{message}` should mention `{expected}`"
        );
    }
    // A non-finite value names the kernel and the field.
    let mut nan = good.clone();
    nan[header_end + 8 * 4..header_end + 8 * 5].copy_from_slice(&(-1.0f64).to_le_bytes());
    let message = parse_scene_ply(&nan, "bad.ply").unwrap_err().to_string();
    assert!(
        message.contains("kernel 0") && message.contains("scale"),
        "{message}"
    );
}

#[test]
fn mutated_plys_never_panic() {
    let good = valid_bytes();
    assert!(parse_scene_ply(&good, "fuzz.ply").is_ok());
    let mut rng = splat4d::model::random::seeded_rng(5);
    use rand::RngExt;
    let (mut changed, mut refused) = (0, 0);
    for _ in 0..3000 {
        let mut bytes = good.clone();
        for _ in 0..rng.random_range(1..4) {
            let k = rng.random_range(0..bytes.len());
            bytes[k] = rng.random();
        }
        if rng.random_range(0..4) == 0 {
            bytes.truncate(rng.random_range(0..bytes.len()));
        }
        changed += usize::from(bytes != good);
        if let Err(e) = parse_scene_ply(&bytes, "fuzz.ply") {
            assert_eq!(e.kind(), splat4d::ErrorKind::Input, "{e}");
            refused += 1;
        }
    }
    println!("PLY: 3000 mutated inputs, {changed} changed, {refused} refused");
    // Thresholds below the counts these seeds give: the mutated bytes reach the parser.
    assert!(
        changed >= PLY_CHANGED && refused >= PLY_REFUSED,
        "{changed} changed, {refused} refused"
    );
}

/// The least [`mutated_plys_never_panic`] accepts (measured: 2994 changed, 938 refused).
const PLY_CHANGED: usize = 2950;
const PLY_REFUSED: usize = 800;

#[test]
fn sh_rest_properties_for_degree_3_loaders() {
    let scene = scene();
    let dir = tempfile::tempdir().unwrap();
    let (plain, rest) = (dir.path().join("a.ply"), dir.path().join("b.ply"));
    write_slice_ply(&scene, 0.4, 1.0 / 255.0, false, &plain).unwrap();
    write_slice_ply(&scene, 0.4, 1.0 / 255.0, true, &rest).unwrap();
    let ((_, a), (names, b)) = (independent_read(&plain), independent_read(&rest));
    assert_eq!(names.len(), 17 + 45);
    assert_eq!(names[9], "f_rest_0");
    assert_eq!(names[53], "f_rest_44");
    assert_eq!(names[54], "opacity");
    for (x, y) in a.iter().zip(&b) {
        for name in SLICE_PROPERTIES {
            assert_eq!(value(x, name), value(y, name), "{name}");
        }
        assert_eq!(value(y, "f_rest_17"), 0.0);
    }
}

/// `export-ply --frames N` / `--times …`: one 3DGS PLY per time, each the same bytes as the
/// single-time export at that time and readable by an independent PLY parser, an index
/// `frames.json` with file and time, and a folder that is replaced only when it holds an
/// earlier sequence.
#[test]
fn export_ply_writes_a_sequence_with_an_index() {
    use crate::common::{splat4d, stderr};
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let scene = scene();
    splat4d::io::scene_file::save_scene(&scene, &d.join("s.json")).unwrap();
    let [t0, t1] = splat4d::scenes::paths::time_range(&scene);
    let output = splat4d(
        &[
            "export-ply",
            "--scene",
            "s.json",
            "--frames",
            "4",
            "--out",
            "seq",
        ],
        d,
    );
    assert!(output.status.success(), "{}", stderr(&output));
    let index: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("seq/frames.json")).unwrap()).unwrap();
    let frames = index["frames"].as_array().unwrap();
    assert_eq!(frames.len(), 4);
    for (k, frame) in frames.iter().enumerate() {
        let file = frame["file"].as_str().unwrap();
        assert_eq!(file, format!("frame_{k:04}.ply"));
        let tau = frame["time"].as_f64().unwrap();
        let expected = t0 + (t1 - t0) * k as f64 / 3.0;
        assert!(
            (tau - expected).abs() <= 1e-12 * (1.0 + expected.abs()),
            "{tau} {expected}"
        );
        let (names, rows) = independent_read(&d.join("seq").join(file));
        assert_eq!(names, SLICE_PROPERTIES);
        let single = d.join(format!("single_{k}.ply"));
        let tau_text = format!("{tau:?}");
        let output = splat4d(
            &[
                "export-ply",
                "--scene",
                "s.json",
                "--time",
                &tau_text,
                "--out",
                single.to_str().unwrap(),
            ],
            d,
        );
        assert!(output.status.success(), "{}", stderr(&output));
        assert_eq!(
            std::fs::read(d.join("seq").join(file)).unwrap(),
            std::fs::read(&single).unwrap(),
            "frame {k}"
        );
        assert!(!rows.is_empty());
    }
    // A re-run with other times replaces the earlier sequence whole.
    let output = splat4d(
        &[
            "export-ply",
            "--scene",
            "s.json",
            "--times",
            "0.25,0.75",
            "--out",
            "seq",
        ],
        d,
    );
    assert!(output.status.success(), "{}", stderr(&output));
    let mut names: Vec<String> = std::fs::read_dir(d.join("seq"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert_eq!(
        names,
        [
            ".splat4d-output",
            "frame_0000.ply",
            "frame_0001.ply",
            "frames.json"
        ]
    );
    // A folder holding anything else is never replaced.
    std::fs::write(d.join("seq/notes.txt"), "mine").unwrap();
    let output = splat4d(
        &[
            "export-ply",
            "--scene",
            "s.json",
            "--frames",
            "2",
            "--out",
            "seq",
        ],
        d,
    );
    assert_eq!(output.status.code(), Some(2), "{}", stderr(&output));
    assert!(stderr(&output).contains("notes.txt"), "{}", stderr(&output));
    assert!(d.join("seq/notes.txt").exists());
    for bad in [["--frames", "0"], ["--times", "nan"]] {
        let output = splat4d(
            &[
                "export-ply",
                "--scene",
                "s.json",
                bad[0],
                bad[1],
                "--out",
                "other",
            ],
            d,
        );
        assert_eq!(
            output.status.code(),
            Some(2),
            "{bad:?}: {}",
            stderr(&output)
        );
        assert!(!d.join("other").exists());
    }
}
