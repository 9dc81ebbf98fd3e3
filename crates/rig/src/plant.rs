//! The dual-stage plant: lumped model of paper §2.2, eq. 1 (Table 2).
//!
//! Along x the bodies are the terminal assembly `h` (mass m_h), the
//! Haptuator's moving magnet `v` (m_v), the motor windings `1` (m_1) and the
//! links `2` (m_2): M Ẍ + C Ẋ + K X = F with X = [x_h, x_v, x_1, x_2],
//! F = [f_v, −f_v, f, 0] and the chain 1 —(k_1,b_1)— 2 —(k_2,b_2)— h
//! —(k_v,b_v)— v. The finger (k_f, b_f) ties h to the hand, whose position
//! (and velocity) is an input: it adds k_f x_hand + b_f ẋ_hand to h's force.
//! (The paper prints m_l twice on the mass diagonal; the fourth mass is m_2.)
//!
//! Two optional side branches extend eq. 1 (see `docs/THEORY.md` for
//! why the chain alone cannot show two antiresonances in the force channel):
//! a mass `e` on node 1 (motor shaft torsion, the sharp pair near 800 Hz)
//! and a mass `l` on node 2 (link bending, the damped antiresonance just
//! above 200 Hz). An absent branch leaves a "phantom" degree of freedom
//! with zero dynamics that is never excited (fixed-size matrices).
//!
//! The Haptuator drive u_v (V) reaches the Laplace force through a
//! first-order drive stage, ḟ_v = ω_d (g_v u_v − f_v). The magnet's stroke
//! r = x_v − x_h is limited by one-sided end stops: beyond ±s a spring–damper
//! (k_s, b_s) acts on r. The y axis has the same structure without the
//! Haptuator (bodies h, 1, 2 and the branches).
//!
//! State order: positions (one per DOF), velocities, then f_v (x axis only).
//! Inputs: [f (N), u_v (V), x_hand (m), ẋ_hand (m/s), 1] — the constant
//! input carries the end-stop offsets. Outputs: [ẍ_h (m/s²), x_h (m),
//! x_1 (m), r (m)].
//!
//! Discretisation: exact ZOH per end-stop regime (free, +stop, −stop; each
//! an affine LTI, switched on the state at the start of a step) is the
//! default; RK4 and semi-implicit Euler evaluate the piecewise-linear
//! vector field stage by stage. The per-step update uses fixed-size nalgebra
//! matrices and allocates nothing.

use crate::config::{HaptuatorConfig, PlantConfig, RigConfig};
use crate::error::RigError;
use crate::lti::{self, Integrator, StateSpace};
use nalgebra::{DMatrix, SMatrix, SVector};
use num_complex::Complex64 as C64;
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// Number of plant inputs.
pub const NU: usize = 5;
/// Number of plant outputs.
pub const NY: usize = 4;
/// Input index: Pantograph force, N.
pub const IN_FORCE: usize = 0;
/// Input index: Haptuator drive, V.
pub const IN_DRIVE: usize = 1;
/// Input index: hand position, m.
pub const IN_HAND_POS: usize = 2;
/// Input index: hand velocity, m/s.
pub const IN_HAND_VEL: usize = 3;
/// Input index: constant 1 (end-stop offsets).
pub const IN_ONE: usize = 4;
/// Output index: tip acceleration ẍ_h, m/s².
pub const OUT_ACCEL: usize = 0;
/// Output index: tip position x_h, m.
pub const OUT_TIP: usize = 1;
/// Output index: motor position x_1 (what the encoders see), m.
pub const OUT_MOTOR: usize = 2;
/// Output index: magnet stroke r = x_v − x_h, m.
pub const OUT_STROKE: usize = 3;

/// State dimension of the x axis: 6 DOF × 2 + drive state.
pub const NX: usize = 13;
/// State dimension of the y axis: 5 DOF × 2.
pub const NYAX: usize = 10;

/// Plant axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Axis {
    /// x: with the Haptuator.
    X,
    /// y: Pantograph only.
    Y,
}

/// Drive channel of the dual-stage device.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Channel {
    /// Pantograph force (N) → tip acceleration (m/s²).
    Low,
    /// Haptuator drive (V) → tip acceleration (m/s²).
    High,
}

impl std::str::FromStr for Channel {
    type Err = RigError;
    fn from_str(s: &str) -> Result<Self, RigError> {
        match s {
            "low" => Ok(Channel::Low),
            "high" => Ok(Channel::High),
            _ => Err(RigError::InvalidInput(format!(
                "unknown channel `{s}` (expected low|high)"
            ))),
        }
    }
}

/// End-stop regime of the Haptuator magnet.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Regime {
    /// |r| ≤ stroke.
    Free,
    /// r > stroke.
    Plus,
    /// r < −stroke.
    Minus,
}

/// Indices of one axis's degrees of freedom (`None` if absent).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DofMap {
    /// Terminal assembly.
    pub h: usize,
    /// Haptuator magnet (x axis only).
    pub v: Option<usize>,
    /// Motor windings.
    pub m1: usize,
    /// Links.
    pub m2: usize,
    /// Motor-side branch (phantom if absent).
    pub e: usize,
    /// Link-side branch (phantom if absent).
    pub l: usize,
    /// Number of DOF.
    pub n_dof: usize,
    /// Index of the drive state f_v, if any.
    pub drive: Option<usize>,
}

/// Continuous model of one axis: the three end-stop regimes plus metadata.
#[derive(Debug, Clone)]
pub struct AxisModel {
    /// Which axis.
    pub axis: Axis,
    /// Free regime (linear; used for frequency responses).
    pub free: StateSpace,
    /// Magnet beyond +stroke.
    pub plus: StateSpace,
    /// Magnet beyond −stroke.
    pub minus: StateSpace,
    /// DOF layout.
    pub dofs: DofMap,
    /// States that belong to real (non-phantom) bodies.
    pub active: Vec<usize>,
    /// Stroke limit ±s, m (∞ on the y axis).
    pub stroke_m: f64,
}

impl AxisModel {
    /// Build the x or y axis from a rig configuration.
    pub fn new(cfg: &RigConfig, axis: Axis) -> Result<Self, RigError> {
        build_axis(&cfg.plant, &cfg.haptuator, axis)
    }

    /// State dimension.
    pub fn n_states(&self) -> usize {
        self.free.n_states()
    }

    /// Model of a regime.
    pub fn regime(&self, r: Regime) -> &StateSpace {
        match r {
            Regime::Free => &self.free,
            Regime::Plus => &self.plus,
            Regime::Minus => &self.minus,
        }
    }

    /// Free-regime model restricted to the active states (for eigen-analysis).
    pub fn active_free(&self) -> StateSpace {
        self.free.restrict(&self.active)
    }

    /// Analytic (continuous, linear, free-regime) response of a channel from
    /// drive to tip acceleration at `f` Hz: m/s² per N (low) or per V (high).
    pub fn channel_response(&self, channel: Channel, f_hz: f64) -> Result<C64, RigError> {
        let input = match channel {
            Channel::Low => IN_FORCE,
            Channel::High => IN_DRIVE,
        };
        if self.axis == Axis::Y && channel == Channel::High {
            return Err(RigError::InvalidInput("the y axis has no Haptuator".into()));
        }
        self.free.response(OUT_ACCEL, input, f_hz)
    }

    /// Analytic response from Haptuator drive to magnet stroke r, m/V.
    pub fn stroke_response(&self, f_hz: f64) -> Result<C64, RigError> {
        self.free.response(OUT_STROKE, IN_DRIVE, f_hz)
    }

    /// Poles of the free regime (active states), rad/s.
    pub fn poles(&self) -> Vec<C64> {
        self.active_free().poles()
    }

