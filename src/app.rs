//! Wires a checked config into running tasks: one per bus, one for MQTT.

use tokio_util::sync::CancellationToken;

use crate::bus::BusTask;
use crate::config::Config;

/// Runs the gateway until `shutdown` is cancelled; then each bus finishes its transaction in
/// flight and saves its state, and MQTT says the gateway is offline.
pub async fn run(config: Config, shutdown: CancellationToken) {
    let (tx, rx) = tokio::sync::mpsc::unbounded_channel();
    let mqtt = tokio::spawn(crate::publish::mqtt::run(
        config.mqtt.clone(),
        rx,
        shutdown.clone(),
    ));
    let mut buses = Vec::new();
    for bus in config.buses.iter().cloned() {
        let task = BusTask::new(bus, &config.gateway, tx.clone());
        buses.push(tokio::spawn(task.run(shutdown.clone())));
    }
    drop(tx);
    for b in buses {
        if let Err(e) = b.await {
            tracing::error!("bus task failed: {e}");
        }
    }
    if let Err(e) = mqtt.await {
        tracing::error!("MQTT task failed: {e}");
    }
}
