//! Writes what the Debian package ships beside the binary, generated from the clap
//! definitions in `src/cli`: a man page for `nanoforce` and one for each subcommand
//! (`nanoforce-run.1`, ...), and the bash, zsh and fish completions.
//!
//! ```text
//! cargo run --release --example dist_files -- target/dist
//! cargo deb
//! ```
//!
//! writes `target/dist/man/*.1` and `target/dist/completions/` (`nanoforce.bash`,
//! `_nanoforce`, `nanoforce.fish`), the paths `[package.metadata.deb]` in Cargo.toml
//! packages. Both folders are emptied first, so a removed subcommand leaves no page behind.
use std::fs;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use clap::CommandFactory;
use clap_complete::Shell;
use nanoforce::cli::Cli;

fn main() -> ExitCode {
    let mut args = std::env::args_os().skip(1);
    let out = args
        .next()
        .map_or_else(|| PathBuf::from("target/dist"), PathBuf::from);
    if args.next().is_some() {
        eprintln!("usage: dist_files [OUT_DIR]   (default target/dist)");
        return ExitCode::from(2);
    }
    match write_all(&out) {
        Ok(files) => {
            for file in files {
                println!("{}", file.display());
            }
            ExitCode::SUCCESS
        }
        Err(err) => {
            eprintln!("dist_files: {err}");
            ExitCode::FAILURE
        }
    }
}

/// Writes the man pages into `out/man` and the completions into `out/completions`;
/// returns every file written.
fn write_all(out: &Path) -> Result<Vec<PathBuf>, String> {
    let man_dir = out.join("man");
    let completions_dir = out.join("completions");
    let mut files = Vec::new();
    for dir in [&man_dir, &completions_dir] {
        fresh_dir(dir)?;
    }
    for (name, page) in man_pages()? {
        files.push(write(&man_dir.join(name), &page)?);
    }
    for (name, script) in completions() {
        files.push(write(&completions_dir.join(name), &script)?);
    }
    Ok(files)
}

/// `dir`, created if missing and emptied of files if not.
fn fresh_dir(dir: &Path) -> Result<(), String> {
    fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let entries = fs::read_dir(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    for entry in entries {
        let path = entry.map_err(|e| format!("{}: {e}", dir.display()))?.path();
        if path.is_file() {
            fs::remove_file(&path).map_err(|e| format!("{}: {e}", path.display()))?;
        }
    }
    Ok(())
}

fn write(path: &Path, bytes: &[u8]) -> Result<PathBuf, String> {
    fs::write(path, bytes).map_err(|e| format!("{}: {e}", path.display()))?;
    Ok(path.to_path_buf())
}

/// Section 1 pages, file name and roff text: `nanoforce.1` for the command, then
/// `nanoforce-SUB.1` for each visible subcommand (no page for clap's `help`).
fn man_pages() -> Result<Vec<(String, Vec<u8>)>, String> {
    let mut cli = Cli::command().disable_help_subcommand(true);
    cli.build();
    // Every page's footer names the release (a subcommand has no version of its own).
    let source = format!("nanoforce {}", cli.get_version().unwrap_or_default());
    let mut commands = vec![cli.clone()];
    commands.extend(cli.get_subcommands().filter(|s| !s.is_hide_set()).cloned());
    commands
        .into_iter()
        .map(|cmd| {
            let man = clap_mangen::Man::new(cmd)
                .source(source.as_str())
                .manual("nanoforce manual");
            let mut page = Vec::new();
            man.render(&mut page)
                .map_err(|e| format!("rendering {}: {e}", man.get_filename()))?;
            Ok((man.get_filename(), page))
        })
        .collect()
}

/// The completion scripts, named as each shell's vendor directory expects them
/// (Cargo.toml installs them there).
fn completions() -> Vec<(&'static str, Vec<u8>)> {
    [
        (Shell::Bash, "nanoforce.bash"),
        (Shell::Zsh, "_nanoforce"),
        (Shell::Fish, "nanoforce.fish"),
    ]
    .into_iter()
    .map(|(shell, name)| {
        let mut script = Vec::new();
        clap_complete::generate(shell, &mut Cli::command(), "nanoforce", &mut script);
        (name, script)
    })
    .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn text(bytes: &[u8]) -> &str {
        std::str::from_utf8(bytes).expect("generated text is UTF-8")
    }

    /// A name as roff prints it: hyphens escaped.
    fn roff(name: &str) -> String {
        name.replace('-', "\\-")
    }

    #[test]
    fn every_subcommand_gets_a_man_page_with_its_options() {
        let pages = man_pages().expect("pages render");
        let names: Vec<&str> = pages.iter().map(|(n, _)| n.as_str()).collect();
        let cli = Cli::command();
        let subcommands: Vec<&clap::Command> = cli.get_subcommands().collect();
        assert!(subcommands.len() >= 6, "{names:?}");
        assert_eq!(names.len(), subcommands.len() + 1, "{names:?}");
        let (_, top) = pages
            .iter()
            .find(|(n, _)| n == "nanoforce.1")
            .expect("nanoforce.1");
        let version = format!("\"nanoforce {}\"", env!("CARGO_PKG_VERSION"));
        assert!(
            text(top).contains(".TH nanoforce 1") && text(top).contains(&version),
            "{}",
            text(top)
        );
        for sub in subcommands {
            let file = format!("nanoforce-{}.1", sub.get_name());
            let (_, page) = pages
                .iter()
                .find(|(n, _)| *n == file)
                .unwrap_or_else(|| panic!("no {file} in {names:?}"));
            let page = text(page);
            // The top page lists the subcommand; its own page names it and every option.
            assert!(
                text(top).contains(&format!("nanoforce\\-{}(1)", roff(sub.get_name()))),
                "nanoforce.1 does not list {file}"
            );
            assert!(
                page.contains(&format!(".TH nanoforce-{} 1", sub.get_name()))
                    && page.contains(&version),
                "{file}: {page}"
            );
            let about = sub.get_about().map(|a| a.to_string()).unwrap_or_default();
            assert!(
                page.contains(&roff(&about).replace('\'', "\\*(Aq")),
                "{file} lacks the summary {about:?}"
            );
            for arg in sub.get_arguments().filter(|a| !a.is_hide_set()) {
                if let Some(long) = arg.get_long() {
                    let flag = format!("\\-\\-{}", roff(long));
                    assert!(page.contains(&flag), "{file} lacks {flag}");
                }
            }
        }
        assert!(!names.contains(&"nanoforce-help.1"), "{names:?}");
    }

    #[test]
    fn every_shell_completes_every_subcommand() {
        let scripts = completions();
        assert_eq!(scripts.len(), 3);
        for (name, script) in &scripts {
            let script = text(script);
            for sub in Cli::command().get_subcommands() {
                assert!(
                    script.contains(sub.get_name()),
                    "{name} does not complete {}",
                    sub.get_name()
                );
            }
        }
    }

    #[test]
    fn write_all_replaces_what_an_earlier_run_left() {
        let dir = tempfile::tempdir().expect("temp dir");
        let stale = dir.path().join("man").join("nanoforce-gone.1");
        fs::create_dir_all(stale.parent().expect("parent")).expect("man dir");
        fs::write(&stale, b"old").expect("stale page");
        let files = write_all(dir.path()).expect("written");
        assert!(!stale.exists());
        assert!(files.iter().all(|f| f.is_file()));
        assert!(dir.path().join("completions/_nanoforce").is_file());
        assert!(dir.path().join("man/nanoforce-probe-devices.1").is_file());
    }
}
