//! Attention lapses of the simulated operator ([`crate::operator`]): when
//! they start and how long they last, fitted to short, self-paced,
//! trial-based work by rested adults.
//!
//! * **Rate.** Lapse starts form a Poisson process whose rate grows
//!   linearly with the time on task τ since the last break (the start of
//!   the block): λ(τ) = λ₀·(1 + g·τ / 600 s). λ₀ is
//!   `operator::OperatorParams::lapse_rate_per_h` (per participant, log-normal
//!   between participants) and g is `lapse_growth_per_10min`. The process
//!   is sampled exactly, by inverting its integrated rate (a quadratic in
//!   the waiting time), not by a per-step coin.
//! * **Duration.** `lapse_min_s` plus an exponential, so that the mean is
//!   `lapse_mean_s`. A lapse that starts while another is under way
//!   prolongs it (the starts stay a Poisson process; the episodes merge).
//! * **Time on task** comes with each trial ([`TrialBrief::time_on_task_s`]):
//!   what the trial's participant had done since the block began. A
//!   simulated study runs a block's trials in parallel and a resumed one
//!   re-runs single trials, so there every trial must be a function of its
//!   key alone: its time on task is the nominal one,
//!   [`crate::operator::nominal_time_on_task_s`] (the trials before it in its block times a
//!   nominal trial plus the inter-trial interval).
//!
//! Sources, numbers and limits: `docs/STUDY.md` §13, "Attention lapses".
//!
//! [`TrialBrief::time_on_task_s`]: crate::participant::TrialBrief::time_on_task_s

use rand_chacha::ChaCha20Rng;

use crate::task::unit_uniform;

/// Time on task over which `lapse_growth_per_10min` is the relative rate
/// increase, s (the standard 10-min psychomotor vigilance test).
pub const GROWTH_SPAN_S: f64 = 600.0;

/// The lapse process of one participant (module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LapseModel {
    /// Rate at time on task 0, per s (≥ 0; not finite or ≤ 0: no lapses).
    pub rate0_per_s: f64,
    /// Relative rate increase per [`GROWTH_SPAN_S`] of time on task (≥ 0;
    /// a negative value counts as 0).
    pub growth: f64,
    /// Shortest lapse, s.
    pub min_s: f64,
    /// Mean lapse, s (at least `min_s`).
    pub mean_s: f64,
}

impl LapseModel {
    fn active(&self) -> bool {
        self.rate0_per_s > 0.0 && self.rate0_per_s.is_finite()
    }

    fn slope(&self) -> f64 {
        if self.growth.is_finite() {
            self.growth.max(0.0) / GROWTH_SPAN_S
        } else {
            0.0
        }
    }

    /// λ(τ), per s, at time on task `tau_s` (s).
    pub fn rate_per_s(&self, tau_s: f64) -> f64 {
        if !self.active() {
            return 0.0;
        }
        self.rate0_per_s * (1.0 + self.slope() * tau_s.max(0.0))
    }

    /// ∫ λ dτ from time on task `a_s` to `b_s` (s; a ≤ b): the expected
    /// number of lapse starts in between.
    pub fn expected_starts(&self, a_s: f64, b_s: f64) -> f64 {
        if !self.active() {
            return 0.0;
        }
        let (a, b) = (a_s.max(0.0), b_s.max(0.0));
        self.rate0_per_s * ((b - a) + 0.5 * self.slope() * (b * b - a * a))
    }

    /// The waiting time from time on task `tau_s` to the next start, s,
    /// for a unit exponential `e` (the integrated rate over the wait is
    /// `e`): the positive root of λ₀·(w + k·(2τ·w + w²)/2) = e with k the
    /// slope, in a form without cancellation. Infinite without lapses.
    pub fn wait_s(&self, tau_s: f64, e: f64) -> f64 {
        if !self.active() {
            return f64::INFINITY;
        }
        let a = 0.5 * self.rate0_per_s * self.slope();
        let b = self.rate_per_s(tau_s);
        2.0 * e / (b + (b * b + 4.0 * a * e).sqrt())
    }

    /// A lapse's duration for a unit exponential `e`, s.
    pub fn duration_s(&self, e: f64) -> f64 {
        let min = self.min_s.max(0.0);
        min + (self.mean_s - min).max(0.0) * e
    }
}

