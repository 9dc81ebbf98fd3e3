//! The plant model of the QEMU build: the analog front end simulated inside
//! the firmware, loaded at start through test frames
//! (`kilotouch firmware load-plant`).
//!
//! The host discretises the rig's linear plant (zero-order hold at the
//! sample rate, the free regime of eq. 1) and sends each channel —
//! Pantograph force x, y and Haptuator drive to tip acceleration x, y and
//! handle position x, y — as second-order sections in parallel
//! ([`kilotouch_proto::testing::Section`]). Per sample the device steps every
//! section with its input (transposed direct form II, f64 state), sums the
//! sections of each output, passes the accelerations through the
//! accelerometer (one pole per axis, static offset, clipping at the range,
//! quantisation: `kilotouch_rig::accel`'s model without its noise) and
//! rounds the handle positions to encoder counts.
//!
//! The model is linear: the Haptuator's end stops are not simulated, so the
//! plant never sets `END_STOP`. A non-finite output resets the model (flag
//! `NONFINITE`).

use crate::device::Frontend;
use kilotouch_proto::testing::{self, PlantSensors, Section, input, output, result};
use kilotouch_proto::{DaqCaps, DaqCommand, DaqSample, flag};

/// Most sections of a plant (the built-in rig needs 38).
pub const MAX_SECTIONS: usize = 64;

/// 2⁵².
const TWO52: f64 = 4_503_599_627_370_496.0;

/// Round half away from zero (as the host's `round_half_away`), without
/// `std`: for |x| < 2⁵², (|x| + 2⁵²) − 2⁵² rounds to nearest even, and a tie
/// that went down goes up.
pub fn round_half_away(x: f64) -> f64 {
    let a = x.abs();
    if a >= TWO52 || !a.is_finite() {
        return x;
    }
    let r = (a + TWO52) - TWO52;
    let r = if a - r == 0.5 { r + 1.0 } else { r };
    if x < 0.0 { -r } else { r }
}

/// One section with its state.
#[derive(Debug, Clone, Copy, Default)]
struct Sos {
    input: u8,
    output: u8,
    b: [f64; 3],
    a: [f64; 2],
    s: [f64; 2],
}

impl Sos {
    #[inline(always)]
    fn step(&mut self, x: f64) -> f64 {
        let y = self.b[0] * x + self.s[0];
        self.s[0] = self.b[1] * x - self.a[0] * y + self.s[1];
        self.s[1] = self.b[2] * x - self.a[1] * y;
        y
    }

    /// Poles strictly inside the unit circle (the stability triangle of
    /// 1 + a1 z⁻¹ + a2 z⁻²).
    fn stable(&self) -> bool {
        let [a1, a2] = self.a;
        a2.abs() < 1.0 && a1.abs() < 1.0 + a2
    }
}

/// The plant model as the device's [`Frontend`] (module docs).
#[derive(Debug, Clone)]
pub struct PlantFrontend {
    sections: [Sos; MAX_SECTIONS],
    n: usize,
    sensors: PlantSensors,
    accel: [f64; 3],
    cmd: DaqCommand,
    clock: fn() -> u32,
    cost: u32,
}

impl PlantFrontend {
    /// A plant without sections (outputs zero) and these sensors;
    /// `clock` is the cycle counter whose counts [`Self::take_cost`] sums.
    pub fn new(sensors: PlantSensors, clock: fn() -> u32) -> Self {
        Self {
            sections: [Sos::default(); MAX_SECTIONS],
            n: 0,
            sensors,
            accel: sensors.accel_offset_m_s2,
            cmd: DaqCommand::default(),
            clock,
            cost: 0,
        }
    }

    /// Sections loaded.
    pub fn sections(&self) -> usize {
        self.n
    }

    /// Cycle-counter counts spent in the model since the last call.
    pub fn take_cost(&mut self) -> u32 {
        core::mem::take(&mut self.cost)
    }

    fn reset_state(&mut self) {
        for s in &mut self.sections[..self.n] {
            s.s = [0.0; 2];
        }
        self.accel = self.sensors.accel_offset_m_s2;
    }

    /// The plant outputs for inputs `u` (N, N, V): accelerations x, y (m/s²)
    /// and handle positions x, y (m).
    fn outputs(&mut self, u: [f64; input::COUNT]) -> [f64; output::COUNT] {
        let mut y = [0.0; output::COUNT];
        for s in &mut self.sections[..self.n] {
            y[usize::from(s.output)] += s.step(u[usize::from(s.input)]);
        }
        y
    }
}

