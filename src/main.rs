//! The `bonnetlab` binary: parse arguments, call the library, map errors to exit codes
//! (0 success, 1 processing error, 2 bad input or usage). Never panics on user input.

use clap::Parser;

fn main() {
    // clap itself exits with code 2 on a usage error.
    let cli = bonnetlab::cli::Cli::parse();
    std::process::exit(bonnetlab::cli::run(cli));
}
