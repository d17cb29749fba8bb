//! Routes command messages from MQTT to the bus of their device, after every check that needs no
//! module, and publishes each result. Retained command messages are ignored: a stale retained
//! clear must not fire at every start.

use std::collections::{BTreeSet, HashMap};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use bytes::Bytes;
use tokio::sync::mpsc::{UnboundedReceiver, UnboundedSender};
use tokio::sync::oneshot;
use tokio::time::Instant;

use crate::bus::BusCommand;
use crate::command::{self, CommandError, Dedupe, Reply, Request, Seen};
use crate::config::Config;
use crate::reading::Output;

fn targets_of(
    config: &Config,
    buses: &HashMap<String, UnboundedSender<BusCommand>>,
) -> HashMap<String, Target> {
    config
        .devices()
        .filter_map(|(bus, d)| {
            let target = Target {
                bus: buses.get(&bus.name)?.clone(),
                commands: d.commands && d.enabled && bus.enabled,
                channels: d
                    .profile
                    .all_channels()
                    .into_iter()
                    .map(|c| c.name)
                    .collect(),
            };
            Some((d.name.clone(), target))
        })
        .collect()
}

/// A message that arrived on a command topic.
#[derive(Debug, Clone)]
pub struct Incoming {
    pub topic: String,
    pub payload: Bytes,
    pub retain: bool,
    pub response_topic: Option<String>,
    pub correlation: Option<Bytes>,
}

/// Where a device's commands go.
pub struct Target {
    bus: UnboundedSender<BusCommand>,
    commands: bool,
    channels: BTreeSet<String>,
}

/// How long a command waits for an offline device.
pub const EXPIRY: Duration = Duration::from_secs(10);

/// Devices by name, swapped whole when the config is reloaded.
pub type Targets = Arc<std::sync::RwLock<HashMap<String, Target>>>;

/// The command router of a gateway.
pub struct Router {
    root: String,
    targets: Targets,
    out: UnboundedSender<Output>,
    dedupe: Arc<Mutex<Dedupe>>,
}

impl Router {
    /// A router for `config`, sending to the bus command channels by bus name.
    pub fn new(
        config: &Config,
        buses: &HashMap<String, UnboundedSender<BusCommand>>,
        out: UnboundedSender<Output>,
    ) -> Router {
        Router {
            root: config.mqtt.topic_root.clone(),
            targets: Arc::new(std::sync::RwLock::new(targets_of(config, buses))),
            out,
            dedupe: Arc::default(),
        }
    }

    /// The router's device table, to update after a reload.
    pub fn targets(&self) -> Targets {
        self.targets.clone()
    }

    /// Points the router at the devices of a reloaded config.
    pub fn set_targets(
        targets: &Targets,
        config: &Config,
        buses: &HashMap<String, UnboundedSender<BusCommand>>,
    ) {
        *targets.write().unwrap_or_else(|e| e.into_inner()) = targets_of(config, buses);
    }

    /// Handles messages until the MQTT side closes the channel.
    pub async fn run(self, mut incoming: UnboundedReceiver<Incoming>) {
        while let Some(msg) = incoming.recv().await {
            self.handle(msg);
        }
    }

    fn handle(&self, msg: Incoming) {
        if msg.retain {
            tracing::info!(topic = %msg.topic, "ignoring a retained command message");
            return;
        }
        let Some((device, channel)) = command::parse_topic(&self.root, &msg.topic) else {
            return;
        };
        let mut reply = Reply {
            topics: vec![format!("{}/result", msg.topic)],
            correlation: msg.correlation.clone(),
        };
        if let Some(rt) = &msg.response_topic {
            reply.topics.push(rt.clone());
        }
        let parsed = match command::parse_payload(&msg.payload, channel.is_some()) {
            Ok(p) => p,
            Err((id, e)) => {
                tracing::warn!(topic = %msg.topic, "command refused: {e}");
                return self.answer(&reply, id.as_deref(), None, &Err(e));
            }
        };
        let op = parsed.op.name();
        let id = parsed.id.as_deref();
        if let Some(id) = id {
            let seen = self.dedupe.lock().unwrap_or_else(|e| e.into_inner()).check(
                &msg.topic,
                id,
                std::time::Instant::now(),
            );
            match seen {
                Seen::New => {}
                Seen::InFlight => return,
                Seen::Answered(result) => return self.send(&reply, result),
            }
        }
        let refuse = |e: CommandError| self.finish(&msg.topic, &reply, id, op, &Err(e));
        let targets = self.targets.read().unwrap_or_else(|e| e.into_inner());
        let Some(target) = targets.get(device) else {
            return refuse(CommandError::UnknownDevice(device.into()));
        };
        if !target.commands {
            return refuse(CommandError::Disabled(device.into()));
        }
        if let Some(ch) = channel
            && !target.channels.contains(ch)
        {
            return refuse(CommandError::UnknownChannel {
                device: device.into(),
                channel: ch.into(),
            });
        }
        let now = Instant::now();
        let (done, result) = oneshot::channel();
        let request = Request {
            device: device.into(),
            channel: channel.map(Into::into),
            op: parsed.op,
            id: parsed.id.clone(),
            reply: reply.clone(),
            received: now,
            expires: now + EXPIRY,
        };
        if target.bus.send(BusCommand { request, done }).is_err() {
            return refuse(CommandError::Offline(device.into()));
        }
        let out = self.out.clone();
        let dedupe = self.dedupe.clone();
        let topic = msg.topic.clone();
        let id = parsed.id.clone();
        tokio::spawn(async move {
            let outcome = result
                .await
                .unwrap_or_else(|_| Err(CommandError::Offline("gateway stopping".into())));
            let json = command::result_json(id.as_deref(), Some(op), &outcome);
            if let Some(id) = &id {
                dedupe
                    .lock()
                    .unwrap_or_else(|e| e.into_inner())
                    .answered(&topic, id, json.clone());
            }
            let _ = out.send(Output::CommandResult {
                topics: reply.topics,
                correlation: reply.correlation,
                payload: json,
            });
        });
    }

    fn finish(
        &self,
        topic: &str,
        reply: &Reply,
        id: Option<&str>,
        op: &str,
        outcome: &Result<Option<i64>, CommandError>,
    ) {
        if let Err(e) = outcome {
            tracing::warn!(%topic, "command refused: {e}");
        }
        let json = command::result_json(id, Some(op), outcome);
        if let Some(id) = id {
            self.dedupe
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .answered(topic, id, json.clone());
        }
        self.send(reply, json);
    }

    fn answer(
        &self,
        reply: &Reply,
        id: Option<&str>,
        op: Option<&str>,
        outcome: &Result<Option<i64>, CommandError>,
    ) {
        self.send(reply, command::result_json(id, op, outcome));
    }

    fn send(&self, reply: &Reply, payload: serde_json::Value) {
        let _ = self.out.send(Output::CommandResult {
            topics: reply.topics.clone(),
            correlation: reply.correlation.clone(),
            payload,
        });
    }
}
