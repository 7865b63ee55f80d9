//! The CLI's error is the pipelines' error (one type for both layers): a one-line message that
//! names the file (and field) and an exit code.

pub use crate::pipeline::error::{io_what, Error as CliError, EXIT_BAD_INPUT, EXIT_PROCESSING};
