//! The one CSV reader for files a researcher hands to kilotouch (a record
//! for `psd` / `tfest` / `frf` / `tweezer calibrate`, a long table for
//! `stats`, a pilot for `study power`), with errors that name the file, the
//! line and the column.
//!
//! Parsing (quoting, escaped quotes, a UTF-8 byte-order mark, comments) is
//! the well-kept `csv` crate's; this module adds what it does not do: the
//! bounds, exact line numbers whatever the line ends (the crate's record
//! position is one line early after a CRLF, a comment or a blank line), the
//! header checks, typed cells and messages in a researcher's words.
//!
//! Format: a header row naming the columns, then one row per observation.
//! Whitespace around a cell is ignored; lines starting with `#` are comments
//! (a recording's metadata). Every row must have the header's number of
//! fields. A cell is read as text ([`Row::text`]), as a finite number
//! ([`Row::number`]) or as a value that may be missing ([`Row::value`]: an
//! empty cell, `NA` or `NaN` in any case is missing; `inf` is refused).
//!
//! Bounds: at most [`MAX_ROWS`] data rows and [`MAX_BYTES`] bytes per file
//! (a caller may set lower ones with [`Limits`]); a larger file is refused
//! naming the bound, never truncated. An empty file, a header without data
//! rows, a column name used twice, a ragged row, malformed quoting or
//! invalid UTF-8 is an error, never a panic.

use std::io::Read;
use std::path::{Path, PathBuf};
use thiserror::Error;

/// Most data rows a file may have: 2·10⁷ (a 33-minute record at 10 kHz,
/// 160 MB per numeric column in memory). Longer records are split before
/// analysis.
pub const MAX_ROWS: usize = 20_000_000;

/// Most bytes a file may have: 4 GiB (2·10⁷ rows of about 200 characters).
pub const MAX_BYTES: u64 = 4 << 30;

/// The bounds a [`CsvReader`] enforces.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Limits {
    /// Most data rows (comments and the header not counted).
    pub rows: usize,
    /// Most bytes of the whole file.
    pub bytes: u64,
}

impl Default for Limits {
    /// [`MAX_ROWS`] and [`MAX_BYTES`].
    fn default() -> Self {
        Self {
            rows: MAX_ROWS,
            bytes: MAX_BYTES,
        }
    }
}

/// Errors reading a CSV file; every one names the file, and the line and
/// column where there is one.
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
    #[error("{path}, line {line}: malformed CSV: {msg}")]
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
    #[error("{path}, line {line}: ragged row: {found} field(s), the header has {expected}")]
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
    #[error(
        "{path}, line {line}, column `{column}`: `{cell}` is not a finite number{}",
        if *missing_ok { " (leave the cell empty or write NA for a missing value)" } else { "" }
    )]
    NotNumeric {
        /// File path.
        path: PathBuf,
        /// 1-based line number.
        line: u64,
        /// Column name.
        column: String,
        /// The cell text.
        cell: String,
        /// Whether the column may have missing values ([`Row::value`]).
        missing_ok: bool,
    },
    /// A cell holds text its column does not allow (a caller's own rule).
    #[error("{path}, line {line}, column `{column}`: {message}")]
    Cell {
        /// File path.
        path: PathBuf,
        /// 1-based line number.
        line: u64,
        /// Column name.
        column: String,
        /// What is wrong, in the caller's words.
        message: String,
    },
    /// The file has more data rows than its bound ([`Limits::rows`]).
    #[error(
        "{path}, line {line}: more than {limit} data rows (the most this file may have); \
         split it into shorter files"
    )]
    TooManyRows {
        /// File path.
        path: PathBuf,
        /// 1-based line number of the first row over the limit.
        line: u64,
        /// The limit.
        limit: usize,
    },
    /// The file is longer than its bound ([`Limits::bytes`]).
    #[error(
        "{path}: more than {limit} bytes (the most this file may have); \
         split it into shorter files"
    )]
    TooLarge {
        /// File path.
        path: PathBuf,
        /// The limit in bytes.
        limit: u64,
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

/// The marker a [`Lines`] reader's error carries past the `csv` crate.
#[derive(Debug)]
struct OverByteLimit;

impl std::fmt::Display for OverByteLimit {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("over the byte limit")
    }
}

impl std::error::Error for OverByteLimit {}

