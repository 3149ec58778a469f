//! One run of the baro-fault scenario (truth and run): the true altitude profile and specific
//! force, the baro (`sensors`) with its faults into the six loops (gated,
//! ungated, fault-free twins) stepped on the same IMU samples.

use super::*;

/// Simulates one run: the faulty stream into the four variants, the clean one into the twins.
pub fn simulate<T: Real>(cfg: &Config, fc: &FaultConfig, rng: &mut SimRng) -> Result<FaultRun> {
    let profile = Profile::new(&cfg.profile)?;
    let dt = 1.0 / cfg.imu_rate_hz;
    let steps = (cfg.duration_s / dt).round() as usize;
    let baro_every = (cfg.imu_rate_hz / cfg.baro.rate_hz).round() as usize;
    let vel_every = (cfg.imu_rate_hz / cfg.velocity_aid.rate_hz).round() as usize;
    let out_every = ((cfg.output_interval_s / dt).round() as usize).max(1);
    ensure!(
        baro_every >= 1 && vel_every >= 1,
        "aid rates above the IMU rate"
    );
    let lat = cfg.latitude_deg.to_radians();
    let (h0, v0, _) = profile.at(0.0);
    let mut variants = Variants::<T>::new(cfg, fc, h0, v0)?;

    // Sensor error states (as in the base scenario).
    let bias = normal(rng, cfg.imu.bias_sigma_mg * 9.806_65e-3);
    let sigma_f = cfg.imu.noise_m_s2_rt_hz / dt.sqrt();
    let mut baro = Baro::new(cfg, baro_every as f64 * dt, h0, v0, rng);

    let mut out = FaultRun {
        consistency: (0..6).map(|_| RunConsistency::new(&AXES)).collect(),
        ..FaultRun::default()
    };
    let (mut h_prev, mut v_prev, _) = profile.at(0.0);
    for k in 1..=steps {
        let t = k as f64 * dt;
        let stamp = Timestamp::from_secs_f64(t).map_err(|e| anyhow!("time stamp {t}: {e}"))?;
        let (h, v, _) = profile.at(t);
        let (h_mid, _, _) = profile.at(t - 0.5 * dt);
        let f = (v - v_prev) / dt + gravity_down_m_s2(lat, h_mid) + bias + normal(rng, sigma_f);
        baro.lag(h, h_prev, dt);
        // (clean reading, faulty reading or None)
        let (clean, faulty) = if k % baro_every == 0 {
            baro.read(cfg, fc, t, rng)
        } else {
            (None, None)
        };
        let vel = (k % vel_every == 0).then(|| VelocitySample {
            time: stamp,
            vz_up_m_s: T::lit(v + normal(rng, cfg.velocity_aid.noise_m_s)),
        });
        let imu = ImuSample {
            time: stamp,
            specific_force_up_m_s2: T::lit(f),
        };
        let sample = |z: Option<f64>| {
            z.map(|z| BaroSample {
                time: stamp,
                altitude_m: T::lit(z),
            })
        };
        let (bf, bc) = (sample(faulty), sample(clean));
        let (est, lost) =
            variants.step(&imu, (bf.as_ref(), bc.as_ref()), vel.as_ref(), t, &mut out)?;
        for ((a, n), (e, l)) in out
            .abs_err
            .iter_mut()
            .zip(out.lost_steps.iter_mut())
            .zip(est.iter().zip(&lost))
        {
            a.push((e - h).abs());
            *n += usize::from(*l);
        }
        if k % out_every == 0 {
            out.t.push(t);
            out.h_true.push(h);
            out.h_baro.push(faulty.unwrap_or(f64::NAN));
            for (series, e) in out.err_h.iter_mut().zip(&est) {
                series.push(e - h);
            }
            for (j, rc) in out.consistency.iter_mut().enumerate() {
                push_consistency(rc, t, est[j] - h, variants.est_v[j] - v, &variants.cov[j]);
            }
        }
        h_prev = h;
        v_prev = v;
    }
    Ok(out)
}

/// The six loops of a run and their latest velocity and covariance. Variant order:
/// classical gated, classical ungated, aided gated, aided ungated, classical twin, aided twin.
struct Variants<T: Real> {
    /// Index 0 gated, 1 ungated, 2 the gated fault-free twin.
    classical: [ClassicalLoop<T>; 3],
    aided: [AidedLoop<T>; 3],
    est_v: [f64; 6],
    cov: [Matrix2<f64>; 6],
}

