//! `kilotouch tweezer calibrate` and `record`, and the Rig page's Tweezer
//! section: recording the detector signals of a tweezer ([`record`], the
//! one path from a `--rig` spec to a record), passive power-spectral
//! calibration of both axes ([`calibrate_axes`],
//! `kilotouch_rig::tweezer::calibration`) and the plot of a spectrum and
//! its fit (PNG, plotters with an embedded font: no system font lookup).

use kilotouch_dsp::trap_psd::PsdFit;
use kilotouch_rig::RigConfig;
use kilotouch_rig::device::RigSpec;
use kilotouch_rig::serial::LinkTweezer;
use kilotouch_rig::tweezer::calibration::{
    MAX_RECORD_SAMPLES, RECORD_BLOCK, TrapCalibration, TrapCalibrationSettings, calibrate_trap,
    record_detector,
};
use kilotouch_rig::tweezer::{
    DetectedTweezer, SurfaceDrag, TrapCalibrationRecord, Tweezer, TweezerParams, surface_drag,
};
use plotters::prelude::*;
use std::path::Path;

/// Periodogram bins averaged per block by default (the Rig page's and
/// `kilotouch tweezer record --calibration-out`'s).
pub const DEFAULT_POINTS_PER_BLOCK: usize = 100;

/// The calibration settings a rig file implies for its tweezer: its bead,
/// medium and detector; the fit range from 10 Hz to the Nyquist frequency
/// of the loop rate; the aliased Lorentzian for a detector without an
/// anti-aliasing (diode) filter, point-sampled at the loop rate (Berg-Sørensen
/// & Flyvbjerg 2004, eq. 4), the diode filter when the detector has one;
/// Faxén's wall correction when the rig file places the bead near the
/// coverslip. The sample rate is the loop rate (a record's replaces it in
/// [`calibrate_axes`]).
pub fn default_settings(rc: &RigConfig) -> TrapCalibrationSettings {
    use kilotouch_rig::tweezer::calibration::{
        DEFAULT_BEAD_DENSITY_KG_M3, DEFAULT_FLUID_DENSITY_KG_M3,
    };
    let t = &rc.tweezer;
    let fs = rc.rig.sample_rate_hz;
    let diode = t.detector.diode_hz.is_some();
    TrapCalibrationSettings {
        fs_hz: fs,
        radius_m: t.radius_m,
        viscosity_pa_s: t.viscosity_pa_s,
        temperature_k: t.temperature_k,
        fit_range_hz: (10.0, 0.5 * fs),
        points_per_block: DEFAULT_POINTS_PER_BLOCK,
        hydro: false,
        diode,
        aliased: !diode,
        fluid_density_kg_m3: DEFAULT_FLUID_DENSITY_KG_M3,
        bead_density_kg_m3: DEFAULT_BEAD_DENSITY_KG_M3,
        distance_to_surface_m: t.wall_distance_m,
    }
}

/// A record of a tweezer's position-detector signals.
#[derive(Debug, Clone)]
pub struct DetectorRecord {
    /// Sample rate, Hz.
    pub fs_hz: f64,
    /// The signals (x, y), V.
    pub volts: [Vec<f64>; 2],
    /// The tweezer it came from (`sim`, `serial:PATH`).
    pub source: String,
    /// For the simulated tweezer: the drag its obstacles add at the trap
    /// spot (`None` for a live tweezer, whose surroundings are unknown).
    pub surface: Option<SurfaceDrag>,
    /// For a live tweezer: its link's round trip measured at connection
    /// and the command lead of the record's blocks.
    pub link: Option<LinkTiming>,
}

/// The timing of a live tweezer's link during a record.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct LinkTiming {
    /// Round trip measured at connection (longest of the HELLO probes), ms.
    pub round_trip_ms: Option<f64>,
    /// Command lead of the record's blocks, samples.
    pub lead_samples: u64,
    /// Samples per block.
    pub block_samples: usize,
}

/// Prefix of the comment line of a record CSV that carries the predicted
/// surface drag at the trap spot (`# surface-drag x=1.3112 y=1.1358 …`),
/// read back by `kilotouch tweezer calibrate`.
pub const SURFACE_DRAG_TAG: &str = "# surface-drag";

/// The comment line [`SURFACE_DRAG_TAG`] for `d`.
pub fn surface_drag_line(d: &SurfaceDrag) -> String {
    format!(
        "{SURFACE_DRAG_TAG} x={:.6} y={:.6} ({})",
        d.drag_factor[0],
        d.drag_factor[1],
        d.describe()
    )
}

