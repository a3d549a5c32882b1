//! End-to-end tests of `nanoforce model`: the real binary, fed good and bad input on
//! standard input, checked against the library's exact elastica.
use std::io::Write;
use std::path::Path;
use std::process::{Command, Output, Stdio};

use nanoforce::config::Config;
use nanoforce::model::{exact, ModelTable};

/// Runs `nanoforce model ARGS` with `input` on standard input.
fn run_model(args: &[&str], input: &[u8]) -> Output {
    let mut child = Command::new(env!("CARGO_BIN_EXE_nanoforce"))
        .arg("model")
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("the nanoforce binary runs");
    // A child that exits early (bad config) may close its stdin: ignore a broken pipe.
    let _ = child.stdin.take().expect("piped stdin").write_all(input);
    child
        .wait_with_output()
        .expect("the nanoforce binary finishes")
}

fn stdout(output: &Output) -> String {
    String::from_utf8(output.stdout.clone()).expect("UTF-8 output")
}

fn stderr(output: &Output) -> String {
    String::from_utf8_lossy(&output.stderr).into_owned()
}

fn rows(text: &str) -> Vec<Vec<f64>> {
    text.lines()
        .skip(1)
        .map(|l| {
            l.split(',')
                .map(|v| v.parse().expect("numeric CSV"))
                .collect()
        })
        .collect()
}

fn sample_config() -> &'static Path {
    Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/samples/mixed/probe.toml"
    ))
}

#[test]
fn angles_in_model_out() {
    let angles = [0.0, 0.001, -0.5, 5.0, 20.0, -45.0, 85.0, 89.0, -89.0];
    let input: String = angles.iter().map(|a| format!("{a}\n")).collect();
    let output = run_model(&[], input.as_bytes());
    assert!(output.status.success(), "{}", stderr(&output));
    let text = stdout(&output);
    assert!(
        text.starts_with("angle_deg,alpha,delta_over_l,shortening_over_l\n"),
        "{text}"
    );
    let rows = rows(&text);
    assert_eq!(rows.len(), angles.len());
    for (row, &angle) in rows.iter().zip(&angles) {
        assert_eq!(row.len(), 4);
        assert_eq!(row[0], angle);
        let e = exact(angle.to_radians()).expect("in range");
        let want = [e.alpha, e.delta_over_l, e.shortening_over_l];
        for (got, want) in row[1..].iter().zip(want) {
            let err = if want == 0.0 {
                got.abs()
            } else {
                (got / want - 1.0).abs()
            };
            assert!(err < 1e-12, "{angle} deg: {got} vs {want}");
        }
    }
}

#[test]
fn values_round_trip_the_shared_table_exactly() {
    let output = run_model(&[], b"12.345\n-0.01\n");
    assert!(output.status.success(), "{}", stderr(&output));
    let table = ModelTable::global();
    for row in rows(&stdout(&output)) {
        let e = table.elastica_deg(row[0]).value;
        assert_eq!(row[1..], [e.alpha, e.delta_over_l, e.shortening_over_l]);
    }
}

#[test]
fn whitespace_and_blank_lines_are_ignored() {
    let output = run_model(&[], b"\n  1.5\t\r\n\n-3\n   \n");
    assert!(output.status.success(), "{}", stderr(&output));
    let firsts: Vec<f64> = rows(&stdout(&output)).iter().map(|r| r[0]).collect();
    assert_eq!(firsts, vec![1.5, -3.0]);
    let empty = run_model(&[], b"");
    assert!(empty.status.success());
    assert_eq!(
        stdout(&empty),
        "angle_deg,alpha,delta_over_l,shortening_over_l\n"
    );
}

