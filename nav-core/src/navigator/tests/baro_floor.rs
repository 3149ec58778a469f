//! The baro update's measurement floor: what the first-order lag compensation and the
//! rounding of the innovation's altitudes leave below the configured σ.

use super::*;

/// The baro update's white variance: the configured σ_w² when it is above what the model
/// resolves; below it, the lag compensation's neglected term `τ² ā` (ā: at the first sample
/// the INS's vertical acceleration, then `|ΔV̂_D/Δt|` through the baro's lag) and the rounding
/// `ε z` of the innovation's altitudes.
#[test]
fn baro_measurement_variance_has_the_models_floor() {
    use crate::navigator::baro::loop_vertical_input_m_s2;
    // No IMU sample yet: zero specific force, the INS in free fall.
    let ekf = flight_ekf();
    let s = ekf.state();
    let g = crate::earth::normal_gravity_m_s2(s.position.lat_rad, s.position.alt_m);
    let a0 = (loop_vertical_input_m_s2(s, &Vector3::zeros()) - g).abs();
    assert!((a0 - g).abs() < 0.05 * g, "free fall: {a0} vs g {g}");
    let model = BaroErrorModel {
        white_sigma_m: 1e-6,
        markov_sigma_m: 0.01,
        markov_tau_s: 100.0,
        lag_s: 0.2,
    };
    let (tau, z) = (0.25, 1000.0);
    let sample = |us: u64| BaroSample {
        time: Timestamp::from_micros(us),
        altitude_m: z,
    };
    let mut st = BaroState::start(&model);
    let rounding2 = (f64::EPSILON * z).powi(2);
    let r0 = st.measurement_variance_m2(&model, &ekf, tau, &sample(1_000_000), None);
    let want0 = (tau * tau * a0).powi(2) + rounding2;
    assert!((r0 / want0 - 1.0).abs() < 1e-12, "{r0} vs {want0}");
    // 40 ms later with the same V̂_D: no acceleration, the envelope decays through the lag
    // (implicit Euler over Δt: × τ_b / (τ_b + Δt)).
    let t0 = Some(Timestamp::from_micros(1_000_000));
    let r1 = st.measurement_variance_m2(&model, &ekf, tau, &sample(1_040_000), t0);
    let a1 = a0 * 0.2 / (0.2 + 0.04);
    let want1 = (tau * tau * a1).powi(2) + rounding2;
    assert!((r1 / want1 - 1.0).abs() < 1e-12, "{r1} vs {want1}");
    // A baro described above the floor keeps its σ exactly.
    let loose = BaroErrorModel {
        white_sigma_m: 1.0,
        ..model
    };
    let t1 = Some(Timestamp::from_micros(1_040_000));
    assert_eq!(
        st.measurement_variance_m2(&loose, &ekf, tau, &sample(1_080_000), t1),
        1.0
    );
    // Without lag and age only the rounding is left: in f32, (ε₃₂ z)², 1.4e-8 m² at 1 km.
    let model32 = BaroErrorModel {
        white_sigma_m: 1e-6_f32,
        markov_sigma_m: 0.01,
        markov_tau_s: 100.0,
        lag_s: 0.0,
    };
    let ekf32 = flight_ekf_f32();
    let mut st32 = BaroState::start(&model32);
    let s32 = BaroSample {
        time: Timestamp::from_micros(1_000_000),
        altitude_m: 1000.0_f32,
    };
    let r32 = st32.measurement_variance_m2(&model32, &ekf32, 0.0, &s32, None);
    assert_eq!(r32, (f32::EPSILON * 1000.0).powi(2));
}

/// [`flight_ekf`]'s state in f32 (its initial covariance without the correlation).
fn flight_ekf_f32() -> SeekerIns<f32> {
    let cfg = config::<f32>(BaroDamping::Ekf(baro_model()));
    let s = *flight_ekf().state();
    let init = SeekerInsInitial {
        state: InsState {
            position: s.position,
            vel_ned_m_s: s.vel_ned_m_s.cast(),
            q_b_n: nalgebra::Quaternion::from(s.q_b_n.coords.cast::<f32>()),
        },
        covariance: crate::seeker_ins::paper_initial_covariance::<f32>(),
    };
    <SeekerIns<f32> as crate::contract::Estimator>::new(&cfg.ins, &init).unwrap()
}
