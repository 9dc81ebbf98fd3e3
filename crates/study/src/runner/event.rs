//! Event codes of the raw `event` channel (legend in the sidecar's
//! `attrs.event_legend`, [`super::raw_layout`]).

/// The bead entered the tweezer's contact zone.
pub const CONTACT_START: f64 = 1.0;
/// The bead left it.
pub const CONTACT_END: f64 = 2.0;
/// The bead escaped the trap.
pub const ESCAPED: f64 = 3.0;
/// A lost bead was recaptured.
pub const RECAPTURED: f64 = 4.0;
/// A camera frame was captured.
pub const FRAME: f64 = 5.0;
/// The trial ended at this sample.
pub const END: f64 = 9.0;
