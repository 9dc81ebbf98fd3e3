//! Simulated studies drawn from a [`PilotModel`] and analysed with the
//! statistics of `kilotouch stats` ([`crate::stats::paired_t`],
//! [`crate::stats::rm_anova`] with the Greenhouse–Geisser p-value).
//!
//! One replication = n participants × k conditions × `trials` test trials:
//!
//! 1. participant i's true means b_i = μ + L z, z ~ N(0, I_k);
//! 2. per condition, p_ij ~ Beta(α_j, β_j) (or p̂_j without spread), and
//!    s_ij ~ Binomial(trials, p_ij) successful trials — rejected trials drop
//!    out of the cell mean as in a real study;
//! 3. the cell mean of the s_ij kept trials is b_ij + ē_ij with
//!    ē_ij ~ N(0, σ²_e,j / s_ij) (exactly the distribution of the mean of
//!    s_ij residuals, drawn at once); for the DV `success` it is s_ij/trials;
//! 4. a participant with a cell without kept trials is deleted listwise;
//! 5. the test runs on the complete participants' cell means; a study the
//!    test cannot analyse (fewer than 2 complete participants, zero
//!    variance) counts as *not* rejecting H₀.
//!
//! Each replication draws from its own generator
//! ([`crate::seeds::replication_rng`]), so results do not depend on the
//! number of threads or on the order in which replications run.

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::time::Duration;

use rand_chacha::ChaCha20Rng;
use rand_distr::{Beta, Binomial, Distribution, StandardNormal};

use super::model::{PilotModel, SuccessModel};
use crate::seeds::replication_rng;
use crate::stats::{CellMatrix, paired_t, rm_anova};

/// The test applied to each simulated study.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Analysis {
    /// Paired t-test of condition 0 against condition 1 (two-sided).
    PairedT,
    /// Repeated-measures ANOVA, Greenhouse–Geisser-corrected p.
    RmGg,
}

/// What is simulated: the model with the assumed condition means.
#[derive(Debug)]
pub struct Scenario<'a> {
    /// The fitted model (covariances, residuals, success spread).
    pub model: &'a PilotModel,
    /// Condition means of the DV to simulate (the effect applied).
    pub means: Vec<f64>,
    /// Success model per condition (for the DV `success`, with the effect
    /// applied to p).
    pub success: Vec<SuccessModel>,
    /// The test.
    pub analysis: Analysis,
    /// Significance level α.
    pub alpha: f64,
}

/// Outcome of one simulated study.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Outcome {
    /// H₀ rejected at α.
    pub rejected: bool,
    /// The test could run.
    pub analysed: bool,
    /// Participants deleted listwise.
    pub dropped: u32,
}

/// Sums of outcomes at one sample size.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Tally {
    /// Replications run.
    pub replications: u64,
    /// Rejections of H₀.
    pub rejected: u64,
    /// Replications the test could analyse.
    pub analysed: u64,
    /// Participants deleted listwise, summed.
    pub dropped: u64,
}

impl Tally {
    fn add(&mut self, o: Outcome) {
        self.replications += 1;
        self.rejected += u64::from(o.rejected);
        self.analysed += u64::from(o.analysed);
        self.dropped += u64::from(o.dropped);
    }
}

fn normal(rng: &mut ChaCha20Rng) -> f64 {
    StandardNormal.sample(rng)
}

