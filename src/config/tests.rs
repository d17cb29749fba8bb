use std::collections::HashMap;
use std::path::Path;
use std::time::Duration;

use super::*;
use crate::modbus::config::Line;

const GOOD: &str = r#"
[gateway]
id = "edge-01"
state_dir = "/tmp/pg"
[mqtt]
host = "broker"
[buses.line1]
port = "/dev/ttyUSB0"
baud = 19200
parity = "even"
timeout = "300ms"
[buses.line1.devices.press1]
unit = 1
model = "yl67"
poll = "500ms"
[buses.line1.devices.press1.channels.enc0]
ppr = 1024
[buses.hall2]
host = "10.0.0.7"
port = 20108
[buses.hall2.devices.doors]
unit = 1
model = "zh-yx1600"
"#;

fn check(text: &str) -> Result<Config, ConfigErrors> {
    Config::from_toml(
        text,
        Path::new("/etc/pulsegate/pulsegate.toml"),
        Some(HashMap::new()),
    )
}

fn errors(text: &str) -> Vec<String> {
    check(text)
        .unwrap_err()
        .0
        .iter()
        .map(|e| e.to_string())
        .collect()
}

#[test]
fn a_good_config_is_checked_into_typed_values() {
    let c = check(GOOD).unwrap();
    assert_eq!(c.gateway.id, "edge-01");
    assert_eq!(c.mqtt.topic_root, "pulsegate/edge-01");
    assert_eq!(c.mqtt.qos, 1);
    assert_eq!(c.buses.len(), 2);
    let hall = &c.buses[0];
    assert_eq!(
        hall.link,
        Link::new(Line::Tcp {
            host: "10.0.0.7".into(),
            port: 20108
        })
    );
    let line1 = &c.buses[1];
    assert!(matches!(
        line1.link.line(),
        Some(Line::Rtu {
            baud: 19200,
            parity: Parity::Even,
            stop_bits: 1,
            ..
        })
    ));
    let press = &line1.devices[0];
    assert_eq!(press.poll, Duration::from_millis(500));
    assert_eq!(press.answer_timeout(line1), Duration::from_millis(300));
    assert_eq!(press.channels["enc0"].ppr, Some(1024.0));
    // The bus has no timeout: the model's answer time.
    assert_eq!(
        hall.devices[0].answer_timeout(hall),
        Duration::from_millis(100)
    );
}

#[test]
fn the_environment_overrides_a_device_by_name() {
    let env = HashMap::from([
        (
            "PULSEGATE__BUSES__LINE1__DEVICES__PRESS1__POLL".to_string(),
            "2s".to_string(),
        ),
        ("PULSEGATE__MQTT__PORT".to_string(), "1884".to_string()),
    ]);
    let c = Config::from_toml(GOOD, Path::new("x.toml"), Some(env)).unwrap();
    assert_eq!(c.mqtt.port, 1884);
    assert_eq!(c.buses[1].devices[0].poll, Duration::from_secs(2));
}

#[test]
fn an_error_from_the_environment_names_the_environment() {
    let env = HashMap::from([(
        "PULSEGATE__BUSES__LINE1__DEVICES__PRESS1__POLL".to_string(),
        "soon".to_string(),
    )]);
    let err = Config::from_toml(GOOD, Path::new("x.toml"), Some(env))
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("the environment: buses.line1.devices.press1.poll"),
        "{err}"
    );
}

#[test]
fn all_errors_are_reported_at_once_with_file_and_key_path() {
    let e = errors(
        r#"
[gateway]
idd = "x"
[buses.line1]
port = "/dev/ttyUSB0"
baud = 1234
[buses.line1.devices.a]
unit = 0
model = "nope"
poll = "0s"
"#,
    );
    let all = e.join("\n");
    for want in [
        "/etc/pulsegate/pulsegate.toml: gateway.idd: unknown key",
        "buses.line1.baud: 1234 is not a rate",
        "buses.line1.devices.a.unit: unit 0 is outside 1..247",
        "buses.line1.devices.a.model: unknown model \"nope\"",
        "buses.line1.devices.a.poll: must be greater than zero",
    ] {
        assert!(all.contains(want), "missing {want:?} in:\n{all}");
    }
}

#[test]
fn device_names_are_unique_across_buses_and_safe_in_a_topic() {
    let e = errors(
        r#"
[buses.a]
port = "/dev/ttyS0"
[buses.a.devices.press]
unit = 1
model = "yl67"
[buses.a.devices."bad/name"]
unit = 2
model = "yl67"
[buses.b]
port = "/dev/ttyS1"
[buses.b.devices.press]
unit = 1
model = "yl67"
"#,
    )
    .join("\n");
    assert!(
        e.contains("buses.b.devices.press: device name is already used on bus a"),
        "{e}"
    );
    assert!(e.contains("bad/name"), "{e}");
}

#[test]
fn a_bus_needs_a_port_or_a_host() {
    let e = errors("[buses.x.devices.d]\nunit = 1\nmodel = \"yl67\"\n").join("\n");
    assert!(e.contains("buses.x: needs `port`"), "{e}");
}

