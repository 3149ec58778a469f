//! Property tests of the flight navigator (`nav_core::navigator`), f32 and f64: random aid
//! schedules over a short synthetic chain carry → released → midcourse → terminal, with
//! hostile input on random ticks.
//!
//! The chain: straight level flight, the master INS = the truth (its late samples time-tagged,
//! with random latency and loss), the slave IMU = the truth's increments in a fixed mount
//! misalignment on a lever arm; the release signal, a 0 g drop, the coast, then baro and LOS
//! samples (truth plus small errors) at random ticks, coinciding ones included. IMU rates 100
//! to 1000 Hz, start time stamps 0 or hours. After every tick (`check_tick`): `Ok`; solution
//! and σ finite; the EKF's P exactly symmetric with a non-negative diagonal; the phase
//! monotone; the one-heavy-update rule (a valid baro sample on a tick whose LOS sample went
//! through the EKF is `Held`, the held sample fused or superseded on the next tick without a
//! LOS update, dropped only when older than `MAX_BARO_AGE_S`); the baro counters add up to
//! the samples offered; the baro timeout exactly when no valid sample came for `baro_s`.
//! Hostile input (`hostile_imu`, `hostile_aid`): an IMU sample that is refused changes
//! nothing (the navigator's `Debug` output, bit for bit); a refused aid sample changes
//! nothing but its aid's `refused` counter and its reported state.

#[path = "navigator_props/chain.rs"]
mod chain;

use chain::{
    config, draw_aids, imu_tick, schedule, world, Bus, Draws, Nav, Schedule, World, FLY_S,
};
use nav_core::contract::AidCounters;
use nav_core::navigator::{
    AidAvailability, AidState, AidStatus, Aids, ImuTick, MasterNav, Phase, TickReport,
    MAX_BARO_AGE_S,
};
use nav_core::seeker_ins::{LosSample, MAX_DELTA_THETA_RAD};
use nav_core::time::Timestamp;
use nav_core::vertical_channel::BaroSample;
use nav_core::Real;
use proptest::prelude::*;

fn rank(p: Phase) -> u8 {
    match p {
        Phase::Carry => 0,
        Phase::Released => 1,
        Phase::Midcourse => 2,
        Phase::Terminal => 3,
    }
}

fn sum(c: &AidCounters) -> u64 {
    [c.fused, c.rejected, c.skipped, c.superseded, c.refused]
        .iter()
        .map(|&v| u64::from(v))
        .sum()
}

/// What the test knows of one tick's baro and LOS input.
#[derive(Debug, Clone, Copy, Default)]
struct Offered<T: Real> {
    /// A valid baro sample (later than every baro sample offered before, age ≤ 1 s).
    baro: Option<BaroSample<T>>,
    /// A baro sample that must be refused (hostile).
    bad_baro: bool,
    /// A LOS sample that went to the navigator, and whether it must be refused.
    los: bool,
    bad_los: bool,
}

/// The running record the checks keep between ticks.
struct Track<T: Real> {
    phase: Phase,
    held: Option<BaroSample<T>>,
    baro: AidCounters,
    /// Baro samples offered in a phase that uses them (every one counted somewhere).
    baro_offered: u64,
    midcourse_at: Option<Timestamp>,
    last_valid_baro: Option<Timestamp>,
    /// The time stamp of the last valid baro sample offered where it is used.
    last_baro_stamp: Option<Timestamp>,
    /// The time stamp of the last LOS sample the EKF took.
    last_los: Option<Timestamp>,
    ticks: u64,
}

impl<T: Real> Track<T> {
    fn new() -> Self {
        Self {
            phase: Phase::Carry,
            held: None,
            baro: AidCounters::default(),
            baro_offered: 0,
            midcourse_at: None,
            last_valid_baro: None,
            last_baro_stamp: None,
            last_los: None,
            ticks: 0,
        }
    }
}

fn finite<T: Real>(v: &[T]) -> bool {
    v.iter().all(|x| x.is_finite())
}

