//! Where and how an output's next connection is made: which of its brokers (`mqtt.hosts`,
//! round robin after the connection has failed for `failover_after`, or at once when asked),
//! which protocol (`mqtt.protocol = "auto"`: MQTT 5, and 3.1.1 after a broker refused 5 or
//! closed the connection without a CONNACK), and with which TLS files (read again when they
//! change: the next connection uses them; a set that does not load keeps the old one). A state
//! machine: failures, connections and times in, options and what to log out.

use std::path::PathBuf;
use std::time::SystemTime;

use tokio::time::Instant;

use super::session::{Failure, Options, client_options_as};
use crate::config::{Mqtt, MqttProtocol};

/// The protocol spoken on the wire (never `Auto`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Wire {
    V5,
    V311,
}

impl Wire {
    fn protocol(self) -> MqttProtocol {
        match self {
            Wire::V5 => MqttProtocol::V5,
            Wire::V311 => MqttProtocol::V311,
        }
    }

    fn name(self) -> &'static str {
        match self {
            Wire::V5 => "MQTT 5",
            Wire::V311 => "MQTT 3.1.1",
        }
    }
}

/// Something the dialer decided that the log should say.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Said {
    /// The broker did not take MQTT 5: the next attempt speaks 3.1.1 (or the other way).
    Fallback { broker: String, to: &'static str },
    /// Connected with `auto`: the broker speaks this one.
    Speaks {
        broker: String,
        protocol: &'static str,
    },
    /// The connection failed for long enough (or the host asked): the next broker.
    MovedOn {
        from: String,
        to: String,
        why: String,
    },
    /// The TLS files changed and load: the next connection uses them.
    TlsReloaded,
    /// The TLS files changed but do not load: the previous ones are kept.
    TlsRefused(String),
}

/// The connection settings of one output and the choices made on them.
pub struct Dialer {
    config: Mqtt,
    client_id: String,
    /// Index into `config.servers()`.
    at: usize,
    /// Per server: the protocol of the next attempt, and whether it ever answered with it.
    wire: Vec<(Wire, bool)>,
    /// The connection has failed since then (none while connected).
    failing_since: Option<Instant>,
    /// The options of the current server and protocol, built with the TLS files of `tls_seen`.
    options: Options,
    tls_seen: Option<Vec<Option<SystemTime>>>,
}

impl Dialer {
    /// A dialer over `config`, connecting as `config.client_id`.
    pub fn new(config: &Mqtt) -> Result<Dialer, crate::config::tls::TlsError> {
        let first = match config.protocol {
            MqttProtocol::V311 => Wire::V311,
            MqttProtocol::V5 | MqttProtocol::Auto => Wire::V5,
        };
        let servers = config.servers().len();
        let options = build(config, 0, first, &config.client_id)?;
        Ok(Dialer {
            client_id: config.client_id.clone(),
            wire: vec![(first, false); servers],
            config: config.clone(),
            at: 0,
            failing_since: None,
            options,
            tls_seen: tls_stamps(config),
        })
    }

    /// The options of the next connection.
    pub fn options(&self) -> &Options {
        &self.options
    }

    /// The broker of the next connection, as logs name it.
    pub fn broker(&self) -> String {
        broker_name(&self.config, self.at)
    }

    /// Connected: failures start afresh; with `auto`, the first answer says which protocol
    /// this broker speaks.
    pub fn connected(&mut self) -> Option<Said> {
        self.failing_since = None;
        let (wire, answered) = &mut self.wire[self.at];
        let first = !std::mem::replace(answered, true);
        (first && self.config.protocol == MqttProtocol::Auto).then(|| Said::Speaks {
            broker: broker_name(&self.config, self.at),
            protocol: wire.name(),
        })
    }

