//! Reading the whitespace-separated text files of the TUM format.
//!
//! Rules shared by `rgb.txt`, `depth.txt`, `groundtruth.txt` and trajectory files, as the TUM
//! tools read them: lines starting with `#` and blank lines are skipped; fields are separated
//! by spaces, tabs or commas; a UTF-8 byte-order mark is ignored; Windows line ends are fine.

use crate::error::DatasetError;
use std::path::Path;

/// A data line of a text file: its one-based line number and its trimmed text.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DataLine<'a> {
    /// One-based line number in the file.
    pub line: usize,
    /// The line without leading/trailing whitespace.
    pub text: &'a str,
}

impl<'a> DataLine<'a> {
    /// The fields, separators removed (no allocation).
    pub fn fields(&self) -> impl Iterator<Item = &'a str> {
        self.text.split([' ', '\t', ',']).filter(|f| !f.is_empty())
    }

    /// The first `N` fields if the line has exactly `N`; otherwise the count it has.
    pub fn exact_fields<const N: usize>(&self) -> Result<[&'a str; N], usize> {
        let mut out = [""; N];
        let mut n = 0;
        for f in self.fields() {
            if let Some(slot) = out.get_mut(n) {
                *slot = f;
            }
            n += 1;
        }
        if n == N {
            Ok(out)
        } else {
            Err(n)
        }
    }
}

/// Splits text into data lines (comments and blank lines dropped).
pub fn data_lines(text: &str) -> impl Iterator<Item = DataLine<'_>> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    text.lines().enumerate().filter_map(|(i, raw)| {
        let trimmed = raw.trim();
        if trimmed.is_empty() || trimmed.starts_with('#') {
            return None;
        }
        Some(DataLine {
            line: i + 1,
            text: trimmed,
        })
    })
}

/// Reads a whole text file, naming it in the error.
pub fn read_text(path: &Path) -> Result<String, DatasetError> {
    let bytes = std::fs::read(path).map_err(|e| DatasetError::io(path, e))?;
    String::from_utf8(bytes).map_err(|e| {
        DatasetError::invalid(
            path,
            format!(
                "not UTF-8 text (invalid byte at offset {})",
                e.utf8_error().valid_up_to()
            ),
        )
    })
}

/// Parses a finite number, naming the file, line and field on failure.
pub fn parse_finite(
    path: &Path,
    line: usize,
    name: &str,
    field: &str,
) -> Result<f64, DatasetError> {
    let v: f64 = field.parse().map_err(|_| {
        DatasetError::parse(path, line, format!("{name} '{field}' is not a number"))
    })?;
    if !v.is_finite() {
        return Err(DatasetError::parse(
            path,
            line,
            format!("{name} is {field}: only finite numbers are allowed"),
        ));
    }
    Ok(v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn splits_like_the_tum_tools() {
        let text = "\u{feff}# comment\n\n1.0 2,3\t4\r\n  # indented comment\n5 6 \n";
        let lines: Vec<_> = data_lines(text).collect();
        assert_eq!(lines.len(), 2);
        assert_eq!(lines[0].line, 3);
        assert_eq!(
            lines[0].fields().collect::<Vec<_>>(),
            vec!["1.0", "2", "3", "4"]
        );
        assert_eq!(lines[0].exact_fields::<4>(), Ok(["1.0", "2", "3", "4"]));
        assert_eq!(lines[0].exact_fields::<3>(), Err(4));
        assert_eq!(lines[1].line, 5);
        assert_eq!(lines[1].exact_fields::<2>(), Ok(["5", "6"]));
    }

    #[test]
    fn numbers_must_be_finite() {
        let p = Path::new("f.txt");
        assert_eq!(parse_finite(p, 1, "t", "1.5").unwrap(), 1.5);
        let e = parse_finite(p, 7, "tx", "abc").unwrap_err().to_string();
        assert_eq!(e, "f.txt:7: tx 'abc' is not a number");
        let e = parse_finite(p, 2, "qw", "nan").unwrap_err().to_string();
        assert!(e.starts_with("f.txt:2: qw is nan"), "{e}");
        assert!(parse_finite(p, 2, "qw", "-inf").is_err());
    }
}
