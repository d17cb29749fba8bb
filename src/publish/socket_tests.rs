//! The client options for a local broker's Unix socket, on both protocols.

use std::path::PathBuf;

use rumqttc::Transport;

use super::mqtt::client_options;
use super::session::Options;
use crate::config::{Config, Mqtt, MqttProtocol, Tls};

fn mqtt(protocol: &str) -> Mqtt {
    let text = format!(
        "[gateway]\nid = \"e1\"\n[mqtt]\nprotocol = \"{protocol}\"\nsocket = \"/run/mosquitto/mqtt.sock\"\n\
         [buses.l]\nhost = \"127.0.0.1\"\nport = 502\n[buses.l.devices.d]\nunit = 1\nmodel = \"yl67\"\n"
    );
    let env = Some(std::collections::HashMap::new());
    Config::from_toml(&text, std::path::Path::new("x.toml"), env)
        .expect("config")
        .mqtt
}

#[test]
fn a_v5_client_connects_to_the_socket_path_over_the_unix_transport() {
    let config = mqtt("5");
    assert_eq!(config.protocol, MqttProtocol::V5);
    match client_options(&config).unwrap() {
        Options::V5(o) => {
            assert_eq!(o.broker_address().0, "/run/mosquitto/mqtt.sock");
            assert!(matches!(o.transport(), Transport::Unix));
        }
        Options::V311(_) => panic!("asked for v5"),
    }
}

#[test]
fn a_3_1_1_client_connects_to_the_socket_path_over_the_unix_transport() {
    let config = mqtt("3.1.1");
    match client_options(&config).unwrap() {
        Options::V311(o) => {
            assert_eq!(o.broker_address().0, "/run/mosquitto/mqtt.sock");
            assert!(matches!(o.transport(), Transport::Unix));
        }
        Options::V5(_) => panic!("asked for 3.1.1"),
    }
}

/// `check` refuses it; a config built another way must not connect without the TLS it names.
#[test]
fn a_socket_with_tls_never_connects_without_tls() {
    let mut config = mqtt("5");
    config.tls = Some(Tls {
        ca_file: PathBuf::from("/etc/ssl/ca.pem"),
        cert_file: None,
        key_file: None,
    });
    let e = client_options(&config).err().expect("refused");
    assert!(e.to_string().contains("mqtt.socket"), "{e}");
    assert!(e.to_string().contains("mqtt.tls"), "{e}");
}
