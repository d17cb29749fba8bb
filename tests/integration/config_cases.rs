//! Broken configs as a table: each case changes one key of a good config (or adds, or removes
//! one) and names the error it must produce, by key path and message. None may panic, and each
//! error must name the file.

use std::path::Path;

const BASE: &str = r#"
[gateway]
id = "edge-01"
state_dir = "/var/lib/pulsegate"
state_flush = "5s"
stats_interval = "60s"
[mqtt]
host = "127.0.0.1"
port = 1883
client_id = "gw"
keep_alive = "30s"
qos = 1
retain = false
topic_root = "plant/edge-01"
spool_mb = 64
[buses.line1]
port = "/dev/ttyUSB0"
baud = 9600
parity = "none"
stop_bits = 1
timeout = "300ms"
guard = "1ms"
offline_after = 3
backoff_min = "1s"
backoff_max = "60s"
slow_poll = "60s"
[buses.line1.devices.press1]
unit = 1
model = "yl67"
poll = "500ms"
timeout = "200ms"
commands = true
[buses.line1.devices.press1.channels.enc0]
ppr = 1024
max_rate_hz = 20000
[buses.hall2]
host = "127.0.0.1"
port = 20108
[buses.hall2.devices.doors]
unit = 1
model = "zh-yx1600"
"#;