/// The solution and the EKF's P after a tick.
fn check_numbers<T: Real>(nav: &Nav<T>, r: &TickReport<T>) -> Result<(), String> {
    let s = &r.solution;
    let p = s.state.position;
    if !([p.lat_rad, p.lon_rad, p.alt_m]
        .iter()
        .all(|v| v.is_finite())
        && finite(s.state.vel_ned_m_s.as_slice())
        && finite(s.state.q_b_n.coords.as_slice())
        && finite(s.nav_covariance.as_slice()))
    {
        return Err(format!("solution not finite: {s:?}"));
    }
    if s.nav_covariance.diagonal().iter().any(|v| *v < T::zero()) {
        return Err("negative variance in the solution".into());
    }
    if nav.ekf().is_some() != (r.phase != Phase::Carry) {
        return Err(format!("EKF {} in {:?}", nav.ekf().is_some(), r.phase));
    }
    if let Some(e) = nav.ekf() {
        let pk = e.covariance();
        if !finite(pk.as_slice()) || pk != &pk.transpose() {
            return Err("EKF P not finite or not exactly symmetric".into());
        }
        if pk.diagonal().iter().any(|v| *v < T::zero()) {
            return Err("EKF P with a negative variance".into());
        }
    }
    Ok(())
}

/// Phase order and transitions; the seeker's state by phase.
fn check_phase<T: Real>(nav: &Nav<T>, r: &TickReport<T>, tr: &mut Track<T>) -> Result<(), String> {
    if r.phase != nav.phase() || rank(r.phase) < rank(tr.phase) {
        return Err(format!("phase {:?} after {:?}", r.phase, tr.phase));
    }
    if r.phase != tr.phase {
        let t = r.transition.ok_or("phase change without a transition")?;
        if t.from != tr.phase || rank(t.to) > rank(r.phase) || t.time != r.solution.time {
            return Err(format!(
                "transition {t:?} from {:?} to {:?}",
                tr.phase, r.phase
            ));
        }
        if t.to == Phase::Midcourse {
            tr.midcourse_at = Some(t.time);
        }
    }
    if r.phase == Phase::Terminal
        && tr.phase != Phase::Terminal
        && r.seeker.state != AidState::Fused
    {
        return Err(format!(
            "terminal without a fused LOS: {:?}",
            r.seeker.state
        ));
    }
    let seeker_used = rank(r.phase) >= 2;
    if seeker_used == (r.seeker.state == AidState::NotUsedInPhase) {
        return Err(format!("seeker {:?} in {:?}", r.seeker.state, r.phase));
    }
    tr.phase = r.phase;
    Ok(())
}

/// The baro in a phase that does not use it: ignored, nothing held, nothing counted.
fn check_baro_unused<T: Real>(
    nav: &Nav<T>,
    r: &TickReport<T>,
    tr: &Track<T>,
) -> Result<(), String> {
    if r.baro.state != AidState::NotUsedInPhase
        || nav.held_baro().is_some()
        || r.baro.counters != tr.baro
    {
        return Err(format!("baro used in {:?}: {:?}", r.phase, r.baro));
    }
    Ok(())
}

