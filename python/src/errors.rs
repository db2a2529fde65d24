//! The library's errors as Python exceptions (`splat4d/_errors.py` defines the classes):
//! one class per [`ErrorKind`], the message the command line would print, and the names
//! the error carries (`origin`, `item`, `field`, or the settings it blames) as attributes.

use pyo3::exceptions::PyRuntimeError;
use pyo3::prelude::*;
use pyo3::types::PyList;
use splat4d::{Error, ErrorKind};

/// The Python class of an error kind.
fn class_name(kind: ErrorKind) -> &'static str {
    match kind {
        ErrorKind::Input => "InputError",
        ErrorKind::Usage => "UsageError",
        ErrorKind::Output => "OutputError",
        ErrorKind::Numeric => "NumericError",
    }
}

/// `error` as the exception of its kind, with its names as attributes.
pub fn to_py(py: Python<'_>, error: Error) -> PyErr {
    match exception(py, &error) {
        Ok(exception) => PyErr::from_value(exception),
        // The classes are the package's own: failing to make one is a broken install.
        Err(failure) => PyRuntimeError::new_err(format!("{error} (and {failure})")),
    }
}

fn exception<'py>(py: Python<'py>, error: &Error) -> PyResult<Bound<'py, PyAny>> {
    let class = py
        .import("splat4d._errors")?
        .getattr(class_name(error.kind()))?;
    let exception = class.call1((error.to_string(),))?;
    let none = py.None();
    let (mut origin, mut item, mut field) = (
        none.bind(py).clone(),
        none.bind(py).clone(),
        none.bind(py).clone(),
    );
    let mut fields = PyList::empty(py);
    match error {
        Error::Read { origin: o, .. }
        | Error::Write { origin: o, .. }
        | Error::Malformed { origin: o, .. } => {
            origin = o.into_pyobject(py)?.into_any();
        }
        Error::Invalid {
            origin: o,
            item: i,
            field: f,
            ..
        } => {
            origin = o.into_pyobject(py)?.into_any();
            item = i.into_pyobject(py)?.into_any();
            field = f.into_pyobject(py)?.into_any();
        }
        Error::Setting { fields: names, .. } => fields = PyList::new(py, names)?,
        Error::Usage(_) | Error::Numeric(_) => {}
    }
    exception.setattr("origin", origin)?;
    exception.setattr("item", item)?;
    exception.setattr("field", field)?;
    exception.setattr("settings", fields)?;
    Ok(exception)
}

/// A library result as a Python one.
pub fn lib<T>(py: Python<'_>, result: splat4d::Result<T>) -> PyResult<T> {
    result.map_err(|error| to_py(py, error))
}

/// A [`Error::Usage`] about the arguments of a call, as its exception.
pub fn usage(py: Python<'_>, message: impl Into<String>) -> PyErr {
    to_py(py, Error::usage(message))
}