/// (key path, new value as TOML or "-" to remove it, expected error path, expected message part)
const CASES: &[(&str, &str, &str, &str)] = &[
    // unknown keys, at every level
    ("gateway.idd", "\"x\"", "gateway.idd", "unknown key"),
    ("mqtt.hostname", "\"x\"", "mqtt.hostname", "unknown key"),
    (
        "buses.line1.bauds",
        "9600",
        "buses.line1.bauds",
        "unknown key",
    ),
    (
        "buses.line1.devices.press1.pol",
        "\"1s\"",
        "buses.line1.devices.press1.pol",
        "unknown key",
    ),
    (
        "buses.line1.devices.press1.channels.enc0.pp",
        "1",
        "buses.line1.devices.press1.channels.enc0.pp",
        "unknown key",
    ),
    (
        "buses.hall2.devices.doors.modle",
        "\"yl67\"",
        "buses.hall2.devices.doors.modle",
        "unknown key",
    ),
    ("extra", "1", "extra", "unknown key"),
    ("mqtt.tls.cafile", "\"x\"", "mqtt.tls.cafile", "unknown key"),
    // gateway
    ("gateway.id", "\"a/b\"", "gateway.id", "topic level"),
    ("gateway.id", "\"a+b\"", "gateway.id", "topic level"),
    ("gateway.id", "\"\"", "gateway.id", "topic level"),
    ("gateway.id", "\"edge 01\"", "gateway.id", "topic level"),
    (
        "gateway.state_flush",
        "\"0s\"",
        "gateway.state_flush",
        "greater than zero",
    ),
    (
        "gateway.state_flush",
        "\"soon\"",
        "gateway.state_flush",
        "bad duration",
    ),
    (
        "gateway.state_flush",
        "5",
        "gateway.state_flush",
        "expected a duration",
    ),
    (
        "gateway.state_flush",
        "\"5 parsecs\"",
        "gateway.state_flush",
        "bad duration",
    ),
    (
        "gateway.stats_interval",
        "\"0ms\"",
        "gateway.stats_interval",
        "greater than zero",
    ),
    (
        "gateway.stats_interval",
        "true",
        "gateway.stats_interval",
        "expected a duration",
    ),
    (
        "gateway.state_dir",
        "[1]",
        "gateway.state_dir",
        "invalid type",
    ),
    ("gateway", "5", "gateway", "expected a table"),
    // mqtt
    ("mqtt.port", "0", "mqtt.port", "1..65535"),
    ("mqtt.port", "70000", "mqtt.port", "out of range"),
    ("mqtt.port", "-1", "mqtt.port", "out of range"),
    ("mqtt.port", "\"x\"", "mqtt.port", "whole number"),
    (
        "mqtt.socket",
        "\"mqtt.sock\"",
        "mqtt.socket",
        "absolute path",
    ),
    ("mqtt.socket", "\"/run/\\u0000\"", "mqtt.socket", "NUL"),
    ("mqtt.socket", "7", "mqtt.socket", "absolute path"),
    ("mqtt.qos", "3", "mqtt.qos", "0, 1 or 2"),
    ("mqtt.qos", "-1", "mqtt.qos", "out of range"),
    (
        "mqtt.keep_alive",
        "\"1s\"",
        "mqtt.keep_alive",
        "at least 5s",
    ),
    (
        "mqtt.keep_alive",
        "\"0s\"",
        "mqtt.keep_alive",
        "greater than zero",
    ),
    (
        "mqtt.keep_alive",
        "\"x\"",
        "mqtt.keep_alive",
        "bad duration",
    ),
    ("mqtt.retain", "\"yes please\"", "mqtt.retain", "invalid"),
    ("mqtt.topic_root", "\"a/#\"", "mqtt.topic_root", "wildcards"),
    (
        "mqtt.topic_root",
        "\"a/+/b\"",
        "mqtt.topic_root",
        "wildcards",
    ),
    ("mqtt.topic_root", "\"/a\"", "mqtt.topic_root", "leading"),
    ("mqtt.topic_root", "\"a/\"", "mqtt.topic_root", "trailing"),
    (
        "mqtt.topic_root",
        "\"a//b\"",
        "mqtt.topic_root",
        "empty levels",
    ),
    (
        "mqtt.topic_root",
        "\"\"",
        "mqtt.topic_root",
        "without wildcards",
    ),
    // absurd durations and sizes (issue 11): bounded, no overflow, no panic
    (
        "mqtt.keep_alive",
        "\"70000s\"",
        "mqtt.keep_alive",
        "at most",
    ),
    (
        "mqtt.keep_alive",
        "\"500000000000years\"",
        "mqtt.keep_alive",
        "at most",
    ),
    (
        "gateway.state_flush",
        "\"500000000000years\"",
        "gateway.state_flush",
        "at most 7days",
    ),
    (
        "gateway.stats_interval",
        "\"8days\"",
        "gateway.stats_interval",
        "at most 7days",
    ),
    (
        "buses.line1.guard",
        "\"500000000000years\"",
        "buses.line1.guard",
        "at most 1s",
    ),
    (
        "buses.line1.timeout",
        "\"500000000000years\"",
        "buses.line1.timeout",
        "at most 1m",
    ),
    (
        "buses.line1.backoff_max",
        "\"500000000000years\"",
        "buses.line1.backoff_max",
        "at most 7days",
    ),
    (
        "buses.line1.slow_poll",
        "\"99999999999999999999s\"",
        "buses.line1.slow_poll",
        "bad duration",
    ),
    (
        "buses.line1.devices.press1.poll",
        "\"500000000000years\"",
        "buses.line1.devices.press1.poll",
        "at most 7days",
    ),
    (
        "buses.line1.devices.press1.timeout",
        "\"2m\"",
        "buses.line1.devices.press1.timeout",
        "at most 1m",
    ),
    (
        "mqtt.spool_mb",
        "9223372036854775807",
        "mqtt.spool_mb",
        "must be 1..",
    ),
    ("mqtt.spool_mb", "0", "mqtt.spool_mb", "must be 1.."),
    ("mqtt.spool_mb", "-5", "mqtt.spool_mb", "out of range"),
    (
        "mqtt.password_file",
        "\"/nonexistent/pw\"",
        "mqtt.password_file",
        "cannot read",
    ),
    (
        "mqtt.tls.ca_file",
        "\"/nonexistent/ca.pem\"",
        "mqtt.tls.ca_file",
        "no such file",
    ),
    (
        "mqtt.tls.cert_file",
        "\"/nonexistent/c.pem\"",
        "mqtt.tls.ca_file",
        "missing",
    ),
    ("mqtt", "\"broker\"", "mqtt", "expected a table"),
    // buses
    ("buses", "5", "buses", "table of named entries"),
    (
        "buses.line1.baud",
        "1234",
        "buses.line1.baud",
        "not a rate the modules support",
    ),
    ("buses.line1.baud", "0", "buses.line1.baud", "not a rate"),
    (
        "buses.line1.baud",
        "9600.5",
        "buses.line1.baud",
        "not a decimal",
    ),
    (
        "buses.line1.baud",
        "\"fast\"",
        "buses.line1.baud",
        "whole number",
    ),
    (
        "buses.line1.parity",
        "\"mark\"",
        "buses.line1.parity",
        "does not have variant",
    ),
    (
        "buses.line1.parity",
        "1",
        "buses.line1.parity",
        "should be represented",
    ),
    (
        "buses.line1.stop_bits",
        "3",
        "buses.line1.stop_bits",
        "1 or 2",
    ),
    (
        "buses.line1.stop_bits",
        "0",
        "buses.line1.stop_bits",
        "1 or 2",
    ),
    (
        "buses.line1.timeout",
        "\"0s\"",
        "buses.line1.timeout",
        "greater than zero",
    ),
    (
        "buses.line1.timeout",
        "\"300\"",
        "buses.line1.timeout",
        "bad duration",
    ),
    (
        "buses.line1.timeout",
        "300",
        "buses.line1.timeout",
        "expected a duration",
    ),
    (
        "buses.line1.guard",
        "\"x\"",
        "buses.line1.guard",
        "bad duration",
    ),
    (
        "buses.line1.offline_after",
        "0",
        "buses.line1.offline_after",
        "at least 1",
    ),
    (
        "buses.line1.offline_after",
        "-3",
        "buses.line1.offline_after",
        "out of range",
    ),
    (
        "buses.line1.backoff_min",
        "\"0s\"",
        "buses.line1.backoff_min",
        "greater than zero",
    ),
    (
        "buses.line1.backoff_max",
        "\"500ms\"",
        "buses.line1.backoff_max",
        "below backoff_min",
    ),
    (
        "buses.line1.slow_poll",
        "\"never\"",
        "buses.line1.slow_poll",
        "bad duration",
    ),
    ("buses.line1.port", "5", "buses.line1.port", "absolute path"),
    ("buses.line1.port", "-", "buses.line1", "needs `port`"),
    (
        "buses.line1.devices",
        "-",
        "buses.line1.devices",
        "no device on this bus",
    ),
    (
        "buses.line1.devices",
        "3",
        "buses.line1.devices",
        "table of named entries",
    ),
    ("buses.hall2.port", "0", "buses.hall2.port", "1..65535"),
    (
        "buses.hall2.port",
        "\"/dev/ttyS0\"",
        "buses.hall2.port",
        "whole number",
    ),
    (
        "buses.hall2.baud",
        "9600",
        "buses.hall2.baud",
        "serial setting on a TCP bus",
    ),
    (
        "buses.hall2.parity",
        "\"even\"",
        "buses.hall2.parity",
        "serial setting on a TCP bus",
    ),
    (
        "buses.hall2.stop_bits",
        "2",
        "buses.hall2.stop_bits",
        "serial setting on a TCP bus",
    ),
    ("buses.line1", "\"x\"", "buses.line1", "expected a table"),
    (
        "buses.\"line 3\"",
        "{ port = \"/dev/ttyS1\", devices = { d9 = { unit = 9, model = \"yl67\" } } }",
        "buses.line 3",
        "bus name",
    ),
    (
        "buses.line4",
        "{ port = \"/dev/ttyS1\" }",
        "buses.line4.devices",
        "no device on this bus",
    ),
    (
        "buses.line5",
        "{ devices = { d5 = { unit = 5, model = \"yl67\" } } }",
        "buses.line5",
        "needs `port`",
    ),
    // metering: intervals at every level, the time zone
    (
        "gateway.timezone",
        "\"Europe/Berln\"",
        "gateway.timezone",
        "not an IANA time zone name",
    ),
    (
        "gateway.intervals",
        "[\"7min\"]",
        "gateway.intervals",
        "does not divide a day",
    ),
    (
        "buses.line1.devices.press1.intervals",
        "[\"15m\"]",
        "buses.line1.devices.press1.intervals",
        "for minutes",
    ),
    (
        "buses.line1.devices.press1.channels.enc0.intervals",
        "[\"1h\", \"60min\"]",
        "buses.line1.devices.press1.channels.enc0.intervals",
        "same period",
    ),
    (
        "gateway.intervals",
        "\"15min\"",
        "gateway.intervals",
        "invalid type",
    ),
    (
        "gateway.intervals",
        "[\"0.5s\"]",
        "gateway.intervals",
        "not a period",
    ),
    // devices
    (
        "buses.line1.devices.press1.unit",
        "0",
        "buses.line1.devices.press1.unit",
        "outside 1..247",
    ),
    (
        "buses.line1.devices.press1.unit",
        "248",
        "buses.line1.devices.press1.unit",
        "outside 1..247",
    ),
    (
        "buses.line1.devices.press1.unit",
        "-1",
        "buses.line1.devices.press1.unit",
        "outside 1..247",
    ),
    (
        "buses.line1.devices.press1.unit",
        "1000",
        "buses.line1.devices.press1.unit",
        "outside 1..247",
    ),
    (
        "buses.line1.devices.press1.unit",
        "1.5",
        "buses.line1.devices.press1.unit",
        "not a decimal",
    ),
    (
        "buses.line1.devices.press1.unit",
        "\"one\"",
        "buses.line1.devices.press1.unit",
        "whole number",
    ),
    (
        "buses.line1.devices.press1.unit",
        "true",
        "buses.line1.devices.press1.unit",
        "whole number",
    ),
    (
        "buses.line1.port",
        "\"ttyUSB0\"",
        "buses.line1.port",
        "absolute path",
    ),
    (
        "buses.line1.devices.press1.poll",
        "\"1 fortnight\"",
        "buses.line1.devices.press1.poll",
        "bad duration",
    ),
    ("mqtt.qos", "1.0", "mqtt.qos", "not a decimal"),
    (
        "buses.line1.devices.press1.unit",
        "-",
        "buses.line1.devices.press1.unit",
        "missing",
    ),
    (
        "buses.line1.devices.press1.model",
        "\"yl68\"",
        "buses.line1.devices.press1.model",
        "unknown model",
    ),
    (
        "buses.line1.devices.press1.model",
        "\"\"",
        "buses.line1.devices.press1.model",
        "unknown model",
    ),
    (
        "buses.line1.devices.press1.model",
        "67",
        "buses.line1.devices.press1.model",
        "unknown model",
    ),
    (
        "buses.line1.devices.press1.model",
        "-",
        "buses.line1.devices.press1.model",
        "missing",
    ),
    (
        "buses.line1.devices.press1.poll",
        "\"0ms\"",
        "buses.line1.devices.press1.poll",
        "greater than zero",
    ),
    (
        "buses.line1.devices.press1.poll",
        "\"fast\"",
        "buses.line1.devices.press1.poll",
        "bad duration",
    ),
    (
        "buses.line1.devices.press1.poll",
        "500",
        "buses.line1.devices.press1.poll",
        "expected a duration",
    ),
    (
        "buses.line1.devices.press1.poll",
        "\"-1s\"",
        "buses.line1.devices.press1.poll",
        "bad duration",
    ),
    (
        "buses.line1.devices.press1.timeout",
        "\"0s\"",
        "buses.line1.devices.press1.timeout",
        "greater than zero",
    ),
    (
        "buses.line1.devices.press1.channels.enc9",
        "{ ppr = 5 }",
        "buses.line1.devices.press1.channels.enc9",
        "has no channel enc9",
    ),
    (
        "buses.line1.devices.press1.channels.enc0.ppr",
        "0",
        "buses.line1.devices.press1.channels.enc0.ppr",
        "greater than zero",
    ),
    (
        "buses.line1.devices.press1.channels.enc0.ppr",
        "-5",
        "buses.line1.devices.press1.channels.enc0.ppr",
        "greater than zero",
    ),
    (
        "buses.line1.devices.press1.channels.enc0.ppr",
        "\"many\"",
        "buses.line1.devices.press1.channels.enc0.ppr",
        "invalid",
    ),
    (
        "buses.line1.devices.press1.channels.enc0.max_rate_hz",
        "0",
        "buses.line1.devices.press1.channels.enc0.max_rate_hz",
        "greater than zero",
    ),
    (
        "buses.line1.devices.press1.channels.enc0",
        "7",
        "buses.line1.devices.press1.channels.enc0",
        "expected a table",
    ),
    (
        "buses.line1.devices.press1",
        "[]",
        "buses.line1.devices.press1",
        "expected a table",
    ),
    (
        "buses.line1.devices.\"bad/name\"",
        "{ unit = 7, model = \"yl67\" }",
        "buses.line1.devices.bad/name",
        "device name",
    ),
    (
        "buses.line1.devices.status",
        "{ unit = 7, model = \"yl67\" }",
        "buses.line1.devices.status",
        "not status, bus, cmd or gateway",
    ),
    (
        "buses.line1.devices.cmd",
        "{ unit = 7, model = \"yl67\" }",
        "buses.line1.devices.cmd",
        "not status, bus, cmd or gateway",
    ),
    (
        "buses.line1.devices.gateway",
        "{ unit = 7, model = \"yl67\" }",
        "buses.line1.devices.gateway",
        "not status, bus, cmd or gateway",
    ),
    (
        "buses.line1.devices.twin",
        "{ unit = 1, model = \"wj157\" }",
        ".unit",
        "already used by device",
    ),
    (
        "buses.hall2.devices.press1",
        "{ unit = 9, model = \"wj157\" }",
        "buses.line1.devices.press1",
        "already used on bus",
    ),
    (
        "buses.line1.devices.wj",
        "{ unit = 2, model = \"wj157\", channels = { enc3 = { ppr = 1 } } }",
        "buses.line1.devices.wj.channels.enc3",
        "model wj157 has no channel enc3",
    ),
    // mqtt.format and [sparkplug] come together
    (
        "mqtt.format",
        "\"sparkplug\"",
        "sparkplug",
        "needs [sparkplug] with its group_id",
    ),
    (
        "sparkplug.group_id",
        "\"plant\"",
        "sparkplug",
        "no output is of kind \"sparkplug\"",
    ),
    ("mqtt.format", "[]", "mqtt.format", "an empty list"),
    (
        "mqtt.format",
        "[\"json\", \"json\"]",
        "mqtt.format",
        "\"json\" is named twice",
    ),
    (
        "mqtt.format",
        "[\"json\", \"xml\"]",
        "mqtt.format",
        "unknown output format \"xml\"",
    ),
    ("mqtt.format", "5", "mqtt.format", "a format name or a list"),
    (
        "mqtt.format",
        "\"homeassistant\"",
        "mqtt.format",
        "not a payload format",
    ),
    // [outputs.NAME]: a kind, a name fit for a file and a client id, [mqtt]'s keys only
    (
        "outputs.scada",
        "{ kind = \"opcua\" }",
        "outputs.scada.kind",
        "unknown output format \"opcua\": one of \"json\", \"sparkplug\", \"homeassistant\"",
    ),
    (
        "outputs.scada",
        "{ host = \"10.0.0.9\" }",
        "outputs.scada.kind",
        "missing",
    ),
    (
        "outputs.gateway",
        "{ kind = \"json\" }",
        "outputs.gateway",
        "not an output name",
    ),
    (
        "outputs.\"Bad Name\"",
        "{ kind = \"json\" }",
        "outputs.Bad Name",
        "not an output name",
    ),
    (
        "outputs.json",
        "{ kind = \"json\", format = \"json\" }",
        "outputs.json.format",
        "unknown key",
    ),
    (
        "outputs.json",
        "{ kind = \"json\", port = 0 }",
        "outputs.json.port",
        "must be 1..65535",
    ),
    (
        "outputs.json",
        "{ kind = \"json\", tls = { ca_file = \"/nonexistent/ca.pem\" } }",
        "outputs.json.tls.ca_file",
        "no such file",
    ),
    (
        "outputs.s",
        "{ kind = \"sparkplug\" }",
        "sparkplug",
        "an output of kind \"sparkplug\" needs [sparkplug]",
    ),
];

