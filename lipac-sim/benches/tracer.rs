//! Tracer benchmark (placeholder until written).
fn main() {}
