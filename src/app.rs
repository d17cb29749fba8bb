//! Wires a checked config into running tasks: one per bus, one for MQTT, one command router.

use std::collections::HashMap;

use tokio::sync::mpsc::unbounded_channel;
use tokio_util::sync::CancellationToken;

use crate::bus::BusTask;
use crate::config::Config;
use crate::dispatch::Router;

/// Runs the gateway until `shutdown` is cancelled; then each bus finishes its transaction in
/// flight and saves its state, and MQTT says the gateway is offline.
pub async fn run(config: Config, shutdown: CancellationToken) {
    let (out_tx, out_rx) = unbounded_channel();
    let (incoming_tx, incoming_rx) = unbounded_channel();
    let mut bus_commands = HashMap::new();
    let mut buses = Vec::new();
    for bus in config.buses.iter().cloned() {
        let (cmd_tx, cmd_rx) = unbounded_channel();
        bus_commands.insert(bus.name.clone(), cmd_tx);
        let task = BusTask::new(bus, &config.gateway, out_tx.clone(), cmd_rx);
        buses.push(tokio::spawn(task.run(shutdown.clone())));
    }
    let router = Router::new(&config, &bus_commands, out_tx.clone());
    drop(bus_commands);
    let router = tokio::spawn(router.run(incoming_rx));
    let mqtt_config = config.mqtt.clone();
    let spool_dir = config.gateway.state_dir.join("spool");
    let flush = config.gateway.state_flush;
    let mqtt_shutdown = shutdown.clone();
    let mqtt = tokio::spawn(async move {
        crate::publish::mqtt::run(
            mqtt_config,
            &spool_dir,
            flush,
            out_rx,
            incoming_tx,
            mqtt_shutdown,
        )
        .await
    });
    drop(out_tx);
    for b in buses {
        if let Err(e) = b.await {
            tracing::error!("bus task failed: {e}");
        }
    }
    router.abort();
    if let Err(e) = mqtt.await {
        tracing::error!("MQTT task failed: {e}");
    }
}