/// Outputs that would fight on one broker, each a change to [`BASE`] with an output `b`.
const OUTPUT_CLASHES: &[(&str, &str, &str, &str)] = &[
    (
        "outputs.a",
        "{ kind = \"json\", client_id = \"same\" }",
        "outputs.b.client_id",
        "same client id \"same\" on the same broker as output \"a\"",
    ),
    (
        "outputs.a",
        "{ kind = \"homeassistant\", topic_root = \"x/b\" }",
        "outputs.b",
        "publishes the same JSON topics on the same broker as output \"a\"",
    ),
];

#[test]
fn two_outputs_that_would_fight_on_one_broker_are_refused() {
    let base = mutate(
        BASE,
        "outputs.b",
        "{ kind = \"json\", client_id = \"same\", topic_root = \"x/b\" }",
    );
    let file = Path::new("/etc/pulsegate/pulsegate.toml");
    let good = pulsegate::config::Config::from_toml(&base, file, Some(Default::default()));
    let good = good.expect("one output is fine");
    assert_eq!(good.outputs.list.len(), 1);
    refused(&base, OUTPUT_CLASHES);
}

/// Broken `[sparkplug]` tables, each a change to [`BASE`] with `mqtt.format = ["json",
/// "sparkplug"]` and `[sparkplug] group_id = "plant"`.
const SPARKPLUG_CASES: &[(&str, &str, &str, &str)] = &[
    ("sparkplug.group_id", "-", "sparkplug.group_id", "missing"),
    (
        "sparkplug.group_id",
        "\"plant/west\"",
        "sparkplug.group_id",
        "not a Sparkplug id",
    ),
    (
        "sparkplug.group_id",
        "\"plant+\"",
        "sparkplug.group_id",
        "not a Sparkplug id",
    ),
    (
        "sparkplug.edge_node_id",
        "\"edge#1\"",
        "sparkplug.edge_node_id",
        "not a Sparkplug id",
    ),
    (
        "sparkplug.primary_host",
        "\"\"",
        "sparkplug.primary_host",
        "not a Sparkplug id",
    ),
    (
        "sparkplug.group_id",
        "\"gggggggggggggggggggggggggggggggggggggggggggggggggggggggggggggggggggg\"",
        "sparkplug.group_id",
        "1..64 bytes",
    ),
    (
        "sparkplug.host",
        "\"scada\"",
        "sparkplug.host",
        "unknown key",
    ),
];

