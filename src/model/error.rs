//! The library's error type, by kind.
//!
//! Every message about user data names where the bad value came from (`origin`: a file
//! path, or a description such as `<scene>` for data built in code), the item (a kernel
//! index, a frame, ...) and the field, so that a user can find and fix it. Each error has
//! one [`ErrorKind`]; the command line maps kinds to exit codes in one place (`main.rs`).

use std::path::Path;

/// What went wrong, in the terms a caller acts on.
///
/// The binary maps kinds to exit statuses (input and usage 2, output 3, numeric 4).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ErrorKind {
    /// An input could not be read, is not well-formed, or holds an invalid value.
    Input,
    /// A request that cannot be carried out as asked (flags that contradict each other,
    /// an unsupported extension, sizes that do not match).
    Usage,
    /// An output could not be written.
    Output,
    /// A computation left the finite numbers: a fit diverged, a result is not finite.
    Numeric,
}

/// Errors of the splat4d library.
///
/// Every message names the file, the item and the field (`docs/reliability.md`).
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A file could not be read ([`ErrorKind::Input`]).
    #[error("{origin}: {message}: {source}")]
    Read {
        origin: String,
        message: String,
        #[source]
        source: std::io::Error,
    },
    /// A file is not well-formed: JSON syntax, wrong type, unknown field, bad image data
    /// ([`ErrorKind::Input`]).
    #[error("{origin}: {message}")]
    Malformed { origin: String, message: String },
    /// A value that parsed but is not valid: non-finite, out of range, degenerate
    /// ([`ErrorKind::Input`]).
    #[error("{origin}: {item}: field `{field}`: {message}")]
    Invalid {
        origin: String,
        item: String,
        field: String,
        message: String,
    },
    /// A request that cannot be carried out ([`ErrorKind::Usage`]).
    #[error("{0}")]
    Usage(String),
    /// A setting of a request that cannot be carried out ([`ErrorKind::Usage`]). The message
    /// names settings as `` `field` `` (the request's field names, listed in `fields`); the
    /// command line shows a field as its flag where the user gave that flag.
    #[error("{message}")]
    Setting {
        fields: Vec<&'static str>,
        message: String,
    },
    /// A file could not be written ([`ErrorKind::Output`]).
    #[error("{origin}: {message}: {source}")]
    Write {
        origin: String,
        message: String,
        #[source]
        source: std::io::Error,
    },
    /// A computation produced non-finite numbers ([`ErrorKind::Numeric`]).
    #[error("{0}")]
    Numeric(String),
}

/// The library's result type.
///
/// ```
/// fn kernels(path: &std::path::Path) -> splat4d::Result<usize> {
///     Ok(splat4d::io::scene_file::load_scene(path)?.len())
/// }
/// ```
pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    /// The kind of this error.
    #[must_use]
    pub fn kind(&self) -> ErrorKind {
        match self {
            Error::Read { .. } | Error::Malformed { .. } | Error::Invalid { .. } => {
                ErrorKind::Input
            }
            Error::Usage(_) | Error::Setting { .. } => ErrorKind::Usage,
            Error::Write { .. } => ErrorKind::Output,
            Error::Numeric(_) => ErrorKind::Numeric,
        }
    }

    /// Reading `path` failed.
    #[must_use]
    pub fn read(path: &Path, message: &str, source: std::io::Error) -> Self {
        Error::Read {
            origin: path.display().to_string(),
            message: message.to_owned(),
            source,
        }
    }

    /// Writing `path` failed. A full disk (or quota) says so in the message.
    #[must_use]
    pub fn write(path: &Path, message: &str, source: std::io::Error) -> Self {
        let full = matches!(
            source.kind(),
            std::io::ErrorKind::StorageFull | std::io::ErrorKind::QuotaExceeded
        ) || matches!(source.raw_os_error(), Some(28 | 122));
        Error::Write {
            origin: path.display().to_string(),
            message: if full {
                format!("{message} (disk full)")
            } else {
                message.to_owned()
            },
            source,
        }
    }

    /// A value that is present but invalid.
    #[must_use]
    pub fn invalid(
        origin: &str,
        item: impl Into<String>,
        field: &str,
        message: impl Into<String>,
    ) -> Self {
        Error::Invalid {
            origin: origin.to_owned(),
            item: item.into(),
            field: field.to_owned(),
            message: cut(&message.into(), MAX_QUOTE),
        }
    }

    /// A file that is not well-formed.
    #[must_use]
    pub fn malformed(origin: &str, message: impl Into<String>) -> Self {
        Error::Malformed {
            origin: origin.to_owned(),
            message: cut(&message.into(), MAX_QUOTE),
        }
    }

    /// A setting that cannot be carried out: `message` names each of `fields` as
    /// `` `field` ``.
    #[must_use]
    pub fn setting(fields: &[&'static str], message: impl Into<String>) -> Self {
        Error::Setting {
            fields: fields.to_vec(),
            message: cut(&message.into(), 3 * MAX_QUOTE),
        }
    }

    /// A request that cannot be carried out.
    #[must_use]
    pub fn usage(message: impl Into<String>) -> Self {
        Error::Usage(cut(&message.into(), 3 * MAX_QUOTE))
    }
}

/// Most characters of a value quoted in a message (a 10 MB string in a file does not come
/// back whole).
pub const MAX_QUOTE: usize = 300;

/// `text` cut to `limit` characters, with an ellipsis and the full length.
#[must_use]
pub fn cut(text: &str, limit: usize) -> String {
    match text.char_indices().nth(limit) {
        Some((end, _)) => format!(
            "{}… ({} characters in all)",
            &text[..end],
            text.chars().count()
        ),
        None => text.to_owned(),
    }
}

/// Error naming the setting `field` unless `value` is finite and ≥ 0.
pub fn check_non_negative_setting(field: &'static str, value: f64) -> Result<()> {
    if value.is_finite() && value >= 0.0 {
        return Ok(());
    }
    Err(Error::setting(
        &[field],
        format!("`{field}` {value} must be finite and ≥ 0"),
    ))
}

/// Error naming `field` of `item` unless every value is finite.
pub fn check_finite(origin: &str, item: &str, field: &str, values: &[f64]) -> Result<()> {
    match values.iter().position(|v| !v.is_finite()) {
        None => Ok(()),
        Some(c) => Err(Error::invalid(
            origin,
            item,
            field,
            format!("{field}[{c}] = {} is not finite", values[c]),
        )),
    }
}
