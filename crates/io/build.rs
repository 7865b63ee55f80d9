//! Finds the shared test data for this crate's tests (see tests/common/shared_data.rs at the
//! workspace root).

#[path = "../../tests/common/shared_data.rs"]
mod shared_data;

fn main() {
    shared_data::gate();
}
