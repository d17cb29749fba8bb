//! Wired M-Bus, everything the gateway knows of it in one folder, each part at the floor of
//! the layer it implements: [`config`] its line, a meter's address and the checks of
//! `[buses.NAME]`; [`driver`] the pure protocol layer (frames, telegrams, records) and on it
//! the master ([`driver::master`], the driver under the bus core); [`commission`] scanning and
//! reading meters; [`sim`] simulated meters and segments. `crate::protocols` registers it
//! (one line of `STANDARD`: [`config::protocol::PROTOCOL`] and [`driver::master::spawn`]).

pub mod commission;
pub mod config;
pub mod driver;
pub mod sim;
