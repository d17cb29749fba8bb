//! The metric families, their names, help texts, labels and histogram buckets: the one place
//! that defines what `/metrics` shows.

use std::collections::BTreeSet;

use prometheus::{
    CounterVec, Gauge, GaugeVec, HistogramOpts, HistogramVec, IntCounter, IntCounterVec,
    IntGaugeVec, Opts, Registry,
};

const BUS: &[&str] = &["bus"];
const DEVICE: &[&str] = &["bus", "device"];
const CHANNEL: &[&str] = &["bus", "device", "channel"];
const OUTPUT: &[&str] = &["output"];

/// Transaction latency buckets (seconds): a 9600-baud read takes 30–60 ms, a timeout
/// hundreds; TCP answers in a millisecond or two.
const LATENCY_BUCKETS: &[f64] = &[
    0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5,
];

pub(super) struct Families {
    pub channel_pulses: IntCounterVec,
    pub channel_position: IntGaugeVec,
    pub channel_rate: GaugeVec,
    pub device_up: IntGaugeVec,
    pub device_wrong_model: IntGaugeVec,
    pub device_transactions: IntCounterVec,
    pub device_timeouts: IntCounterVec,
    pub device_garbled: IntCounterVec,
    pub device_exceptions: IntCounterVec,
    pub device_latency: HistogramVec,
    pub device_last_answer: GaugeVec,
    pub device_last_latency: GaugeVec,
    pub device_request_limit: IntGaugeVec,
    pub device_requests_per_poll: IntGaugeVec,
    pub bus_transactions: IntCounterVec,
    pub bus_reconnects: IntCounterVec,
    pub bus_line_faults: IntCounterVec,
    pub bus_busy: CounterVec,
    pub bus_utilisation: GaugeVec,
    pub mqtt_connected: IntGaugeVec,
    pub mqtt_held: IntGaugeVec,
    pub output_events: IntCounterVec,
    pub tls_expiry: IntGaugeVec,
    pub config_info: IntGaugeVec,
    pub spool_messages: IntGaugeVec,
    pub spool_bytes: IntGaugeVec,
    pub spool_dropped: IntCounterVec,
    pub spool_fallback: IntGaugeVec,
    pub spool_written: IntCounterVec,
    pub spool_write_failures: IntCounterVec,
    pub spool_unreadable_lines: IntCounterVec,
    pub chatter_messages: IntGaugeVec,
    pub chatter_dropped: IntCounterVec,
    pub messages_dropped: IntCounterVec,
    pub server_requests: IntCounterVec,
    pub server_connections: IntGaugeVec,
    pub server_closed: IntCounterVec,
    pub commands_received: IntCounter,
    pub commands_refused: IntCounterVec,
    pub http_login_failures: IntCounterVec,
    pub start_time: Gauge,
    pub build_info: IntGaugeVec,
}

/// Registers `m` with `r`; our names are fixed and unique, so registering cannot fail.
fn reg<M: prometheus::core::Collector + Clone + 'static>(r: &Registry, m: M) -> M {
    r.register(Box::new(m.clone()))
        .expect("metric families are registered once");
    m
}

fn opts(name: &str, help: &str) -> Opts {
    Opts::new(name, help)
}

/// A family's name and help text.
type Family = (&'static str, &'static str);

macro_rules! family {
    ($r:expr, $ty:ident, $family:expr, $labels:expr) => {
        reg(
            $r,
            $ty::new(opts($family.0, $family.1), $labels).expect("valid metric name"),
        )
    };
    ($r:expr, $ty:ident, $family:expr) => {
        reg(
            $r,
            $ty::with_opts(opts($family.0, $family.1)).expect("valid metric name"),
        )
    };
}

