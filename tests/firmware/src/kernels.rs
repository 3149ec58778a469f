//! The measured kernels. Each has a setup (fresh state), the step under test, and a check of
//! its result (so the optimiser cannot drop the work, and a wrong result fails the run).

use core::cell::RefCell;
use cortex_m::interrupt::{self, Mutex};
use nalgebra::Vector3;
use nalgebra::{SMatrix, SVector};
use nav_core::math::kalman::{fuse_scalar, propagate_dense, FusionOutcome, Gate};
use nav_core::transfer_alignment::{
    AxisFlexure, ConventionalFilter, MasterSample, ProposedFilter, SlaveSample, TaConfig,
};

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

struct S17 {
    x: SVector<f32, 17>,
    p: SMatrix<f32, 17, 17>,
    phi: SMatrix<f32, 17, 17>,
    q: SMatrix<f32, 17, 17>,
    fused: bool,
}

static S17_STATE: Mutex<RefCell<Option<S17>>> = Mutex::new(RefCell::new(None));

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
    interrupt::free(|cs| {
        *S17_STATE.borrow(cs).borrow_mut() = Some(S17 {
            x: SVector::zeros(),
            p,
            phi,
            q,
            fused: false,
        });
    });
}

fn k17_scalar() {
    interrupt::free(|cs| {
        if let Some(s) = S17_STATE.borrow(cs).borrow_mut().as_mut() {
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
        }
    });
}

fn k17_check() -> bool {
    interrupt::free(|cs| {
        S17_STATE
            .borrow(cs)
            .borrow()
            .as_ref()
            .is_some_and(|s| s.fused && s.p[(0, 0)] < 1.0 && s.x[0] > 0.0)
    })
}

fn k17_dense_predict() {
    interrupt::free(|cs| {
        if let Some(s) = S17_STATE.borrow(cs).borrow_mut().as_mut() {
            let phi = core::hint::black_box(s.phi);
            propagate_dense(&mut s.p, &phi, &s.q);
        }
    });
}

fn k17_check_pred() -> bool {
    interrupt::free(|cs| {
        S17_STATE
            .borrow(cs)
            .borrow()
            .as_ref()
            .is_some_and(|s| s.p[(0, 0)] > 1.0)
    })
}

// ---------------------------------------------------------------- transfer alignment

const TA_DT_S: f32 = 0.01;

fn ta_config() -> TaConfig<f32> {
    let deg = core::f32::consts::PI / 180.0;
    TaConfig {
        lever_arm_m: Vector3::new(0.0, 5.0, 0.0),
        flexure: [
            AxisFlexure {
                sigma_rad: 0.5 * deg,
                tau_s: 0.358,
            },
            AxisFlexure {
                sigma_rad: 0.1 * deg,
                tau_s: 2.146,
            },
            AxisFlexure {
                sigma_rad: 0.1 * deg,
                tau_s: 2.146,
            },
        ],
        mount_sigma_rad: Vector3::new(0.5 * deg, 0.5 * deg, 0.5 * deg),
        rate_noise_sigma_rad_s: 2.0e-4,
        accel_noise_sigma_m_s2: 5.0e-3,
        dt_s: TA_DT_S,
        time_tolerance_s: 0.001,
        max_gap_steps: 5,
        nis_gate: Some(25.0),
    }
}

fn ta_samples(k: u32) -> (MasterSample<f32>, SlaveSample<f32>) {
    let t = k as f32 * TA_DT_S;
    let w = Vector3::new(0.001, -0.002, 0.0005);
    let f = Vector3::new(9.8, 0.05, -9.81);
    // Slave sees a small fixed misalignment (θ × f, θ × ω) plus flexure-like wobble.
    let theta = Vector3::new(0.004, -0.003, 0.002);
    let master = MasterSample {
        time_s: t,
        angular_rate_rad_s: w,
        angular_accel_rad_s2: Vector3::zeros(),
        specific_force_m_s2: f,
    };
    let slave = SlaveSample {
        time_s: t,
        angular_rate_rad_s: w - theta.cross(&w),
        specific_force_m_s2: f - theta.cross(&f),
    };
    (core::hint::black_box(master), core::hint::black_box(slave))
}

struct Ta<F> {
    filter: F,
    k: u32,
    ok: bool,
}

static TA9: Mutex<RefCell<Option<Ta<ConventionalFilter<f32>>>>> = Mutex::new(RefCell::new(None));
static TA12: Mutex<RefCell<Option<Ta<ProposedFilter<f32>>>>> = Mutex::new(RefCell::new(None));

macro_rules! ta_kernel {
    ($setup:ident, $step:ident, $check:ident, $cell:ident, $ty:ty) => {
        fn $setup() {
            let mut state = <$ty>::new(ta_config()).ok().map(|filter| Ta { filter, k: 0, ok: true });
            // Warm up so the measured call is a steady-state predict + 6 updates.
            if let Some(s) = state.as_mut() {
                for _ in 0..5 {
                    let (m, sl) = ta_samples(s.k);
                    s.ok &= s.filter.step(&m, &sl).is_ok();
                    s.k += 1;
                }
            }
            interrupt::free(|cs| *$cell.borrow(cs).borrow_mut() = state);
        }
        fn $step() {
            interrupt::free(|cs| {
                if let Some(s) = $cell.borrow(cs).borrow_mut().as_mut() {
                    let (m, sl) = ta_samples(s.k);
                    s.ok &= matches!(s.filter.step(&m, &sl), Ok(r) if r.predictions == 1);
                    s.k += 1;
                }
            });
        }
        fn $check() -> bool {
            interrupt::free(|cs| {
                $cell.borrow(cs).borrow().as_ref().is_some_and(|s| {
                    s.ok && s.filter.theta().iter().all(|v| v.is_finite())
                })
            })
        }
    };
}

ta_kernel!(ta9_setup, ta9_step, ta9_check, TA9, ConventionalFilter<f32>);
ta_kernel!(ta12_setup, ta12_step, ta12_check, TA12, ProposedFilter<f32>);
