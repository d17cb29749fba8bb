//! The Modbus server output against real Modbus clients: tokio-modbus here, pymodbus and mbpoll
//! (libmodbus) from other projects, a real Mosquitto for the MQTT totals it is compared with,
//! the simulator on pseudo-terminals for the modules.

use std::time::Duration;

use tokio_modbus::client::Reader as _;

use crate::support::*;

/// One YL67 counting on `a0` at 200 Hz.
const ONE: &str = "[buses.line1.devices.m]\nunit = 3\nmodel = \"yl67\"\nmodes = [1, 1, 1, 1]\nchannels.a0 = { count = 0, rate = 200.0 }\n";

pub(crate) fn server_toml(port: u16, extra: &str) -> String {
    format!(
        "[outputs.json]\nkind = \"json\"\n[outputs.plc]\nkind = \"modbus\"\nlisten = \"127.0.0.1:{port}\"\n{extra}"
    )
}

/// The i64 of four registers, high word first.
pub(crate) fn i64_of(w: &[u16]) -> i64 {
    w.iter().fold(0i64, |acc, x| (acc << 16) | i64::from(*x))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_plc_reads_the_total_the_gateway_publishes() {
    let broker = Broker::start();
    let plant = plant(ONE).await;
    let dir = temp_dir("plc-total");
    let port = free_port();
    let devices = [("line1", "m", 3, "yl67", "100ms")];
    let text = gateway_toml(&plant, broker.port, &dir, &devices, &server_toml(port, ""));
    let config = write_config(&dir, &text);
    let sub = Subscriber::start(broker.port, "pulsegate/test/m/a0").await;
    let gw = Gateway::start(&config);
    sub.expect_any("pulsegate/test/m/a0", Duration::from_secs(10))
        .await;
    let addr = format!("127.0.0.1:{port}").parse().unwrap();
    let mut ctx = tokio_modbus::client::tcp::connect_slave(addr, tokio_modbus::Slave(3))
        .await
        .unwrap();
    let head = ctx.read_input_registers(0, 3).await.unwrap().unwrap();
    assert_eq!(head[0], 1, "online: {head:?} {}", gw.log_text());
    // a0 is the YL67's channel of index k in its profile: find it in the map.
    let map = std::process::Command::new(bin())
        .args(["check", "--config"])
        .arg(&config)
        .args(["--register-map", "--json"])
        .output()
        .unwrap();
    let entries: serde_json::Value = serde_json::from_slice(&map.stdout).unwrap();
    let total = entries
        .as_array()
        .unwrap()
        .iter()
        .find(|e| e["channel"] == "a0" && e["field"] == "total" && e["table"] == "input")
        .unwrap();
    let address = total["address"].as_u64().unwrap() as u16;
    let before = sub.on("pulsegate/test/m/a0").last().unwrap().json()["total"]
        .as_i64()
        .unwrap();
    let words = ctx.read_input_registers(address, 4).await.unwrap().unwrap();
    let read = i64_of(&words);
    tokio::time::sleep(Duration::from_millis(300)).await;
    let after = sub.on("pulsegate/test/m/a0").last().unwrap().json()["total"]
        .as_i64()
        .unwrap();
    assert!(
        before <= read && read <= after,
        "{before} <= {read} <= {after}"
    );
    let e = ctx.read_input_registers(0, 3).await;
    println!("{e:?}");
    let unknown = tokio_modbus::client::tcp::connect_slave(addr, tokio_modbus::Slave(9))
        .await
        .unwrap()
        .read_input_registers(0, 1)
        .await
        .unwrap();
    assert_eq!(
        unknown,
        Err(tokio_modbus::ExceptionCode::GatewayTargetDevice)
    );
}
