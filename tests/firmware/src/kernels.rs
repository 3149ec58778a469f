//! The measured kernels. Each has a setup (fresh state), the step under test, and a check of
//! its result (so the optimiser cannot drop the work, and a wrong result fails the run).

use core::cell::RefCell;
use cortex_m::interrupt::{self, Mutex};
use nalgebra::Vector3;
use nalgebra::{SMatrix, SVector};
use nav_core::math::kalman::{fuse_scalar, propagate_dense, FusionOutcome, Gate};
use nav_core::transfer_alignment::{
    ConventionalFilter, FlightFilter, MasterSample, ProposedFilter, SlaveSample, TaConfig,
    TransferAlignment,
};
use nav_core::Estimator;

/// One measured kernel.
pub struct Kernel {
    pub name: &'static str,
    pub setup: fn(),
    pub run: fn(),
    pub check: fn() -> bool,
}

pub static KERNELS: &[Kernel] = &[
    Kernel {
        name: "ta9_step",
        setup: ta9_setup,
        run: ta9_step,
        check: ta9_check,
    },
    Kernel {
        name: "ta12_step",
        setup: ta12_setup,
        run: ta12_step,
        check: ta12_check,
    },
    Kernel {
        name: "ta15_step",
        setup: ta15_setup,
        run: ta15_step,
        check: ta15_check,
    },
    Kernel {
        name: "ta9_step_rejected",
        setup: ta9_setup,
        run: ta9_step_rejected,
        check: ta9_check,
    },
    Kernel {
        name: "ta9_step_rejected_first",
        setup: ta9_setup,
        run: ta9_step_rejected_first,
        check: ta9_check,
    },
    Kernel {
        name: "ta12_step_rejected",
        setup: ta12_setup,
        run: ta12_step_rejected,
        check: ta12_check,
    },
    Kernel {
        name: "ta12_step_rejected_first",
        setup: ta12_setup,
        run: ta12_step_rejected_first,
        check: ta12_check,
    },
    Kernel {
        name: "ta15_step_rejected",
        setup: ta15_setup,
        run: ta15_step_rejected,
        check: ta15_check,
    },
    Kernel {
        name: "ta15_step_rejected_first",
        setup: ta15_setup,
        run: ta15_step_rejected_first,
        check: ta15_check,
    },
    Kernel {
        name: "ta9_propagate",
        setup: ta9_setup,
        run: ta9_propagate,
        check: ta9_check,
    },
    Kernel {
        name: "ta12_propagate",
        setup: ta12_setup,
        run: ta12_propagate,
        check: ta12_check,
    },
    Kernel {
        name: "ta15_propagate",
        setup: ta15_setup,
        run: ta15_propagate,
        check: ta15_check,
    },
    Kernel {
        name: "vc_classical_step",
        setup: vcc_setup_settled,
        run: vcc_step,
        check: vcc_check,
    },
    Kernel {
        name: "vc_classical_step_held",
        setup: vcc_setup_settled_held,
        run: vcc_step,
        check: vcc_check,
    },
    Kernel {
        name: "vc_classical_step_transient",
        setup: vcc_setup_transient,
        run: vcc_step,
        check: vcc_check,
    },
    Kernel {
        name: "vc_classical_step_sigma",
        setup: vcc_setup_sigma,
        run: vcc_step,
        check: vcc_check,
    },
    Kernel {
        name: "vc_aided_step",
        setup: vca_setup_settled,
        run: vca_step,
        check: vca_check,
    },
    Kernel {
        name: "vc_aided_step_held",
        setup: vca_setup_settled_held,
        run: vca_step,
        check: vca_check,
    },
    Kernel {
        name: "vc_aided_step_transient",
        setup: vca_setup_transient,
        run: vca_step,
        check: vca_check,
    },
    Kernel {
        name: "vc_aided_step_sigma",
        setup: vca_setup_sigma,
        run: vca_step,
        check: vca_check,
    },
    Kernel {
        name: "ins_mech_step",
        setup: ins_setup,
        run: ins_step,
        check: ins_check,
    },
    Kernel {
        name: "eskf17_predict",
        setup: seeker_setup,
        run: eskf_predict,
        check: seeker_check,
    },
    Kernel {
        name: "eskf17_predict_flight",
        setup: seeker_setup_flight,
        run: eskf_predict,
        check: seeker_check,
    },
    Kernel {
        name: "eskf17_sample_psd_checked",
        setup: seeker_setup_sample_step,
        run: eskf_sample_step,
        check: seeker_check,
    },
    Kernel {
        name: "eskf17_los_update",
        setup: seeker_setup_predicted,
        run: eskf_los_update,
        check: seeker_check,
    },
    Kernel {
        name: "kalman17_scalar_update",
        setup: k17_setup,
        run: k17_scalar,
        check: k17_check,
    },
    Kernel {
        name: "dense17_predict",
        setup: k17_setup,
        run: k17_dense_predict,
        check: k17_check_pred,
    },
];

