//! The hostile inputs (NaN, ∞, out of range, time going back) and their check.

use super::Nav;
use nalgebra::Vector3;
use nav_core::navigator::{AidState, Aids, ImuTick, MasterNav};
use nav_core::seeker_ins::{GimbalAngles, LosSample};
use nav_core::time::Timestamp;
use nav_core::vertical_channel::BaroSample;

/// The hostile inputs, in turn.
pub(super) const HOSTILE: [&str; 9] = [
    "imu dθ NaN",
    "imu dv +∞",
    "imu time going back",
    "master velocity NaN",
    "master position latitude 4 rad",
    "baro NaN",
    "baro −∞",
    "seeker gimbal NaN",
    "seeker gimbal ∞",
];

fn fingerprint(nav: &Nav) -> String {
    format!(
        "{:?}|{:?}|{:?}|{:?}|{:?}",
        nav.phase(),
        nav.solution(),
        nav.ekf().map(|e| e.covariance()),
        nav.alignment().state(),
        nav.alignment().covariance()
    )
}

/// One hostile call on `nav`; `Some(what went wrong)` when it was not refused cleanly.
pub(super) fn hostile_call(
    nav: &mut Nav,
    which: usize,
    imu: &ImuTick<f32>,
    genuine: GenuineAids<'_>,
    last_imu_time: Timestamp,
) -> Option<String> {
    if which < 3 {
        return imu_hostile(nav, which, imu, last_imu_time);
    }
    aid_hostile(nav, which, imu, genuine)
}

/// The genuine aids of the tick (their separation signal is not used).
pub(super) type GenuineAids<'a> = Aids<'a, f32>;

/// Owned aid samples (a hostile one among them).
struct OwnedAids {
    master: Option<MasterNav<f32>>,
    baro: Option<BaroSample<f32>>,
    seeker: Option<LosSample<f32>>,
}

/// A bad IMU sample: must be refused with the navigator unchanged.
fn imu_hostile(
    nav: &mut Nav,
    which: usize,
    imu: &ImuTick<f32>,
    last_imu_time: Timestamp,
) -> Option<String> {
    let before = fingerprint(nav);
    {
        let mut bad = *imu;
        match which {
            0 => bad.increment.delta_theta_rad.y = f32::NAN,
            1 => bad.increment.delta_v_m_s.z = f32::INFINITY,
            _ => {
                bad.increment.time =
                    Timestamp::from_micros(last_imu_time.as_micros().saturating_sub(1_000))
            }
        }
        let r = nav.tick(&bad, &Aids::NONE);
        if r.is_ok() {
            return Some("accepted".into());
        }
        (fingerprint(nav) != before).then(|| "refused but the navigator changed".into())
    }
}

/// A bad aid sample: must be refused (or not used in the phase) and leave the navigator as
/// the same tick without it.
fn aid_hostile(
    nav: &mut Nav,
    which: usize,
    imu: &ImuTick<f32>,
    genuine: GenuineAids<'_>,
) -> Option<String> {
    let (master, baro, seeker) = (genuine.master, genuine.baro, genuine.seeker);
    // Aid: the same tick with the bad aid and without it must leave the same navigator; the
    // navigator is then put back as it was before (the genuine tick follows).
    let saved = nav.clone();
    let mut without = nav.clone();
    let bad = bad_aid(which, imu.increment.time, &genuine);
    let bad_aids = Aids {
        master: bad.master.as_ref(),
        baro: bad.baro.as_ref(),
        seeker: bad.seeker.as_ref(),
        separation: None,
    };
    let good_aids = Aids {
        master: if which <= 4 { None } else { master },
        baro: if which == 5 || which == 6 { None } else { baro },
        seeker: if which >= 7 { None } else { seeker },
        separation: None,
    };
    let r_bad = nav.tick(imu, &bad_aids);
    let r_good = without.tick(imu, &good_aids);
    let verdict = match (&r_bad, which) {
        (Err(e), _) => Some(format!("the tick failed: {e:?}")),
        (Ok(_), _) if r_good.is_err() => Some("the tick without the aid failed".into()),
        (Ok(rep), _) => {
            let state = match which {
                3 | 4 => rep.master.state,
                5 | 6 => rep.baro.state,
                _ => rep.seeker.state,
            };
            if !matches!(state, AidState::Refused(_) | AidState::NotUsedInPhase) {
                Some(format!("aid state {state:?}"))
            } else {
                (fingerprint(nav) != fingerprint(&without))
                    .then(|| "the refused aid changed the navigator".to_string())
            }
        }
    };
    *nav = saved;
    verdict
}

fn placeholder_master(t: Timestamp) -> MasterNav<f32> {
    MasterNav {
        time: t,
        c_m_n: nalgebra::Matrix3::identity(),
        vel_ned_m_s: Vector3::zeros(),
        position: nav_core::seeker_ins::Position {
            lat_rad: 0.65,
            lon_rad: 2.2,
            alt_m: 3000.0,
        },
        angular_rate_rad_s: Vector3::zeros(),
        angular_accel_rad_s2: Vector3::zeros(),
        specific_force_m_s2: Vector3::new(0.0, 0.0, -9.8),
        attitude_sigma_rad: Vector3::from_element(1e-3),
        velocity_sigma_m_s: Vector3::from_element(0.1),
        position_sigma_m: Vector3::from_element(3.0),
    }
}

/// The aids with aid `which` (3-8) replaced with a hostile sample at time `t`.
fn bad_aid(which: usize, t: Timestamp, genuine: &GenuineAids<'_>) -> OwnedAids {
    let master = genuine.master;
    let mut m = master.copied();
    let mut b = genuine.baro.copied();
    let mut s = genuine.seeker.copied();
    let g = |x: f32| GimbalAngles {
        pitch_rad: x,
        yaw_rad: 0.01,
    };
    let any_master = || {
        master.copied().unwrap_or(MasterNav {
            time: t,
            ..placeholder_master(t)
        })
    };
    match which {
        3 => {
            let mut x = any_master();
            x.vel_ned_m_s.x = f32::NAN;
            m = Some(x);
        }
        4 => {
            let mut x = any_master();
            x.position.lat_rad = 4.0;
            m = Some(x);
        }
        5 => {
            b = Some(BaroSample {
                time: t,
                altitude_m: f32::NAN,
            })
        }
        6 => {
            b = Some(BaroSample {
                time: t,
                altitude_m: f32::NEG_INFINITY,
            })
        }
        7 => {
            s = Some(LosSample {
                time: t,
                gimbal: g(f32::NAN),
            })
        }
        _ => {
            s = Some(LosSample {
                time: t,
                gimbal: g(f32::INFINITY),
            })
        }
    }
    OwnedAids {
        master: m,
        baro: b,
        seeker: s,
    }
}