/// A unit exponential from `rng`: −ln u with u in (0, 1].
fn exp1(rng: &mut ChaCha20Rng) -> f64 {
    -(1.0 - unit_uniform(rng)).ln()
}

/// The lapses of one trial, drawn from the trial's lapse stream as the
/// trial goes on (allocation-free).
#[derive(Debug, Clone)]
pub struct LapseSchedule {
    model: LapseModel,
    /// Time on task at the trial's start, s.
    offset_s: f64,
    /// Next start, s since the trial start.
    next_start_s: f64,
    /// End of the latest lapse, s since the trial start.
    end_s: f64,
    /// Starts reached so far.
    starts: u32,
}

impl Default for LapseSchedule {
    fn default() -> Self {
        Self {
            model: LapseModel {
                rate0_per_s: 0.0,
                growth: 0.0,
                min_s: 0.0,
                mean_s: 0.0,
            },
            offset_s: 0.0,
            next_start_s: f64::INFINITY,
            end_s: f64::NEG_INFINITY,
            starts: 0,
        }
    }
}

impl LapseSchedule {
    /// Starts a trial whose participant has been `time_on_task_s` (s) on
    /// task: draws the first start from `rng`.
    pub fn begin(&mut self, model: LapseModel, time_on_task_s: f64, rng: &mut ChaCha20Rng) {
        self.model = model;
        self.offset_s = if time_on_task_s.is_finite() {
            time_on_task_s.max(0.0)
        } else {
            0.0
        };
        self.end_s = f64::NEG_INFINITY;
        self.starts = 0;
        self.next_start_s = if model.active() {
            model.wait_s(self.offset_s, exp1(rng))
        } else {
            f64::INFINITY
        };
    }

    /// Whether a lapse is under way at `t_s` (s since the trial start; call
    /// with non-decreasing times): reaches every start up to `t_s`, drawing
    /// its duration and the next start from `rng`.
    pub fn lapsing(&mut self, t_s: f64, rng: &mut ChaCha20Rng) -> bool {
        while self.next_start_s <= t_s {
            let start = self.next_start_s;
            self.starts = self.starts.saturating_add(1);
            self.end_s = self.end_s.max(start + self.model.duration_s(exp1(rng)));
            self.next_start_s = start + self.model.wait_s(self.offset_s + start, exp1(rng));
        }
        t_s < self.end_s
    }

