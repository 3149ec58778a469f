//! Exact instruction counts and painted stack depth on QEMU's MPS2 boards.
//!
//! With `-icount shift=10,sleep=off` every guest instruction advances virtual time by 1024 ns,
//! and the FPGAIO 32-bit counter (0x4002_8018) runs at 25 MHz of virtual time, so one
//! instruction is 25.6 ticks: `instructions = round(ticks · 5 / 128)`, exact and repeatable.

use core::ptr::{read_volatile, write_volatile};

const FPGAIO_COUNTER: usize = 0x4002_8018;
const PAINT: u32 = 0xC0FF_EE55;
/// Bytes painted below the stack pointer before a kernel runs.
pub const PAINT_BYTES: usize = 24 * 1024;

#[inline(always)]
fn ticks() -> u32 {
    // SAFETY: MPS2 FPGAIO counter register, read-only, always mapped on mps2-an386/an500.
    unsafe { read_volatile(FPGAIO_COUNTER as *const u32) }
}

#[inline(never)]
fn ticks_of(f: &mut dyn FnMut()) -> u32 {
    let t0 = ticks();
    f();
    let t1 = ticks();
    t1.wrapping_sub(t0)
}

/// Instructions executed by `f` (the cost of an empty call through the same path subtracted).
pub fn instructions(f: &mut dyn FnMut()) -> u32 {
    let empty = ticks_of(&mut || {});
    let t = ticks_of(f).wrapping_sub(empty);
    ((u64::from(t) * 5 + 64) / 128) as u32
}

/// [`instructions`] and [`stack_bytes_within`] of one run of `f`, so that a step need not be
/// run twice (once on a copy of the filter for its stack). The stack is painted before the
/// count starts; `f` is inlined here (generic, called once), so its frame — the slot of the
/// step's returned report included — lies above the painted region, as in
/// [`stack_bytes_within`]. The count is of the instructions between two counter reads around
/// `f`, less those of two adjacent reads: [`instructions`] less the few of its indirect call.
#[inline(never)]
pub fn instructions_and_stack<F: FnMut()>(mut f: F, paint_bytes: usize) -> (u32, u32) {
    let e0 = ticks();
    let e1 = ticks();
    let sp = cortex_m::register::msp::read() as usize;
    let top = sp & !3;
    let bottom = top - paint_bytes;
    let mut a = bottom;
    while a < top - 16 {
        // SAFETY: as in `stack_bytes_within`.
        unsafe { write_volatile(a as *mut u32, PAINT) };
        a += 4;
    }
    let t0 = ticks();
    f();
    let t1 = ticks();
    let mut a = bottom;
    while a < top {
        // SAFETY: same region as painted above.
        if unsafe { read_volatile(a as *const u32) } != PAINT {
            break;
        }
        a += 4;
    }
    let t = t1.wrapping_sub(t0).wrapping_sub(e1.wrapping_sub(e0));
    (((u64::from(t) * 5 + 64) / 128) as u32, (top - a) as u32)
}

/// Peak stack used by `f`, bytes: paints [SP − PAINT_BYTES, SP) and finds the lowest word `f`
/// changed. Includes the call into `f` itself (a few words).
pub fn stack_bytes(f: &mut dyn FnMut()) -> u32 {
    stack_bytes_within(f, PAINT_BYTES)
}

/// [`stack_bytes`] with `paint_bytes` painted (a result equal to it: the region was exhausted).
#[inline(never)]
pub fn stack_bytes_within(f: &mut dyn FnMut(), paint_bytes: usize) -> u32 {
    let sp = cortex_m::register::msp::read() as usize;
    let top = sp & !3;
    let bottom = top - paint_bytes;
    let mut a = bottom;
    while a < top - 16 {
        // SAFETY: below the live stack pointer, inside RAM (4 MiB); no interrupts are enabled,
        // so nothing else uses this memory until `f` runs.
        unsafe { write_volatile(a as *mut u32, PAINT) };
        a += 4;
    }
    f();
    let mut a = bottom;
    while a < top {
        // SAFETY: same region as painted above.
        if unsafe { read_volatile(a as *const u32) } != PAINT {
            break;
        }
        a += 4;
    }
    (top - a) as u32
}
