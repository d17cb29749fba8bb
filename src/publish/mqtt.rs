//! The MQTT shell (rumqttc, MQTT v5): an event-loop task that only drives the connection and
//! never awaits a publish (that can deadlock rumqttc), and a publisher task that turns bus
//! output into messages. The buses hand output over an unbounded channel: they never wait on
//! MQTT.

use std::time::Duration;

use rumqttc::v5::mqttbytes::QoS;
use rumqttc::v5::mqttbytes::v5::{Filter, PublishProperties, RetainForwardRule};
use rumqttc::v5::mqttbytes::v5::{LastWill, Packet};
use rumqttc::v5::{AsyncClient, Event, EventLoop, MqttOptions};
use tokio::sync::mpsc::{UnboundedReceiver, UnboundedSender};
use tokio::sync::watch;
use tokio_util::sync::CancellationToken;

use super::payload;
use super::topics::Topics;
use crate::config::Mqtt;
use crate::dispatch::Incoming;
use crate::reading::Output;

fn qos(level: u8) -> QoS {
    match level {
        0 => QoS::AtMostOnce,
        2 => QoS::ExactlyOnce,
        _ => QoS::AtLeastOnce,
    }
}

/// Runs MQTT until `shutdown`, then publishes the gateway offline and disconnects. Returns when
/// `output` is closed and drained or shortly after shutdown.
pub async fn run(
    config: Mqtt,
    mut output: UnboundedReceiver<Output>,
    incoming: UnboundedSender<Incoming>,
    shutdown: CancellationToken,
) {
    let topics = Topics::new(&config.topic_root);
    let mut options = MqttOptions::new(config.client_id.clone(), config.host.clone(), config.port);
    options.set_keep_alive(config.keep_alive);
    options.set_last_will(LastWill::new(
        topics.gateway_status(),
        "offline",
        QoS::AtLeastOnce,
        true,
        None,
    ));
    if let Some(user) = &config.username {
        options.set_credentials(user.clone(), config.password.clone().unwrap_or_default());
    }
    let (client, eventloop) = AsyncClient::new(options, 1024);
    let (connected_tx, mut connected) = watch::channel(0u64);
    let loop_stop = CancellationToken::new();
    let events = tokio::spawn(drive(
        eventloop,
        connected_tx,
        incoming,
        loop_stop.clone(),
        format!("{}:{}", config.host, config.port),
    ));

    let reading_qos = qos(config.qos);
    loop {
        tokio::select! {
            biased;
            Ok(()) = connected.changed() => {
                // (Re)connected with a clean session: subscriptions are restored every time.
                // Retained command messages are never forwarded (and ignored if they are).
                let filters = [command_filter(&topics, "+/+/cmd"), command_filter(&topics, "+/cmd")];
                if let Err(e) = client.subscribe_many(filters).await {
                    tracing::error!("cannot subscribe to command topics: {e}");
                }
                // Say we are here. Retained device statuses stay on the broker.
                let _ = client.publish(topics.gateway_status(), QoS::AtLeastOnce, true, "online").await;
            }
            out = output.recv() => {
                let Some(out) = out else { break };
                let (topic, retain, qos, body) = match out {
                    Output::Reading(r) => (topics.reading(&r.device, &r.channel), config.retain, reading_qos, payload::reading(&r)),
                    Output::DeviceStatus { device, online } => (
                        topics.device_status(&device),
                        true,
                        QoS::AtLeastOnce,
                        if online { b"online".to_vec() } else { b"offline".to_vec() },
                    ),
                    Output::BusStats { bus, stats } => (topics.bus_stats(&bus), false, QoS::AtMostOnce, stats.to_string().into_bytes()),
                    Output::CommandResult { topics: to, correlation, payload } => {
                        for (i, t) in to.into_iter().enumerate() {
                            let body = payload.to_string();
                            // The MQTT v5 response topic (after the result topic) gets the
                            // request's correlation data back.
                            let sent = match (&correlation, i) {
                                (Some(c), 1..) => {
                                    let props = PublishProperties { correlation_data: Some(c.clone()), ..Default::default() };
                                    client.publish_with_properties(t, QoS::AtLeastOnce, false, body, props).await
                                }
                                _ => client.publish(t, QoS::AtLeastOnce, false, body).await,
                            };
                            if sent.is_err() {
                                tracing::error!("MQTT client stopped; command result dropped");
                            }
                        }
                        continue;
                    }
                };
                if client.publish(topic, qos, retain, body).await.is_err() {
                    tracing::error!("MQTT client stopped; reading dropped");
                }
            }
            () = shutdown.cancelled(), if !shutdown.is_cancelled() => {}
        }
        if shutdown.is_cancelled() && output.is_empty() {
            // Keep draining what the buses send while they finish; they close the channel.
            if output.is_closed() {
                break;
            }
        }
    }
    let _ = client
        .publish(topics.gateway_status(), QoS::AtLeastOnce, true, "offline")
        .await;
    let _ = client.disconnect().await;
    // Give the event loop a moment to flush the offline status and the disconnect.
    let _ = tokio::time::timeout(Duration::from_secs(2), events).await;
    loop_stop.cancel();
}

fn command_filter(topics: &Topics, tail: &str) -> Filter {
    let mut f = Filter::new(format!("{}/{tail}", topics.root()), QoS::AtLeastOnce);
    f.retain_forward_rule = RetainForwardRule::Never;
    f
}

/// Drives the connection; logs once per state change; reconnects after a pause. Forwards
/// command messages without waiting.
async fn drive(
    mut eventloop: EventLoop,
    connected: watch::Sender<u64>,
    incoming: UnboundedSender<Incoming>,
    stop: CancellationToken,
    broker: String,
) {
    let mut up = None;
    loop {
        let event = tokio::select! {
            e = eventloop.poll() => e,
            () = stop.cancelled() => return,
        };
        match event {
            Ok(Event::Incoming(Packet::ConnAck(_))) => {
                if up != Some(true) {
                    tracing::info!(%broker, "connected to MQTT broker");
                }
                up = Some(true);
                connected.send_modify(|n| *n += 1);
            }
            Ok(Event::Incoming(Packet::Publish(p))) => {
                let props = p.properties.unwrap_or_default();
                let _ = incoming.send(Incoming {
                    topic: String::from_utf8_lossy(&p.topic).into_owned(),
                    payload: p.payload,
                    retain: p.retain,
                    response_topic: props.response_topic,
                    correlation: props.correlation_data,
                });
            }
            Ok(Event::Incoming(Packet::Disconnect(_))) => {}
            Ok(Event::Outgoing(rumqttc::Outgoing::Disconnect)) => return,
            Ok(_) => {}
            Err(rumqttc::v5::ConnectionError::RequestsDone) => return,
            Err(e) => {
                if up != Some(false) {
                    tracing::warn!(%broker, "MQTT broker unreachable: {e}; retrying");
                }
                up = Some(false);
                tokio::select! {
                    () = tokio::time::sleep(Duration::from_secs(1)) => {}
                    () = stop.cancelled() => return,
                }
            }
        }
    }
}