/// The one-heavy-update rule, the counters' identity and the baro timeout.
fn check_baro<T: Real>(
    nav: &Nav<T>,
    r: &TickReport<T>,
    off: &Offered<T>,
    tr: &mut Track<T>,
) -> Result<(), String> {
    let now = r.solution.time;
    let (c0, c) = (tr.baro, r.baro.counters);
    let held = nav.held_baro().copied();
    if off.baro.is_some() || off.bad_baro {
        tr.baro_offered += 1;
    }
    // Every sample offered is fused, rejected, skipped, superseded, refused or still held.
    if sum(&c) + u64::from(held.is_some()) != tr.baro_offered {
        return Err(format!(
            "counters {c:?} + held {} != {} offered",
            held.is_some(),
            tr.baro_offered
        ));
    }
    if c.refused - c0.refused != u32::from(off.bad_baro) {
        return Err(format!(
            "refused {} -> {} (bad sample {})",
            c0.refused, c.refused, off.bad_baro
        ));
    }
    if off.bad_baro != matches!(r.baro.state, AidState::Refused(_)) {
        return Err(format!(
            "baro {:?}, bad sample {}",
            r.baro.state, off.bad_baro
        ));
    }
    if off.los && (off.bad_los != matches!(r.seeker.state, AidState::Refused(_))) {
        return Err(format!(
            "seeker {:?}, bad sample {}",
            r.seeker.state, off.bad_los
        ));
    }
    let los_ran = off.los && !off.bad_los;
    let expired = tr.held.filter(|h| {
        now.micros_since(h.time)
            .is_none_or(|a| a > (MAX_BARO_AGE_S * 1e6) as u64)
    });
    let waiting = tr.held.filter(|_| expired.is_none());
    let candidate = off.baro.or(waiting);
    let done = |c: &AidCounters| u64::from(c.fused) + u64::from(c.rejected) + u64::from(c.skipped);
    let want_done = u64::from(expired.is_some()) + u64::from(candidate.is_some() && !los_ran);
    if done(&c) - done(&c0) != want_done {
        return Err(format!(
            "{c0:?} -> {c:?}: {want_done} fused/rejected/skipped expected"
        ));
    }
    if c.superseded - c0.superseded != u32::from(off.baro.is_some() && waiting.is_some()) {
        return Err(format!("superseded {c0:?} -> {c:?}"));
    }
    match (candidate, los_ran) {
        (Some(b), true) => {
            if held != Some(b) || !(off.bad_baro || r.baro.state == AidState::Held) {
                return Err(format!(
                    "LOS tick: baro {:?}, held {held:?}, want {b:?}",
                    r.baro.state
                ));
            }
        }
        (Some(_), false) => {
            let fused = matches!(
                r.baro.state,
                AidState::Fused | AidState::Rejected | AidState::Waiting
            );
            if held.is_some() || !(off.bad_baro || fused) {
                return Err(format!(
                    "tick without LOS: baro {:?}, held {held:?}",
                    r.baro.state
                ));
            }
        }
        (None, _) => {
            if held.is_some() || matches!(r.baro.state, AidState::Held | AidState::Fused) {
                return Err(format!("no sample: baro {:?}, held {held:?}", r.baro.state));
            }
        }
    }
    if off.baro.is_some() {
        tr.last_valid_baro = Some(now);
    }
    check_baro_timeout(r, tr)?;
    tr.held = held;
    Ok(())
}

/// The baro timeout exactly when no valid sample arrived for `baro_s` (1 s) since midcourse.
fn check_baro_timeout<T: Real>(r: &TickReport<T>, tr: &Track<T>) -> Result<(), String> {
    let since = tr
        .last_valid_baro
        .max(tr.midcourse_at)
        .ok_or("midcourse start unknown")?;
    let gap_s = r.solution.time.signed_seconds_since::<f64>(since);
    let timed_out = r.degradation.baro == AidAvailability::TimedOut;
    if (timed_out && gap_s < 1.0 - 1e-3) || (!timed_out && gap_s > 1.0 + 1e-3) {
        return Err(format!(
            "baro {:?} after {gap_s} s without a sample",
            r.degradation.baro
        ));
    }
    Ok(())
}

/// Every check after a tick.
fn check_tick<T: Real>(
    nav: &Nav<T>,
    r: &TickReport<T>,
    off: &Offered<T>,
    tr: &mut Track<T>,
) -> Result<(), String> {
    check_numbers(nav, r)?;
    check_phase(nav, r, tr)?;
    if rank(r.phase) >= 2 {
        check_baro(nav, r, off, tr)?;
        tr.last_baro_stamp = off.baro.map(|b| b.time).or(tr.last_baro_stamp);
        if off.los && !off.bad_los {
            tr.last_los = Some(r.solution.time);
        }
    } else {
        check_baro_unused(nav, r, tr)?;
    }
    tr.baro = r.baro.counters;
    tr.ticks += 1;
    Ok(())
}

/// `Debug` output with every `refused: N` counter blanked.
fn without_refusals(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    let mut rest = s;
    while let Some(i) = rest.find("refused: ") {
        let (head, tail) = rest.split_at(i + "refused: ".len());
        out.push_str(head);
        out.push('#');
        rest = tail.trim_start_matches(|c: char| c.is_ascii_digit());
    }
    out.push_str(rest);
    out
}

