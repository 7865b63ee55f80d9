//! Dwell-time solvers (in progress).
