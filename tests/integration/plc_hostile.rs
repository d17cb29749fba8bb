//! Hostile and unwelcome clients of the Modbus server output, on raw loopback sockets (the
//! exact bytes) and pymodbus/mbpoll: each is answered or closed, and the readings on MQTT go
//! on with no gap over 2 s; the connections held stay bounded; `allow` keeps out an address
//! not in it.

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::time::{Duration, Instant};

use serde_json::json;

use crate::plc::*;
use crate::support::*;

/// A Modbus TCP frame: transaction 1, protocol 0, unit and PDU.
fn frame(unit: u8, pdu: &[u8]) -> Vec<u8> {
    let mut f = vec![0, 1, 0, 0];
    f.extend_from_slice(&(pdu.len() as u16 + 1).to_be_bytes());
    f.push(unit);
    f.extend_from_slice(pdu);
    f
}

fn connect(addr: SocketAddr) -> TcpStream {
    let s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    s
}

/// What the server says to `bytes` on a connection of their own: its answer (empty when none
/// came within 5 s or it closed) and whether it closed the connection.
fn exchange(addr: SocketAddr, bytes: &[u8]) -> (Vec<u8>, bool) {
    let mut s = connect(addr);
    s.write_all(bytes).unwrap();
    let mut buf = [0u8; 300];
    match s.read(&mut buf) {
        Ok(0) => (Vec::new(), true),
        Ok(n) => (buf[..n].to_vec(), false),
        Err(e) if e.kind() == std::io::ErrorKind::ConnectionReset => (Vec::new(), true),
        Err(_) => (Vec::new(), false),
    }
}

/// The exception a request is answered with (`None`: answered otherwise, or not at all).
fn exception(addr: SocketAddr, unit: u8, pdu: &[u8]) -> Option<u8> {
    let (answer, _) = exchange(addr, &frame(unit, pdu));
    match answer[..] {
        [0, 1, 0, 0, 0, 3, u, f, code] if u == unit && f == pdu[0] | 0x80 => Some(code),
        _ => None,
    }
}

/// Whether the server closed `s` by `deadline` rather than answer or keep it.
fn closed(s: &TcpStream, deadline: Instant) -> bool {
    let left = deadline.saturating_duration_since(Instant::now());
    s.set_read_timeout(Some(left.max(Duration::from_millis(1))))
        .unwrap();
    let mut buf = [0u8; 16];
    match (&*s).read(&mut buf) {
        Ok(0) => true,
        Err(e) => e.kind() == std::io::ErrorKind::ConnectionReset,
        Ok(_) => false,
    }
}

/// The longest time without a reading on `topic` from `since` to now.
fn longest_gap(sub: &Subscriber, topic: &str, since: Instant) -> Duration {
    let mut at: Vec<Instant> = sub
        .on(topic)
        .iter()
        .map(|m| m.at)
        .filter(|t| *t >= since)
        .collect();
    at.insert(0, since);
    at.push(Instant::now());
    at.windows(2).map(|w| w[1] - w[0]).max().unwrap()
}

/// The file descriptors the gateway holds.
fn fds(gw: &Gateway) -> usize {
    std::fs::read_dir(format!("/proc/{}/fd", gw.pid()))
        .map(|d| d.count())
        .unwrap_or(0)
}