/// A refused IMU sample (`imu` corrupted by `kind`, with this tick's aids): `Err`, and the
/// navigator exactly as before (its `Debug` output).
fn hostile_imu<T: Real>(
    nav: &mut Nav<T>,
    imu: &ImuTick<T>,
    aids: &Aids<'_, T>,
    kind: u64,
    axis: usize,
) -> Result<(), String> {
    let mut bad = *imu;
    let last = nav.solution().time;
    let dt_us = imu.increment.time.micros_since(last).unwrap_or(1);
    match kind {
        0 => bad.increment.delta_theta_rad[axis] = T::lit(f64::NAN),
        1 => bad.increment.delta_v_m_s[axis] = T::lit(f64::INFINITY),
        2 => bad.increment.delta_theta_rad[axis] = T::lit(f64::NEG_INFINITY),
        3 => bad.increment.delta_v_m_s[axis] = T::lit(1e30),
        4 => bad.increment.time = last,
        5 => bad.increment.time = Timestamp::from_micros(last.as_micros().saturating_sub(dt_us)),
        _ => bad.increment.delta_theta_rad[axis] = T::lit(2.0 * MAX_DELTA_THETA_RAD),
    }
    let before = format!("{nav:?}");
    match nav.tick(&bad, aids) {
        Ok(r) => Err(format!(
            "bad IMU sample (kind {kind}) accepted: {:?}",
            r.phase
        )),
        Err(_) if format!("{nav:?}") != before => Err(format!(
            "refused IMU sample (kind {kind}) changed the navigator"
        )),
        Err(_) => Ok(()),
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Which {
    Master,
    Baro,
    Seeker,
}

fn status_mut<T: Real>(r: &mut TickReport<T>, w: Which) -> &mut AidStatus<T> {
    match w {
        Which::Master => &mut r.master,
        Which::Baro => &mut r.baro,
        Which::Seeker => &mut r.seeker,
    }
}

/// A tick with a refused aid sample (`nav`, `ra`) against the same tick without it (`b`,
/// `rb`): the aid `Refused` (or `NotUsedInPhase` in a phase that ignores it), its `refused`
/// counter one up, everything else the same, the navigator's whole state included.
fn same_but_refused<T: Real>(
    nav: &Nav<T>,
    ra: &TickReport<T>,
    b: &Nav<T>,
    rb: &TickReport<T>,
    w: Which,
    used: bool,
) -> Result<(), String> {
    let mut patched = *ra;
    let s = status_mut(&mut patched, w);
    let refused = matches!(s.state, AidState::Refused(_));
    if refused != used && !(w == Which::Master && s.state == AidState::NotUsedInPhase) {
        return Err(format!(
            "bad {w:?} sample: {:?} (used in phase {used})",
            s.state
        ));
    }
    if refused {
        s.counters.refused -= 1;
    }
    s.state = status_mut(&mut rb.clone(), w).state;
    if &patched != rb {
        return Err(format!(
            "bad {w:?} sample changed the report:\n{ra:?}\n{rb:?}"
        ));
    }
    if without_refusals(&format!("{nav:?}")) != without_refusals(&format!("{b:?}")) {
        return Err(format!("bad {w:?} sample changed the navigator"));
    }
    Ok(())
}

/// Hostile aid samples: the slot a bad sample takes, and the sample.
struct BadAids<T: Real> {
    which: Which,
    master: MasterNav<T>,
    baro: BaroSample<T>,
    los: LosSample<T>,
}

fn bad_aid<T: Real>(
    w: &World,
    kind: u64,
    last_baro: Option<Timestamp>,
    last_los: Option<Timestamp>,
    rng: &mut Draws,
) -> BadAids<T> {
    let now = w.time();
    let nan = T::lit(f64::NAN);
    let mut master = w.master_sample::<T>(w.k).unwrap();
    let mut baro = BaroSample {
        time: now,
        altitude_m: T::lit(3000.0),
    };
    let mut los = chain::los::<T>(w, rng);
    let which = match kind % 3 {
        0 => Which::Master,
        1 => Which::Baro,
        _ => Which::Seeker,
    };
    match (which, kind / 3) {
        (Which::Master, 0) => master.vel_ned_m_s.y = nan,
        (Which::Master, 1) => master.c_m_n[(1, 2)] = T::lit(f64::INFINITY),
        (Which::Master, 2) => {
            master.time = Timestamp::from_micros(now.as_micros().saturating_sub(1_000_000))
        }
        (Which::Master, _) => master.time = now.add_micros(10_000),
        (Which::Baro, 0) => baro.altitude_m = nan,
        (Which::Baro, 1) => baro.altitude_m = T::lit(f64::INFINITY),
        (Which::Baro, 2) => baro.time = now.add_micros(1),
        (Which::Baro, _) => {
            baro.time = last_baro.unwrap_or(Timestamp::from_micros(
                now.as_micros().saturating_sub(1_500_000),
            ))
        }
        (Which::Seeker, 0) => los.gimbal.pitch_rad = nan,
        (Which::Seeker, 1) => los.gimbal.yaw_rad = T::lit(f64::NEG_INFINITY),
        (Which::Seeker, 2) => los.gimbal.pitch_rad = T::lit(3.0),
        (Which::Seeker, _) => match last_los {
            Some(t) => los.time = t,
            None => los.gimbal.yaw_rad = nan,
        },
    }
    BadAids {
        which,
        master,
        baro,
        los,
    }
}

/// What a case exercised.
#[derive(Debug, Default, Clone, Copy)]
struct Stats {
    ticks: u64,
    held: u32,
    superseded: u32,
    expired: u32,
    baro_fused: u32,
    terminal: bool,
    bad_imu: u32,
    bad_aids: u32,
    /// Samples refused: master, baro, seeker.
    refused: [u32; 3],
}

impl Stats {
    /// The counts the navigator's final counters give.
    fn at_end<T: Real>(mut self, nav: &Nav<T>) -> Self {
        let end = nav.blank_report();
        let c = end.baro.counters;
        (self.superseded, self.baro_fused) = (c.superseded, c.fused);
        self.terminal = nav.phase() == Phase::Terminal;
        self.refused = [
            end.master.counters.refused,
            c.refused,
            end.seeker.counters.refused,
        ];
        self
    }
}

/// The hostile aid's tick (`nav`, `r`) against the same tick without it (`reference`, the
/// navigator and the aids before the bad sample took its slot); whether the phase uses it.
fn check_bad_aid<T: Real>(
    nav: &Nav<T>,
    r: &TickReport<T>,
    b: &BadAids<T>,
    reference: (Nav<T>, Aids<'_, T>),
    imu: &ImuTick<T>,
    carry: bool,
) -> Result<bool, String> {
    let used = match b.which {
        Which::Master => carry,
        _ => rank(r.phase) >= 2,
    };
    let (mut nb, mut ab) = reference;
    match b.which {
        Which::Master => ab.master = None,
        Which::Baro => ab.baro = None,
        Which::Seeker => ab.seeker = None,
    }
    let rb = nb.tick(imu, &ab).map_err(|e| format!("reference: {e:?}"))?;
    same_but_refused(nav, r, &nb, &rb, b.which, used)
        .map_err(|e| format!("{e} ({:?} {:?} {:?})", b.master, b.baro, b.los))?;
    Ok(used)
}

/// The LOS burst's flags at tick `k`: LOS on every tick, the baro quiet, a baro sample at
/// its start.
fn burst_at(s: &Schedule, burst: &std::ops::Range<u64>, k: u64) -> (bool, bool, bool) {
    let on = burst.contains(&k);
    (
        on,
        s.quiet_burst && on && k > burst.start,
        s.quiet_burst && on && k == burst.start,
    )
}

/// One case: the chain flown tick by tick, every tick checked; what it exercised.
fn run<T: Real>(s: &Schedule) -> Result<Stats, String> {
    let cfg = config::<T>(s);
    let mut w = world(s, cfg.lever_arm.nominal_m.map(|x| x.to_f64()));
    let mut nav = Nav::<T>::new(&cfg, &w.initial()).map_err(|e| format!("new: {e:?}"))?;
    let mut rng = Draws(s.seed);
    let rate = s.rate_hz as f64;
    let flight = w.sep_tick + w.drop_ticks;
    let total = flight + ((s.coast_s + FLY_S) * rate).round() as u64;
    let hostile: Vec<u64> = (0..s.hostile).map(|_| 1 + rng.below(total - 1)).collect();
    let burst_from = flight + ((s.coast_s + 0.3) * rate) as u64;
    let burst = burst_from..burst_from + (s.los_burst_s * rate) as u64;
    let mut bus = Bus::new(s);
    let (mut tr, mut st) = (Track::<T>::new(), Stats::default());
    let mut last_baro = None;
    for _ in 0..total {
        let inc = w.step();
        let (imu, k) = (imu_tick::<T>(&inc), w.k);
        let master = bus.at::<T>(&w, s, &mut rng);
        let flags = burst_at(s, &burst, k);
        let (baro, los) = draw_aids::<T>(&w, s, &mut rng, &mut last_baro, flags);
        let mut aids = Aids {
            master: master.as_ref(),
            baro: baro.as_ref(),
            seeker: los.as_ref(),
            separation: (k == w.sep_tick + 1).then_some(inc.time),
        };
        let mut off = Offered {
            baro,
            bad_baro: false,
            los: los.is_some(),
            bad_los: false,
        };
        let kind = hostile.contains(&k).then(|| rng.below(19));
        if let Some(kind) = kind.filter(|k| *k < 7) {
            hostile_imu(&mut nav, &imu, &aids, kind, rng.below(3) as usize)
                .map_err(|e| format!("tick {k}: {e}"))?;
            st.bad_imu += 1;
        }
        let bad = kind
            .filter(|k| *k >= 7)
            .map(|kind| bad_aid::<T>(&w, kind - 7, tr.last_baro_stamp, tr.last_los, &mut rng));
        let reference = bad.as_ref().map(|_| (nav.clone(), aids));
        if let Some(b) = &bad {
            match b.which {
                Which::Master => aids.master = Some(&b.master),
                Which::Baro => (aids.baro, off.baro, off.bad_baro) = (Some(&b.baro), None, true),
                Which::Seeker => (aids.seeker, off.los, off.bad_los) = (Some(&b.los), true, true),
            }
        }
        let r = nav
            .tick(&imu, &aids)
            .map_err(|e| format!("tick {k}: valid IMU refused: {e:?}"))?;
        if let (Some(b), Some(reference)) = (&bad, reference) {
            let carry = tr.phase == Phase::Carry;
            if !check_bad_aid(&nav, &r, b, reference, &imu, carry)
                .map_err(|e| format!("tick {k}: {e}"))?
            {
                // Ignored in this phase: as if it had not come.
                (off.bad_baro, off.bad_los) = (false, false);
                off.los = los.is_some() && b.which != Which::Seeker;
            }
            st.bad_aids += 1;
        }
        let (before, held_before) = (tr.baro, tr.held);
        check_tick(&nav, &r, &off, &mut tr)
            .map_err(|e| format!("tick {k} ({:?}): {e}", r.phase))?;
        st.held += u32::from(r.baro.state == AidState::Held);
        st.expired += u32::from(held_before.is_some() && r.baro.counters.skipped > before.skipped);
        st.ticks += 1;
    }
    Ok(st.at_end(&nav))
}

fn run_both(s: &Schedule) -> Result<(Stats, Stats), String> {
    let a = run::<f32>(s).map_err(|e| format!("f32: {e}"))?;
    let b = run::<f64>(s).map_err(|e| format!("f64: {e}"))?;
    Ok((a, b))
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, .. ProptestConfig::default() })]

    /// Random aid schedules and hostile ticks over the chain, f32 and f64: every tick's
    /// checks (`check_tick`, `hostile_imu`, `same_but_refused`) hold.
    #[test]
    fn random_schedules_keep_the_navigator_contract(s in schedule()) {
        let r = run_both(&s);
        prop_assert!(r.is_ok(), "{:?}: {}", s, r.unwrap_err());
    }
}

