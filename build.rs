//! Finds the shared test data and Chromium for the tests (see tests/common/shared_data.rs).

#[path = "tests/common/shared_data.rs"]
mod shared_data;

fn main() {
    shared_data::gate();
}
