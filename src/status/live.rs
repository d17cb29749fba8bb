//! The board of a running gateway, in a task of its own: the fan-out hands it every event, a
//! reload its new config, and a client's ask makes the snapshot (the API's JSON) with what
//! health and the metrics measure. A snapshot is handed out again for [`FRESH`] and shared by
//! every client asking within that time and by every open page's event stream (a `watch`):
//! fifty scripts or pages cost the gateway one snapshot a second, not fifty. The task owns the
//! board: no lock.

use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime};

use bytes::Bytes;
use tokio::sync::mpsc::{UnboundedReceiver, UnboundedSender, unbounded_channel};
use tokio::sync::{oneshot, watch};

use super::board::{Board, Measured};
use crate::config::Config;
use crate::health::Health;
use crate::metrics::Metrics;
use crate::reading::{Output, unix_ms};

/// How often the snapshot is made.
pub const FRESH: Duration = Duration::from_secs(1);

/// What the board hears.
enum Fed {
    Event(Box<Output>),
    Config(Box<Config>),
    /// A client wants a snapshot and the last is older than [`FRESH`].
    Ask(oneshot::Sender<Bytes>),
}

/// A snapshot: when it was made, and its JSON.
pub type Snapshot = (Instant, Bytes);

/// The handle of the board's task: what feeds it and where its snapshot is.
pub struct Live {
    fed: UnboundedSender<Fed>,
    snapshot: watch::Receiver<Snapshot>,
}

/// What the board's task reads of the running gateway.
struct Keeper {
    board: Board,
    health: Arc<Health>,
    metrics: Metrics,
}

impl Live {
    /// Starts the board of a gateway that runs `config`; its task ends when the handle is
    /// dropped.
    pub fn start(config: &Config, health: Arc<Health>, metrics: Metrics) -> Live {
        let started = unix_ms(SystemTime::now()).saturating_sub(health.uptime().as_millis() as u64);
        let live = Keeper {
            board: Board::new(config, started),
            health,
            metrics,
        };
        // The first snapshot counts as old: the first ask makes one.
        let made = Instant::now()
            .checked_sub(FRESH)
            .unwrap_or_else(Instant::now);
        let (snapshots, snapshot) = watch::channel((made, live.json()));
        let (fed, feed) = unbounded_channel();
        tokio::spawn(live.run(feed, snapshots));
        Live { fed, snapshot }
    }

    /// An event on its way to the outputs.
    pub fn hand(&self, event: &Output) {
        let _ = self.fed.send(Fed::Event(Box::new(event.clone())));
    }

    /// A reloaded config.
    pub fn reconfigure(&self, config: &Config) {
        let _ = self.fed.send(Fed::Config(Box::new(config.clone())));
    }

    /// The latest snapshot as JSON, however old (at most [`FRESH`] while the task runs).
    pub fn json(&self) -> Bytes {
        self.snapshot.borrow().1.clone()
    }

    /// `GET /api/v1/status`: the latest snapshot when it is younger than [`FRESH`], else one
    /// made now, after every event handed so far (clients asking within a second share it).
    pub async fn fresh(&self) -> Bytes {
        let (made, body) = self.snapshot.borrow().clone();
        if made.elapsed() < FRESH {
            return body;
        }
        self.made_now().await
    }

    /// A snapshot made now, after every event handed so far (the event stream's, once every
    /// [`FRESH`] while a page is open).
    pub async fn made_now(&self) -> Bytes {
        let body = self.json();
        let (ask, answer) = oneshot::channel();
        if self.fed.send(Fed::Ask(ask)).is_err() {
            return body;
        }
        answer.await.unwrap_or(body)
    }

    /// Every new snapshot, as it is made.
    pub fn snapshots(&self) -> watch::Receiver<Snapshot> {
        self.snapshot.clone()
    }
}

impl Keeper {
    /// Takes events, configs and asks in the order they come, until the handle is gone: a
    /// snapshot is made only when asked, so it holds every event handed before the ask.
    async fn run(mut self, mut feed: UnboundedReceiver<Fed>, snapshots: watch::Sender<Snapshot>) {
        while let Some(fed) = feed.recv().await {
            match fed {
                Fed::Event(event) => self.board.hand(&event, unix_ms(SystemTime::now())),
                Fed::Config(config) => self.board.reconfigure(&config),
                Fed::Ask(answer) => {
                    let json = self.json();
                    snapshots.send_replace((Instant::now(), json.clone()));
                    let _ = answer.send(json);
                }
            }
        }
    }

    fn json(&self) -> Bytes {
        Bytes::from(serde_json::to_vec(&self.status()).unwrap_or_default())
    }

    /// The snapshot now.
    fn status(&self) -> super::view::Status {
        let devices = self.board.devices();
        let mut measured = Measured {
            uptime_s: self.health.uptime().as_secs(),
            loops: self.health.loops(),
            ..Measured::default()
        };
        let mut looks = self.metrics.device_looks();
        for (bus, device) in devices {
            if let Some(look) = looks.remove(&(bus.clone(), device.clone())) {
                measured.devices.insert(device, look);
            }
            if let std::collections::btree_map::Entry::Vacant(e) = measured.buses.entry(bus) {
                if let Some(look) = self.metrics.bus_look(e.key()) {
                    e.insert(look);
                }
            }
        }
        self.board.status(unix_ms(SystemTime::now()), &measured)
    }
}
