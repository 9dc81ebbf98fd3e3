//! NPY writer checked against the format specification (NEP 1 / numpy's
//! `format.py`): magic, version, header length, header dict, 64-byte
//! alignment, C-order little-endian data. The parser below is written from
//! the spec, independently of `rawsig::read_npy`.

use std::path::Path;

use kilotouch_study::export::ExportError;
use kilotouch_study::rawsig::{
    Channel, Dtype, GROWTH_AXIS_MAX_DIGITS, NpyWriter, RawLayout, npy_header, read_npy,
    read_sidecar, sidecar_path, standard_channels,
};

struct Parsed {
    version: (u8, u8),
    header_len: usize,
    dict: String,
    descr: String,
    fortran: bool,
    shape: Vec<u64>,
    data: Vec<u8>,
}

/// Parses an NPY v1.0 file per spec, asserting its structural rules.
fn parse_spec(bytes: &[u8]) -> Parsed {
    assert_eq!(&bytes[..6], b"\x93NUMPY", "magic");
    let version = (bytes[6], bytes[7]);
    let header_len = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
    let header = std::str::from_utf8(&bytes[10..10 + header_len]).expect("ASCII header");
    assert!(header.is_ascii());
    assert_eq!((10 + header_len) % 64, 0, "data must start 64-byte aligned");
    assert!(header.ends_with('\n'), "header ends with a newline");
    let dict = header
        .trim_end_matches('\n')
        .trim_end_matches(' ')
        .to_owned();
    assert!(dict.starts_with('{') && dict.ends_with('}'), "{dict}");
    // Python literal dict with exactly the keys descr, fortran_order, shape.
    let inner = &dict[1..dict.len() - 1];
    let get = |key: &str| -> String {
        let start = inner.find(&format!("'{key}': ")).expect(key) + key.len() + 4;
        let rest = &inner[start..];
        let end = if rest.starts_with('(') {
            rest.find(')').expect("test setup") + 1
        } else {
            rest.find(',').expect("test setup")
        };
        rest[..end].to_owned()
    };
    let descr = get("descr").trim_matches('\'').to_owned();
    let fortran = match get("fortran_order").as_str() {
        "False" => false,
        "True" => true,
        o => panic!("fortran_order {o}"),
    };
    let shape_text = get("shape");
    let shape: Vec<u64> = shape_text
        .trim_matches(|c| c == '(' || c == ')')
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| s.parse().expect("test setup"))
        .collect();
    assert_eq!(
        inner.matches("': ").count(),
        3,
        "exactly three keys: {dict}"
    );
    Parsed {
        version,
        header_len,
        dict,
        descr,
        fortran,
        shape,
        data: bytes[10 + header_len..].to_vec(),
    }
}

fn layout(dtype: Dtype, channels: usize) -> RawLayout {
    RawLayout {
        sample_rate_hz: 10_000.0,
        dtype,
        channels: (0..channels)
            .map(|i| Channel::new(&format!("ch{i}"), "m", "test channel"))
            .collect(),
        attrs: serde_json::Map::new(),
    }
}

/// Deterministic test values with awkward bit patterns.
fn value(i: usize, j: usize) -> f64 {
    let x = (i * 31 + j * 7) as f64;
    (x * 0.001).sin() * 1e-6 + x * 1e3 - 0.1
}

#[test]
fn f64_file_follows_the_npy_spec() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("a.npy");
    let (rows, cols) = (1234, 5);
    let mut w = NpyWriter::create(&path, layout(Dtype::F64, cols)).unwrap();
    for i in 0..rows {
        let sample: Vec<f64> = (0..cols).map(|j| value(i, j)).collect();
        w.push(&sample).unwrap();
    }
    let written = w.finish().unwrap();
    let bytes = std::fs::read(&path).unwrap();
    let p = parse_spec(&bytes);
    assert_eq!(p.version, (1, 0));
    assert_eq!(p.descr, "<f8");
    assert!(!p.fortran);
    assert_eq!(p.shape, vec![rows as u64, cols as u64]);
    assert_eq!(
        p.dict,
        format!("{{'descr': '<f8', 'fortran_order': False, 'shape': ({rows}, {cols}), }}")
    );
    assert_eq!(p.data.len(), rows * cols * 8, "no trailing bytes");
    for i in 0..rows {
        for j in 0..cols {
            let k = (i * cols + j) * 8;
            let v = f64::from_le_bytes(p.data[k..k + 8].try_into().unwrap());
            assert_eq!(v.to_bits(), value(i, j).to_bits(), "row {i} col {j}");
        }
    }
    assert_eq!(written.meta.shape, [rows as u64, cols as u64]);
    assert_eq!(written.sidecar, sidecar_path(&path));
}

