//! `nanoforce model`: tip angles in, the cantilever model out as CSV, through the same
//! lookup table ([`ModelTable::global`]) the tracker uses. All input is checked before
//! anything is written, so a bad line never leaves a half-written table behind.
use std::fmt;
use std::io::{self, BufWriter, Read, Write};
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::Args;

use crate::config::Config;
use crate::model::{Cantilever, ModelTable, MAX_PHI0_DEG};

/// Tabulate the cantilever model (load, deflection, shortening) for tip angles on stdin.
#[derive(Debug, Args)]
#[command(long_about = LONG_ABOUT, after_long_help = AFTER_LONG_HELP)]
pub struct ModelArgs {
    /// Probe config (TOML with a [cantilever] section): adds a force_nN column.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Which probe's cantilever, when the config has several [[probe]] entries.
    #[arg(long, value_name = "NAME", requires = "config")]
    pub probe: Option<String>,
}

const LONG_ABOUT: &str = "\
Tabulates the exact large-deflection model of the AFM cantilever for tip angles read \
from standard input.

For each tip angle phi0 (the slope of the beam's free end relative to its unloaded \
direction, in degrees, either sign) it gives the elastica of a cantilever clamped with \
zero slope and loaded at its free end by a force of fixed direction, transverse to the \
undeformed beam: the nondimensional load alpha = F L^2 / EI, the tip deflection delta/L \
and the projected shortening Delta/L. The values come from the lookup table the tracker \
uses, built at start-up from the closed form in elliptic integrals (relative error below \
1e-12; docs/model.md).

INPUT
One angle in degrees per line, as a decimal number (12, -3.5, 1e-3). Whitespace around a \
number is ignored and blank lines are skipped; nothing else is accepted. The model covers \
|angle| <= 89 degrees.
All input is read and checked before anything is written. If any line is not a number or \
is out of range, every such line is reported on standard error with its line number and \
text, nothing at all is written to standard output, and the exit status is 1.

OUTPUT
CSV on standard output: a header, then one row per angle in input order.
  angle_deg          the angle as read, degrees
  alpha              tip load F L^2 / EI, dimensionless, sign of the angle
  delta_over_l       tip deflection across the undeformed beam over its length L,
                     sign of the angle
  shortening_over_l  how much shorter the beam's projection on its undeformed axis
                     is, over L (>= 0)
  force_nN           only with --config: the tip force alpha EI / L^2 in nanonewtons,
                     sign of the angle
Each number is printed in the shortest decimal form that reads back as the same \
double-precision value.";

const AFTER_LONG_HELP: &str = "\
EXAMPLES
  $ printf '5\\n-20\\n' | nanoforce model
  angle_deg,alpha,delta_over_l,shortening_over_l
  5,0.17502147081732788,0.0581375744326988,0.002030341784810373
  -20,-0.730591636107194,-0.23016373407277602,0.03238299492105391

  $ seq -20 1 20 | nanoforce model --config probe.toml > model.csv

EXIT STATUS
  0 on success; 1 on bad input, a bad config file, or an I/O error.";

/// Runs `nanoforce model`.
pub fn run(args: ModelArgs) -> anyhow::Result<ExitCode> {
    // A bad config fails before any input is read.
    let cantilever = match &args.config {
        Some(path) => {
            let config = Config::load(path)?;
            let names = || {
                let names: Vec<&str> = config.probes.iter().map(|p| p.name.as_str()).collect();
                names.join(", ")
            };
            let probe = match (&args.probe, config.probes.as_slice()) {
                (None, [probe]) => probe,
                (None, _) => anyhow::bail!(
                    "{}: several probes ({}): name one with --probe",
                    path.display(),
                    names()
                ),
                (Some(name), probes) => match probes.iter().find(|p| &p.name == name) {
                    Some(probe) => probe,
                    None => anyhow::bail!(
                        "{}: no probe named {name} (its probes: {})",
                        path.display(),
                        names()
                    ),
                },
            };
            let cantilever = probe
                .cantilever
                .with_context(|| format!("{}: no [cantilever] section to model", path.display()))?;
            Some(cantilever)
        }
        None => None,
    };
    let mut input = Vec::new();
    io::stdin()
        .lock()
        .read_to_end(&mut input)
        .context("cannot read standard input")?;
    let angles = parse_angles(&input)?;
    let mut out = BufWriter::new(io::stdout().lock());
    write_csv(&mut out, &angles, cantilever.as_ref(), ModelTable::global())
        .and_then(|()| out.flush())
        .context("cannot write standard output")?;
    Ok(ExitCode::SUCCESS)
}

/// Input lines that are not usable angles; nothing is written when there are any.
#[derive(Debug, Clone, PartialEq)]
pub struct BadInput {
    lines: Vec<BadLine>,
}

impl std::error::Error for BadInput {}

/// One unusable input line (numbered from 1) and why.
#[derive(Debug, Clone, PartialEq)]
struct BadLine {
    line: usize,
    text: String,
    reason: String,
}

/// At most this many bad lines are listed; the rest are counted.
const MAX_LISTED: usize = 20;

impl fmt::Display for BadInput {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if let [only] = self.lines.as_slice() {
            return write!(f, "standard input, {only}; nothing was written");
        }
        write!(
            f,
            "{} bad input lines; nothing was written",
            self.lines.len()
        )?;
        for bad in self.lines.iter().take(MAX_LISTED) {
            write!(f, "\n  {bad}")?;
        }
        if self.lines.len() > MAX_LISTED {
            write!(f, "\n  ... and {} more", self.lines.len() - MAX_LISTED)?;
        }
        Ok(())
    }
}

