//! A flag that cannot act is refused, never ignored: for every command besides `fit`
//! (`fit_flags`), each flag given where it has no effect exits 2 naming it and why, run
//! through the binary. Each refusal is a combination that earlier wrote the same bytes with
//! the flag as without it.

use std::path::Path;

use crate::common::{data, run_limited};

/// Runs `args` in `dir` and asserts exit 2, a message holding each of `needles`, no panic
/// and no field name left unmapped for a flag given (`` `field` ``).
fn refused(dir: &Path, args: &[&str], needles: &[&str]) {
    let output = run_limited(args, dir);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(2), "{args:?}: {stderr}");
    for needle in needles {
        assert!(
            stderr.contains(needle),
            "{args:?}: {needle:?} not in {stderr}"
        );
    }
    assert!(!stderr.contains("panicked"), "{args:?}: {stderr}");
    for flag in args.iter().filter_map(|a| a.strip_prefix("--")) {
        let field = format!("`{}`", flag.replace('-', "_"));
        assert!(!stderr.contains(&field), "{args:?}: {field} in {stderr}");
    }
}

/// Runs `args` in `dir` and asserts success.
fn ok(dir: &Path, args: &[&str]) {
    let output = run_limited(args, dir);
    assert!(
        output.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&output.stderr)
    );
}

/// The blob scene and its camera in `dir` (`blob.json`, `camera.json`).
fn blob_in(dir: &Path) {
    std::fs::copy(data("blob.json"), dir.join("blob.json")).unwrap();
    std::fs::copy(data("blob_camera.json"), dir.join("camera.json")).unwrap();
}

const VIEW: [&str; 7] = [
    "--scene",
    "blob.json",
    "--camera",
    "camera.json",
    "--time",
    "0.3",
    "--threads",
];

fn with_view<'a>(command: &'a str, extra: &[&'a str]) -> Vec<&'a str> {
    let mut args = vec![command];
    args.extend(VIEW);
    args.push("1");
    args.extend(extra);
    args
}

#[test]
fn render_and_grad_refuse_size_with_a_camera_file() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    blob_in(d);
    let why = [
        "--size sizes a glTF model's camera (--camera-from)",
        "gives its own size",
    ];
    refused(
        d,
        &with_view("render", &["--size", "20x20", "--out", "r.png"]),
        &why,
    );
    ok(d, &with_view("render", &["--out", "r.png"]));
    ok(d, &with_view("render", &["--out", "r.exr"]));
    refused(
        d,
        &with_view(
            "grad",
            &["--size", "9x9", "--target", "r.exr", "--out", "g.json"],
        ),
        &why,
    );
}

#[test]
fn render_refuses_bit_depth_where_no_png_bits_are_chosen() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    blob_in(d);
    refused(
        d,
        &with_view("render", &["--bit-depth", "16", "--out", "r.exr"]),
        &[
            "r.exr: --bit-depth sets a PNG's bits per channel",
            "an EXR holds float32",
        ],
    );
    refused(
        d,
        &with_view(
            "render",
            &["--bit-depth", "8", "--overlay", "--out", "o.png"],
        ),
        &[
            "--bit-depth sets a PNG's bits per channel",
            "--overlay draws an 8-bit PNG",
        ],
    );
    assert!(!d.join("r.exr").exists() && !d.join("o.png").exists());
    ok(
        d,
        &with_view("render", &["--bit-depth", "16", "--out", "r.png"]),
    );
}

#[test]
fn toy_refuses_a_seed_for_a_scene_without_noise() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for kind in ["blob", "three-blobs"] {
        refused(
            d,
            &["toy", "--kind", kind, "--seed", "5", "--out", "t.json"],
            &[
                "--seed draws the points scene's noise",
                &format!("the {kind} scene has none"),
            ],
        );
    }
    // The points take it.
    ok(d, &["toy", "--kind", "points", "--out", "a.json"]);
    ok(
        d,
        &["toy", "--kind", "points", "--seed", "5", "--out", "b.json"],
    );
    assert_ne!(
        std::fs::read(d.join("a.json")).unwrap(),
        std::fs::read(d.join("b.json")).unwrap()
    );
}

#[test]
fn import_gltf_refuses_a_tolerance_with_a_count_of_times() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/gltf/BoxAnimated.gltf");
    let model = model.to_str().unwrap();
    let args = [
        "import-gltf",
        model,
        "--kernels",
        "10",
        "--out",
        "i.json",
        "--tolerance",
        "0.5",
    ];
    refused(
        d,
        &[&args[..], &["--times", "3"]].concat(),
        &[
            "--tolerance bounds the path error of --times auto",
            "--times is 3",
        ],
    );
    ok(d, &[&args[..], &["--times", "auto"]].concat());
}

