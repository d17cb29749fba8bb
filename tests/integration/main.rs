//! One integration binary: the gateway against the simulator over real pseudo-terminals and a
//! real Mosquitto broker.

mod clock;
mod commands;
mod config_cases;
mod counters;
mod faults;
mod pipeline;
mod plants;
mod service;
mod support;
