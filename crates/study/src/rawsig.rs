//! Raw per-trial signals as NPY files with a JSON sidecar.
//!
//! # File format
//!
//! Each trial's signals at full rate are one 2-D array, samples × channels,
//! in NumPy's `.npy` format version 1.0 (NEP 1, "A simple file format for
//! NumPy arrays"), readable by `numpy.load` and by MATLAB through
//! `readNPY` (npy-matlab) or a 10-line reader:
//!
//! ```text
//! bytes 0–5   \x93NUMPY                     magic
//! bytes 6–7   0x01 0x00                     version 1.0
//! bytes 8–9   HEADER_LEN, u16 little-endian
//! header      {'descr': '<f8', 'fortran_order': False, 'shape': (N, C), }
//!             + spaces + '\n', so that 10 + HEADER_LEN ≡ 0 (mod 64)
//! data        N·C values, C order (row-major: sample after sample),
//!             little-endian IEEE 754 binary64 ('<f8') or binary32 ('<f4')
//! ```
//!
//! # Streaming
//!
//! [`NpyWriter`] writes the header first with room for a 21-digit sample
//! count (NumPy's own `GROWTH_AXIS_MAX_DIGITS`), streams rows through a
//! buffer, and on [`NpyWriter::finish`] rewrites the header in place with
//! the final N (same length: the spare digits become padding spaces), so a
//! long trial is never held in memory. Until then the header says N = 0: a
//! file left by a crash loads as an empty array and is overwritten when the
//! trial is run again. `finish` fsyncs the data, writes the sidecar
//! atomically and fsyncs the directory; only then may the trial row that
//! references the file be appended.
//!
//! # Sidecar
//!
//! `<name>.json` next to `<name>.npy` ([`Sidecar`]) names the channels and
//! their units (SI), the sample rate, dtype, shape and the number of
//! non-finite values written (NaN / ±Inf are stored as they are: a dropped
//! sample stays visible instead of being invented).

use std::fs::File;
use std::io::{BufWriter, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::storage::error::{ExportError, Result, io_err};
use crate::storage::fsutil::{no_follow, read_json, write_atomic};

/// NPY magic string.
pub const NPY_MAGIC: &[u8; 6] = b"\x93NUMPY";

/// Digits reserved for the sample count in the header (NumPy's
/// `GROWTH_AXIS_MAX_DIGITS`; u64::MAX has 20).
pub const GROWTH_AXIS_MAX_DIGITS: usize = 21;

/// Sample type of a raw file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Dtype {
    /// `<f4`: little-endian binary32 (7 significant digits; halves the size).
    #[serde(rename = "<f4")]
    F32,
    /// `<f8`: little-endian binary64.
    #[serde(rename = "<f8")]
    F64,
}

impl Dtype {
    /// NumPy `descr` string.
    pub fn descr(self) -> &'static str {
        match self {
            Dtype::F32 => "<f4",
            Dtype::F64 => "<f8",
        }
    }

    /// Bytes per value.
    pub fn size(self) -> usize {
        match self {
            Dtype::F32 => 4,
            Dtype::F64 => 8,
        }
    }
}

/// One channel (column) of a raw file.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Channel {
    /// Column name (unique in the file).
    pub name: String,
    /// Unit (SI unless stated, `1` for dimensionless, `code` for events).
    pub unit: String,
    /// What the channel is.
    pub description: String,
}

impl Channel {
    /// A channel.
    pub fn new(name: &str, unit: &str, description: &str) -> Self {
        Self {
            name: name.to_owned(),
            unit: unit.to_owned(),
            description: description.to_owned(),
        }
    }
}

