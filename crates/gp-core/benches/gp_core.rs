//! Criterion benchmarks for gp-core (placeholder, filled below).
fn main() {}
