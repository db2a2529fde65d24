//! The manual says what the executable does: `docs/commands.md` holds `splat4d help COMMAND`
//! for every command (the file itself is generated from the clap definitions by the binary's
//! unit test `commands_reference`), and `--version` names the package version.

use std::process::Command;

fn splat4d(args: &[&str]) -> String {
    let output = Command::new(env!("CARGO_BIN_EXE_splat4d"))
        .args(args)
        .output()
        .unwrap();
    assert!(output.status.success(), "splat4d {args:?} failed");
    String::from_utf8(output.stdout).unwrap()
}

#[test]
fn the_commands_reference_holds_splat4d_help_of_every_command() {
    let reference =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/docs/commands.md")).unwrap();
    let top = splat4d(&["help"]);
    let commands: Vec<&str> = top
        .lines()
        .skip_while(|line| !line.starts_with("Commands:"))
        .skip(1)
        .take_while(|line| !line.trim().is_empty())
        .filter_map(|line| line.split_whitespace().next())
        .filter(|name| *name != "help")
        .collect();
    assert!(
        commands.len() >= 11,
        "commands listed by `splat4d help`: {commands:?}"
    );
    assert!(
        reference.contains(top.trim_end()),
        "docs/commands.md lacks `splat4d help`; regenerate it (see its header)"
    );
    for command in commands {
        let help = splat4d(&["help", command]);
        assert!(
            reference.contains(&format!(
                "## `splat4d {command}`\n\n```text\n{}\n```",
                help.trim_end()
            )),
            "docs/commands.md does not hold `splat4d help {command}`; regenerate it with \
             SPLAT4D_BLESS=1 cargo test --release --bin splat4d commands_reference"
        );
    }
}

#[test]
fn version_names_the_package_version() {
    let version = splat4d(&["--version"]);
    let expected = format!("splat4d {}", env!("CARGO_PKG_VERSION"));
    assert!(
        version.starts_with(&expected),
        "`splat4d --version` printed {version:?}, expected it to start with {expected:?}"
    );
}

/// `docs/fitting.md`'s table of defaults quotes the numbers each blend's fit uses when no
/// flag is given (`FitSettings` with nothing chosen), to 5 significant digits.
#[test]
fn the_fitting_manuals_defaults_are_the_codes() {
    use splat4d::fit::settings::FitSettings;
    let manual =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/docs/fitting.md")).unwrap();
    let settings = FitSettings::default();
    let additive = settings.additive_plan("").unwrap();
    let alpha = settings.alpha_options("").unwrap();
    let (r, a) = (&additive.rates, &alpha.rates);
    let rounds = &additive.rounds;
    let code: Vec<(&str, Option<f64>, Option<f64>)> = vec![
        (
            "steps",
            Some(additive.steps as f64),
            Some(alpha.steps as f64),
        ),
        (
            "batch",
            Some(additive.batch_size as f64),
            Some(alpha.batch_size as f64),
        ),
        (
            "start_kernels",
            Some(additive.start_kernels as f64),
            Some(alpha.start_kernels as f64),
        ),
        (
            "max_kernels",
            Some(rounds.max_kernels as f64),
            Some(alpha.max_kernels as f64),
        ),
        (
            "eval_every",
            Some(additive.eval_every as f64),
            Some(alpha.eval_every as f64),
        ),
        ("lr_mean", Some(r.mean), Some(a.mean)),
        ("lr_time", Some(r.time), Some(a.time)),
        ("lr_velocity", Some(r.velocity), Some(a.velocity)),
        ("lr_scale", Some(r.scale), Some(a.scale)),
        ("lr_amplitude", Some(r.amplitude), Some(a.colour)),
        (
            "lr_final",
            Some(additive.final_rate_factor),
            Some(alpha.final_rate_factor),
        ),
        (
            "densify_every",
            Some(rounds.every as f64),
            Some(alpha.densify_every as f64),
        ),
        ("densify_from", Some(rounds.from), Some(alpha.densify_from)),
        (
            "densify_until",
            Some(rounds.until),
            Some(alpha.densify_until),
        ),
        (
            "densify_threshold",
            Some(rounds.gradient_threshold),
            Some(alpha.densify_threshold),
        ),
        (
            "max_growth",
            Some(rounds.max_growth),
            Some(alpha.densify_fraction),
        ),
        (
            "prune_below",
            Some(rounds.prune_below),
            Some(alpha.prune_opacity),
        ),
        ("min_improvement", Some(rounds.min_improvement), None),
        ("merge_tolerance", Some(rounds.merge_tolerance), None),
        ("lr_background", Some(r.background), None),
        ("sh", None, Some(alpha.sh_count as f64)),
        ("sh_raise_every", None, Some(alpha.sh_raise_every as f64)),
        ("lr_opacity", None, Some(a.opacity)),
        ("lr_rotation", None, Some(a.rotation)),
        ("lr_sh", None, Some(a.sh)),
        (
            "opacity_reset_every",
            None,
            Some(alpha.opacity_reset_every as f64),
        ),
        ("percent_dense", None, Some(alpha.percent_dense)),
        ("time_split_fraction", None, Some(alpha.time_split_fraction)),
        ("lr_acceleration", None, Some(a.acceleration)),
        ("lr_angular_velocity", None, Some(a.angular_velocity)),
        (
            "motion_after_splits",
            None,
            Some(f64::from(
                splat4d::fit::defaults::DEFAULT_MOTION_AFTER_SPLITS,
            )),
        ),
    ];
    let cell = |text: &str| -> Option<f64> {
        let first = text.split_whitespace().next()?;
        (first != "–").then(|| first.parse().unwrap_or_else(|_| panic!("`{text}`")))
    };
    for (name, additive, alpha) in code {
        let row = manual
            .lines()
            .find(|line| line.starts_with(&format!("| `{name}` |")))
            .unwrap_or_else(|| panic!("docs/fitting.md has no defaults row for `{name}`"));
        let cells: Vec<&str> = row.split('|').map(str::trim).collect();
        for (quoted, value, blend) in [(cells[2], additive, "additive"), (cells[3], alpha, "alpha")]
        {
            let quoted = cell(quoted);
            let same = match (quoted, value) {
                (Some(q), Some(v)) => (q - v).abs() <= 1e-5 * v.abs(),
                (None, None) => true,
                _ => false,
            };
            assert!(
                same,
                "`{name}` ({blend}): the manual says {quoted:?}, the code {value:?}"
            );
        }
    }
}

/// README reads as a map: at most 200 lines, no table cell over 400 characters.
#[test]
fn the_readme_is_short_and_its_cells_too() {
    let readme =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/README.md")).unwrap();
    assert!(
        readme.lines().count() <= 200,
        "{} lines",
        readme.lines().count()
    );
    for (n, line) in readme.lines().enumerate() {
        if line.starts_with('|') {
            for cell in line.split('|') {
                assert!(
                    cell.chars().count() <= 400,
                    "README.md line {}: a cell of {} characters",
                    n + 1,
                    cell.chars().count()
                );
            }
        }
    }
}
