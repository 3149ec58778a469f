//! nav-sim
