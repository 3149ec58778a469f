//! Design/run split (configuration-time design separable from the flight step): for the
//! transfer alignment (both models) and both vertical-channel loops, in f32 and f64,
//! `new(config)` and `from_design(config, &compute(config))` build bit-identical filters that
//! produce bit-identical outputs; the flat value list round-trips exactly; `from_design` and
//! `read_values` refuse corrupted designs with typed errors.
use nalgebra::Vector3;
use nav_core::design::DesignValues;
use nav_core::error::ConfigIssue;
use nav_core::time::Timestamp;
use nav_core::transfer_alignment::{
    MasterSample, PaperCase, SlaveSample, TaConfig, TaDesign, TaInitial, TransferAlignment,
    TA_DESIGN_VERSION,
};
use nav_core::vertical_channel::{
    Aid, AidedConfig, AidedDesign, AidedLoop, BaroSample, ClassicalConfig, ClassicalDesign,
    ClassicalLoop, ImuSample, InitialState, VelocitySample,
};
use nav_core::{Estimator, NavError, Real};

const STEPS: usize = 400;

/// Bit pattern of a float of either type (as f64, exact).
fn bits<T: Real>(v: T) -> u64 {
    v.to_f64().to_bits()
}

/// A small deterministic pseudo-random sequence in [−1, 1) (no dependency on the simulator).
struct Lcg(u64);
impl Lcg {
    fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        ((self.0 >> 11) as f64) / ((1u64 << 52) as f64) - 1.0
    }
}

// ---------------------------------------------------------------- transfer alignment

/// The paper's case 2 with distinct mount σ per axis (so a mixed-up axis shows) and the
/// golden vectors' rate noise.
fn ta_config<T: Real>() -> TaConfig<T> {
    let deg = |v: f64| T::lit(v.to_radians());
    TaConfig {
        mount_sigma_rad: Vector3::new(deg(0.5), deg(0.4), deg(0.3)),
        rate_noise_sigma_rad_s: T::lit(2.0e-4),
        ..TaConfig::paper(PaperCase::Case2)
    }
}

fn ta_design<T: Real, const K: usize, const N: usize>(cfg: &TaConfig<T>) -> TaDesign<T, K> {
    TransferAlignment::<T, K, N>::design(cfg).unwrap()
}

fn ta_samples<T: Real>(k: usize, rng: &mut Lcg) -> (MasterSample<T>, SlaveSample<T>) {
    let t = 0.01 * (k + 1) as f64;
    let w = Vector3::new(0.3 * (2.0 * t).sin(), 0.2 * (1.3 * t).cos(), 0.05);
    let wd = Vector3::new(0.6 * (2.0 * t).cos(), -0.26 * (1.3 * t).sin(), 0.0);
    let f = Vector3::new(1.5 * (0.7 * t).sin(), 0.8, -9.8);
    // Slave: a fixed 0.2° misalignment about z plus noise.
    let mis = Vector3::new(0.0, 0.0, 0.2_f64.to_radians());
    let ws = w - mis.cross(&w) + Vector3::new(rng.next(), rng.next(), rng.next()) * 2e-4;
    let fs = f - mis.cross(&f) + Vector3::new(rng.next(), rng.next(), rng.next()) * 5e-3;
    let v = |x: Vector3<f64>| x.map(T::lit);
    (
        MasterSample {
            time: nav_core::time::Timestamp::from_micros(10_000 * (k as u64 + 1)),
            angular_rate_rad_s: v(w),
            angular_accel_rad_s2: v(wd),
            specific_force_m_s2: v(f),
        },
        SlaveSample {
            time: nav_core::time::Timestamp::from_micros(10_000 * (k as u64 + 1)),
            angular_rate_rad_s: v(ws),
            specific_force_m_s2: v(fs),
        },
    )
}

