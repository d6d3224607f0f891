//! A comparison row's change and regression, and the JUnit file's escaping.

use super::compare::Row;

fn row(base: f64, new: f64) -> Row {
    Row {
        entry: "e".into(),
        metric: "ate".into(),
        statistic: "rmse".into(),
        base,
        new,
    }
}

#[test]
fn a_row_regresses_only_when_worse_beyond_the_tolerance() {
    assert!((row(0.02, 0.021).change_pct() - 5.0).abs() < 1e-9);
    assert!(!row(0.02, 0.0209).regressed(5.0) && row(0.02, 0.0209).regressed(4.4));
    // Better is never a regression; a new NaN always is; from 0 any growth is.
    assert!(!row(0.02, 0.01).regressed(0.0));
    assert!(row(0.02, f64::NAN).regressed(1000.0));
    assert!(row(0.0, 0.001).regressed(1000.0) && !row(0.0, 0.0).regressed(0.0));
}

#[test]
fn names_are_escaped_in_the_junit_file() {
    let r = super::SuiteResult {
        suite: "s<1>.toml".into(),
        entries: Vec::new(),
    };
    let x = r.junit_xml();
    assert!(
        x.contains("name=\"s&lt;1&gt;.toml\"") && x.contains("tests=\"0\""),
        "{x}"
    );
}
