//! The library's error type.
//!
//! Every message about user data names where the bad value came from (`origin`: a file
//! path, or a description such as `<scene>` for data built in code), the item (a kernel
//! index, a frame, ...) and the field, so that a user can find and fix it.

use std::path::Path;

/// Errors of the splat4d library.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A file could not be read or written.
    #[error("{origin}: {message}: {source}")]
    Io {
        origin: String,
        message: String,
        #[source]
        source: std::io::Error,
    },
    /// A file is not well-formed (JSON syntax, wrong type, unknown field, bad image data).
    #[error("{origin}: {message}")]
    Malformed { origin: String, message: String },
    /// A value that parsed but is not valid (non-finite, out of range, degenerate).
    #[error("{origin}: {item}: field `{field}`: {message}")]
    Invalid {
        origin: String,
        item: String,
        field: String,
        message: String,
    },
    /// A request that cannot be carried out (unsupported extension, mismatched sizes).
    #[error("{0}")]
    Usage(String),
}

/// The library's result type.
pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    /// An I/O error on `path`.
    #[must_use]
    pub fn io(path: &Path, message: &str, source: std::io::Error) -> Self {
        Error::Io {
            origin: path.display().to_string(),
            message: message.to_owned(),
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
            message: message.into(),
        }
    }

    /// A file that is not well-formed.
    #[must_use]
    pub fn malformed(origin: &str, message: impl Into<String>) -> Self {
        Error::Malformed {
            origin: origin.to_owned(),
            message: message.into(),
        }
    }
}
