//! `rust-version` in Cargo.toml is the truth: the newest `rust-version` any locked
//! dependency declares (dev and build ones included), read from `cargo metadata`.

use std::process::Command;

/// "1.88" or "1.88.0" as (major, minor, patch).
fn parse(version: &str) -> Option<(u32, u32, u32)> {
    let mut parts = version.trim().split('.').map(|p| p.parse::<u32>().ok());
    let major = parts.next()??;
    let minor = parts.next().unwrap_or(Some(0))?;
    let patch = parts.next().unwrap_or(Some(0))?;
    Some((major, minor, patch))
}

#[test]
fn rust_version_is_what_the_locked_dependencies_need() {
    let manifest_dir = env!("CARGO_MANIFEST_DIR");
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".to_string());
    let host = format!("{}-unknown-linux-gnu", std::env::consts::ARCH);
    let out = Command::new(cargo)
        .current_dir(manifest_dir)
        .args([
            "metadata",
            "--format-version",
            "1",
            "--locked",
            "--offline",
            "--filter-platform",
            &host,
        ])
        .output()
        .expect("cargo metadata runs");
    assert!(
        out.status.success(),
        "cargo metadata failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let meta: serde_json::Value = serde_json::from_slice(&out.stdout).expect("metadata is JSON");
    let packages = meta["packages"].as_array().expect("a package list");
    let ours = packages
        .iter()
        .find(|p| p["name"] == "nanoforce")
        .and_then(|p| p["rust_version"].as_str())
        .and_then(parse)
        .expect("Cargo.toml declares rust-version");
    let (needed, by) = packages
        .iter()
        .filter(|p| p["name"] != "nanoforce")
        .filter_map(|p| {
            let v = parse(p["rust_version"].as_str()?)?;
            let name = p["name"].as_str().unwrap_or("?");
            let version = p["version"].as_str().unwrap_or("?");
            Some((v, format!("{name} {version}")))
        })
        .max()
        .expect("some dependency declares a rust-version");
    assert_eq!(
        ours, needed,
        "Cargo.toml's rust-version is {ours:?}, but {by} needs {needed:?}: set it to what the \
         dependencies need"
    );
}
