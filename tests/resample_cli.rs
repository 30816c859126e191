//! End-to-end checks of `irlgrid resample`: the JSON shape other programs
//! rely on, and line-precise errors for bad subject files.

use std::process::Command;

use shared::analysis::{subjects_to_csv, SubjectPath};
use shared::test_support::StandUp;

fn resample(csv: &str) -> std::process::Output {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("subjects.csv");
    std::fs::write(&path, csv).unwrap();
    Command::new(env!("CARGO_BIN_EXE_irlgrid"))
        .args(["resample", "--input", path.to_str().unwrap()])
        .output()
        .unwrap()
}

/// A subject's rise bulging forward by `bulge` (m), sampled at 200 Hz.
fn arc(subject: &str, bulge: f64) -> SubjectPath {
    StandUp::new(bulge)
        .sampled(101, 0.5)
        .rising(0.6, 0.38)
        .subject(subject)
}

#[test]
fn prints_sixty_points_and_area_per_subject() {
    let csv = subjects_to_csv(&[arc("s1", 0.05), arc("s2", -0.02)]);
    let out = resample(&csv);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let doc: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let items = doc.as_array().unwrap();
    assert_eq!(items.len(), 2);
    for (item, name) in items.iter().zip(["s1", "s2"]) {
        let obj = item.as_object().unwrap();
        let mut keys: Vec<&str> = obj.keys().map(String::as_str).collect();
        keys.sort();
        assert_eq!(keys, ["area", "subject", "x", "z"]);
        assert_eq!(obj["subject"], name);
        assert_eq!(obj["x"].as_array().unwrap().len(), 60);
        let z = obj["z"].as_array().unwrap();
        assert_eq!(z.len(), 60);
        assert!(z[0].as_f64().unwrap().abs() < 1e-12);
        assert!((z[59].as_f64().unwrap() - 1.0).abs() < 1e-12);
    }
    // Forward bulge gives a positive area, backward a negative one (docs/science.md#area).
    assert!(items[0]["area"].as_f64().unwrap() > 0.0);
    assert!(items[1]["area"].as_f64().unwrap() < 0.0);
}

#[test]
fn bad_subject_file_names_the_line_and_exits_2() {
    let out = resample("subject,time,x,z\ns1,0,0,0\ns1,0.1,0,nan\n");
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("subjects.csv") && err.contains("line 3"),
        "{err}"
    );
    let out = resample("subject,t,x,z\n");
    assert_eq!(out.status.code(), Some(2));
}
