//! The `bonnetlab` binary: parse arguments, call the library, map errors to exit codes
//! (0 success, 1 processing error, 2 bad input or usage). Never panics on user input.

use clap::Parser;

fn main() {
    // Map-sized arrays are freed and allocated again thousands of times per calibration.
    bonnetlab_process::memory::retain_freed_memory();
    let cli = match bonnetlab::cli::Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => std::process::exit(bonnetlab::cli::usage_error(&e)),
    };
    std::process::exit(bonnetlab::cli::run(cli));
}