/// The raw bytes as the `csv` crate is given them: every line end (CRLF,
/// LF or a lone CR) as one LF, and an LF after the last line. With that,
/// the line of a record is exact, which the crate's own record position is
/// not after a CRLF, a comment or a blank line. Fails with
/// [`OverByteLimit`] once more than `left` raw bytes are asked of it.
#[derive(Debug)]
struct Lines<R> {
    inner: R,
    left: u64,
    after_cr: bool,
    last: Option<u8>,
}

impl<R: Read> Lines<R> {
    fn new(inner: R, limit: u64) -> Self {
        Self {
            inner,
            left: limit,
            after_cr: false,
            last: None,
        }
    }

    /// Raw bytes, at most `left` of them.
    fn read_raw(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        if self.left == 0 {
            let mut probe = [0_u8; 1];
            return match self.inner.read(&mut probe)? {
                0 => Ok(0),
                _ => Err(std::io::Error::other(OverByteLimit)),
            };
        }
        let want = usize::try_from(self.left).map_or(buf.len(), |l| l.min(buf.len()));
        let n = self.inner.read(&mut buf[..want])?;
        self.left -= n as u64;
        Ok(n)
    }
}

impl<R: Read> Read for Lines<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        if buf.is_empty() {
            return Ok(0);
        }
        loop {
            let n = self.read_raw(buf)?;
            if n == 0 {
                if self.last.is_some_and(|b| b != b'\n') {
                    self.last = Some(b'\n');
                    buf[0] = b'\n';
                    return Ok(1);
                }
                return Ok(0);
            }
            let mut w = 0;
            for r in 0..n {
                let b = buf[r];
                let after_cr = std::mem::replace(&mut self.after_cr, b == b'\r');
                if after_cr && b == b'\n' {
                    continue;
                }
                buf[w] = if b == b'\r' { b'\n' } else { b };
                w += 1;
            }
            if w > 0 {
                self.last = Some(buf[w - 1]);
                return Ok(w);
            }
        }
    }
}

/// A header row: the column names (trimmed), all different.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Header {
    path: PathBuf,
    names: Vec<String>,
}

impl Header {
    /// The column names, in file order.
    pub fn names(&self) -> &[String] {
        &self.names
    }

    /// Index of the column with this name, if there is one.
    pub fn position(&self, name: &str) -> Option<usize> {
        self.names.iter().position(|n| n == name)
    }

    /// Index of the column with this name.
    ///
    /// # Errors
    /// [`CsvError::MissingColumn`], listing the columns there are.
    pub fn require(&self, name: &str) -> Result<usize, CsvError> {
        self.position(name).ok_or_else(|| CsvError::MissingColumn {
            path: self.path.clone(),
            name: name.to_owned(),
            available: self.names.join(", "),
        })
    }
}

/// One data row.
#[derive(Debug, Clone, Copy)]
pub struct Row<'a> {
    header: &'a Header,
    record: &'a csv::StringRecord,
    line: u64,
}

impl Row<'_> {
    /// 1-based line number in the file where the row starts (comment and
    /// blank lines counted; the header is line 1 when nothing precedes it).
    pub fn line(&self) -> u64 {
        self.line
    }

    /// Column `col`'s cell as text, without surrounding whitespace.
    pub fn text(&self, col: usize) -> &str {
        self.record.get(col).map_or("", str::trim)
    }

    /// Column `col`'s cell as a finite number.
    ///
    /// # Errors
    /// [`CsvError::NotNumeric`] for anything else (empty, NA, NaN, inf, text).
    pub fn number(&self, col: usize) -> Result<f64, CsvError> {
        let cell = self.text(col);
        match cell.parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(v),
            _ => Err(self.not_numeric(col, false)),
        }
    }

    /// Column `col`'s cell as a value that may be missing: `None` for an
    /// empty cell, `NA` or `NaN` (any case).
    ///
    /// # Errors
    /// [`CsvError::NotNumeric`] for text or an infinite number.
    pub fn value(&self, col: usize) -> Result<Option<f64>, CsvError> {
        let cell = self.text(col);
        if cell.is_empty() || cell.eq_ignore_ascii_case("na") || cell.eq_ignore_ascii_case("nan") {
            return Ok(None);
        }
        match cell.parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(Some(v)),
            _ => Err(self.not_numeric(col, true)),
        }
    }

    /// An error about column `col`'s cell of this row, in the caller's
    /// words ([`CsvError::Cell`]).
    pub fn error(&self, col: usize, message: impl Into<String>) -> CsvError {
        CsvError::Cell {
            path: self.header.path.clone(),
            line: self.line,
            column: self.column_name(col),
            message: message.into(),
        }
    }

    fn column_name(&self, col: usize) -> String {
        self.header.names.get(col).cloned().unwrap_or_default()
    }

    fn not_numeric(&self, col: usize, missing_ok: bool) -> CsvError {
        CsvError::NotNumeric {
            path: self.header.path.clone(),
            line: self.line,
            column: self.column_name(col),
            cell: self.text(col).to_owned(),
            missing_ok,
        }
    }
}

