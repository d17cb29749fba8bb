//! The board of a running gateway: the fan-out hands it every event, the HTTP endpoint asks it
//! for the API's JSON. The answer is made at most every [`FRESH`] and shared by every client
//! asking within that time (and by every open page's event stream), so fifty scripts or pages
//! cost the gateway one snapshot a second, not fifty.

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime};

use bytes::Bytes;

use super::board::{Board, Measured};
use crate::config::Config;
use crate::health::Health;
use crate::metrics::Metrics;
use crate::reading::{Output, unix_ms};

/// How long a made answer is handed out again.
pub const FRESH: Duration = Duration::from_secs(1);

/// A board and what it reads of the running gateway.
pub struct Live {
    board: Mutex<Board>,
    health: Arc<Health>,
    metrics: Metrics,
    made: Mutex<Option<(Instant, Bytes)>>,
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl Live {
    /// The board of a gateway that runs `config`, started now.
    pub fn new(config: &Config, health: Arc<Health>, metrics: Metrics) -> Live {
        let started = unix_ms(SystemTime::now()).saturating_sub(health.uptime().as_millis() as u64);
        Live {
            board: Mutex::new(Board::new(config, started)),
            health,
            metrics,
            made: Mutex::new(None),
        }
    }

    /// An event on its way to the outputs.
    pub fn hand(&self, event: &Output) {
        lock(&self.board).hand(event, unix_ms(SystemTime::now()));
    }

    /// A reloaded config.
    pub fn reconfigure(&self, config: &Config) {
        lock(&self.board).reconfigure(config);
        *lock(&self.made) = None;
    }

    /// `GET /api/v1/status`: the snapshot as JSON.
    pub fn json(&self) -> Bytes {
        let made = lock(&self.made);
        if let Some((at, body)) = made.as_ref() {
            if at.elapsed() < FRESH {
                return body.clone();
            }
        }
        drop(made);
        self.fresh_json()
    }

    /// The snapshot made now (the event stream's, once every [`FRESH`]), kept for the API.
    pub fn fresh_json(&self) -> Bytes {
        let body = Bytes::from(serde_json::to_vec(&self.status()).unwrap_or_default());
        *lock(&self.made) = Some((Instant::now(), body.clone()));
        body
    }

    /// The snapshot now.
    pub fn status(&self) -> super::view::Status {
        let devices = lock(&self.board).devices();
        let mut measured = Measured {
            uptime_s: self.health.uptime().as_secs(),
            loops: self.health.loops(),
            ..Measured::default()
        };
        for (bus, device) in devices {
            if let Some(look) = self.metrics.device_look(&bus, &device) {
                measured.devices.insert(device, look);
            }
            if let std::collections::btree_map::Entry::Vacant(e) = measured.buses.entry(bus) {
                if let Some(look) = self.metrics.bus_look(e.key()) {
                    e.insert(look);
                }
            }
        }
        lock(&self.board).status(unix_ms(SystemTime::now()), &measured)
    }
}