/// [`BASE`] with two M-Bus buses: a serial level converter and a TCP converter, meters by
/// primary address and by secondary address.
const MBUS: &str = r#"
[buses.heat]
protocol = "mbus"
port = "/dev/ttyUSB1"
baud = 2400
parity = "even"
[buses.heat.devices.flat1]
address = 5
poll = "30s"
[buses.heat.devices.flat2]
id = "12345678"
manufacturer = "KAM"
[buses.heat.devices.flat2.channels.heat]
record = 0
[buses.cellar]
protocol = "mbus"
host = "10.0.0.5:10001"
[buses.cellar.devices.water]
id = "87654321"
medium = 7
"#;

/// Broken M-Bus buses and meters, each a change to [`BASE`] + [`MBUS`].
const MBUS_CASES: &[(&str, &str, &str, &str)] = &[
    (
        "buses.heat.protocol",
        "\"mbuss\"",
        "buses.heat.protocol",
        "use \"modbus\" or \"mbus\"",
    ),
    (
        "buses.heat.baud",
        "115200",
        "buses.heat.baud",
        "not an M-Bus baud rate",
    ),
    (
        "buses.heat.parity",
        "\"high\"",
        "buses.heat.parity",
        "does not have variant",
    ),
    (
        "buses.heat.port",
        "-",
        "buses.heat",
        "needs `port` (a serial level converter)",
    ),
    (
        "buses.heat.port",
        "\"ttyUSB1\"",
        "buses.heat.port",
        "absolute path",
    ),
    (
        "buses.heat.guard",
        "\"1ms\"",
        "buses.heat.guard",
        "unknown key",
    ),
    (
        "buses.cellar.host",
        "\"10.0.0.5\"",
        "buses.cellar.host",
        "\"HOST:PORT\"",
    ),
    (
        "buses.cellar.host",
        "\"10.0.0.5:0\"",
        "buses.cellar.host",
        "\"HOST:PORT\"",
    ),
    (
        "buses.cellar.baud",
        "2400",
        "buses.cellar.baud",
        "serial setting on a TCP bus",
    ),
    (
        "buses.cellar.port",
        "10001",
        "buses.cellar.port",
        "give the TCP port in `host`",
    ),
    (
        "buses.heat.devices.flat1.address",
        "251",
        "buses.heat.devices.flat1.address",
        "outside 0..250",
    ),
    (
        "buses.heat.devices.flat1.address",
        "-",
        "buses.heat.devices.flat1",
        "needs `address`",
    ),
    (
        "buses.heat.devices.flat1.id",
        "\"11111111\"",
        "buses.heat.devices.flat1",
        "not both",
    ),
    (
        "buses.heat.devices.flat1.unit",
        "5",
        "buses.heat.devices.flat1.unit",
        "not by a Modbus unit",
    ),
    (
        "buses.heat.devices.flat1.model",
        "\"yl67\"",
        "buses.heat.devices.flat1.model",
        "not by a Modbus unit",
    ),
    (
        "buses.heat.devices.flat1.manufacturer",
        "\"KAM\"",
        "buses.heat.devices.flat1.manufacturer",
        "only with `id`",
    ),
    (
        "buses.heat.devices.flat2.id",
        "\"1234567\"",
        "buses.heat.devices.flat2.id",
        "8 digits",
    ),
    (
        "buses.heat.devices.flat2.id",
        "\"1234567X\"",
        "buses.heat.devices.flat2.id",
        "8 digits",
    ),
    (
        "buses.heat.devices.flat2.manufacturer",
        "\"kam\"",
        "buses.heat.devices.flat2.manufacturer",
        "three letters A-Z",
    ),
    (
        "buses.heat.devices.flat2.version",
        "300",
        "buses.heat.devices.flat2.version",
        "out of range",
    ),
    (
        "buses.heat.devices.flat2.channels.heat.record",
        "-1",
        "buses.heat.devices.flat2.channels.heat.record",
        "out of range",
    ),
    (
        "buses.heat.devices.flat2.channels.other",
        "{ record = 0 }",
        "buses.heat.devices.flat2.channels.other.record",
        "record 0 is already channel heat",
    ),
    (
        "buses.heat.devices.flat2.channels.heat.scale",
        "0.001",
        "buses.heat.devices.flat2.channels.heat.scale",
        "unknown key",
    ),
    (
        "buses.heat.devices.flat2.channels.heat.max_rate_hz",
        "0",
        "buses.heat.devices.flat2.channels.heat.max_rate_hz",
        "greater than zero",
    ),
    (
        "buses.heat.devices.flat3",
        "{ address = 5 }",
        "buses.heat.devices.flat3.address",
        "primary address 5 is already used by meter flat1",
    ),
    (
        "buses.cellar.devices.water2",
        "{ id = \"87654321\" }",
        "buses.cellar.devices.water2.id",
        "id 87654321 is already used by meter water",
    ),
    (
        "buses.cellar.devices.status",
        "{ address = 1 }",
        "buses.cellar.devices.status",
        "topic level",
    ),
];

