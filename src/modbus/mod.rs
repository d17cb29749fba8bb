//! Modbus, everything the gateway knows of it in one folder, each part at the floor of the
//! layer it implements: [`config`] its bus's line, a device's unit, the checks of
//! `[buses.NAME]`, the FC03 poll planner and its bus in words (and, in [`config::server`], the
//! Modbus server output's keys and register map); [`driver`] the RTU/TCP driver under the bus
//! core; [`server`] the Modbus TCP server output for PLCs (its task and its metric families);
//! [`commission`] the commissioning commands on a Modbus line; [`sim`] the simulated modules.
//! `crate::protocols` registers it (one line of `STANDARD`: [`config::protocol::PROTOCOL`] and
//! [`driver::spawn`]); `config/protocols/` and `config/buses.rs` name its serving output.

pub mod commission;
pub mod config;
pub mod driver;
pub mod server;
pub mod sim;
