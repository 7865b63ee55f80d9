//! Analyses that join several crates for one user question (called by the CLI and by tests).

pub mod bonnets;
