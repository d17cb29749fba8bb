use std::sync::Arc;
use std::time::{Duration, SystemTime};

use super::*;
use crate::counter::Update;

fn reading(device: &str, channel: &str, total: i64, rate: f64, encoder: bool) -> Reading {
    Reading {
        device: Arc::from(device),
        channel: Arc::from(channel),
        ts: SystemTime::now(),
        count: total,
        freq_hz: None,
        rpm: None,
        after_seq: None,
        meter: None,
        kind: if encoder {
            crate::profile::ChannelKind::Encoder
        } else {
            crate::profile::ChannelKind::Counter
        },
        units: None,
        update: Update {
            delta: 0,
            total,
            seq: 1,
            rate_hz: Some(rate),
            event: None,
        },
        measured: None,
    }
}

fn line<'a>(text: &'a str, start: &str) -> &'a str {
    text.lines()
        .find(|l| l.starts_with(start))
        .unwrap_or_else(|| panic!("no line starting {start} in\n{text}"))
}

#[test]
fn a_device_that_goes_offline_shows_up_0_with_its_bus_and_device_labels() {
    let m = Metrics::new();
    let d = m.bus("line1").device("press1");
    d.up(Some(true));
    assert!(
        m.encode()
            .contains("pulsegate_device_up{bus=\"line1\",device=\"press1\"} 1")
    );
    d.up(Some(false));
    assert!(
        m.encode()
            .contains("pulsegate_device_up{bus=\"line1\",device=\"press1\"} 0")
    );
}

#[test]
fn a_devices_transactions_are_the_link_counters_it_moved() {
    let m = Metrics::new();
    let d = m.bus("line1").device("press1");
    let before = WireCounters {
        transactions: 10,
        timeouts: 1,
        ..Default::default()
    };
    let after = WireCounters {
        transactions: 13,
        timeouts: 2,
        garbled: 1,
        exceptions: 1,
        ..Default::default()
    };
    d.wire(&before, &after);
    let text = m.encode();
    let labels = "{bus=\"line1\",device=\"press1\"}";
    for (name, v) in [
        ("pulsegate_device_transactions_total", 3),
        ("pulsegate_device_timeouts_total", 1),
        ("pulsegate_device_garbled_answers_total", 1),
        ("pulsegate_device_exception_answers_total", 1),
    ] {
        assert_eq!(
            line(&text, &format!("{name}{labels}")),
            format!("{name}{labels} {v}")
        );
    }
}

#[test]
fn bus_counters_never_go_backwards_when_a_restarted_bus_task_starts_from_zero() {
    let m = Metrics::new();
    let mut first = m.bus("line1");
    let c = WireCounters {
        transactions: 100,
        reconnects: 2,
        ..Default::default()
    };
    first.wire(&c, Duration::from_millis(1500));
    // A config reload restarts the bus task: its link counts from zero again.
    let mut second = m.bus("line1");
    second.wire(
        &WireCounters {
            transactions: 5,
            ..Default::default()
        },
        Duration::from_millis(500),
    );
    let text = m.encode();
    assert_eq!(
        line(&text, "pulsegate_bus_transactions_total{"),
        "pulsegate_bus_transactions_total{bus=\"line1\"} 105"
    );
    assert_eq!(
        line(&text, "pulsegate_bus_busy_seconds_total{"),
        "pulsegate_bus_busy_seconds_total{bus=\"line1\"} 2"
    );
}

#[test]
fn inputs_are_counters_and_encoders_are_positions_that_may_go_negative() {
    let m = Metrics::new();
    let mut d = m.bus("line1").device("press1");
    d.reading(&reading("press1", "a2", 1618, 250.0, false));
    d.reading(&reading("press1", "a2", 1700, 41.0, false));
    d.reading(&reading("press1", "enc0", -13680, -120.0, true));
    let text = m.encode();
    assert!(text.contains(
        "pulsegate_channel_pulses_total{bus=\"line1\",channel=\"a2\",device=\"press1\"} 1700"
    ));
    assert!(text.contains(
        "pulsegate_channel_position_pulses{bus=\"line1\",channel=\"enc0\",device=\"press1\"} -13680"
    ));
    assert!(text.contains(
        "pulsegate_channel_rate_hertz{bus=\"line1\",channel=\"a2\",device=\"press1\"} 41"
    ));
    assert!(text.contains("# TYPE pulsegate_channel_pulses_total counter"));
    assert!(text.contains("# TYPE pulsegate_channel_position_pulses gauge"));
}

