//! The `nanoforce` binary: parses the command line and hands over to the library.
use std::process::ExitCode;

use clap::Parser;

fn main() -> ExitCode {
    let cli = nanoforce::cli::Cli::parse();
    match nanoforce::cli::run(cli) {
        Ok(code) => code,
        Err(err) => {
            let priority = nanoforce::cli::logging::error_prefix();
            eprintln!("{priority}nanoforce: error: {}", message(&err));
            ExitCode::FAILURE
        }
    }
}

/// The error and its causes, "a: b: c"; a cause whose text its parent already ends
/// with (our errors name their source in their own message) is not repeated.
fn message(err: &anyhow::Error) -> String {
    let mut text = String::new();
    for cause in err.chain() {
        let part = cause.to_string();
        if text.ends_with(&part) {
            continue;
        }
        if !text.is_empty() {
            text.push_str(": ");
        }
        text.push_str(&part);
    }
    text
}
