//! pulsegate: pulse counters, encoders and meters (Modbus, M-Bus) → MQTT, Sparkplug B,
//! Prometheus and PLCs.
//!
//! The pipeline, top to bottom:
//! 1. [`config`] reads one TOML file (plus environment) into a checked [`config::Config`];
//! 2. [`profile`] says, per module model, where each channel's registers are;
//! 3. [`modbus::config::plan`] turns the registers a poll needs into as few Modbus
//!    reads as the wire favours;
//! 4. [`bus`] runs one task per bus, one transaction at a time, earliest deadline first;
//! 5. [`decode`] turns the words into counts and frequencies;
//! 6. [`counter`] turns counts into deltas and totals that survive wrap, resets and restarts;
//! 7. [`publish`] sends readings and availability to MQTT, and [`command`] takes clear/preset.
//!
//! [`sim`] is a simulated plant of every supported model, served over real Modbus.

pub mod admission;
pub mod app;
pub mod billing_report;
pub mod boot;
pub mod bus;
pub mod bus_health;
pub mod command;
pub mod commission;
pub mod config;
pub mod counter;
pub mod decimal;
pub mod decode;
pub mod dedupe;
pub mod demo;
pub mod dispatch;
pub mod event;
pub mod health;
pub mod http;
pub mod log_budget;
pub mod mbus;
pub mod metering;
pub mod metrics;
pub mod modbus;
pub mod outbox;
pub mod outcome;
pub mod profile;
pub mod protocols;
pub mod publish;
pub mod reading;
pub mod remote;
pub mod report;
pub mod sample;
pub mod scan;
pub mod setreading;
pub mod signing;
pub mod sim;
pub mod state;
pub mod status;
pub mod systemd;
pub mod topics;
#[cfg(test)]
mod toy_protocol_tests;
pub mod verify;
