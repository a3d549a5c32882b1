//! Every configuration file shipped in `config/` must load and validate.
use std::path::Path;

use nanoforce::config::Config;

#[test]
fn shipped_example_probe_config_is_valid() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/probe.example.toml");
    let cfg = Config::load(&path).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(cfg.cantilever.length_um, 434.675);
    assert!(cfg.tracker.calibration.is_some());
}

#[test]
fn public_sample_configs_are_valid() {
    for name in ["mixed", "sequence"] {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/data/samples")
            .join(name)
            .join("probe.toml");
        let cfg = Config::load(&path).unwrap_or_else(|e| panic!("{e}"));
        let cal = cfg.tracker.calibration.expect("calibration block");
        assert!(
            cal.reference_image.exists(),
            "{}",
            cal.reference_image.display()
        );
    }
}

#[test]
fn shipped_sim_config_is_valid_and_matches_the_defaults() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/sim.toml");
    let cfg = Config::load(&path).unwrap_or_else(|e| panic!("{e}"));
    assert!(cfg.devices.all_simulated());
    // The file documents the defaults: a config without those sections means the same.
    let bare = Config::from_toml_str(
        "[cantilever]\nlength_um = 434.675\nspring_constant_n_per_m = 0.06\n",
        Path::new("bare.toml"),
    )
    .unwrap();
    assert_eq!(cfg.sim, bare.sim);
    assert_eq!(cfg.daemon, bare.daemon);
    let mut teleop = cfg.teleop.clone();
    teleop.safety.max_contact_force_nn = bare.teleop.safety.max_contact_force_nn;
    assert_eq!(teleop, bare.teleop);
}