/// A kernel's state, shared by its setup, the measured call and the check.
type Slot<S> = Mutex<RefCell<Option<S>>>;

/// Replaces the state in `slot`.
fn store<S>(slot: &Slot<S>, state: Option<S>) {
    interrupt::free(|cs| {
        if let Ok(mut s) = slot.borrow(cs).try_borrow_mut() {
            *s = state;
        }
    });
}

/// Runs `f` on the state in `slot`, if any (inlined: the measured call is `f`'s body).
#[inline(always)]
fn with_state<S>(slot: &Slot<S>, f: impl FnOnce(&mut S)) {
    interrupt::free(|cs| {
        if let Some(s) = slot
            .borrow(cs)
            .try_borrow_mut()
            .ok()
            .as_deref_mut()
            .and_then(Option::as_mut)
        {
            f(s);
        }
    });
}

/// `check` of the state in `slot`; `false` when there is none.
fn check_state<S>(slot: &Slot<S>, check: impl FnOnce(&S) -> bool) -> bool {
    interrupt::free(|cs| {
        slot.borrow(cs)
            .try_borrow()
            .ok()
            .as_deref()
            .and_then(Option::as_ref)
            .is_some_and(check)
    })
}

struct S17 {
    x: SVector<f32, 17>,
    p: SMatrix<f32, 17, 17>,
    phi: SMatrix<f32, 17, 17>,
    q: SMatrix<f32, 17, 17>,
    fused: bool,
}

static S17_STATE: Slot<S17> = Mutex::new(RefCell::new(None));

fn k17_setup() {
    let mut p = SMatrix::<f32, 17, 17>::identity();
    for i in 0..16 {
        p[(i, i + 1)] = 0.1;
        p[(i + 1, i)] = 0.1;
    }
    let mut phi = SMatrix::<f32, 17, 17>::identity();
    for i in 0..16 {
        phi[(i, i + 1)] = 0.01;
    }
    let q = SMatrix::<f32, 17, 17>::identity() * 1e-4;
    store(
        &S17_STATE,
        Some(S17 {
            x: SVector::zeros(),
            p,
            phi,
            q,
            fused: false,
        }),
    );
}

fn k17_scalar() {
    with_state(&S17_STATE, |s| {
        let mut h = SVector::<f32, 17>::zeros();
        for (i, v) in [
            (0usize, 1.0f32),
            (1, -0.5),
            (2, 0.2),
            (6, 0.3),
            (7, -0.1),
            (8, 0.05),
            (15, 1.0),
            (16, 0.4),
        ] {
            h[i] = v;
        }
        let h = core::hint::black_box(h);
        let r = fuse_scalar(&mut s.x, &mut s.p, &h, 0.5, 0.01, Gate::Nis(25.0));
        s.fused = matches!(r, Ok(rep) if rep.outcome == FusionOutcome::Fused);
    });
}

fn k17_check() -> bool {
    check_state(&S17_STATE, |s| s.fused && s.p[(0, 0)] < 1.0 && s.x[0] > 0.0)
}

fn k17_dense_predict() {
    with_state(&S17_STATE, |s| {
        let phi = core::hint::black_box(s.phi);
        propagate_dense(&mut s.p, &phi, &s.q);
    });
}