#[test]
fn f32_file_rounds_to_nearest_and_counts_non_finite() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("b.npy");
    let mut w = NpyWriter::create(&path, layout(Dtype::F32, 3)).unwrap();
    let samples = [
        [0.1, -2.5e-7, 1e40],
        [f64::NAN, 3.0, f64::NEG_INFINITY],
        [1.0 + f64::EPSILON, -0.0, 16_777_217.0],
    ];
    w.push_rows(&samples.concat()).unwrap();
    let written = w.finish().unwrap();
    let p = parse_spec(&std::fs::read(&path).unwrap());
    assert_eq!(p.descr, "<f4");
    assert_eq!(p.shape, vec![3, 3]);
    let vals: Vec<f32> = p
        .data
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
        .collect();
    assert_eq!(vals.len(), 9);
    assert_eq!(vals[0], 0.1_f32);
    assert_eq!(vals[1], -2.5e-7_f32);
    assert_eq!(vals[2], f32::INFINITY, "beyond f32 range");
    assert!(vals[3].is_nan());
    assert_eq!(vals[5], f32::NEG_INFINITY);
    assert_eq!(vals[6], 1.0, "1 + 2⁻⁵² rounds to 1 in binary32");
    assert!(vals[7] == 0.0 && vals[7].is_sign_negative());
    assert_eq!(vals[8], 16_777_216.0, "2²⁴ + 1 rounds to even");
    // NaN, −Inf and the overflowed 1e40.
    assert_eq!(written.meta.non_finite_values, 3);
}

#[test]
fn header_is_patched_in_place_with_constant_length() {
    for cols in [1, 17, 300] {
        for dtype in [Dtype::F32, Dtype::F64] {
            let h0 = npy_header(dtype, 0, cols);
            let hmax = npy_header(dtype, u64::MAX, cols);
            assert_eq!(h0.len(), hmax.len());
            assert_eq!(h0.len() % 64, 0);
            // Room for 21 digits: the dict with 21 nines must still fit.
            let p = parse_spec(&[hmax.clone(), vec![]].concat());
            assert_eq!(p.shape, vec![u64::MAX, cols as u64]);
            assert!(p.header_len >= p.dict.len() + 1 + (GROWTH_AXIS_MAX_DIGITS - 20));
        }
    }
}

#[test]
fn streamed_long_file_and_unfinished_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("long.npy");
    let channels = standard_channels().len();
    let mut w = NpyWriter::create(&path, RawLayout::standard(10_000.0, Dtype::F32)).unwrap();
    // 100 s at 10 kHz in blocks of 1000 samples.
    let rows = 1_000_000_usize;
    let mut block = vec![0.0; 1000 * channels];
    for b in 0..rows / 1000 {
        for (k, v) in block.iter_mut().enumerate() {
            *v = (b * 1000 * channels + k) as f64;
        }
        w.push_rows(&block).unwrap();
    }
    assert_eq!(w.rows(), rows as u64);
    w.finish().unwrap();
    let a = read_npy(&path).unwrap();
    assert_eq!((a.rows, a.cols), (rows as u64, channels));
    // Integers up to 2²⁴ are exact in binary32.
    let last = rows * channels - 1;
    assert_eq!(a.data[12_345], 12_345.0);
    assert_eq!(a.data.len(), last + 1);
    let side = read_sidecar(&sidecar_path(&path)).unwrap();
    assert_eq!(side.duration_s, 100.0);
    assert_eq!(side.channels, standard_channels());

    // A writer dropped without finish (crash) leaves a valid empty array.
    let path = dir.path().join("crashed.npy");
    let mut w = NpyWriter::create(&path, layout(Dtype::F64, 2)).unwrap();
    for i in 0..10_000 {
        w.push(&[i as f64, 0.0]).unwrap();
    }
    drop(w);
    let p = parse_spec(&std::fs::read(&path).unwrap());
    assert_eq!(p.shape, vec![0, 2]);
    assert_eq!(read_npy(&path).unwrap().rows, 0);
    assert!(!sidecar_path(&path).exists(), "no sidecar before finish");
}

