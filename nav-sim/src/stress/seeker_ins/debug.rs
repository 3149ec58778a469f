//! A diagnostic for a LOS update that breaks P, run only with `SEEKER_DEBUG` set.

use super::*;
use nav_core::seeker_ins::LosReport;
use nav_core::NavError;

/// When the LOS update at step `k` of case `c` left the filter `f` with a covariance that is
/// not positive semi-definite: prints the update's report, P's diagonal and the smallest
/// eigenvalues of its correlation matrix before and after, repeats the update in f64 from the
/// same prior (`before`, with the landmark `lm64`), and exits the process.
pub(super) fn dump_if_not_psd<T: Real>(
    c: &Case,
    k: u64,
    lm64: Landmark<f64>,
    before: &SeekerIns<T>,
    f: &SeekerIns<T>,
    meas: &LosSample<T>,
    r: &Result<LosReport<T>, NavError>,
) {
    let eps = T::EPS.to_f64();
    let defect = |f: &SeekerIns<T>| {
        let p = f.covariance();
        let rows: Vec<f64> = (0..17)
            .flat_map(|i| (0..17).map(move |j| (i, j)))
            .map(|(i, j)| p[(i, j)].to_f64())
            .collect();
        crate::stress::psd_defect(&rows, 17, eps)
    };
    if let Some(d) = defect(f) {
        eprintln!(
            "{}: k {k}: after {d}; before {:?}; report {:?}",
            c.name,
            defect(before),
            r
        );
        let p = before.covariance();
        eprintln!(
            "diag before {:?}",
            (0..17).map(|i| p[(i, i)].to_f64()).collect::<Vec<_>>()
        );
        let pf = p.map(|v| v.to_f64());
        let ev = correlation_eigenvalues(&pf);
        eprintln!("corr eig before {:?}", &ev[..5]);
        let pa = f.covariance().map(|v| v.to_f64());
        let ev = correlation_eigenvalues(&pa);
        eprintln!("corr eig after {:?}", &ev[..5]);
        // Same update in f64 from the same prior.
        let (r64, pa) = update_in_f64(c, lm64, before, pf, meas);
        let ev = correlation_eigenvalues(&pa);
        eprintln!(
            "f64 from same prior: {r64:?}; corr eig after {:?}",
            &ev[..5]
        );
        std::process::exit(1);
    }
}

/// The eigenvalues of the correlation matrix of `p`, ascending.
fn correlation_eigenvalues(p: &SMatrix<f64, 17, 17>) -> Vec<f64> {
    let d = p.diagonal().map(|v| 1.0 / v.max(1e-300).sqrt());
    let mut ev: Vec<f64> = SMatrix::<f64, 17, 17>::from_fn(|i, j| p[(i, j)] * d[i] * d[j])
        .symmetric_eigen()
        .eigenvalues
        .iter()
        .copied()
        .collect();
    ev.sort_by(|a, b| a.partial_cmp(b).unwrap());
    ev
}

/// The LOS update `meas` repeated in f64 from the prior of `before` (covariance `pf`): its
/// result and the covariance after it.
fn update_in_f64<T: Real>(
    c: &Case,
    lm64: Landmark<f64>,
    before: &SeekerIns<T>,
    pf: SMatrix<f64, 17, 17>,
    meas: &LosSample<T>,
) -> (Result<LosReport<f64>, NavError>, SMatrix<f64, 17, 17>) {
    let st = before.state();
    let s64 = InsState {
        position: st.position,
        vel_ned_m_s: st.vel_ned_m_s.map(|v| v.to_f64()),
        q_b_n: nalgebra::Quaternion::from(st.q_b_n.coords.map(|v| v.to_f64())),
    };
    let cfg = before.config();
    let cfg64 = SeekerInsConfig {
        imu_dt_s: cfg.imu_dt_s.to_f64(),
        covariance_interval_steps: cfg.covariance_interval_steps,
        accel_noise_density_m_s2_rt_hz: cfg.accel_noise_density_m_s2_rt_hz.to_f64(),
        gyro_noise_density_rad_s_rt_hz: cfg.gyro_noise_density_rad_s_rt_hz.to_f64(),
        seeker_noise_rad: cfg.seeker_noise_rad.to_f64().max(1e-5),
        gate: Gate::Nis(c.gate_nis),
        recovery: c.recovery,
        imu_faults: c.policy,
        landmark: lm64,
        residual: LosResidual::Projected2d,
        instrument_errors: Default::default(),
    };
    let init64 = SeekerInsInitial {
        state: s64,
        covariance: pf,
    };
    let mut f64f = SeekerIns::new(&cfg64, &init64).unwrap();
    let m64 = LosSample {
        time: meas.time,
        gimbal: GimbalAngles {
            pitch_rad: meas.gimbal.pitch_rad.to_f64(),
            yaw_rad: meas.gimbal.yaw_rad.to_f64(),
        },
    };
    let r64 = f64f.update_los(&m64);
    (r64, *f64f.covariance())
}