/// The schedules exercise what the properties check: over the cases the proptest draws (the
/// same strategy, a fixed seed), holds, supersessions, expiries, terminal phases and hostile
/// samples of every kind occur.
#[test]
fn the_random_schedules_exercise_every_rule() {
    use proptest::strategy::ValueTree;
    use proptest::test_runner::{Config, RngAlgorithm, TestRng, TestRunner};
    let mut runner = TestRunner::new_with_rng(
        Config::default(),
        TestRng::from_seed(RngAlgorithm::ChaCha, &[7; 32]),
    );
    let mut total = Stats::default();
    let mut terminal = 0;
    for _ in 0..12 {
        let s = schedule().new_tree(&mut runner).unwrap().current();
        let st = run::<f32>(&s).unwrap();
        println!("{s:?}\n  {st:?}");
        total.ticks += st.ticks;
        total.held += st.held;
        total.superseded += st.superseded;
        total.expired += st.expired;
        total.baro_fused += st.baro_fused;
        total.bad_imu += st.bad_imu;
        total.bad_aids += st.bad_aids;
        for (t, r) in total.refused.iter_mut().zip(st.refused) {
            *t += r;
        }
        terminal += u32::from(st.terminal);
    }
    println!("{total:?}, terminal {terminal}");
    let t = &total;
    assert!(
        t.held > 0 && t.superseded > 0 && t.expired > 0 && t.baro_fused > 0,
        "{t:?}"
    );
    assert!(
        t.bad_imu > 0 && t.bad_aids > 0 && t.refused.iter().all(|&r| r > 0),
        "{t:?}"
    );
    assert!(terminal > 0);
}
