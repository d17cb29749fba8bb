//! The protocol seam: what the bus task asks of a protocol. The bus task keeps the schedule,
//! availability, command priority, stats and state flushing; a driver discovers a device, polls
//! it and carries out clear/preset on it, and reports what the wire did. Modbus RTU/TCP
//! ([`Modbus`]) is the one driver today; a new protocol is a new implementation of [`Driver`].

use std::time::Duration;

use super::device::{DeviceRt, PollError};
use super::execute::Executed;
use super::link::{Link, WireCounters};
use crate::command::Request;
use crate::reading::Reading;

/// Asked between transactions: `true` when a command waits and the poll should give way.
pub type Preempt<'a> = &'a (dyn Fn() -> bool + Sync);

/// One protocol on one bus.
#[allow(async_fn_in_trait)] // used by the bus task only, never as a trait object across threads
pub trait Driver {
    /// Learns what the device is when due (identity, work modes, the registers a poll needs).
    async fn discover(
        &mut self,
        device: &mut DeviceRt,
        preempt: Preempt<'_>,
    ) -> Result<(), PollError>;
    /// One poll of a device (discovering it first when due): its readings.
    async fn poll(
        &mut self,
        device: &mut DeviceRt,
        preempt: Preempt<'_>,
    ) -> Result<Vec<Reading>, PollError>;
    /// Carries out a clear or preset (the device is discovered and online).
    async fn execute(&mut self, device: &mut DeviceRt, request: &Request) -> Executed;
    /// What the wire did so far: transactions, timeouts, errors, and the time it was busy.
    fn wire(&self) -> (WireCounters, Duration);
    /// A fault of the line itself (port gone, connection refused), as opposed to one device.
    fn is_line_fault(&self, e: &PollError) -> bool;
    /// Closes the port or connection at shutdown.
    fn close(&mut self);
}

/// Modbus RTU or TCP over one [`Link`].
pub struct Modbus {
    pub link: Link,
}

impl Driver for Modbus {
    async fn discover(
        &mut self,
        device: &mut DeviceRt,
        preempt: Preempt<'_>,
    ) -> Result<(), PollError> {
        device.discover(&mut self.link, preempt).await
    }

    async fn poll(
        &mut self,
        device: &mut DeviceRt,
        preempt: Preempt<'_>,
    ) -> Result<Vec<Reading>, PollError> {
        device.poll(&mut self.link, preempt).await
    }

    async fn execute(&mut self, device: &mut DeviceRt, request: &Request) -> Executed {
        device.execute(&mut self.link, request).await
    }

    fn wire(&self) -> (WireCounters, Duration) {
        (self.link.counters, self.link.busy)
    }

    fn is_line_fault(&self, e: &PollError) -> bool {
        matches!(e, PollError::Link(l) if l.is_line_fault())
    }

    fn close(&mut self) {
        self.link.close();
    }
}
