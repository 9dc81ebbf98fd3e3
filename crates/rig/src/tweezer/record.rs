//! Recording a tweezer's detector signals and calibrating both axes from
//! the record, for `kilotouch tweezer calibrate` and `record` and the GUI's
//! Rig page: [`record`] is the one path from a rig spec (`sim`,
//! `serial:PATH`) to a [`DetectorRecord`]; [`calibrate_axes`] runs the
//! passive power-spectral calibration of [`super::calibration`] on each
//! axis with the settings a rig file implies ([`default_settings`]).

use super::calibration::{
    MAX_RECORD_SAMPLES, RECORD_BLOCK, TrapCalibrationSettings, calibrate_trap, record_detector,
};
use super::{
    DetectedTweezer, SurfaceDrag, TrapCalibrationRecord, Tweezer, TweezerParams, surface_drag,
};
use crate::config::RigConfig;
use crate::device::RigSpec;
use crate::error::RigError;
use crate::serial::LinkTweezer;
use kilotouch_dsp::trap_psd::PsdFit;

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
    use super::calibration::{DEFAULT_BEAD_DENSITY_KG_M3, DEFAULT_FLUID_DENSITY_KG_M3};
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
) -> Result<DetectorRecord, RigError> {
    if !(duration_s.is_finite() && duration_s > 0.0) {
        return Err(RigError::InvalidInput(format!(
            "the duration must be finite and > 0 s, got {duration_s}"
        )));
    }
    if !trap_m.iter().all(|v| v.is_finite()) {
        return Err(RigError::InvalidInput(
            "the trap position must be finite".into(),
        ));
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
            record_from(&mut tw, duration_s, trap_m, progress).map_err(|e| {
                match tw.take_failure() {
                    Some(f) => RigError::In {
                        context: e.to_string(),
                        source: Box::new(f),
                    },
                    None => e,
                }
            })?
        }
        RigSpec::Audio(_) => {
            return Err(RigError::InvalidInput(
                "an audio interface has no tweezer; use sim or serial:PATH".into(),
            ));
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
) -> Result<(f64, [Vec<f64>; 2]), RigError> {
    let fs = tw.sample_rate_hz();
    let n = (duration_s * fs).round();
    if n > MAX_RECORD_SAMPLES as f64 {
        return Err(RigError::InvalidInput(format!(
            "{duration_s} s is {n} samples at {fs} Hz; at most {MAX_RECORD_SAMPLES}"
        )));
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
) -> Result<(TrapCalibrationRecord, [PsdFit; 2]), RigError> {
    let s = TrapCalibrationSettings {
        fs_hz: rec.fs_hz,
        ..s.clone()
    };
    let axis = |name: &str, e: RigError| RigError::In {
        context: format!("{name} axis"),
        source: Box::new(e),
    };
    let (cx, fx) = calibrate_trap(&rec.volts[0], &s).map_err(|e| axis("x", e))?;
    let (cy, fy) = calibrate_trap(&rec.volts[1], &s).map_err(|e| axis("y", e))?;
    let n = rec.volts[0].len();
    Ok((
        TrapCalibrationRecord::new(&rec.source, n, s, cx, cy),
        [fx, fy],
    ))
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