fn ta_new_equals_from_design<T: Real, const K: usize, const N: usize>() {
    let cfg = ta_config::<T>();
    let init = TaInitial::default();
    let design = ta_design::<T, K, N>(&cfg);
    let mut a = TransferAlignment::<T, K, N>::new(&cfg, &init).unwrap();
    let mut b = TransferAlignment::<T, K, N>::from_design(&cfg, &design, &init).unwrap();
    assert_eq!(format!("{a:?}"), format!("{b:?}"));
    assert_eq!(a.chains(), &design.chains);
    // The design read back from its values builds the same filter too.
    let mut values = vec![0.0; TaDesign::<T, K>::COUNT];
    design.write_values(&mut values).unwrap();
    let read = TaDesign::<T, K>::read_values(&values).unwrap();
    let mut c = TransferAlignment::<T, K, N>::from_design(&cfg, &read, &init).unwrap();
    let mut rng = Lcg(7);
    let mut fused = 0;
    for k in 0..STEPS {
        let (m, s) = ta_samples::<T>(k, &mut rng);
        let ra = a.step(&m, &s).unwrap();
        let rb = b.step(&m, &s).unwrap();
        let rc = c.step(&m, &s).unwrap();
        assert_eq!(format!("{ra:?}"), format!("{rb:?}"), "step {k}");
        assert_eq!(format!("{ra:?}"), format!("{rc:?}"), "step {k}");
        for ((x, y), z) in a.state().iter().zip(b.state().iter()).zip(c.state().iter()) {
            assert_eq!(bits(*x), bits(*y));
            assert_eq!(bits(*x), bits(*z));
        }
        for ((x, y), z) in a
            .covariance()
            .iter()
            .zip(b.covariance().iter())
            .zip(c.covariance().iter())
        {
            assert_eq!(bits(*x), bits(*y));
            assert_eq!(bits(*x), bits(*z));
        }
        fused += ra
            .updates
            .iter()
            .filter(|u| u.outcome == nav_core::FusionOutcome::Fused)
            .count();
    }
    // The run did exercise the updates.
    assert!(fused > STEPS * 3, "fused {fused}");
    assert_eq!(format!("{a:?}"), format!("{b:?}"));
    assert_eq!(format!("{a:?}"), format!("{c:?}"));
}

#[test]
fn ta_new_and_from_design_are_bit_identical_f32_f64() {
    ta_new_equals_from_design::<f32, 3, 9>();
    ta_new_equals_from_design::<f32, 4, 12>();
    ta_new_equals_from_design::<f64, 3, 9>();
    ta_new_equals_from_design::<f64, 4, 12>();
}

fn ta_round_trip<T: Real, const K: usize, const N: usize>() {
    let design = ta_design::<T, K, N>(&ta_config::<T>());
    assert_eq!(TaDesign::<T, K>::COUNT, 2 + 15 * K * K);
    let mut values = vec![f64::NAN; TaDesign::<T, K>::COUNT];
    design.write_values(&mut values).unwrap();
    assert!(values.iter().all(|v| v.is_finite()));
    // Documented order: the stamp, then chain X's F, column by column; chain Z's P0 last.
    assert_eq!(values[0], f64::from(TA_DESIGN_VERSION));
    assert_eq!(values[1], f64::from(design.stamp.fingerprint));
    assert_eq!(values[2 + 1], design.chains[0].f[(1, 0)].to_f64());
    assert_eq!(values[2 + K], design.chains[0].f[(0, 1)].to_f64());
    assert_eq!(
        values[2 + 2 * K * K + K + 1],
        design.chains[0].phi[(1, 1)].to_f64()
    );
    assert_eq!(
        *values.last().unwrap(),
        design.chains[2].p0[(K - 1, K - 1)].to_f64()
    );
    let read = TaDesign::<T, K>::read_values(&values).unwrap();
    assert_eq!(read, design);
    let mut again = vec![0.0; TaDesign::<T, K>::COUNT];
    read.write_values(&mut again).unwrap();
    let b1: Vec<u64> = values.iter().map(|v| v.to_bits()).collect();
    let b2: Vec<u64> = again.iter().map(|v| v.to_bits()).collect();
    assert_eq!(b1, b2);
}

#[test]
fn ta_design_values_round_trip_exactly_f32_f64() {
    ta_round_trip::<f32, 3, 9>();
    ta_round_trip::<f32, 4, 12>();
    ta_round_trip::<f64, 3, 9>();
    ta_round_trip::<f64, 4, 12>();
}

fn invalid(field: &'static str, issue: ConfigIssue) -> NavError {
    NavError::InvalidConfig { field, issue }
}

