//! The measured kernels. Each has a setup (fresh state), the step under test, and a check of
//! its result (so the optimiser cannot drop the work, and a wrong result fails the run).

use core::cell::RefCell;
use cortex_m::interrupt::{self, Mutex};
use nalgebra::{SMatrix, SVector};
use nav_core::math::kalman::{fuse_scalar, propagate_dense, FusionOutcome, Gate};

/// One measured kernel.
pub struct Kernel {
    pub name: &'static str,
    pub setup: fn(),
    pub run: fn(),
    pub check: fn() -> bool,
}

pub static KERNELS: &[Kernel] = &[
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
