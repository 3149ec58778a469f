//! What the transfer alignment's property and envelope tests share: a filter from no prior
//! knowledge, and the snapshot a refused call must leave unchanged.

use nav_core::transfer_alignment::{Channel, TaConfig, TaInitial, TransferAlignment};
use nav_core::{Estimator, Health, NavError, Real};

/// A filter for `c`, starting from no prior knowledge of θ_m.
pub fn filter<T: Real, const K: usize, const N: usize>(
    c: TaConfig<T>,
) -> Result<TransferAlignment<T, K, N>, NavError> {
    TransferAlignment::new(&c, &TaInitial::default())
}

/// Everything a refused call must leave as it was: state, covariance, clock, channel counters
/// and health except the count of refusals.
pub fn snapshot<T: Real, const K: usize, const N: usize>(f: &TransferAlignment<T, K, N>) -> String {
    let health = Health {
        imu_refused: 0,
        ..f.health()
    };
    let counters = Channel::ALL.map(|c| f.aid_counters(c));
    format!(
        "{:?} {:?} {:?} {:?} {health:?} {counters:?}",
        f.state(),
        f.covariance(),
        f.time(),
        f.grid_time()
    )
}