fn value(code: i16, max: f64) -> f64 {
    f64::from(code) * max / 32767.0
}

fn sat_i32(x: f64) -> i32 {
    if x.is_nan() {
        0
    } else {
        x.clamp(f64::from(i32::MIN), f64::from(i32::MAX)) as i32
    }
}

impl Frontend for PlantFrontend {
    fn apply(&mut self, cmd: &DaqCommand) {
        self.cmd = *cmd;
    }

    fn read(&mut self) -> DaqSample {
        let t0 = (self.clock)();
        let p = self.sensors;
        let c = self.cmd;
        let u = [
            value(c.force[0], p.force_max_n),
            value(c.force[1], p.force_max_n),
            value(c.drive, p.drive_max_v),
        ];
        let mut y = self.outputs(u);
        let mut flags = 0;
        if !y.iter().all(|v| v.is_finite()) {
            self.reset_state();
            y = [0.0; output::COUNT];
            flags |= flag::NONFINITE;
        }
        let a = [
            y[usize::from(output::ACCEL_X)],
            y[usize::from(output::ACCEL_Y)],
            0.0,
        ];
        let mut acc = [0i16; 3];
        for i in 0..3 {
            let al = p.accel_alpha[i];
            self.accel[i] = al * self.accel[i] + (1.0 - al) * (a[i] + p.accel_offset_m_s2[i]);
            let r = p.accel_range_m_s2;
            let v = self.accel[i];
            let v = if v > r {
                flags |= flag::CLIPPED;
                r
            } else if v < -r {
                flags |= flag::CLIPPED;
                -r
            } else {
                v
            };
            acc[i] = round_half_away(v / p.accel_m_s2_per_code).clamp(-32767.0, 32767.0) as i16;
        }
        let enc = |m: f64| sat_i32(round_half_away(m * p.encoder_counts_per_m));
        let s = DaqSample {
            enc: [
                enc(y[usize::from(output::HANDLE_X)]),
                enc(y[usize::from(output::HANDLE_Y)]),
            ],
            acc,
            flags,
        };
        self.cost = self.cost.wrapping_add((self.clock)().wrapping_sub(t0));
        s
    }

    fn safe(&mut self) {
        self.cmd = DaqCommand::default();
    }

    fn outputs(&self) -> DaqCommand {
        self.cmd
    }

    fn caps(&self) -> DaqCaps {
        let p = &self.sensors;
        DaqCaps {
            encoder_counts_per_m: p.encoder_counts_per_m,
            accel_m_s2_per_code: p.accel_m_s2_per_code,
            accel_range_m_s2: p.accel_range_m_s2,
            force_max_n: p.force_max_n,
            drive_max_v: p.drive_max_v,
        }
    }

    fn test(&mut self, op: u8, args: &[u8], idle: bool) -> Result<u32, u8> {
        let plant_op = matches!(
            op,
            testing::op::PLANT_CLEAR
                | testing::op::PLANT_SECTION
                | testing::op::PLANT_SENSORS
                | testing::op::PLANT_COMMIT
        );
        if !plant_op {
            return Err(result::UNSUPPORTED);
        }
        if !idle {
            return Err(result::BUSY);
        }
        match op {
            testing::op::PLANT_CLEAR if args.is_empty() => {
                self.n = 0;
                self.reset_state();
                Ok(0)
            }
            testing::op::PLANT_SECTION => {
                let s = Section::parse(args).ok_or(result::BAD_ARGUMENT)?;
                if self.n == MAX_SECTIONS {
                    return Err(result::FULL);
                }
                self.sections[self.n] = Sos {
                    input: s.input,
                    output: s.output,
                    b: s.b,
                    a: s.a,
                    s: [0.0; 2],
                };
                self.n += 1;
                Ok(self.n as u32)
            }
            testing::op::PLANT_SENSORS => {
                self.sensors = PlantSensors::parse(args).ok_or(result::BAD_ARGUMENT)?;
                self.reset_state();
                Ok(0)
            }
            testing::op::PLANT_COMMIT if args.is_empty() => {
                if !self.sections[..self.n].iter().all(Sos::stable) {
                    return Err(result::UNSTABLE);
                }
                self.reset_state();
                Ok(self.n as u32)
            }
            _ => Err(result::BAD_ARGUMENT),
        }
    }
}