fn k17_check_pred() -> bool {
    check_state(&S17_STATE, |s| s.p[(0, 0)] > 1.0)
}

// ---------------------------------------------------------------- transfer alignment

/// TA filter step, µs.
const TA_DT_US: u64 = 10_000;

fn ta_time(k: u32) -> nav_core::time::Timestamp {
    nav_core::time::Timestamp::from_micros(u64::from(k) * TA_DT_US)
}

/// The same configuration the golden-vector replay uses.
fn ta_config() -> TaConfig<f32> {
    nav_golden::ta_config()
}

fn ta_samples(k: u32) -> (MasterSample<f32>, SlaveSample<f32>) {
    let t = ta_time(k);
    let w = Vector3::new(0.001, -0.002, 0.0005);
    let f = Vector3::new(9.8, 0.05, -9.81);
    // Slave sees a small fixed misalignment (θ × f, θ × ω) plus flexure-like wobble.
    let theta = Vector3::new(0.004, -0.003, 0.002);
    let master = MasterSample {
        time: t,
        angular_rate_rad_s: w,
        angular_accel_rad_s2: Vector3::zeros(),
        specific_force_m_s2: f,
    };
    let slave = SlaveSample {
        time: t,
        angular_rate_rad_s: w - theta.cross(&w),
        specific_force_m_s2: f - theta.cross(&f),
    };
    (core::hint::black_box(master), core::hint::black_box(slave))
}

/// The outlier added to one master specific-force component for the `…_step_rejected`
/// kernels, m/s²: 200 σ of the paper configuration's accelerometer noise (5 mm/s²), far outside
/// the 5σ gate.
const OUTLIER_M_S2: f32 = 1.0;

/// One step with [`OUTLIER_M_S2`] added to the master's specific force along `axis`: the
/// gate must reject exactly one row. Inlined into each kernel: the axis folds and the harness
/// adds no call to the measured step.
#[inline(always)]
fn gated_step<const K: usize, const N: usize>(
    s: &mut Ta<TransferAlignment<f32, K, N>>,
    axis: usize,
) {
    let (mut m, sl) = ta_samples(s.k);
    if let Some(f) = m.specific_force_m_s2.get_mut(axis) {
        *f += OUTLIER_M_S2;
    }
    s.ok &= matches!(s.filter.step(&m, &sl), Ok(r) if r.predictions == 1
        && r.updates.iter().filter(|u| u.outcome == FusionOutcome::Rejected).count() == 1);
    s.k += 1;
}

struct Ta<F> {
    filter: F,
    k: u32,
    ok: bool,
}

static TA9: Slot<Ta<ConventionalFilter<f32>>> = Mutex::new(RefCell::new(None));
static TA12: Slot<Ta<ProposedFilter<f32>>> = Mutex::new(RefCell::new(None));
static TA15: Slot<Ta<FlightFilter<f32>>> = Mutex::new(RefCell::new(None));

macro_rules! ta_kernel {
    ($setup:ident, $step:ident, $prop:ident, $rejected:ident, $rejected_first:ident, $check:ident, $cell:ident, $ty:ty, $config:expr) => {
        /// Prediction only (a master-data dropout epoch).
        fn $prop() {
            with_state(&$cell, |s| {
                let t = core::hint::black_box(ta_time(s.k));
                s.ok &= matches!(s.filter.propagate(t), Ok(p) if p.predictions == 1);
                s.k += 1;
            });
        }
        fn $setup() {
            let mut state = <$ty>::new(&$config, &nav_golden::ta_initial())
                .ok()
                .map(|filter| Ta { filter, k: 0, ok: true });
            // Warm up so the measured call is a steady-state predict + 6 updates.
            if let Some(s) = state.as_mut() {
                for _ in 0..5 {
                    let (m, sl) = ta_samples(s.k);
                    s.ok &= s.filter.step(&m, &sl).is_ok();
                    s.k += 1;
                }
            }
            store(&$cell, state);
        }
        fn $step() {
            with_state(&$cell, |s| {
                let (m, sl) = ta_samples(s.k);
                s.ok &= matches!(s.filter.step(&m, &sl), Ok(r) if r.predictions == 1);
                s.k += 1;
            });
        }
        /// A step whose master specific force along X is an outlier ([`OUTLIER_M_S2`]): the
        /// gate rejects that row (the second of its pair, dω_Z–df_X) and the pair's first row
        /// is fused alone — the dearer path a flight loop meets whenever a channel is gated.
        fn $rejected() {
            with_state(&$cell, |s| gated_step(s, 0));
        }
        /// The same with the outlier along Y: the gated row is the FIRST of its pair (df_Y–df_Z),
        /// so the pair's second row is fused alone.
        fn $rejected_first() {
            with_state(&$cell, |s| gated_step(s, 1));
        }
        fn $check() -> bool {
            check_state(&$cell, |s| s.ok && s.filter.theta().iter().all(|v| v.is_finite()))
        }
    };
}

