//! Benchmarks (criterion) for this capability; see reports/performance.md.

fn main() {}