/// The default channel layout of a trial (SI units; positions in the sample
/// plane for trap and bead, in the Pantograph workspace for the handle).
pub fn standard_channels() -> Vec<Channel> {
    vec![
        Channel::new("handle_x", "m", "Pantograph handle (hand) position, x"),
        Channel::new("handle_y", "m", "Pantograph handle (hand) position, y"),
        Channel::new("trap_x", "m", "laser trap centre, x (sample plane)"),
        Channel::new("trap_y", "m", "laser trap centre, y (sample plane)"),
        Channel::new("bead_x", "m", "trapped bead centre, x (sample plane)"),
        Channel::new("bead_y", "m", "trapped bead centre, y (sample plane)"),
        Channel::new(
            "force_bead_x",
            "N",
            "optical force on the bead κ(trap − bead), x",
        ),
        Channel::new(
            "force_bead_y",
            "N",
            "optical force on the bead κ(trap − bead), y",
        ),
        Channel::new(
            "force_hand_x",
            "N",
            "force rendered to the hand (haptic image), x",
        ),
        Channel::new(
            "force_hand_y",
            "N",
            "force rendered to the hand (haptic image), y",
        ),
        Channel::new(
            "out_low",
            "N",
            "low channel output C_L·L (Pantograph command)",
        ),
        Channel::new(
            "out_high",
            "V",
            "high channel output C_H·H: Haptuator drive voltage",
        ),
        Channel::new("accel_x", "m/s^2", "handle accelerometer, x"),
        Channel::new("accel_y", "m/s^2", "handle accelerometer, y"),
        Channel::new("accel_z", "m/s^2", "handle accelerometer, z"),
        Channel::new(
            "contact",
            "1",
            "1 when bead and obstacle are in contact, else 0",
        ),
        Channel::new(
            "event",
            "code",
            "event code at this sample (0 = none; legend in the sidecar's attrs)",
        ),
    ]
}

/// Layout of a raw file, given to [`NpyWriter::create`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RawLayout {
    /// Sample rate, Hz (the paper's loop: 10 kHz).
    pub sample_rate_hz: f64,
    /// Sample type.
    pub dtype: Dtype,
    /// Channels, in column order.
    pub channels: Vec<Channel>,
    /// Free attributes copied to the sidecar (trial identity, event legend,
    /// …).
    pub attrs: serde_json::Map<String, serde_json::Value>,
}

impl RawLayout {
    /// Layout with [`standard_channels`] and no attributes.
    pub fn standard(sample_rate_hz: f64, dtype: Dtype) -> Self {
        Self {
            sample_rate_hz,
            dtype,
            channels: standard_channels(),
            attrs: serde_json::Map::new(),
        }
    }
}

/// The JSON sidecar of a raw file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Sidecar {
    /// `npy-1.0`.
    pub format: String,
    /// File name of the array (same folder).
    pub npy_file: String,
    /// Sample type.
    pub dtype: Dtype,
    /// `[samples, channels]`.
    pub shape: [u64; 2],
    /// `C` (row-major: one sample per row).
    pub order: String,
    /// Sample rate, Hz.
    pub sample_rate_hz: f64,
    /// Duration, s = samples / rate.
    pub duration_s: f64,
    /// Channels in column order.
    pub channels: Vec<Channel>,
    /// Number of NaN / ±Inf values written.
    pub non_finite_values: u64,
    /// Free attributes.
    pub attrs: serde_json::Map<String, serde_json::Value>,
    /// CRC-32 (IEEE, 8 hex digits) of the data bytes after the header,
    /// checked when a study is resumed (absent in files written before it
    /// was recorded).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub data_crc32: Option<String>,
}

/// The NPY 1.0 header (preamble + padded dict + `\n`) for `rows × cols`
/// samples of `dtype`, padded to the fixed length that leaves room for
/// [`GROWTH_AXIS_MAX_DIGITS`] digits of `rows`: the header length depends
/// only on `dtype` and `cols`, and is a multiple of 64.
pub fn npy_header(dtype: Dtype, rows: u64, cols: usize) -> Vec<u8> {
    let dict = |n: &str| {
        format!(
            "{{'descr': '{}', 'fortran_order': False, 'shape': ({n}, {cols}), }}",
            dtype.descr()
        )
    };
    let reserved = dict(&"9".repeat(GROWTH_AXIS_MAX_DIGITS)).len();
    // 10-byte preamble + dict + at least one pad + '\n', rounded up to 64.
    let total = (10 + reserved + 1).div_ceil(64) * 64;
    let header_len = total - 10;
    let mut text = dict(&rows.to_string());
    while text.len() < header_len - 1 {
        text.push(' ');
    }
    text.push('\n');
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(NPY_MAGIC);
    out.extend_from_slice(&[1, 0]);
    // header_len < 65536 for any realistic channel count (checked in create).
    out.extend_from_slice(&u16::try_from(header_len).unwrap_or(u16::MAX).to_le_bytes());
    out.extend_from_slice(text.as_bytes());
    out
}