ta_kernel!(
    ta9_setup,
    ta9_step,
    ta9_propagate,
    ta9_step_rejected,
    ta9_step_rejected_first,
    ta9_check,
    TA9,
    ConventionalFilter<f32>,
    ta_config()
);
ta_kernel!(
    ta12_setup,
    ta12_step,
    ta12_propagate,
    ta12_step_rejected,
    ta12_step_rejected_first,
    ta12_check,
    TA12,
    ProposedFilter<f32>,
    ta_config()
);
// The flight configuration: the golden configuration with the bias σ of `TaConfig::flight`.
ta_kernel!(
    ta15_setup,
    ta15_step,
    ta15_propagate,
    ta15_step_rejected,
    ta15_step_rejected_first,
    ta15_check,
    TA15,
    FlightFilter<f32>,
    TaConfig {
        accel_bias_sigma_m_s2: TaConfig::<f32>::flight(
            nav_core::transfer_alignment::PaperCase::Case2
        )
        .accel_bias_sigma_m_s2,
        ..ta_config()
    }
);

// ---------------------------------------------------------------- vertical channel
//
// Four cases per loop, all at the nominal 10 ms IMU interval with the χ² gate on:
// * `…_step`: σ settled (P at the design's steady state, not propagated), a new aid sample
//   landing and gated (baro; aided: baro and velocity): the dearest step of normal flight,
//   the one the budget applies to;
// * `…_step_held`: σ settled, no new sample (the held samples extrapolated): the steps between
//   aid samples (3 of 4 at the papers' 25 Hz baro);
// * `…_step_transient`: σ not settled yet, the step only accumulates the covariance interval
//   (the 4th step after start), a sample landing;
// * `…_step_sigma`: σ not settled and this step completes a covariance interval (the 10th
//   step after start): P propagated once, a sample landing — the worst case of a nominal step.

use nav_core::time::Timestamp;
use nav_core::vertical_channel::{
    AidedLoop, BaroSample, ClassicalLoop, ImuSample, InitialState, VelocitySample, VerticalSigma,
};

// The χ² gate is on in the bench (its cost is part of the step): every sample is gated.
use nav_golden::vc_gate;

const VC_DT_S: f64 = 0.01;

fn vc_init() -> InitialState<f32> {
    nav_golden::vc_initial()
}

/// Nominal IMU interval of the bench, µs.
const VC_DT_US: u64 = (VC_DT_S * 1.0e6) as u64;
/// Steps of the σ-propagation case before the measured one (covariance interval 0.1 s = 10
/// IMU intervals: the 10th step propagates).
const VC_STEPS_BEFORE_SIGMA: u32 = 9;
/// Steps of the transient case before the measured one.
const VC_STEPS_BEFORE_TRANSIENT: u32 = 3;
/// Most steps run to let σ settle (the check fails if it has not).
const VC_MAX_SETTLE_STEPS: u32 = 1_000_000;

fn vc_imu(k: u32) -> (ImuSample<f32>, BaroSample<f32>, VelocitySample<f32>) {
    let t = Timestamp::from_micros((u64::from(k) + 1) * VC_DT_US);
    let imu = ImuSample {
        time: t,
        specific_force_up_m_s2: 9.80,
    };
    let baro = BaroSample {
        time: t,
        altitude_m: 500.0,
    };
    let vel = VelocitySample {
        time: t,
        vz_up_m_s: 0.0,
    };
    (
        core::hint::black_box(imu),
        core::hint::black_box(baro),
        core::hint::black_box(vel),
    )
}

