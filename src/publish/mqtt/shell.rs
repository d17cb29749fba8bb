//! The outbox and the client it feeds: what the MQTT task hands rumqttc, and what a
//! connection's start and loss do to them.

use tokio::time::Instant;

use super::link::Connection;
use crate::outbox::{Message, Outbox, Step};
use crate::publish::lifecycle::Stage;
use crate::publish::session::{Client, EventLoop, Options, REQUESTS, WINDOW};
use crate::publish::spool::Spool;
use crate::topics::Topics;

/// The outbox and the client it feeds, owned by the MQTT task.
pub(super) struct Shell {
    pub(super) outbox: Outbox<Spool>,
    pub(super) client: Client,
    pub(super) topics: Topics,
    /// The formats' own filters (Home Assistant's status, say), renewed at every connection.
    pub(super) extra_filters: Vec<String>,
    /// The last pump stopped at a full window or queue, not at the end of the outbox: the
    /// next acknowledgement lets more out.
    pub(super) backlog: bool,
}

impl Shell {
    pub(super) fn new(spool: Spool, client: Client, topics: Topics) -> Shell {
        Shell {
            outbox: Outbox::new(spool, WINDOW, Instant::now()),
            client,
            topics,
            extra_filters: Vec::new(),
            backlog: false,
        }
    }

    /// Hands rumqttc what the outbox says, until it says wait or rumqttc's queue is full. Each
    /// stored message passes the formats' last look on its way ([`Stage::outgoing`]).
    pub(super) fn pump(&mut self, stage: &mut Stage) {
        let now = Instant::now();
        self.backlog = false;
        if stage.held().is_some() {
            return;
        }
        while let Some(step) = self.outbox.next(now) {
            match step {
                Step::Send { entry: e, replay } => {
                    let corr = e.correlation.as_deref();
                    let payload = stage
                        .outgoing(&e.topic, &e.payload, replay)
                        .unwrap_or(e.payload);
                    if self
                        .client
                        .publish(e.topic, e.qos, e.retain, payload, corr)
                        .is_err()
                    {
                        self.outbox.refused(); // more when it sends
                        stage.unsent();
                        self.backlog = true;
                        break;
                    }
                }
                Step::Dropped { topic, why } => {
                    tracing::error!(%topic, "message dropped, it can never be sent: {why}");
                }
            }
        }
        self.backlog |= self.outbox.backlogged();
    }

    /// Into the outbox (and its spool) without handing anything to rumqttc yet. Storing
    /// never fails: a message the disk refuses waits in memory or is dropped and counted.
    pub(super) fn queue(&mut self, message: Message) {
        let Ok(_) = self.outbox.enqueue(message);
    }

    /// A publish outside the outbox (boot marker, what formats say at connect and at stop).
    /// Counted as direct only when rumqttc took it: a send event that never comes would be
    /// taken for the next stored message's, whose acknowledgement would then never count.
    pub(super) fn publish_direct(&mut self, m: Message) {
        let topic: String = m.topic.chars().take(200).collect();
        match self
            .client
            .publish(m.topic, m.qos, m.retain, m.payload, None)
        {
            Ok(()) => self.outbox.direct(),
            Err(e) => tracing::error!(%topic, "not published, the client's queue is full: {e}"),
        }
    }

    pub(super) fn subscribe(&self, filter: &str) {
        if let Err(e) = self.client.subscribe(filter.to_string()) {
            tracing::error!("cannot subscribe to {filter}: {e}");
        }
    }

    /// Connected: the formats say so before the backlog, subscriptions are restored (clean
    /// session); the caller sends the backlog.
    pub(super) fn on_connack(
        &mut self,
        max_packet: Option<u32>,
        link: &Connection,
        stage: &mut Stage,
    ) {
        self.outbox.connected(max_packet, Instant::now());
        if link.voice {
            // The boot marker: subscribe first, so the retained one of another gateway arrives
            // before ours replaces it.
            let marker = self.topics.gateway_marker();
            self.subscribe(&marker);
            let boot = link.boot.marker(&link.client_id, &link.config_hash);
            self.publish_direct(Message::new(marker, boot, 1, true));
        }
        for m in stage.connected() {
            self.publish_direct(m);
        }
        if link.commands || link.remote {
            let mut filters: Vec<(String, bool)> = Vec::new();
            if link.commands {
                filters.extend(
                    self.topics
                        .command_filters()
                        .into_iter()
                        .map(|f| (f, false)),
                );
            }
            if link.remote {
                filters.push((self.topics.config_set(), true));
            }
            if let Err(e) = self.client.subscribe_commands(&filters) {
                tracing::error!("cannot subscribe to command topics: {e}");
            }
        }
        for f in &self.extra_filters {
            self.subscribe(f);
        }
    }

    /// The connection failed: everything rumqttc held goes with it (the outbox sends it again,
    /// in order, on the fresh connection, which leaves the formats' current will).
    pub(super) fn on_lost(&mut self, options: &Options, stage: &mut Stage) -> EventLoop {
        self.outbox.lost();
        stage.disconnected();
        let (client, fresh) = options.connect(stage.will().as_ref(), REQUESTS);
        self.client = client;
        fresh
    }
}