    /// Hankel singular values (decreasing) of the free regime's exact ZOH
    /// map at step `dt` (s), active states only, from the plant inputs
    /// `inputs` (indices `IN_*`) to the output `output` (`OUT_*`); see
    /// [`lti::hankel_singular_values`]. How many of them are far from zero
    /// is the number of states that path needs (`docs/PERFORMANCE.md`,
    /// closed-loop speed).
    pub fn hankel_singular_values(
        &self,
        inputs: &[usize],
        output: usize,
        dt: f64,
    ) -> Result<Vec<f64>, RigError> {
        let ss = self.active_free();
        if let Some(&bad) = inputs.iter().find(|&&i| i >= ss.b.ncols()) {
            return Err(RigError::InvalidInput(format!("no plant input {bad}")));
        }
        if output >= ss.c.nrows() {
            return Err(RigError::InvalidInput(format!("no plant output {output}")));
        }
        let b = DMatrix::from_fn(ss.b.nrows(), inputs.len(), |i, j| ss.b[(i, inputs[j])]);
        let (phi, gam) = lti::zoh(&ss.a, &b, dt)?;
        lti::hankel_singular_values(&phi, &gam, &ss.c.rows(output, 1).into_owned())
    }
}

fn build_axis(p: &PlantConfig, h: &HaptuatorConfig, axis: Axis) -> Result<AxisModel, RigError> {
    // DOF layout.
    let dofs = match axis {
        Axis::X => DofMap {
            h: 0,
            v: Some(1),
            m1: 2,
            m2: 3,
            e: 4,
            l: 5,
            n_dof: 6,
            drive: Some(12),
        },
        Axis::Y => DofMap {
            h: 0,
            v: None,
            m1: 1,
            m2: 2,
            e: 3,
            l: 4,
            n_dof: 5,
            drive: None,
        },
    };
    let nd = dofs.n_dof;
    let n = 2 * nd + usize::from(dofs.drive.is_some());
    let mut mass = vec![1.0; nd];
    let mut k = DMatrix::<f64>::zeros(nd, nd);
    let mut c = DMatrix::<f64>::zeros(nd, nd);
    let mut active_dof = vec![dofs.h, dofs.m1, dofs.m2];
    let link =
        |k: &mut DMatrix<f64>, c: &mut DMatrix<f64>, i: usize, j: usize, kk: f64, cc: f64| {
            k[(i, i)] += kk;
            k[(j, j)] += kk;
            k[(i, j)] -= kk;
            k[(j, i)] -= kk;
            c[(i, i)] += cc;
            c[(j, j)] += cc;
            c[(i, j)] -= cc;
            c[(j, i)] -= cc;
        };
    mass[dofs.h] = p.m_h;
    mass[dofs.m1] = p.m_1;
    mass[dofs.m2] = p.m_2;
    if let Some(v) = dofs.v {
        mass[v] = p.m_v;
        active_dof.push(v);
        link(&mut k, &mut c, dofs.h, v, p.k_v, p.b_v);
    }
    link(&mut k, &mut c, dofs.m1, dofs.m2, p.k_1, p.b_1);
    link(&mut k, &mut c, dofs.m2, dofs.h, p.k_2, p.b_2);
    k[(dofs.h, dofs.h)] += p.k_f;
    c[(dofs.h, dofs.h)] += p.b_f;
    if let Some(br) = p.motor_branch {
        mass[dofs.e] = br.mass;
        link(&mut k, &mut c, dofs.m1, dofs.e, br.stiffness, br.damping);
        active_dof.push(dofs.e);
    }
    if let Some(br) = p.link_branch {
        mass[dofs.l] = br.mass;
        link(&mut k, &mut c, dofs.m2, dofs.l, br.stiffness, br.damping);
        active_dof.push(dofs.l);
    }
    if mass.iter().any(|m| !(m.is_finite() && *m > 0.0)) {
        return Err(RigError::InvalidInput(
            "plant masses must be finite and > 0".into(),
        ));
    }
    let mut a = DMatrix::<f64>::zeros(n, n);
    let mut b = DMatrix::<f64>::zeros(n, NU);
    for i in 0..nd {
        a[(i, nd + i)] = 1.0;
        for j in 0..nd {
            a[(nd + i, j)] = -k[(i, j)] / mass[i];
            a[(nd + i, nd + j)] = -c[(i, j)] / mass[i];
        }
    }
    let vh = nd + dofs.h;
    b[(nd + dofs.m1, IN_FORCE)] = 1.0 / p.m_1;
    b[(vh, IN_HAND_POS)] = p.k_f / p.m_h;
    b[(vh, IN_HAND_VEL)] = p.b_f / p.m_h;
    if let (Some(v), Some(di)) = (dofs.v, dofs.drive) {
        let wd = 2.0 * PI * h.drive_corner_hz;
        a[(di, di)] = -wd;
        b[(di, IN_DRIVE)] = wd * h.drive_gain_n_per_v;
        a[(vh, di)] = 1.0 / p.m_h;
        a[(nd + v, di)] = -1.0 / p.m_v;
    }
    // Outputs.
    let mut cm = DMatrix::<f64>::zeros(NY, n);
    let dm = DMatrix::<f64>::zeros(NY, NU);
    cm[(OUT_TIP, dofs.h)] = 1.0;
    cm[(OUT_MOTOR, dofs.m1)] = 1.0;
    if let Some(v) = dofs.v {
        cm[(OUT_STROKE, v)] = 1.0;
        cm[(OUT_STROKE, dofs.h)] = -1.0;
    }
    let with_accel = |a: &DMatrix<f64>, b: &DMatrix<f64>| -> StateSpace {
        let mut cc = cm.clone();
        let mut dd = dm.clone();
        for j in 0..n {
            cc[(OUT_ACCEL, j)] = a[(vh, j)];
        }
        for j in 0..NU {
            dd[(OUT_ACCEL, j)] = b[(vh, j)];
        }
        StateSpace {
            a: a.clone(),
            b: b.clone(),
            c: cc,
            d: dd,
        }
    };
    let free = with_accel(&a, &b);
    // End-stop regimes: F_m = −k_s r − b_s ṙ ± k_s s on the magnet, −F_m on h.
    let (plus, minus, stroke) = match dofs.v {
        Some(v) => {
            let (ks, bs, s) = (
                h.stop_stiffness_n_per_m,
                h.stop_damping_n_s_per_m,
                h.stroke_m,
            );
            let mut ap = a.clone();
            let mut bp = b.clone();
            let mut bm = b.clone();
            for (row, g) in [(nd + v, 1.0 / p.m_v), (vh, -1.0 / p.m_h)] {
                ap[(row, v)] -= g * ks;
                ap[(row, dofs.h)] += g * ks;
                ap[(row, nd + v)] -= g * bs;
                ap[(row, nd + dofs.h)] += g * bs;
                bp[(row, IN_ONE)] += g * ks * s;
                bm[(row, IN_ONE)] -= g * ks * s;
            }
            (with_accel(&ap, &bp), with_accel(&ap, &bm), s)
        }
        None => (free.clone(), free.clone(), f64::INFINITY),
    };
    let mut active: Vec<usize> = Vec::new();
    active_dof.sort_unstable();
    for &d in &active_dof {
        active.push(d);
    }
    for &d in &active_dof {
        active.push(nd + d);
    }
    if let Some(di) = dofs.drive {
        active.push(di);
    }
    Ok(AxisModel {
        axis,
        free,
        plus,
        minus,
        dofs,
        active,
        stroke_m: stroke,
    })
}

/// Outputs of one axis after a step.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct AxisOutput {
    /// Tip acceleration, m/s².
    pub accel: f64,
    /// Tip position, m.
    pub tip: f64,
    /// Motor position, m.
    pub motor: f64,
    /// Magnet stroke, m (0 on y).
    pub stroke: f64,
}

fn to_s<const R: usize, const C: usize>(m: &DMatrix<f64>) -> Result<SMatrix<f64, R, C>, RigError> {
    if m.nrows() != R || m.ncols() != C {
        return Err(RigError::Numerical(format!(
            "matrix is {}×{}, expected {R}×{C}",
            m.nrows(),
            m.ncols()
        )));
    }
    Ok(SMatrix::<f64, R, C>::from_fn(|i, j| m[(i, j)]))
}

