//! `mqtt.socket`: a local broker's Unix socket instead of `host`/`port`.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use super::*;

const BUS: &str = "[buses.l]\nhost = \"127.0.0.1\"\nport = 502\n[buses.l.devices.d]\nunit = 1\nmodel = \"yl67\"\n";

fn with_mqtt(mqtt: &str, env: &[(&str, &str)]) -> Result<Config, ConfigErrors> {
    let text = format!("[gateway]\nid = \"e1\"\n[mqtt]\n{mqtt}\n{BUS}");
    let env = env
        .iter()
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect::<HashMap<_, _>>();
    Config::from_toml(&text, Path::new("/etc/pulsegate/pulsegate.toml"), Some(env))
}

fn errors(mqtt: &str) -> String {
    with_mqtt(mqtt, &[]).unwrap_err().to_string()
}

#[test]
fn a_socket_path_is_taken_and_names_the_broker_instead_of_host_and_port() {
    let c = with_mqtt("socket = \"/run/mosquitto/mqtt.sock\"\nport = 1884", &[]).unwrap();
    assert_eq!(
        c.mqtt.socket,
        Some(PathBuf::from("/run/mosquitto/mqtt.sock"))
    );
    assert_eq!(c.mqtt.broker(), "/run/mosquitto/mqtt.sock");
}

#[test]
fn without_a_socket_the_broker_is_host_and_port() {
    let c = with_mqtt("host = \"broker\"\nport = 1884", &[]).unwrap();
    assert_eq!(c.mqtt.socket, None);
    assert_eq!(c.mqtt.broker(), "broker:1884");
}

#[test]
fn the_environment_sets_the_socket() {
    let env = [("PULSEGATE__MQTT__SOCKET", "/run/mosquitto/env.sock")];
    let c = with_mqtt("host = \"broker\"", &env).unwrap();
    assert_eq!(
        c.mqtt.socket,
        Some(PathBuf::from("/run/mosquitto/env.sock"))
    );
}

#[test]
fn a_bad_socket_from_the_environment_names_the_environment() {
    let env = [("PULSEGATE__MQTT__SOCKET", "mqtt.sock")];
    let e = with_mqtt("", &env).unwrap_err().to_string();
    assert!(e.contains("mqtt.socket"), "{e}");
    assert!(e.contains("the environment: mqtt.socket"), "{e}");
    assert!(e.contains("must be an absolute path"), "{e}");
}

#[test]
fn a_socket_with_tls_is_refused_naming_both_keys() {
    let dir = std::env::temp_dir().join(format!("pulsegate-socket-tls-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let ca = dir.join("ca.pem");
    std::fs::write(&ca, "not checked before the socket").unwrap();
    let e = errors(&format!(
        "socket = \"/run/mosquitto/mqtt.sock\"\n[mqtt.tls]\nca_file = \"{}\"",
        ca.display()
    ));
    assert!(
        e.contains("mqtt.socket and mqtt.tls cannot be set together"),
        "{e}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_relative_socket_path_is_refused() {
    let e = errors("socket = \"run/mosquitto/mqtt.sock\"");
    assert!(e.contains("mqtt.socket"), "{e}");
    assert!(e.contains("must be an absolute path"), "{e}");
    assert!(errors("socket = \"\"").contains("must be an absolute path"));
}

#[test]
fn a_socket_path_longer_than_sun_path_holds_is_refused() {
    // 107 bytes fit (108 with the closing NUL); 108 do not.
    let fits = format!("/{}", "s".repeat(106));
    let c = with_mqtt(&format!("socket = \"{fits}\""), &[]).unwrap();
    assert_eq!(c.mqtt.socket, Some(PathBuf::from(&fits)));
    let long = format!("/{}", "s".repeat(107));
    let e = errors(&format!("socket = \"{long}\""));
    assert!(e.contains("is 108 bytes long"), "{e}");
    assert!(e.contains("at most 107"), "{e}");
}

#[test]
fn a_socket_path_with_a_nul_byte_is_refused() {
    let e = errors("socket = \"/run/mqtt\\u0000.sock\"");
    assert!(e.contains("NUL"), "{e}");
}

#[test]
fn a_socket_that_is_not_a_string_is_refused() {
    // The config crate turns the number into the string "5": a relative path.
    let e = errors("socket = 5");
    assert!(
        e.contains("mqtt.socket: 5: must be an absolute path"),
        "{e}"
    );
}
