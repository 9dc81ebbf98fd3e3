//! Stepping one axis: the discretised maps of the three end-stop regimes
//! and the step that switches between them. The dense update is the
//! readable reference; the modal path ([`super::modal`], [`super::kernel`])
//! is the fast one, chosen once at construction ([`StepPath`]).

use super::kernel::{colmul, modal_outputs, modal_pass};
use super::modal::{LANES, ModalRegime, SlowInputs, from_lanes, lanes, modal_regime, to_lanes};
use super::{
    AxisModel, AxisOutput, IN_DRIVE, IN_FORCE, IN_HAND_POS, IN_HAND_VEL, IN_ONE, NU, NY, OUT_ACCEL,
};
use crate::error::RigError;
use crate::lanes::{A16, L2};
use crate::lti::{self, Integrator};
use nalgebra::{DMatrix, SMatrix, SVector};

pub(super) fn to_s<const R: usize, const C: usize>(
    m: &DMatrix<f64>,
) -> Result<SMatrix<f64, R, C>, RigError> {
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
    pub(super) drive_free: bool,
    // Some regime has a feed-through of force or drive to ẍ_h.
    pub(super) fast_d: bool,
    // Every regime takes the drive as (0, 1) in its block groups.
    pub(super) drive_unit: bool,
    // Which step runs (from the flags above; one test per step).
    pub(super) path: StepPath,
}
/// Which step [`AxisSim`] runs, chosen once from its configuration.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum StepPath {
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
pub(super) fn sanitize(u: &mut [f64; NU]) {
    for v in u.iter_mut() {
        if !v.is_finite() {
            *v = 0.0;
        }
    }
}
