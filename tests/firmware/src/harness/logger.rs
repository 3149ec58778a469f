//! A defmt global logger over semihosting that cannot panic (unlike defmt-semihosting, whose
//! re-entrancy check panics): a nested acquire is dropped and counted instead, so the image can
//! link with the panic-never handler.

use core::cell::UnsafeCell;
use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use cortex_m_semihosting::hio::{self, HostStream};

#[defmt::global_logger]
struct Logger;

struct State {
    encoder: defmt::Encoder,
    stdout: Option<HostStream>,
    restore: critical_section::RestoreState,
}

struct Shared(UnsafeCell<State>);
// SAFETY: only touched between acquire and release, inside a critical section, with `TAKEN`
// guaranteeing a single owner (single core).
unsafe impl Sync for Shared {}

static TAKEN: AtomicBool = AtomicBool::new(false);
/// Frames dropped because the logger was already taken (re-entrant log from an exception).
pub static DROPPED: AtomicU32 = AtomicU32::new(0);
static STATE: Shared = Shared(UnsafeCell::new(State {
    encoder: defmt::Encoder::new(),
    stdout: None,
    restore: critical_section::RestoreState::invalid(),
}));

// SAFETY: defmt calls acquire/write/flush/release in that discipline; the critical section and
// TAKEN make the exclusive access to STATE sound.
unsafe impl defmt::Logger for Logger {
    fn acquire() {
        // SAFETY: paired with the release below (or immediately, when re-entered).
        let restore = unsafe { critical_section::acquire() };
        if TAKEN.load(Ordering::Relaxed) {
            DROPPED.fetch_add(1, Ordering::Relaxed);
            // SAFETY: releases the critical section just acquired.
            unsafe { critical_section::release(restore) };
            return;
        }
        TAKEN.store(true, Ordering::Relaxed);
        // SAFETY: exclusive while TAKEN within the critical section.
        let state = unsafe { &mut *STATE.0.get() };
        state.restore = restore;
        let State {
            encoder, stdout, ..
        } = state;
        encoder.start_frame(|b| {
            if stdout.is_none() {
                *stdout = hio::hstdout().ok();
            }
            if let Some(out) = stdout.as_mut() {
                let _ = out.write_all(b);
            }
        });
    }

    unsafe fn flush() {}

    unsafe fn release() {
        if !TAKEN.load(Ordering::Relaxed) {
            return;
        }
        // SAFETY: exclusive while TAKEN.
        let state = unsafe { &mut *STATE.0.get() };
        let State {
            encoder,
            stdout,
            restore,
        } = state;
        encoder.end_frame(|b| {
            if let Some(out) = stdout.as_mut() {
                let _ = out.write_all(b);
            }
        });
        let restore = *restore;
        TAKEN.store(false, Ordering::Relaxed);
        // SAFETY: pairs with the acquire that set TAKEN.
        unsafe { critical_section::release(restore) };
    }

    unsafe fn write(bytes: &[u8]) {
        if !TAKEN.load(Ordering::Relaxed) {
            return;
        }
        // SAFETY: exclusive while TAKEN.
        let state = unsafe { &mut *STATE.0.get() };
        let State {
            encoder, stdout, ..
        } = state;
        encoder.write(bytes, |b| {
            if let Some(out) = stdout.as_mut() {
                let _ = out.write_all(b);
            }
        });
    }
}