/// What the measured step must have done with σ (checked after it).
#[derive(Clone, Copy, PartialEq)]
enum VcCase {
    /// σ settled before and after the step.
    Settled,
    /// σ unchanged by the step and not settled.
    Accumulated,
    /// σ changed by the step (propagated) and not settled.
    Propagated,
}

/// A vertical loop as the bench drives it.
trait VcLoop {
    /// One step `k` with (`samples`) or without new aid samples; `true` when accepted.
    fn bench_step(&mut self, k: u32, samples: bool) -> bool;
    fn sigma(&self) -> VerticalSigma<f32>;
    fn steady_sigma(&self) -> VerticalSigma<f32>;
    fn altitude_m(&self) -> f32;
}

impl VcLoop for ClassicalLoop<f32> {
    #[inline(always)]
    fn bench_step(&mut self, k: u32, samples: bool) -> bool {
        let (imu, baro, _) = vc_imu(k);
        self.step(&imu, samples.then_some(&baro)).is_ok()
    }
    fn sigma(&self) -> VerticalSigma<f32> {
        ClassicalLoop::sigma(self)
    }
    fn steady_sigma(&self) -> VerticalSigma<f32> {
        ClassicalLoop::steady_sigma(self)
    }
    fn altitude_m(&self) -> f32 {
        ClassicalLoop::altitude_m(self)
    }
}

impl VcLoop for AidedLoop<f32> {
    #[inline(always)]
    fn bench_step(&mut self, k: u32, samples: bool) -> bool {
        let (imu, baro, vel) = vc_imu(k);
        self.step(
            &imu,
            samples.then_some(&baro),
            samples.then_some(&vel),
        )
        .is_ok()
    }
    fn sigma(&self) -> VerticalSigma<f32> {
        AidedLoop::sigma(self)
    }
    fn steady_sigma(&self) -> VerticalSigma<f32> {
        AidedLoop::steady_sigma(self)
    }
    fn altitude_m(&self) -> f32 {
        AidedLoop::altitude_m(self)
    }
}

struct Vc<L> {
    filter: L,
    k: u32,
    ok: bool,
    /// New aid samples in the measured step.
    samples: bool,
    case: VcCase,
    /// σ before the measured step.
    sigma_before: VerticalSigma<f32>,
}

impl<L: VcLoop> Vc<L> {
    /// The loop after the steps of `case` (with samples), ready for the measured step.
    fn prepared(filter: L, case: VcCase, samples: bool) -> Self {
        let sigma_before = filter.sigma();
        let mut s = Self {
            filter,
            k: 0,
            ok: true,
            samples,
            case,
            sigma_before,
        };
        let settled = |f: &L| f.sigma() == f.steady_sigma();
        let before = match case {
            VcCase::Settled => VC_MAX_SETTLE_STEPS,
            VcCase::Accumulated => VC_STEPS_BEFORE_TRANSIENT,
            VcCase::Propagated => VC_STEPS_BEFORE_SIGMA,
        };
        for _ in 0..before {
            if case == VcCase::Settled && settled(&s.filter) {
                break;
            }
            s.ok &= s.filter.bench_step(s.k, true);
            s.k += 1;
        }
        s.sigma_before = s.filter.sigma();
        s
    }

    #[inline(always)]
    fn step(&mut self) {
        self.ok &= self.filter.bench_step(self.k, self.samples);
        self.k += 1;
    }

    fn check(&self) -> bool {
        let sigma = self.filter.sigma();
        let settled = sigma == self.filter.steady_sigma();
        let case_ok = match self.case {
            VcCase::Settled => settled && sigma == self.sigma_before,
            VcCase::Accumulated => !settled && sigma == self.sigma_before,
            VcCase::Propagated => !settled && sigma != self.sigma_before,
        };
        self.ok && case_ok && self.filter.altitude_m().is_finite()
    }
}

