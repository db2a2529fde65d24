//! JSON documents with errors that say where: a parse error inside the `kernels` array
//! becomes "kernel 3: field `scale[1]`: ...", anything else names its path in the document.

use serde::de::DeserializeOwned;
use serde_path_to_error::Segment;

use crate::model::error::{Error, Result};

/// Parses `text` as a `T`. `origin` (a file name) and `what` (the document's item name, such
/// as `camera`) go into error messages.
pub fn parse_json<T: DeserializeOwned>(text: &str, origin: &str, what: &str) -> Result<T> {
    // A UTF-8 byte order mark (some Windows editors write one) is not JSON, but harmless.
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut deserializer = serde_json::Deserializer::from_str(text);
    let value: T =
        serde_path_to_error::deserialize(&mut deserializer).map_err(|e| locate(e, origin, what))?;
    deserializer
        .end()
        .map_err(|e| Error::malformed(origin, format!("malformed JSON after the {what}: {e}")))?;
    Ok(value)
}

/// Longest message echoed from the parser: values quoted in it are cut, so a 10 MB string
/// in a file does not come back whole.
const MAX_MESSAGE: usize = 300;

/// `text` cut to 300 characters, with an ellipsis: every value quoted in a message.
#[must_use]
pub fn cut(text: &str) -> String {
    shorten(text)
}

/// `message` cut to [`MAX_MESSAGE`] characters, with an ellipsis.
fn shorten(message: &str) -> String {
    match message.char_indices().nth(MAX_MESSAGE) {
        Some((end, _)) => format!(
            "{}… ({} characters in all)",
            &message[..end],
            message.chars().count()
        ),
        None => message.to_owned(),
    }
}

fn locate(error: serde_path_to_error::Error<serde_json::Error>, origin: &str, what: &str) -> Error {
    let segments: Vec<&Segment> = error.path().iter().collect();
    let (item, rest) = match segments.as_slice() {
        [Segment::Map { key }, Segment::Seq { index }, rest @ ..] if key == "kernels" => {
            (format!("kernel {index}"), rest)
        }
        _ => (what.to_owned(), segments.as_slice()),
    };
    let mut field = String::new();
    for segment in rest {
        match segment {
            Segment::Seq { index } => field.push_str(&format!("[{index}]")),
            Segment::Map { key } => {
                if !field.is_empty() {
                    field.push('.');
                }
                field.push_str(key);
            }
            Segment::Enum { variant } => field.push_str(variant),
            Segment::Unknown => {}
        }
    }
    let message = shorten(&error.inner().to_string());
    if field.is_empty() {
        Error::malformed(origin, format!("{item}: {message}"))
    } else {
        Error::invalid(origin, item, &field, message)
    }
}
