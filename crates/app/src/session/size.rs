//! What a sitting will write, estimated before it opens (module
//! [`kilotouch_study::size`]): one function for the Study page and
//! `kilotouch study run`.

use kilotouch_study::export::{SESSION_FILE, read_session};
use kilotouch_study::simulate::SimulateOptions;
use kilotouch_study::size::{
    SpaceError, StudySize, available_space, bound_sitting, estimate_sitting, format_bytes,
};

use super::SessionOptions;

/// What the sitting `opts` will write and the free space of its folder's
/// disk (`assume_free`: this many bytes instead of asking the operating
/// system): the upper bound (every pending trial of the participant `only`
/// to its time-out, [`bound_sitting`]: only `trials.csv` is read) when it
/// is below both `threshold` and the free space, else the estimate
/// ([`estimate_sitting`]: the folder's raw files, or a pilot of a few
/// pending trials by the simulated participant, which takes seconds). The
/// Study page runs it on a thread of its own; `kilotouch study run` before
/// it connects.
///
/// # Errors
/// The folder's protocol cannot be read, the estimate or the free-space
/// query failed (in a researcher's words).
pub fn estimate_size(
    opts: &SessionOptions,
    only: Option<u32>,
    assume_free: Option<u64>,
    threshold: u64,
) -> Result<(StudySize, u64), String> {
    let protocol = match &opts.protocol {
        Some(p) => p.clone(),
        None => {
            read_session(&opts.out.join(SESSION_FILE))
                .map_err(|e| format!("reading the folder's protocol: {e}"))?
                .protocol
        }
    };
    let mut sim = SimulateOptions::new(protocol, &opts.out);
    sim.resume = opts.protocol.is_none();
    sim.rig = opts.rig.clone();
    sim.calibration.clone_from(&opts.calibration);
    sim.runner = opts.runner;
    sim.threads = 1;
    let available = match assume_free {
        Some(b) => b,
        None => available_space(&opts.out)
            .map_err(|e| format!("free space of the disk of {}: {e}", opts.out.display()))?,
    };
    let bound = bound_sitting(&sim, only)
        .map_err(|e| format!("estimating the size of the sitting: {e}"))?;
    if bound.bytes <= threshold.min(available) {
        return Ok((bound, available));
    }
    let size = estimate_sitting(&sim, only)
        .map_err(|e| format!("estimating the size of the sitting: {e}"))?;
    Ok((size, available))
}

/// The refusal of a sitting that does not fit its disk, with the numbers
/// and the ways out; `no_raw` names the way to write without raw signals
/// where the reader is ("add --no-raw", "run without raw signals").
pub fn space_refusal(e: &SpaceError, no_raw: &str) -> String {
    format!(
        "not enough disk space: the sitting would write {} to {} and the disk has {} free. Free \
         some space, choose a folder on another disk, or {no_raw} (about {}).",
        format_bytes(e.size.bytes),
        e.target.display(),
        format_bytes(e.available),
        format_bytes(e.size.no_raw_bytes)
    )
}
