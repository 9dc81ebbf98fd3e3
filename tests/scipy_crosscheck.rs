//! Cross-checks of the dsp crate against scipy.signal 1.17.
//!
//! The reference numbers in `tests/data/scipy_reference.json` were produced
//! by `tests/scipy_reference.py` (committed beside this file) from scipy's
//! own designs: they are an independent implementation, not earlier output
//! of kilotouch. Responses are compared, not coefficients, because section
//! pairing and ordering are free choices.

use kilotouch_dsp::C64;
use kilotouch_dsp::crossover::LinkwitzRiley;
use kilotouch_dsp::design::{FilterKind, Prewarp, butter, butter_zpk, tf_to_sos};
use kilotouch_dsp::spectral::{WelchConfig, coherence, csd, welch};
use serde_json::Value;

const FS: f64 = 10_000.0;

fn reference() -> Value {
    let text = include_str!("data/scipy_reference.json");
    serde_json::from_str(text).expect("valid reference JSON")
}

fn vecf(v: &Value) -> Vec<f64> {
    v.as_array()
        .expect("array")
        .iter()
        .map(|x| x.as_f64().expect("number"))
        .collect()
}

fn complex(v: &Value, re: &str, im: &str) -> Vec<C64> {
    vecf(&v[re])
        .into_iter()
        .zip(vecf(&v[im]))
        .map(|(r, i)| C64::new(r, i))
        .collect()
}

fn sos_response(sections: &[kilotouch_dsp::filter::BiquadCoeffs], f: f64) -> C64 {
    sections.iter().map(|s| s.response(f, FS)).product()
}

/// Relative complex error, with an absolute floor for deep stop-band values.
fn assert_close(got: C64, want: C64, rel: f64, what: &str) {
    let err = (got - want).norm();
    let scale = want.norm().max(1e-12);
    assert!(
        err <= rel * scale,
        "{what}: got {got}, scipy {want} (rel err {:.2e})",
        err / scale
    );
}

#[test]
fn butterworth_designs_match_scipy() {
    let r = reference();
    for d in r["butter"].as_array().expect("designs") {
        let order = d["order"].as_u64().expect("order") as usize;
        let fc = d["fc"].as_f64().expect("fc");
        let kind = match d["kind"].as_str() {
            Some("low") => FilterKind::Lowpass,
            _ => FilterKind::Highpass,
        };
        let zpk = butter_zpk(order, fc, FS, kind, Prewarp::AtCutoff).expect("design");
        let sos = butter(order, fc, FS, kind, Prewarp::AtCutoff).expect("sos design");
        let f = vecf(&d["f"]);
        let h = complex(d, "re", "im");
        for (fi, hi) in f.iter().zip(&h) {
            let what = format!("butter({order}, {fc}, {kind:?}) at {fi} Hz");
            assert_close(zpk.digital_response(*fi, FS), *hi, 1e-9, &what);
            assert_close(sos_response(&sos, *fi), *hi, 1e-9, &what);
        }
    }
}

#[test]
fn lr4_crossover_matches_squared_scipy_butterworth() {
    let r = reference();
    let d = &r["lr4_200"];
    let xo = LinkwitzRiley::new(4, 200.0, FS).expect("LR4");
    let f = vecf(&d["f"]);
    let low = complex(d, "low_re", "low_im");
    let high = complex(d, "high_re", "high_im");
    for i in 0..f.len() {
        let (l, h) = xo.response(f[i]);
        assert_close(l, low[i], 1e-9, &format!("LR4 low at {} Hz", f[i]));
        assert_close(h, high[i], 1e-9, &format!("LR4 high at {} Hz", f[i]));
    }
}

#[test]
fn compensator_bilinear_matches_scipy() {
    let r = reference();
    let d = &r["c_h_bilinear"];
    let tf = kilotouch_dsp::Tf::new(vecf(&d["num"]), vecf(&d["den"])).expect("C_H");
    let sos = tf_to_sos(&tf, FS, None).expect("bilinear");
    let f = vecf(&d["f"]);
    let h = complex(d, "re", "im");
    for (fi, hi) in f.iter().zip(&h) {
        assert_close(
            sos_response(&sos, *fi),
            *hi,
            1e-9,
            &format!("C_H at {fi} Hz"),
        );
    }
}

#[test]
fn welch_csd_coherence_match_scipy() {
    let r = reference();
    let d = &r["welch"];
    let x = vecf(&d["x"]);
    let y = vecf(&d["y"]);
    let cfg = WelchConfig::new(d["nperseg"].as_u64().expect("nperseg") as usize);
    let p = welch(&x, FS, &cfg).expect("welch");
    let want = vecf(&d["pxx"]);
    let peak = want.iter().cloned().fold(0.0, f64::max);
    assert_eq!(p.p.len(), want.len());
    for (g, w) in p.p.iter().zip(&want) {
        assert!((g - w).abs() <= 1e-12 * peak, "Pxx {g} vs {w}");
    }
    let c = csd(&x, &y, FS, &cfg).expect("csd");
    let want = complex(d, "pxy_re", "pxy_im");
    let peak = want.iter().map(|z| z.norm()).fold(0.0, f64::max);
    for (g, w) in c.pxy.iter().zip(&want) {
        assert!((g - w).norm() <= 1e-12 * peak, "Pxy {g} vs {w}");
    }
    let coh = coherence(&x, &y, FS, &cfg).expect("coherence");
    for (g, w) in coh.c.iter().zip(vecf(&d["coh"])) {
        assert!((g - w).abs() <= 1e-8, "coherence {g} vs {w}");
    }
}

#[test]
fn mls_order_10_matches_scipy_max_len_seq() {
    let r = reference();
    let want: Vec<u8> = vecf(&r["mls10"]).into_iter().map(|v| v as u8).collect();
    let got = kilotouch_dsp::excitation::mls_bits(10).expect("mls");
    assert_eq!(got, want);
}
