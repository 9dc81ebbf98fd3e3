//! What a resume must keep: the rig file, the calibration and raw
//! recording in force when the study's data were taken (the protocol is
//! checked by its own hash in [`super::open::load_session`]). A resume
//! whose settings differ from `session.json`'s would mix two set-ups in one
//! study; it is refused with every difference named, unless the
//! experimenter starts a new sitting with the change recorded
//! ([`super::StudyMeta::recorded_change`]).

use super::session::{CalibrationRef, SessionInfo, StudyMeta};
use kilotouch_rig::units::{to_pn_per_um, to_um_per_v};

/// One setting that differs between the folder and this sitting.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SettingChange {
    /// The setting, in a researcher's words (`rig file`, …).
    pub what: &'static str,
    /// As recorded in `session.json`.
    pub was: String,
    /// In this sitting.
    pub now: String,
}

impl std::fmt::Display for SettingChange {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} was {}, now {}", self.what, self.was, self.now)
    }
}

fn calibration_text(c: Option<&CalibrationRef>) -> String {
    c.map_or_else(
        || "none (as-designed chain)".to_owned(),
        |c| format!("{} (sha256 {})", c.path, c.sha256),
    )
}

fn on_off(b: bool) -> String {
    if b { "on" } else { "off" }.to_owned()
}

/// The settings of `meta` that differ from those `info` records. A setting
/// the folder does not record (an older folder) or the writer does not
/// know is not compared.
pub(crate) fn changes(info: &SessionInfo, meta: &StudyMeta) -> Vec<SettingChange> {
    let mut out = Vec::new();
    if let (Some(was), Some(now)) = (&info.rig_hash, &meta.rig_hash)
        && was != now
    {
        out.push(SettingChange {
            what: "rig file",
            was: format!("content hash {was} (rig `{}`)", info.rig),
            now: format!("content hash {now} (rig `{}`)", meta.rig),
        });
    }
    let (was, now) = (info.calibration.as_ref(), meta.calibration.as_ref());
    if was.map(|c| &c.sha256) != now.map(|c| &c.sha256) {
        out.push(SettingChange {
            what: "calibration",
            was: calibration_text(was),
            now: calibration_text(now),
        });
    }
    // The same calibration read back from session.json may differ in the
    // last bits of its numbers: the applied values are compared to 1e-12.
    let same = |a: f64, b: f64| (a - b).abs() <= 1e-12 * a.abs().max(b.abs());
    if let (Some(was), Some(now)) = (&info.trap_calibration, &meta.trap_calibration)
        && !(was.source == now.source
            && same(was.kappa_n_per_m, now.kappa_n_per_m)
            && same(was.rd_m_per_v[0], now.rd_m_per_v[0])
            && same(was.rd_m_per_v[1], now.rd_m_per_v[1]))
    {
        let text = |t: &kilotouch_rig::tweezer::TrapCalibrationRecord| {
            format!(
                "κ {:.4} pN/µm, R_d {:.5}/{:.5} µm/V ({})",
                to_pn_per_um(t.kappa_n_per_m),
                to_um_per_v(t.rd_m_per_v[0]),
                to_um_per_v(t.rd_m_per_v[1]),
                t.source
            )
        };
        out.push(SettingChange {
            what: "trap calibration",
            was: text(was),
            now: text(now),
        });
    }
    if let (Some(was), Some(now)) = (info.raw_signals, meta.raw_signals)
        && was != now
    {
        out.push(SettingChange {
            what: "raw signal recording",
            was: on_off(was),
            now: on_off(now),
        });
    }
    out
}

/// Makes `info` record the settings of `meta` (after a recorded change, or
/// to fill in settings an older folder did not record).
pub(crate) fn adopt(info: &mut SessionInfo, meta: &StudyMeta) {
    if meta.rig_hash.is_some() {
        info.rig_hash.clone_from(&meta.rig_hash);
        info.rig.clone_from(&meta.rig);
    }
    info.calibration.clone_from(&meta.calibration);
    if meta.raw_signals.is_some() {
        info.raw_signals = meta.raw_signals;
    }
    if meta.trap_calibration.is_some() {
        info.trap_calibration.clone_from(&meta.trap_calibration);
    }
    if meta.camera.is_some() {
        info.camera = meta.camera;
    }
}

#[cfg(test)]
mod tests {
    use kilotouch_rig::tweezer::TrapCalibrationRecord;

    #[test]
    fn a_recorded_trap_calibration_is_written_back_byte_for_byte() {
        // A record `kilotouch tweezer record --calibration-out` wrote when
        // the record held pN/µm: read (SI inside) and written again as a
        // session.json keeps it, with this crate's exact float parser.
        let text = include_str!("../../../rig/tests/data/trap_calibration_record.json");
        let r: TrapCalibrationRecord = serde_json::from_str(text).unwrap();
        assert!((r.kappa_n_per_m - 20.19e-6).abs() < 0.01e-6, "{r:?}");
        assert_eq!(serde_json::to_string_pretty(&r).unwrap() + "\n", text);
    }
}
