//! The board of a running gateway, in a task of its own: the fan-out hands it every event, a
//! reload its new config, and once every [`FRESH`] it makes the snapshot (the API's JSON) with
//! what health and the metrics measure, shared through a `watch` by every client asking within
//! that time and by every open page's event stream: fifty scripts or pages cost the gateway one
//! snapshot a second, not fifty. The task owns the board: no lock.

use std::sync::Arc;
use std::time::{Duration, SystemTime};

use bytes::Bytes;
use tokio::sync::mpsc::{UnboundedReceiver, UnboundedSender, unbounded_channel};
use tokio::sync::watch;

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
}

/// The handle of the board's task: what feeds it and where its snapshot is.
pub struct Live {
    fed: UnboundedSender<Fed>,
    snapshot: watch::Receiver<Bytes>,
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
        let (snapshots, snapshot) = watch::channel(live.json());
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

    /// `GET /api/v1/status`: the latest snapshot as JSON.
    pub fn json(&self) -> Bytes {
        self.snapshot.borrow().clone()
    }

    /// Every new snapshot, as it is made.
    pub fn snapshots(&self) -> watch::Receiver<Bytes> {
        self.snapshot.clone()
    }
}

impl Keeper {
    /// Takes events and configs as they come, and makes the snapshot every [`FRESH`] and at
    /// once after a reload, until the handle is gone.
    async fn run(mut self, mut feed: UnboundedReceiver<Fed>, snapshots: watch::Sender<Bytes>) {
        let mut tick = tokio::time::interval(FRESH);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        loop {
            tokio::select! {
                fed = feed.recv() => match fed {
                    Some(Fed::Event(event)) => {
                        self.board.hand(&event, unix_ms(SystemTime::now()));
                        continue;
                    }
                    Some(Fed::Config(config)) => self.board.reconfigure(&config),
                    None => return,
                },
                _ = tick.tick() => {}
            }
            snapshots.send_replace(self.json());
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
        self.board.status(unix_ms(SystemTime::now()), &measured)
    }
}
