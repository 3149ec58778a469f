//! Shared math: rotations, discretisation of linear stochastic systems, Gauss-Markov processes
//! and the Kalman measurement update.

pub mod checks;
pub mod discretize;
pub mod kalman;
pub mod linalg;
pub mod markov;
pub mod rotation;
