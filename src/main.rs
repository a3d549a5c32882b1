//! The `nanoforce` binary: parses the command line and hands over to the library.
use std::process::ExitCode;

use clap::Parser;

fn main() -> ExitCode {
    let cli = nanoforce::cli::Cli::parse();
    match nanoforce::cli::run(cli) {
        Ok(code) => code,
        Err(err) => {
            eprintln!("nanoforce: error: {err:#}");
            ExitCode::FAILURE
        }
    }
}
