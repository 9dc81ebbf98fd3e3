//! The D-mode force splitter of the engine: the dsp [`Chain`] plus a private
//! lock-free inbox through which a new coefficient set (a calibration) is
//! swapped in while the loop runs.
//!
//! The coupling owns its splitter and exposes it read-only, so the swap
//! request travels through an `rtrb` queue polled by the splitter itself:
//! one `is_empty` check (an atomic load) per sample, the swap in a cold
//! function. A swap uses [`Chain::set_coefficients`] (state converted, output
//! cross-faded over the chain's fade length) when the new set has the same
//! structure; otherwise the ready-made replacement chain built on the GUI
//! thread is swapped in whole (state restarts from zero, which can give a
//! small transient). The box travels back to the GUI to be dropped there, so
//! the engine neither allocates nor frees.

use kilotouch_dsp::chain::{Chain, ChainCoefficients};
use kilotouch_rig::coupling::ForceSplitter;

/// A coefficient set on its way to the engine, with a ready-made chain for
/// the case where the structure differs (both built on the GUI thread).
#[derive(Debug)]
pub struct ChainSwap {
    /// The new coefficients.
    pub coefficients: ChainCoefficients,
    /// `Chain::new(&coefficients)`: swapped in whole when the structure
    /// differs from the running chain.
    pub replacement: Chain,
}

impl ChainSwap {
    /// Prepare a swap (allocates: GUI thread).
    pub fn new(coefficients: ChainCoefficients) -> Box<Self> {
        let replacement = Chain::new(&coefficients);
        Box::new(Self {
            coefficients,
            replacement,
        })
    }
}

/// How a swap was carried out.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SwapOutcome {
    /// Same structure: state converted, output cross-faded.
    Faded,
    /// Different structure: the replacement chain took over (state reset).
    Replaced,
    /// Refused: the coefficients are for another sample rate.
    WrongSampleRate,
}

/// A finished swap: the outcome and the box (now holding the old chain) to
/// drop on the GUI side.
#[derive(Debug)]
pub struct SwapDone {
    /// Outcome.
    pub outcome: SwapOutcome,
    /// The box to drop.
    pub garbage: Box<ChainSwap>,
}

/// The engine's D-mode splitter (module docs).
#[derive(Debug)]
pub struct SwappableChain {
    chain: Chain,
    inbox: rtrb::Consumer<Box<ChainSwap>>,
    outbox: rtrb::Producer<SwapDone>,
}

/// The other ends of a [`SwappableChain`]'s queues (kept by the engine).
#[derive(Debug)]
pub struct SwapPort {
    /// Send swaps here.
    pub to_chain: rtrb::Producer<Box<ChainSwap>>,
    /// Finished swaps come back here.
    pub from_chain: rtrb::Consumer<SwapDone>,
}

impl SwappableChain {
    /// Wrap a chain; returns the splitter and the port to drive it.
    pub fn new(chain: Chain) -> (Self, SwapPort) {
        let (to_chain, inbox) = rtrb::RingBuffer::new(2);
        let (outbox, from_chain) = rtrb::RingBuffer::new(2);
        (
            Self {
                chain,
                inbox,
                outbox,
            },
            SwapPort {
                to_chain,
                from_chain,
            },
        )
    }

    /// The running chain.
    pub fn chain(&self) -> &Chain {
        &self.chain
    }

    #[cold]
    #[inline(never)]
    fn take_swap(&mut self) {
        // Wait for room to hand the box back and for a running fade to end.
        if self.outbox.is_full() || self.chain.is_fading() {
            return;
        }
        let Ok(mut swap) = self.inbox.pop() else {
            return;
        };
        let outcome = if swap.coefficients.fs() != self.chain.fs() {
            SwapOutcome::WrongSampleRate
        } else if self.chain.set_coefficients(&swap.coefficients).is_ok() {
            SwapOutcome::Faded
        } else {
            std::mem::swap(&mut self.chain, &mut swap.replacement);
            SwapOutcome::Replaced
        };
        // Cannot fail: checked for room above and only this thread pushes.
        let _ = self.outbox.push(SwapDone {
            outcome,
            garbage: swap,
        });
    }
}

impl ForceSplitter for SwappableChain {
    #[inline]
    fn split(&mut self, force_n: f64) -> (f64, f64) {
        if !self.inbox.is_empty() {
            self.take_swap();
        }
        self.chain.process(force_n)
    }

    fn reset(&mut self) {
        self.chain.reset();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use kilotouch_dsp::chain::ChainDesign;

    #[test]
    fn swap_fades_to_the_new_design_and_returns_the_box() {
        let a = ChainCoefficients::paper().unwrap();
        let b = ChainCoefficients::design(&ChainDesign {
            crossover_hz: 300.0,
            ..ChainDesign::paper()
        })
        .unwrap();
        let (mut s, mut port) = SwappableChain::new(Chain::new(&a));
        let mut reference = Chain::new(&b);
        port.to_chain.push(ChainSwap::new(b.clone())).unwrap();
        for _ in 0..20_000 {
            s.split(1.0);
            reference.process(1.0);
        }
        let done = port.from_chain.pop().unwrap();
        assert_eq!(done.outcome, SwapOutcome::Faded);
        // After the fade the running response is the new design's.
        for f in [50.0, 300.0, 900.0] {
            let (l, h) = s.chain().response(f);
            let (lr, hr) = reference.response(f);
            assert!((l - lr).norm() < 1e-12 && (h - hr).norm() < 1e-12);
        }
        // Step response settled to the same steady state as a chain that always ran b.
        let (x, y) = s.split(1.0);
        let (xr, yr) = reference.process(1.0);
        assert!(
            (x - xr).abs() < 1e-9 && (y - yr).abs() < 1e-9,
            "{x} {xr} {y} {yr}"
        );
    }

    #[test]
    fn wrong_rate_is_refused() {
        let a = ChainCoefficients::paper().unwrap();
        let b = ChainCoefficients::design(&ChainDesign {
            fs: 20_000.0,
            ..ChainDesign::paper()
        })
        .unwrap();
        let (mut s, mut port) = SwappableChain::new(Chain::new(&a));
        port.to_chain.push(ChainSwap::new(b)).unwrap();
        s.split(0.0);
        assert_eq!(
            port.from_chain.pop().unwrap().outcome,
            SwapOutcome::WrongSampleRate
        );
        assert_eq!(s.chain().fs(), a.fs());
    }
}