impl fmt::Display for BadLine {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "line {}: {:?} {}", self.line, self.text, self.reason)
    }
}

/// The angles on the non-blank lines of `input`, or every line that is not one.
fn parse_angles(input: &[u8]) -> Result<Vec<f64>, BadInput> {
    let mut angles = Vec::new();
    let mut bad = Vec::new();
    for (index, raw) in input.split(|&b| b == b'\n').enumerate() {
        let text = String::from_utf8_lossy(raw);
        let trimmed = text.trim();
        if trimmed.is_empty() {
            continue;
        }
        match angle_from_line(raw, trimmed) {
            Ok(angle) => angles.push(angle),
            Err(reason) => bad.push(BadLine {
                line: index + 1,
                text: shorten(trimmed),
                reason,
            }),
        }
    }
    if bad.is_empty() {
        Ok(angles)
    } else {
        Err(BadInput { lines: bad })
    }
}

/// The angle on one non-blank line, or why it is not one.
fn angle_from_line(raw: &[u8], trimmed: &str) -> Result<f64, String> {
    if std::str::from_utf8(raw).is_err() {
        return Err("is not UTF-8 text".into());
    }
    let angle: f64 = trimmed
        .parse()
        .map_err(|_| "is not a number (expected a tip angle in degrees)".to_string())?;
    if !angle.is_finite() {
        return Err("is not a finite number".into());
    }
    if angle.abs() > MAX_PHI0_DEG {
        return Err(format!(
            "is out of range: the model covers |angle| <= {MAX_PHI0_DEG} degrees"
        ));
    }
    Ok(angle)
}

/// The first 60 characters of a line, for messages.
fn shorten(text: &str) -> String {
    match text.char_indices().nth(60) {
        Some((cut, _)) => format!("{}...", &text[..cut]),
        None => text.to_string(),
    }
}

