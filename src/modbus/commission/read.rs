//! `pulsegate read`, `clear` and `preset`: one module through the gateway's own device poller,
//! so the values are decoded exactly as the gateway publishes them and a write is read back
//! the same way as an MQTT command.

use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Duration;

use serde_json::{Value, json};

use crate::bus::device::DeviceRt;
use crate::command::{Op, Reply, Request};
use crate::commission::error::CommissionError;
use crate::commission::target::Target;
use crate::config::{Bus, ChannelConfig, Device, Run};
use crate::modbus::config::plan::Wire;
use crate::modbus::driver::link::Link;
use crate::modbus::driver::probe::{Identified, identify};
use crate::modbus::driver::{ModbusDevice, ModbusError};
use crate::profile::{Profile, Profiles};

/// The profile for `model` ("auto": identified on the line). An unknown name or a baud rate
/// the model does not support is refused before anything is sent.
pub(crate) async fn resolve_model(
    link: &mut Link,
    target: &Target,
    profiles: &Profiles,
    unit: u8,
    model: &str,
    baud: u32,
) -> Result<Arc<Profile>, CommissionError> {
    let profile = if model == "auto" {
        check_baud_known(profiles, target, baud)?;
        let timeout = link.timeout_for(crate::modbus::driver::probe::answer_time(profiles), 3);
        match identify(link, profiles, unit, timeout, true).await {
            Ok(Some(Identified::Model(p))) => p,
            Ok(Some(Identified::Unknown(seen))) => {
                return Err(CommissionError::Failed(format!(
                    "unit {unit} answers, but no profile matches its identification \
                     {seen:04X?}: give --model NAME, or use `pulsegate raw`"
                )));
            }
            Ok(None) => {
                let at = if target.is_serial() {
                    format!(" at {baud} baud")
                } else {
                    String::new()
                };
                return Err(CommissionError::Failed(format!(
                    "unit {unit} did not answer{at}; `pulsegate scan --baud all` finds it"
                )));
            }
            Err(e) => return Err(target.error(unit, e)),
        }
    } else {
        profiles.get(model).ok_or_else(|| {
            CommissionError::BadInput(format!(
                "unknown model {model:?}; known: {}",
                profiles.names().join(", ")
            ))
        })?
    };
    if target.is_serial() && !profile.bauds.contains(&baud) {
        return Err(CommissionError::BadInput(format!(
            "model {} does not support {baud} baud ({:?})",
            profile.model, profile.bauds
        )));
    }
    Ok(profile)
}

fn check_baud_known(
    profiles: &Profiles,
    target: &Target,
    baud: u32,
) -> Result<(), CommissionError> {
    if target.is_serial() {
        super::scan::scan_bauds(&baud.to_string(), profiles)?;
    }
    Ok(())
}

/// The gateway's poller for one module.
pub(crate) fn poller(
    target: &Target,
    baud: u32,
    unit: u8,
    profile: &Arc<Profile>,
    link: &Link,
) -> DeviceRt<ModbusDevice> {
    let bus = Bus {
        name: "commission".into(),
        link: crate::config::Link::new(target.link_config(baud)),
        timeout: None,
        guard: Duration::ZERO,
        offline_after: 1,
        backoff_min: Duration::from_secs(1),
        backoff_max: Duration::from_secs(1),
        slow_poll: Duration::from_secs(3600),
        devices: Vec::new(),
        enabled: true,
    };
    // Commissioning reads: a counter found stopped or paused is left so (the gateway's own
    // start of a stopped ZH-YX1600 counter is a write, which a read must never make).
    let leave = ChannelConfig {
        run: Run::Leave,
        ..ChannelConfig::default()
    };
    let channels = profile
        .all_channels()
        .into_iter()
        .map(|c| (c.name, leave.clone()))
        .collect();
    let device = Device {
        name: format!("unit{unit}"),
        unit,
        model: profile.model.clone(),
        profile: profile.clone(),
        poll: Duration::from_secs(1),
        timeout: None,
        commands: true,
        baud: None,
        channels,
        publish: Default::default(),
        payload: None,
        intervals: None,
        enabled: true,
        address: crate::config::Address::new(crate::modbus::config::Unit(unit)),
        server_unit: None,
    };
    let wire = Wire::for_line(link.timing().as_ref());
    let proto = ModbusDevice::new(&bus, &device, wire, Vec::new());
    DeviceRt::new(&bus, &device, &BTreeMap::new(), proto)
}

