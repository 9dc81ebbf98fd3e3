//! The Study page's form: what the experimenter types and chooses before a
//! sitting opens (protocol, participant ID, output folder, participant
//! kind, pacing, calibration), and its validation into a sitting's
//! settings, with errors in the researcher's words. No egui here: the
//! view (`setup.rs`) edits these fields.

use std::path::{Path, PathBuf};

use crate::session::{ParticipantKind, Speed};

/// Where the protocol comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ProtocolSource {
    /// Built-in `paper` (circling, V/P/D).
    Paper,
    /// Built-in `blind` (blind navigation).
    Blind,
    /// A TOML file.
    File,
}

/// Which chain D runs in a sitting (recorded in `session.json` and the
/// journal with the file's SHA-256).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum CalibrationChoice {
    /// The calibration applied to the engine on the Calibration page (its
    /// file); the as-designed chain when none is applied.
    #[default]
    Applied,
    /// The model's as-designed chain, recorded as uncalibrated.
    AsDesigned,
    /// A calibration file typed in.
    File,
}

/// The Study page's form fields, as typed and chosen.
#[derive(Debug, Clone, PartialEq)]
pub struct StudyForm {
    /// Protocol source.
    pub source: ProtocolSource,
    /// Protocol file path (for [`ProtocolSource::File`]).
    pub protocol_file: String,
    /// Participant ID as typed.
    pub participant_text: String,
    /// Output folder as typed (initialised from the settings).
    pub out_text: String,
    /// Person at the mouse or simulated participant.
    pub kind: ParticipantKind,
    /// Pacing (as fast as possible: simulated participant only).
    pub speed: Speed,
    /// Which chain D runs.
    pub calibration: CalibrationChoice,
    /// Calibration file (for [`CalibrationChoice::File`]).
    pub calibration_file: String,
}

impl Default for StudyForm {
    fn default() -> Self {
        Self {
            source: ProtocolSource::Paper,
            protocol_file: String::new(),
            participant_text: String::new(),
            out_text: String::new(),
            kind: ParticipantKind::Mouse,
            speed: Speed::RealTime,
            calibration: CalibrationChoice::default(),
            calibration_file: String::new(),
        }
    }
}

impl StudyForm {
    /// The output folder, or an error when none is typed.
    pub fn out_folder(&self) -> Result<PathBuf, String> {
        let t = self.out_text.trim();
        if t.is_empty() {
            Err("choose an output folder".into())
        } else {
            Ok(PathBuf::from(t))
        }
    }

    /// The calibration file the sitting runs and records (`None`: the
    /// as-designed chain, recorded as uncalibrated). `applied` is the
    /// calibration applied on the Calibration page: `None` when none is,
    /// `Some(None)` when it was never saved to a file.
    pub fn calibration_path(
        &self,
        applied: Option<Option<&Path>>,
    ) -> Result<Option<PathBuf>, String> {
        match self.calibration {
            CalibrationChoice::AsDesigned => Ok(None),
            CalibrationChoice::Applied => match applied {
                None => Ok(None),
                Some(Some(p)) => Ok(Some(p.to_path_buf())),
                Some(None) => Err(
                    "the applied calibration was not saved: save it on the Calibration page \
                     (a study records the file and its SHA-256), or choose another chain"
                        .into(),
                ),
            },
            CalibrationChoice::File => {
                let t = self.calibration_file.trim();
                if t.is_empty() {
                    Err("type the calibration file, or choose another chain".into())
                } else {
                    Ok(Some(PathBuf::from(t)))
                }
            }
        }
    }

    /// Who takes part: the handle on a live rig; the mouse instead of the
    /// handle on the simulated rig; else as chosen.
    pub fn participant_kind(&self, live: bool) -> ParticipantKind {
        if live {
            ParticipantKind::Handle
        } else if self.kind == ParticipantKind::Handle {
            ParticipantKind::Mouse
        } else {
            self.kind
        }
    }

    /// The pacing of a sitting with participant `kind`: as chosen for the
    /// simulated participant, real time for a person.
    pub fn speed_for(&self, kind: ParticipantKind) -> Speed {
        if kind == ParticipantKind::Simulated {
            self.speed
        } else {
            Speed::RealTime
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn out_folder_must_be_typed() {
        let mut f = StudyForm {
            out_text: "  ".into(),
            ..StudyForm::default()
        };
        assert_eq!(f.out_folder(), Err("choose an output folder".into()));
        f.out_text = " /tmp/s1 ".into();
        assert_eq!(f.out_folder(), Ok(PathBuf::from("/tmp/s1")));
    }

    #[test]
    fn calibration_choices_resolve() {
        let mut f = StudyForm {
            calibration: CalibrationChoice::Applied,
            ..StudyForm::default()
        };
        let saved = Path::new("/cal/c.toml");
        assert_eq!(f.calibration_path(None), Ok(None));
        assert_eq!(
            f.calibration_path(Some(Some(saved))),
            Ok(Some(saved.to_path_buf()))
        );
        let unsaved = f.calibration_path(Some(None)).unwrap_err();
        assert!(unsaved.contains("was not saved"), "{unsaved}");
        f.calibration = CalibrationChoice::AsDesigned;
        assert_eq!(f.calibration_path(Some(Some(saved))), Ok(None));
        f.calibration = CalibrationChoice::File;
        let empty = f.calibration_path(None).unwrap_err();
        assert!(empty.contains("type the calibration file"), "{empty}");
        f.calibration_file = " /x/y.toml ".into();
        assert_eq!(
            f.calibration_path(None),
            Ok(Some(PathBuf::from("/x/y.toml")))
        );
    }

    #[test]
    fn participant_and_pacing_follow_the_rig() {
        let mut f = StudyForm {
            kind: ParticipantKind::Simulated,
            speed: Speed::Fast,
            ..StudyForm::default()
        };
        assert_eq!(f.participant_kind(true), ParticipantKind::Handle);
        assert_eq!(f.participant_kind(false), ParticipantKind::Simulated);
        assert_eq!(f.speed_for(ParticipantKind::Simulated), Speed::Fast);
        assert_eq!(f.speed_for(ParticipantKind::Mouse), Speed::RealTime);
        f.kind = ParticipantKind::Handle;
        assert_eq!(f.participant_kind(false), ParticipantKind::Mouse);
    }
}