/// The CSV: header, then one row per angle (all within range).
fn write_csv(
    out: &mut impl Write,
    angles: &[f64],
    cantilever: Option<&Cantilever>,
    table: &ModelTable,
) -> io::Result<()> {
    let force_column = if cantilever.is_some() {
        ",force_nN"
    } else {
        ""
    };
    writeln!(
        out,
        "angle_deg,alpha,delta_over_l,shortening_over_l{force_column}"
    )?;
    for &angle_deg in angles {
        let e = table.elastica_deg(angle_deg).value;
        write!(
            out,
            "{angle_deg},{},{},{}",
            e.alpha, e.delta_over_l, e.shortening_over_l
        )?;
        match cantilever {
            Some(c) => writeln!(out, ",{}", c.force_nn(angle_deg).value)?,
            None => writeln!(out)?,
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blank_lines_and_surrounding_whitespace_are_ignored() {
        let angles = parse_angles(b"  5\n\n\t-12.5 \r\n+1e-3\n\n").unwrap();
        assert_eq!(angles, vec![5.0, -12.5, 1e-3]);
        assert_eq!(parse_angles(b"").unwrap(), Vec::<f64>::new());
        assert_eq!(parse_angles(b"89\n-89").unwrap(), vec![89.0, -89.0]);
    }

    #[test]
    fn every_bad_line_is_reported_with_its_number_and_text() {
        let err = parse_angles(b"5\nabc\n\n95\nnan\n-inf\n1 2\n").unwrap_err();
        let lines: Vec<usize> = err.lines.iter().map(|b| b.line).collect();
        assert_eq!(lines, vec![2, 4, 5, 6, 7]);
        let msg = err.to_string();
        assert!(
            msg.starts_with("5 bad input lines; nothing was written"),
            "{msg}"
        );
        assert!(msg.contains("line 2: \"abc\" is not a number"), "{msg}");
        assert!(msg.contains("line 4: \"95\" is out of range"), "{msg}");
        assert!(
            msg.contains("line 5: \"nan\" is not a finite number"),
            "{msg}"
        );
        assert!(msg.contains("line 7: \"1 2\" is not a number"), "{msg}");
    }

    #[test]
    fn a_single_bad_line_reads_as_one_sentence() {
        let msg = parse_angles(b"1\n2\n89.5\n").unwrap_err().to_string();
        assert_eq!(
            msg,
            "standard input, line 3: \"89.5\" is out of range: the model covers \
             |angle| <= 89 degrees; nothing was written"
        );
        let msg = parse_angles(b"\xff\xfe\n").unwrap_err().to_string();
        assert!(msg.contains("line 1") && msg.contains("not UTF-8"), "{msg}");
    }

    #[test]
    fn long_lists_and_long_lines_are_cut() {
        let input = "x\n".repeat(25) + &"9".repeat(100);
        let msg = parse_angles(input.as_bytes()).unwrap_err().to_string();
        assert!(msg.contains("... and 6 more"), "{msg}");
        assert_eq!(msg.lines().count(), 1 + MAX_LISTED + 1);
        let msg = parse_angles("7".repeat(100).as_bytes())
            .unwrap_err()
            .to_string();
        assert!(msg.contains(&format!("\"{}...\"", "7".repeat(60))), "{msg}");
    }

    #[test]
    fn csv_has_the_header_and_round_trips_the_table_values() {
        let table = ModelTable::global();
        let mut out = Vec::new();
        write_csv(&mut out, &[0.0, -20.0, 0.01], None, table).unwrap();
        let text = String::from_utf8(out).unwrap();
        let mut lines = text.lines();
        assert_eq!(
            lines.next(),
            Some("angle_deg,alpha,delta_over_l,shortening_over_l")
        );
        assert_eq!(lines.next(), Some("0,0,0,0"));
        let row: Vec<f64> = lines
            .next()
            .unwrap()
            .split(',')
            .map(|v| v.parse().unwrap())
            .collect();
        let e = table.elastica_deg(-20.0).value;
        assert_eq!(
            row,
            vec![-20.0, e.alpha, e.delta_over_l, e.shortening_over_l]
        );
        assert_eq!(text.lines().count(), 4);
    }

    #[test]
    fn force_column_with_a_cantilever() {
        let c = Cantilever::new(400.0, Cantilever::rigidity_from_spring_constant(0.1, 400.0));
        let mut out = Vec::new();
        write_csv(&mut out, &[10.0], Some(&c), ModelTable::global()).unwrap();
        let text = String::from_utf8(out).unwrap();
        assert!(text.starts_with("angle_deg,alpha,delta_over_l,shortening_over_l,force_nN\n"));
        let force: f64 = text
            .lines()
            .nth(1)
            .unwrap()
            .rsplit(',')
            .next()
            .unwrap()
            .parse()
            .unwrap();
        assert_eq!(force, c.force_nn(10.0).value);
    }
}