fn ta_refusals<T: Real, const K: usize, const N: usize>() {
    let cfg = ta_config::<T>();
    let init = TaInitial::default();
    let good = ta_design::<T, K, N>(&cfg);
    let from = |c: &TaConfig<T>, d: &TaDesign<T, K>| {
        TransferAlignment::<T, K, N>::from_design(c, d, &init).err()
    };
    let build = |d: &TaDesign<T, K>| from(&cfg, d);
    assert_eq!(build(&good), None);

    let mut d = good;
    d.chains[1].phi[(2, 1)] = T::lit(f64::NAN);
    assert_eq!(build(&d), Some(invalid("flexure", ConfigIssue::OutOfRange)));
    let mut d = good;
    d.chains[2].p0[(1, 1)] = T::lit(f64::INFINITY);
    assert_eq!(build(&d), Some(invalid("flexure", ConfigIssue::OutOfRange)));
    // Asymmetric Q_d (one off-diagonal element moved by one ulp-sized amount).
    let mut d = good;
    let q = d.chains[0].q_d[(1, 2)];
    d.chains[0].q_d[(1, 2)] = q + q.abs() * T::lit(1e-3) + T::lit(1e-30);
    assert_eq!(
        build(&d),
        Some(invalid("design.q_d", ConfigIssue::OutOfRange))
    );
    // Negative variance on Q_d's and P0's diagonals.
    let mut d = good;
    d.chains[2].q_d[(K - 1, K - 1)] = T::lit(-1e-12);
    assert_eq!(
        build(&d),
        Some(invalid("design.q_d", ConfigIssue::OutOfRange))
    );
    let mut d = good;
    d.chains[1].p0[(1, 1)] = T::lit(-1e-6);
    assert_eq!(
        build(&d),
        Some(invalid("design.p0", ConfigIssue::OutOfRange))
    );
    // Asymmetric P0.
    let mut d = good;
    d.chains[1].p0[(2, 1)] += T::lit(1e-9);
    assert_eq!(
        build(&d),
        Some(invalid("design.p0", ConfigIssue::OutOfRange))
    );
    // θ_m must be a random constant: Φ's first row and column e₁.
    let mut d = good;
    d.chains[0].phi[(0, 1)] = T::lit(1e-6);
    assert_eq!(
        build(&d),
        Some(invalid("design.phi", ConfigIssue::OutOfRange))
    );
    let mut d = good;
    d.chains[0].phi[(0, 0)] = T::lit(0.999);
    assert_eq!(
        build(&d),
        Some(invalid("design.phi", ConfigIssue::OutOfRange))
    );
    // A θ_m variance that is not the configuration's mount σ².
    let mut d = good;
    d.chains[1].p0[(0, 0)] *= T::lit(4.0);
    assert_eq!(
        build(&d),
        Some(invalid("design.p0", ConfigIssue::OutOfRange))
    );
    // A design computed for another mount σ, flexure or step, or stored with another layout
    // version: the stamp does not match.
    let mismatch = Some(invalid("design", ConfigIssue::DesignMismatch));
    let mut other = cfg;
    other.mount_sigma_rad.y *= T::lit(2.0);
    assert_eq!(from(&other, &good), mismatch);
    let mut other = cfg;
    other.flexure[0].sigma_rad *= T::lit(1.5);
    assert_eq!(from(&other, &good), mismatch);
    let mut d = good;
    d.stamp.version += 1;
    assert_eq!(build(&d), mismatch);
    // Settings the design does not depend on may change.
    let mut other = cfg;
    other.accel_noise_sigma_m_s2 *= T::lit(2.0);
    other.max_gap_steps = 1;
    assert_eq!(from(&other, &good), None);
    // The configuration is still validated.
    let mut bad = cfg;
    bad.dt_s = T::zero();
    assert_eq!(
        from(&bad, &good),
        TransferAlignment::<T, K, N>::new(&bad, &init).err()
    );
    assert!(from(&bad, &good).is_some());
    assert_eq!(
        TransferAlignment::<T, K, N>::design(&bad).err(),
        TransferAlignment::<T, K, N>::new(&bad, &init).err()
    );

    // Value lists: wrong length, non-finite, f32 overflow; a short output buffer.
    let mut values = vec![0.0; TaDesign::<T, K>::COUNT];
    good.write_values(&mut values).unwrap();
    let bad_len = invalid("design values", ConfigIssue::OutOfRange);
    let not_finite = invalid("design values", ConfigIssue::NotFinite);
    let n = values.len();
    assert_eq!(
        TaDesign::<T, K>::read_values(&values[..n - 1]).err(),
        Some(bad_len)
    );
    let mut longer = values.clone();
    longer.push(0.0);
    assert_eq!(TaDesign::<T, K>::read_values(&longer).err(), Some(bad_len));
    assert_eq!(TaDesign::<T, K>::read_values(&[]).err(), Some(bad_len));
    for bad_value in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
        let mut v = values.clone();
        v[n / 2] = bad_value;
        assert_eq!(TaDesign::<T, K>::read_values(&v).err(), Some(not_finite));
    }
    let mut short = vec![7.0; n - 1];
    assert_eq!(
        good.write_values(&mut short).err(),
        Some(NavError::CapacityExceeded)
    );
    assert!(short.iter().all(|v| *v == 7.0), "output untouched on error");
    let mut long = vec![7.0; n + 1];
    assert_eq!(
        good.write_values(&mut long).err(),
        Some(NavError::CapacityExceeded)
    );
    // An asymmetric Q_d read from values is refused by from_design.
    let mut v = values.clone();
    // Chain X, Q_d (4th matrix), element (1, 2) column-major: index 2 + 3K² + 2K + 1.
    v[2 + 3 * K * K + 2 * K + 1] += 1e-3;
    let read = TaDesign::<T, K>::read_values(&v).unwrap();
    assert_eq!(
        build(&read),
        Some(invalid("design.q_d", ConfigIssue::OutOfRange))
    );
    // The stamp's values must be integers in range.
    for (i, bad_stamp) in [(0, 0.5), (0, 70_000.0), (1, -1.0), (1, 5.0e9)] {
        let mut v = values.clone();
        v[i] = bad_stamp;
        assert_eq!(TaDesign::<T, K>::read_values(&v).err(), Some(bad_len));
    }
}