/// Discrete-time simulator of one axis with `N` states (fixed size, no
/// allocation per step).
#[derive(Debug, Clone)]
pub struct AxisSim<const N: usize> {
    integrator: Integrator,
    dt: f64,
    n_pos: usize,
    x: SVector<f64, N>,
    // Column-major copies of [Φ | Γ] for the hand-written ZOH update.
    phi_cols: [[[f64; N]; N]; 3],
    gamma_cols: [[[f64; N]; NU]; 3],
    a: [SMatrix<f64, N, N>; 3],
    b: [SMatrix<f64, N, NU>; 3],
    c: [SMatrix<f64, NY, N>; 3],
    d: [SMatrix<f64, NY, NU>; 3],
    stroke: Option<(usize, usize, f64)>,
    tip: usize,
    motor: usize,
    stop_steps: u64,
    resets: u64,
    // Modal form of the ZOH maps (None: dense update).
    modal: Option<Box<[ModalRegime<N>; 3]>>,
    z: A16<[L2; LANES]>,
    cur: usize,
    slow: SlowInputs,
    // The drive input has no effect in any regime (y axis): skip it.
    drive_free: bool,
    // Some regime has a feed-through of force or drive to ẍ_h.
    fast_d: bool,
    // Every regime takes the drive as (0, 1) in its block groups.
    drive_unit: bool,
    // Which step runs (from the flags above; one test per step).
    path: StepPath,
}

/// Which step [`AxisSim`] runs, chosen once from its configuration.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum StepPath {
    /// Dense ZOH, RK4 or semi-implicit Euler.
    Dense,
    /// Modal, general inputs and feed-through.
    Modal,
    /// Modal without drive column, end stops or feed-through (y axis).
    ModalNoDrive,
    /// Modal with unit force and drive columns, end stops, no feed-through
    /// (x axis).
    ModalDriveUnit,
}

/// Largest state dimension with a modal fast path (lanes of 2 states).
const MODAL_MAX_STATES: usize = 14;
/// Lanes of the modal state.
const LANES: usize = MODAL_MAX_STATES / 2;
/// Two adjacent states, processed together (packed SSE2 on baseline x86-64).
type L2 = [f64; 2];

#[inline(always)]
fn l2_mul_add(acc: L2, a: L2, b: L2) -> L2 {
    [acc[0] + a[0] * b[0], acc[1] + a[1] * b[1]]
}

/// 16-byte aligned wrapper: packed SSE2 arithmetic can then read lane
/// arrays straight from memory (no separate unaligned loads).
#[derive(Debug, Clone, Copy)]
#[repr(C, align(16))]
struct A16<T>(T);

/// Number of lanes in use for `n` states.
#[inline(always)]
const fn lanes(n: usize) -> usize {
    n.div_ceil(2)
}

/// Flat state ↔ lanes (unused padding lanes are zero).
fn to_lanes<const N: usize>(x: &[f64; N]) -> [L2; LANES] {
    let mut l = [[0.0; 2]; LANES];
    for (i, v) in x.iter().enumerate().take(MODAL_MAX_STATES) {
        l[i / 2][i % 2] = *v;
    }
    l
}

fn from_lanes<const N: usize>(l: &[L2; LANES]) -> [f64; N] {
    let mut x = [0.0; N];
    for (i, v) in x.iter_mut().enumerate().take(MODAL_MAX_STATES) {
        *v = l[i / 2][i % 2];
    }
    x
}

/// The ZOH map of one regime in real modal coordinates x = T z:
/// z ← Λ z + T⁻¹Γ u with Λ block-diagonal: 2×2 blocks (an eigenvalue pair
/// a ± jb of Φ, or two real eigenvalues), then at most one single real
/// eigenvalue.
///
/// Basis. Each 2×2 block's basis columns are multiplied by a 2×2 matrix S
/// chosen from the block's part of T⁻¹Γ: with g_f = (p, q) (force) and
/// g_v = (r, w) (drive), S = [g_f g_v] when the two are far from parallel
/// (|sin ∠| ≥ 10⁻³, so round-off grows by at most 10³; x axis), else
/// S = [[p, −q], [q, p]] (a rotation-scaling, condition number 1, which
/// commutes with a pair's block [[a, b], [−b, a]]; y axis). Then S⁻¹g_f =
/// (1, 0) (and S⁻¹g_v = (0, 1)): the force costs one add per lane pair
/// instead of two multiply-adds, the drive another. The block itself becomes
/// S⁻¹ Λ_b S, a general 2×2 matrix, which the layout below handles at the
/// same cost. The map is the same exact ZOH map in another basis; only the
/// round-off differs.
///
/// Layout. Everything the step reads is stored as lanes of two states
/// ([`L2`]) in the *flat* order of the modal state. The first 4·⌊N/4⌋
/// states are groups of two blocks in structure-of-arrays form: lane 2g
/// holds the first coordinates of blocks 2g and 2g+1, lane 2g+1 their second
/// coordinates, so a group update is A' = c_s⊙A + c_p⊙B, B' = c_s⊙B + c_p⊙A
/// (four packed multiplies, no shuffle), the force adds [f, f] to A and,
/// when every group block takes the drive as (0, 1), the drive [u_v, u_v]
/// to B. The remaining states are "AoS" lanes (a whole block, or a single
/// real and a zero padding): z' = c_s⊙z + c_p⊙swap(z) + γ_f f + ….
/// Padding is zero.
#[derive(Debug, Clone)]
struct ModalRegime<const N: usize> {
    /// Λ entries on the diagonal (c_s) and to the block partner (c_p).
    cs: A16<[L2; LANES]>,
    cp: A16<[L2; LANES]>,
    gam: A16<[[L2; LANES]; NU]>,
    /// Output weights of flat state j: [(ẍ_h, x_1), (x_h, r)] rows of C T.
    outw: A16<[[L2; 2]; MODAL_MAX_STATES]>,
    acc_d: [f64; NU],
    /// Every structure-of-arrays block takes the drive as (0, 1).
    drive_unit: bool,
    t: [[f64; N]; N],
    tinv: [[f64; N]; N],
}

/// Number of structure-of-arrays block groups (4 states each) for `n` states.
#[inline(always)]
const fn groups(n: usize) -> usize {
    n / 4
}

/// Natural modal index (blocks in order, 2b and 2b + 1 for block b) of the
/// flat (lane) index `fl`; see [`ModalRegime`].
const fn natural_index(fl: usize, n: usize) -> usize {
    if fl < 4 * groups(n) {
        let (g, r) = (fl / 4, fl % 4);
        2 * (2 * g + r % 2) + r / 2
    } else {
        fl
    }
}

/// Contribution of the slowly varying inputs (hand position, hand velocity,
/// constant 1) to the modal update and to the acceleration feed-through,
/// cached while those inputs and the regime stay the same (they are constant
/// over a block, or for ever when nobody moves the hand). Bit-identical to
/// computing them every step.
#[derive(Debug, Clone)]
struct SlowInputs {
    key: [u64; 4],
    bias: A16<[L2; LANES]>,
    acc: f64,
}

impl SlowInputs {
    fn new() -> Self {
        Self {
            // Regime u64::MAX never occurs: the first step refreshes.
            key: [u64::MAX; 4],
            bias: A16([[0.0; 2]; LANES]),
            acc: 0.0,
        }
    }