/// Streaming writer of one raw file (see the module documentation).
#[derive(Debug)]
pub struct NpyWriter {
    path: PathBuf,
    out: BufWriter<File>,
    layout: RawLayout,
    rows: u64,
    non_finite: u64,
}

/// What [`NpyWriter::finish`] wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct RawWritten {
    /// The `.npy` file.
    pub npy: PathBuf,
    /// The sidecar.
    pub sidecar: PathBuf,
    /// Its content.
    pub meta: Sidecar,
}

/// Sidecar path of an `.npy` path (`x.npy` → `x.json`).
pub fn sidecar_path(npy: &Path) -> PathBuf {
    npy.with_extension("json")
}

impl NpyWriter {
    /// Creates (truncating) `path` and writes the provisional header
    /// (N = 0).
    ///
    /// # Errors
    /// [`ExportError::Raw`] for no channel, duplicate or empty channel
    /// names, a non-positive or non-finite sample rate, or a header over
    /// 65 535 bytes; I/O errors.
    pub fn create(path: &Path, layout: RawLayout) -> Result<Self> {
        let raw = |message: String| ExportError::Raw {
            path: path.to_path_buf(),
            message,
        };
        if layout.channels.is_empty() {
            return Err(raw("at least one channel is needed".into()));
        }
        if !(layout.sample_rate_hz.is_finite() && layout.sample_rate_hz > 0.0) {
            return Err(raw(format!(
                "sample rate must be positive and finite, got {} Hz",
                layout.sample_rate_hz
            )));
        }
        for (i, c) in layout.channels.iter().enumerate() {
            if c.name.trim().is_empty() {
                return Err(raw(format!("channel {i} has an empty name")));
            }
            if layout.channels[..i].iter().any(|o| o.name == c.name) {
                return Err(raw(format!("duplicate channel name `{}`", c.name)));
            }
        }
        let header = npy_header(layout.dtype, 0, layout.channels.len());
        if header.len() - 10 > usize::from(u16::MAX) {
            return Err(raw(format!(
                "{} channels do not fit an NPY 1.0 header",
                layout.channels.len()
            )));
        }
        let file = no_follow()
            .write(true)
            .create(true)
            .truncate(true)
            .open(path)
            .map_err(io_err(path, "create"))?;
        let mut out = BufWriter::with_capacity(1 << 16, file);
        out.write_all(&header).map_err(io_err(path, "write"))?;
        Ok(Self {
            path: path.to_path_buf(),
            out,
            layout,
            rows: 0,
            non_finite: 0,
        })
    }

    /// Number of channels C.
    pub fn channels(&self) -> usize {
        self.layout.channels.len()
    }

    /// Samples (rows) written so far.
    pub fn rows(&self) -> u64 {
        self.rows
    }

    /// Path of the `.npy` file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Appends one sample (one value per channel). Allocation-free; the
    /// values go through a 64 KiB buffer.
    ///
    /// # Errors
    /// [`ExportError::Raw`] when `sample.len()` is not C; I/O errors.
    pub fn push(&mut self, sample: &[f64]) -> Result<()> {
        if sample.len() != self.layout.channels.len() {
            return Err(ExportError::Raw {
                path: self.path.clone(),
                message: format!(
                    "sample has {} value(s), the file has {} channel(s)",
                    sample.len(),
                    self.layout.channels.len()
                ),
            });
        }
        self.write_values(sample)?;
        self.rows += 1;
        Ok(())
    }

