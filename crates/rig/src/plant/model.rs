//! The continuous model of one axis from a rig file: the matrices of eq. 1
//! with the finger and the two side branches, the drive stage and the three
//! end-stop regimes of the Haptuator magnet.

use super::{
    Axis, Channel, DofMap, IN_DRIVE, IN_FORCE, IN_HAND_POS, IN_HAND_VEL, IN_ONE, NU, NY, OUT_ACCEL,
    OUT_MOTOR, OUT_STROKE, OUT_TIP, Regime,
};
use crate::config::{HaptuatorConfig, PlantConfig, RigConfig};
use crate::error::RigError;
use crate::lti::{self, StateSpace};
use nalgebra::DMatrix;
use num_complex::Complex64 as C64;
use std::f64::consts::PI;

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
/// The degrees of freedom of an axis (module docs of [`super`]).
fn dof_map(axis: Axis) -> DofMap {
    match axis {
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
    }
}

/// Masses, stiffness and damping matrices of eq. 1 with the finger and the
/// side branches, and the DOF of real (non-phantom) bodies.
struct Mechanics {
    mass: Vec<f64>,
    k: DMatrix<f64>,
    c: DMatrix<f64>,
    active_dof: Vec<usize>,
}

fn mechanics(p: &PlantConfig, dofs: &DofMap) -> Result<Mechanics, RigError> {
    let nd = dofs.n_dof;
    let mut m = Mechanics {
        mass: vec![1.0; nd],
        k: DMatrix::<f64>::zeros(nd, nd),
        c: DMatrix::<f64>::zeros(nd, nd),
        active_dof: vec![dofs.h, dofs.m1, dofs.m2],
    };
    let link = |m: &mut Mechanics, i: usize, j: usize, kk: f64, cc: f64| {
        for (mat, x) in [(&mut m.k, kk), (&mut m.c, cc)] {
            mat[(i, i)] += x;
            mat[(j, j)] += x;
            mat[(i, j)] -= x;
            mat[(j, i)] -= x;
        }
    };
    m.mass[dofs.h] = p.m_h;
    m.mass[dofs.m1] = p.m_1;
    m.mass[dofs.m2] = p.m_2;
    if let Some(v) = dofs.v {
        m.mass[v] = p.m_v;
        m.active_dof.push(v);
        link(&mut m, dofs.h, v, p.k_v, p.b_v);
    }
    link(&mut m, dofs.m1, dofs.m2, p.k_1, p.b_1);
    link(&mut m, dofs.m2, dofs.h, p.k_2, p.b_2);
    m.k[(dofs.h, dofs.h)] += p.k_f;
    m.c[(dofs.h, dofs.h)] += p.b_f;
    for (br, node, dof) in [
        (p.motor_branch, dofs.m1, dofs.e),
        (p.link_branch, dofs.m2, dofs.l),
    ] {
        if let Some(br) = br {
            m.mass[dof] = br.mass;
            link(&mut m, node, dof, br.stiffness, br.damping);
            m.active_dof.push(dof);
        }
    }
    if m.mass.iter().any(|x| !(x.is_finite() && *x > 0.0)) {
        return Err(RigError::InvalidInput(
            "plant masses must be finite and > 0".into(),
        ));
    }
    Ok(m)
}

/// State matrices (A, B) of the free regime: positions, velocities and the
/// drive state.
fn free_matrices(
    p: &PlantConfig,
    h: &HaptuatorConfig,
    dofs: &DofMap,
    m: &Mechanics,
) -> (DMatrix<f64>, DMatrix<f64>) {
    let nd = dofs.n_dof;
    let n = 2 * nd + usize::from(dofs.drive.is_some());
    let mut a = DMatrix::<f64>::zeros(n, n);
    let mut b = DMatrix::<f64>::zeros(n, NU);
    for i in 0..nd {
        a[(i, nd + i)] = 1.0;
        for j in 0..nd {
            a[(nd + i, j)] = -m.k[(i, j)] / m.mass[i];
            a[(nd + i, nd + j)] = -m.c[(i, j)] / m.mass[i];
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
    (a, b)
}

/// The state-space model of (A, B) with the outputs [ẍ_h, x_h, x_1, r]; the
/// acceleration row is h's velocity row of (A, B).
fn with_outputs(dofs: &DofMap, a: &DMatrix<f64>, b: &DMatrix<f64>) -> StateSpace {
    let n = a.nrows();
    let vh = dofs.n_dof + dofs.h;
    let mut cm = DMatrix::<f64>::zeros(NY, n);
    let mut dm = DMatrix::<f64>::zeros(NY, NU);
    cm[(OUT_TIP, dofs.h)] = 1.0;
    cm[(OUT_MOTOR, dofs.m1)] = 1.0;
    if let Some(v) = dofs.v {
        cm[(OUT_STROKE, v)] = 1.0;
        cm[(OUT_STROKE, dofs.h)] = -1.0;
    }
    for j in 0..n {
        cm[(OUT_ACCEL, j)] = a[(vh, j)];
    }
    for j in 0..NU {
        dm[(OUT_ACCEL, j)] = b[(vh, j)];
    }
    StateSpace {
        a: a.clone(),
        b: b.clone(),
        c: cm,
        d: dm,
    }
}

fn build_axis(p: &PlantConfig, h: &HaptuatorConfig, axis: Axis) -> Result<AxisModel, RigError> {
    let dofs = dof_map(axis);
    let nd = dofs.n_dof;
    let m = mechanics(p, &dofs)?;
    let (a, b) = free_matrices(p, h, &dofs, &m);
    let free = with_outputs(&dofs, &a, &b);
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
            for (row, g) in [(nd + v, 1.0 / p.m_v), (nd + dofs.h, -1.0 / p.m_h)] {
                ap[(row, v)] -= g * ks;
                ap[(row, dofs.h)] += g * ks;
                ap[(row, nd + v)] -= g * bs;
                ap[(row, nd + dofs.h)] += g * bs;
                bp[(row, IN_ONE)] += g * ks * s;
                bm[(row, IN_ONE)] -= g * ks * s;
            }
            (
                with_outputs(&dofs, &ap, &bp),
                with_outputs(&dofs, &ap, &bm),
                s,
            )
        }
        None => (free.clone(), free.clone(), f64::INFINITY),
    };
    let mut active_dof = m.active_dof;
    active_dof.sort_unstable();
    let mut active: Vec<usize> = active_dof.clone();
    active.extend(active_dof.iter().map(|&d| nd + d));
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
