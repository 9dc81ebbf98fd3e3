//! CSV input for the headless commands, with errors that name the file, the
//! line and the column.
//!
//! Files must have a header row. Cells are parsed as `f64`; surrounding
//! whitespace is ignored. A missing column, a non-numeric or non-finite cell,
//! a ragged row, an empty file, a column name used twice in the header or
//! more than [`MAX_ROWS`] data rows is an error, never a panic.

use std::path::{Path, PathBuf};
use thiserror::Error;

/// Most data rows a file may have: 2·10⁷ (a 33-minute record at 10 kHz,
/// 160 MB per column in memory). Longer records are split before analysis.
pub const MAX_ROWS: usize = 20_000_000;

/// Errors reading numeric CSV data.
#[derive(Debug, Error)]
pub enum CsvError {
    /// The file could not be opened or read.
    #[error("{path}: cannot read: {source}")]
    Io {
        /// File path.
        path: PathBuf,
        /// Underlying error.
        source: std::io::Error,
    },
    /// The CSV layer failed (bad quoting, invalid UTF-8, …).
    #[error("{path}:{line}: malformed CSV: {msg}")]
    Malformed {
        /// File path.
        path: PathBuf,
        /// 1-based line number.
        line: u64,
        /// Description from the CSV reader.
        msg: String,
    },
    /// The file has no header row.
    #[error("{path}: empty file (a header row naming the columns is required)")]
    Empty {
        /// File path.
        path: PathBuf,
    },
    /// The header has no column with the requested name.
    #[error("{path}: no column named `{name}` (columns are: {available})")]
    MissingColumn {
        /// File path.
        path: PathBuf,
        /// Requested column.
        name: String,
        /// The header's column names, comma separated.
        available: String,
    },
    /// A row has a different number of fields than the header.
    #[error("{path}:{line}: ragged row: {found} field(s), the header has {expected}")]
    Ragged {
        /// File path.
        path: PathBuf,
        /// 1-based line number.
        line: u64,
        /// Fields in the header.
        expected: usize,
        /// Fields in this row.
        found: usize,
    },
    /// A cell is not a finite number.
    #[error("{path}:{line}: column `{column}`: `{cell}` is not a finite number")]
    NotNumeric {
        /// File path.
        path: PathBuf,
        /// 1-based line number.
        line: u64,
        /// Column name.
        column: String,
        /// The cell text.
        cell: String,
    },
    /// The file has more data rows than [`MAX_ROWS`].
    #[error("{path}:{line}: more than {limit} data rows; split the record into shorter files")]
    TooManyRows {
        /// File path.
        path: PathBuf,
        /// 1-based line number of the first row over the limit.
        line: u64,
        /// The limit.
        limit: usize,
    },
    /// Two columns of the header have the same name (which one a command
    /// would read is ambiguous).
    #[error(
        "{path}: the header names column `{name}` twice (columns {first} and {second}); \
         rename one of them"
    )]
    DuplicateColumn {
        /// File path.
        path: PathBuf,
        /// The repeated name.
        name: String,
        /// 1-based position of its first occurrence.
        first: usize,
        /// 1-based position of the repeat.
        second: usize,
    },
    /// The file has a header but no data rows.
    #[error("{path}: no data rows after the header")]
    NoRows {
        /// File path.
        path: PathBuf,
    },
}

/// Numeric columns read from a CSV file, in the order requested.
#[derive(Debug, Clone, PartialEq)]
pub struct Columns {
    /// Names as requested.
    pub names: Vec<String>,
    /// One vector per requested column, all the same length.
    pub data: Vec<Vec<f64>>,
    /// Text columns requested with [`read_table`], in the order requested.
    pub text: Vec<Vec<String>>,
    /// 1-based line number of each data row (for messages about rows).
    pub lines: Vec<u64>,
}

impl Columns {
    /// The column with this name (one that was requested).
    pub fn get(&self, name: &str) -> Option<&[f64]> {
        self.names
            .iter()
            .position(|n| n == name)
            .map(|i| self.data[i].as_slice())
    }
}

/// Read the named columns (required) and the optional ones that exist.
///
/// Every row is checked for the header's field count; only requested columns
/// are parsed. Optional columns absent from the header are skipped silently.
pub fn read_columns(
    path: &Path,
    required: &[&str],
    optional: &[&str],
) -> Result<Columns, CsvError> {
    read_table(path, &[], required, optional)
}

