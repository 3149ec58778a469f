//! Kernels written by `cargo xtask gen` (`xtask/src/gen.rs`) from the sparsity of the seeker
//! INS's error model, which is known when the generator runs. Not edited by hand: change the
//! generator, run `cargo xtask gen` and commit both; `cargo xtask gen --check` (part of
//! `cargo xtask ci`) fails when a committed file is stale.

pub(super) mod los17;
pub(super) mod predict17;
