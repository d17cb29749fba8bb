//! The settings of one MQTT connection (`[mqtt]`, and each output's over it), as types only, so
//! the files that read, check and use them need not go through the whole config.

use std::fmt;
use std::path::PathBuf;
use std::time::Duration;

/// A secret (the MQTT password): never printed, never logged.
#[derive(Clone, PartialEq, Eq)]
pub struct Secret(pub String);

impl fmt::Debug for Secret {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("Secret(***)")
    }
}

/// `[mqtt.tls]`: TLS to the broker (rustls).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Tls {
    /// CA certificate(s) the broker's certificate must chain to (PEM).
    pub ca_file: PathBuf,
    /// Client certificate and key (PEM), for brokers that ask for one.
    pub cert_file: Option<PathBuf>,
    pub key_file: Option<PathBuf>,
}

/// `[mqtt]`: the broker connection of the gateway's own voice, and the defaults of every
/// output's (see `config::outputs`).
#[derive(Debug, Clone, PartialEq)]
pub struct Mqtt {
    /// Not used when `socket` is set.
    pub host: String,
    pub port: u16,
    /// `mqtt.socket`: a local broker's Unix domain socket, used instead of `host`/`port`
    /// (no TCP port: the socket file's permissions decide who may connect).
    pub socket: Option<PathBuf>,
    pub client_id: String,
    pub username: Option<String>,
    /// From `password`, `password_file`, `PULSEGATE__MQTT__PASSWORD`, or the systemd credential
    /// `mqtt-password` (`LoadCredential=`).
    pub password: Option<Secret>,
    pub tls: Option<Tls>,
    pub keep_alive: Duration,
    pub qos: u8,
    pub retain: bool,
    pub topic_root: String,
    /// Bound of the store-and-forward spool (memory and disk), in bytes.
    pub spool_bytes: u64,
    /// Subscribe to command topics at all (`false`: a read-only site, no clear or preset from
    /// MQTT whatever the devices say).
    pub commands: bool,
    /// `mqtt.protocol`: "auto" (default: MQTT 5, else 3.1.1), "5" or "3.1.1".
    pub protocol: MqttProtocol,
    /// `mqtt.hosts` after the first (which is `host`/`port`): the brokers to move to, round
    /// robin, after the connection has failed for `failover_after`.
    pub failover: Vec<(String, u16)>,
    /// `mqtt.failover_after`: how long the connection may fail before the next broker is tried.
    pub failover_after: Duration,
    /// `mqtt.batch`: how long readings may wait to go to the broker with the next polls' (see
    /// [`crate::publish::batch`]); zero sends each poll's at once.
    pub batch: Duration,
}

impl Mqtt {
    /// Every broker this connection may use, in order: `host:port`, then the failover hosts.
    pub fn servers(&self) -> Vec<(String, u16)> {
        let mut all = vec![(self.host.clone(), self.port)];
        all.extend(self.failover.iter().cloned());
        all
    }

    /// The broker as logs and status name it: the socket path, or `host:port`.
    pub fn broker(&self) -> String {
        match &self.socket {
            Some(path) => path.display().to_string(),
            None => format!("{}:{}", self.host, self.port),
        }
    }
}

/// The MQTT protocol version spoken to the broker.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum MqttProtocol {
    /// MQTT 5 first; a broker that refuses it, or closes the connection without a CONNACK,
    /// gets MQTT 3.1.1 next (and keeps it once it answered).
    #[default]
    Auto,
    V5,
    /// For brokers that refuse v5 (Azure IoT Hub, older Mosquitto, some embedded brokers): no
    /// response topic or correlation data; everything else works the same.
    V311,
}