/// One read of every channel, as JSON: the gateway's payload fields (count, freq_hz, rpm) plus
/// kind and pulses per revolution, and the work modes.
pub(crate) async fn read_once(
    rt: &mut DeviceRt<ModbusDevice>,
    link: &mut Link,
    profile: &Profile,
    target: &Target,
    baud: u32,
) -> Result<Value, CommissionError> {
    let unit = rt.proto.unit;
    let samples = rt.poll(link, &|| false).await.map_err(|e| match e {
        crate::bus::device::PollError::Protocol(ModbusError::Link(l)) => target.error(unit, l),
        other => CommissionError::Failed(format!("unit {unit}: {other}")),
    })?;
    // Counted by the bus core, as the gateway counts them.
    let readings = rt.book_poll(samples);
    let timeout = link.timeout_for(profile.answer_timeout, 1);
    let modes = crate::modbus::driver::probe::read_modes(link, unit, profile, timeout)
        .await
        .map_err(CommissionError::Failed)?;
    let specs = profile
        .channels(&modes)
        .map_err(|e| CommissionError::Failed(e.to_string()))?;
    let mut channels = serde_json::Map::new();
    for spec in &specs {
        let Some(r) = readings.iter().find(|r| *r.channel == spec.name) else {
            continue;
        };
        let published: Value =
            serde_json::from_str(&crate::publish::payload::reading(r)).unwrap_or(Value::Null);
        let mut ch = json!({ "kind": spec.kind, "count": published["count"] });
        for key in ["freq_hz", "rpm"] {
            if let Some(v) = published.get(key) {
                ch[key] = v.clone();
            }
        }
        if let Some(reg) = spec.ppr {
            if let Ok(Ok(w)) = link.read(unit, reg.address, 1, timeout).await {
                ch["ppr"] = json!(w[0]);
            }
        }
        channels.insert(spec.name.clone(), ch);
    }
    let mut out = json!({
        "unit": unit,
        "model": profile.model,
        "modes": modes,
        "channels": channels,
    });
    if target.is_serial() {
        out["baud"] = json!(baud);
    }
    Ok(out)
}

/// A read as a table; `previous` gives the deltas under `--watch`.
pub(crate) fn table(read: &Value, previous: Option<&Value>) -> String {
    let mut t = format!(
        "unit {}  {}  work modes {}\n{:<8} {:<8} {:>12} {:>8} {:>12} {:>10} {:>6}\n",
        read["unit"],
        read["model"].as_str().unwrap_or_default(),
        read["modes"],
        "channel",
        "kind",
        "count",
        "delta",
        "freq_hz",
        "rpm",
        "ppr"
    );
    let empty = serde_json::Map::new();
    for (name, ch) in read["channels"].as_object().unwrap_or(&empty) {
        let delta = previous
            .and_then(|p| p["channels"][name]["count"].as_i64())
            .zip(ch["count"].as_i64())
            .map(|(before, now)| format!("{:+}", now - before))
            .unwrap_or_default();
        let num = |k: &str| {
            ch.get(k)
                .map(|v| v.to_string())
                .unwrap_or_else(|| "-".into())
        };
        let count = num("count");
        t += &format!(
            "{:<8} {:<8} {:>12} {:>8} {:>12} {:>10} {:>6}\n",
            name,
            ch["kind"].as_str().unwrap_or_default(),
            count,
            delta,
            num("freq_hz"),
            num("rpm"),
            num("ppr")
        );
    }
    t
}

/// Clears or presets one channel the way an MQTT command does; returns the count read back.
pub(crate) async fn write_count(
    rt: &mut DeviceRt<ModbusDevice>,
    link: &mut Link,
    target: &Target,
    channel: &str,
    op: Op,
) -> Result<Option<i64>, CommissionError> {
    // The poll discovers the channels (work modes) first, as the gateway does, and its counts
    // are booked before the write.
    let samples = rt.poll(link, &|| false).await.map_err(|e| match e {
        crate::bus::device::PollError::Protocol(ModbusError::Link(l)) => {
            target.error(rt.proto.unit, l)
        }
        other => CommissionError::Failed(format!("unit {}: {other}", rt.proto.unit)),
    })?;
    rt.book_poll(samples);
    let now = tokio::time::Instant::now();
    let req = Request {
        device: rt.name.to_string(),
        channel: Some(channel.to_string()),
        op,
        id: None,
        reply: Reply::default(),
        received: now,
        expires: now + Duration::from_secs(10),
    };
    let executed = rt.execute(link, &req).await;
    let (_, result) = rt.book_command(executed);
    result.map_err(|e| match e {
        crate::command::CommandError::UnknownChannel { .. }
        | crate::command::CommandError::OutOfRange { .. } => {
            CommissionError::BadInput(e.to_string())
        }
        other => CommissionError::Failed(other.to_string()),
    })
}