#[test]
fn refused_commands_are_counted_by_error_code() {
    let m = Metrics::new();
    use crate::command::CommandError;
    use crate::outcome::{CommandOutcome, Outcome, ScanOutcome, ScanReport};
    let command = |result| {
        Outcome::Command(CommandOutcome {
            id: None,
            op: Some("clear".into()),
            result,
        })
    };
    m.command_result(&command(Ok(None)));
    m.command_result(&command(Err(CommandError::Offline("press1".into()))));
    m.command_result(&command(Err(CommandError::NotJson("x".into()))));
    // A scan's report has no `ok` key: read as JSON, it once counted as a refusal.
    m.command_result(&Outcome::Scan(ScanOutcome::Report(ScanReport {
        bus: "line1".into(),
        found: Vec::new(),
        configured: Vec::new(),
        asked: 247,
        complete: true,
        elapsed_ms: 9000,
        id: None,
    })));
    let text = m.encode();
    assert!(text.contains("pulsegate_commands_received_total 4"));
    assert!(
        !text.contains("code=\"unknown\""),
        "a successful scan moves no refusal counter: {text}"
    );
    assert!(text.contains("pulsegate_commands_refused_total{code=\"offline\"} 1"));
    assert!(text.contains("pulsegate_commands_refused_total{code=\"bad_json\"} 1"));
}

#[test]
fn the_spool_and_mqtt_state_are_sampled_and_drops_only_count_up() {
    let m = Metrics::new();
    let sample = |messages, bytes| crate::metrics::OutputSample {
        spool_messages: messages,
        spool_bytes: bytes,
        spool_dropped: 3,
        spool_write_failures: 2,
        ..Default::default()
    };
    m.output("json").sample(&sample(42, 4096));
    m.output("json").sample(&sample(43, 4200));
    m.output("scada").sample(&crate::metrics::OutputSample {
        connected: true,
        held: true,
        ..Default::default()
    });
    let text = m.encode();
    assert!(text.contains("pulsegate_mqtt_connected{output=\"json\"} 0"));
    assert!(text.contains("pulsegate_spool_messages{output=\"json\"} 43"));
    assert!(text.contains("pulsegate_spool_bytes{output=\"json\"} 4200"));
    assert!(text.contains("pulsegate_spool_dropped_messages_total{output=\"json\"} 3"));
    assert!(text.contains("pulsegate_spool_write_failures_total{output=\"json\"} 2"));
    assert!(text.contains("pulsegate_mqtt_connected{output=\"scada\"} 1"));
    assert!(text.contains("pulsegate_mqtt_held{output=\"scada\"} 1"));
}

#[test]
fn latency_is_a_histogram_in_seconds_and_build_info_names_the_version() {
    let m = Metrics::new();
    m.bus("line1")
        .device("press1")
        .latency(Duration::from_millis(36));
    let text = m.encode();
    assert!(text.contains("# TYPE pulsegate_device_latency_seconds histogram"));
    assert!(text.contains(
        "pulsegate_device_latency_seconds_bucket{bus=\"line1\",device=\"press1\",le=\"0.05\"} 1"
    ));
    assert!(text.contains(
        "pulsegate_device_latency_seconds_bucket{bus=\"line1\",device=\"press1\",le=\"0.025\"} 0"
    ));
    assert!(text.contains(&format!(
        "pulsegate_build_info{{version=\"{}\"}} 1",
        env!("CARGO_PKG_VERSION")
    )));
    assert!(text.contains("# TYPE process_start_time_seconds gauge"));
}

#[test]
fn metrics_that_are_off_record_nothing_and_expose_nothing() {
    let m = Metrics::disabled();
    let mut bus = m.bus("line1");
    let mut d = bus.device("press1");
    d.up(Some(true));
    d.reading(&reading("press1", "a2", 5, 1.0, false));
    bus.wire(&WireCounters::default(), Duration::from_secs(1));
    m.output("json").sample(&crate::metrics::OutputSample {
        connected: true,
        ..Default::default()
    });
    assert_eq!(m.encode(), "");
}

#[test]
fn a_devices_request_size_shows_the_limit_and_the_requests_of_a_poll() {
    let m = Metrics::new();
    let d = m.bus("line1").device("doors");
    d.request_size(125, 2);
    let text = m.encode();
    assert!(
        text.contains(
            "pulsegate_device_request_limit_registers{bus=\"line1\",device=\"doors\"} 125"
        )
    );
    assert!(text.contains("pulsegate_device_requests_per_poll{bus=\"line1\",device=\"doors\"} 2"));
    d.request_size(1, 48);
    let text = m.encode();
    assert!(
        text.contains("pulsegate_device_request_limit_registers{bus=\"line1\",device=\"doors\"} 1")
    );
}

fn config(text: &str) -> Config {
    Config::from_toml(
        text,
        std::path::Path::new("/etc/pulsegate.toml"),
        Some(Default::default()),
    )
    .unwrap()
}

