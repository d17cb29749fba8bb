//! Protocol drivers: one folder per protocol, each an implementation of
//! [`crate::bus::driver::Driver`] under the protocol-neutral bus task. [`spawn`] is the one
//! place that picks a bus's driver from its config (`config::Link`).

pub mod mbus;
pub mod modbus;

/// The log filter that keeps the protocol libraries' own logs to their errors (a late or
/// garbled answer is the driver's to count and say, not the library's to log at each frame).
pub const QUIET_LIBRARIES: &str = "tokio_modbus=error";

use tokio::sync::mpsc::Receiver;
use tokio::task::JoinHandle;
use tokio_util::sync::CancellationToken;

use crate::bus::BusTask;
use crate::config::{Bus, Link};
use crate::scan::ScanRequest;

/// Runs `task` over the driver of `bus`'s link until `shutdown`. A new protocol is a folder
/// beside `modbus/`, its folder under `config/protocols/` (with its `config::Link`
/// variant) and one arm here.
pub fn spawn(
    task: BusTask,
    bus: &Bus,
    scans: Receiver<ScanRequest>,
    shutdown: CancellationToken,
) -> JoinHandle<()> {
    match &bus.link {
        Link::Modbus(line) => {
            let driver = modbus::Modbus::for_bus(bus, line).with_scans(Some(scans));
            tokio::spawn(task.run(driver, shutdown))
        }
        Link::Mbus(line) => {
            let driver =
                crate::driver::mbus::master::Mbus::for_bus(bus, line).with_scans(Some(scans));
            tokio::spawn(task.run(driver, shutdown))
        }
    }
}