#[test]
fn ta_from_design_refuses_corrupted_designs_f32_f64() {
    ta_refusals::<f32, 3, 9>();
    ta_refusals::<f32, 4, 12>();
    ta_refusals::<f64, 3, 9>();
    ta_refusals::<f64, 4, 12>();
    // f32 overflow of a finite f64 value.
    let mut values = vec![0.0; TaDesign::<f32, 4>::COUNT];
    ta_design::<f32, 4, 12>(&ta_config())
        .write_values(&mut values)
        .unwrap();
    values[3] = 1e300;
    assert_eq!(
        TaDesign::<f32, 4>::read_values(&values).err(),
        Some(invalid("design values", ConfigIssue::NotFinite))
    );
    assert!(TaDesign::<f64, 4>::read_values(&values).is_ok());
}

// ---------------------------------------------------------------- vertical channel

/// The papers' configurations (the golden cases').
fn classical_config<T: Real>() -> ClassicalConfig<T> {
    ClassicalConfig::paper()
}

fn aided_config<T: Real>() -> AidedConfig<T> {
    AidedConfig::paper()
}

fn initial<T: Real>() -> InitialState<T> {
    InitialState {
        time: Timestamp::ZERO,
        altitude_m: T::lit(520.0),
        vz_up_m_s: T::lit(2.0),
        accel_bias_m_s2: T::lit(0.01),
    }
}

/// IMU, baro (every 4th step, with a dropout) and velocity (every 10th step) samples.
#[allow(clippy::type_complexity)]
fn vc_samples<T: Real>(
    k: usize,
    rng: &mut Lcg,
) -> (
    ImuSample<T>,
    Option<BaroSample<T>>,
    Option<VelocitySample<T>>,
) {
    let t = 0.01 * (k + 1) as f64;
    let us = 10_000 * (k as u64 + 1);
    let imu = ImuSample {
        time: Timestamp::from_micros(us),
        specific_force_up_m_s2: T::lit(9.8 + 0.3 * (0.5 * t).sin() + 0.01 * rng.next()),
    };
    let h = 500.0 + 10.0 * (1.0 - (0.5 * t).cos());
    let baro = (k % 4 == 0 && !(150..250).contains(&k)).then(|| BaroSample {
        time: Timestamp::from_micros(us - 5_000),
        altitude_m: T::lit(h + rng.next()),
    });
    let vel = (k % 10 == 0).then(|| VelocitySample {
        time: Timestamp::from_micros(us - 2_000),
        vz_up_m_s: T::lit(5.0 * (0.5 * t).sin() + 0.1 * rng.next()),
    });
    (imu, baro, vel)
}

