//! Fault injection for the watchdog test, compiled only with the `test-hooks` feature (which
//! only the test build turns on: the package's dev-dependency on itself; a release or
//! `cargo build` binary has none of this). `PULSEGATE_TEST_STALL_BUS=<bus>:<seconds>` makes
//! that bus loop stop making progress after so long, as a stuck loop would.

use std::time::Duration;

use tokio_util::sync::CancellationToken;

/// How long after its start bus `bus` stalls, if the environment asks for it.
pub(super) fn after(bus: &str) -> Option<Duration> {
    let v = std::env::var("PULSEGATE_TEST_STALL_BUS").ok()?;
    let (name, secs) = v.split_once(':')?;
    (name == bus).then(|| Duration::from_secs_f64(secs.parse().unwrap_or(0.0)))
}

/// Stops making progress (no heartbeat) until shutdown.
pub(super) async fn hang(bus: &str, shutdown: &CancellationToken) {
    tracing::error!(bus, "test hook: this bus loop now stalls");
    shutdown.cancelled().await;
}