#[test]
fn export_ply_refuses_sh_rest_for_a_scene_of_degree_3() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let sh: Vec<[f64; 3]> = (0..15).map(|j| [0.01 * f64::from(j), 0.0, 0.0]).collect();
    let scene = serde_json::json!({"blend": "alpha", "kernels": [{"mean": [0, 0, 0, 0.5],
        "scale": [0.3, 0.3, 0.3, 5], "amplitude": [0.5, 0.5, 0.5], "opacity": 0.9, "sh": sh}]});
    std::fs::write(d.join("sh3.json"), scene.to_string()).unwrap();
    let why = [
        "--sh-rest pads the `f_rest_*` properties to degree 3",
        "degree 3 already",
    ];
    for (times, out) in [(["--time", "0.5"], "e.ply"), (["--times", "0.4,0.6"], "e")] {
        let args = [
            "export-ply",
            "--scene",
            "sh3.json",
            "--sh-rest",
            "--out",
            out,
        ];
        refused(d, &[&args[..], &times].concat(), &why);
        assert!(!d.join(out).exists());
    }
    blob_in(d);
    ok(
        d,
        &[
            "export-ply",
            "--scene",
            "blob.json",
            "--time",
            "0.5",
            "--sh-rest",
            "--out",
            "b.ply",
        ],
    );
}

/// `video` of the blob without GIF and MP4, into `v`, with `extra`.
fn video<'a>(extra: &[&'a str]) -> Vec<&'a str> {
    let mut args = vec![
        "video",
        "--scene",
        "blob.json",
        "--no-gif",
        "--no-mp4",
        "--out",
        "v",
    ];
    args.extend(extra);
    args
}

/// The blob, its camera, and a path file of two timed frames through it (`path.json`).
fn video_inputs(dir: &Path) {
    blob_in(dir);
    let camera: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(data("blob_camera.json")).unwrap()).unwrap();
    let path =
        serde_json::json!([{"camera": camera, "time": 0.2}, {"camera": camera, "time": 0.8}]);
    std::fs::write(dir.join("path.json"), path.to_string()).unwrap();
}

#[test]
fn video_refuses_times_without_an_orbit() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    video_inputs(d);
    let why = [
        "--times are the orbits' times, and no orbit is asked",
        "add --orbit",
    ];
    refused(d, &video(&["--path", "path.json", "--times", "0.1"]), &why);
    refused(
        d,
        &video(&["--spiral=0.5,0.5,0.5,3,20,3", "--times", "0.1"]),
        &why,
    );
    assert!(!d.join("v").exists());
    ok(
        d,
        &video(&[
            "--orbit=0.5,0.5,0.5,3,20,2",
            "--times",
            "0.1",
            "--path",
            "path.json",
        ]),
    );
}

#[test]
fn video_refuses_the_circles_settings_with_only_a_path() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    video_inputs(d);
    for (flag, value) in [("--up", "z"), ("--size", "32x32"), ("--fov", "60")] {
        refused(
            d,
            &video(&["--path", "path.json", flag, value]),
            &[&format!(
                "{flag} shapes the orbits and spirals, and only a --path is asked"
            )],
        );
        ok(
            d,
            &video(&[
                "--spiral=0.5,0.5,0.5,3,20,2",
                "--path",
                "path.json",
                flag,
                value,
            ]),
        );
    }
}

#[test]
fn video_refuses_a_time_range_nothing_sweeps() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    video_inputs(d);
    let why = [
        "--time-range spans the spiral, the orbits' default --times",
        "has none of them",
    ];
    refused(
        d,
        &video(&["--path", "path.json", "--time-range", "0,5"]),
        &why,
    );
    refused(
        d,
        &video(&[
            "--orbit=0.5,0.5,0.5,3,20,2",
            "--times",
            "0.3",
            "--time-range",
            "0,5",
        ]),
        &why,
    );
    // It spans the orbits' default times.
    ok(
        d,
        &video(&["--orbit=0.5,0.5,0.5,3,20,2", "--time-range", "0,5"]),
    );
}

/// `bench` with `extra`.
fn bench<'a>(extra: &[&'a str]) -> Vec<&'a str> {
    let mut args = vec!["bench"];
    args.extend(extra);
    args
}

