//! Experiments and their reports: the seed paper's study, metrics and charts.

pub mod charts;
