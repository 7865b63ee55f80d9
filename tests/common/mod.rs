//! Helpers shared by integration tests (each test file includes what it needs).

pub mod calibrate;
pub mod shared_data;
