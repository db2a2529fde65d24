//! numpy arrays in and out. Inputs are read in place where their dtype and layout allow
//! (a C-contiguous float64 array is one slice: no copy before the library's own arrays are
//! filled); any other array-like is converted by numpy first. Outputs hand their buffer to
//! numpy without a copy.

use numpy::{
    AllowTypeChange, IxDyn, PyArray1, PyArrayLikeDyn, PyArrayMethods, PyUntypedArrayMethods,
};
use pyo3::prelude::*;

use crate::errors::usage;

/// An array-like of any dtype, as float64.
pub type AnyF64<'py> = PyArrayLikeDyn<'py, f64, AllowTypeChange>;
/// An array-like of any dtype, as float32.
pub type AnyF32<'py> = PyArrayLikeDyn<'py, f32, AllowTypeChange>;

/// `value` as a float64 array; `what` names it in the error.
pub fn array_f64<'py>(value: &Bound<'py, PyAny>, what: &str) -> PyResult<AnyF64<'py>> {
    value
        .extract::<AnyF64<'py>>()
        .map_err(|e| usage(value.py(), format!("{what}: not an array of numbers ({e})")))
}

/// A shape as Python prints it.
pub fn shape_text(shape: &[usize]) -> String {
    match shape {
        [n] => format!("({n},)"),
        _ => format!(
            "({})",
            shape
                .iter()
                .map(usize::to_string)
                .collect::<Vec<_>>()
                .join(", ")
        ),
    }
}

/// The values of `array`, row-major: its own memory when contiguous, else a copy.
pub fn values<T: numpy::Element + Copy>(array: &numpy::PyReadonlyArray<'_, T, IxDyn>) -> Vec<T> {
    match array.as_slice() {
        Ok(slice) => slice.to_vec(),
        Err(_) => array.as_array().iter().copied().collect(),
    }
}

/// Calls `each` with the rows of width `K` of `array`, shape `(n, K)`, in place when
/// contiguous.
pub fn for_rows<const K: usize>(array: &AnyF64<'_>, mut each: impl FnMut([f64; K])) {
    match array.as_slice() {
        Ok(slice) => slice
            .chunks_exact(K)
            .for_each(|row| each(row.try_into().expect("rows of K values"))),
        Err(_) => {
            let view = array.as_array();
            for row in view.rows() {
                each(std::array::from_fn(|k| row[k]));
            }
        }
    }
}

/// The rows of width `K` of an `(n, K)` array (`n` free when `None`); `what` names it.
pub fn rows<const K: usize>(
    py: Python<'_>,
    array: &AnyF64<'_>,
    what: &str,
    n: Option<usize>,
) -> PyResult<Vec<[f64; K]>> {
    let shape = array.shape();
    let ok = shape.len() == 2 && shape[1] == K && n.is_none_or(|n| shape[0] == n);
    if !ok {
        let n = n.map_or("N".to_owned(), |n| n.to_string());
        return Err(usage(
            py,
            format!("{what}: shape {}, expected ({n}, {K})", shape_text(shape)),
        ));
    }
    let mut out = Vec::with_capacity(shape[0]);
    for_rows::<K>(array, |row| out.push(row));
    Ok(out)
}

/// `(n, K)` float64 array of `rows`.
pub fn rows_array<'py, const K: usize>(
    py: Python<'py>,
    rows: &[[f64; K]],
) -> PyResult<Bound<'py, PyAny>> {
    Ok(PyArray1::from_slice(py, rows.as_flattened())
        .reshape([rows.len(), K])?
        .into_any())
}

/// An array of `shape` owning `values` (no copy).
pub fn owned_array<'py, T: numpy::Element>(
    py: Python<'py>,
    values: Vec<T>,
    shape: &[usize],
) -> PyResult<Bound<'py, PyAny>> {
    Ok(PyArray1::from_vec(py, values).reshape(shape)?.into_any())
}