static VCC: Slot<Vc<ClassicalLoop<f32>>> = Mutex::new(RefCell::new(None));
static VCA: Slot<Vc<AidedLoop<f32>>> = Mutex::new(RefCell::new(None));

fn vcc_setup(case: VcCase, samples: bool) {
    let cfg = nav_golden::vc_classical_config();
    let state = ClassicalLoop::new(&cfg, &vc_init())
        .ok()
        .and_then(|mut filter| {
            filter.set_gate(vc_gate()).ok()?;
            Some(Vc::prepared(filter, case, samples))
        });
    store(&VCC, state);
}

fn vcc_setup_settled() {
    vcc_setup(VcCase::Settled, true);
}
fn vcc_setup_settled_held() {
    vcc_setup(VcCase::Settled, false);
}
fn vcc_setup_transient() {
    vcc_setup(VcCase::Accumulated, true);
}
fn vcc_setup_sigma() {
    vcc_setup(VcCase::Propagated, true);
}

fn vcc_step() {
    with_state(&VCC, Vc::step);
}

fn vcc_check() -> bool {
    check_state(&VCC, Vc::check)
}

fn vca_setup(case: VcCase, samples: bool) {
    let cfg = nav_golden::vc_aided_config();
    let state = AidedLoop::new(&cfg, &vc_init())
        .ok()
        .and_then(|mut filter| {
            filter.set_gate(vc_gate()).ok()?;
            Some(Vc::prepared(filter, case, samples))
        });
    store(&VCA, state);
}

fn vca_setup_settled() {
    vca_setup(VcCase::Settled, true);
}
fn vca_setup_settled_held() {
    vca_setup(VcCase::Settled, false);
}
fn vca_setup_transient() {
    vca_setup(VcCase::Accumulated, true);
}
fn vca_setup_sigma() {
    vca_setup(VcCase::Propagated, true);
}

fn vca_step() {
    with_state(&VCA, Vc::step);
}

fn vca_check() -> bool {
    check_state(&VCA, Vc::check)
}

// ---------------------------------------------------------------- seeker-aided INS

use nalgebra::Vector2;
use nav_core::math::rotation::{dcm_to_quat, euler_to_dcm, quat_to_dcm};
use nav_core::seeker_ins::{
    gimbal_angles_of, landmark_vector_ned, paper_initial_covariance, ImuIncrement, Ins, InsState,
    Landmark, LosSample, Position, SeekerIns, SeekerInsConfig, SeekerInsInitial,
};

const INS_DT_S: f32 = 0.01;

fn ins_initial() -> InsState<f32> {
    let deg = core::f64::consts::PI / 180.0;
    InsState {
        position: Position {
            lat_rad: 37.0 * deg,
            lon_rad: 127.0 * deg,
            alt_m: 1000.0,
        },
        vel_ned_m_s: Vector3::new(0.0, 200.0, 0.0),
        q_b_n: dcm_to_quat(&euler_to_dcm(0.0, 0.0, core::f32::consts::FRAC_PI_2)),
    }
}

/// The sample after the INS's last one (a regular 100 Hz clock).
fn ins_increment(ins: &Ins<f32>) -> ImuIncrement<f32> {
    let dt_us = ins.dt_us();
    let time = ins
        .time()
        .map_or(Timestamp::from_micros(dt_us), |t| t.add_micros(dt_us));
    // Level flight east: the accelerometers feel gravity (up), the gyros earth + transport rate.
    core::hint::black_box(ImuIncrement {
        time,
        delta_theta_rad: Vector3::new(1.0e-7, 4.4e-7, -3.5e-7),
        delta_v_m_s: Vector3::new(0.0, 0.0, -9.80 * INS_DT_S),
    })
}

fn landmark() -> Option<Landmark<f32>> {
    let deg = core::f64::consts::PI / 180.0;
    let lat = 37.0 * deg + 2000.0 / 6_356_000.0;
    let lon = 127.0 * deg + 70_000.0 / (6_386_000.0 * libm::cos(37.0 * deg));
    Landmark::new(Position {
        lat_rad: lat,
        lon_rad: lon,
        alt_m: 0.0,
    })
    .ok()
}

struct Seeker {
    filter: SeekerIns<f32>,
    ok: bool,
}

