//! A trial's raw-signal file: its channels and layout, and the sinks its
//! full-rate rows go to ([`RawSink`]).

use crate::rawsig::{Channel, Dtype, NpyWriter, RawLayout, standard_channels};
use crate::storage::error::ExportError;
use crate::task::Scene;

/// Channels of a trial's raw file: the standard 17
/// ([`standard_channels`]) plus the participant's hand target.
pub fn raw_channels() -> Vec<Channel> {
    let mut c = standard_channels();
    c.push(Channel::new(
        "hand_x",
        "m",
        "participant's hand position (input), x",
    ));
    c.push(Channel::new(
        "hand_y",
        "m",
        "participant's hand position (input), y",
    ));
    c
}

/// Number of raw channels.
pub const RAW_CHANNELS: usize = 19;

/// The raw layout of trials (sample rate, dtype, channels, event legend).
pub fn raw_layout(sample_rate_hz: f64, dtype: Dtype) -> RawLayout {
    let mut attrs = serde_json::Map::new();
    attrs.insert(
        "event_legend".into(),
        serde_json::json!({
            "1": "contact_start", "2": "contact_end", "3": "escaped",
            "4": "recaptured", "5": "camera_frame", "9": "trial_end"
        }),
    );
    RawLayout {
        sample_rate_hz,
        dtype,
        channels: raw_channels(),
        attrs,
    }
}

/// `layout` with the trial's scene in its attributes (`attrs.scene`, sample
/// plane, m): obstacle centre and radius, bead radius, contact radius
/// R_c = R_o + R_b, start position and instructed heading — what is needed
/// to recompute the bead–obstacle gap and `disp_err_mean_um` from the
/// `bead_x`, `bead_y` channels.
pub fn with_scene(mut layout: RawLayout, scene: &Scene) -> RawLayout {
    let g = &scene.geometry;
    layout.attrs.insert(
        "scene".into(),
        serde_json::json!({
            "obstacle_centre_m": g.obstacle_m,
            "obstacle_radius_m": g.obstacle_radius_m,
            "bead_radius_m": g.bead_radius_m,
            "contact_radius_m": g.contact_radius_m(),
            "start_m": scene.start_m,
            "heading": scene.heading,
        }),
    );
    layout
}

/// Where a trial's full-rate rows go.
pub trait RawSink {
    /// One row of [`RAW_CHANNELS`] values.
    ///
    /// # Errors
    /// I/O errors.
    fn push(&mut self, row: &[f64]) -> Result<(), ExportError>;
}

impl RawSink for NpyWriter {
    #[inline]
    fn push(&mut self, row: &[f64]) -> Result<(), ExportError> {
        NpyWriter::push(self, row)
    }
}

/// A sink that drops everything.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoRaw;

impl RawSink for NoRaw {
    #[inline]
    fn push(&mut self, _row: &[f64]) -> Result<(), ExportError> {
        Ok(())
    }
}

impl<S: RawSink + ?Sized> RawSink for Option<&mut S> {
    #[inline]
    fn push(&mut self, row: &[f64]) -> Result<(), ExportError> {
        match self {
            Some(s) => s.push(row),
            None => Ok(()),
        }
    }
}
