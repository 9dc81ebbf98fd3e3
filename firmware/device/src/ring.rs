//! The command buffer: commands for the next [`RING`] samples, each stored
//! in the slot of its sequence number modulo [`RING`] with the sequence
//! number as its tag (a slot whose tag differs is empty).

use kilotouch_proto::DaqCommand;

/// Commands buffered ahead of execution, samples: 0.2 s at 10 kHz, eight
/// host blocks of 256 samples (the calibration's), ≥ 2 blocks of any size
/// the host uses (docs/FIRMWARE.md). 2048 × 14 bytes of RAM.
pub const RING: usize = 2048;

const EMPTY: u64 = u64::MAX;

/// Fixed-size command buffer (module docs).
#[derive(Debug, Clone)]
pub struct CommandRing {
    tag: [u64; RING],
    cmd: [DaqCommand; RING],
}

impl Default for CommandRing {
    fn default() -> Self {
        Self::new()
    }
}

impl CommandRing {
    /// Empty buffer.
    pub const fn new() -> Self {
        Self {
            tag: [EMPTY; RING],
            cmd: [DaqCommand {
                force: [0; 2],
                drive: 0,
            }; RING],
        }
    }

    /// Forget every command.
    pub fn clear(&mut self) {
        self.tag = [EMPTY; RING];
    }

    /// Store the command for sample `seq` (replacing one sent before).
    pub fn put(&mut self, seq: u64, c: DaqCommand) {
        let i = (seq % RING as u64) as usize;
        self.tag[i] = seq;
        self.cmd[i] = c;
    }

    /// Take the command for sample `seq`, if it is here.
    pub fn take(&mut self, seq: u64) -> Option<DaqCommand> {
        let i = (seq % RING as u64) as usize;
        (self.tag[i] == seq).then(|| {
            self.tag[i] = EMPTY;
            self.cmd[i]
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn commands_come_back_by_sequence_number_once() {
        let mut r = CommandRing::new();
        let c = |k: i16| DaqCommand {
            force: [k, -k],
            drive: k,
        };
        r.put(5, c(1));
        r.put(5 + RING as u64, c(2)); // same slot, a later sample
        assert_eq!(r.take(5), None);
        assert_eq!(r.take(5 + RING as u64), Some(c(2)));
        assert_eq!(r.take(5 + RING as u64), None);
        r.put(7, c(3));
        r.clear();
        assert_eq!(r.take(7), None);
    }
}
