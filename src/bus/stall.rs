//! Fault injection for the watchdog test, compiled only with the `test-hooks` feature (which
//! only the test build turns on: the package's dev-dependency on itself; a release or
//! `cargo build` binary has none of this). `PULSEGATE_TEST_STALL_BUS=<bus>:<seconds>` makes
//! that bus loop stop making progress after so long, as a stuck loop would.
//!
//! The hook is a driver around the bus's driver ([`Stalling`]), put in place before the loop
//! starts: the production poll loop itself has no test code. A poll due after the stall begins
//! hangs until shutdown, so the loop beats no more, and then steps aside like a preempted poll.

use std::time::Duration;

use tokio::time::Instant;
use tokio_util::sync::CancellationToken;

use super::device::{DeviceRt, PollError};
use super::driver::{DeviceState, Driver, Executed, Failure, Idle, Preempt};
use crate::bus_health::WireCounters;
use crate::command::Request;
use crate::config::Bus;
use crate::sample::Sample;
use crate::state::BusState;

/// How long after its start bus `bus` stalls, if the environment asks for it.
fn after(bus: &str) -> Option<Duration> {
    let v = std::env::var("PULSEGATE_TEST_STALL_BUS").ok()?;
    let (name, secs) = v.split_once(':')?;
    (name == bus).then(|| Duration::from_secs_f64(secs.parse().unwrap_or(0.0)))
}

/// A driver that behaves as `inner` until `at`, then hangs in its next poll until `shutdown`.
pub(super) struct Stalling<D> {
    inner: D,
    at: Option<Instant>,
    bus: String,
    shutdown: CancellationToken,
}

impl<D: Driver> Stalling<D> {
    /// `driver` for bus `bus`, stalling if the environment asks for it (from now on).
    pub(super) fn wrap(driver: D, bus: &str, shutdown: &CancellationToken) -> Stalling<D> {
        Stalling {
            inner: driver,
            at: after(bus).map(|after| Instant::now() + after),
            bus: bus.to_string(),
            shutdown: shutdown.clone(),
        }
    }
}

impl<D: Driver> Driver for Stalling<D> {
    type Device = D::Device;

    fn device(&self, bus: &Bus, config: &crate::config::Device, saved: &BusState) -> D::Device {
        self.inner.device(bus, config, saved)
    }

    async fn poll(
        &mut self,
        device: &mut DeviceRt<D::Device>,
        preempt: Preempt<'_>,
    ) -> Result<Vec<Sample>, Failure<D>> {
        if self.at.is_some_and(|at| Instant::now() >= at) {
            tracing::error!(bus = %self.bus, "test hook: this bus loop now stalls");
            self.shutdown.cancelled().await;
            return Err(PollError::Preempted);
        }
        self.inner.poll(device, preempt).await
    }

    async fn execute(&mut self, device: &mut DeviceRt<D::Device>, request: &Request) -> Executed {
        self.inner.execute(device, request).await
    }

    fn wire(&self) -> (WireCounters, Duration) {
        self.inner.wire()
    }

    fn is_line_fault(&self, e: &PollError<<D::Device as DeviceState>::Error>) -> bool {
        self.inner.is_line_fault(e)
    }

    fn ready_for_commands(&self, device: &DeviceRt<D::Device>) -> bool {
        self.inner.ready_for_commands(device)
    }

    async fn idle(&mut self, idle: Idle<'_>) -> bool {
        self.inner.idle(idle).await
    }

    fn close(&mut self) {
        self.inner.close()
    }
}