/// Read text columns (kept verbatim, e.g. subject and condition labels) and
/// numeric columns (required and optional).
pub fn read_table(
    path: &Path,
    text: &[&str],
    required: &[&str],
    optional: &[&str],
) -> Result<Columns, CsvError> {
    let file = std::fs::File::open(path).map_err(|source| CsvError::Io {
        path: path.to_owned(),
        source,
    })?;
    read_table_from(file, path, text, required, optional)
}

/// The column names of a CSV file's header row.
pub fn read_header(path: &Path) -> Result<Vec<String>, CsvError> {
    let file = std::fs::File::open(path).map_err(|source| CsvError::Io {
        path: path.to_owned(),
        source,
    })?;
    let mut rdr = csv::ReaderBuilder::new()
        .has_headers(true)
        .flexible(true)
        .trim(csv::Trim::All)
        .comment(Some(b'#'))
        .from_reader(file);
    let headers = rdr.headers().map_err(|e| CsvError::Malformed {
        path: path.to_owned(),
        line: e.position().map(|p| p.line()).unwrap_or(0),
        msg: e.to_string(),
    })?;
    check_unique(headers, path)?;
    Ok(headers.iter().map(str::to_owned).collect())
}

/// Refuses a header that names one column twice ([`CsvError::DuplicateColumn`]).
fn check_unique(headers: &csv::StringRecord, path: &Path) -> Result<(), CsvError> {
    let mut seen = std::collections::HashMap::with_capacity(headers.len());
    for (i, h) in headers.iter().enumerate() {
        if let Some(first) = seen.insert(h, i) {
            return Err(CsvError::DuplicateColumn {
                path: path.to_owned(),
                name: h.to_owned(),
                first: first + 1,
                second: i + 1,
            });
        }
    }
    Ok(())
}

/// As [`read_columns`], from any reader; `path` is used in messages only.
pub fn read_columns_from<R: std::io::Read>(
    reader: R,
    path: &Path,
    required: &[&str],
    optional: &[&str],
) -> Result<Columns, CsvError> {
    read_table_from(reader, path, &[], required, optional)
}

/// As [`read_table`], from any reader; `path` is used in messages only.
pub fn read_table_from<R: std::io::Read>(
    reader: R,
    path: &Path,
    text: &[&str],
    required: &[&str],
    optional: &[&str],
) -> Result<Columns, CsvError> {
    read_bounded(reader, path, text, required, optional, MAX_ROWS)
}