fn classical_new_equals_from_design<T: Real>() {
    let cfg = classical_config::<T>();
    let design = ClassicalDesign::<T>::compute(&cfg).unwrap();
    let mut values = vec![0.0; ClassicalDesign::<T>::COUNT];
    design.write_values(&mut values).unwrap();
    let read = ClassicalDesign::<T>::read_values(&values).unwrap();
    assert_eq!(read, design);
    let mut a = ClassicalLoop::<T>::new(&cfg, &initial()).unwrap();
    let mut b = ClassicalLoop::<T>::from_design(&cfg, &design, &initial()).unwrap();
    let mut c = ClassicalLoop::<T>::from_design(&cfg, &read, &initial()).unwrap();
    assert_eq!(a, b);
    assert_eq!(a, c);
    assert_eq!(format!("{a:?}"), format!("{b:?}"));
    assert_eq!(a.gains(), design.gains());
    assert_eq!(a.phi_with_baro(), design.phi_with_baro());
    let mut rng = Lcg(3);
    for k in 0..STEPS {
        let (imu, baro, _) = vc_samples::<T>(k, &mut rng);
        let ra = a.step(&imu, baro.as_ref()).unwrap();
        let rb = b.step(&imu, baro.as_ref()).unwrap();
        let rc = c.step(&imu, baro.as_ref()).unwrap();
        assert_eq!(format!("{ra:?}"), format!("{rb:?}"), "step {k}");
        assert_eq!(format!("{ra:?}"), format!("{rc:?}"), "step {k}");
        for (x, y) in [
            (a.altitude_m(), b.altitude_m()),
            (a.vz_up_m_s(), b.vz_up_m_s()),
            (a.accel_bias_m_s2(), b.accel_bias_m_s2()),
        ] {
            assert_eq!(bits(x), bits(y));
        }
    }
    assert_eq!(a, b);
    assert_eq!(a, c);
    let c = a.aid_counters(Aid::Baro);
    assert!(c.fused > 50, "{c:?}");
}

fn aided_new_equals_from_design<T: Real>() {
    let cfg = aided_config::<T>();
    let design = AidedDesign::<T>::compute(&cfg).unwrap();
    let mut values = vec![0.0; AidedDesign::<T>::COUNT];
    design.write_values(&mut values).unwrap();
    let read = AidedDesign::<T>::read_values(&values).unwrap();
    assert_eq!(read, design);
    let mut a = AidedLoop::<T>::new(&cfg, &initial()).unwrap();
    let mut b = AidedLoop::<T>::from_design(&cfg, &design, &initial()).unwrap();
    let mut c = AidedLoop::<T>::from_design(&cfg, &read, &initial()).unwrap();
    assert_eq!(a, b);
    assert_eq!(a, c);
    assert_eq!(a.gains(), design.gains());
    let variances = design.innovation_variances();
    let sigmas = a.design_innovation_sigmas();
    assert_eq!(bits(sigmas.baro), bits(variances.baro.sqrt()));
    assert_eq!(bits(sigmas.velocity), bits(variances.velocity.sqrt()));
    let mut rng = Lcg(5);
    let mut used = [0usize; 2];
    for k in 0..STEPS {
        let (imu, baro, vel) = vc_samples::<T>(k, &mut rng);
        let ra = a.step(&imu, baro.as_ref(), vel.as_ref()).unwrap();
        let rb = b.step(&imu, baro.as_ref(), vel.as_ref()).unwrap();
        let rc = c.step(&imu, baro.as_ref(), vel.as_ref()).unwrap();
        assert_eq!(format!("{ra:?}"), format!("{rb:?}"), "step {k}");
        assert_eq!(format!("{ra:?}"), format!("{rc:?}"), "step {k}");
        used[0] += usize::from(ra.baro.correction.is_some());
        used[1] += usize::from(ra.velocity.correction.is_some());
        for (x, y) in [
            (a.altitude_m(), b.altitude_m()),
            (a.vz_up_m_s(), b.vz_up_m_s()),
            (a.accel_bias_m_s2(), b.accel_bias_m_s2()),
        ] {
            assert_eq!(bits(x), bits(y));
        }
    }
    // Both aids were used, and the baro went Lost in the dropout (all four modes ran).
    assert!(used[0] > 100 && used[1] > 100, "{used:?}");
    assert!(used[0] < STEPS, "{used:?}");
    assert_eq!(a, b);
    assert_eq!(a, c);
}