/// A value of the gateway's Prometheus exposition.
fn metric(port: u16, series: &str) -> f64 {
    let mut s = connect(SocketAddr::from(([127, 0, 0, 1], port)));
    s.write_all(b"GET /metrics HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n")
        .unwrap();
    let mut text = String::new();
    s.read_to_string(&mut text).unwrap();
    text.lines()
        .find_map(|l| l.strip_prefix(series))
        .and_then(|v| v.trim().parse().ok())
        .unwrap_or(0.0)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn hostile_frames_are_answered_or_closed_while_readings_go_on() {
    let metrics = free_port();
    let setup = Setup {
        server: "max_connections = 16\n",
        extra: &format!("[metrics]\nlisten = \"127.0.0.1:{metrics}\"\n"),
        // The debug build's panic in tokio-modbus's decoder (below) would otherwise print a
        // backtrace, and symbolising this binary holds stderr, and every log line, for
        // seconds; a release build has no such panic.
        wrapper: &["env", "RUST_BACKTRACE=0"],
        ..Setup::default()
    };
    let rig = Rig::start("plc-hostile", setup).await;
    let addr = rig.addr();
    let since = Instant::now();
    let total = rig.address("m", Some("a0"), "total");

    // Not Modbus TCP: protocol id 1, length 0. Closed, no answer.
    let not_modbus = [0, 1, 0, 1, 0, 6, 3, 4, 0, 20, 0, 4];
    assert_eq!(
        exchange(addr, &not_modbus),
        (Vec::new(), true),
        "protocol 1"
    );
    assert_eq!(
        exchange(addr, &[0, 1, 0, 0, 0, 0, 3, 4, 0, 20, 0, 4]),
        (Vec::new(), true),
        "length 0"
    );
    // Function 16 with a register count whose byte count overflows 16 bits: tokio-modbus
    // 0.17's decoder refuses it in a release build; in a debug build its `quantity * 2`
    // overflows and panics in this connection's task only, which tokio ends. No answer either
    // way, and the server goes on (below).
    assert_eq!(
        exchange(addr, &frame(3, &[0x10, 0, 32, 0x80, 0, 0])).0,
        Vec::<u8>::new(),
        "a write of 32768 registers"
    );

    // Functions the server does not have: 01.
    for pdu in [
        &[0x41, 0, 0][..],                // a user-defined code
        &[0x01, 0, 0, 0, 1],              // read coils
        &[0x2B, 0x0E, 1, 0],              // read device identification
        &[0x16, 0, 32, 0xFF, 0xFF, 0, 0], // mask write
    ] {
        assert_eq!(exception(addr, 3, pdu), Some(1), "function {:#04x}", pdu[0]);
    }
    // Outside the map: 02. YL67: 12 channel blocks after the device's, 260 registers.
    assert_eq!(exception(addr, 3, &[0x04, 1, 4, 0, 1]), Some(2), "260");
    assert_eq!(
        exception(addr, 3, &[0x04, 0, 250, 0, 20]),
        Some(2),
        "250..270"
    );
    assert_eq!(
        exception(addr, 3, &[0x03, 0xFF, 0xFF, 0, 1]),
        Some(2),
        "65535"
    );
    // Counts no read may ask for: 03.
    assert_eq!(exception(addr, 3, &[0x04, 0, 0, 0, 126]), Some(3), "126");
    assert_eq!(exception(addr, 3, &[0x04, 0, 0, 0, 0]), Some(3), "0");
    assert_eq!(
        exception(addr, 3, &[0x03, 0, 0, 0x07, 0xD0]),
        Some(3),
        "2000"
    );
    // The same through two real clients.
    let mut py = Pymodbus::connect(rig.port, None);
    assert_eq!(py.read(3, 260, 1).unwrap_err()["exception"], 2);
    let e = mbpoll(rig.port, 3, 3, 300, 4).unwrap_err();
    assert!(e.contains("Illegal data address"), "mbpoll: {e}");

    // A half frame that stalls holds its own connection only.
    let mut stalled = connect(addr);
    stalled
        .write_all(&frame(3, &[0x04, 0, 20, 0, 4])[..9])
        .unwrap();
    tokio::time::sleep(Duration::from_millis(500)).await;
    assert!(
        py.read(3, total, 4).is_ok(),
        "answered beside a stalled frame"
    );

    // Hundreds of connections at once: the 16 newest are held, every older one is closed.
    let before = fds(&rig.gw);
    let mut flood: Vec<TcpStream> = (0..300).map(|_| connect(addr)).collect();
    let newest = flood.split_off(300 - 16);
    let deadline = Instant::now() + Duration::from_secs(10);
    let open = flood.iter().filter(|s| !closed(s, deadline)).count();
    assert_eq!(open, 0, "older connections evicted");
    assert!(closed(&stalled, deadline), "the stalled one too");
    for mut s in newest {
        s.write_all(&frame(3, &[0x04, 0, total as u8, 0, 4]))
            .unwrap();
        let mut answer = [0u8; 17];
        s.read_exact(&mut answer).unwrap();
        assert_eq!(answer[7..9], [0x04, 8], "a held connection is answered");
    }
    let held = fds(&rig.gw);
    assert!(
        held <= before + 16,
        "{held} descriptors, {before} before the flood"
    );
    assert!(
        metric(
            metrics,
            "pulsegate_modbus_server_connections_closed_total{output=\"plc\",reason=\"evicted\"}"
        ) >= 285.0
    );
    assert!(
        metric(
            metrics,
            "pulsegate_modbus_server_connections_closed_total{output=\"plc\",reason=\"bad_frame\"}"
        ) >= 2.0
    );

    // And still a server: a new client reads a total.
    let mut py = Pymodbus::connect(rig.port, None);
    assert!(py.read(3, total, 4).is_ok());
    let gap = longest_gap(&rig.sub, "pulsegate/test/m/a0", since);
    assert!(
        gap <= Duration::from_secs(2),
        "readings stopped for {gap:?}"
    );
}

/// A flood of connections beyond the gateway's file descriptors (here 64, more than its
/// `max_connections` can keep within): accepts fail, the server closes what it holds and
/// listens again, and a client that comes after the flood is served.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_flood_beyond_the_file_descriptors_leaves_the_server_listening() {
    let setup = Setup {
        server: "max_connections = 64\n",
        wrapper: &["prlimit", "--nofile=64:64"],
        ..Setup::default()
    };
    let rig = Rig::start("plc-fd-flood", setup).await;
    let addr = rig.addr();
    let total = rig.address("m", Some("a0"), "total");
    let since = Instant::now();
    let flood: Vec<TcpStream> = (0..200).map(|_| connect(addr)).collect();
    tokio::time::sleep(Duration::from_secs(1)).await;
    drop(flood);
    let deadline = Instant::now() + Duration::from_secs(10);
    let read = loop {
        match tokio_modbus::client::tcp::connect_slave(addr, tokio_modbus::Slave(3)).await {
            Ok(mut ctx) => {
                use tokio_modbus::client::Reader as _;
                if let Ok(Ok(w)) = ctx.read_input_registers(total, 4).await {
                    break Some(i64_of(&w));
                }
            }
            Err(_) if Instant::now() > deadline => break None,
            Err(_) => {}
        }
        if Instant::now() > deadline {
            break None;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    };
    let log = rig.gw.log_text();
    assert!(read.is_some(), "served after the flood:\n{log}");
    assert!(log.contains("could not accept"), "{log}");
    let gap = longest_gap(&rig.sub, "pulsegate/test/m/a0", since);
    assert!(
        gap <= Duration::from_secs(2),
        "readings stopped for {gap:?}"
    );
}

/// `allow = ["127.0.0.2/32"]`: a client from 127.0.0.1 is closed at once, one from 127.0.0.2
/// is served.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn allow_keeps_out_an_address_not_in_it() {
    let setup = Setup {
        server: "allow = [\"127.0.0.2/32\"]\n",
        ..Setup::default()
    };
    let rig = Rig::start("plc-allow", setup).await;
    let total = rig.address("m", Some("a0"), "total");
    let request = frame(3, &[0x04, 0, total as u8, 0, 4]);
    assert_eq!(exchange(rig.addr(), &request), (Vec::new(), true));
    let mut outside = Pymodbus::connect(rig.port, None);
    let a = outside.ask(json!({"op": "read", "unit": 3, "address": total, "count": 4}));
    assert!(a.get("registers").is_none(), "127.0.0.1 read: {a}");
    assert!(
        mbpoll(rig.port, 3, 3, total, 4).is_err(),
        "mbpoll from 127.0.0.1"
    );
    let mut inside = Pymodbus::connect(rig.port, Some("127.0.0.2"));
    let words = inside.read(3, total, 4).expect("served from 127.0.0.2");
    assert!(i64_of(&words) >= 0);
}
