//! `nanoforce probe-devices`: checks the lab's devices before a run. Each configured
//! device is opened as the daemon would open it and exercised once (a frame, a stylus
//! sample; a DAQ is left at zero), then closed; then what this machine offers is listed.
//! Exits non-zero if a configured device cannot be opened.
use std::path::PathBuf;
use std::process::ExitCode;

use clap::Args;

use crate::config::Config;
use crate::hw::{probe, Clock};

/// Open each configured device once and list what this machine offers.
#[derive(Debug, Args)]
#[command(
    long_about = "Checks the lab's devices before a run.\n\n\
Each device the configuration names ([frames], [daq], [haptic]) is opened the way \
`nanoforce run` opens it, asked for one frame or one stylus sample, and closed again \
(a DAQ's outputs are left at zero; no force is rendered). Then what this machine offers \
is listed: /dev/video* and /dev/comedi* nodes and whether you may open them, HID \
devices, whether OpenHaptics' libHD.so loads, and which hardware features this build \
has. The exit status is non-zero if a configured device cannot be opened.",
    after_help = "Examples:\n  nanoforce probe-devices --config /etc/nanoforce/nanoforce.toml\n  \
nanoforce probe-devices                 # the built-in simulated lab, and what is attached"
)]
pub struct ProbeArgs {
    /// Lab configuration (TOML); default: the built-in simulated lab.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Only the configured devices, not what else the machine offers.
    #[arg(long)]
    pub configured_only: bool,
}

pub fn run(args: ProbeArgs) -> anyhow::Result<ExitCode> {
    let config = match &args.config {
        Some(path) => Config::load(path)?,
        None => Config::from_toml_str(
            super::run::SIM_CONFIG,
            std::path::Path::new("<built-in sim.toml>"),
        )?,
    };
    println!("configured devices ({}):", config.path.display());
    let findings = probe::configured(&config.devices, Clock::start());
    for f in &findings {
        println!(
            "  [{}] {:<6} {}",
            if f.ok { " ok " } else { "FAIL" },
            f.kind,
            f.detail
        );
    }
    if !args.configured_only {
        println!("on this machine:");
        for line in probe::discover() {
            println!("  {line}");
        }
    }
    let failed = findings.iter().filter(|f| !f.ok).count();
    if failed > 0 {
        eprintln!("nanoforce: {failed} configured device(s) cannot be used; `nanoforce run` would refuse to start");
        return Ok(ExitCode::FAILURE);
    }
    Ok(ExitCode::SUCCESS)
}
