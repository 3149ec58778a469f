//! Shared math: `f32`-only sine/cosine ([`trig`]), rotations, discretisation of linear stochastic systems, Gauss-Markov processes
//! and the Kalman measurement update.

pub mod checks;
pub mod discretize;
pub mod kalman;
pub mod linalg;
pub mod markov;
pub mod rotation;
pub mod trig;