/// The INS kernel's state: the mechanisation and whether every step succeeded.
static INS: Slot<(Ins<f32>, bool)> = Mutex::new(RefCell::new(None));
static SEEKER: Slot<Seeker> = Mutex::new(RefCell::new(None));

fn ins_setup() {
    let ins = Ins::new(ins_initial(), INS_DT_S).ok().map(|i| (i, true));
    store(&INS, ins);
}

fn ins_step() {
    with_state(&INS, |(ins, ok)| {
        *ok &= ins.step(&ins_increment(ins)).is_ok();
    });
}

fn ins_check() -> bool {
    check_state(&INS, |(ins, ok)| {
        *ok && ins.state().vel_ned_m_s.iter().all(|v| v.is_finite())
    })
}

fn seeker_setup() {
    seeker_setup_with(SeekerInsConfig::paper, 100, 10);
}

/// As [`seeker_setup`] with the flight configuration (the IMU's scale-factor and
/// misalignment σ charged after the covariance step).
fn seeker_setup_flight() {
    seeker_setup_with(SeekerInsConfig::flight, 100, 10);
}

/// The stand-alone flight configuration one IMU sample before its covariance step (every 10
/// samples): the measured call is the sample whose arrival runs the step, with the INS step,
/// ΦPΦᵀ + Q, the instrument-error charge and the LDLᵀ check of P's PSD margin.
fn seeker_setup_sample_step() {
    seeker_setup_with(SeekerInsConfig::flight, 10, 9);
}

/// A seeker INS built from `make`, its covariance step every `interval_steps` IMU samples,
/// after `samples` samples.
fn seeker_setup_with(
    make: fn(Landmark<f32>) -> SeekerInsConfig<f32>,
    interval_steps: u16,
    samples: usize,
) {
    let state = landmark().and_then(|lm| {
        // With an interval of 100 the covariance step stays deferred: the kernels measure the
        // prediction and the update separately.
        let cfg = SeekerInsConfig {
            covariance_interval_steps: interval_steps,
            ..make(lm)
        };
        let initial = SeekerInsInitial {
            state: ins_initial(),
            covariance: paper_initial_covariance(),
        };
        SeekerIns::new(&cfg, &initial).ok()
    });
    let mut state = state.map(|filter| Seeker { filter, ok: true });
    if let Some(s) = state.as_mut() {
        for _ in 0..samples {
            let inc = ins_increment(s.filter.ins());
            s.ok &= s.filter.propagate(&inc).is_ok();
        }
    }
    store(&SEEKER, state);
}

/// As [`seeker_setup`], with P already propagated: the LOS update is measured alone (the
/// prediction it would otherwise run first is `eskf17_predict`).
fn seeker_setup_predicted() {
    seeker_setup();
    eskf_predict();
}

fn eskf_predict() {
    with_state(&SEEKER, |s| {
        s.ok &= s.filter.predict_covariance().is_ok();
    });
}

/// One IMU sample into the stand-alone filter (the increment formed in the call, as
/// `ins_mech_step` does).
fn eskf_sample_step() {
    with_state(&SEEKER, |s| {
        let inc = ins_increment(s.filter.ins());
        s.ok &= s.filter.propagate(&inc).is_ok();
    });
}

fn eskf_los_update() {
    with_state(&SEEKER, |s| {
        // The filter's own landmark (built at setup): its construction is not the update's cost.
        let st = *s.filter.state();
        let d = landmark_vector_ned(&st.position, &s.filter.config().landmark);
        let u_b = quat_to_dcm(&st.q_b_n).transpose() * d.normalize();
        let sample = core::hint::black_box(LosSample {
            time: s.filter.time().unwrap_or_default(),
            gimbal: gimbal_angles_of(&u_b),
        });
        s.ok &= s.filter.update_los(&sample).is_ok();
    });
}

fn seeker_check() -> bool {
    check_state(&SEEKER, |s| {
        s.ok && s.filter.covariance().iter().all(|v| v.is_finite())
            && s.filter.gimbal_bias_rad() != Vector2::new(f32::NAN, 0.0)
    })
}