    /// The cached contribution for hand position `hp` (m), hand velocity
    /// `hv` (m/s) and constant input `one` in `regime`.
    #[inline(always)]
    fn get<const N: usize>(
        &mut self,
        m: &ModalRegime<N>,
        regime: usize,
        [hp, hv, one]: [f64; 3],
    ) -> (&[L2; LANES], f64) {
        let key = [hp.to_bits(), hv.to_bits(), one.to_bits(), regime as u64];
        // One test for the four words (no early exits).
        let diff = (key[0] ^ self.key[0])
            | (key[1] ^ self.key[1])
            | (key[2] ^ self.key[2])
            | (key[3] ^ self.key[3]);
        if diff != 0 {
            self.refresh(m, regime, [hp, hv, one]);
        }
        (&self.bias.0, self.acc)
    }

    // Not `#[cold]`: while the hand moves (study tasks, the GUI's mouse) it
    // runs every sample.
    #[inline(never)]
    fn refresh<const N: usize>(&mut self, m: &ModalRegime<N>, regime: usize, u: [f64; 3]) {
        let [hp, hv, one] = u;
        let key = [hp.to_bits(), hv.to_bits(), one.to_bits(), regime as u64];
        // Lane pairs (packed); per entry (γ_p hp + γ_v hv) + γ_1 one.
        let g = &m.gam.0;
        let (hp2, hv2, one2) = ([hp, hp], [hv, hv], [one, one]);
        let lanes_in = g[IN_HAND_POS].iter().zip(&g[IN_HAND_VEL]).zip(&g[IN_ONE]);
        for (b, ((gp, gv), g1)) in self.bias.0.iter_mut().zip(lanes_in).take(lanes(N)) {
            *b = l2_add(
                l2_add(l2_mul(*gp, hp2), l2_mul(*gv, hv2)),
                l2_mul(*g1, one2),
            );
        }
        self.acc = (m.acc_d[IN_HAND_POS] * hp + m.acc_d[IN_HAND_VEL] * hv) + m.acc_d[IN_ONE] * one;
        self.key = key;
    }
}

#[inline(always)]
fn l2_add(a: L2, b: L2) -> L2 {
    [a[0] + b[0], a[1] + b[1]]
}

#[inline(always)]
fn l2_mul(a: L2, b: L2) -> L2 {
    [a[0] * b[0], a[1] * b[1]]
}

/// Adds the output contributions of the two states in lane `zk` (weights
/// `w0`, `w1`, each [(ẍ_h, x_1), (x_h, r)]) to the pair accumulators `p`:
/// each state is broadcast to a lane pair, so every product and sum is
/// vertical (packed), with even and odd states in separate accumulators.
#[inline(always)]
fn outputs_add(p: &mut [L2; 4], w0: &[L2; 2], w1: &[L2; 2], zk: L2) {
    let (lo, hi) = ([zk[0], zk[0]], [zk[1], zk[1]]);
    p[0] = l2_mul_add(p[0], w0[0], lo);
    p[2] = l2_mul_add(p[2], w0[1], lo);
    p[1] = l2_mul_add(p[1], w1[0], hi);
    p[3] = l2_mul_add(p[3], w1[1], hi);
}

/// Outputs (ẍ_h without feed-through, x_1, x_h, r) of the pair accumulators.
#[inline(always)]
fn outputs_sum(p: &[L2; 4]) -> [f64; 4] {
    let am = l2_add(p[0], p[1]);
    let ts = l2_add(p[2], p[3]);
    [am[0], am[1], ts[0], ts[1]]
}

/// Outputs (ẍ_h without feed-through, x_1, x_h, r) of the modal state `z`:
/// Σ_j w_j z_j, same order of operations as [`modal_pass`].
#[inline(always)]
fn modal_outputs<const N: usize>(w: &[[L2; 2]; MODAL_MAX_STATES], z: &[L2; LANES]) -> [f64; 4] {
    let mut p = [[0.0f64; 2]; 4];
    for (k, zk) in z.iter().enumerate().take(lanes(N)) {
        outputs_add(&mut p, &w[2 * k], &w[2 * k + 1], *zk);
    }
    outputs_sum(&p)
}

/// One modal update z ← Λz + γ_f f (+ γ_v u_v when `DRIVE`) + bias and the
/// outputs (ẍ_h without feed-through, x_1, x_h, r) of the new state, in one
/// pass over the lanes (layout in [`ModalRegime`]; outputs as in
/// [`modal_outputs`]). `DRIVE = false` skips the drive column where it is
/// identically zero, `STOPS = false` the stroke output (y axis: no magnet,
/// r = 0), `TIP = false` the tip position (returned as 0; ground truth only,
/// see [`AxisSim::tip_m`]).
#[inline(always)]
fn modal_pass<
    const N: usize,
    const DRIVE: bool,
    const DUNIT: bool,
    const STOPS: bool,
    const TIP: bool,
>(
    m: &ModalRegime<N>,
    z: &[L2; LANES],
    bias: &[L2; LANES],
    f: f64,
    v: f64,
) -> (A16<[L2; LANES]>, [f64; 4]) {
    let (gf, gv) = (&m.gam.0[IN_FORCE], &m.gam.0[IN_DRIVE]);
    let (cs, cp) = (&m.cs.0, &m.cp.0);
    let w = &m.outw.0;
    let (ff, vv) = ([f, f], [v, v]);
    let mut zn = A16([[0.0; 2]; LANES]);
    let mut p = [[0.0f64; 2]; 4];
    for g in 0..groups(N) {
        let (l, h) = (2 * g, 2 * g + 1);
        let (a, b) = (z[l], z[h]);
        // Force input (1, 0) per block: A only.
        let mut an = l2_add(l2_add(l2_mul(cs[l], a), l2_mul(cp[l], b)), ff);
        let mut bn = l2_add(l2_mul(cs[h], b), l2_mul(cp[h], a));
        if DRIVE && DUNIT {
            // Drive input (0, 1) per block: B only.
            bn = l2_add(bn, vv);
        } else if DRIVE {
            an = l2_mul_add(an, gv[l], vv);
            bn = l2_mul_add(bn, gv[h], vv);
        }
        an = l2_add(an, bias[l]);
        bn = l2_add(bn, bias[h]);
        zn.0[l] = an;
        zn.0[h] = bn;
        outputs_add(&mut p, &w[2 * l], &w[2 * l + 1], an);
        outputs_add(&mut p, &w[2 * h], &w[2 * h + 1], bn);
    }
    for k in 2 * groups(N)..lanes(N) {
        let zk = z[k];
        let rot = l2_mul_add(l2_mul(cs[k], zk), cp[k], [zk[1], zk[0]]);
        let inp = if DRIVE {
            l2_mul_add(l2_mul(gf[k], ff), gv[k], vv)
        } else {
            l2_mul(gf[k], ff)
        };
        let y = l2_add(l2_add(rot, inp), bias[k]);
        zn.0[k] = y;
        outputs_add(&mut p, &w[2 * k], &w[2 * k + 1], y);
    }
    let out = outputs_sum(&p);
    // Without end stops the stroke weights are zero: r = +0 exactly.
    (
        zn,
        [
            out[0],
            out[1],
            if TIP { out[2] } else { 0.0 },
            if STOPS { out[3] } else { 0.0 },
        ],
    )
}

/// Column-major matrix–vector product y = M x (M given by its columns).
#[inline]
fn colmul<const N: usize>(cols: &[[f64; N]; N], x: &[f64; N]) -> [f64; N] {
    let mut y = [0.0; N];
    for (col, &xj) in cols.iter().zip(x) {
        for (yi, ci) in y.iter_mut().zip(col) {
            *yi += ci * xj;
        }
    }
    y
}

