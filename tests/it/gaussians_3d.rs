//! 3DGS files both ways (SPEC §8): a graphdeco PLY written here by an independent writer
//! reads as static alpha kernels and renders; splat4d's export of an alpha scene, read by an
//! independent parser and drawn by a minimal 3DGS compositor written here (graphdeco's
//! rules: EWA with the 0.3 px² dilation, a 3σ radius per splat, depth order, α < 1/255
//! skipped, stop below T = 1e-4), matches splat4d's own render.

use ply_rs_bw::parser::Parser;
use ply_rs_bw::ply::{DefaultElement, Property};
use rand::RngExt;
use splat4d::model::random::{random_rotation, seeded_rng};
use splat4d::{Blend, Camera, Kernel, RenderOptions, Scene};

const C0: f64 = 0.282_094_791_773_878_14;

/// A graphdeco-layout PLY: `x y z nx ny nz f_dc_0..2 f_rest_0..44 opacity scale_0..2
/// rot_0..3`, float, written byte by byte.
fn write_graphdeco_ply(path: &std::path::Path, rows: &[Vec<f32>], rest: usize) {
    let mut names: Vec<String> = [
        "x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2",
    ]
    .iter()
    .map(|s| (*s).to_owned())
    .collect();
    names.extend((0..rest).map(|k| format!("f_rest_{k}")));
    names.extend(
        [
            "opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3",
        ]
        .iter()
        .map(|s| (*s).to_owned()),
    );
    let mut bytes = format!(
        "ply\nformat binary_little_endian 1.0\nelement vertex {}\n",
        rows.len()
    )
    .into_bytes();
    for name in &names {
        bytes.extend(format!("property float {name}\n").as_bytes());
    }
    bytes.extend(b"end_header\n");
    for row in rows {
        assert_eq!(row.len(), names.len());
        for v in row {
            bytes.extend(v.to_le_bytes());
        }
    }
    std::fs::write(path, bytes).unwrap();
}

#[test]
fn a_graphdeco_ply_reads_as_static_alpha_kernels_and_renders() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("point_cloud.ply");
    let mut rng = seeded_rng(3);
    let rows: Vec<Vec<f32>> = (0..50)
        .map(|_| {
            let mut row = vec![
                rng.random_range(-0.5..0.5),
                rng.random_range(-0.5..0.5),
                rng.random_range(-0.5..0.5),
                0.0,
                0.0,
                0.0,
            ];
            row.extend((0..3).map(|_| rng.random_range(-1.0..1.0)));
            row.extend((0..45).map(|_| rng.random_range(-0.2..0.2)));
            row.push(rng.random_range(-2.0..3.0));
            row.extend((0..3).map(|_| rng.random_range(-3.0..-1.5)));
            row.extend([1.5, 0.1, -0.2, 0.3]);
            row
        })
        .collect();
    write_graphdeco_ply(&path, &rows, 45);
    let scene = splat4d::io::scene_file::load_scene(&path).unwrap();
    assert_eq!(scene.blend, Blend::Alpha);
    assert_eq!((scene.len(), scene.sh_count), (50, 15));
    let row = &rows[7];
    let f = |k: usize| f64::from(row[k]);
    assert_eq!(scene.means[7], [f(0), f(1), f(2), 0.0]);
    assert!(scene.scales[7][3] >= 1e15, "static in time");
    assert!((scene.scales[7][0] - f(55).exp()).abs() < 1e-12);
    assert!((scene.opacities[7] - 1.0 / (1.0 + (-f(54)).exp())).abs() < 1e-12);
    assert!((scene.amplitudes[7][1] - (C0 * f(7) + 0.5)).abs() < 1e-12);
    // f_rest is channel by channel: triplet 2's green is f_rest_{15 + 2}.
    assert_eq!(scene.sh_of(7)[2][1], f(9 + 17));
    let norm = (1.5_f64 * 1.5 + 0.01 + 0.04 + 0.09).sqrt();
    assert!((scene.rotations[7][0] - 1.5 / norm).abs() < 1e-7);
    let camera =
        Camera::look_at([0.0, 0.0, -3.0], [0.0; 3], [0.0, 1.0, 0.0], 40.0, 40, 30).unwrap();
    let image = splat4d::render(&scene, &camera, 12.0, &RenderOptions::default()).unwrap();
    assert!(
        image.pixels.iter().any(|&v| v > 0.05),
        "the splats are drawn"
    );
    // Without f_rest too.
    let plain: Vec<Vec<f32>> = rows
        .iter()
        .map(|r| r[..9].iter().chain(&r[54..]).copied().collect())
        .collect();
    write_graphdeco_ply(&path, &plain, 0);
    let scene = splat4d::io::scene_file::load_scene(&path).unwrap();
    assert_eq!((scene.blend, scene.sh_count), (Blend::Alpha, 0));
}