#[test]
fn bench_ceiling_refuses_every_flag_but_threads() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    blob_in(d);
    for extra in [
        &["--scene", "300"][..],
        &["--camera", "camera.json"],
        &["--size", "8x8"],
        &["--frames", "1"],
        &["--samples", "10"],
        &["--time", "0.2"],
        &["--dilation", "0.1"],
        &["--cutoff", "0.01"],
        &["--exp", "std"],
        &["--dense"],
        &["--no-dense"],
        &["--sweep"],
        &["--out", "o"],
        &["--blend", "alpha"],
    ] {
        let why = format!(
            "{} has no effect with --ceiling, which runs only the ceiling probes",
            extra[0]
        );
        refused(
            d,
            &bench(&[&["--ceiling", "--threads", "1"][..], extra].concat()),
            &[&why],
        );
    }
}

#[test]
fn bench_sweep_refuses_what_it_does_not_measure() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    blob_in(d);
    let sweep = ["--sweep", "--threads", "1", "--scene", "300"];
    refused(
        d,
        &bench(&[&sweep[..], &["--scene", "400"]].concat()),
        &["--scene names 2 scenes, and --sweep measures one"],
    );
    for flag in ["--dense", "--no-dense"] {
        refused(
            d,
            &bench(&[&sweep[..], &[flag]].concat()),
            &[&format!(
                "{flag} chooses whether the dense baseline runs, and --sweep never times it"
            )],
        );
    }
    for (flag, value) in [
        ("--dilation", "0.1"),
        ("--exp", "std"),
        ("--cutoff", "0.01"),
    ] {
        refused(
            d,
            &bench(&[&sweep[..], &[flag, value]].concat()),
            &[&format!(
                "{flag} has no effect with --sweep, which measures its own grid"
            )],
        );
    }
    // Through a camera the cut-off frames nothing; without one it frames the scene file.
    let file_sweep = [
        "--sweep",
        "--threads",
        "1",
        "--scene",
        "blob.json",
        "--cutoff",
        "0.01",
    ];
    refused(
        d,
        &bench(&[&file_sweep[..], &["--camera", "camera.json"]].concat()),
        &["--cutoff has no effect with --sweep"],
    );
    assert!(!d.join("out").exists());
    ok(
        d,
        &bench(
            &[
                &file_sweep[..],
                &[
                    "--size",
                    "16x16",
                    "--frames",
                    "1",
                    "--samples",
                    "10",
                    "--out",
                    "s",
                ],
            ]
            .concat(),
        ),
    );
    assert!(d.join("s/sweep.md").exists());
}

#[test]
fn bench_refuses_out_without_sweep() {
    let dir = tempfile::tempdir().unwrap();
    refused(
        dir.path(),
        &bench(&["--scene", "300", "--out", "o"]),
        &[
            "--out is where --sweep writes its table and chart",
            "add --sweep",
        ],
    );
}

#[test]
fn bench_refuses_scene_file_settings_with_only_built_in_scenes_and_back() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    blob_in(d);
    refused(
        d,
        &bench(&["--scene", "300", "--camera", "camera.json"]),
        &["--camera frames scene files, and every --scene here is a built-in one"],
    );
    refused(
        d,
        &bench(&[
            "--scene",
            "blob.json",
            "--camera",
            "camera.json",
            "--size",
            "8x8",
        ]),
        &["--size sizes the built-in scenes and scene files without --camera"],
    );
    refused(
        d,
        &bench(&["--scene", "blob.json", "--blend", "alpha"]),
        &["--blend is the built-in scenes' blend, and every --scene here is a file"],
    );
    // Beside a built-in scene, each acts on its own kind.
    ok(
        d,
        &bench(&[
            "--scene",
            "300",
            "--scene",
            "blob.json",
            "--camera",
            "camera.json",
            "--size",
            "16x16",
            "--blend",
            "alpha",
            "--frames",
            "1",
            "--samples",
            "10",
            "--threads",
            "1",
        ]),
    );
}

#[test]
fn bench_refuses_the_dense_baselines_settings_with_only_alpha_scenes() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for flag in ["--dense", "--no-dense"] {
        refused(
            d,
            &bench(&[
                "--scene",
                "300",
                "--blend",
                "alpha",
                "--frames",
                "1",
                "--threads",
                "1",
                flag,
            ]),
            &[
                &format!("{flag} chooses whether the additive sum's dense baseline runs"),
                "every scene here is alpha",
            ],
        );
    }
}