#[test]
fn sidecar_names_channels_units_and_rate() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("s.npy");
    let mut l = RawLayout::standard(10_000.0, Dtype::F64);
    l.attrs
        .insert("event_codes".into(), serde_json::json!({"1": "contact"}));
    let n = l.channels.len();
    let mut w = NpyWriter::create(&path, l).unwrap();
    w.push(&vec![0.5; n]).unwrap();
    w.finish().unwrap();
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(sidecar_path(&path)).unwrap()).unwrap();
    assert_eq!(v["npy_file"], "s.npy");
    assert_eq!(v["dtype"], "<f8");
    assert_eq!(v["shape"], serde_json::json!([1, n]));
    assert_eq!(v["order"], "C");
    assert_eq!(v["sample_rate_hz"], 10_000.0);
    assert_eq!(v["channels"][0]["name"], "handle_x");
    assert_eq!(v["channels"][0]["unit"], "m");
    assert_eq!(v["attrs"]["event_codes"]["1"], "contact");
    let names: Vec<&str> = v["channels"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["name"].as_str().unwrap())
        .collect();
    for needed in [
        "trap_x",
        "bead_y",
        "force_bead_x",
        "out_low",
        "out_high",
        "accel_z",
        "event",
    ] {
        assert!(names.contains(&needed), "{needed}");
    }
}

#[test]
fn invalid_layouts_and_samples_are_errors() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("x.npy");
    let mut l = layout(Dtype::F64, 2);
    l.channels.clear();
    assert!(matches!(
        NpyWriter::create(&path, l),
        Err(ExportError::Raw { .. })
    ));
    let mut l = layout(Dtype::F64, 2);
    l.channels[1].name = "ch0".into();
    let e = NpyWriter::create(&path, l).unwrap_err();
    assert!(
        e.to_string().contains("duplicate channel name `ch0`"),
        "{e}"
    );
    for rate in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        let mut l = layout(Dtype::F64, 2);
        l.sample_rate_hz = rate;
        assert!(NpyWriter::create(&path, l).is_err(), "rate {rate}");
    }
    let mut w = NpyWriter::create(&path, layout(Dtype::F64, 2)).unwrap();
    assert!(w.push(&[1.0]).is_err());
    assert!(w.push_rows(&[1.0, 2.0, 3.0]).is_err());
    w.push(&[1.0, 2.0]).unwrap();
    assert_eq!(w.rows(), 1);
    w.finish().unwrap();
    // The reader rejects what it cannot represent.
    let bad = dir.path().join("bad.npy");
    std::fs::write(&bad, b"\x93NUMPX\x01\x00").unwrap();
    assert!(read_npy(&bad).is_err());
    let mut h = npy_header(Dtype::F64, 3, 2);
    h.extend_from_slice(&[0; 8]); // shorter than 3 × 2 values
    std::fs::write(&bad, &h).unwrap();
    let e = read_npy(&bad).unwrap_err();
    assert!(e.to_string().contains("shorter"), "{e}");
}

#[test]
fn reads_files_written_by_numpy_conventions() {
    // A header in numpy's own layout (v1.0, no growth padding, 64-aligned
    // since numpy 1.22's 64-byte rule) for a (2, 3) '<f8' array.
    let dict = "{'descr': '<f8', 'fortran_order': False, 'shape': (2, 3), }";
    let mut header = dict.to_owned();
    while !(10 + header.len() + 1).is_multiple_of(64) {
        header.push(' ');
    }
    header.push('\n');
    let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
    bytes.extend_from_slice(&(header.len() as u16).to_le_bytes());
    bytes.extend_from_slice(header.as_bytes());
    for v in [1.0_f64, 2.0, 3.0, 4.0, 5.0, 6.0] {
        bytes.extend_from_slice(&v.to_le_bytes());
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("np.npy");
    std::fs::write(&path, &bytes).unwrap();
    let a = read_npy(Path::new(&path)).unwrap();
    assert_eq!((a.rows, a.cols), (2, 3));
    assert_eq!(a.row(1), &[4.0, 5.0, 6.0]);
}