    /// Lapses started so far in this trial.
    pub fn starts(&self) -> u32 {
        self.starts
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use rand_chacha::rand_core::SeedableRng;

    use super::*;

    fn model(rate_per_h: f64, growth: f64) -> LapseModel {
        LapseModel {
            rate0_per_s: rate_per_h / 3600.0,
            growth,
            min_s: 0.25,
            mean_s: 0.6,
        }
    }

    /// Counts of starts in [0, T] of trials beginning at time on task
    /// `tau0`: their mean and variance match ∫λ dt (a Poisson count has
    /// both equal to it), within 5 standard errors.
    fn check_poisson(m: LapseModel, tau0: f64, horizon: f64, seed: u64) {
        let n = 20_000;
        let mut rng = ChaCha20Rng::seed_from_u64(seed);
        let mut counts = Vec::with_capacity(n);
        let mut s = LapseSchedule::default();
        for _ in 0..n {
            s.begin(m, tau0, &mut rng);
            s.lapsing(horizon, &mut rng);
            // Starts reached are those at or before the horizon.
            counts.push(f64::from(s.starts()));
        }
        let mu = m.expected_starts(tau0, tau0 + horizon);
        let nf = n as f64;
        let mean = counts.iter().sum::<f64>() / nf;
        let var = counts.iter().map(|c| (c - mean).powi(2)).sum::<f64>() / (nf - 1.0);
        // SE of the mean: √(μ/n); SE of the sample variance of a Poisson
        // count: √((μ + 2μ²)/n) (its fourth central moment is μ + 3μ²).
        let se_mean = (mu / nf).sqrt();
        let se_var = ((mu + 2.0 * mu * mu) / nf).sqrt();
        assert!(
            (mean - mu).abs() < 5.0 * se_mean,
            "mean {mean} vs ∫λ = {mu} (SE {se_mean})"
        );
        assert!(
            (var - mu).abs() < 5.0 * se_var,
            "variance {var} vs ∫λ = {mu} (SE {se_var})"
        );
    }

    #[test]
    fn starts_are_a_poisson_process_with_the_time_varying_rate() {
        // A high rate so the counts are large: 2 per s growing 3× per
        // 600 s, over 30 s from 0 and from 20 min on task.
        check_poisson(model(7200.0, 3.0), 0.0, 30.0, 1);
        check_poisson(model(7200.0, 3.0), 1200.0, 30.0, 2);
        // The default-like regime: a few per hour over a 10-min block.
        check_poisson(model(6.0, 1.0), 0.0, 600.0, 3);
        // No growth: a homogeneous process.
        check_poisson(model(360.0, 0.0), 0.0, 60.0, 4);
    }

    #[test]
    fn the_waiting_time_inverts_the_integrated_rate() {
        let m = model(40.0, 2.0);
        for &(tau, e) in &[(0.0, 0.1), (0.0, 3.0), (300.0, 1.0), (5000.0, 0.01)] {
            let w = m.wait_s(tau, e);
            let got = m.expected_starts(tau, tau + w);
            assert!((got - e).abs() < 1e-9 * e.max(1.0), "{got} vs {e}");
        }
    }

    #[test]
    fn durations_have_the_parameter_mean_and_floor() {
        let m = model(3600.0, 0.0);
        let mut rng = ChaCha20Rng::seed_from_u64(5);
        let n = 100_000;
        let d: Vec<f64> = (0..n).map(|_| m.duration_s(exp1(&mut rng))).collect();
        let mean = d.iter().sum::<f64>() / n as f64;
        // Exponential part of mean 0.35 s: SD 0.35 s.
        let se = (m.mean_s - m.min_s) / (n as f64).sqrt();
        assert!((mean - m.mean_s).abs() < 5.0 * se, "mean {mean}");
        assert!(d.iter().all(|&x| x >= m.min_s));
    }

    #[test]
    fn rate_grows_with_time_on_task_and_is_back_at_its_base_after_a_break() {
        let m = model(6.0, 1.0);
        let r0 = m.rate_per_s(0.0);
        assert_eq!(r0, 6.0 / 3600.0);
        assert!(m.rate_per_s(300.0) > r0);
        assert!((m.rate_per_s(600.0) / r0 - 2.0).abs() < 1e-12);
        // Drawn lapses follow: over many trials at 20 min on task, more
        // starts than at 0 with the same seed.
        let m = model(360.0, 1.0);
        let count = |tau: f64| {
            let mut rng = ChaCha20Rng::seed_from_u64(9);
            let mut s = LapseSchedule::default();
            (0..2000)
                .map(|_| {
                    s.begin(m, tau, &mut rng);
                    s.lapsing(20.0, &mut rng);
                    s.starts()
                })
                .sum::<u32>()
        };
        assert!(count(1200.0) > 2 * count(0.0));
    }

    #[test]
    fn a_zero_rate_gives_no_lapses() {
        for rate in [0.0, -1.0, f64::NAN] {
            let m = LapseModel {
                rate0_per_s: rate,
                ..model(0.0, 1.0)
            };
            let mut rng = ChaCha20Rng::seed_from_u64(11);
            let mut s = LapseSchedule::default();
            s.begin(m, 100.0, &mut rng);
            let mut any = false;
            for k in 0..100_000 {
                any |= s.lapsing(f64::from(k) * 0.01, &mut rng);
            }
            assert!(!any);
            assert_eq!(s.starts(), 0);
            assert_eq!(m.expected_starts(0.0, 1e6), 0.0);
        }
    }

    #[test]
    fn a_lapse_covers_its_start_to_its_end() {
        // Always lapsing once a start is reached with long lapses.
        let m = LapseModel {
            rate0_per_s: 1.0,
            growth: 0.0,
            min_s: 5.0,
            mean_s: 5.0,
        };
        let mut rng = ChaCha20Rng::seed_from_u64(3);
        let mut s = LapseSchedule::default();
        s.begin(m, 0.0, &mut rng);
        let first = s.next_start_s;
        assert!(!s.lapsing(first - 1e-9, &mut rng));
        assert!(s.lapsing(first, &mut rng));
        assert!(s.lapsing(first + 4.9, &mut rng));
    }
}
