//! What a suite writes: results.json (versioned), summary.md (short enough for a pull
//! request), junit.xml (one test case per entry and metric) and the HTML report.

use super::{Detail, SuiteResult, SUITE_SCHEMA, SUITE_SCHEMA_VERSION};
use serde_json::{json, Value};
use std::fmt::Write as _;
use std::path::Path;
use stride_eval::report::Report;
use stride_output::fs::write_atomic;

/// A statistic of a single result's JSON (NaN when missing).
fn stat(result: &Value, key: &str) -> f64 {
    result.get(key).and_then(Value::as_f64).unwrap_or(f64::NAN)
}

/// Escapes text for XML attributes and content.
fn xml(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
        .replace('\'', "&apos;")
}

impl SuiteResult {
    /// results.json: the schema and its version, and every entry with its result, limits,
    /// outcome and failures.
    pub fn to_json(&self) -> Value {
        let entries: Vec<Value> = self
            .entries
            .iter()
            .map(|e| {
                let mut v = serde_json::to_value(e).unwrap_or(Value::Null);
                v["passed"] = json!(e.passed());
                v["failures"] = json!(e.failures());
                v
            })
            .collect();
        json!({
            "schema": SUITE_SCHEMA,
            "schema_version": SUITE_SCHEMA_VERSION,
            "suite": self.suite.display().to_string(),
            "entries_passed": self.entries.len() - self.failed(),
            "entries_failed": self.failed(),
            "entries": entries,
        })
    }

    /// A Markdown summary: one line of outcome and one table row per entry.
    pub fn markdown(&self) -> String {
        let failed = self.failed();
        let mut md = format!(
            "### stride eval suite: {} of {} entries passed{}\n\n",
            self.entries.len() - failed,
            self.entries.len(),
            if failed > 0 { " (FAILED)" } else { "" }
        );
        md.push_str("| entry | metric | rmse (m) | mean (m) | max (m) | rot rmse (deg) | pairs | result |\n");
        md.push_str("|---|---|---:|---:|---:|---:|---:|---|\n");
        for e in &self.entries {
            let r = &e.result;
            let outcome = if e.passed() {
                if e.limits.any() { "pass" } else { "no limits" }.to_owned()
            } else {
                format!("**FAIL**: {}", e.failures().join("; "))
            };
            let _ = writeln!(
                md,
                "| {} | {} ({}) | {:.6} | {:.6} | {:.6} | {:.4} | {} | {} |",
                e.name.replace('|', "\\|"),
                e.metric.to_uppercase(),
                r.get("align").and_then(Value::as_str).unwrap_or("?"),
                stat(r, "rmse"),
                stat(r, "mean"),
                stat(r, "max"),
                stat(r, "rot_deg_rmse"),
                r.get("count").and_then(Value::as_u64).unwrap_or(0),
                outcome
            );
        }
        md
    }

    /// JUnit XML: one test suite, one test case per entry and metric, a failure element
    /// naming every limit exceeded, the statistics in the case's output.
    pub fn junit_xml(&self) -> String {
        let mut x = String::from("<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n");
        let _ = writeln!(
            x,
            "<testsuites name=\"stride eval suite\" tests=\"{n}\" failures=\"{f}\" errors=\"0\">\n  <testsuite name=\"{s}\" tests=\"{n}\" failures=\"{f}\" errors=\"0\" skipped=\"0\">",
            n = self.entries.len(),
            f = self.failed(),
            s = xml(&self.suite.display().to_string())
        );
        for e in &self.entries {
            let r = &e.result;
            let _ = writeln!(
                x,
                "    <testcase classname=\"stride.eval.{}\" name=\"{}\" time=\"0\">",
                xml(&e.metric),
                xml(&e.name)
            );
            if !e.passed() {
                let all = e.failures().join("; ");
                let _ = writeln!(
                    x,
                    "      <failure message=\"{}\" type=\"limit exceeded\">{}</failure>",
                    xml(&all),
                    xml(&all)
                );
            }
            let _ = writeln!(
                x,
                "      <system-out>{} rmse {:.6} m, mean {:.6} m, max {:.6} m, rotation rmse {:.4} deg over {} pairs</system-out>\n    </testcase>",
                xml(&e.metric.to_uppercase()),
                stat(r, "rmse"),
                stat(r, "mean"),
                stat(r, "max"),
                stat(r, "rot_deg_rmse"),
                r.get("count").and_then(Value::as_u64).unwrap_or(0)
            );
        }
        x.push_str("  </testsuite>\n</testsuites>\n");
        x
    }

    /// The HTML report: the summary table, then each entry's statistics and charts.
    pub fn report(&self) -> Report {
        let mut rep = Report::new("stride eval suite");
        rep.paragraph(format!(
            "Suite {}: {} of {} entries passed.",
            self.suite.display(),
            self.entries.len() - self.failed(),
            self.entries.len()
        ));
        let rows = self
            .entries
            .iter()
            .map(|e| {
                vec![
                    e.name.clone(),
                    e.metric.to_uppercase(),
                    format!("{:.6}", stat(&e.result, "rmse")),
                    format!("{:.4}", stat(&e.result, "rot_deg_rmse")),
                    if e.passed() {
                        "pass".to_owned()
                    } else {
                        format!("FAIL: {}", e.failures().join("; "))
                    },
                ]
            })
            .collect();
        rep.table(
            &["entry", "metric", "rmse (m)", "rot rmse (deg)", "result"],
            rows,
        );
        for (i, e) in self.entries.iter().enumerate() {
            rep.heading(format!("{} ({})", e.name, e.metric.to_uppercase()));
            rep.paragraph(format!("Ground truth {}, estimate {}.", e.gt, e.est));
            let figure = format!("entry{i}_{}", e.metric);
            match &e.detail {
                Some(Detail::Ate(r)) => r.add_to_report(&mut rep, &figure),
                Some(Detail::Rpe(r)) => r.add_to_report(&mut rep, &figure),
                None => {}
            }
        }
        rep
    }

    /// Writes results.json, summary.md, junit.xml and the report into `dir` (created if
    /// missing; each file atomically).
    pub fn write(&self, dir: &Path) -> std::io::Result<()> {
        std::fs::create_dir_all(dir)?;
        let json = serde_json::to_string_pretty(&self.to_json()).map_err(std::io::Error::other)?;
        write_atomic(&dir.join("results.json"), json.as_bytes())?;
        write_atomic(&dir.join("summary.md"), self.markdown().as_bytes())?;
        write_atomic(&dir.join("junit.xml"), self.junit_xml().as_bytes())?;
        self.report().write(dir)?;
        Ok(())
    }
}