/// A bounded, streaming reader of a CSV file with a header row.
#[derive(Debug)]
pub struct CsvReader<R> {
    reader: csv::Reader<Lines<R>>,
    header: Header,
    record: csv::StringRecord,
    limits: Limits,
    rows: usize,
}

impl CsvReader<std::fs::File> {
    /// Opens `path` and reads its header.
    ///
    /// # Errors
    /// As [`CsvReader::new`], and [`CsvError::Io`] for a file that cannot
    /// be opened.
    pub fn open(path: &Path, limits: Limits) -> Result<Self, CsvError> {
        let file = std::fs::File::open(path).map_err(|source| CsvError::Io {
            path: path.to_owned(),
            source,
        })?;
        Self::new(file, path, limits)
    }
}

impl<R: Read> CsvReader<R> {
    /// Reads the header from `reader`; `path` is used in messages only.
    ///
    /// # Errors
    /// [`CsvError::Empty`] without a header, [`CsvError::DuplicateColumn`]
    /// for a name used twice, [`CsvError::Malformed`] / [`CsvError::TooLarge`]
    /// from the CSV layer.
    pub fn new(reader: R, path: &Path, limits: Limits) -> Result<Self, CsvError> {
        let mut reader = csv::ReaderBuilder::new()
            .has_headers(true)
            .flexible(true)
            .comment(Some(b'#'))
            .from_reader(Lines::new(reader, limits.bytes));
        let names: Vec<String> = reader
            .headers()
            .map_err(|e| {
                let line = e.position().map_or(1, csv::Position::line);
                csv_error(path, limits, line, e)
            })?
            .iter()
            .map(|h| h.trim().to_owned())
            .collect();
        if names.is_empty() || (names.len() == 1 && names[0].is_empty()) {
            return Err(CsvError::Empty {
                path: path.to_owned(),
            });
        }
        check_unique(&names, path)?;
        Ok(Self {
            reader,
            header: Header {
                path: path.to_owned(),
                names,
            },
            record: csv::StringRecord::new(),
            limits,
            rows: 0,
        })
    }

    /// The header row.
    pub fn header(&self) -> &Header {
        &self.header
    }

    /// The next data row; `None` after the last one.
    ///
    /// # Errors
    /// [`CsvError::NoRows`] at the end of a file without data rows,
    /// [`CsvError::Ragged`], [`CsvError::TooManyRows`], [`CsvError::TooLarge`],
    /// [`CsvError::Malformed`], [`CsvError::Io`].
    pub fn next_row(&mut self) -> Result<Option<Row<'_>>, CsvError> {
        let path = &self.header.path;
        // The reader has read up to the LF after the record (see [`Lines`]).
        let more = self.reader.read_record(&mut self.record).map_err(|e| {
            let line = self.reader.position().line().saturating_sub(1);
            csv_error(path, self.limits, line, e)
        })?;
        if !more {
            return if self.rows == 0 {
                Err(CsvError::NoRows { path: path.clone() })
            } else {
                Ok(None)
            };
        }
        let inner = self
            .record
            .as_slice()
            .bytes()
            .filter(|&b| b == b'\n')
            .count();
        let line = self
            .reader
            .position()
            .line()
            .saturating_sub(1 + inner as u64);
        if self.rows >= self.limits.rows {
            return Err(CsvError::TooManyRows {
                path: path.clone(),
                line,
                limit: self.limits.rows,
            });
        }
        if self.record.len() != self.header.names.len() {
            return Err(CsvError::Ragged {
                path: path.clone(),
                line,
                expected: self.header.names.len(),
                found: self.record.len(),
            });
        }
        self.rows += 1;
        Ok(Some(Row {
            header: &self.header,
            record: &self.record,
            line,
        }))
    }
}