/// Real modal decomposition of Φ: `None` if Φ is defective, has repeated
/// eigenvalues or an ill-conditioned eigenbasis (the dense update is used then).
fn modal_regime<const N: usize>(
    phi: &DMatrix<f64>,
    gamma: &DMatrix<f64>,
    c: &DMatrix<f64>,
    d: &DMatrix<f64>,
    picks: (usize, usize, Option<usize>),
) -> Option<ModalRegime<N>> {
    use num_complex::Complex64 as C;
    let n = phi.nrows();
    if n != N || N > MODAL_MAX_STATES {
        return None;
    }
    let ev = lti::eigenvalues(phi);
    let scale = ev.iter().map(|z| z.norm()).fold(1.0, f64::max);
    let tol = 1e-9 * scale;
    let mut pairs: Vec<C> = ev.iter().copied().filter(|z| z.im > tol).collect();
    let mut reals: Vec<f64> = ev
        .iter()
        .filter(|z| z.im.abs() <= tol)
        .map(|z| z.re)
        .collect();
    if 2 * pairs.len() + reals.len() != n {
        return None;
    }
    pairs.sort_by(|x, y| x.norm().total_cmp(&y.norm()));
    reals.sort_by(f64::total_cmp);
    // Distinct eigenvalues only (inverse iteration and diagonalisability).
    let all: Vec<C> = pairs
        .iter()
        .copied()
        .chain(reals.iter().map(|&r| C::new(r, 0.0)))
        .collect();
    for i in 0..all.len() {
        for j in 0..i {
            if (all[i] - all[j]).norm() < 1e-7 * scale {
                return None;
            }
        }
    }
    let eigvec = |lam: C| -> Option<Vec<C>> {
        let mu = lam + C::new(1e-11, 1e-11) * scale;
        let m = DMatrix::<C>::from_fn(n, n, |i, j| {
            let v = C::new(phi[(i, j)], 0.0);
            if i == j { v - mu } else { v }
        });
        let lu = m.lu();
        let mut v = DMatrix::<C>::from_fn(n, 1, |i, _| {
            C::new(1.0 + 0.1 * i as f64, 0.3 - 0.05 * i as f64)
        });
        for _ in 0..3 {
            v = lu.solve(&v)?;
            let nv = v.iter().map(|z| z.norm_sqr()).sum::<f64>().sqrt();
            if !(nv.is_finite() && nv > 0.0) {
                return None;
            }
            v /= C::new(nv, 0.0);
        }
        Some(v.iter().copied().collect())
    };
    let mut t = DMatrix::<f64>::zeros(n, n);
    let mut lam = DMatrix::<f64>::zeros(n, n);
    for (k, &p) in pairs.iter().enumerate() {
        let v = eigvec(p)?;
        for i in 0..n {
            t[(i, 2 * k)] = v[i].re;
            t[(i, 2 * k + 1)] = v[i].im;
        }
        lam[(2 * k, 2 * k)] = p.re;
        lam[(2 * k, 2 * k + 1)] = p.im;
        lam[(2 * k + 1, 2 * k)] = -p.im;
        lam[(2 * k + 1, 2 * k + 1)] = p.re;
    }
    let np = pairs.len();
    for (k, &r) in reals.iter().enumerate() {
        let v = eigvec(C::new(r, 0.0))?;
        // Make the vector real: rotate by the phase of its largest entry.
        let big = v
            .iter()
            .copied()
            .max_by(|a, b| a.norm().total_cmp(&b.norm()))?;
        let ph = big / C::new(big.norm(), 0.0);
        for i in 0..n {
            t[(i, 2 * np + k)] = (v[i] / ph).re;
        }
        lam[(2 * np + k, 2 * np + k)] = r;
    }
    let tinv = t.clone().try_inverse()?;
    let cond = t.norm() * tinv.norm();
    let resid = (phi * &t - &t * &lam).norm() / (phi.norm().max(1.0) * t.norm());
    if !(cond.is_finite() && cond < 1e8 && resid < 1e-11) {
        return None;
    }
    // Input normalisation of the 2×2 blocks (see `ModalRegime`).
    let g0 = &tinv * gamma;
    let gmax = (0..n).map(|i| g0[(i, IN_FORCE)].abs()).fold(0.0, f64::max);
    let vmax = (0..n).map(|i| g0[(i, IN_DRIVE)].abs()).fold(0.0, f64::max);
    let mut sm = DMatrix::<f64>::identity(n, n);
    let mut si = DMatrix::<f64>::identity(n, n);
    // Per block: 0 = as is, 1 = force (1, 0), 2 = force (1, 0) and drive (0, 1).
    let mut kind = vec![0u8; n / 2];
    for (bk, kd) in kind.iter_mut().enumerate() {
        let (i, j) = (2 * bk, 2 * bk + 1);
        let (p, q) = (g0[(i, IN_FORCE)], g0[(j, IN_FORCE)]);
        let (r, w) = (g0[(i, IN_DRIVE)], g0[(j, IN_DRIVE)]);
        let nn = p * p + q * q;
        if !(nn.is_finite() && nn > 0.0 && nn.sqrt() > 1e-12 * gmax) {
            // The structure-of-arrays groups add the force as (1, 0).
            if bk < 2 * groups(N) {
                return None;
            }
            continue;
        }
        // S = [γ_f γ_v] when the two columns are far from parallel
        // (|sin angle| ≥ 1e-3: round-off grows by at most 1/|sin|).
        let det = p * w - q * r;
        let nv = (r * r + w * w).sqrt();
        if vmax > 0.0 && nv > 1e-12 * vmax && det.abs() >= 1e-3 * nn.sqrt() * nv {
            (sm[(i, i)], sm[(i, j)], sm[(j, i)], sm[(j, j)]) = (p, r, q, w);
            (si[(i, i)], si[(i, j)], si[(j, i)], si[(j, j)]) =
                (w / det, -r / det, -q / det, p / det);
            *kd = 2;
        } else {
            (sm[(i, i)], sm[(i, j)], sm[(j, i)], sm[(j, j)]) = (p, -q, q, p);
            (si[(i, i)], si[(i, j)], si[(j, i)], si[(j, j)]) = (p / nn, q / nn, -q / nn, p / nn);
            *kd = 1;
        }
    }
    let t = &t * &sm;
    let tinv = &si * &tinv;
    let lam = &si * &lam * &sm;
    let mut g = &si * &g0;
    for (bk, &kd) in kind.iter().enumerate() {
        if kd >= 1 {
            g[(2 * bk, IN_FORCE)] = 1.0;
            g[(2 * bk + 1, IN_FORCE)] = 0.0;
        }
        if kd == 2 {
            g[(2 * bk, IN_DRIVE)] = 0.0;
            g[(2 * bk + 1, IN_DRIVE)] = 1.0;
        }
    }
    let drive_unit = kind[..2 * groups(N)].iter().all(|&k| k == 2);
    let ct = c * &t;
    let (h, m1, v) = picks;
    let nat = |fl: usize| natural_index(fl, N);
    let flat = |f: &dyn Fn(usize) -> f64| -> [L2; LANES] {
        let x: [f64; N] = std::array::from_fn(|fl| f(nat(fl)));
        to_lanes(&x)
    };
    let mut m = ModalRegime::<N> {
        cs: A16(flat(&|i| lam[(i, i)])),
        cp: A16(flat(&|i| if i ^ 1 < n { lam[(i, i ^ 1)] } else { 0.0 })),
        gam: A16(std::array::from_fn(|j| flat(&|i| g[(i, j)]))),
        outw: A16(std::array::from_fn(|fl| {
            if fl < N {
                let i = nat(fl);
                [
                    [ct[(OUT_ACCEL, i)], t[(m1, i)]],
                    [t[(h, i)], v.map_or(0.0, |v| t[(v, i)] - t[(h, i)])],
                ]
            } else {
                [[0.0; 2]; 2]
            }
        })),
        acc_d: std::array::from_fn(|j| d[(OUT_ACCEL, j)]),
        drive_unit,
        t: [[0.0; N]; N],
        tinv: [[0.0; N]; N],
    };
    for i in 0..N {
        for j in 0..N {
            m.t[j][i] = t[(i, nat(j))];
            m.tinv[j][i] = tinv[(nat(i), j)];
        }
    }
    Some(m)
}