/// The drag factors (x, y) of a record's [`SURFACE_DRAG_TAG`] line, if
/// `line` is one.
pub fn parse_surface_drag_line(line: &str) -> Option<[f64; 2]> {
    let rest = line.strip_prefix(SURFACE_DRAG_TAG)?;
    let mut f = [None, None];
    for tok in rest.split_whitespace() {
        for (k, key) in ["x=", "y="].iter().enumerate() {
            if let Some(v) = tok.strip_prefix(key) {
                f[k] = v.parse::<f64>().ok().filter(|b| b.is_finite() && *b > 0.0);
            }
        }
    }
    Some([f[0]?, f[1]?])
}

/// Record `duration_s` seconds of the detector signals of the tweezer
/// `spec` names — `sim`: the simulated tweezer of `rc` behind its simulated
/// detector; `serial:…`: a live (or emulated) tweezer — with the trap held
/// at `trap_m` (m) after 50 ms of settling. `progress` gets the fraction
/// done.
pub fn record(
    spec: &RigSpec,
    rc: &RigConfig,
    duration_s: f64,
    trap_m: [f64; 2],
    progress: &mut dyn FnMut(f64),
) -> anyhow::Result<DetectorRecord> {
    if !(duration_s.is_finite() && duration_s > 0.0) {
        anyhow::bail!("the duration must be finite and > 0 s, got {duration_s}");
    }
    if !trap_m.iter().all(|v| v.is_finite()) {
        anyhow::bail!("the trap position must be finite");
    }
    let surface = matches!(spec, RigSpec::Sim)
        .then(|| surface_drag(&TweezerParams::from_config(&rc.tweezer), trap_m));
    let mut link = None;
    let (fs, volts) = match spec {
        RigSpec::Sim => {
            let mut tw = DetectedTweezer::new(
                TweezerParams::from_config(&rc.tweezer),
                &rc.tweezer.detector,
                rc.rig.sample_rate_hz,
            )?;
            record_from(&mut tw, duration_s, trap_m, progress)?
        }
        // The block link with its command lead (`lead=auto` unless the
        // spec says otherwise); a link failure is reported with what the
        // link saw (stall, end of file, watchdog), naming the port.
        RigSpec::Serial(cfg) => {
            let mut tw = LinkTweezer::open(cfg)?;
            link = Some(LinkTiming {
                round_trip_ms: tw.round_trip_s().map(|r| r * 1e3),
                lead_samples: tw.lead_samples(RECORD_BLOCK),
                block_samples: RECORD_BLOCK,
            });
            record_from(&mut tw, duration_s, trap_m, progress).map_err(|e| match tw.failure() {
                Some(f) => anyhow::anyhow!("{e}: {f}"),
                None => e,
            })?
        }
        RigSpec::Audio(_) => {
            anyhow::bail!("an audio interface has no tweezer; use sim or serial:PATH")
        }
    };
    Ok(DetectorRecord {
        fs_hz: fs,
        volts,
        source: spec.describe(),
        surface,
        link,
    })
}

/// The record of [`record`] from tweezer `tw`: its sample rate and the
/// signals (x, y), V.
fn record_from(
    tw: &mut dyn Tweezer,
    duration_s: f64,
    trap_m: [f64; 2],
    progress: &mut dyn FnMut(f64),
) -> anyhow::Result<(f64, [Vec<f64>; 2])> {
    let fs = tw.sample_rate_hz();
    let n = (duration_s * fs).round();
    if n > MAX_RECORD_SAMPLES as f64 {
        anyhow::bail!("{duration_s} s is {n} samples at {fs} Hz; at most {MAX_RECORD_SAMPLES}");
    }
    let n = n as usize;
    // Move the trap there and let the bead settle (50 relaxation times of
    // any trap above 10 Hz): the record starts stationary.
    tw.reset(trap_m);
    let settle = (0.05 * fs).ceil() as usize;
    let volts = record_detector(tw, trap_m, settle, n, &mut |i| {
        progress(i as f64 / n as f64)
    })?;
    Ok((fs, volts))
}

/// Calibrate both axes of a record with the same settings (the record's
/// sample rate replaces `s.fs_hz`): the combined record and each axis' fit.
pub fn calibrate_axes(
    rec: &DetectorRecord,
    s: &TrapCalibrationSettings,
) -> anyhow::Result<(TrapCalibrationRecord, [PsdFit; 2])> {
    let s = TrapCalibrationSettings {
        fs_hz: rec.fs_hz,
        ..s.clone()
    };
    let (cx, fx) = calibrate_trap(&rec.volts[0], &s).map_err(|e| anyhow::anyhow!("x axis: {e}"))?;
    let (cy, fy) = calibrate_trap(&rec.volts[1], &s).map_err(|e| anyhow::anyhow!("y axis: {e}"))?;
    let n = rec.volts[0].len();
    Ok((
        TrapCalibrationRecord::new(&rec.source, n, s, cx, cy),
        [fx, fy],
    ))
}

use crate::paper::style::FONT;

/// The one embedded font of every plot ([`crate::paper::style::ensure_font`]).
fn ensure_font() -> anyhow::Result<()> {
    crate::paper::style::ensure_font().map_err(anyhow::Error::msg)
}

