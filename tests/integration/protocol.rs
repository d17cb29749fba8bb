//! The MQTT protocol a test's gateway speaks, and a broker limited to MQTT 3.1.1 for it.
//!
//! Debian's Mosquitto (2.0) accepts every protocol level on every listener (its
//! `accept_protocol_versions` arrives in 2.1), so the 3.1.1-only listener is a gate in front of
//! a real Mosquitto: it reads the CONNECT packet, refuses any protocol level but 4 (3.1.1) the
//! way a 3.1.1-only broker does (CONNACK "unacceptable protocol version", then close), and
//! passes the accepted connection through byte for byte. The session is then Mosquitto's own
//! 3.1.1 session: no properties, retained flags as 3.1.1 sets them.

#![allow(dead_code)] // shared helpers: not every test module uses each one

use std::io::{Read, Write};
use std::net::{Shutdown, TcpListener, TcpStream};
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use pulsegate::sim::Plant;

use crate::support::{Gateway, gateway_toml, write_config};

/// The protocol a test gateway speaks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Protocol {
    V5,
    V311,
}

/// Where a test gateway connects: the broker itself (v5) or a 3.1.1-only gate in front of it.
pub struct Side {
    pub protocol: Protocol,
    pub port: u16,
    _gate: Option<Gate>,
}

impl Protocol {
    pub fn side(self, broker_port: u16) -> Side {
        match self {
            Protocol::V5 => Side {
                protocol: self,
                port: broker_port,
                _gate: None,
            },
            Protocol::V311 => {
                let gate = Gate::start(broker_port);
                Side {
                    protocol: self,
                    port: gate.port,
                    _gate: Some(gate),
                }
            }
        }
    }
}

impl Side {
    /// The gateway config for this side: its port, and `mqtt.protocol` on 3.1.1.
    pub fn config(
        &self,
        plant: &Plant,
        dir: &Path,
        devices: &[(&str, &str, u8, &str, &str)],
        extra: &str,
    ) -> String {
        let text = gateway_toml(plant, self.port, dir, devices, extra);
        match self.protocol {
            Protocol::V5 => text,
            Protocol::V311 => text.replacen("[mqtt]\n", "[mqtt]\nprotocol = \"3.1.1\"\n", 1),
        }
    }

    /// Writes the config (as [`Side::config`]) to `dir` and starts the gateway.
    pub fn start_gateway(
        &self,
        plant: &Plant,
        dir: &Path,
        devices: &[(&str, &str, u8, &str, &str)],
        extra: &str,
    ) -> Gateway {
        Gateway::start(&write_config(dir, &self.config(plant, dir, devices, extra)))
    }
}

/// A listener that takes MQTT 3.1.1 connections only and passes them to a broker.
pub struct Gate {
    pub port: u16,
    stop: Arc<AtomicBool>,
}

impl Gate {
    pub fn start(upstream: u16) -> Gate {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        let port = listener.local_addr().unwrap().port();
        let stop = Arc::new(AtomicBool::new(false));
        let stopped = stop.clone();
        std::thread::spawn(move || {
            for conn in listener.incoming() {
                if stopped.load(Ordering::Relaxed) {
                    break;
                }
                if let Ok(c) = conn {
                    std::thread::spawn(move || pass(c, upstream));
                }
            }
        });
        Gate { port, stop }
    }
}

impl Drop for Gate {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        let _ = TcpStream::connect(("127.0.0.1", self.port)); // wakes the accept loop
    }
}

/// One MQTT packet: fixed header, remaining length, body.
fn read_packet(s: &mut TcpStream) -> Option<Vec<u8>> {
    let mut packet = vec![0u8; 1];
    s.read_exact(&mut packet).ok()?;
    let (mut len, mut shift) = (0usize, 0);
    loop {
        let mut b = [0u8; 1];
        s.read_exact(&mut b).ok()?;
        packet.push(b[0]);
        len |= usize::from(b[0] & 0x7F) << shift;
        shift += 7;
        if b[0] & 0x80 == 0 || shift > 21 {
            break;
        }
    }
    let start = packet.len();
    packet.resize(start + len, 0);
    s.read_exact(&mut packet[start..]).ok()?;
    Some(packet)
}