#[test]
fn a_good_mbus_config_is_valid_and_every_broken_one_is_refused() {
    let base = format!("{BASE}{MBUS}");
    let file = Path::new("/etc/pulsegate/pulsegate.toml");
    let good = pulsegate::config::Config::from_toml(&base, file, Some(Default::default()))
        .expect("the M-Bus base is valid");
    let heat = good.buses.iter().find(|b| b.name == "heat").unwrap();
    assert_eq!(heat.devices.len(), 2);
    refused(&base, MBUS_CASES);
}

/// Sets `path` in a TOML table to `value` (TOML text), or removes it with "-".
fn mutate(base: &str, path: &str, value: &str) -> String {
    let mut doc: toml::Table = base.parse().unwrap();
    let keys: Vec<String> = split_path(path);
    let (last, parents) = keys.split_last().unwrap();
    let mut t = &mut doc;
    for k in parents {
        t = t
            .entry(k.clone())
            .or_insert_with(|| toml::Value::Table(Default::default()))
            .as_table_mut()
            .expect("a table on the way");
    }
    if value == "-" {
        t.remove(last);
    } else {
        let v: toml::Table = format!("v = {value}").parse().unwrap();
        t.insert(last.clone(), v["v"].clone());
    }
    toml::to_string(&doc).unwrap()
}