/// A short description of the model fitted, e.g. "Lorentzian + diode".
pub fn model_name(s: &TrapCalibrationSettings) -> String {
    let mut m = if s.hydro {
        "hydrodynamic".to_owned()
    } else if s.aliased {
        "aliased Lorentzian".to_owned()
    } else {
        "Lorentzian".to_owned()
    };
    if s.diode {
        m += " × diode";
    }
    if let (false, Some(h)) = (s.hydro, s.distance_to_surface_m) {
        m += &format!(", Faxén at {:.2} µm", h * 1e6);
    }
    m
}

/// Draw the blocked spectrum and the fitted model (log–log) to a PNG.
pub fn plot_fit(
    path: &Path,
    fit: &PsdFit,
    cal: &TrapCalibration,
    s: &TrapCalibrationSettings,
) -> anyhow::Result<()> {
    ensure_font()?;
    let spec = &fit.spectrum;
    let (f0, f1) = (
        spec.f.first().copied().unwrap_or(1.0),
        spec.f.last().copied().unwrap_or(10.0),
    );
    let model: Vec<(f64, f64)> = (0..=400)
        .map(|i| {
            let f = f0 * (f1 / f0).powf(i as f64 / 400.0);
            (f, fit.model_at(f))
        })
        .collect();
    let all = spec.p.iter().copied().chain(model.iter().map(|m| m.1));
    let (pmin, pmax) = all.fold((f64::INFINITY, 0.0f64), |(a, b), v| (a.min(v), b.max(v)));
    if !(pmin.is_finite() && pmin > 0.0 && pmax > pmin) {
        anyhow::bail!("nothing to plot: the spectrum is not positive");
    }
    const W: u32 = 960;
    const H: u32 = 640;
    let mut buf = vec![255_u8; (W as usize) * (H as usize) * 3];
    draw_fit(
        &mut buf,
        (W, H),
        spec,
        &model,
        cal,
        s,
        (f0, f1),
        (pmin, pmax),
    )?;
    image::save_buffer(path, &buf, W, H, image::ExtendedColorType::Rgb8)
        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    Ok(())
}

/// The drawing of [`plot_fit`] into an RGB buffer.
#[allow(clippy::too_many_arguments)]
fn draw_fit(
    buf: &mut [u8],
    size: (u32, u32),
    spec: &kilotouch_dsp::trap_psd::BlockedSpectrum,
    model: &[(f64, f64)],
    cal: &TrapCalibration,
    s: &TrapCalibrationSettings,
    (f0, f1): (f64, f64),
    (pmin, pmax): (f64, f64),
) -> anyhow::Result<()> {
    let root = BitMapBackend::with_buffer(buf, size).into_drawing_area();
    root.fill(&WHITE)?;
    let title = format!(
        "κ = {:.3} ± {:.3} pN/µm   f_c = {:.1} ± {:.1} Hz   R_d = {:.4} µm/V",
        cal.kappa_pn_um, cal.kappa_se_pn_um, cal.fc_hz, cal.fc_se_hz, cal.rd_um_per_v
    );
    let mut chart = ChartBuilder::on(&root)
        .caption(title, (FONT, 22).into_font())
        .margin(16)
        .x_label_area_size(56)
        .y_label_area_size(90)
        .build_cartesian_2d(
            ((f0 * 0.8)..(f1 * 1.25)).log_scale(),
            ((pmin * 0.5)..(pmax * 2.0)).log_scale(),
        )?;
    chart
        .configure_mesh()
        .x_desc("frequency (Hz)")
        .y_desc("power spectral density (V²/Hz)")
        .label_style((FONT, 17))
        .axis_desc_style((FONT, 20))
        .y_label_formatter(&|v| format!("{v:.0e}"))
        .draw()?;
    let blue = RGBColor(31, 119, 180);
    let red = RGBColor(214, 39, 40);
    chart
        .draw_series(
            spec.f
                .iter()
                .zip(&spec.p)
                .map(|(&f, &p)| Circle::new((f, p), 3, blue.filled())),
        )?
        .label(format!(
            "blocked periodogram ({} points per block)",
            spec.points_per_block
        ))
        .legend(move |(x, y)| Circle::new((x + 10, y), 4, blue.filled()));
    chart
        .draw_series(LineSeries::new(model.iter().copied(), red.stroke_width(3)))?
        .label(format!(
            "fit: {} (χ²/dof {:.2}, backing {:.0} %)",
            model_name(s),
            cal.chi2_per_dof,
            cal.backing_pct
        ))
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], red.stroke_width(3)));
    chart
        .configure_series_labels()
        .label_font((FONT, 17))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .position(SeriesLabelPosition::LowerLeft)
        .draw()?;
    root.present()?;
    Ok(())
}
