//! `docs/commands.md` is generated from the clap definitions: this test has clap parse
//! `splat4d help` and `splat4d help COMMAND` for every subcommand and takes the help it
//! renders (the text the executable prints), and compares it with the file. `SPLAT4D_BLESS=1 cargo test --release --bin splat4d commands_reference`
//! rewrites the file.

use clap::CommandFactory;

const PATH: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/docs/commands.md");

/// What `splat4d help ARGS…` prints: clap's own rendering of the help it was asked for.
fn help(args: &[&str]) -> String {
    let argv = ["splat4d", "help"].into_iter().chain(args.iter().copied());
    let error = super::Cli::command()
        .try_get_matches_from(argv)
        .expect_err("`help` ends parsing with the help text");
    assert_eq!(error.kind(), clap::error::ErrorKind::DisplayHelp);
    error.render().to_string().trim_end().to_string()
}

/// The whole of `docs/commands.md`.
fn reference() -> String {
    let mut command = super::Cli::command();
    command.build();
    let mut text = String::from(
        "# Commands\n\n\
         <!-- Generated from the clap definitions in src/cli/ by \
         `SPLAT4D_BLESS=1 cargo test --release --bin splat4d commands_reference`. \
         Do not edit: that test fails when this file and `splat4d help` differ. -->\n\n\
         Every subcommand and flag, exactly as `splat4d help COMMAND` prints them. What each \
         command does, with examples, is in [guide.md](guide.md) and [fitting.md](fitting.md); \
         the files they read and write in [formats.md](formats.md).\n\n",
    );
    let names: Vec<String> = command
        .get_subcommands()
        .filter(|sub| sub.get_name() != "help")
        .map(|sub| sub.get_name().to_string())
        .collect();
    text.push_str("| command | what |\n|---|---|\n");
    for sub in command
        .get_subcommands()
        .filter(|sub| sub.get_name() != "help")
    {
        let about = sub.get_about().map(|a| a.to_string()).unwrap_or_default();
        let anchor = format!("splat4d-{}", sub.get_name());
        text.push_str(&format!(
            "| [`{}`](#{anchor}) | {} |\n",
            sub.get_name(),
            about.replace('|', "\\|")
        ));
    }
    text.push_str("\n## `splat4d`\n\n```text\n");
    text.push_str(&help(&[]));
    text.push_str("\n```\n");
    for name in names {
        text.push_str(&format!("\n## `splat4d {name}`\n\n```text\n"));
        text.push_str(&help(&[&name]));
        text.push_str("\n```\n");
    }
    text
}

#[test]
fn commands_reference_matches_the_clap_definitions() {
    let expected = reference();
    if std::env::var_os("SPLAT4D_BLESS").is_some_and(|v| v == "1") {
        std::fs::write(PATH, &expected).expect("write docs/commands.md");
        return;
    }
    let actual = std::fs::read_to_string(PATH).unwrap_or_default();
    if actual == expected {
        return;
    }
    let (old, new): (Vec<&str>, Vec<&str>) = (actual.lines().collect(), expected.lines().collect());
    let first = old
        .iter()
        .zip(&new)
        .position(|(a, b)| a != b)
        .unwrap_or(old.len().min(new.len()));
    let mut message = format!(
        "docs/commands.md is stale: the flags in src/cli/ changed.\n\
         Regenerate it with: SPLAT4D_BLESS=1 cargo test --release --bin splat4d commands_reference\n\
         First difference at line {}:\n",
        first + 1
    );
    for line in old.iter().skip(first).take(6) {
        message.push_str(&format!("- {line}\n"));
    }
    for line in new.iter().skip(first).take(6) {
        message.push_str(&format!("+ {line}\n"));
    }
    panic!("{message}");
}