/// [`read_table_from`] with at most `max_rows` data rows.
fn read_bounded<R: std::io::Read>(
    reader: R,
    path: &Path,
    text: &[&str],
    required: &[&str],
    optional: &[&str],
    max_rows: usize,
) -> Result<Columns, CsvError> {
    let mut rdr = csv::ReaderBuilder::new()
        .has_headers(true)
        .flexible(true)
        .trim(csv::Trim::All)
        .comment(Some(b'#'))
        .from_reader(reader);
    let malformed = |e: csv::Error| CsvError::Malformed {
        path: path.to_owned(),
        line: e.position().map(|p| p.line()).unwrap_or(0),
        msg: e.to_string(),
    };
    let headers = rdr.headers().map_err(malformed)?.clone();
    if headers.is_empty() || (headers.len() == 1 && headers[0].is_empty()) {
        return Err(CsvError::Empty {
            path: path.to_owned(),
        });
    }
    check_unique(&headers, path)?;
    let available = headers.iter().collect::<Vec<_>>().join(", ");
    let find = |name: &str| {
        headers
            .iter()
            .position(|h| h == name)
            .ok_or_else(|| CsvError::MissingColumn {
                path: path.to_owned(),
                name: name.to_owned(),
                available: available.clone(),
            })
    };
    let text_idx = text
        .iter()
        .map(|n| find(n))
        .collect::<Result<Vec<_>, _>>()?;
    let mut idx = Vec::new();
    let mut names = Vec::new();
    for &name in required {
        idx.push(find(name)?);
        names.push(name.to_owned());
    }
    for &name in optional {
        if let Some(i) = headers.iter().position(|h| h == name) {
            idx.push(i);
            names.push(name.to_owned());
        }
    }
    let mut data = vec![Vec::new(); idx.len()];
    let mut text_data = vec![Vec::new(); text_idx.len()];
    let mut lines = Vec::new();
    let mut record = csv::StringRecord::new();
    loop {
        match rdr.read_record(&mut record) {
            Ok(false) => break,
            Ok(true) => {}
            Err(e) => return Err(malformed(e)),
        }
        let line = record.position().map(|p| p.line()).unwrap_or(0);
        if lines.len() >= max_rows {
            return Err(CsvError::TooManyRows {
                path: path.to_owned(),
                line,
                limit: max_rows,
            });
        }
        if record.len() != headers.len() {
            return Err(CsvError::Ragged {
                path: path.to_owned(),
                line,
                expected: headers.len(),
                found: record.len(),
            });
        }
        lines.push(line);
        for (k, &i) in text_idx.iter().enumerate() {
            text_data[k].push(record[i].to_owned());
        }
        for (k, &i) in idx.iter().enumerate() {
            let cell = &record[i];
            match cell.parse::<f64>() {
                Ok(v) if v.is_finite() => data[k].push(v),
                _ => {
                    return Err(CsvError::NotNumeric {
                        path: path.to_owned(),
                        line,
                        column: names[k].clone(),
                        cell: cell.to_owned(),
                    });
                }
            }
        }
    }
    if lines.is_empty() {
        return Err(CsvError::NoRows {
            path: path.to_owned(),
        });
    }
    Ok(Columns {
        names,
        data,
        text: text_data,
        lines,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn read(text: &str, req: &[&str], opt: &[&str]) -> Result<Columns, CsvError> {
        read_columns_from(text.as_bytes(), Path::new("t.csv"), req, opt)
    }

    #[test]
    fn reads_named_columns_in_request_order() {
        let c = read("a,b,c\n1,2,3\n4,5,6\n", &["c", "a"], &["w"]).unwrap();
        assert_eq!(c.get("c").unwrap(), &[3.0, 6.0]);
        assert_eq!(c.get("a").unwrap(), &[1.0, 4.0]);
        assert!(c.get("w").is_none());
    }

    #[test]
    fn a_file_over_the_row_limit_is_refused_naming_the_line() {
        let text = "t,x\n0,1\n1,2\n2,3\n";
        let ok = read_bounded(text.as_bytes(), Path::new("r.csv"), &[], &["x"], &[], 3);
        assert_eq!(ok.map(|c| c.data[0].len()).ok(), Some(3));
        let e = read_bounded(text.as_bytes(), Path::new("r.csv"), &[], &["x"], &[], 2)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(e.starts_with("r.csv:4: more than 2 data rows"), "{e}");
    }

    #[test]
    fn errors_name_file_line_and_column() {
        let e = read("a,b\n1,2\n3,x\n", &["b"], &[])
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("t.csv:3") && e.contains("`b`") && e.contains("`x`"),
            "{e}"
        );
        let e = read("a,b\n1,2\n3\n", &["a"], &[]).unwrap_err().to_string();
        assert!(e.contains("t.csv:3") && e.contains("ragged"), "{e}");
        let e = read("a,b\n1,2\n", &["z"], &[]).unwrap_err().to_string();
        assert!(
            e.contains("no column named `z`") && e.contains("a, b"),
            "{e}"
        );
        let e = read("", &["a"], &[]).unwrap_err().to_string();
        assert!(e.contains("empty file"), "{e}");
        let e = read("a\n", &["a"], &[]).unwrap_err().to_string();
        assert!(e.contains("no data rows"), "{e}");
        let e = read("a\nNaN\n", &["a"], &[]).unwrap_err().to_string();
        assert!(e.contains("not a finite number"), "{e}");
    }

    /// A header naming a column twice is refused, naming the column and
    /// both positions, whichever column is asked for.
    #[test]
    fn a_repeated_column_name_is_refused_naming_it() {
        for req in ["x", "y"] {
            let e = read("x,y,x\n1,2,3\n", &[req], &[]).unwrap_err().to_string();
            assert_eq!(
                e,
                "t.csv: the header names column `x` twice (columns 1 and 3); rename one of them"
            );
        }
    }
}