const CHANNEL_PULSES: Family = (
    "pulsegate_channel_pulses_total",
    "Pulses counted on an input counting on its own (running total, survives wrap, resets and restarts).",
);
const CHANNEL_POSITION: Family = (
    "pulsegate_channel_position_pulses",
    "An encoder's position: the running sum of its signed deltas.",
);
const CHANNEL_RATE: Family = (
    "pulsegate_channel_rate_hertz",
    "Pulses per second between the channel's last two readings.",
);
const DEVICE_UP: Family = (
    "pulsegate_device_up",
    "1 while the device answers (online), 0 when offline or not yet seen.",
);
const DEVICE_WRONG_MODEL: Family = (
    "pulsegate_device_wrong_model",
    "1 when the module identifies as another model than configured.",
);
const DEVICE_LAST_ANSWER: Family = (
    "pulsegate_device_last_answer_timestamp_seconds",
    "Unix time of the device's last good answer (0 before the first): alert on time() minus it.",
);
const DEVICE_LAST_LATENCY: Family = (
    "pulsegate_device_last_latency_seconds",
    "Time from request to answer of the device's last good answer.",
);
const DEVICE_TRANSACTIONS: Family = (
    "pulsegate_device_transactions_total",
    "Transactions with the device (polls and commands).",
);
const DEVICE_TIMEOUTS: Family = (
    "pulsegate_device_timeouts_total",
    "Transactions the device did not answer in time.",
);
const DEVICE_GARBLED: Family = (
    "pulsegate_device_garbled_answers_total",
    "Answers that arrived garbled (bad CRC, cut short).",
);
const DEVICE_EXCEPTIONS: Family = (
    "pulsegate_device_exception_answers_total",
    "Answers in which the device refused the request (an exception answer).",
);
const DEVICE_REQUEST_LIMIT: Family = (
    "pulsegate_device_request_limit_registers",
    "The longest read the device's poll may use now: 125 on a clean line, fewer after answers lost to noise.",
);
const DEVICE_REQUESTS_PER_POLL: Family = (
    "pulsegate_device_requests_per_poll",
    "Requests one count poll of the device takes now (more while reads are shortened).",
);
const BUS_TRANSACTIONS: Family = (
    "pulsegate_bus_transactions_total",
    "Transactions on the bus.",
);
const BUS_RECONNECTS: Family = (
    "pulsegate_bus_reconnects_total",
    "Times the bus's port or TCP connection was (re)opened.",
);
const BUS_LINE_FAULTS: Family = (
    "pulsegate_bus_line_faults_total",
    "Line faults (adapter gone, port or connection failing), counted when each starts.",
);
const BUS_BUSY: Family = (
    "pulsegate_bus_busy_seconds_total",
    "Time the line was busy with transactions; its rate is the line utilisation.",
);
const BUS_UTILISATION: Family = (
    "pulsegate_bus_utilisation_ratio",
    "Share of the last stats interval the line was busy.",
);
const MQTT_CONNECTED: Family = (
    "pulsegate_mqtt_connected",
    "1 while the output's connection to its MQTT broker is up.",
);
const MQTT_HELD: Family = (
    "pulsegate_mqtt_held",
    "1 while the output holds what it would publish (its protocol waits, e.g. for a primary host).",
);
const OUTPUT_EVENTS: Family = (
    "pulsegate_output_protocol_events_total",
    "Events of an output's protocol, by name: STATE messages of a host ignored (stale or malformed), rebirths asked for and done.",
);
const CONFIG_INFO: Family = (
    "pulsegate_config_info",
    "Always 1; the hash of the config in force is a label (the same config, the same hash at every start).",
);
const TLS_EXPIRY: Family = (
    "pulsegate_tls_certificate_expiry_timestamp_seconds",
    "When a TLS certificate the gateway uses (a client certificate, a CA) expires: its notAfter, seconds since the Unix epoch.",
);
const SPOOL_MESSAGES: Family = (
    "pulsegate_spool_messages",
    "Messages waiting in the store-and-forward spool.",
);
const SPOOL_BYTES: Family = (
    "pulsegate_spool_bytes",
    "Bytes the spool's messages take (memory and disk).",
);
const SPOOL_DROPPED: Family = (
    "pulsegate_spool_dropped_messages_total",
    "Oldest messages dropped because the spool was full, or because memory's share for messages the disk refused was.",
);
const SPOOL_FALLBACK: Family = (
    "pulsegate_spool_private_fallback",
    "1 while the spool is in a fresh private temporary directory because <state_dir>/spool could not be used (lost at reboot).",
);
const SPOOL_WRITTEN: Family = (
    "pulsegate_spool_written_bytes_total",
    "Bytes written to the spool's files (while the broker is away, and at checkpoints a stalled broker leaves unacknowledged).",
);
const SPOOL_WRITE_FAILURES: Family = (
    "pulsegate_spool_write_failures_total",
    "Writes or syncs of the spool's files that failed (disk full, I/O error, permissions): their messages stayed in memory (tried again at the next flush) or were dropped and counted in pulsegate_spool_dropped_messages_total; never counted as on disk.",
);
const SPOOL_UNREADABLE_LINES: Family = (
    "pulsegate_spool_unreadable_lines_total",
    "Lines of spool files that were not a stored message (not UTF-8, not an entry): skipped, the rest of the file sent, the file kept as <name>.unreadable.",
);
const CHATTER_MESSAGES: Family = (
    "pulsegate_mqtt_chatter_messages",
    "Messages the gateway can make again (discovery configs, results, bus stats) waiting for the broker.",
);
const CHATTER_DROPPED: Family = (
    "pulsegate_mqtt_chatter_dropped_total",
    "Oldest chatter messages dropped to keep their bound (readings are never dropped for them).",
);
const MESSAGES_DROPPED: Family = (
    "pulsegate_mqtt_messages_dropped_total",
    "Incoming MQTT messages dropped unread, by reason (too_large: larger than the largest packet the gateway takes); the connection stays up.",
);
const COMMANDS_RECEIVED: Family = (
    "pulsegate_commands_received_total",
    "Commands answered (a retained command message is ignored, not counted).",
);
const COMMANDS_REFUSED: Family = (
    "pulsegate_commands_refused_total",
    "Commands answered with an error, by error code.",
);
const HTTP_LOGIN_FAILURES: Family = (
    "pulsegate_http_login_failures_total",
    "Tokens the status page and its API refused (a login form's, a bearer, the cookie), by result: wrong_token (checked, wrong), limited (not checked: the client gave too many wrong ones and is locked out, answered 429).",
);
const START_TIME: Family = (
    "process_start_time_seconds",
    "Start time of the process since the Unix epoch, in seconds.",
);
const BUILD_INFO: Family = ("pulsegate_build_info", "Always 1; the version is a label.");