#[test]
fn vc_new_and_from_design_are_bit_identical_f32_f64() {
    classical_new_equals_from_design::<f32>();
    classical_new_equals_from_design::<f64>();
    aided_new_equals_from_design::<f32>();
    aided_new_equals_from_design::<f64>();
}

fn vc_values_and_refusals<T: Real>() {
    assert_eq!(ClassicalDesign::<T>::COUNT, 235);
    assert_eq!(AidedDesign::<T>::COUNT, 275);
    let mismatch = invalid("design", ConfigIssue::DesignMismatch);
    let bad_len = invalid("design values", ConfigIssue::OutOfRange);
    let not_finite = invalid("design values", ConfigIssue::NotFinite);

    // Classical: documented order (stamp, gains, gravity, dt, dt/2, lag, modes).
    let cc = classical_config::<T>();
    let cd = ClassicalDesign::<T>::compute(&cc).unwrap();
    let mut v = vec![0.0; 235];
    cd.write_values(&mut v).unwrap();
    assert_eq!(v[0], f64::from(cd.stamp().version));
    assert_eq!(v[1], f64::from(cd.stamp().fingerprint));
    assert_eq!(cd.stamp(), nav_core::vertical_channel::classical_stamp(&cc));
    assert_eq!(v[2], cd.gains().c1_per_s);
    assert_eq!(v[5], cc.baro_lag_s.to_f64());
    assert_eq!(v[7], cd.gravity().g0_m_s2.to_f64());
    assert_eq!(v[10], cc.imu_dt_s.to_f64());
    assert_eq!(v[13], cd.phi_with_baro()[(0, 0)].to_f64());
    // The σ design after the modes: the covariance interval (0.1 s in µs) first, P∞ after the
    // four modes' Φ and Q and the design-mode flag.
    assert_eq!(v[70], 100_000.0);
    assert_eq!(v[70 + 1 + 128], 0.0);
    assert_eq!(v[70 + 2 + 128], cd.steady_covariance()[(0, 0)].to_f64());
    let mut w = v.clone();
    w[220] = f64::NAN;
    assert_eq!(
        ClassicalDesign::<T>::read_values(&w).err(),
        Some(not_finite)
    );
    let mut again = vec![0.0; 235];
    ClassicalDesign::<T>::read_values(&v)
        .unwrap()
        .write_values(&mut again)
        .unwrap();
    assert_eq!(
        v.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
        again.iter().map(|x| x.to_bits()).collect::<Vec<_>>()
    );
    assert_eq!(
        ClassicalDesign::<T>::read_values(&v[..234]).err(),
        Some(bad_len)
    );
    let mut w = v.clone();
    w[42] = f64::NAN;
    assert_eq!(
        ClassicalDesign::<T>::read_values(&w).err(),
        Some(not_finite)
    );
    assert_eq!(
        cd.write_values(&mut [0.0; 236]).err(),
        Some(NavError::CapacityExceeded)
    );
    // A design for another IMU interval or baro lag is refused (its stamp).
    let mut other = cc;
    other.imu_dt_s = T::lit(0.02);
    assert_eq!(
        ClassicalLoop::<T>::from_design(&other, &cd, &initial()).err(),
        Some(mismatch)
    );
    let mut other = cc;
    other.baro_lag_s = T::lit(0.1);
    assert_eq!(
        ClassicalLoop::<T>::from_design(&other, &cd, &initial()).err(),
        Some(mismatch)
    );
    // A stored design with a wrong step value (read from values) is refused too.
    let mut w = v.clone();
    w[10] *= 2.0;
    let wrong = ClassicalDesign::<T>::read_values(&w).unwrap();
    assert!(ClassicalLoop::<T>::from_design(&cc, &wrong, &initial()).is_err());
    // Configuration and initial state still validated, with the errors of `new`.
    let mut bad = cc;
    bad.baro_timeouts.lost_after_s = T::lit(0.01);
    assert_eq!(
        ClassicalLoop::<T>::from_design(&bad, &cd, &initial()).err(),
        ClassicalLoop::<T>::new(&bad, &initial()).err()
    );
    assert!(ClassicalLoop::<T>::new(&bad, &initial()).is_err());
    let mut init = initial::<T>();
    init.altitude_m = T::lit(f64::NAN);
    assert_eq!(
        ClassicalLoop::<T>::from_design(&cc, &cd, &init).err(),
        ClassicalLoop::<T>::new(&cc, &init).err()
    );
    assert!(ClassicalLoop::<T>::new(&cc, &init).is_err());

    // Aided.
    let ac = aided_config::<T>();
    let ad = AidedDesign::<T>::compute(&ac).unwrap();
    let mut v = vec![0.0; 275];
    ad.write_values(&mut v).unwrap();
    assert_eq!(
        v[1],
        f64::from(nav_core::vertical_channel::aided_stamp(&ac).fingerprint)
    );
    assert_eq!(v[2], ad.gains().k[(0, 0)]);
    assert_eq!(v[43], f64::from(ad.gains().riccati_iterations));
    assert_eq!(v[45], ad.gravity().g0_m_s2.to_f64());
    assert_eq!(v[51], ad.innovation_variances().baro.to_f64());
    assert_eq!(v[53], ad.phi_with_baro()[(0, 0)].to_f64());
    assert_eq!(v[110], 100_000.0);
    assert_eq!(v[110 + 1 + 128], 1.0);
    assert_eq!(v[110 + 2 + 128], ad.steady_covariance()[(0, 0)].to_f64());
    let mut again = vec![0.0; 275];
    AidedDesign::<T>::read_values(&v)
        .unwrap()
        .write_values(&mut again)
        .unwrap();
    assert_eq!(
        v.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
        again.iter().map(|x| x.to_bits()).collect::<Vec<_>>()
    );
    let mut longer = v.clone();
    longer.push(1.0);
    assert_eq!(AidedDesign::<T>::read_values(&longer).err(), Some(bad_len));
    let mut w = v.clone();
    w[102] = f64::INFINITY;
    assert_eq!(AidedDesign::<T>::read_values(&w).err(), Some(not_finite));
    // The iteration count must be a non-negative integer.
    for it in [2.5, -1.0, 1e10] {
        let mut w = v.clone();
        w[43] = it;
        assert_eq!(
            AidedDesign::<T>::read_values(&w).err(),
            Some(bad_len),
            "{it}"
        );
    }
    // Non-positive design innovation variance.
    let mut w = v.clone();
    w[52] = 0.0;
    let zero_var = AidedDesign::<T>::read_values(&w).unwrap();
    assert_eq!(
        AidedLoop::<T>::from_design(&ac, &zero_var, &initial()).err(),
        Some(invalid(
            "design.innovation_variances",
            ConfigIssue::NotPositive
        ))
    );
    let mut other = ac;
    other.imu_dt_s = T::lit(0.005);
    assert_eq!(
        AidedLoop::<T>::from_design(&other, &ad, &initial()).err(),
        Some(mismatch)
    );
    // A stamp that is not an exact integer, or of another layout version, is refused.
    let mut w = v.clone();
    w[0] = 1.0;
    let old = AidedDesign::<T>::read_values(&w).unwrap();
    assert_eq!(
        AidedLoop::<T>::from_design(&ac, &old, &initial()).err(),
        Some(mismatch)
    );
    w[1] += 0.5;
    assert_eq!(AidedDesign::<T>::read_values(&w).err(), Some(bad_len));
    let mut bad = ac;
    bad.velocity_timeouts.stale_after_s = T::lit(-1.0);
    assert_eq!(
        AidedLoop::<T>::from_design(&bad, &ad, &initial()).err(),
        AidedLoop::<T>::new(&bad, &initial()).err()
    );
    assert!(AidedLoop::<T>::new(&bad, &initial()).is_err());
    // compute refuses what new refuses, with the same error.
    let mut bad = ac;
    bad.baro_noise_m = T::zero();
    assert_eq!(
        AidedDesign::<T>::compute(&bad).err(),
        AidedLoop::<T>::new(&bad, &initial()).err()
    );
    assert!(AidedDesign::<T>::compute(&bad).is_err());
}

#[test]
fn vc_design_values_round_trip_and_refusals_f32_f64() {
    vc_values_and_refusals::<f32>();
    vc_values_and_refusals::<f64>();
}