    /// The connection failed with `why` at `now`: the protocol or the broker of the next
    /// attempt may change. What to log, if anything.
    pub fn failed(&mut self, why: &Failure, now: Instant) -> Vec<Said> {
        let mut said = Vec::new();
        let since = *self.failing_since.get_or_insert(now);
        if self.config.protocol == MqttProtocol::Auto && no_answer_to_connect(why) {
            let (wire, answered) = &mut self.wire[self.at];
            if !*answered {
                *wire = match wire {
                    Wire::V5 => Wire::V311,
                    Wire::V311 => Wire::V5,
                };
                said.push(Said::Fallback {
                    broker: broker_name(&self.config, self.at),
                    to: wire.name(),
                });
            }
        }
        let servers = self.wire.len();
        if servers > 1 && now.saturating_duration_since(since) >= self.config.failover_after {
            let waited = self.config.failover_after.as_secs();
            said.push(self.move_on(now, format!("no connection for {waited} s: {why}")));
        }
        if let Some(s) = self.rebuild() {
            said.push(s);
        }
        said
    }

    /// Moves to the next broker now (Sparkplug's `Node Control/Next Server`, or a primary host
    /// offline on this one); with one broker it stays.
    pub fn next_server(&mut self, now: Instant, why: &str) -> Option<Said> {
        if self.wire.len() < 2 {
            return None;
        }
        let said = self.move_on(now, why.to_string());
        let _ = self.rebuild();
        Some(said)
    }

    fn move_on(&mut self, now: Instant, why: String) -> Said {
        let from = broker_name(&self.config, self.at);
        self.at = (self.at + 1) % self.wire.len();
        self.failing_since = Some(now);
        Said::MovedOn {
            from,
            to: broker_name(&self.config, self.at),
            why,
        }
    }

    /// Rebuilds the options for the current broker and protocol, with the TLS files as they are
    /// now (when they changed and load); what to log about the files.
    pub fn rebuild(&mut self) -> Option<Said> {
        let stamps = tls_stamps(&self.config);
        let tls_changed = stamps != self.tls_seen;
        let (wire, _) = self.wire[self.at];
        match build(&self.config, self.at, wire, &self.client_id) {
            Ok(o) => {
                self.options = o;
                self.tls_seen = stamps;
                tls_changed.then_some(Said::TlsReloaded)
            }
            Err(e) if tls_changed => {
                // Not again at every attempt: the same files are refused once.
                self.tls_seen = stamps;
                Some(Said::TlsRefused(e.to_string()))
            }
            Err(_) => None,
        }
    }

    /// The TLS files of this connection (for expiry metrics).
    pub fn tls_files(&self) -> Vec<PathBuf> {
        let Some(tls) = &self.config.tls else {
            return Vec::new();
        };
        let mut files = vec![tls.ca_file.clone()];
        files.extend(tls.cert_file.iter().cloned());
        files
    }
}

/// A failure that means the broker took the TCP connection but never answered MQTT 5's
/// CONNECT (refused the version, closed, or kept silent): what a 3.1.1-only broker does.
fn no_answer_to_connect(why: &Failure) -> bool {
    match why {
        Failure::ProtocolRefused => true,
        Failure::Other(text) => {
            let t = text.to_ascii_lowercase();
            (t.contains("timeout") && !t.contains("refused"))
                || t.contains("connection reset")
                || t.contains("unexpected eof")
                || t.contains("connection closed")
                || t.contains("connection aborted")
        }
        _ => false,
    }
}

fn broker_name(config: &Mqtt, at: usize) -> String {
    if let Some(socket) = &config.socket {
        return socket.display().to_string();
    }
    let (host, port) = &config.servers()[at];
    format!("{host}:{port}")
}

/// The options for server `at` speaking `wire`.
fn build(
    config: &Mqtt,
    at: usize,
    wire: Wire,
    client_id: &str,
) -> Result<Options, crate::config::tls::TlsError> {
    let mut c = config.clone();
    (c.host, c.port) = config.servers()[at].clone();
    c.protocol = wire.protocol();
    client_options_as(&c, client_id)
}

/// When each TLS file was last changed (none: no TLS).
fn tls_stamps(config: &Mqtt) -> Option<Vec<Option<SystemTime>>> {
    let tls = config.tls.as_ref()?;
    let files = [
        Some(&tls.ca_file),
        tls.cert_file.as_ref(),
        tls.key_file.as_ref(),
    ];
    Some(
        files
            .into_iter()
            .flatten()
            .map(|f| std::fs::metadata(f).and_then(|m| m.modified()).ok())
            .collect(),
    )
}

#[cfg(test)]
#[path = "dialer_tests.rs"]
mod tests;
