//! systemd integration through sd-notify (pure Rust): READY=1 once every bus has opened its
//! line (or tried to), STATUS= with a one-line summary, WATCHDOG=1 only while every bus loop and
//! the MQTT task make progress, STOPPING=1 at shutdown. Without NOTIFY_SOCKET all of it is a
//! no-op.

use std::sync::Arc;
use std::time::Duration;

use sd_notify::NotifyState;
use tokio::time::Instant;
use tokio_util::sync::CancellationToken;

use crate::health::Health;

/// The longest the gateway waits for its buses before telling systemd it is ready anyway (a
/// serial port that cannot be opened must not keep the service from starting: the status says
/// which bus is down).
const READY_AT_THE_LATEST: Duration = Duration::from_secs(10);

fn notify(states: &[NotifyState]) {
    if let Err(e) = sd_notify::notify(false, states) {
        tracing::debug!("sd_notify: {e}");
    }
}

/// The watchdog period systemd asked for (`WATCHDOG_USEC`), unless `WATCHDOG_PID` names another
/// process (as libsystemd's `sd_watchdog_enabled` reads them).
fn watchdog_period() -> Option<Duration> {
    let usec: u64 = std::env::var("WATCHDOG_USEC").ok()?.parse().ok()?;
    if let Ok(pid) = std::env::var("WATCHDOG_PID")
        && pid.parse::<u32>().ok() != Some(std::process::id())
    {
        return None;
    }
    (usec > 0).then(|| Duration::from_micros(usec))
}

/// Runs until `shutdown`, then says STOPPING=1.
pub async fn supervise(health: Arc<Health>, shutdown: CancellationToken) {
    let watchdog = watchdog_period();
    // Feed at a quarter of the period; a loop silent for half of it is stuck.
    let tick = watchdog.map_or(Duration::from_secs(1), |w| {
        (w / 4).clamp(Duration::from_millis(100), Duration::from_secs(1))
    });
    let stale_after = watchdog.map_or(Duration::from_secs(10), |w| {
        (w / 2).max(Duration::from_secs(3))
    });
    let started = Instant::now();
    let mut ready = false;
    let mut last_status = String::new();
    let mut was_stale: Vec<String> = Vec::new();
    let mut interval = tokio::time::interval(tick);
    loop {
        tokio::select! {
            _ = interval.tick() => {}
            () = shutdown.cancelled() => break,
        }
        // The same truth as `/healthz`: what is not well leads the line.
        let status = match health.verdict(stale_after) {
            Ok(line) => line,
            Err(why) => format!("degraded: {why}"),
        };
        if !ready && (health.all_started() || started.elapsed() >= READY_AT_THE_LATEST) {
            ready = true;
            tracing::info!("ready: {status}");
            notify(&[NotifyState::Ready, NotifyState::Status(&status)]);
            last_status = status.clone();
        } else if ready && status != last_status {
            notify(&[NotifyState::Status(&status)]);
            last_status = status;
        }
        if watchdog.is_some() && ready {
            let stale = health.stale(stale_after);
            if stale.is_empty() {
                notify(&[NotifyState::Watchdog]);
            } else if stale != was_stale {
                tracing::error!(loops = ?stale, "no progress: not feeding the watchdog, systemd will restart the service");
            }
            was_stale = stale;
        }
    }
    notify(&[NotifyState::Stopping, NotifyState::Status("stopping")]);
}
