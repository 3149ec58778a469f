//! One INS run's state and what it measured, the frame check, the statistics of the
//! differences and the quaternion helpers they use.

use super::*;

/// RMS and largest magnitude of a difference.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct AbsStat {
    pub(super) n: u64,
    pub(super) sum_sq: f64,
    pub(super) max_abs: f64,
}

impl AbsStat {
    pub(super) fn add(&mut self, x: f64) {
        if x.is_finite() {
            self.n += 1;
            self.sum_sq += x * x;
            self.max_abs = self.max_abs.max(x.abs());
        }
    }
    pub(super) fn json(&self, scale: f64, unit: &str) -> Value {
        if self.n == 0 {
            return Value::Null;
        }
        json!({
            format!("rms_{unit}"): sig((self.sum_sq / self.n as f64).sqrt() * scale, 4),
            format!("max_abs_{unit}"): sig(self.max_abs * scale, 4),
        })
    }
}

pub(super) fn add3(stats: &mut [AbsStat; 3], v: &[f64; 3]) {
    for (st, x) in stats.iter_mut().zip(v) {
        st.add(*x);
    }
}

pub(super) fn axes_json(s: &[AbsStat; 3], names: [&str; 3], scale: f64, unit: &str) -> Value {
    let mut m = serde_json::Map::new();
    for (st, name) in s.iter().zip(names) {
        m.insert(name.into(), st.json(scale, unit));
    }
    m.insert("samples".into(), json!(s.iter().map(|x| x.n).max()));
    Value::Object(m)
}

pub(super) const RPY: [&str; 3] = ["roll", "pitch", "yaw"];
pub(super) const NED: [&str; 3] = ["north", "east", "down"];

/// Hamilton product of (w, x, y, z) arrays.
pub(super) fn qmul(a: &[f64; 4], b: &[f64; 4]) -> [f64; 4] {
    let q = quat_mul(
        &Quaternion::new(a[0], a[1], a[2], a[3]),
        &Quaternion::new(b[0], b[1], b[2], b[3]),
    );
    [q.w, q.i, q.j, q.k]
}

pub(super) fn qconj(q: &[f64; 4]) -> [f64; 4] {
    [q[0], -q[1], -q[2], -q[3]]
}

pub(super) fn dcm(q: &[f64; 4]) -> nalgebra::Matrix3<f64> {
    quat_to_dcm(&Quaternion::new(q[0], q[1], q[2], q[3]))
}

/// 3-2-1 Euler angles (roll, pitch, yaw) of a quaternion, rad.
pub(super) fn euler(q: &[f64; 4]) -> [f64; 3] {
    let (r, p, y) = dcm_to_euler(&dcm(q));
    [r, p, y]
}

pub(super) fn wrap_pi(a: f64) -> f64 {
    let w = (a + std::f64::consts::PI).rem_euclid(2.0 * std::f64::consts::PI);
    w - std::f64::consts::PI
}

/// Euler-angle difference `a − b` per axis (yaw wrapped), rad.
pub(super) fn euler_diff(a: &[f64; 4], b: &[f64; 4]) -> [f64; 3] {
    let (ea, eb) = (euler(a), euler(b));
    [ea[0] - eb[0], ea[1] - eb[1], wrap_pi(ea[2] - eb[2])]
}

/// Where an initial value came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Source {
    Autopilot,
    Gnss,
    Baro,
    Configuration,
    /// No reference yet: zero.
    Zero,
}

/// One initialisation of a run.
#[derive(Debug, Clone, Copy)]
pub(super) struct InitRecord {
    pub(super) t: Timestamp,
    pub(super) horizontal_velocity: Source,
    pub(super) vertical_velocity: Source,
    pub(super) lat_lon: Source,
    pub(super) altitude: Source,
    pub(super) lat_deg: f64,
    pub(super) alt_m: f64,
}

/// A difference reached a reporting horizon.
#[derive(Debug, Clone, Copy)]
pub(super) struct HorizonHit {
    pub(super) after_s: f64,
    pub(super) elapsed_s: f64,
    pub(super) att_rad: [f64; 3],
    pub(super) vel_vs_autopilot_m_s: Option<[f64; 3]>,
    pub(super) vel_vs_gnss_m_s: Option<[f64; 3]>,
}

/// One INS run (free or re-levelled) and what it measured.
#[derive(Debug, Default)]
pub(super) struct Run {
    pub(super) ins: Option<Ins<f32>>,
    /// Time of the state: the last integrated IMU sample, or the IMU sample before the
    /// initialisation.
    pub(super) t_ins: Option<Timestamp>,
    /// The INS was (re-)initialised and has not integrated a sample yet: it is rebuilt with
    /// the actual first interval at the next sample.
    pub(super) first_pending: bool,
    pub(super) init_t: Option<Timestamp>,
    pub(super) inits: Vec<InitRecord>,
    /// Product of the inverse attitude resets since the initialisation (reference without
    /// the autopilot's jumps: `q_cont = reset_acc ⊗ q`).
    pub(super) reset_acc: Option<[f64; 4]>,
    pub(super) accepted: u64,
    pub(super) refused: BTreeMap<String, u64>,
    pub(super) gap_reinits: u64,
    /// The first gaps: (start, length).
    pub(super) gaps: Vec<(Timestamp, f64)>,
    /// Initialisations nav-core refused (bad reference values), by reason.
    pub(super) init_refused: BTreeMap<String, u64>,
    pub(super) att: [AbsStat; 3],
    pub(super) vel_ap: [AbsStat; 3],
    pub(super) vel_gnss: [AbsStat; 3],
    pub(super) last_att: Option<[f64; 3]>,
    pub(super) last_vel_ap: Option<[f64; 3]>,
    pub(super) last_vel_gnss: Option<[f64; 3]>,
    pub(super) window_att: [AbsStat; 3],
    pub(super) window_vel_ap: [AbsStat; 3],
    pub(super) window_vel_gnss: [AbsStat; 3],
    pub(super) windows: u64,
    pub(super) horizons: Vec<HorizonHit>,
    pub(super) horizon_next: usize,
}