impl<const N: usize> AxisSim<N> {
    /// Discretise `model` at step `dt` (s) with `integrator`.
    pub fn new(model: &AxisModel, integrator: Integrator, dt: f64) -> Result<Self, RigError> {
        if model.n_states() != N {
            return Err(RigError::Numerical(format!(
                "axis model has {} states, simulator expects {N}",
                model.n_states()
            )));
        }
        let regs = [&model.free, &model.plus, &model.minus];
        let n_pos = model.dofs.n_dof;
        let mut phi = [SMatrix::<f64, N, N>::zeros(); 3];
        let mut gamma = [SMatrix::<f64, N, NU>::zeros(); 3];
        let mut a = [SMatrix::<f64, N, N>::zeros(); 3];
        let mut b = [SMatrix::<f64, N, NU>::zeros(); 3];
        let mut c = [SMatrix::<f64, NY, N>::zeros(); 3];
        let mut d = [SMatrix::<f64, NY, NU>::zeros(); 3];
        for (i, ss) in regs.iter().enumerate() {
            let (p, g) = lti::one_step_map(integrator, &ss.a, &ss.b, dt, n_pos)?;
            phi[i] = to_s(&p)?;
            gamma[i] = to_s(&g)?;
            a[i] = to_s(&ss.a)?;
            b[i] = to_s(&ss.b)?;
            c[i] = to_s(&ss.c)?;
            d[i] = to_s(&ss.d)?;
        }
        let stroke = model.dofs.v.map(|v| (v, model.dofs.h, model.stroke_m));
        let modal = if integrator == Integrator::Zoh {
            let picks = (model.dofs.h, model.dofs.m1, model.dofs.v);
            let mut regs_m = Vec::with_capacity(3);
            for ss in regs.iter() {
                let (p, g) = lti::zoh(&ss.a, &ss.b, dt)?;
                regs_m.push(modal_regime::<N>(&p, &g, &ss.c, &ss.d, picks));
            }
            match (regs_m.pop(), regs_m.pop(), regs_m.pop()) {
                (Some(Some(m2)), Some(Some(m1)), Some(Some(m0))) => Some(Box::new([m0, m1, m2])),
                _ => None,
            }
        } else {
            None
        };
        let mut phi_cols = [[[0.0; N]; N]; 3];
        let mut gamma_cols = [[[0.0; N]; NU]; 3];
        for r in 0..3 {
            for j in 0..N {
                for i in 0..N {
                    phi_cols[r][j][i] = phi[r][(i, j)];
                }
            }
            for j in 0..NU {
                for i in 0..N {
                    gamma_cols[r][j][i] = gamma[r][(i, j)];
                }
            }
        }
        let drive_free = modal.as_deref().is_some_and(|regs| {
            regs.iter().all(|r| {
                r.acc_d[IN_DRIVE] == 0.0
                    && r.gam.0[IN_DRIVE].iter().all(|l| l[0] == 0.0 && l[1] == 0.0)
            })
        });
        let fast_d = modal.as_deref().is_some_and(|regs| {
            regs.iter()
                .any(|r| r.acc_d[IN_FORCE] != 0.0 || r.acc_d[IN_DRIVE] != 0.0)
        });
        let drive_unit = modal
            .as_deref()
            .is_some_and(|regs| regs.iter().all(|r| r.drive_unit));
        let mut sim = Self {
            phi_cols,
            gamma_cols,
            integrator,
            dt,
            n_pos,
            x: SVector::zeros(),
            a,
            b,
            c,
            d,
            stroke,
            tip: model.dofs.h,
            motor: model.dofs.m1,
            stop_steps: 0,
            resets: 0,
            modal,
            drive_free,
            fast_d,
            drive_unit,
            path: StepPath::Dense,
            z: A16([[0.0; 2]; LANES]),
            cur: 0,
            slow: SlowInputs::new(),
        };
        sim.path = sim.select_path();
        Ok(sim)
    }

    /// The step variant for the current configuration (see [`StepPath`]).
    fn select_path(&self) -> StepPath {
        if self.integrator != Integrator::Zoh || self.modal.is_none() {
            StepPath::Dense
        } else if self.fast_d {
            StepPath::Modal
        } else if self.drive_free && self.stroke.is_none() {
            StepPath::ModalNoDrive
        } else if !self.drive_free && self.stroke.is_some() && self.drive_unit {
            StepPath::ModalDriveUnit
        } else {
            StepPath::Modal
        }
    }

    /// True when the ZOH update runs in modal coordinates (fast path).
    pub fn is_modal(&self) -> bool {
        self.modal.is_some()
    }

    /// Use the dense ZOH update even if a modal form exists (comparison).
    pub fn force_dense(&mut self) {
        let x = self.state();
        self.modal = None;
        self.path = StepPath::Dense;
        self.x = x;
    }

    /// Integration scheme.
    pub fn integrator(&self) -> Integrator {
        self.integrator
    }

    /// Step, s.
    pub fn dt(&self) -> f64 {
        self.dt
    }

    /// Current (physical) state.
    pub fn state(&self) -> SVector<f64, N> {
        match &self.modal {
            Some(m) => SVector::from(colmul(&m[self.cur].t, &from_lanes(&self.z.0))),
            None => self.x,
        }
    }

    /// Overwrite the state (tests, initial conditions). Non-finite → zero.
    pub fn set_state(&mut self, x: SVector<f64, N>) {
        self.x = if x.iter().all(|v| v.is_finite()) {
            x
        } else {
            SVector::zeros()
        };
        if let Some(m) = &self.modal {
            self.cur = self.regime_of(&self.x);
            let xa: [f64; N] = self.x.into();
            self.z = A16(to_lanes(&colmul(&m[self.cur].tinv, &xa)));
        }
    }

    /// Zero the state and counters.
    pub fn reset(&mut self) {
        self.x = SVector::zeros();
        self.z = A16([[0.0; 2]; LANES]);
        self.cur = 0;
        self.stop_steps = 0;
        self.resets = 0;
    }

    #[inline]
    fn regime_of_stroke(&self, r: f64) -> usize {
        match self.stroke {
            Some((_, _, s)) if r > s => 1,
            Some((_, _, s)) if r < -s => 2,
            _ => 0,
        }
    }

    /// The modal ZOH step (see [`ModalRegime`]).
    ///
    /// Hot path: one lane-wise update z ← Λz + γ_f f + γ_v u_v + (slow
    /// inputs, cached), then the output dot products. A non-finite state is
    /// detected through the acceleration dot product (0·∞ = NaN, so it is
    /// non-finite as soon as any state is); a non-finite input is caught the
    /// same way (it makes the new state non-finite). The reset, the input
    /// sanitising and the rare end-stop regime switch run out of line.
    #[inline]
    fn step_modal<const TIP: bool>(
        &mut self,
        f: f64,
        drive: f64,
        slow: [f64; 3],
    ) -> Option<AxisOutput> {
        let regs = self.modal.as_deref()?;
        let r0 = self.cur;
        let m = &regs[r0];
        let (bias, bias_acc) = self.slow.get(m, r0, slow);
        let z = &self.z.0;
        // Without a drive column (y axis) the drive input is not read at all
        // (a non-finite value there could not be detected through the state).
        // The specialised paths have no feed-through of force and drive to
        // ẍ_h (none in eq. 1: both act through other bodies or the drive
        // state); the general one adds it.
        let (zn, [acc_z, motor, tip, stroke], d_fast) = match self.path {
            StepPath::ModalNoDrive => {
                let (zn, o) = modal_pass::<N, false, false, false, TIP>(m, z, bias, f, 0.0);
                (zn, o, 0.0)
            }
            StepPath::ModalDriveUnit => {
                let (zn, o) = modal_pass::<N, true, true, true, TIP>(m, z, bias, f, drive);
                (zn, o, 0.0)
            }
            _ => {
                let v = if self.drive_free { 0.0 } else { drive };
                let (zn, o) = modal_pass::<N, true, false, true, TIP>(m, z, bias, f, v);
                (zn, o, m.acc_d[IN_FORCE] * f + m.acc_d[IN_DRIVE] * v)
            }
        };
        let r1 = self.regime_of_stroke(stroke);
        if r1 != r0 || !acc_z.is_finite() {
            let [hp, hv, one] = slow;
            return Some(self.finish_modal_slow(from_lanes(&zn.0), [f, drive, hp, hv, one]));
        }
        let out = AxisOutput {
            accel: acc_z + (d_fast + bias_acc),
            tip,
            motor,
            stroke,
        };
        // Padding lanes stay zero: copy only the lanes in use.
        self.z.0[..lanes(N)].copy_from_slice(&zn.0[..lanes(N)]);
        if r0 != 0 {
            self.stop_steps += 1;
        }
        Some(out)
    }

