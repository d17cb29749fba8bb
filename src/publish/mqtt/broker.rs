//! The broker side of an output's task: a failed or stalled connection rebuilt, the next
//! broker, the TLS files and certificates, what the dialer decided said in the log.

use std::time::Duration;

use tokio::time::Instant;

use super::{Poller, Publisher};
use crate::outbox::Message;
use crate::publish::dialer::Said;
use crate::publish::session::Failure;

/// How long before a certificate expires the log and the status warn of it.
const EXPIRY_WARNING: Duration = Duration::from_secs(30 * 86_400);

impl Publisher<'_> {
    /// The connection failed or stalled: everything rumqttc held goes with it, a fresh client
    /// connects after the back-off (the outbox sends again, in order, what was not acked).
    pub(super) fn reconnect(&mut self, why: &Failure) {
        self.watch.failed(why, &self.link);
        self.task.heart.set_up(false);
        self.task.heart.set_error(why.to_string());
        let pinned = self.task.config.protocol != crate::config::MqttProtocol::Auto;
        if pinned && matches!(why, Failure::ProtocolRefused) {
            self.task.heart.set_problem(Some(why.to_string()));
        }
        for said in self.link.dialer.failed(why, Instant::now()) {
            self.say(&said);
        }
        self.link.broker = self.link.dialer.broker();
        let eventloop = self
            .shell
            .on_lost(self.link.dialer.options(), &mut self.stage);
        self.poller = Poller::start(eventloop, self.watch.pause, self.routes.clone());
        self.settle(Instant::now());
    }
    /// Moves to the next broker at once (with one broker: stays), the connection rebuilt.
    pub(super) fn move_on(&mut self, why: &str) {
        let Some(said) = self.link.dialer.next_server(Instant::now(), why) else {
            tracing::warn!(output = %self.task.name, "{why}, but this output has one broker (mqtt.hosts)");
            return;
        };
        self.say(&said);
        self.link.broker = self.link.dialer.broker();
        self.task.heart.set_up(false);
        let eventloop = self
            .shell
            .on_lost(self.link.dialer.options(), &mut self.stage);
        self.poller = Poller::start(eventloop, Duration::ZERO, self.routes.clone());
        self.settle(Instant::now());
    }
    /// Held on this broker (a Sparkplug primary host offline) for `failover_after`: the next
    /// broker, as Sparkplug 3.0 has a node do (its host may be on another server).
    pub(super) fn held_on_this_broker(&mut self, held: bool, now: Instant) {
        if !held || !self.shell.outbox.is_connected() {
            self.held_since = None;
            return;
        }
        let since = *self.held_since.get_or_insert(now);
        let servers = self.task.config.servers().len();
        if servers > 1 && now.saturating_duration_since(since) >= self.task.config.failover_after {
            self.held_since = None;
            self.move_on(
                "held on this broker for mqtt.failover_after (its primary host is offline here)",
            );
        }
    }
    /// A config with another hash is in force: the boot marker says so at once.
    pub(super) fn new_config_hash(&mut self, hash: String) {
        if hash == self.link.config_hash {
            return;
        }
        self.link.config_hash = hash;
        if self.link.voice && self.shell.outbox.is_connected() {
            let marker = self.shell.topics.gateway_marker();
            let boot = self
                .link
                .boot
                .marker(&self.link.client_id, &self.link.config_hash);
            self.shell
                .publish_direct(Message::new(marker, boot, 1, true));
        }
    }
    /// The TLS files read again when they changed (logged; a set that does not load keeps the
    /// one in use).
    pub(super) fn refresh_tls(&mut self) {
        if let Some(said) = self.link.dialer.rebuild() {
            self.say(&said);
        }
    }
    /// The expiry of this connection's certificates, as metrics; a warning in the log and the
    /// status within [`EXPIRY_WARNING`] of it (or after it).
    pub(super) fn check_certificates(&self) {
        let now = crate::reading::unix_ms(std::time::SystemTime::now()) as i64 / 1000;
        let mut soon = Vec::new();
        for file in self.link.dialer.tls_files() {
            let shown = file.display().to_string();
            match crate::config::tls::expiry(&file) {
                Ok(at) => {
                    self.task.metrics.tls_expiry(&shown, at);
                    let days = (at - now) / 86_400;
                    if at - now < EXPIRY_WARNING.as_secs() as i64 {
                        soon.push(format!("TLS certificate {shown} expires in {days} days"));
                    }
                }
                Err(e) => {
                    tracing::warn!(output = %self.task.name, "cannot read the expiry of {shown}: {e}")
                }
            }
        }
        for s in &soon {
            tracing::warn!(output = %self.task.name, "{s}: renew it (the gateway reads new files at its next connection)");
        }
        self.task
            .heart
            .set_note((!soon.is_empty()).then(|| soon.join(", ")));
    }
    /// Logs what the dialer decided.
    pub(super) fn say(&self, said: &Said) {
        let output = &self.task.name;
        match said {
            Said::Fallback { broker, to } => {
                tracing::warn!(%output, %broker, "the broker did not answer this protocol's CONNECT (refused, closed or silent): trying {to} next (mqtt.protocol = \"auto\")")
            }
            Said::Speaks { broker, protocol } => {
                tracing::info!(%output, %broker, "the broker speaks {protocol}: connected with it (mqtt.protocol = \"auto\")")
            }
            Said::MovedOn { from, to, why } => {
                tracing::warn!(%output, "moving from broker {from} to {to}: {why}; what is spooled goes there, in order")
            }
            Said::TlsReloaded => {
                tracing::info!(%output, "TLS files changed: the next connection uses them");
                self.check_certificates();
            }
            Said::TlsRefused(e) => {
                tracing::error!(%output, "the changed TLS files do not load ({e}): the previous ones stay in use")
            }
        }
    }
}
