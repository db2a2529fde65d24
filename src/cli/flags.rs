//! Library errors name a request's fields; the command line names its flags. A setting
//! error ([`splat4d::Error::Setting`]) names each field as `` `field` ``: where the user gave
//! the field's flag, the message shows the flag (`` `max_memory` `` → `--max-memory`);
//! elsewhere (a default, a value from a file) the field's name stays.

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

/// `error` with the fields of a setting error shown as the flags in `given`.
pub fn name_given_flags(error: Error, given: &[String]) -> Error {
    match error {
        Error::Setting { fields, message } => {
            let mut message = message;
            for field in &fields {
                let flag = flag_of(field);
                if given.contains(&flag) {
                    message = message.replace(&format!("`{field}`"), &flag);
                }
            }
            Error::Setting { fields, message }
        }
        other => other,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_given_flags_replace_their_fields() {
        let given =
            given_flags(["splat4d", "x", "--times=3", "--max-memory", "1G"].map(String::from));
        assert_eq!(given, ["--times", "--max-memory"]);
        let error = Error::setting(
            &["kernels", "times", "max_memory"],
            "`kernels` 5 × `times` 3 needs more than `max_memory`",
        );
        assert_eq!(
            name_given_flags(error, &given).to_string(),
            "`kernels` 5 × --times 3 needs more than --max-memory"
        );
    }
}