/// A `csv` crate error as a [`CsvError`] naming the file and line.
fn csv_error(path: &Path, limits: Limits, line: u64, e: csv::Error) -> CsvError {
    let msg = e.to_string();
    match e.into_kind() {
        csv::ErrorKind::Io(source)
            if source
                .get_ref()
                .is_some_and(|inner| inner.is::<OverByteLimit>()) =>
        {
            CsvError::TooLarge {
                path: path.to_owned(),
                limit: limits.bytes,
            }
        }
        csv::ErrorKind::Io(source) => CsvError::Io {
            path: path.to_owned(),
            source,
        },
        _ => CsvError::Malformed {
            path: path.to_owned(),
            line,
            msg,
        },
    }
}

/// Refuses a header that names one column twice ([`CsvError::DuplicateColumn`]).
fn check_unique(names: &[String], path: &Path) -> Result<(), CsvError> {
    let mut seen = std::collections::HashMap::with_capacity(names.len());
    for (i, h) in names.iter().enumerate() {
        if let Some(first) = seen.insert(h.as_str(), i) {
            return Err(CsvError::DuplicateColumn {
                path: path.to_owned(),
                name: h.clone(),
                first: first + 1,
                second: i + 1,
            });
        }
    }
    Ok(())
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

/// Read the named numeric columns (required) and the optional ones that
/// exist, within [`Limits::default`].
///
/// Every row is checked for the header's field count; only requested columns
/// are parsed. Optional columns absent from the header are skipped silently.
///
/// # Errors
/// Any [`CsvError`] but [`CsvError::Cell`].
pub fn read_columns(
    path: &Path,
    required: &[&str],
    optional: &[&str],
) -> Result<Columns, CsvError> {
    read_table(path, &[], required, optional)
}

/// Read text columns (kept verbatim, e.g. subject and condition labels) and
/// numeric columns (required and optional), within [`Limits::default`].
///
/// # Errors
/// As [`read_columns`].
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
///
/// # Errors
/// As [`CsvReader::open`].
pub fn read_header(path: &Path) -> Result<Vec<String>, CsvError> {
    Ok(CsvReader::open(path, Limits::default())?.header.names)
}

/// As [`read_table`], from any reader; `path` is used in messages only.
///
/// # Errors
/// As [`read_columns`].
pub fn read_table_from<R: Read>(
    reader: R,
    path: &Path,
    text: &[&str],
    required: &[&str],
    optional: &[&str],
) -> Result<Columns, CsvError> {
    read_bounded(reader, path, text, required, optional, Limits::default())
}

/// [`read_table_from`] within `limits`.
fn read_bounded<R: Read>(
    reader: R,
    path: &Path,
    text: &[&str],
    required: &[&str],
    optional: &[&str],
    limits: Limits,
) -> Result<Columns, CsvError> {
    let mut rdr = CsvReader::new(reader, path, limits)?;
    let header = rdr.header();
    let text_idx = text
        .iter()
        .map(|n| header.require(n))
        .collect::<Result<Vec<_>, _>>()?;
    let mut idx = Vec::new();
    let mut names = Vec::new();
    for &name in required {
        idx.push(header.require(name)?);
        names.push(name.to_owned());
    }
    for &name in optional {
        if let Some(i) = header.position(name) {
            idx.push(i);
            names.push(name.to_owned());
        }
    }
    let mut data = vec![Vec::new(); idx.len()];
    let mut text_data = vec![Vec::new(); text_idx.len()];
    let mut lines = Vec::new();
    while let Some(row) = rdr.next_row()? {
        lines.push(row.line());
        for (k, &i) in text_idx.iter().enumerate() {
            text_data[k].push(row.text(i).to_owned());
        }
        for (k, &i) in idx.iter().enumerate() {
            data[k].push(row.number(i)?);
        }
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
        read_table_from(text.as_bytes(), Path::new("t.csv"), &[], req, opt)
    }

    /// The file `name` of `text`, column `x` required, within `limits`.
    fn read_x(text: &str, name: &str, limits: Limits) -> Result<Columns, CsvError> {
        read_bounded(text.as_bytes(), Path::new(name), &[], &["x"], &[], limits)
    }

    fn message(text: &str, req: &[&str]) -> String {
        read(text, req, &[])
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default()
    }

    /// Every cell of column `col` read with [`Row::value`].
    fn values(text: &str, col: &str) -> Result<Vec<Option<f64>>, CsvError> {
        let mut rdr = CsvReader::new(text.as_bytes(), Path::new("v.csv"), Limits::default())?;
        let i = rdr.header().require(col)?;
        let mut out = Vec::new();
        while let Some(row) = rdr.next_row()? {
            out.push(row.value(i)?);
        }
        Ok(out)
    }

    #[test]
    fn reads_named_columns_in_request_order() {
        let c = read("a,b,c\n1,2,3\n4,5,6\n", &["c", "a"], &["w"]).unwrap();
        assert_eq!(c.get("c").unwrap(), &[3.0, 6.0]);
        assert_eq!(c.get("a").unwrap(), &[1.0, 4.0]);
        assert!(c.get("w").is_none());
        assert_eq!(c.lines, [2, 3]);
    }

    #[test]
    fn a_file_over_the_row_limit_is_refused_naming_the_line() {
        let text = "t,x\n0,1\n1,2\n2,3\n";
        let rows = |n| Limits {
            rows: n,
            bytes: MAX_BYTES,
        };
        let ok = read_x(text, "r.csv", rows(3));
        assert_eq!(ok.map(|c| c.data[0].len()).ok(), Some(3));
        let e = read_x(text, "r.csv", rows(2))
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(e.starts_with("r.csv, line 4: more than 2 data rows"), "{e}");
    }

    /// The byte bound holds wherever it falls: in the header, in a row or
    /// exactly at the end (which is still within it).
    #[test]
    fn a_file_over_the_byte_limit_is_refused_naming_the_bound() {
        let text = "t,x\n0,1\n1,2\n";
        let bytes = |n| Limits {
            rows: MAX_ROWS,
            bytes: n,
        };
        let at = |n| read_x(text, "b.csv", bytes(n));
        assert_eq!(at(text.len() as u64).map(|c| c.data[0].len()).ok(), Some(2));
        for n in [2, 6, text.len() as u64 - 1] {
            let e = at(n).err().map(|e| e.to_string()).unwrap_or_default();
            assert_eq!(
                e,
                format!(
                    "b.csv: more than {n} bytes (the most this file may have); \
                     split it into shorter files"
                )
            );
        }
    }

    #[test]
    fn errors_name_file_line_and_column() {
        let e = message("a,b\n1,2\n3,x\n", &["b"]);
        assert_eq!(e, "t.csv, line 3, column `b`: `x` is not a finite number");
        let e = message("a,b\n1,2\n3\n", &["a"]);
        assert_eq!(e, "t.csv, line 3: ragged row: 1 field(s), the header has 2");
        let e = message("a,b\n1,2,3\n", &["a"]);
        assert!(e.contains("line 2: ragged row: 3 field(s)"), "{e}");
        let e = message("a,b\n1,2\n", &["z"]);
        assert_eq!(e, "t.csv: no column named `z` (columns are: a, b)");
    }

    /// An empty file, a blank first line and a header without rows.
    #[test]
    fn empty_file_and_header_only_are_refused() {
        for text in ["", "\n", "# only a comment\n"] {
            let e = message(text, &["a"]);
            assert_eq!(
                e, "t.csv: empty file (a header row naming the columns is required)",
                "{text:?}"
            );
        }
        for text in ["a\n", "a", "a,b\n# a comment\n"] {
            assert_eq!(
                message(text, &["a"]),
                "t.csv: no data rows after the header"
            );
        }
    }

    /// `NaN`, `inf` and text are never numbers; as values, empty, NA and
    /// NaN (any case) are missing, infinities still refused.
    #[test]
    fn non_finite_and_missing_cells() {
        for cell in [
            "NaN", "nan", "inf", "-inf", "infinity", "1e999", "NA", "", "-", "1,5",
        ] {
            let text = format!("a\n\"{cell}\"\n");
            let e = message(&text, &["a"]);
            assert!(e.contains("is not a finite number"), "{cell}: {e}");
        }
        let v = values("a\n1\n\nNA\nna\nNaN\nNAN\n -2.5 \n", "a").unwrap();
        assert_eq!(v, [Some(1.0), None, None, None, None, Some(-2.5)]);
        // The empty line is skipped by the CSV layer; a quoted empty cell
        // is a row with a missing value.
        let v = values("a,b\n\"\",1\n", "a").unwrap();
        assert_eq!(v, [None]);
        for cell in ["inf", "-Infinity", "1e400", "abc"] {
            let e = values(&format!("a\n{cell}\n"), "a")
                .err()
                .map(|e| e.to_string())
                .unwrap_or_default();
            assert_eq!(
                e,
                format!(
                    "v.csv, line 2, column `a`: `{cell}` is not a finite number \
                     (leave the cell empty or write NA for a missing value)"
                )
            );
        }
    }

    /// Quoting, CRLF line ends, a byte-order mark and comments.
    #[test]
    fn quoted_fields_crlf_bom_and_comments() {
        let text = "\u{feff}label,x\r\n# recorded 2024\r\n\"a, b\",1.5\r\n\"say \"\"hi\"\"\",2\r\n";
        let c =
            read_table_from(text.as_bytes(), Path::new("q.csv"), &["label"], &["x"], &[]).unwrap();
        assert_eq!(c.text[0], ["a, b", "say \"hi\""]);
        assert_eq!(c.get("x").unwrap(), &[1.5, 2.0]);
        assert_eq!(c.lines, [3, 4]);
        // A quote left open runs to the end of the file: refused, not read.
        let e = message("a\n1\n\"unterminated\n", &["a"]);
        assert!(
            e.contains("column `a`: `unterminated") && e.contains("is not a finite number"),
            "{e}"
        );
        let bad_utf8: &[u8] = b"a\n1\n\xff\xfe\n";
        let e = read_table_from(bad_utf8, Path::new("u.csv"), &[], &["a"], &[])
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("u.csv, line 3: malformed CSV"), "{e}");
    }

    /// A row's line is the file's, whatever the line ends and whatever
    /// lies between rows (the `csv` crate alone is one line early after a
    /// CRLF, a comment or a blank line).
    #[test]
    fn line_numbers_are_exact() {
        let lines = |text: &str| {
            read_table_from(text.as_bytes(), Path::new("l.csv"), &["k"], &[], &[])
                .map(|c| c.lines)
                .unwrap_or_default()
        };
        for text in [
            "k\n2\n3\n",
            "k\n2\n3",
            "k\r\n2\r\n3\r\n",
            "k\r\n2\r\n3",
            "k\r2\r3\r",
            "k\n2\n3\n# a comment without a line end",
            "k\n2\n3\n\n\n",
        ] {
            assert_eq!(lines(text), [2, 3], "{text:?}");
        }
        for text in [
            "k\n#c\n3\n4\n",
            "k\r\n#c\r\n3\r\n4\r\n",
            "k\n\n3\n4\n",
            "#c\nk\n3\n4\n",
            "k\n\"2\nx\"\n4\n",
            "k\r\n\"2\r\nx\"\r\n4\r\n",
        ] {
            assert_eq!(lines(text)[1..], [4], "{text:?}");
        }
        let e = message("a\r\n# c\r\n\r\n1\r\nx\r\n", &["a"]);
        assert_eq!(e, "t.csv, line 5, column `a`: `x` is not a finite number");
        let e = message("a,b\r\n\r\n1,2\r\n3\r\n", &["a"]);
        assert!(e.starts_with("t.csv, line 4: ragged row"), "{e}");
    }

    /// A caller's own rule for a cell names the file, line and column.
    #[test]
    fn a_callers_cell_error_names_the_cell() {
        let mut rdr = CsvReader::new(
            "p,q\n1,odd\n".as_bytes(),
            Path::new("c.csv"),
            Limits::default(),
        )
        .unwrap();
        let q = rdr.header().require("q").unwrap();
        let row = rdr.next_row().unwrap().unwrap();
        let e = row.error(q, format!("`{}` is not even", row.text(q)));
        assert_eq!(
            e.to_string(),
            "c.csv, line 2, column `q`: `odd` is not even"
        );
        assert!(rdr.next_row().unwrap().is_none());
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
