//! Writes the demo session in `replay/demo/` (or any folder): a rendered 640x480 sequence
//! at 60 Hz of an operator pressing and releasing, with the magnification changed now and
//! then and a few frames without the probe, in the layout of docs/conventions.md
//! (probe.toml, reference.png, frames/, truth.csv). The session in the repository was made
//! with
//!
//! ```text
//! cargo run --release --example demo_session -- replay/demo
//! ```
//!
//! Options: FOLDER (default replay/demo), --seed N (default 7), --frames N (default 60),
//! --style clean|clutter|noisy|harsh (default clutter: the sequence's own style, with its
//! particles and scratches, at every frame; noisy frames make PNGs three times larger).
use std::path::PathBuf;
use std::process::ExitCode;

use nanoforce::scene::rng::Rng;
use nanoforce::scene::{varied_look, FrameFormat, Session, Style};

fn main() -> ExitCode {
    let mut dir = PathBuf::from("replay/demo");
    let mut seed = 7u64;
    let mut frames = 60usize;
    let mut style = Style::Clutter;
    let mut args = std::env::args().skip(1);
    while let Some(arg) = args.next() {
        let mut number = |name: &str| -> Option<u64> {
            let value = args.next();
            let parsed = value.as_deref().and_then(|v| v.parse().ok());
            if parsed.is_none() {
                eprintln!("{name} needs a whole number, got {value:?}");
            }
            parsed
        };
        match arg.as_str() {
            "--seed" => match number("--seed") {
                Some(n) => seed = n,
                None => return ExitCode::FAILURE,
            },
            "--frames" => match number("--frames") {
                Some(n) => frames = n as usize,
                None => return ExitCode::FAILURE,
            },
            "--style" => {
                let name = args.next().unwrap_or_default();
                match Style::ALL.into_iter().find(|s| s.name() == name) {
                    Some(s) => style = s,
                    None => {
                        eprintln!("--style: {name:?} is not clean, clutter, noisy or harsh");
                        return ExitCode::FAILURE;
                    }
                }
            }
            _ => dir = PathBuf::from(arg),
        }
    }
    let mut session = Session::sequence(seed, frames, 640, 480);
    let mut rng = Rng::new(seed);
    session.reference.look = style.look();
    for frame in &mut session.frames {
        frame.look = varied_look(style, &mut rng);
    }
    match session.write(&dir, FrameFormat::Png) {
        Ok(truth) => {
            let in_view = truth.iter().filter(|t| t.probe_in_view).count();
            println!(
                "wrote {} frames ({in_view} with the probe in view) to {}",
                truth.len(),
                dir.display()
            );
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("{e}");
            ExitCode::FAILURE
        }
    }
}