/// The CONNECT packet's protocol level (4: 3.1.1, 5: v5), if it is a CONNECT.
pub fn protocol_level(packet: &[u8]) -> Option<u8> {
    if packet.first()? >> 4 != 1 {
        return None;
    }
    let body = packet.iter().skip(1).position(|b| b & 0x80 == 0)? + 2;
    let name_len = usize::from(u16::from_be_bytes([
        *packet.get(body)?,
        *packet.get(body + 1)?,
    ]));
    packet.get(body + 2 + name_len).copied()
}

fn pass(mut client: TcpStream, upstream: u16) {
    let Some(connect) = read_packet(&mut client) else {
        return;
    };
    match protocol_level(&connect) {
        Some(4) => {}
        Some(5) => {
            // v5 CONNACK: reason 0x84 unsupported protocol version, no properties.
            let _ = client.write_all(&[0x20, 0x03, 0x00, 0x84, 0x00]);
            return;
        }
        _ => {
            // 3.1.1 CONNACK: return code 1, unacceptable protocol version.
            let _ = client.write_all(&[0x20, 0x02, 0x00, 0x01]);
            return;
        }
    }
    let Ok(mut broker) = TcpStream::connect(("127.0.0.1", upstream)) else {
        return; // broker away: the client sees the connection close
    };
    if broker.write_all(&connect).is_err() {
        return;
    }
    let (Ok(mut c2), Ok(mut b2)) = (client.try_clone(), broker.try_clone()) else {
        return;
    };
    let up = std::thread::spawn(move || {
        let _ = std::io::copy(&mut c2, &mut b2);
        let _ = b2.shutdown(Shutdown::Both);
    });
    let _ = std::io::copy(&mut broker, &mut client);
    let _ = client.shutdown(Shutdown::Both);
    let _ = up.join();
}

/// The gate is what makes the 3.1.1 tests mean something: an MQTT 5 client is refused, a 3.1.1
/// client gets through to the broker.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_3_1_1_listener_refuses_mqtt_5_and_passes_3_1_1() {
    use std::time::Duration;
    let broker = crate::support::Broker::start();
    let gate = Gate::start(broker.port);

    let options = rumqttc::v5::MqttOptions::new("v5-probe", "127.0.0.1", gate.port);
    let (_c, mut events) = rumqttc::v5::AsyncClient::new(options, 10);
    let v5 = tokio::time::timeout(Duration::from_secs(5), events.poll())
        .await
        .expect("an answer from the gate");
    assert!(
        !matches!(
            v5,
            Ok(rumqttc::v5::Event::Incoming(
                rumqttc::v5::mqttbytes::v5::Packet::ConnAck(_)
            ))
        ),
        "an MQTT 5 client must be refused: {v5:?}"
    );

    let options = rumqttc::MqttOptions::new("v311-probe", "127.0.0.1", gate.port);
    let (_c, mut events) = rumqttc::AsyncClient::new(options, 10);
    let v311 = tokio::time::timeout(Duration::from_secs(5), events.poll())
        .await
        .expect("an answer from the gate");
    assert!(
        matches!(
            v311,
            Ok(rumqttc::Event::Incoming(rumqttc::Packet::ConnAck(ref a)))
                if a.code == rumqttc::ConnectReturnCode::Success
        ),
        "an MQTT 3.1.1 client must get through: {v311:?}"
    );
}

#[test]
fn an_unknown_mqtt_protocol_is_a_config_error_naming_the_choices() {
    let dir = crate::support::temp_dir("protocol-bad");
    let config = write_config(
        &dir,
        "[mqtt]\nprotocol = \"3.1\"\n[buses.l]\nhost = \"127.0.0.1\"\nport = 502\n[buses.l.devices.d]\nunit = 1\nmodel = \"yl67\"\n",
    );
    let out = std::process::Command::new(crate::support::bin())
        .args(["check", "--config"])
        .arg(&config)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("mqtt.protocol") && err.contains("\"5\" or \"3.1.1\""),
        "{err}"
    );
}
