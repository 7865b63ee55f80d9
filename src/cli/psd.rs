//! `bonnetlab psd` (contract: shared/spec/interfaces.md).

use super::CliError;

#[derive(Debug, clap::Args)]
pub struct Args {}

pub fn run(_args: &Args) -> Result<(), CliError> {
    Err(CliError::usage("'psd' is not available in this build yet"))
}