    /// End of a modal step with a regime switch or a non-finite state
    /// (reset to zero, counted): change of basis x = T z, z' = T'⁻¹ x.
    #[cold]
    #[inline(never)]
    fn finish_modal_slow(&mut self, mut zn: [f64; N], u: [f64; NU]) -> AxisOutput {
        if !u.iter().all(|v| v.is_finite()) {
            // Nothing was stored yet: redo the step with non-finite inputs
            // replaced by 0 (the documented input handling of `step`).
            let mut clean = u;
            sanitize(&mut clean);
            return self
                .step_modal::<true>(
                    clean[IN_FORCE],
                    clean[IN_DRIVE],
                    [clean[IN_HAND_POS], clean[IN_HAND_VEL], clean[IN_ONE]],
                )
                .unwrap_or_default();
        }
        let Some(regs) = self.modal.as_deref() else {
            return AxisOutput::default();
        };
        let r0 = self.cur;
        if !zn.iter().all(|v| v.is_finite()) {
            zn = [0.0; N];
            self.resets += 1;
        }
        let mut zl = to_lanes(&zn);
        let mut cur = r0;
        let stroke = modal_outputs::<N>(&regs[r0].outw.0, &zl)[3];
        let r1 = self.regime_of_stroke(stroke);
        if r1 != r0 {
            let x = colmul(&regs[r0].t, &zn);
            zl = to_lanes(&colmul(&regs[r1].tinv, &x));
            cur = r1;
        }
        let m = &regs[cur];
        let accel_d = m.acc_d.iter().zip(u).fold(0.0, |s, (a, b)| s + a * b);
        let [acc_z, motor, tip, stroke] = modal_outputs::<N>(&m.outw.0, &zl);
        let out = AxisOutput {
            accel: acc_z + accel_d,
            tip,
            motor,
            stroke,
        };
        self.z = A16(zl);
        self.cur = cur;
        if r0 != 0 {
            self.stop_steps += 1;
        }
        out
    }

    /// Number of steps that started with the magnet on an end stop.
    pub fn end_stop_steps(&self) -> u64 {
        self.stop_steps
    }

    /// Number of times a non-finite state was detected and reset to zero.
    pub fn nonfinite_resets(&self) -> u64 {
        self.resets
    }

    #[inline]
    fn regime_of(&self, x: &SVector<f64, N>) -> usize {
        match self.stroke {
            Some((v, h, s)) => {
                let r = x[v] - x[h];
                if r > s {
                    1
                } else if r < -s {
                    2
                } else {
                    0
                }
            }
            None => 0,
        }
    }

    #[inline]
    fn deriv(&self, x: &SVector<f64, N>, u: &SVector<f64, NU>) -> SVector<f64, N> {
        let r = self.regime_of(x);
        self.a[r] * x + self.b[r] * u
    }

    /// Advance one step with inputs `u` (held over the step) and return the
    /// outputs at the end of the step. Non-finite inputs are replaced by 0;
    /// a non-finite state (only possible with an unstable explicit scheme)
    /// is reset to zero and counted.
    #[inline]
    pub fn step(&mut self, u: &SVector<f64, NU>) -> AxisOutput {
        self.step_inputs((*u).into())
    }

    /// [`Self::step`] with the inputs as an array (no nalgebra on the hot path).
    #[inline]
    pub fn step_inputs(&mut self, ua: [f64; NU]) -> AxisOutput {
        self.step_impl::<true>(ua)
    }

    /// [`Self::step_inputs`] without the tip position (`tip` is not computed
    /// on the modal path and must not be used; read it with [`Self::tip_m`]
    /// when needed): the outputs a control loop needs each sample. Same
    /// state update, counters and non-finite handling; the other outputs are
    /// bit-identical.
    #[inline]
    pub fn step_inputs_fast(&mut self, ua: [f64; NU]) -> AxisOutput {
        self.step_impl::<false>(ua)
    }

    /// Tip position x_h (m) of the current state; bit-identical to the `tip`
    /// output of the step that produced the state.
    pub fn tip_m(&self) -> f64 {
        match &self.modal {
            Some(m) => modal_outputs::<N>(&m[self.cur].outw.0, &self.z.0)[2],
            None => self.x[self.tip],
        }
    }

    #[inline(always)]
    fn step_impl<const TIP: bool>(&mut self, ua: [f64; NU]) -> AxisOutput {
        // The modal path takes the inputs unchecked: a non-finite input makes
        // the new state non-finite (0·∞ = NaN, c·∞ = ±∞), which its cold
        // path detects before anything is stored and then repeats the step
        // with the inputs sanitised (same result as sanitising here).
        if self.path != StepPath::Dense
            && let Some(o) = self.step_modal::<TIP>(
                ua[IN_FORCE],
                ua[IN_DRIVE],
                [ua[IN_HAND_POS], ua[IN_HAND_VEL], ua[IN_ONE]],
            )
        {
            return o;
        }
        self.step_general(ua)
    }

    /// The dense ZOH, RK4 and semi-implicit Euler steps.
    #[inline]
    fn step_general(&mut self, mut ua: [f64; NU]) -> AxisOutput {
        sanitize(&mut ua);
        let u = SVector::<f64, NU>::from(ua);
        let r0 = self.regime_of(&self.x);
        if r0 != 0 {
            self.stop_steps += 1;
        }
        match self.integrator {
            Integrator::Zoh => {
                // x ← Φ x + Γ u as column axpys over fixed-size arrays.
                let mut y = [0.0; N];
                let pc = &self.phi_cols[r0];
                for (col, &xj) in pc.iter().zip(self.x.iter()) {
                    for (yi, ci) in y.iter_mut().zip(col.iter()) {
                        *yi += ci * xj;
                    }
                }
                let gc = &self.gamma_cols[r0];
                for (col, &uj) in gc.iter().zip(u.iter()) {
                    for (yi, ci) in y.iter_mut().zip(col.iter()) {
                        *yi += ci * uj;
                    }
                }
                self.x = SVector::from(y);
            }
            Integrator::Rk4 => {
                let h = self.dt;
                let x = self.x;
                let k1 = self.deriv(&x, &u);
                let k2 = self.deriv(&(x + k1 * (0.5 * h)), &u);
                let k3 = self.deriv(&(x + k2 * (0.5 * h)), &u);
                let k4 = self.deriv(&(x + k3 * h), &u);
                self.x = x + (k1 + k2 * 2.0 + k3 * 2.0 + k4) * (h / 6.0);
            }
            Integrator::SemiImplicitEuler => {
                let h = self.dt;
                let d = self.a[r0] * self.x + self.b[r0] * u;
                let mut xn = self.x;
                for i in self.n_pos..N {
                    xn[i] += h * d[i];
                }
                // Positions with the new velocities (their rows read only
                // non-position states).
                let a = &self.a[r0];
                for i in 0..self.n_pos {
                    let mut s = 0.0;
                    for j in self.n_pos..N {
                        s += a[(i, j)] * xn[j];
                    }
                    xn[i] += h * s;
                }
                self.x = xn;
            }
        }
        if !self.x.iter().all(|v| v.is_finite()) {
            self.x = SVector::zeros();
            self.resets += 1;
        }
        let r1 = self.regime_of(&self.x);
        // Only the acceleration needs a product; the other outputs are state
        // picks (their C rows are unit vectors, D rows zero).
        let accel = self.c[r1].row(OUT_ACCEL).dot(&self.x.transpose())
            + self.d[r1].row(OUT_ACCEL).dot(&u.transpose());
        let (tip, motor, stroke) = match self.stroke {
            Some((v, h, _)) => (self.x[h], self.x[self.motor], self.x[v] - self.x[h]),
            None => (self.x[self.tip], self.x[self.motor], 0.0),
        };
        AxisOutput {
            accel,
            tip,
            motor,
            stroke,
        }
    }
}

