//! Shared body of the size images: a flight program's use of nav-core — every filter's
//! constructor, configuration calls and every run-time entry point, on opaque inputs so that
//! nothing is optimised away or specialised on constants — without the bench harness, the
//! golden replay and the recorded vectors. The design source decides whether the design code
//! (discretisation, Riccati solver, f64 gravity fit) is in the image. Logger, exit and the
//! fault and panic handlers are the harness's (`nav_firmware::harness`), as in every image.
//!
//! Included by path in both size binaries rather than put in the library: as a library module
//! the same code linked 1 448 B smaller in `nav-size` (LTO inlines differently across the crate
//! boundary); kept here so the reported flash figure stays comparable with earlier ones.

use core::hint::black_box as bb;
use nalgebra::Vector3;
use nav_core::seeker_ins::{ClipFlags, GimbalAngles, ImuIncrement, LosSample, SeekerIns};
use nav_core::transfer_alignment::{Channel, MasterSample, SlaveHistory, SlaveSample};
use nav_core::vertical_channel::{BaroSample, ImuSample, VelocitySample};
use nav_core::{Estimator, HealthState, NavError};
use nav_firmware::harness;
use nav_golden::DesignSource;

pub fn run(designs: &dyn DesignSource) -> ! {
    let result = flight_loop(designs);
    defmt::println!("SIZE image ran: ok={=bool}", result.is_ok());
    harness::exit(result.is_ok())
}

/// What a flight program does with nav-core: build every filter (designs from `designs`,
/// configurations opaque to the optimiser), set its gates and recovery policies, then at each
/// cycle call every run-time entry point: both transfer-alignment filters (`step`, the delayed
/// match from the slave history, `propagate` through master dropouts, `reinitialise`, the
/// channel counters), both vertical loops
/// (gated `step`, `reinitialise`), and the seeker INS (`propagate` and its clipped form, gaps bridged inside,
/// `predict_covariance`, `update_los`). Inputs are opaque values; the cycle count is opaque (0
/// here: the image is only linked and measured).
fn flight_loop(designs: &dyn DesignSource) -> Result<(), NavError> {
    let mut ta9 = designs.ta9()?;
    let mut ta12 = designs.ta12()?;
    let mut cl = designs.vc_classical()?;
    let mut ai = designs.vc_aided()?;
    let sk_initial = bb(nav_golden::seeker_start_state());
    let mut sk = SeekerIns::new(&bb(nav_golden::seeker_config()?), &sk_initial)?;
    let gate = bb(nav_golden::vc_gate());
    cl.set_gate(gate)?;
    ai.set_gate(gate)?;
    cl.set_aid_model(bb(nav_golden::vc_classical_config().aid_model))?;
    ai.set_aid_model(bb(nav_golden::vc_aided_config().aid_model))?;
    cl.set_recovery(bb(nav_golden::vc_classical_config().recovery))?;
    ai.set_recovery(bb(nav_golden::vc_aided_config().recovery))?;
    ta9.set_gate(bb(ta9.config().gate))?;
    ta12.set_gate(bb(ta12.config().gate))?;
    ta9.set_recovery(bb(ta9.config().recovery))?;
    ta12.set_recovery(bb(ta12.config().recovery))?;
    sk.set_gate(bb(sk.config().gate))?;
    sk.set_recovery(bb(sk.config().recovery))?;
    sk.set_imu_faults(bb(sk.config().imu_faults))?;
    let mut history = SlaveHistory::<f32, 8>::new();
    let v = |x: f32| bb(Vector3::new(x, x, x));
    // A flight loop does not stop on a refused sample: it counts the error (the filter is
    // unchanged) and goes on.
    let mut refused = 0u32;
    let mut count = |r: Result<(), NavError>| refused += u32::from(r.is_err());
    for _ in 0..bb(0u32) {
        let master = MasterSample {
            time: bb(nav_core::time::Timestamp::ZERO),
            angular_rate_rad_s: v(0.0),
            angular_accel_rad_s2: v(0.0),
            specific_force_m_s2: v(0.0),
        };
        let slave = SlaveSample {
            time: bb(nav_core::time::Timestamp::ZERO),
            angular_rate_rad_s: v(0.0),
            specific_force_m_s2: v(0.0),
        };
        count(history.push(&slave));
        if bb(true) {
            count(ta9.step(&master, &slave).map(|r| {
                bb(r);
            }));
            count(ta12.step_delayed(&master, &history).map(|r| {
                bb(r);
            }));
        } else {
            count(ta9.propagate(bb(nav_core::time::Timestamp::ZERO)).map(|r| {
                bb(r);
            }));
            count(
                ta12.propagate(bb(nav_core::time::Timestamp::ZERO))
                    .map(|r| {
                        bb(r);
                    }),
            );
        }
        if bb(ta9.health().state) == HealthState::NeedsReinitialisation {
            count(ta9.reinitialise(&bb(nav_golden::ta_initial())));
        }
        if bb(ta12.health().state) == HealthState::NeedsReinitialisation {
            count(ta12.reinitialise(&bb(nav_golden::ta_initial())));
        }
        let imu = bb(ImuSample {
            time: bb(nav_core::time::Timestamp::ZERO),
            specific_force_up_m_s2: 9.8,
        });
        let baro = bb(BaroSample {
            time: bb(nav_core::time::Timestamp::ZERO),
            altitude_m: 0.0,
        });
        let vel = bb(VelocitySample {
            time: bb(nav_core::time::Timestamp::ZERO),
            vz_up_m_s: 0.0,
        });
        count(cl.step(&imu, bb(Some(&baro))).map(|r| {
            bb(r);
        }));
        count(ai.step(&imu, bb(Some(&baro)), bb(Some(&vel))).map(|r| {
            bb(r);
        }));
        if bb(false) {
            count(cl.reinitialise(&bb(nav_golden::vc_initial())));
            count(ai.reinitialise(&bb(nav_golden::vc_initial())));
        }
        let inc = ImuIncrement {
            time: bb(nav_core::time::Timestamp::ZERO),
            delta_theta_rad: v(0.0),
            delta_v_m_s: v(0.0),
        };
        count(match bb(0u8) {
            0 => sk.propagate(&inc),
            _ => sk.propagate_clipped(&inc, bb(ClipFlags::default())),
        });
        if bb(sk.health().state) == HealthState::NeedsReinitialisation {
            count(sk.reinitialise(&sk_initial));
        }
        if bb(true) {
            count(sk.predict_covariance());
            count(
                sk.update_los(&bb(LosSample {
                    time: inc.time,
                    gimbal: GimbalAngles {
                        pitch_rad: 0.0,
                        yaw_rad: 0.0,
                    },
                }))
                .map(|r| {
                    bb(r);
                }),
            );
        }
        bb((
            ta9.theta(),
            ta12.theta_sigma_rad(),
            ta12.aid_counters(bb(Channel::ForceX)),
            cl.altitude_m(),
            ai.vz_up_m_s(),
            sk.state().vel_ned_m_s,
            sk.health(),
            sk.aid_counters(nav_core::seeker_ins::SeekerAid::Los),
        ));
    }
    bb(refused);
    Ok(())
}