#[test]
fn a_reload_forgets_every_series_of_a_device_channel_or_bus_that_is_gone() {
    let before = config(
        "[buses.line1]\nport = \"/dev/ttyUSB0\"\n\
         [buses.line1.devices.m1]\nunit = 1\nmodel = \"yl67\"\n\
         [buses.line1.devices.m3]\nunit = 3\nmodel = \"yl67\"\n\
         [buses.line2]\nport = \"/dev/ttyUSB1\"\n\
         [buses.line2.devices.m9]\nunit = 9\nmodel = \"yl67\"\n",
    );
    let m = Metrics::new();
    let mut handles = Vec::new();
    for (bus, device) in [("line1", "m1"), ("line1", "m3"), ("line2", "m9")] {
        let b = m.bus(bus);
        b.utilisation(0.5);
        let mut d = b.device(device);
        d.up(Some(true));
        d.latency(Duration::from_millis(30));
        d.request_size(8, 10);
        d.reading(&reading(device, "a0", 5, 1.0, false));
        d.reading(&reading(device, "gone0", 5, 1.0, false));
        handles.push(d);
    }
    m.retain(&before);
    let text = m.encode();
    assert!(
        !text.contains("gone0"),
        "a channel the model does not have:\n{text}"
    );
    assert!(text.contains("device=\"m3\""));

    let after = config(
        "[buses.line1]\nport = \"/dev/ttyUSB0\"\n\
         [buses.line1.devices.m1]\nunit = 1\nmodel = \"yl67\"\n\
         [buses.line1.devices.m1.channels.a1]\nenabled = false\n",
    );
    let mut m1 = m.bus("line1").device("m1");
    m1.reading(&reading("m1", "a1", 5, 1.0, false));
    m.retain(&after);
    let text = m.encode();
    for gone in ["\"m3\"", "\"m9\"", "\"line2\"", "\"a1\""] {
        assert!(!text.contains(gone), "{gone} is still exported:\n{text}");
    }
    assert!(
        text.contains("pulsegate_device_up{bus=\"line1\",device=\"m1\"} 1")
            && text.contains("channel=\"a0\",device=\"m1\"")
            && text.contains("{bus=\"line1\"}"),
        "what stays is kept:\n{text}"
    );
}

#[test]
fn refused_tokens_are_counted_by_result_and_both_results_show_0_from_the_start() {
    let m = Metrics::new();
    let text = m.encode();
    assert!(text.contains("pulsegate_http_login_failures_total{result=\"wrong_token\"} 0"));
    assert!(text.contains("pulsegate_http_login_failures_total{result=\"limited\"} 0"));
    m.login_failure(LoginFailure::WrongToken);
    m.login_failure(LoginFailure::Limited);
    m.login_failure(LoginFailure::Limited);
    let text = m.encode();
    assert!(text.contains("pulsegate_http_login_failures_total{result=\"wrong_token\"} 1"));
    assert!(text.contains("pulsegate_http_login_failures_total{result=\"limited\"} 2"));
}

#[test]
fn a_devices_last_answer_is_a_series_the_page_reads_as_prometheus_does() {
    let m = Metrics::new();
    let d = m.bus("line1").device("press1");
    let _quiet = m.bus("line1").device("press2");
    let looks = m.device_looks();
    let quiet = looks[&("line1".to_string(), "press2".to_string())];
    assert_eq!(quiet.last_answer_ms, None, "never answered");
    assert_eq!(quiet.mean_latency_ms, None);
    let before = SystemTime::now()
        .duration_since(SystemTime::UNIX_EPOCH)
        .unwrap()
        .as_millis() as u64;
    d.latency(Duration::from_millis(40));
    d.latency(Duration::from_millis(20));
    let text = m.encode();
    assert!(
        text.contains(
            "pulsegate_device_last_latency_seconds{bus=\"line1\",device=\"press1\"} 0.02"
        ),
        "{text}"
    );
    let stamp: f64 = line(
        &text,
        "pulsegate_device_last_answer_timestamp_seconds{bus=\"line1\",device=\"press1\"}",
    )
    .rsplit(' ')
    .next()
    .unwrap()
    .parse()
    .unwrap();
    assert!(
        stamp * 1000.0 >= before as f64 - 1.0,
        "{stamp} after {before}"
    );
    let look = m.device_looks()[&("line1".to_string(), "press1".to_string())];
    assert_eq!(look.last_answer_ms, Some((stamp * 1000.0) as u64));
    assert!((look.last_latency_ms.unwrap() - 20.0).abs() < 1e-9);
    assert!((look.mean_latency_ms.unwrap() - 30.0).abs() < 1e-9);
    assert!(
        !m.device_looks()
            .contains_key(&("line1".to_string(), "press9".to_string())),
        "a device whose bus made no series has no look (and asking makes none)"
    );
    assert!(!m.encode().contains("press9"));
}