/// Why the status page or its API refused a token (`pulsegate_http_login_failures_total`'s
/// `result`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LoginFailure {
    /// Checked, and not the token.
    WrongToken,
    /// Not checked: its client is locked out after too many wrong ones (answered 429).
    Limited,
}

impl LoginFailure {
    pub const ALL: [LoginFailure; 2] = [LoginFailure::WrongToken, LoginFailure::Limited];

    /// Its `result` label.
    pub fn label(self) -> &'static str {
        match self {
            LoginFailure::WrongToken => "wrong_token",
            LoginFailure::Limited => "limited",
        }
    }
}

/// The login failures' family, both results at 0 from the start (a rate over a series that
/// appears with its first failure misses that failure).
fn login_failures(r: &Registry) -> IntCounterVec {
    let f = family!(r, IntCounterVec, HTTP_LOGIN_FAILURES, &["result"]);
    for result in LoginFailure::ALL {
        f.with_label_values(&[result.label()]);
    }
    f
}

/// Series of buses, devices and channels that are gone (see `Metrics::retain`).
#[derive(Default)]
pub(super) struct Gone {
    pub buses: BTreeSet<String>,
    pub devices: BTreeSet<(String, String)>,
    pub channels: BTreeSet<(String, String, String)>,
}

impl Families {
    /// Removes the series of what is gone from every family labelled with it.
    pub fn forget(&self, gone: &Gone) {
        // A series never created is not there to remove: the error says only that.
        for (b, d, c) in &gone.channels {
            let l = [b.as_str(), d.as_str(), c.as_str()];
            let _ = self.channel_pulses.remove_label_values(&l);
            let _ = self.channel_position.remove_label_values(&l);
            let _ = self.channel_rate.remove_label_values(&l);
        }
        for (b, d) in &gone.devices {
            let l = [b.as_str(), d.as_str()];
            let _ = self.device_up.remove_label_values(&l);
            let _ = self.device_wrong_model.remove_label_values(&l);
            let _ = self.device_transactions.remove_label_values(&l);
            let _ = self.device_timeouts.remove_label_values(&l);
            let _ = self.device_garbled.remove_label_values(&l);
            let _ = self.device_exceptions.remove_label_values(&l);
            let _ = self.device_latency.remove_label_values(&l);
            let _ = self.device_last_answer.remove_label_values(&l);
            let _ = self.device_last_latency.remove_label_values(&l);
            let _ = self.device_request_limit.remove_label_values(&l);
            let _ = self.device_requests_per_poll.remove_label_values(&l);
        }
        for b in &gone.buses {
            let l = [b.as_str()];
            let _ = self.bus_transactions.remove_label_values(&l);
            let _ = self.bus_reconnects.remove_label_values(&l);
            let _ = self.bus_line_faults.remove_label_values(&l);
            let _ = self.bus_busy.remove_label_values(&l);
            let _ = self.bus_utilisation.remove_label_values(&l);
        }
    }

