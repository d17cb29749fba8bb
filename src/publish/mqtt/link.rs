//! What a connection is built from and announces, and what the log says of it (once per state
//! change; takeovers and dropped chatter at most once a minute).

use std::time::Duration;

use tokio::time::Instant;

use crate::publish::dialer::Dialer;
use crate::publish::session::Failure;

/// What a fresh client is built from, and what it announces.
pub(super) struct Connection {
    /// Which broker, protocol and TLS files the next connection uses.
    pub(super) dialer: Dialer,
    /// The broker of the current (or next) connection, as logs name it.
    pub(super) broker: String,
    pub(super) client_id: String,
    /// Subscribe to command topics (the voice's, with `mqtt.commands`).
    pub(super) commands: bool,
    /// Carries the gateway's voice: publishes and watches the boot marker.
    pub(super) voice: bool,
    /// Takes pushed configs (`<root>/config/set`, `[remote] config = true`).
    pub(super) remote: bool,
    /// This run's boot id, published retained on `<root>/gateway`.
    pub(super) boot: crate::boot::Boot,
    /// The hash of the config in force, in that marker.
    pub(super) config_hash: String,
}

/// Logs of the connection: once per state change, takeovers at most once a minute.
pub(super) struct Watch {
    pub(super) up: Option<bool>,
    /// Chatter dropped when last logged, and the budget of those lines.
    pub(super) chatter_dropped: u64,
    pub(super) chatter_log: crate::log_budget::LogBudget,
    pub(super) takeovers: u64,
    pub(super) takeover_log: crate::log_budget::LogBudget,
    /// Wait before the next attempt after a failure.
    pub(super) pause: Duration,
    /// The broker's refusal of MQTT 5 was logged (once a run: it will not change by itself).
    pub(super) protocol_named: bool,
    /// This machine's previous run was recognised by its marker (said once).
    pub(super) earlier_run_named: bool,
    /// Messages too large to take: at most one line a minute, the rest counted in it.
    pub(super) too_large_log: crate::log_budget::LogBudget,
}

impl Watch {
    pub(super) fn new() -> Watch {
        Watch {
            up: None,
            chatter_dropped: 0,
            chatter_log: crate::log_budget::LogBudget::new(1),
            takeovers: 0,
            takeover_log: crate::log_budget::LogBudget::new(1),
            pause: Duration::from_secs(1),
            protocol_named: false,
            earlier_run_named: false,
            too_large_log: crate::log_budget::LogBudget::new(1),
        }
    }

    /// Chatter was dropped since the last look: said at most once a minute, with the count.
    pub(super) fn chatter_dropped(&mut self, dropped: u64, now: Instant) {
        if dropped > self.chatter_dropped && self.chatter_log.allow(now).0 {
            let n = dropped - self.chatter_dropped;
            tracing::warn!(
                dropped = n,
                "{n} command results, discovery configs or bus stats dropped: they came faster than the broker took them (readings are never dropped for them)"
            );
            self.chatter_dropped = dropped;
        }
    }

    /// A message larger than the gateway takes was dropped unread (rumqttc skipped it and
    /// acknowledged it): said within budget, with how many went unsaid in the last minute. A
    /// retained one comes back at every connection; the connection stays up.
    pub(super) fn too_large(&mut self, topic: &str, size: usize, link: &Connection, now: Instant) {
        let (log, unsaid) = self.too_large_log.allow(now);
        if !log {
            return;
        }
        let more = match unsaid {
            Some(n) => format!("; {n} more were dropped since the last such line"),
            None => String::new(),
        };
        let max_kib = crate::publish::session::MAX_PACKET / 1024;
        tracing::warn!(broker = %link.broker, topic, size, "dropped an MQTT message of {size} bytes on {topic}: larger than the packets of {max_kib} KiB the gateway takes; the connection stays up (a retained one comes back at each connection until it is cleared on the broker){more}");
    }

    /// A boot marker arrived: another gateway's is logged (within budget); this machine's
    /// previous run, which `boot.json` did not record, is said once as what it is.
    pub(super) fn marker(&mut self, payload: &[u8], link: &Connection) {
        match link.boot.judge(payload) {
            crate::boot::Marker::Ours => {}
            crate::boot::Marker::EarlierRun(earlier) => {
                if !std::mem::replace(&mut self.earlier_run_named, true) {
                    tracing::info!(earlier = %earlier, "the boot marker on the topic root is this machine's previous run (same host, its process is gone), which boot.json did not record: not another gateway");
                }
            }
            crate::boot::Marker::Foreign(other) => {
                let (log, _) = self.takeover_log.allow(Instant::now());
                if log {
                    tracing::error!(other = %other, "another gateway publishes under this topic root (its boot marker is not ours): two gateways share gateway.id or mqtt.topic_root, so both receive each other's commands and, with one client id, take each other's MQTT session; give each gateway its own id");
                }
            }
        }
    }

    /// A connection failure: logged once per state change (takeovers each time, within
    /// budget); a takeover backs off so two gateways do not fight over the id every second.
    pub(super) fn failed(&mut self, e: &Failure, link: &Connection) {
        if matches!(e, Failure::TakenOver) {
            self.takeovers += 1;
            let (log, _) = self.takeover_log.allow(Instant::now());
            if log {
                tracing::error!(client_id = %link.client_id, takeovers = self.takeovers, "the broker dropped this connection because another client connected with the same client id: is a second gateway using mqtt.client_id {:?}? Both would receive each other's commands", link.client_id);
            }
            self.pause = (self.pause * 2).clamp(Duration::from_secs(5), Duration::from_secs(60));
        } else if matches!(e, Failure::ProtocolRefused) {
            if !std::mem::replace(&mut self.protocol_named, true) {
                tracing::error!(broker = %link.broker, "MQTT broker refused the connection: {e}");
            }
        } else if self.up != Some(false) {
            tracing::warn!(broker = %link.broker, "MQTT broker unreachable: {e}; reconnecting with a fresh client, readings are spooled");
        }
        self.up = Some(false);
    }
}
