//! `pulsegate set-reading DEVICE CHANNEL VALUE`: sends `set_reading` to the running gateway over
//! its broker (the gateway owns the counter state, so the command line does not edit the state
//! file behind its back) and waits for the result.

use std::time::Duration;

use bytes::Bytes;

use crate::config::Config;
use crate::decimal::{Decimal, DecimalError};
use crate::publish::session::{Event, EventLoop, Options};
use crate::topics::Topics;

/// Why a reading could not be set.
#[derive(Debug, thiserror::Error)]
pub enum SetReadingError {
    #[error("{0}")]
    Value(#[from] DecimalError),
    #[error("no device {0} in the configuration")]
    UnknownDevice(String),
    #[error(
        "channel {channel} of {device} has no scale in the configuration: a meter reading is in its unit"
    )]
    NoScale { device: String, channel: String },
    #[error("{0}")]
    Tls(#[from] crate::config::tls::TlsError),
    #[error("MQTT broker {broker}: {why}")]
    Broker { broker: String, why: String },
    #[error("no result from the gateway within {0:?}: is it running and connected to the broker?")]
    NoAnswer(Duration),
}

/// Checks what the configuration can tell before anything is sent.
fn check(config: &Config, device: &str, channel: &str) -> Result<(), SetReadingError> {
    let (_, d) = config
        .devices()
        .find(|(_, d)| d.name == device)
        .ok_or_else(|| SetReadingError::UnknownDevice(device.to_string()))?;
    if d.channels
        .get(channel)
        .and_then(|c| c.units.scale)
        .is_none()
    {
        return Err(SetReadingError::NoScale {
            device: device.to_string(),
            channel: channel.to_string(),
        });
    }
    Ok(())
}

/// A client of its own (its own id, no will: it must never mark the gateway offline), on the
/// connection settings of the gateway's own voice (`[mqtt]`), built where every connection's
/// are.
fn options(config: &Config) -> Result<Options, SetReadingError> {
    let m = &config.mqtt;
    let id = format!("{}-set-reading-{}", m.client_id, std::process::id());
    Ok(crate::publish::session::client_options_as(m, &id)?)
}

/// Sends `set_reading` for `device`/`channel` with `value` (decimal text) and returns the
/// gateway's result (JSON); waits at most `wait`.
pub async fn run(
    config: &Config,
    device: &str,
    channel: &str,
    value: &str,
    wait: Duration,
) -> Result<serde_json::Value, SetReadingError> {
    let shown = Decimal::parse(value)?;
    check(config, device, channel)?;
    let topics = Topics::new(&config.mqtt.topic_root);
    let command = topics.channel_command(device, channel);
    let result = Topics::result(&command);
    let id = format!("cli-{}", std::process::id());
    let payload = serde_json::json!({"op": "set_reading", "value": shown.to_string(), "id": id});
    let broker = |why: String| SetReadingError::Broker {
        broker: config.mqtt.broker(),
        why,
    };
    let (client, mut events) = options(config)?.connect(None, 16);
    client
        .subscribe(result.clone())
        .map_err(|e| broker(e.to_string()))?;
    let body = Bytes::from(payload.to_string());
    client
        .publish(command, 1, false, body, None)
        .map_err(|e| broker(e.to_string()))?;
    let answer = tokio::time::timeout(wait, answer(&mut events, &result, &id)).await;
    let _ = client.disconnect();
    match answer {
        Ok(r) => r.map_err(broker),
        Err(_) => Err(SetReadingError::NoAnswer(wait)),
    }
}

/// The result on `topic` that echoes `id`.
async fn answer(
    events: &mut EventLoop,
    topic: &str,
    id: &str,
) -> Result<serde_json::Value, String> {
    loop {
        match events.poll().await {
            Ok(Event::Received(r)) if r.topic == topic.as_bytes() => {
                let Ok(v) = serde_json::from_slice::<serde_json::Value>(&r.payload) else {
                    continue;
                };
                if v["id"] == id {
                    return Ok(v);
                }
            }
            Ok(_) => {}
            Err(e) => return Err(format!("{e:?}")),
        }
    }
}
