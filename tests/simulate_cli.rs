//! End-to-end checks of `irlgrid simulate`: the fixed output format, the
//! golden run of the shipped example, and every bad-input class.

use std::process::{Command, Output};

fn irlgrid(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_irlgrid"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("irlgrid runs")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// The golden file was produced by this simulator when the equations of
/// motion were checked against the independent Euler-Lagrange test; it pins
/// the output format and guards against silent numerical changes.
#[test]
fn example_without_termination_matches_golden_output() {
    let out = irlgrid(&[
        "simulate",
        "--actions",
        "examples/pd_rise.csv",
        "--no-termination",
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    let stdout = String::from_utf8(out.stdout).unwrap();
    let golden = std::fs::read_to_string("tests/golden/pd_rise_no_termination.csv").unwrap();
    assert_eq!(stdout, golden);
    let rows = std::fs::read_to_string("examples/pd_rise.csv")
        .unwrap()
        .lines()
        .count()
        - 1;
    let mut lines = stdout.lines();
    assert_eq!(lines.next(), Some("t,q1,q2,q3,dq1,dq2,dq3,x_com,z_com"));
    assert!(lines.next().unwrap().starts_with("0,0.5,-1.85,2.06,0,0,0,"));
    assert_eq!(
        stdout.lines().count(),
        1 + 1 + rows,
        "header, t=0, one row per action"
    );
}

#[test]
fn with_termination_stops_at_the_fall_and_reports_it() {
    let out = irlgrid(&["simulate", "--actions", "examples/pd_rise.csv", "--w1", "2"]);
    assert!(out.status.success());
    let err = stderr(&out);
    assert!(err.contains("outcome: fail after 28 steps"), "{err}");
    assert!(err.contains("w1 = 2"), "{err}");
    assert_eq!(
        String::from_utf8(out.stdout).unwrap().lines().count(),
        1 + 1 + 28
    );
}

#[test]
fn initial_state_and_gain_flags_are_used() {
    let dir = tempfile::tempdir().unwrap();
    let actions = dir.path().join("zero.csv");
    std::fs::write(&actions, "a1,a2,a3\n0,0,0\n0,0,0\n").unwrap();
    let out = irlgrid(&[
        "simulate",
        "--actions",
        actions.to_str().unwrap(),
        "--initial",
        "0,0,0,0,0,0",
        "--perturbation-gain",
        "0",
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    let stdout = String::from_utf8(out.stdout.clone()).unwrap();
    // Upright with zero torque is an equilibrium, and standing still is a
    // success after the first step: 1000 - 10 * 1.
    assert!(stdout
        .lines()
        .nth(1)
        .unwrap()
        .starts_with("0,0,0,0,0,0,0,0,0.98239"));
    assert!(stdout
        .lines()
        .nth(2)
        .unwrap()
        .starts_with("0.05,0,0,0,0,0,0,0,0.98239"));
    assert!(stderr(&out).contains("outcome: success after 1 steps, return 990"));
}

/// Runs `simulate` on a file holding `contents` (or no file at all) and
/// returns the exit status and stderr, which must be exactly one line.
fn bad_input(contents: Option<&str>, extra: &[&str]) -> (i32, String) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("actions.csv");
    if let Some(c) = contents {
        std::fs::write(&path, c).unwrap();
    }
    let p = path.to_str().unwrap().to_string();
    let mut args = vec!["simulate", "--actions", p.as_str()];
    args.extend_from_slice(extra);
    let out = irlgrid(&args);
    let err = stderr(&out);
    assert_eq!(err.trim().lines().count(), 1, "one-line error: {err}");
    (out.status.code().unwrap(), err)
}

#[test]
fn missing_file_is_a_one_line_error_with_status_2() {
    let (code, err) = bad_input(None, &[]);
    assert_eq!(code, 2);
    assert!(
        err.contains("actions.csv") && err.contains("cannot read"),
        "{err}"
    );
}

#[test]
fn wrong_header_is_reported_on_line_1() {
    let (code, err) = bad_input(Some("x,y,z\n0,0,0\n"), &[]);
    assert_eq!(code, 2);
    assert!(
        err.contains("actions.csv:1:") && err.contains("a1,a2,a3"),
        "{err}"
    );
}

#[test]
fn non_finite_number_names_line_and_column() {
    let (code, err) = bad_input(Some("a1,a2,a3\n0,0,0\n0,NaN,0\n"), &[]);
    assert_eq!(code, 2);
    assert!(
        err.contains("actions.csv:3:") && err.contains("a2"),
        "{err}"
    );
    let (code, err) = bad_input(Some("a1,a2,a3\n0,0,inf\n"), &[]);
    assert_eq!(code, 2);
    assert!(
        err.contains("actions.csv:2:") && err.contains("a3"),
        "{err}"
    );
    let (code, err) = bad_input(Some("a1,a2,a3\n0,abc,0\n"), &[]);
    assert_eq!(code, 2);
    assert!(err.contains("actions.csv:2:"), "{err}");
}

#[test]
fn wrong_column_count_names_the_line() {
    let (code, err) = bad_input(Some("a1,a2,a3\n0,0,0\n0,0\n"), &[]);
    assert_eq!(code, 2);
    assert!(
        err.contains("actions.csv:3:") && err.contains("3 columns"),
        "{err}"
    );
}

#[test]
fn bad_flags_are_rejected_with_status_2() {
    let (code, err) = bad_input(Some("a1,a2,a3\n0,0,0\n"), &["--initial", "1,2,3"]);
    assert_eq!(code, 2);
    assert!(err.contains("--initial"), "{err}");
    let (code, err) = bad_input(Some("a1,a2,a3\n0,0,0\n"), &["--perturbation-gain", "-5"]);
    assert_eq!(code, 2);
    assert!(err.contains("perturbation_gain"), "{err}");
}
