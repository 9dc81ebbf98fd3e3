//! Sequence numbers (`docs/PROTOCOL.md` §7): the device numbers samples
//! with 64-bit counters and the wire carries the low 32 bits.

/// Map a 32-bit wire sequence number to the 64-bit one nearest to `near`
/// (streams wrap after 2³² samples, 119 h at 10 kHz); never below 0.
pub fn unwrap_seq(wire: u32, near: u64) -> u64 {
    let d = i64::from(wire.wrapping_sub(near as u32) as i32);
    (near as i64).saturating_add(d).max(0) as u64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sequence_numbers_unwrap_across_the_32_bit_boundary() {
        assert_eq!(unwrap_seq(5, 3), 5);
        assert_eq!(unwrap_seq(2, 3), 2);
        assert_eq!(unwrap_seq(1, (1u64 << 32) - 2), (1u64 << 32) + 1);
        assert_eq!(unwrap_seq(u32::MAX, 1u64 << 32), (1u64 << 32) - 1);
        assert_eq!(unwrap_seq(u32::MAX, 0), 0);
        // Half the range either way.
        assert_eq!(unwrap_seq(0x8000_0000, 0), 0);
        assert_eq!(unwrap_seq(0x7FFF_FFFF, 0), 0x7FFF_FFFF);
    }
}