#[test]
fn config_adds_the_force_in_nanonewtons() {
    let config = sample_config();
    let output = run_model(
        &["--config", config.to_str().expect("UTF-8 path")],
        b"-10\n2.5\n",
    );
    assert!(output.status.success(), "{}", stderr(&output));
    let text = stdout(&output);
    assert!(text.starts_with("angle_deg,alpha,delta_over_l,shortening_over_l,force_nN\n"));
    let scale_nn = Config::load(config).expect("sample config").probes[0]
        .cantilever
        .expect("the sample has [cantilever]")
        .force_scale_nn();
    // Sample `mixed`: EI / L^2 = k L / 3 with k = 0.06 N/m, L = 434.675 um.
    assert!((scale_nn / (0.06 * 434.675e-6 / 3.0 * 1e9) - 1.0).abs() < 1e-14);
    for row in rows(&text) {
        let alpha = exact(row[0].to_radians()).expect("in range").alpha;
        assert!((row[4] / (alpha * scale_nn) - 1.0).abs() < 1e-12, "{row:?}");
        assert_eq!(row[4].signum(), row[0].signum());
    }
}

#[test]
fn a_bad_line_is_an_error_naming_it_and_nothing_is_written() {
    let output = run_model(&[], b"5\n10\nfive\n20\n");
    assert!(!output.status.success());
    assert_eq!(output.stdout, b"");
    let err = stderr(&output);
    assert!(err.contains("line 3") && err.contains("\"five\""), "{err}");
    assert!(
        err.contains("not a number") && err.contains("nothing was written"),
        "{err}"
    );
}

#[test]
fn out_of_range_and_non_finite_angles_are_errors() {
    let output = run_model(&[], b"89\n89.01\n\n-120\ninf\nNaN\n");
    assert!(!output.status.success());
    assert_eq!(output.stdout, b"");
    let err = stderr(&output);
    assert!(err.contains("4 bad input lines"), "{err}");
    assert!(err.contains("line 2: \"89.01\" is out of range"), "{err}");
    assert!(err.contains("line 4: \"-120\" is out of range"), "{err}");
    assert!(
        err.contains("line 5: \"inf\" is not a finite number"),
        "{err}"
    );
    assert!(
        err.contains("line 6: \"NaN\" is not a finite number"),
        "{err}"
    );
    assert!(err.contains("|angle| <= 89 degrees"), "{err}");
}

#[test]
fn a_bad_config_names_file_key_and_value() {
    let dir = tempfile::tempdir().expect("temporary directory");
    let path = dir.path().join("probe.toml");
    std::fs::write(
        &path,
        "[cantilever]\nlength_um = 450\nspring_constant_n_per_m = -0.2\n",
    )
    .expect("write config");
    let output = run_model(&["--config", path.to_str().expect("UTF-8 path")], b"5\n");
    assert!(!output.status.success());
    assert_eq!(output.stdout, b"");
    let err = stderr(&output);
    let file = path.display().to_string();
    assert!(err.contains(&file), "{err}");
    assert!(err.contains("cantilever.spring_constant_n_per_m"), "{err}");
    assert!(err.contains("= -0.2 is out of range"), "{err}");

    let missing = dir.path().join("absent.toml");
    let output = run_model(&["--config", missing.to_str().expect("UTF-8 path")], b"5\n");
    assert!(!output.status.success());
    assert!(
        stderr(&output).contains("absent.toml: cannot read"),
        "{}",
        stderr(&output)
    );
}

#[test]
fn help_reads_like_a_manual_page() {
    let output = Command::new(env!("CARGO_BIN_EXE_nanoforce"))
        .args(["model", "--help"])
        .output()
        .expect("the nanoforce binary runs");
    assert!(output.status.success());
    let help = stdout(&output);
    for needle in [
        "alpha = F L^2 / EI",
        "INPUT",
        "blank lines are skipped",
        "nothing at all",
        "OUTPUT",
        "angle_deg,alpha,delta_over_l,shortening_over_l",
        "force_nN",
        "nanonewtons",
        "EXAMPLES",
        "| nanoforce model",
        "EXIT STATUS",
    ] {
        assert!(help.contains(needle), "help lacks {needle:?}:\n{help}");
    }
    // The example's output is what the command prints.
    let example = run_model(&[], b"5\n-20\n");
    for line in stdout(&example).lines() {
        assert!(
            help.contains(&format!("  {line}\n")),
            "example line {line:?} is stale"
        );
    }
}