impl<T: Real> Variants<T> {
    /// The loops started converged at the truth (`h0` m, `v0` m/s) plus the fault
    /// configuration's initial error; the gated ones with its gate.
    fn new(cfg: &Config, fc: &FaultConfig, h0: f64, v0: f64) -> Result<Self> {
        // The loops start converged: their error model's initial σ says so (the baro's
        // correlated error is in the model; the σ grows to its steady state with it).
        let mut start_cfg = cfg.clone();
        start_cfg.initial_error.altitude_m = fc.initial_error_m;
        start_cfg.initial_error.vz_m_s = fc.initial_error_m_s;
        let (ccfg, acfg) = loop_configs::<T>(&start_cfg, cfg.classical.tau_s);
        let init = InitialState {
            time: Timestamp::ZERO,
            altitude_m: T::lit(h0 + fc.initial_error_m),
            vz_up_m_s: T::lit(v0 + fc.initial_error_m_s),
            accel_bias_m_s2: T::zero(),
        };
        let g = &fc.gate;
        let e = |e: nav_core::NavError| anyhow!("{e}");
        let mut classical = [
            ClassicalLoop::<T>::new(&ccfg, &init).map_err(e)?,
            ClassicalLoop::<T>::new(&ccfg, &init).map_err(e)?,
            ClassicalLoop::<T>::new(&ccfg, &init).map_err(e)?,
        ];
        let mut aided = [
            AidedLoop::<T>::new(&acfg, &init).map_err(e)?,
            AidedLoop::<T>::new(&acfg, &init).map_err(e)?,
            AidedLoop::<T>::new(&acfg, &init).map_err(e)?,
        ];
        // [0] gated, [1] ungated, [2] gated fault-free twin.
        for i in [0, 2] {
            classical[i].set_aid_model(g.aid_model()).map_err(e)?;
            classical[i].set_recovery(g.recovery()).map_err(e)?;
            classical[i].set_gate(g.gate()).map_err(e)?;
            aided[i].set_aid_model(g.aid_model()).map_err(e)?;
            aided[i].set_recovery(g.recovery()).map_err(e)?;
            aided[i].set_gate(g.gate()).map_err(e)?;
        }
        Ok(Self {
            classical,
            aided,
            est_v: [0.0; 6],
            cov: [Matrix2::<f64>::zeros(); 6],
        })
    }

    /// One step of every loop: the faulty baro `b.0` to the variants, the clean `b.1` to the
    /// twins; the counters into `out`. Returns each loop's altitude (m) and whether its baro
    /// is `Lost`.
    fn step(
        &mut self,
        imu: &ImuSample<T>,
        (bf, bc): (Option<&BaroSample<T>>, Option<&BaroSample<T>>),
        vel: Option<&VelocitySample<T>>,
        t: f64,
        out: &mut FaultRun,
    ) -> Result<([f64; 6], [bool; 6])> {
        let mut est = [0.0; 6];
        let mut lost = [false; 6];
        let Self {
            classical,
            aided,
            est_v,
            cov,
        } = self;
        // One loop's outputs into its slot: the two loop types share these accessors (not a
        // trait), so one macro records both.
        macro_rules! record {
            ($lp:expr, $r:expr, $slot:expr) => {{
                let slot = $slot;
                est[slot] = $lp.altitude_m().to_f64();
                est_v[slot] = $lp.vz_up_m_s().to_f64();
                cov[slot] = $lp.covariance_h_vz().map(|x| x.to_f64());
                lost[slot] = matches!($r.baro.status, AidStatus::Lost { .. });
                out.counters[slot] = BaroCounts {
                    counters: $lp.aid_counters(Aid::Baro),
                    reacquisition: $lp.reacquisition_counters(Aid::Baro),
                };
            }};
        }
        for (i, lp) in classical.iter_mut().enumerate() {
            let b = if i == 2 { bc } else { bf };
            let r = lp
                .step(imu, b)
                .map_err(|e| anyhow!("classical {i} at t = {t}: {e}"))?;
            record!(lp, r, [0, 1, 4][i]);
        }
        for (i, lp) in aided.iter_mut().enumerate() {
            let b = if i == 2 { bc } else { bf };
            let r = lp
                .step(imu, b, vel)
                .map_err(|e| anyhow!("aided {i} at t = {t}: {e}"))?;
            record!(lp, r, [2, 3, 5][i]);
        }
        Ok((est, lost))
    }
}