/// The splats of a 3DGS PLY, read by an independent parser.
struct Splat {
    position: [f64; 3],
    colour: [f64; 3],
    opacity: f64,
    covariance: [[f64; 3]; 3],
}

fn read_splats(path: &std::path::Path) -> Vec<Splat> {
    let mut file = std::fs::File::open(path).unwrap();
    let ply = Parser::<DefaultElement>::new().read_ply(&mut file).unwrap();
    let value = |e: &DefaultElement, name: &str| match e[name] {
        Property::Float(v) => f64::from(v),
        ref other => panic!("{name}: {other:?}"),
    };
    ply.payload["vertex"]
        .iter()
        .map(|e| {
            let [w, x, y, z] = ["rot_0", "rot_1", "rot_2", "rot_3"].map(|n| value(e, n));
            let n = (w * w + x * x + y * y + z * z).sqrt();
            let (w, x, y, z) = (w / n, x / n, y / n, z / n);
            let r = [
                [
                    1.0 - 2.0 * (y * y + z * z),
                    2.0 * (x * y - w * z),
                    2.0 * (x * z + w * y),
                ],
                [
                    2.0 * (x * y + w * z),
                    1.0 - 2.0 * (x * x + z * z),
                    2.0 * (y * z - w * x),
                ],
                [
                    2.0 * (x * z - w * y),
                    2.0 * (y * z + w * x),
                    1.0 - 2.0 * (x * x + y * y),
                ],
            ];
            let s = ["scale_0", "scale_1", "scale_2"].map(|n| (2.0 * value(e, n)).exp());
            let covariance = std::array::from_fn(|a| {
                std::array::from_fn(|b| (0..3).map(|k| r[a][k] * s[k] * r[b][k]).sum())
            });
            Splat {
                position: ["x", "y", "z"].map(|n| value(e, n)),
                // Degree 0 only (the scene below has no SH): C0 f_dc + 0.5, clamped at 0.
                colour: ["f_dc_0", "f_dc_1", "f_dc_2"].map(|n| (C0 * value(e, n) + 0.5).max(0.0)),
                opacity: 1.0 / (1.0 + (-value(e, "opacity")).exp()),
                covariance,
            }
        })
        .collect()
}

