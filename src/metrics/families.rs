//! The metric families, their names, help texts, labels and histogram buckets: the one place
//! that defines what `/metrics` shows.

use prometheus::{
    CounterVec, Gauge, GaugeVec, HistogramOpts, HistogramVec, IntCounter, IntCounterVec, IntGauge,
    IntGaugeVec, Opts, Registry,
};

const BUS: &[&str] = &["bus"];
const DEVICE: &[&str] = &["bus", "device"];
const CHANNEL: &[&str] = &["bus", "device", "channel"];

/// Modbus transaction latency buckets (seconds): a 9600-baud read takes 30–60 ms, a timeout
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
    pub bus_transactions: IntCounterVec,
    pub bus_reconnects: IntCounterVec,
    pub bus_line_faults: IntCounterVec,
    pub bus_busy: CounterVec,
    pub bus_utilisation: GaugeVec,
    pub mqtt_connected: IntGauge,
    pub spool_messages: IntGauge,
    pub spool_bytes: IntGauge,
    pub spool_dropped: IntCounter,
    pub commands_received: IntCounter,
    pub commands_refused: IntCounterVec,
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

macro_rules! family {
    ($r:expr, $ty:ident, $name:expr, $help:expr, $labels:expr) => {
        reg(
            $r,
            $ty::new(opts($name, $help), $labels).expect("valid metric name"),
        )
    };
    ($r:expr, $ty:ident, $name:expr, $help:expr) => {
        reg(
            $r,
            $ty::with_opts(opts($name, $help)).expect("valid metric name"),
        )
    };
}

impl Families {
    pub fn register(r: &Registry) -> Families {
        Families {
            channel_pulses: family!(
                r,
                IntCounterVec,
                "pulsegate_channel_pulses_total",
                "Pulses counted on an input counting on its own (running total, survives wrap, resets and restarts).",
                CHANNEL
            ),
            channel_position: family!(
                r,
                IntGaugeVec,
                "pulsegate_channel_position_pulses",
                "An encoder's position: the running sum of its signed deltas.",
                CHANNEL
            ),
            channel_rate: family!(
                r,
                GaugeVec,
                "pulsegate_channel_rate_hertz",
                "Pulses per second between the channel's last two readings.",
                CHANNEL
            ),
            device_up: family!(
                r,
                IntGaugeVec,
                "pulsegate_device_up",
                "1 while the device answers (online), 0 when offline or not yet seen.",
                DEVICE
            ),
            device_wrong_model: family!(
                r,
                IntGaugeVec,
                "pulsegate_device_wrong_model",
                "1 when the module identifies as another model than configured.",
                DEVICE
            ),
            device_transactions: family!(
                r,
                IntCounterVec,
                "pulsegate_device_transactions_total",
                "Modbus transactions with the device (polls and commands).",
                DEVICE
            ),
            device_timeouts: family!(
                r,
                IntCounterVec,
                "pulsegate_device_timeouts_total",
                "Transactions the device did not answer in time.",
                DEVICE
            ),
            device_garbled: family!(
                r,
                IntCounterVec,
                "pulsegate_device_garbled_answers_total",
                "Answers that arrived garbled (bad CRC, cut short).",
                DEVICE
            ),
            device_exceptions: family!(
                r,
                IntCounterVec,
                "pulsegate_device_exception_answers_total",
                "Modbus exception answers.",
                DEVICE
            ),
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
            bus_transactions: family!(
                r,
                IntCounterVec,
                "pulsegate_bus_transactions_total",
                "Modbus transactions on the bus.",
                BUS
            ),
            bus_reconnects: family!(
                r,
                IntCounterVec,
                "pulsegate_bus_reconnects_total",
                "Times the bus's port or TCP connection was (re)opened.",
                BUS
            ),
            bus_line_faults: family!(
                r,
                IntCounterVec,
                "pulsegate_bus_line_faults_total",
                "Line faults (adapter gone, port or connection failing), counted when each starts.",
                BUS
            ),
            bus_busy: family!(
                r,
                CounterVec,
                "pulsegate_bus_busy_seconds_total",
                "Time the line was busy with transactions; its rate is the line utilisation.",
                BUS
            ),
            bus_utilisation: family!(
                r,
                GaugeVec,
                "pulsegate_bus_utilisation_ratio",
                "Share of the last stats interval the line was busy.",
                BUS
            ),
            mqtt_connected: family!(
                r,
                IntGauge,
                "pulsegate_mqtt_connected",
                "1 while connected to the MQTT broker."
            ),
            spool_messages: family!(
                r,
                IntGauge,
                "pulsegate_spool_messages",
                "Messages waiting in the store-and-forward spool."
            ),
            spool_bytes: family!(
                r,
                IntGauge,
                "pulsegate_spool_bytes",
                "Bytes the spool's messages take (memory and disk)."
            ),
            spool_dropped: family!(
                r,
                IntCounter,
                "pulsegate_spool_dropped_messages_total",
                "Oldest messages dropped because the spool was full."
            ),
            commands_received: family!(
                r,
                IntCounter,
                "pulsegate_commands_received_total",
                "Commands answered (a retained command message is ignored, not counted)."
            ),
            commands_refused: family!(
                r,
                IntCounterVec,
                "pulsegate_commands_refused_total",
                "Commands answered with an error, by error code.",
                &["code"]
            ),
            start_time: family!(
                r,
                Gauge,
                "process_start_time_seconds",
                "Start time of the process since the Unix epoch, in seconds."
            ),
            build_info: family!(
                r,
                IntGaugeVec,
                "pulsegate_build_info",
                "Always 1; the version is a label.",
                &["version"]
            ),
        }
    }
}
