//! The output seam from the outside: a format written here, in a test, with nothing but the
//! `Format` trait and the config, says something at every connection and leaves a will with the
//! broker; the MQTT task runs it without knowing it (real Mosquitto).

use std::sync::Arc;
use std::time::Duration;

use pulsegate::outbox::{Message, Will};
use pulsegate::publish::format::Format;
use pulsegate::publish::lifecycle::Lifecycle;
use pulsegate::reading::Output;

use crate::support::*;

/// A toy protocol: `toy/hello` at each connection, `toy/gone` as its will.
struct Toy;

impl Format for Toy {
    fn messages(&mut self, _event: &Output) -> Vec<Message> {
        Vec::new()
    }
}

impl Lifecycle for Toy {
    fn connected(&mut self) -> Vec<Message> {
        vec![Message::new("toy/hello".into(), "hi", 1, false)]
    }

    fn will(&mut self) -> Option<Will> {
        Some(Will {
            topic: "toy/gone".into(),
            payload: bytes::Bytes::from_static(b"bye"),
            qos: 1,
            retain: false,
        })
    }
}

/// Runs the MQTT task with only the toy format on a runtime of its own, until `stop` says so;
/// then the runtime is dropped with the connection open (a crash, as the broker sees it).
fn run_toy(port: u16, dir: &std::path::Path, stop: std::sync::mpsc::Receiver<()>) {
    let text = format!(
        "[gateway]\nid = \"toy\"\nstate_dir = {dir:?}\n[mqtt]\nhost = \"127.0.0.1\"\nport = {port}\n[buses.l]\nhost = \"127.0.0.1\"\nport = 1\n[buses.l.devices.d]\nunit = 1\nmodel = \"yl67\"\n"
    );
    let env = Some(std::collections::HashMap::new());
    let config =
        pulsegate::config::Config::from_toml(&text, &dir.join("toy.toml"), env).expect("config");
    let runtime = tokio::runtime::Runtime::new().unwrap();
    runtime.spawn(async move {
        let health = Arc::new(pulsegate::health::Health::default());
        let task = pulsegate::publish::mqtt::Task {
            name: "toy".into(),
            config: config.mqtt,
            spool_dir: dir_spool(&config.gateway.state_dir),
            flush_every: Duration::from_secs(1),
            heart: health.heart(pulsegate::health::Loop::Output("toy".into())),
            boot: pulsegate::boot::Boot::default(),
            metrics: pulsegate::metrics::OutputMetrics::default(),
            formats: vec![Box::new(Toy)],
            voice: false,
            answers: tokio::sync::mpsc::unbounded_channel().0,
            controls: tokio::sync::mpsc::unbounded_channel().0,
            config_hash: String::new(),
            remote_config: false,
        };
        let (_out, output) = tokio::sync::mpsc::unbounded_channel();
        let (incoming, _commands) = tokio::sync::mpsc::channel(8);
        let (_reload, reloads) = tokio::sync::mpsc::unbounded_channel();
        let shutdown = tokio_util::sync::CancellationToken::new();
        pulsegate::publish::mqtt::run(task, output, incoming, reloads, shutdown).await;
    });
    let _ = stop.recv();
    runtime.shutdown_background();
}

fn dir_spool(state_dir: &std::path::Path) -> std::path::PathBuf {
    state_dir.join("spool")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_toy_format_says_hello_at_connect_and_leaves_its_will() {
    let broker = Broker::start();
    let dir = temp_dir("toy-format");
    let sub = Subscriber::start(broker.port, "toy/#").await;
    let (stop, stopped) = std::sync::mpsc::channel();
    let port = broker.port;
    let gateway = std::thread::spawn(move || run_toy(port, &dir, stopped));
    sub.expect_any("toy/hello", Duration::from_secs(10)).await;
    assert!(sub.on("toy/gone").is_empty(), "no will while connected");
    stop.send(()).unwrap();
    gateway.join().unwrap();
    sub.expect_any("toy/gone", Duration::from_secs(10)).await;
    assert_eq!(sub.on("toy/gone")[0].payload, "bye");
}