/// A minimal 3DGS compositor: graphdeco's per-splat and per-pixel rules on this camera.
fn composite_3dgs(splats: &[Splat], camera: &Camera, background: [f64; 3]) -> Vec<f64> {
    let rc = camera.rotation();
    let tc = camera.translation();
    struct Screen {
        depth: f64,
        mean: [f64; 2],
        conic: [f64; 3],
        radius: f64,
        colour: [f64; 3],
        opacity: f64,
    }
    let mut screen: Vec<Screen> = splats
        .iter()
        .filter_map(|splat| {
            let p: [f64; 3] = std::array::from_fn(|r| {
                (0..3).map(|k| rc[r][k] * splat.position[k]).sum::<f64>() + tc[r]
            });
            if p[2] < 0.2 {
                return None;
            }
            let (w, h) = (f64::from(camera.width), f64::from(camera.height));
            let limx = 1.3 * 0.5 * w / camera.fx;
            let limy = 1.3 * 0.5 * h / camera.fy;
            let tx = p[2] * (p[0] / p[2]).clamp(-limx, limx);
            let ty = p[2] * (p[1] / p[2]).clamp(-limy, limy);
            let z = p[2];
            let j = [
                [camera.fx / z, 0.0, -camera.fx * tx / (z * z)],
                [0.0, camera.fy / z, -camera.fy * ty / (z * z)],
            ];
            let t: [[f64; 3]; 2] = std::array::from_fn(|a| {
                std::array::from_fn(|b| (0..3).map(|k| j[a][k] * rc[k][b]).sum())
            });
            let cov = |a: usize, b: usize| {
                (0..3)
                    .map(|k| {
                        (0..3)
                            .map(|l| t[a][k] * splat.covariance[k][l] * t[b][l])
                            .sum::<f64>()
                    })
                    .sum::<f64>()
            };
            let (a, b, c) = (cov(0, 0) + 0.3, cov(0, 1), cov(1, 1) + 0.3);
            let det = a * c - b * b;
            if det <= 0.0 {
                return None;
            }
            let mid = 0.5 * (a + c);
            let lambda = mid + (mid * mid - det).max(0.1).sqrt();
            Some(Screen {
                depth: z,
                mean: [
                    camera.fx * p[0] / z + camera.cx,
                    camera.fy * p[1] / z + camera.cy,
                ],
                conic: [c / det, -b / det, a / det],
                radius: (3.0 * lambda.sqrt()).ceil(),
                colour: splat.colour,
                opacity: splat.opacity,
            })
        })
        .collect();
    screen.sort_by(|a, b| a.depth.total_cmp(&b.depth));
    let mut pixels = Vec::new();
    for j in 0..camera.height {
        for i in 0..camera.width {
            let (x, y) = (f64::from(i) + 0.5, f64::from(j) + 0.5);
            let (mut colour, mut transmittance) = ([0.0; 3], 1.0);
            for s in &screen {
                let (dx, dy) = (s.mean[0] - x, s.mean[1] - y);
                if dx.abs() > s.radius || dy.abs() > s.radius {
                    continue;
                }
                let power =
                    -0.5 * (s.conic[0] * dx * dx + s.conic[2] * dy * dy) - s.conic[1] * dx * dy;
                if power > 0.0 {
                    continue;
                }
                let alpha = (s.opacity * power.exp()).min(0.99);
                if alpha < 1.0 / 255.0 {
                    continue;
                }
                let next = transmittance * (1.0 - alpha);
                if next < 1e-4 {
                    break;
                }
                for (sum, c) in colour.iter_mut().zip(s.colour) {
                    *sum += c * alpha * transmittance;
                }
                transmittance = next;
            }
            for c in 0..3 {
                pixels.push(colour[c] + transmittance * background[c]);
            }
        }
    }
    pixels
}

/// The PSNR a 3DGS rasterizer's drawing of splat4d's export reaches against splat4d's own
/// render of the dense alpha scene below (the 3σ square per splat is the only difference):
/// measured 72.6 dB.
const EXPORT_PSNR: f64 = 60.0;

#[test]
fn an_exported_alpha_scene_draws_in_a_3dgs_compositor_as_splat4d_draws_it() {
    let mut rng = seeded_rng(8);
    let kernels: Vec<Kernel> = (0..3000)
        .map(|_| {
            let mut k = Kernel::new(
                [
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-0.8..0.8),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(0.0..1.0),
                ],
                [
                    rng.random_range(0.02..0.12),
                    rng.random_range(0.02..0.12),
                    rng.random_range(0.02..0.12),
                    rng.random_range(0.3..2.0),
                ],
                std::array::from_fn(|_| rng.random_range(0.0..1.0)),
            );
            k.rotation = random_rotation(&mut rng);
            k.velocity = std::array::from_fn(|_| rng.random_range(-0.3..0.3));
            k
        })
        .collect();
    let opacities = (0..kernels.len())
        .map(|_| rng.random_range(0.05..1.0))
        .collect();
    let scene = Scene::from_kernels(&kernels, [0.0; 3], "<dense>")
        .unwrap()
        .into_alpha(opacities, 0, Vec::new(), "<dense>")
        .unwrap();
    let camera =
        Camera::look_at([0.5, 0.4, -3.5], [0.0; 3], [0.0, 1.0, 0.0], 45.0, 96, 72).unwrap();
    let tau = 0.4;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("slice.ply");
    splat4d::io::ply::write_slice_ply(&scene, tau, 1.0 / 255.0, false, &path).unwrap();
    let drawn = composite_3dgs(&read_splats(&path), &camera, scene.background);
    let ours = splat4d::render(&scene, &camera, tau, &RenderOptions::default()).unwrap();
    let mse = drawn
        .iter()
        .zip(&ours.pixels)
        .map(|(a, &b)| (a - f64::from(b)).powi(2))
        .sum::<f64>()
        / drawn.len() as f64;
    let psnr = 10.0 * (1.0 / mse).log10();
    eprintln!("3DGS compositor vs splat4d on the export: {psnr:.1} dB");
    assert!(psnr >= EXPORT_PSNR, "{psnr:.1} dB");
}
