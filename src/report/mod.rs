//! Experiments and their reports: the seed paper's study, metrics and charts.

pub mod charts;
pub mod experiment;
pub mod markdown;
pub mod methods;