    /// Appends many samples given row after row (`values.len()` a multiple
    /// of C).
    ///
    /// # Errors
    /// [`ExportError::Raw`] for a length that is not a multiple of C; I/O
    /// errors.
    pub fn push_rows(&mut self, values: &[f64]) -> Result<()> {
        let c = self.layout.channels.len();
        if !values.len().is_multiple_of(c) {
            return Err(ExportError::Raw {
                path: self.path.clone(),
                message: format!("{} values are not whole rows of {c} channels", values.len()),
            });
        }
        self.write_values(values)?;
        self.rows += (values.len() / c) as u64;
        Ok(())
    }

    fn write_values(&mut self, values: &[f64]) -> Result<()> {
        let res = match self.layout.dtype {
            Dtype::F64 => values.iter().try_for_each(|&v| {
                self.non_finite += u64::from(!v.is_finite());
                self.out.write_all(&v.to_le_bytes())
            }),
            Dtype::F32 => values.iter().try_for_each(|&v| {
                // `as` rounds to nearest; values beyond f32 range become ±Inf
                // and are counted.
                let x = v as f32;
                self.non_finite += u64::from(!x.is_finite());
                self.out.write_all(&x.to_le_bytes())
            }),
        };
        res.map_err(io_err(&self.path, "write"))
    }

    /// Patches the header with the final sample count, fsyncs the file and
    /// writes the sidecar atomically (temporary file, fsync, rename, fsync
    /// of the directory — which also makes the new `.npy` entry durable).
    ///
    /// # Errors
    /// I/O errors.
    pub fn finish(mut self) -> Result<RawWritten> {
        let path = self.path.clone();
        self.out.flush().map_err(io_err(&path, "write"))?;
        let header = npy_header(self.layout.dtype, self.rows, self.layout.channels.len());
        let file = self.out.get_mut();
        file.seek(SeekFrom::Start(0))
            .map_err(io_err(&path, "seek"))?;
        file.write_all(&header)
            .map_err(io_err(&path, "patch header of"))?;
        file.sync_all().map_err(io_err(&path, "fsync"))?;
        // Read back from the page cache: the checksum covers what is in
        // the file, not what was meant to be written.
        let data_crc32 = no_follow()
            .read(true)
            .open(&path)
            .and_then(|mut f| data_crc32(&mut f, header.len() as u64))
            .map_err(io_err(&path, "read back"))?;
        let npy_file = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let meta = Sidecar {
            format: "npy-1.0".into(),
            npy_file,
            dtype: self.layout.dtype,
            shape: [self.rows, self.layout.channels.len() as u64],
            order: "C".into(),
            sample_rate_hz: self.layout.sample_rate_hz,
            duration_s: self.rows as f64 / self.layout.sample_rate_hz,
            channels: self.layout.channels.clone(),
            non_finite_values: self.non_finite,
            attrs: self.layout.attrs.clone(),
            data_crc32: Some(crate::export::checksum::crc32_hex(data_crc32)),
        };
        let sidecar = sidecar_path(&path);
        let json = serde_json::to_vec_pretty(&meta).map_err(|source| ExportError::Json {
            path: sidecar.clone(),
            source,
        })?;
        // Also makes the new .npy entry durable: same directory.
        write_atomic(&sidecar, &json)?;
        Ok(RawWritten {
            npy: path,
            sidecar,
            meta,
        })
    }
}

/// CRC-32 of the bytes of `file` from `offset` to its end (the data of a
/// raw file after its header), read in 64 KiB pieces.
///
/// # Errors
/// I/O errors.
pub fn data_crc32(file: &mut File, offset: u64) -> std::io::Result<u32> {
    use std::io::Read as _;
    file.seek(SeekFrom::Start(offset))?;
    let mut buf = vec![0u8; 1 << 16];
    let mut crc = crate::export::checksum::Crc32::new();
    loop {
        let n = file.read(&mut buf)?;
        if n == 0 {
            return Ok(crc.finish());
        }
        crc.update(&buf[..n]);
    }
}