impl Scenario<'_> {
    /// Simulates and analyses one study of `n` participants with `trials`
    /// test trials per condition.
    pub fn replicate(&self, n: u32, trials: u32, rng: &mut ChaCha20Rng) -> Outcome {
        let m = self.model;
        let k = m.k();
        let betas: Vec<Option<Beta<f64>>> = self
            .success
            .iter()
            .map(|s| match (s.beta_a, s.beta_b) {
                (Some(a), Some(b)) => Beta::new(a, b).ok(),
                _ => None,
            })
            .collect();
        let mut cols: Vec<Vec<f64>> = vec![Vec::with_capacity(n as usize); k];
        let mut z = vec![0.0; k];
        let mut row = vec![0.0; k];
        let mut dropped = 0;
        for _ in 0..n {
            for zj in z.iter_mut() {
                *zj = normal(rng);
            }
            let mut complete = true;
            for j in 0..k {
                let b = self.means[j] + (0..k).map(|q| m.factor[j * k + q] * z[q]).sum::<f64>();
                let p = match &betas[j] {
                    Some(beta) => beta.sample(rng),
                    None => self.success[j].p,
                };
                let s = if p >= 1.0 {
                    u64::from(trials)
                } else if p <= 0.0 {
                    0
                } else {
                    Binomial::new(u64::from(trials), p).map_or(0, |d| d.sample(rng))
                };
                row[j] = if m.dv_is_success {
                    s as f64 / f64::from(trials)
                } else if s == 0 {
                    complete = false;
                    f64::NAN
                } else {
                    b + m.sd_residual[j] / (s as f64).sqrt() * normal(rng)
                };
            }
            if complete {
                for (c, v) in cols.iter_mut().zip(&row) {
                    c.push(*v);
                }
            } else {
                dropped += 1;
            }
        }
        let p = match self.analysis {
            Analysis::PairedT => paired_t(&cols[0], &cols[1]).map(|t| t.p),
            Analysis::RmGg => {
                let named: Vec<(&str, &[f64])> = m
                    .conditions
                    .iter()
                    .map(String::as_str)
                    .zip(cols.iter().map(Vec::as_slice))
                    .collect();
                CellMatrix::from_columns(&named)
                    .and_then(|c| rm_anova(&c))
                    .map(|r| r.p_gg)
            }
        };
        match p {
            Ok(p) => Outcome {
                rejected: p < self.alpha,
                analysed: true,
                dropped,
            },
            Err(_) => Outcome {
                rejected: false,
                analysed: false,
                dropped,
            },
        }
    }

    /// Runs `replications` studies at each of `ns` on `threads` worker
    /// threads (replication r at n uses `replication_rng(seed, n, trials,
    /// r)`). `progress(done, total)` is called from the calling thread about
    /// ten times a second and at the end; returning `false` cancels (then
    /// `None` is returned).
    pub fn run_grid(
        &self,
        ns: &[u32],
        trials: u32,
        replications: u32,
        seed: u64,
        threads: usize,
        progress: &(dyn Fn(usize, usize) -> bool + Sync),
    ) -> Option<Vec<Tally>> {
        const CHUNK: usize = 32;
        let reps = replications as usize;
        let total = ns.len() * reps;
        let next = AtomicUsize::new(0);
        let done = AtomicUsize::new(0);
        let stop = AtomicBool::new(false);
        let work = || {
            let mut tallies = vec![Tally::default(); ns.len()];
            loop {
                if stop.load(Ordering::Relaxed) {
                    break;
                }
                let start = next.fetch_add(CHUNK, Ordering::Relaxed);
                if start >= total {
                    break;
                }
                let end = (start + CHUNK).min(total);
                for idx in start..end {
                    let (ni, r) = (idx / reps, idx % reps);
                    let mut rng = replication_rng(seed, ns[ni], trials, r as u64);
                    tallies[ni].add(self.replicate(ns[ni], trials, &mut rng));
                }
                done.fetch_add(end - start, Ordering::Relaxed);
            }
            tallies
        };
        let results = std::thread::scope(|scope| {
            let handles: Vec<_> = (0..threads.max(1)).map(|_| scope.spawn(work)).collect();
            while !handles.iter().all(|h| h.is_finished()) {
                if !progress(done.load(Ordering::Relaxed), total) {
                    stop.store(true, Ordering::Relaxed);
                }
                std::thread::sleep(Duration::from_millis(50));
            }
            handles
                .into_iter()
                .map(|h| h.join().unwrap_or_else(|e| std::panic::resume_unwind(e)))
                .collect::<Vec<Vec<Tally>>>()
        });
        if stop.load(Ordering::Relaxed) {
            return None;
        }
        progress(total, total);
        let mut sum = vec![Tally::default(); ns.len()];
        for part in results {
            for (s, t) in sum.iter_mut().zip(part) {
                s.replications += t.replications;
                s.rejected += t.rejected;
                s.analysed += t.analysed;
                s.dropped += t.dropped;
            }
        }
        Some(sum)
    }
}
