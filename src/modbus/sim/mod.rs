//! The simulator's Modbus side: modules of every supported model (`model.rs`, with their
//! datasheets' factory values in `datasheet.rs` and their unit and baud registers in
//! `comm.rs`) behind real Modbus servers (`server.rs`, tokio-modbus's server side) on
//! pseudo-terminals and TCP ports, and a line emulator with seeded noise (`line.rs`).

pub(crate) mod comm;
pub mod config;
pub(crate) mod datasheet;
pub mod line;
pub mod model;
pub mod plant;
pub(crate) mod server;

pub use model::SimModule;
pub use plant::{Buses, PlantBus, every_device};
pub use server::Modules;
