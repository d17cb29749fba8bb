//! `pulsegate demo`: a simulated plant of every supported model, the gateway polling it, an
//! MQTT broker (embedded, or one given), and a live table of what reaches the broker.

use std::collections::BTreeMap;
use std::io::{IsTerminal, Write};
use std::path::Path;
use std::time::Duration;

use rumqttc::v5::mqttbytes::QoS;
use rumqttc::v5::mqttbytes::v5::Packet;
use rumqttc::v5::{AsyncClient, Event, MqttOptions};
use tokio_util::sync::CancellationToken;

use crate::config::Config;
use crate::sim::{Plant, SimConfig};

/// The demo could not start.
#[derive(Debug, thiserror::Error)]
pub enum DemoError {
    #[error("{0}")]
    Sim(#[from] crate::sim::SimError),
    #[error("demo config: {0}")]
    Config(#[from] crate::config::ConfigErrors),
    #[error("--mqtt must be HOST:PORT, got {0:?}")]
    BadBroker(String),
    #[error("embedded broker: {0}")]
    Broker(String),
}

/// The simulated plant: two RTU lines on pseudo-terminals and one Modbus TCP hall, all four
/// models (IBF67 shares the YL67 profile), and an M-Bus heat meter on a TCP converter (its
/// energy register rolls over at 10^8 within the first minutes).
fn plant_config() -> SimConfig {
    let mut c = SimConfig::from_toml(include_str!("../config/demo-plant.toml"))
        .expect("demo plant config is valid");
    if let Some(buses) = c.buses_mut() {
        buses.retain(|_, b| !b.devices.is_empty());
    }
    c
}

/// The gateway config for a running plant, its status page on `page`.
fn gateway_config(
    plant: &Plant,
    (host, port): (&str, u16),
    page: std::net::SocketAddr,
    state_dir: &Path,
) -> Result<Config, DemoError> {
    let sim = plant_config();
    let t = crate::sim::gateway::GatewayToml {
        id: "demo",
        state_dir,
        gateway: "stats_interval = \"30s\"\n",
        mqtt_host: host,
        mqtt_port: Some(port),
        mqtt: "",
        serial: "baud = 9600\n",
        tcp: "",
    };
    let meters = sim.every_meter("2s");
    let text = t.render(plant, &sim.every_device("500ms"))
        + &t.meters(plant, &meters, "")
        + &format!("[metrics]\nlisten = \"{page}\"\n");
    Ok(Config::from_toml(
        &text,
        &state_dir.join("demo.toml"),
        Some(Default::default()),
    )?)
}

/// Runs the demo until `shutdown` or `duration`.
pub async fn run(
    broker: Option<&str>,
    duration: Option<Duration>,
    shutdown: CancellationToken,
) -> Result<(), DemoError> {
    let (host, port) = match broker {
        Some(b) => {
            let (h, p) = b
                .rsplit_once(':')
                .ok_or_else(|| DemoError::BadBroker(b.into()))?;
            (
                h.to_string(),
                p.parse().map_err(|_| DemoError::BadBroker(b.into()))?,
            )
        }
        None => {
            start_embedded_broker("127.0.0.1:1883")?;
            ("127.0.0.1".to_string(), 1883)
        }
    };
    let plant = Plant::start(&plant_config()).await?;
    let state_dir = std::env::temp_dir().join(format!("pulsegate-demo-{}", std::process::id()));
    let page = page_address();
    let config = gateway_config(&plant, (&host, port), page, &state_dir)?;
    let root = config.mqtt.topic_root.clone();
    print!("{}", crate::report::poll_plan(&config));
    println!("status page: http://{page}/\n");

    let gateway = tokio::spawn(crate::app::run(config, shutdown.clone()));
    let view = View {
        root,
        page: format!("http://{page}/"),
    };
    let table = tokio::spawn(live_table(host, port, view, shutdown.clone()));
    if let Some(d) = duration {
        tokio::select! {
            () = tokio::time::sleep(d) => shutdown.cancel(),
            () = shutdown.cancelled() => {}
        }
    } else {
        shutdown.cancelled().await;
    }
    let _ = gateway.await;
    let _ = table.await;
    plant.stop();
    let _ = std::fs::remove_dir_all(&state_dir);
    Ok(())
}

/// Where the demo serves its status page: the usual port when it is free, else any free one.
fn page_address() -> std::net::SocketAddr {
    let usual: std::net::SocketAddr = crate::config::metrics::DEFAULT_LISTEN
        .parse()
        .expect("valid default");
    let free = std::net::TcpListener::bind(usual)
        .or_else(|_| std::net::TcpListener::bind("127.0.0.1:0"))
        .and_then(|l| l.local_addr());
    free.unwrap_or(usual)
}

#[cfg(feature = "embedded-broker")]
fn start_embedded_broker(listen: &str) -> Result<(), DemoError> {
    let text = format!(
        r#"
id = 0
[router]
id = 0
max_connections = 100
max_outgoing_packet_count = 200
max_segment_size = 10485760
max_segment_count = 10
[v5.1]
name = "v5-1"
listen = "{listen}"
next_connection_delay_ms = 1
[v5.1.connections]
connection_timeout_ms = 60000
max_payload_size = 20480
max_inflight_count = 100
"#
    );
    let config: rumqttd::Config =
        toml::from_str(&text).map_err(|e| DemoError::Broker(e.to_string()))?;
    if std::net::TcpListener::bind(listen).is_err() {
        return Err(DemoError::Broker(format!(
            "{listen} is in use; stop that broker or pass --mqtt {listen} to use it"
        )));
    }
    std::thread::spawn(move || {
        let mut broker = rumqttd::Broker::new(config);
        if let Err(e) = broker.start() {
            tracing::error!("embedded broker stopped: {e}");
        }
    });
    std::thread::sleep(Duration::from_millis(200));
    Ok(())
}

#[cfg(not(feature = "embedded-broker"))]
fn start_embedded_broker(_listen: &str) -> Result<(), DemoError> {
    Err(DemoError::Broker(
        "this build has no embedded broker (the package leaves it out); pass --mqtt HOST:PORT, \
         or run `cargo run --release --features embedded-broker -- demo`"
            .into(),
    ))
}

/// What the table says besides the readings: the topic root and the status page's address.
struct View {
    root: String,
    page: String,
}

/// Subscribes to the gateway's topics and redraws a table of the latest value per channel.
async fn live_table(host: String, port: u16, view: View, shutdown: CancellationToken) {
    let root = view.root.clone();
    let mut options = MqttOptions::new(
        format!("pulsegate-demo-view-{}", std::process::id()),
        host,
        port,
    );
    options.set_keep_alive(Duration::from_secs(30));
    let (client, mut eventloop) = AsyncClient::new(options, 64);
    let mut latest: BTreeMap<String, String> = BTreeMap::new();
    let mut tick = tokio::time::interval(Duration::from_secs(1));
    let tty = std::io::stdout().is_terminal();
    loop {
        tokio::select! {
            () = shutdown.cancelled() => break,
            _ = tick.tick() => draw(&latest, &view, tty),
            e = eventloop.poll() => match e {
                Ok(Event::Incoming(Packet::ConnAck(_))) => {
                    let _ = client.try_subscribe(format!("{root}/#"), QoS::AtMostOnce);
                }
                Ok(Event::Incoming(Packet::Publish(p))) => {
                    let topic = String::from_utf8_lossy(&p.topic).to_string();
                    let body = String::from_utf8_lossy(&p.payload).to_string();
                    if let Some(rest) = topic.strip_prefix(&format!("{root}/")) {
                        latest.insert(rest.to_string(), body);
                    }
                }
                Ok(_) => {}
                Err(_) => tokio::time::sleep(Duration::from_millis(500)).await,
            },
        }
    }
}

/// The rows of the table: readings only (no statuses, bus stats, the boot marker `gateway`,
/// commands or their results), channels in natural order (di2 before di10).
fn reading_rows(latest: &BTreeMap<String, String>) -> Vec<(&str, &str)> {
    let mut rows: Vec<(&str, &str)> = latest
        .iter()
        .filter(|(topic, _)| {
            let last = topic.rsplit('/').next().unwrap_or_default();
            // `gateway` is the boot marker, `status` the gateway's availability.
            !matches!(topic.as_str(), "gateway" | "status")
                && !topic.starts_with("bus/")
                && !matches!(last, "status" | "cmd" | "result" | "scan")
        })
        .map(|(t, b)| (t.as_str(), b.as_str()))
        .collect();
    rows.sort_by(|a, b| natural_cmp(a.0, b.0));
    rows
}

/// Text with its runs of digits compared as numbers: `di2` < `di10`.
fn natural_cmp(a: &str, b: &str) -> std::cmp::Ordering {
    fn parts(s: &str) -> Vec<(bool, &str)> {
        let mut out = Vec::new();
        let mut start = 0;
        let bytes = s.as_bytes();
        for i in 1..=bytes.len() {
            if i == bytes.len() || bytes[i].is_ascii_digit() != bytes[start].is_ascii_digit() {
                out.push((bytes[start].is_ascii_digit(), &s[start..i]));
                start = i;
            }
        }
        out
    }
    let (pa, pb) = (parts(a), parts(b));
    for (x, y) in pa.iter().zip(&pb) {
        let ord = match (x, y) {
            ((true, x), (true, y)) => {
                let (x, y) = (x.trim_start_matches('0'), y.trim_start_matches('0'));
                x.len().cmp(&y.len()).then_with(|| x.cmp(y))
            }
            ((_, x), (_, y)) => x.cmp(y),
        };
        if ord.is_ne() {
            return ord;
        }
    }
    pa.len().cmp(&pb.len()).then_with(|| a.cmp(b))
}

fn draw(latest: &BTreeMap<String, String>, view: &View, tty: bool) {
    let root = &view.root;
    let mut out = String::new();
    if tty {
        out += "\x1b[2J\x1b[H";
    }
    out += &format!(
        "pulsegate demo: readings under {root}/ (Ctrl-C to stop); status page: {}\n\n",
        view.page
    );
    out += &format!(
        "{:<24} {:>12} {:>8} {:>14} {:>10} {:>9} {:>7} {:>16}  {}\n",
        "device/channel", "count", "delta", "total", "freq_hz", "rpm", "seq", "value", "event"
    );
    for (topic, body) in reading_rows(latest) {
        let v: serde_json::Value = serde_json::from_str(body).unwrap_or_default();
        let f = |k: &str| v.get(k).map(|x| x.to_string()).unwrap_or_default();
        // A value in its unit: a meter register's or gauge's (M-Bus), a scaled channel's.
        let value = match v.get("unit").and_then(|u| u.as_str()) {
            Some(unit) => format!("{} {unit}", f("value")),
            None => f("value"),
        };
        out += &format!(
            "{:<24} {:>12} {:>8} {:>14} {:>10} {:>9} {:>7} {:>16}  {}\n",
            topic,
            f("count"),
            f("delta"),
            f("total"),
            f("freq_hz"),
            f("rpm"),
            f("seq"),
            value,
            v.get("event").and_then(|e| e.as_str()).unwrap_or("")
        );
    }
    let statuses: Vec<String> = latest
        .iter()
        .filter(|(t, _)| t.ends_with("/status") || *t == "status")
        .map(|(t, b)| format!("{t}={b}"))
        .collect();
    out += &format!("\n{}\n", statuses.join("  "));
    let mut stdout = std::io::stdout();
    let _ = stdout.write_all(out.as_bytes());
    let _ = stdout.flush();
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_table_lists_readings_in_natural_order_and_no_gateway_marker_row() {
        let mut latest = BTreeMap::new();
        for topic in [
            "gateway",
            "status",
            "io/status",
            "bus/line1/stats",
            "io/di10",
            "io/di2",
            "io/di1",
            "io/di16",
            "io/di3",
            "io/cmd/result",
            "io/di1/cmd",
            "meter/enc0",
            "meter/enc1",
        ] {
            latest.insert(topic.to_string(), "{}".to_string());
        }
        let rows: Vec<&str> = reading_rows(&latest).into_iter().map(|r| r.0).collect();
        assert_eq!(
            rows,
            [
                "io/di1",
                "io/di2",
                "io/di3",
                "io/di10",
                "io/di16",
                "meter/enc0",
                "meter/enc1"
            ]
        );
    }

    #[test]
    fn natural_order_compares_digit_runs_as_numbers() {
        use std::cmp::Ordering::*;
        assert_eq!(natural_cmp("di2", "di10"), Less);
        assert_eq!(natural_cmp("di10", "di9"), Greater);
        assert_eq!(natural_cmp("a/x2", "a/x02"), Greater, "ties broken as text");
        assert_eq!(natural_cmp("enc0", "enc0"), Equal);
        assert_eq!(natural_cmp("", "a"), Less);
    }
}