/// Replace non-finite inputs by 0.
#[inline]
fn sanitize(u: &mut [f64; NU]) {
    for v in u.iter_mut() {
        if !v.is_finite() {
            *v = 0.0;
        }
    }
}

/// Inputs of the two-axis plant for one sample.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PlantInput {
    /// Pantograph force command (x, y), N.
    pub force_n: [f64; 2],
    /// Haptuator drive (x axis), V.
    pub drive_v: f64,
    /// Hand position (x, y), m.
    pub hand_m: [f64; 2],
    /// Hand velocity (x, y), m/s.
    pub hand_vel_m_s: [f64; 2],
}

/// Outputs of the two-axis plant after one sample.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PlantOutput {
    /// Tip acceleration (x, y), m/s².
    pub accel_m_s2: [f64; 2],
    /// Tip position (x, y), m.
    pub tip_m: [f64; 2],
    /// Motor-side (encoder) position (x, y), m.
    pub motor_m: [f64; 2],
    /// Haptuator magnet stroke, m.
    pub stroke_m: f64,
}

/// Outputs of the two-axis plant that a control loop needs each sample
/// ([`DualStagePlant::step_fast`]): [`PlantOutput`] without the tip
/// position (ground truth, [`DualStagePlant::tip_m`]).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PlantFastOutput {
    /// Tip acceleration (x, y), m/s².
    pub accel_m_s2: [f64; 2],
    /// Motor-side (encoder) position (x, y), m.
    pub motor_m: [f64; 2],
    /// Haptuator magnet stroke, m.
    pub stroke_m: f64,
}

/// The two-axis dual-stage plant (x with Haptuator, y without).
#[derive(Debug, Clone)]
pub struct DualStagePlant {
    /// x axis simulator.
    pub x: AxisSim<NX>,
    /// y axis simulator.
    pub y: AxisSim<NYAX>,
}

impl DualStagePlant {
    /// Build both axes from a configuration at its sample rate.
    pub fn new(cfg: &RigConfig, integrator: Integrator) -> Result<Self, RigError> {
        Self::with_rate(cfg, integrator, cfg.rig.sample_rate_hz)
    }

    /// Build both axes at an explicit sample rate (Hz).
    pub fn with_rate(cfg: &RigConfig, integrator: Integrator, fs: f64) -> Result<Self, RigError> {
        if !(fs.is_finite() && fs > 0.0) {
            return Err(RigError::InvalidParameter {
                name: "fs",
                value: fs,
                reason: "sample rate must be finite and > 0".into(),
            });
        }
        let mx = AxisModel::new(cfg, Axis::X)?;
        let my = AxisModel::new(cfg, Axis::Y)?;
        Ok(Self {
            x: AxisSim::new(&mx, integrator, 1.0 / fs)?,
            y: AxisSim::new(&my, integrator, 1.0 / fs)?,
        })
    }

    /// Zero both axes.
    pub fn reset(&mut self) {
        self.x.reset();
        self.y.reset();
    }

    /// Advance one sample.
    #[inline]
    pub fn step(&mut self, i: &PlantInput) -> PlantOutput {
        let ox = self
            .x
            .step_inputs([i.force_n[0], i.drive_v, i.hand_m[0], i.hand_vel_m_s[0], 1.0]);
        let oy = self
            .y
            .step_inputs([i.force_n[1], 0.0, i.hand_m[1], i.hand_vel_m_s[1], 1.0]);
        PlantOutput {
            accel_m_s2: [ox.accel, oy.accel],
            tip_m: [ox.tip, oy.tip],
            motor_m: [ox.motor, oy.motor],
            stroke_m: ox.stroke,
        }
    }

    /// [`Self::step`] without the tip position: same state, counters and
    /// (bit-identical) other outputs; the tip of the new state is
    /// [`Self::tip_m`]. Saves the tip's dot products on the modal path.
    #[inline]
    pub fn step_fast(&mut self, i: &PlantInput) -> PlantFastOutput {
        let ox =
            self.x
                .step_inputs_fast([i.force_n[0], i.drive_v, i.hand_m[0], i.hand_vel_m_s[0], 1.0]);
        let oy = self
            .y
            .step_inputs_fast([i.force_n[1], 0.0, i.hand_m[1], i.hand_vel_m_s[1], 1.0]);
        PlantFastOutput {
            accel_m_s2: [ox.accel, oy.accel],
            motor_m: [ox.motor, oy.motor],
            stroke_m: ox.stroke,
        }
    }

    /// Tip position (x, y) of the current state, m (what [`Self::step`]
    /// returned as `tip_m` for the last step, bit for bit).
    pub fn tip_m(&self) -> [f64; 2] {
        [self.x.tip_m(), self.y.tip_m()]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::RigConfig;

    /// `step_fast` + `tip_m` reproduce `step` bit for bit (state, outputs,
    /// counters), through end-stop episodes, hand motion and non-finite
    /// inputs.
    #[test]
    fn step_fast_and_tip_on_demand_match_step() {
        let cfg = RigConfig::default();
        let mut a = DualStagePlant::new(&cfg, Integrator::Zoh).unwrap();
        let mut b = a.clone();
        assert!(a.x.is_modal() && a.y.is_modal());
        // The default rig takes the fast input paths: force and drive as
        // unit columns on x (all three regimes), no drive column on y.
        assert!(a.x.drive_unit && !a.x.drive_free && !a.x.fast_d);
        assert!(a.y.drive_free && !a.y.fast_d);
        assert_eq!(a.x.path, StepPath::ModalDriveUnit);
        assert_eq!(a.y.path, StepPath::ModalNoDrive);
        let vmax = cfg.limits.haptuator_drive_max_v;
        for k in 0..40_000 {
            let t = k as f64 * 1e-4;
            let w = 2.0 * PI * t;
            let mut i = PlantInput {
                force_n: [0.8 * (37.0 * w).sin(), 0.5 * (23.0 * w).cos()],
                drive_v: vmax * (55.0 * w).sin(),
                hand_m: [1e-3 * (3.0 * w).sin(), 0.0],
                hand_vel_m_s: [6e-3 * PI * (3.0 * w).cos(), 0.0],
            };
            if k % 997 == 5 {
                i.force_n[k % 2] = f64::NAN;
                i.drive_v = f64::INFINITY;
            }
            let o = a.step(&i);
            let f = b.step_fast(&i);
            assert_eq!(
                o.accel_m_s2.map(f64::to_bits),
                f.accel_m_s2.map(f64::to_bits)
            );
            assert_eq!(o.motor_m.map(f64::to_bits), f.motor_m.map(f64::to_bits));
            assert_eq!(o.stroke_m.to_bits(), f.stroke_m.to_bits());
            assert_eq!(o.tip_m.map(f64::to_bits), b.tip_m().map(f64::to_bits));
            assert!(o.accel_m_s2.iter().chain(&o.tip_m).all(|v| v.is_finite()));
        }
        assert!(a.x.end_stop_steps() > 100);
        assert_eq!(a.x.end_stop_steps(), b.x.end_stop_steps());
        assert_eq!(a.x.nonfinite_resets() + a.y.nonfinite_resets(), 0);
        assert_eq!(a.x.state(), b.x.state());
        assert_eq!(a.y.state(), b.y.state());
    }
}
