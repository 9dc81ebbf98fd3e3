//! The command lead of a pipelined block exchange (`docs/PROTOCOL.md` §7),
//! shared by the DAQ link ([`super::SerialRig`]) and the tweezer link
//! ([`super::LinkTweezer`]): how many samples of commands the host sends
//! ahead of the samples it waits for ([`CommandLead`],
//! [`super::rig::Link::lead_samples`]), the sequence bookkeeping of a run
//! ([`Pipeline`]: the lead's hold commands first, then every block's
//! commands L samples ahead of the block whose samples come back), and the
//! encoding of command blocks ([`super::rig::Link::queue_items`]).

/// The command lead of a link: how many blocks of commands the host sends
/// ahead of the block whose samples it waits for, so that a free-running
/// device always holds its next commands (`docs/PROTOCOL.md` §7). A lead
/// of L samples adds L samples to the loop's delay (the stability analysis
/// includes it, [`crate::Rig::loop_delay_samples`],
/// [`crate::Tweezer::loop_delay_samples`]), and the samples a block returns
/// are then those of the commands sent L samples earlier.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CommandLead {
    /// Enough whole blocks to cover the round trip measured at connection
    /// with a margin (1.5 × round trip + 0.5 ms), at least one block.
    Auto,
    /// This many blocks (0: block-synchronous, sensor frames and commands
    /// of the same samples — what open-loop measurements such as the
    /// calibration need).
    Blocks(u32),
}

/// Largest command lead, samples (well inside the device's command buffer,
/// the emulator's 8192).
pub const MAX_LEAD_SAMPLES: u64 = 2048;

/// The command lead, samples, for blocks of `n` samples of a device at
/// `rate_hz` whose link's round trip measured at connection is
/// `round_trip_s`: `lead=N` blocks, or for [`CommandLead::Auto`] enough
/// whole blocks to cover 1.5 × the round trip + 0.5 ms (at least one
/// block); at most [`MAX_LEAD_SAMPLES`] (whole blocks).
pub fn lead_samples(lead: CommandLead, rate_hz: f64, round_trip_s: Option<f64>, n: usize) -> u64 {
    let n = n.max(1) as u64;
    let blocks = match lead {
        CommandLead::Blocks(b) => u64::from(b),
        CommandLead::Auto => {
            let rtt = round_trip_s.unwrap_or(0.0);
            let need = (1.5 * rtt + 5e-4) * rate_hz / n as f64;
            (need.ceil() as u64).max(1)
        }
    };
    (blocks * n).min(MAX_LEAD_SAMPLES / n * n)
}

/// Sequence bookkeeping of a pipelined run: the samples the host waits for
/// next, the sample its next command is for, and the run's lead (fixed at
/// its first block). A run begins at the device's START answer
/// ([`Pipeline::start`]); its first block queues the lead's hold commands
/// (DAQ: zero; tweezer: the trap where it was reset) before its own.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub(crate) struct Pipeline {
    /// The first sample of the next block the host waits for.
    pub next_seq: u64,
    /// The sample the next command is for (`next_seq` + lead while
    /// running).
    pub sent_until: u64,
    /// The lead of this run, samples (`None` before its first block).
    pub lead: Option<u64>,
}

impl Pipeline {
    /// A new run whose first sample is `seq`.
    pub fn start(seq: u64) -> Self {
        Self {
            next_seq: seq,
            sent_until: seq,
            lead: None,
        }
    }

    /// At the run's first block: fix its lead at `lead` samples and return
    /// the samples `(first, count)` whose hold commands go out first
    /// (`None` once the lead is fixed).
    pub fn open_lead(&mut self, lead: u64) -> Option<(u64, u64)> {
        if self.lead.is_some() {
            return None;
        }
        self.lead = Some(lead);
        self.sent_until = self.next_seq + lead;
        Some((self.next_seq, lead))
    }

    /// The first sample of a block of `n` commands about to be queued
    /// (they are for the samples `lead` after those waited for).
    pub fn queue(&mut self, n: usize) -> u64 {
        let s = self.sent_until;
        self.sent_until += n as u64;
        s
    }

    /// The block of `n` samples waited for was accounted for.
    pub fn received(&mut self, n: usize) {
        self.next_seq += n as u64;
    }

    /// This run's lead, or `next` (the lead the next run would take).
    pub fn lead_or(&self, next: impl FnOnce() -> u64) -> u64 {
        self.lead.unwrap_or_else(next)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_run_sends_its_lead_first_then_every_block_lead_samples_ahead() {
        let mut p = Pipeline::start(100);
        assert_eq!(p.open_lead(20), Some((100, 20)));
        assert_eq!(
            p.open_lead(30),
            None,
            "the lead is fixed at the first block"
        );
        assert_eq!(p.queue(10), 120);
        p.received(10);
        assert_eq!(p.queue(10), 130);
        p.received(10);
        assert_eq!((p.next_seq, p.sent_until), (120, 140));
        assert_eq!(p.sent_until - p.next_seq, 20);
        assert_eq!(p.lead_or(|| 99), 20);
        assert_eq!(Pipeline::start(0).lead_or(|| 99), 99);
    }

    /// Auto: ⌈(1.5 · rtt + 0.5 ms) · f_s / n⌉ blocks, at least one; bounded.
    #[test]
    fn the_automatic_lead_covers_the_round_trip_in_whole_blocks() {
        let auto = |rtt: f64, n| lead_samples(CommandLead::Auto, 1e4, Some(rtt), n);
        assert_eq!(auto(0.0, 10), 10, "0.5 ms = 5 samples: one block");
        assert_eq!(auto(1e-3, 10), 20, "2 ms = 20 samples: two blocks");
        assert_eq!(auto(1.1e-3, 10), 30, "2.15 ms: three blocks");
        assert_eq!(auto(1.0, 10), MAX_LEAD_SAMPLES / 10 * 10);
        assert_eq!(lead_samples(CommandLead::Auto, 1e4, None, 1), 5);
        assert_eq!(lead_samples(CommandLead::Blocks(3), 1e4, Some(1.0), 10), 30);
        assert_eq!(lead_samples(CommandLead::Blocks(0), 1e4, None, 10), 0);
    }
}
