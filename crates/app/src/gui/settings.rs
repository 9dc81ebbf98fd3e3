//! Settings persisted between runs through eframe's storage (the window
//! size and position are persisted by eframe itself).

use super::scene::CameraModel;
use crate::engine::Condition;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// Storage key of [`Settings`].
pub const KEY: &str = "kilotouch-settings";

/// The pages of the app, in tab order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Page {
    /// Rig selection, connection, status.
    #[default]
    Rig,
    /// Calibration wizard.
    Calibration,
    /// Free exploration of the bead.
    Explore,
    /// Study sessions.
    Study,
    /// Results and statistics.
    Results,
}

impl Page {
    /// All pages in tab order.
    pub const ALL: [Page; 5] = [
        Page::Rig,
        Page::Calibration,
        Page::Explore,
        Page::Study,
        Page::Results,
    ];

    /// Tab title.
    pub fn title(self) -> &'static str {
        match self {
            Page::Rig => "Rig",
            Page::Calibration => "Calibration",
            Page::Explore => "Explore",
            Page::Study => "Study",
            Page::Results => "Results",
        }
    }
}

/// What the app remembers (`#[serde(default)]`: older or partial settings load).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Settings {
    /// Page shown last.
    pub page: Page,
    /// Rig file last loaded (`None` = built-in default).
    pub rig_file: Option<PathBuf>,
    /// Rig last connected, in `--rig` syntax (`sim`, `serial:PATH[,…]`,
    /// `audio[:DEVICE]`); `None` = the simulated rig.
    pub rig_spec: Option<String>,
    /// Tweezer last connected, in `--tweezer` syntax (`serial:PATH[,…]`);
    /// `None` = the simulated tweezer.
    #[serde(default)]
    pub tweezer_spec: Option<String>,
    /// Study protocol last used: `paper` / `blind` (built-in) or `file`.
    pub protocol_source: Option<String>,
    /// Study protocol file last used (with `protocol_source = "file"`).
    pub protocol_file: Option<PathBuf>,
    /// Study output folder last used.
    pub output_dir: Option<PathBuf>,
    /// Camera model of the scene.
    pub camera: CameraModel,
    /// Condition last selected on the Explore page.
    pub condition: Condition,
    /// Length of the live traces, s.
    pub trace_seconds: f64,
}

impl Default for Settings {
    fn default() -> Self {
        Self {
            page: Page::Explore,
            rig_file: None,
            rig_spec: None,
            tweezer_spec: None,
            protocol_source: None,
            protocol_file: None,
            output_dir: None,
            camera: CameraModel::default(),
            condition: Condition::D,
            trace_seconds: 2.0,
        }
    }
}

impl Settings {
    /// Load from eframe storage (defaults when absent or unreadable).
    pub fn load(storage: Option<&dyn eframe::Storage>) -> Self {
        storage
            .and_then(|s| eframe::get_value::<Settings>(s, KEY))
            .unwrap_or_default()
    }

    /// Save to eframe storage.
    pub fn save(&self, storage: &mut dyn eframe::Storage) {
        eframe::set_value(storage, KEY, self);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashMap;

    #[derive(Default)]
    struct Mem(HashMap<String, String>);
    impl eframe::Storage for Mem {
        fn get_string(&self, key: &str) -> Option<String> {
            self.0.get(key).cloned()
        }
        fn set_string(&mut self, key: &str, value: String) {
            self.0.insert(key.into(), value);
        }
        fn remove_string(&mut self, key: &str) {
            self.0.remove(key);
        }
        fn flush(&mut self) {}
    }

    #[test]
    fn settings_round_trip_and_tolerate_garbage() {
        let mut m = Mem::default();
        let s = Settings {
            page: Page::Results,
            rig_file: Some("/tmp/rig.toml".into()),
            rig_spec: Some("serial:/dev/ttyACM0".into()),
            tweezer_spec: Some("serial:/dev/ttyACM1".into()),
            protocol_source: Some("file".into()),
            protocol_file: Some("/tmp/p.toml".into()),
            output_dir: Some("/tmp/out".into()),
            condition: Condition::V,
            ..Default::default()
        };
        s.save(&mut m);
        assert_eq!(Settings::load(Some(&m)), s);
        eframe::Storage::set_string(&mut m, KEY, "not ron at all (".into());
        assert_eq!(Settings::load(Some(&m)), Settings::default());
        assert_eq!(Settings::load(None), Settings::default());
    }
}
