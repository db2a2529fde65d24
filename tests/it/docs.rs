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