/// An NPY array read back (values widened to `f64`).
#[derive(Debug, Clone, PartialEq)]
pub struct NpyArray {
    /// Sample type in the file.
    pub dtype: Dtype,
    /// Rows (samples).
    pub rows: u64,
    /// Columns (channels).
    pub cols: usize,
    /// Row-major values.
    pub data: Vec<f64>,
}

impl NpyArray {
    /// Row `i`.
    pub fn row(&self, i: usize) -> &[f64] {
        &self.data[i * self.cols..(i + 1) * self.cols]
    }
}

/// Reads a 2-D, C-order, little-endian `<f4` / `<f8` NPY file (version 1.0
/// or 2.0), as written by [`NpyWriter`] or `numpy.save`.
///
/// # Errors
/// [`ExportError::Raw`] for anything else (bad magic, Fortran order,
/// another dtype or rank, data shorter than the shape).
pub fn read_npy(path: &Path) -> Result<NpyArray> {
    let bytes = crate::storage::fsutil::read_no_follow(path)?;
    let raw = |message: &str| ExportError::Raw {
        path: path.to_path_buf(),
        message: message.to_owned(),
    };
    if bytes.len() < 10 || &bytes[..6] != NPY_MAGIC {
        return Err(raw("not an NPY file (bad magic)"));
    }
    let (header_len, start) = match bytes[6] {
        1 => (usize::from(u16::from_le_bytes([bytes[8], bytes[9]])), 10),
        2 if bytes.len() >= 12 => (
            u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
            12,
        ),
        _ => return Err(raw("unsupported NPY version")),
    };
    let end = start + header_len;
    let header = bytes
        .get(start..end)
        .and_then(|h| std::str::from_utf8(h).ok())
        .ok_or_else(|| raw("truncated or non-ASCII header"))?;
    let field = |key: &str| -> Option<&str> {
        let i = header.find(&format!("'{key}':"))? + key.len() + 3;
        Some(header[i..].trim_start())
    };
    let descr = field("descr").ok_or_else(|| raw("header lacks 'descr'"))?;
    let dtype = if descr.starts_with("'<f8'") {
        Dtype::F64
    } else if descr.starts_with("'<f4'") {
        Dtype::F32
    } else {
        return Err(raw("dtype must be '<f4' or '<f8'"));
    };
    if !field("fortran_order").is_some_and(|f| f.starts_with("False")) {
        return Err(raw("only C-order arrays are supported"));
    }
    let shape = field("shape").ok_or_else(|| raw("header lacks 'shape'"))?;
    let inside = shape
        .strip_prefix('(')
        .and_then(|s| s.split(')').next())
        .ok_or_else(|| raw("malformed shape"))?;
    let dims: Vec<&str> = inside
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .collect();
    let [r, c] = dims.as_slice() else {
        return Err(raw("only 2-D arrays are supported"));
    };
    let rows: u64 = r.parse().map_err(|_| raw("malformed shape"))?;
    let cols: usize = c.parse().map_err(|_| raw("malformed shape"))?;
    let n = usize::try_from(rows)
        .ok()
        .and_then(|r| r.checked_mul(cols))
        .ok_or_else(|| raw("shape too large"))?;
    let need = n
        .checked_mul(dtype.size())
        .ok_or_else(|| raw("shape too large"))?;
    let data_bytes = bytes
        .get(end..end + need)
        .ok_or_else(|| raw("data shorter than the shape in the header"))?;
    let data = match dtype {
        Dtype::F64 => data_bytes
            .chunks_exact(8)
            .map(|b| f64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]))
            .collect(),
        Dtype::F32 => data_bytes
            .chunks_exact(4)
            .map(|b| f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]])))
            .collect(),
    };
    Ok(NpyArray {
        dtype,
        rows,
        cols,
        data,
    })
}

/// Reads a sidecar.
///
/// # Errors
/// I/O or JSON errors.
pub fn read_sidecar(path: &Path) -> Result<Sidecar> {
    read_json(path)
}
