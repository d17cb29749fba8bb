//! The floor under the gateway's RTU figures in `cargo bench --bench line mbpoll`: the card
//! packages alone, used as plainly as their own examples use them: a tokio current-thread
//! runtime, tokio-serial, tokio-modbus's RTU client and (with a broker port) rumqttc publishing
//! at QoS 1. It polls units 1..=4 as the gateway polls a YL67 (the count block and the
//! frequency block, the 3.5-character silent interval slept on the runtime's timer after each
//! transaction) and, with a broker, publishes the 4 channels of each poll. No decoding, no
//! counter, no outbox: whatever the gateway costs above this, its own code costs.
//!
//! Usage: `rtu_floor <serial port> [<MQTT broker port on 127.0.0.1>]` (9600 baud, 8N1).

use std::time::Duration;

use rumqttc::v5::mqttbytes::QoS;
use rumqttc::v5::{AsyncClient, MqttOptions};
use tokio_modbus::prelude::*;

/// 3.5 characters of 10 bits at 9600 baud.
const SILENT: Duration = Duration::from_micros(3646);
const BLOCKS: [u16; 2] = [16, 128];

fn main() {
    let mut args = std::env::args().skip(1);
    let port = args
        .next()
        .expect("usage: rtu_floor <serial port> [<broker port>]");
    let broker: Option<u16> = args.next().and_then(|p| p.parse().ok());
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("runtime");
    runtime.block_on(poll_forever(port, broker));
}

async fn poll_forever(port: String, broker: Option<u16>) {
    let serial =
        tokio_serial::SerialStream::open(&tokio_serial::new(&port, 9600)).expect("serial port");
    let mut ctx = rtu::attach(serial);
    let client = broker.map(connect);
    let mut seq = 0u64;
    loop {
        for unit in 1..=4u8 {
            ctx.set_slave(Slave(unit));
            let mut words = Vec::with_capacity(16);
            for start in BLOCKS {
                let read = ctx.read_holding_registers(start, 8);
                if let Ok(Ok(Ok(w))) = tokio::time::timeout(Duration::from_millis(100), read).await
                {
                    words.extend(w);
                }
                tokio::time::sleep(SILENT).await;
            }
            let Some(client) = &client else { continue };
            for channel in 0..4 {
                seq += 1;
                let count = words.get(channel * 2).copied().unwrap_or(0);
                let payload = format!(
                    "{{\"count\":{count},\"delta\":0,\"total\":{count},\"unit\":\"count\",\"seq\":{seq}}}"
                );
                let topic = format!("floor/u{unit}/enc{channel}");
                let _ = client
                    .publish(topic, QoS::AtLeastOnce, false, payload)
                    .await;
            }
        }
    }
}

/// A rumqttc v5 client whose event loop runs on its own task, as rumqttc's examples do.
fn connect(port: u16) -> AsyncClient {
    let mut options = MqttOptions::new("rtu-floor", "127.0.0.1", port);
    options.set_keep_alive(Duration::from_secs(30));
    let (client, mut eventloop) = AsyncClient::new(options, 64);
    tokio::spawn(async move {
        loop {
            if eventloop.poll().await.is_err() {
                tokio::time::sleep(Duration::from_millis(200)).await;
            }
        }
    });
    client
}
