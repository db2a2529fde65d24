//! Library errors name a request's fields; the command line names its flags. Messages
//! name settings as `` `field` `` (underscores where the flag has dashes):
//!
//! - a field a setting error blames ([`splat4d::Error::Setting`]'s `fields`) shows as its
//!   flag only where the user gave that flag (`` `max_memory` `` → `--max-memory`);
//!   elsewhere (a default, a value from a file) the field's name stays, so a message never
//!   blames a flag that was not given;
//! - any other `` `field` `` that is a flag of the command run is advice (`` `lr_mean` ``
//!   in "lower its rate, `lr_mean`") and shows as the flag.

use splat4d::Error;

/// The flag a request field is given by.
fn flag_of(field: &str) -> String {
    format!("--{}", field.replace('_', "-"))
}

/// The flags on a command line (`--name` and `--name=value` both give `--name`).
pub fn given_flags(args: impl IntoIterator<Item = String>) -> Vec<String> {
    args.into_iter()
        .take_while(|a| a != "--")
        .filter(|a| a.starts_with("--"))
        .map(|a| a.split('=').next().unwrap_or_default().to_owned())
        .collect()
}

/// The long flags of the subcommand named first in `args` (all of the top level's when
/// none matches), from the clap definitions.
pub fn command_flags(args: &[String]) -> Vec<String> {
    let command = <crate::cli::Cli as clap::CommandFactory>::command();
    let sub = args
        .iter()
        .skip(1)
        .find_map(|a| command.find_subcommand(a).cloned());
    let mut command = sub.unwrap_or(command);
    // A subcommand's flags are defined when it is first used (`defer`): define this one's
    // (on its own, so without the flags the top level passes down, as before `defer`).
    command.build();
    command
        .get_arguments()
        .filter_map(|arg| arg.get_long().map(|long| format!("--{long}")))
        .collect()
}

/// `error` with its settings shown as flags: blamed fields where `given` has their flag,
/// other fields that are flags of the command (`known`) as advice.
pub fn name_flags(error: Error, given: &[String], known: &[String]) -> Error {
    let shown = |message: String, blamed: &[&str]| {
        name_fields(&message, |field| {
            let flag = flag_of(field);
            let is_blamed = blamed.contains(&field);
            ((is_blamed && given.contains(&flag)) || (!is_blamed && known.contains(&flag)))
                .then_some(flag)
        })
    };
    match error {
        Error::Setting { fields, message } => {
            let message = shown(message, &fields);
            Error::Setting { fields, message }
        }
        Error::Usage(message) => Error::Usage(shown(message, &[])),
        Error::Numeric(message) => Error::Numeric(shown(message, &[])),
        Error::Invalid {
            origin,
            item,
            field,
            message,
        } => Error::Invalid {
            origin,
            item,
            field,
            message: shown(message, &[]),
        },
        other => other,
    }
}

/// A note of the library with the fields it mentions that are flags of the command run
/// (this process's arguments) shown as those flags.
pub fn name_advice(text: &str) -> String {
    let args: Vec<String> = std::env::args().collect();
    let known = command_flags(&args);
    name_fields(text, |field| {
        let flag = flag_of(field);
        known.contains(&flag).then_some(flag)
    })
}

/// `message` with each `` `word` `` that `flag` maps replaced by its flag.
fn name_fields(message: &str, flag: impl Fn(&str) -> Option<String>) -> String {
    let mut out = String::with_capacity(message.len());
    let mut rest = message;
    while let Some(open) = rest.find('`') {
        out.push_str(&rest[..open]);
        let after = &rest[open + 1..];
        let Some(close) = after.find('`') else {
            rest = &rest[open..];
            break;
        };
        let word = &after[..close];
        let is_field = !word.is_empty()
            && word
                .chars()
                .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_');
        match is_field.then(|| flag(word)).flatten() {
            Some(flag) => out.push_str(&flag),
            None => {
                out.push('`');
                out.push_str(word);
                out.push('`');
            }
        }
        rest = &after[close + 1..];
    }
    out.push_str(rest);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_given_flags_replace_their_fields() {
        let given =
            given_flags(["splat4d", "x", "--times=3", "--max-memory", "1G"].map(String::from));
        assert_eq!(given, ["--times", "--max-memory"]);
        let known = ["--times", "--max-memory", "--kernels"].map(String::from);
        let error = Error::setting(
            &["kernels", "times", "max_memory"],
            "`kernels` 5 × `times` 3 needs more than `max_memory`",
        );
        assert_eq!(
            name_flags(error, &given, &known).to_string(),
            "`kernels` 5 × --times 3 needs more than --max-memory"
        );
    }

    #[test]
    fn advice_names_the_commands_flags_and_leaves_other_words() {
        let known = ["--lr-mean", "--box"].map(String::from);
        let error = Error::Numeric(
            "kernel 3's mean is no longer finite (its rate: `lr_mean`); the `time` field, `box`, `a`b"
                .into(),
        );
        assert_eq!(
            name_flags(error, &[], &known).to_string(),
            "kernel 3's mean is no longer finite (its rate: --lr-mean); the `time` field, --box, `a`b"
        );
    }

    #[test]
    fn the_fit_commands_flags_come_from_its_definition() {
        let flags = command_flags(&["splat4d".into(), "fit".into()]);
        assert!(flags.contains(&"--lr-mean".to_string()), "{flags:?}");
        assert!(flags.contains(&"--box".to_string()), "{flags:?}");
    }
}
