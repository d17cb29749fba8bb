//! Checking of the unit, publish-policy and Home Assistant keys.

use std::collections::HashMap;
use std::path::Path;
use std::time::Duration;

use super::*;
use crate::config::policy::{PayloadMode, PublishMode};
use crate::config::units::RatePer;

const BASE: &str = r#"
[gateway]
id = "edge-01"
[buses.line1]
port = "/dev/ttyUSB0"
[buses.line1.devices.meter]
unit = 1
model = "yl67"
"#;

fn check(extra: &str, env: &[(&str, &str)]) -> Result<Config, ConfigErrors> {
    let env = env
        .iter()
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect::<HashMap<_, _>>();
    Config::from_toml(
        &format!("{BASE}{extra}"),
        Path::new("/etc/pulsegate/pulsegate.toml"),
        Some(env),
    )
}

fn errors(extra: &str) -> String {
    check(extra, &[]).unwrap_err().to_string()
}

#[test]
fn a_channel_takes_a_scale_as_the_exact_decimal_written() {
    let c = check(
        "[buses.line1.devices.meter.channels.a0]\nscale = 0.001\nunit = \"kWh\"\n\
         rate_unit = \"kW\"\nrate_per = \"h\"\ndevice_class = \"energy\"\n",
        &[],
    )
    .unwrap();
    let u = &c.buses[0].devices[0].channels["a0"].units;
    assert_eq!(u.scale.unwrap().times(1_234_567).to_string(), "1234.567");
    assert_eq!(u.rate_per, RatePer::Hour);
    assert_eq!(u.device_class.as_deref(), Some("energy"));
}

#[test]
fn an_environment_override_gives_the_scale_as_text() {
    let c = check(
        "[buses.line1.devices.meter.channels.a0]\nscale = 1\n",
        &[(
            "PULSEGATE__BUSES__LINE1__DEVICES__METER__CHANNELS__A0__SCALE",
            "0.1",
        )],
    )
    .unwrap();
    let u = &c.buses[0].devices[0].channels["a0"].units;
    assert_eq!(u.scale.unwrap().times(3).to_string(), "0.3");
}

#[test]
fn bad_unit_keys_are_named_with_their_cause() {
    let e = errors("[buses.line1.devices.meter.channels.a0]\nscale = -1\n");
    assert!(
        e.contains("channels.a0.scale: must be greater than zero"),
        "{e}"
    );
    let e = errors("[buses.line1.devices.meter.channels.a0]\nscale = \"1/1000\"\n");
    assert!(e.contains("is not a decimal number"), "{e}");
    let e = errors("[buses.line1.devices.meter.channels.a0]\nunit = \"kWh\"\n");
    assert!(e.contains("channels.a0.unit: needs `scale`"), "{e}");
    let e = errors(
        "[buses.line1.devices.meter.channels.a0]\nscale = 1\nunit = \"rpm\"\ndevice_class = \"energy\"\n",
    );
    assert!(
        e.contains("device class energy does not take unit \"rpm\""),
        "{e}"
    );
    let e = errors("[buses.line1.devices.meter.channels.a0]\nscale = 1\nrate_per = \"day\"\n");
    assert!(e.contains("rate_per: \"day\" is not"), "{e}");
}

#[test]
fn publish_keys_resolve_gateway_then_device_then_channel() {
    let c = check(
        "publish = \"change\"\npayload = \"device\"\n\
         [buses.line1.devices.meter.channels.a0]\nmin_interval = \"5s\"\n",
        &[("PULSEGATE__GATEWAY__HEARTBEAT", "1m")],
    )
    .unwrap();
    let d = &c.buses[0].devices[0];
    assert_eq!(d.publish.publish, Some(PublishMode::Change));
    assert_eq!(d.payload, Some(PayloadMode::Device));
    let p = c
        .gateway
        .publish
        .then(&d.publish)
        .then(&d.channels["a0"].publish)
        .policy();
    assert_eq!(p.heartbeat, Some(Duration::from_secs(60)));
    assert_eq!(p.min_interval, Some(Duration::from_secs(5)));
    let e = errors("publish = \"sometimes\"\npayload = \"bus\"\n");
    assert!(e.contains("publish: \"sometimes\" is not"), "{e}");
    assert!(e.contains("payload: \"bus\" is not"), "{e}");
}

#[test]
fn homeassistant_discovery_is_off_unless_asked_for() {
    use crate::config::outputs::homeassistant::{HomeAssistant, KIND};
    let prefix = |c: &crate::config::Config| {
        c.outputs
            .settings::<HomeAssistant>()
            .unwrap()
            .prefix
            .clone()
    };
    let c = check("", &[]).unwrap();
    assert!(!c.outputs.has(&KIND));
    assert_eq!(prefix(&c), "homeassistant");
    let c = check("[homeassistant]\ndiscovery = true\nprefix = \"ha\"\n", &[]).unwrap();
    assert!(c.outputs.has(&KIND));
    assert_eq!(prefix(&c), "ha");
    let e = errors("[homeassistant]\nprefix = \"ha/#\"\nnope = 1\n");
    assert!(
        e.contains("homeassistant.prefix") && e.contains("homeassistant.nope"),
        "{e}"
    );
}

#[test]
fn zero_min_interval_or_heartbeat_is_accepted_and_undoes_the_gateway_value() {
    let c = check(
        "publish = \"poll\"\nmin_interval = \"0s\"\n\
         [buses.line1.devices.meter.channels.a0]\npublish = \"change\"\nheartbeat = \"0s\"\n",
        &[
            ("PULSEGATE__GATEWAY__MIN_INTERVAL", "1s"),
            ("PULSEGATE__GATEWAY__HEARTBEAT", "1m"),
        ],
    )
    .unwrap();
    assert_eq!(
        c.gateway.publish.policy().min_interval,
        Some(Duration::from_secs(1))
    );
    let d = &c.buses[0].devices[0];
    let device = c.gateway.publish.then(&d.publish);
    assert_eq!(device.policy().min_interval, None);
    let channel = device.then(&d.channels["a0"].publish).policy();
    assert_eq!((channel.min_interval, channel.heartbeat), (None, None));
    let e = errors("min_interval = \"-1s\"\n");
    assert!(e.contains("min_interval"), "{e}");
}

#[test]
fn a_channel_names_its_total_by_obis_and_a_name_not_a_b_c_d_e_is_refused() {
    let c = check(
        "[buses.line1.devices.meter.channels.a0]\nscale = 0.001\nunit = \"kWh\"\nobis = \"1-0:1.8.0\"\n",
        &[],
    )
    .unwrap();
    let u = &c.buses[0].devices[0].channels["a0"].units;
    assert_eq!(u.obis.map(|o| o.to_string()).as_deref(), Some("1-0:1.8.0"));
    let e = errors("[buses.line1.devices.meter.channels.a0]\nscale = 1\nobis = \"1.8.0\"\n");
    assert!(
        e.contains("channels.a0.obis: \"1.8.0\" is not an OBIS name: write A-B:C.D.E"),
        "{e}"
    );
}