#[test]
fn serial_settings_on_a_tcp_bus_are_refused() {
    let e = errors(
        "[buses.x]\nhost = \"h\"\nbaud = 9600\n[buses.x.devices.d]\nunit = 1\nmodel = \"yl67\"\n",
    )
    .join("\n");
    assert!(
        e.contains("buses.x.baud: serial setting on a TCP bus"),
        "{e}"
    );
}

#[test]
fn a_channel_the_model_does_not_have_is_refused() {
    let e = errors("[buses.x]\nport = \"/dev/ttyS0\"\n[buses.x.devices.d]\nunit = 1\nmodel = \"wj157\"\nchannels.enc3 = { ppr = 5 }\n").join("\n");
    assert!(e.contains("model wj157 has no channel enc3"), "{e}");
}

#[test]
fn the_example_config_is_valid() {
    let text = include_str!("../../config/pulsegate.example.toml");
    check(text).unwrap();
}

#[test]
fn topic_safe_names() {
    assert!(crate::topics::is_topic_safe("press-1_a"));
    for bad in ["", "a/b", "a+", "#", "a b", "ü"] {
        assert!(!crate::topics::is_topic_safe(bad), "{bad:?}");
    }
}

#[test]
fn a_tcp_bus_of_zh_yx1600_modules_needs_no_port_the_datasheet_gives_20108() {
    let c = check(
        "[buses.hall]\nhost = \"10.0.0.7\"\n[buses.hall.devices.doors]\nunit = 1\nmodel = \"zh-yx1600\"\n",
    )
    .unwrap();
    assert_eq!(
        c.buses[0].link,
        Link::new(Line::Tcp {
            host: "10.0.0.7".into(),
            port: 20108
        })
    );
    let c = check(
        "[buses.gw]\nhost = \"10.0.0.8\"\n[buses.gw.devices.press]\nunit = 1\nmodel = \"yl67\"\n",
    )
    .unwrap();
    assert!(matches!(
        c.buses[0].link.line(),
        Some(Line::Tcp { port: 502, .. })
    ));
    let e = errors(
        "[buses.gw]\nhost = \"10.0.0.8\"\n[buses.gw.devices.press]\nunit = 1\nmodel = \"yl67\"\n\
         [buses.gw.devices.doors]\nunit = 2\nmodel = \"zh-yx1600\"\n",
    )
    .join("\n");
    assert!(
        e.contains("buses.gw.port") && e.contains("zh-yx1600 listens on 20108"),
        "{e}"
    );
}

#[test]
fn enabled_and_run_are_read_at_bus_device_and_channel_level() {
    let c = check(
        "[buses.hall]\nhost = \"10.0.0.7\"\nenabled = false\n[buses.hall.devices.doors]\nunit = 1\nmodel = \"zh-yx1600\"\nenabled = false\n\
         [buses.hall.devices.doors.channels.di1]\nrun = \"down\"\n[buses.hall.devices.doors.channels.di2]\nrun = \"leave\"\nenabled = false\n",
    )
    .unwrap();
    let bus = &c.buses[0];
    assert!(!bus.enabled && !bus.devices[0].enabled);
    let ch = &bus.devices[0].channels;
    assert_eq!(ch["di1"].run, Run::Down);
    assert!(ch["di1"].enabled);
    assert_eq!((ch["di2"].run, ch["di2"].enabled), (Run::Leave, false));
    let e = errors(
        "[buses.hall]\nhost = \"h\"\n[buses.hall.devices.doors]\nunit = 1\nmodel = \"zh-yx1600\"\nchannels.di1 = { run = \"sideways\" }\n",
    )
    .join("\n");
    assert!(
        e.contains("buses.hall.devices.doors.channels.di1.run"),
        "{e}"
    );
}

#[test]
fn an_fqdn_hostname_becomes_a_visible_id_never_a_shared_default() {
    use super::id_from_host;
    assert_eq!(
        id_from_host("edge-01.plant.example.com").as_deref(),
        Some("edge-01-plant-example-com")
    );
    assert_eq!(id_from_host("edge_7").as_deref(), Some("edge_7"));
    assert_eq!(id_from_host(""), None);
    assert_eq!(id_from_host("..."), None);
    assert_eq!(
        id_from_host(&"a".repeat(100)),
        None,
        "too long for a topic level"
    );
}

#[test]
fn a_device_may_answer_at_its_own_baud_rate_on_a_serial_bus() {
    let text = GOOD.replace("poll = \"500ms\"", "poll = \"500ms\"\nbaud = 9600");
    let c = check(&text).unwrap();
    assert_eq!(c.buses[1].devices[0].baud, Some(9600));
    assert_eq!(c.buses[0].devices[0].baud, None);
}

#[test]
fn a_device_baud_is_refused_on_tcp_and_outside_its_model() {
    let tcp = GOOD.replace(
        "model = \"zh-yx1600\"",
        "model = \"zh-yx1600\"\nbaud = 9600",
    );
    assert!(
        errors(&tcp)
            .iter()
            .any(|e| e.contains("buses.hall2.devices.doors.baud") && e.contains("TCP")),
        "{:?}",
        errors(&tcp)
    );
    let odd = GOOD.replace("poll = \"500ms\"", "poll = \"500ms\"\nbaud = 14400");
    assert!(
        errors(&odd)
            .iter()
            .any(|e| e.contains("does not support 14400")),
        "{:?}",
        errors(&odd)
    );
}