    /// Every family, registered in `r`; `server` names the serving output's three (requests,
    /// connections, connections closed), which its protocol's file defines.
    pub fn register(r: &Registry, server: [Family; 3]) -> Families {
        Families {
            channel_pulses: family!(r, IntCounterVec, CHANNEL_PULSES, CHANNEL),
            channel_position: family!(r, IntGaugeVec, CHANNEL_POSITION, CHANNEL),
            channel_rate: family!(r, GaugeVec, CHANNEL_RATE, CHANNEL),
            device_up: family!(r, IntGaugeVec, DEVICE_UP, DEVICE),
            device_wrong_model: family!(r, IntGaugeVec, DEVICE_WRONG_MODEL, DEVICE),
            device_transactions: family!(r, IntCounterVec, DEVICE_TRANSACTIONS, DEVICE),
            device_timeouts: family!(r, IntCounterVec, DEVICE_TIMEOUTS, DEVICE),
            device_garbled: family!(r, IntCounterVec, DEVICE_GARBLED, DEVICE),
            device_exceptions: family!(r, IntCounterVec, DEVICE_EXCEPTIONS, DEVICE),
            device_latency: reg(
                r,
                HistogramVec::new(
                    HistogramOpts::new(
                        "pulsegate_device_latency_seconds",
                        "Time from request to a good answer, per transaction.",
                    )
                    .buckets(LATENCY_BUCKETS.to_vec()),
                    DEVICE,
                )
                .expect("valid histogram"),
            ),
            device_last_answer: family!(r, GaugeVec, DEVICE_LAST_ANSWER, DEVICE),
            device_last_latency: family!(r, GaugeVec, DEVICE_LAST_LATENCY, DEVICE),
            device_request_limit: family!(r, IntGaugeVec, DEVICE_REQUEST_LIMIT, DEVICE),
            device_requests_per_poll: family!(r, IntGaugeVec, DEVICE_REQUESTS_PER_POLL, DEVICE),
            bus_transactions: family!(r, IntCounterVec, BUS_TRANSACTIONS, BUS),
            bus_reconnects: family!(r, IntCounterVec, BUS_RECONNECTS, BUS),
            bus_line_faults: family!(r, IntCounterVec, BUS_LINE_FAULTS, BUS),
            bus_busy: family!(r, CounterVec, BUS_BUSY, BUS),
            bus_utilisation: family!(r, GaugeVec, BUS_UTILISATION, BUS),
            mqtt_connected: family!(r, IntGaugeVec, MQTT_CONNECTED, OUTPUT),
            mqtt_held: family!(r, IntGaugeVec, MQTT_HELD, OUTPUT),
            output_events: family!(r, IntCounterVec, OUTPUT_EVENTS, &["output", "event"]),
            tls_expiry: family!(r, IntGaugeVec, TLS_EXPIRY, &["output", "file"]),
            config_info: family!(r, IntGaugeVec, CONFIG_INFO, &["hash"]),
            spool_messages: family!(r, IntGaugeVec, SPOOL_MESSAGES, OUTPUT),
            spool_bytes: family!(r, IntGaugeVec, SPOOL_BYTES, OUTPUT),
            spool_dropped: family!(r, IntCounterVec, SPOOL_DROPPED, OUTPUT),
            spool_fallback: family!(r, IntGaugeVec, SPOOL_FALLBACK, OUTPUT),
            spool_written: family!(r, IntCounterVec, SPOOL_WRITTEN, OUTPUT),
            spool_write_failures: family!(r, IntCounterVec, SPOOL_WRITE_FAILURES, OUTPUT),
            spool_unreadable_lines: family!(r, IntCounterVec, SPOOL_UNREADABLE_LINES, OUTPUT),
            chatter_messages: family!(r, IntGaugeVec, CHATTER_MESSAGES, OUTPUT),
            chatter_dropped: family!(r, IntCounterVec, CHATTER_DROPPED, OUTPUT),
            messages_dropped: family!(r, IntCounterVec, MESSAGES_DROPPED, &["output", "reason"]),
            server_requests: family!(
                r,
                IntCounterVec,
                server[0],
                &["output", "function", "result"]
            ),
            server_connections: family!(r, IntGaugeVec, server[1], OUTPUT),
            server_closed: family!(r, IntCounterVec, server[2], &["output", "reason"]),
            commands_received: family!(r, IntCounter, COMMANDS_RECEIVED),
            commands_refused: family!(r, IntCounterVec, COMMANDS_REFUSED, &["code"]),
            http_login_failures: login_failures(r),
            start_time: family!(r, Gauge, START_TIME),
            build_info: family!(r, IntGaugeVec, BUILD_INFO, &["version"]),
        }
    }
}