fn split_path(path: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut cur = String::new();
    let mut quoted = false;
    for c in path.chars() {
        match c {
            '"' => quoted = !quoted,
            '.' if !quoted => out.push(std::mem::take(&mut cur)),
            c => cur.push(c),
        }
    }
    out.push(cur);
    out
}

#[test]
fn the_base_config_is_valid() {
    pulsegate::config::Config::from_toml(
        BASE,
        Path::new("/etc/pulsegate/pulsegate.toml"),
        Some(Default::default()),
    )
    .unwrap();
}

#[test]
fn every_broken_config_is_refused_naming_its_key_and_file() {
    assert!(CASES.len() >= 100, "{} cases", CASES.len());
    refused(BASE, CASES);
}

#[test]
fn every_broken_sparkplug_table_is_refused_naming_its_key_and_file() {
    let base = mutate(BASE, "mqtt.format", "[\"json\", \"sparkplug\"]");
    let base = mutate(&base, "sparkplug.group_id", "\"plant\"");
    let file = Path::new("/etc/pulsegate/pulsegate.toml");
    let good = pulsegate::config::Config::from_toml(&base, file, Some(Default::default()));
    let kinds: Vec<_> = good
        .unwrap()
        .outputs
        .list
        .iter()
        .map(|o| o.kind.name())
        .collect();
    assert_eq!(kinds, ["json", "sparkplug"]);
    refused(&base, SPARKPLUG_CASES);
}

/// Each case applied to `base` is refused with its error.
fn refused(base: &str, cases: &[(&str, &str, &str, &str)]) {
    let file = Path::new("/etc/pulsegate/pulsegate.toml");
    let mut failures = Vec::new();
    for (path, value, want_path, want) in cases {
        let text = mutate(base, path, value);
        let result = std::panic::catch_unwind(|| {
            pulsegate::config::Config::from_toml(&text, file, Some(Default::default()))
        });
        let errors = match result {
            Err(_) => {
                failures.push(format!("{path} = {value}: PANIC"));
                continue;
            }
            Ok(Ok(_)) => {
                failures.push(format!("{path} = {value}: accepted"));
                continue;
            }
            Ok(Err(e)) => e.0,
        };
        let hit = errors.iter().any(|e| {
            e.path.ends_with(want_path)
                && e.message.contains(want)
                && e.origin == file.display().to_string()
        });
        if !hit {
            failures.push(format!(
                "{path} = {value}: want {want_path}: {want}; got {errors:?}"
            ));
        }
    }
    assert!(
        failures.is_empty(),
        "{} of {} cases:\n{}",
        failures.len(),
        cases.len(),
        failures.join("\n")
    );
}