impl Run {
    pub(super) fn refuse(&mut self, why: &str) {
        *self.refused.entry(why.to_string()).or_default() += 1;
    }

    pub(super) fn reference(&self, q: &[f64; 4]) -> [f64; 4] {
        match &self.reset_acc {
            Some(a) => qmul(a, q),
            None => *q,
        }
    }

    pub(super) fn q_ins(&self) -> Option<[f64; 4]> {
        self.ins.as_ref().map(|ins| {
            let q = ins.state().q_b_n;
            [q.w, q.i, q.j, q.k].map(f64::from)
        })
    }

    pub(super) fn vel_ins(&self) -> Option<[f64; 3]> {
        self.ins.as_ref().map(|ins| {
            let v = ins.state().vel_ned_m_s;
            [v.x, v.y, v.z].map(f64::from)
        })
    }

    pub(super) fn close_window(&mut self) {
        if let Some(a) = self.last_att {
            self.windows += 1;
            add3(&mut self.window_att, &a);
        }
        if let Some(v) = self.last_vel_ap {
            add3(&mut self.window_vel_ap, &v);
        }
        if let Some(v) = self.last_vel_gnss {
            add3(&mut self.window_vel_gnss, &v);
        }
    }
}

/// The latest value of a reference and its time.
#[derive(Debug, Clone, Copy)]
pub(super) struct Latest<T> {
    pub(super) t: Timestamp,
    pub(super) v: T,
}

#[derive(Debug, Clone, Copy)]
pub(super) struct VelocityRef {
    pub(super) vd_m_s: f64,
    pub(super) v_ne: Option<HorizontalVelocity>,
}

/// Averages of the frame check: the specific force in NED with the logged quaternion as it is
/// and as its conjugate (the other convention), m/s².
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct FrameCheck {
    pub(super) n: u64,
    pub(super) f_ned: [f64; 3],
    pub(super) f_ned_conjugate: [f64; 3],
    pub(super) f_body: [f64; 3],
}

impl FrameCheck {
    pub(super) fn add(&mut self, q: &[f64; 4], f_b: &[f64; 3]) {
        let fb = Vector3::new(f_b[0], f_b[1], f_b[2]);
        let a = dcm(q) * fb;
        let b = dcm(&qconj(q)) * fb;
        self.n += 1;
        let w = 1.0 / self.n as f64;
        for k in 0..3 {
            self.f_ned[k] += (a[k] - self.f_ned[k]) * w;
            self.f_ned_conjugate[k] += (b[k] - self.f_ned_conjugate[k]) * w;
            self.f_body[k] += (f_b[k] - self.f_body[k]) * w;
        }
    }
    /// Down within tolerance of −g, and the conjugate quaternion (the other convention) not a
    /// clearly better fit: where the vehicle is tilted, the wrong convention tilts gravity by
    /// twice the attitude.
    pub(super) fn passes(&self) -> bool {
        let h = |f: &[f64; 3]| f[0].hypot(f[1]);
        let conjugate_better = h(&self.f_ned) > FRAME_CHECK_TOLERANCE_M_S2
            && h(&self.f_ned_conjugate) < 0.5 * h(&self.f_ned);
        self.n > 0
            && (self.f_ned[2] + G_M_S2).abs() <= FRAME_CHECK_TOLERANCE_M_S2
            && !conjugate_better
    }
    pub(super) fn json(&self) -> Value {
        let r = |v: &[f64; 3]| v.map(|x| sig(x, 4));
        let result = match (self.n, self.passes()) {
            (0, _) => "NotRun",
            (_, true) => "GravityUp",
            (_, false) => "Inconsistent",
        };
        json!({
            "result": result,
            "samples": self.n,
            "f_body_mean_m_s2": r(&self.f_body),
            "f_ned_mean_m_s2": r(&self.f_ned),
            "f_ned_mean_with_conjugate_q_m_s2": r(&self.f_ned_conjugate),
            "tolerance_on_down_m_s2": sig(FRAME_CHECK_TOLERANCE_M_S2, 3),
        })
    }
}

/// A point of the INS plot.
#[derive(Debug, Clone, Copy)]
pub(super) struct PlotRow {
    pub(super) t_s: f64,
    pub(super) free_att_deg: [f64; 3],
    pub(super) relev_att_deg: [f64; 3],
    pub(super) free_v: [f64; 3],
    pub(super) relev_v: [f64; 3],
    pub(super) ap_v: [f64; 3],
    pub(super) gnss_v: [f64; 3],
}
