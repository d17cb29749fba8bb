//! Topic names under the gateway's root, both ways: what the gateway publishes, what it
//! subscribes to, and how an arriving topic is read. The one place for these rules. Pure.

/// A name that can stand as one level of an MQTT topic and as a key in the environment:
/// letters, digits, `-` and `_`, not empty, no wildcards or separators.
pub fn is_topic_safe(name: &str) -> bool {
    !name.is_empty()
        && name.len() <= 64
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
}

/// The topic rules, written once: what any topic the gateway publishes to must be, what a
/// prefix other topics are built under must be, and what one level of a topic may hold.
///
/// Why `topic` cannot be published to, or `Ok`: not empty, at most 65535 bytes (MQTT's string
/// length), no wildcard (`+`, `#`), no NUL.
pub fn publishable(topic: &str) -> Result<(), &'static str> {
    if topic.is_empty() {
        return Err("it is empty");
    }
    if topic.len() > usize::from(u16::MAX) {
        return Err("it is longer than MQTT's 65535 bytes");
    }
    if topic.contains(['+', '#']) {
        return Err("it contains a wildcard ('+' or '#')");
    }
    if topic.contains('\0') {
        return Err("it contains a NUL character");
    }
    Ok(())
}

/// One level of a topic (a Sparkplug id, say): 1 to `max` bytes, no `/`, no wildcard, nothing
/// invisible.
pub fn is_topic_level(level: &str, max: usize) -> bool {
    (1..=max).contains(&level.len())
        && !level
            .chars()
            .any(|c| matches!(c, '/' | '+' | '#') || c.is_control())
}

/// A topic that other topics are built under (`mqtt.topic_root`, Home Assistant's prefix):
/// publishable, no empty level, no leading or trailing `/`.
pub fn is_topic_prefix(prefix: &str) -> bool {
    publishable(prefix).is_ok() && prefix.split('/').all(|level| !level.is_empty())
}

/// Topics of one gateway.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Topics {
    root: String,
}

impl Topics {
    pub fn new(root: &str) -> Topics {
        Topics {
            root: root.to_string(),
        }
    }

    /// `<root>/status`: retained online/offline of the gateway (its last will).
    pub fn gateway_status(&self) -> String {
        format!("{}/status", self.root)
    }

    /// `<root>/gateway`: the retained boot marker of the gateway publishing under this root.
    pub fn gateway_marker(&self) -> String {
        format!("{}/gateway", self.root)
    }

    /// `<root>/<device>/status`: retained online/offline of a device.
    pub fn device_status(&self, device: &str) -> String {
        format!("{}/{device}/status", self.root)
    }

    /// `<root>/<device>`: all channels of a poll in one message (`payload = "device"`).
    pub fn device(&self, device: &str) -> String {
        format!("{}/{device}", self.root)
    }

    /// `<root>/<device>/<channel>`: readings.
    pub fn reading(&self, device: &str, channel: &str) -> String {
        format!("{}/{device}/{channel}", self.root)
    }

    /// `<root>/<device>/<channel>/interval/<period>`: interval records of one period.
    pub fn interval(&self, device: &str, channel: &str, period: &str) -> String {
        format!("{}/interval/{period}", self.reading(device, channel))
    }

    /// `<root>/<device>/<channel>/tariff/<tariff>`: a channel's register of one tariff.
    pub fn tariff(&self, device: &str, channel: &str, tariff: &str) -> String {
        format!("{}/{device}/{channel}/tariff/{tariff}", self.root)
    }

    /// `<root>/<device>/<channel>/billing`: a channel's billing records.
    pub fn billing(&self, device: &str, channel: &str) -> String {
        format!("{}/{device}/{channel}/billing", self.root)
    }

    /// `<root>/bus/<bus>/stats`: bus health.
    pub fn bus_stats(&self, bus: &str) -> String {
        format!("{}/bus/{bus}/stats", self.root)
    }

    /// `<root>/<device>/cmd`: commands to a whole device (clear all).
    pub fn device_command(&self, device: &str) -> String {
        format!("{}/cmd", self.device(device))
    }

    /// `<root>/<device>/<channel>/cmd`: commands to one channel.
    pub fn channel_command(&self, device: &str, channel: &str) -> String {
        format!("{}/cmd", self.reading(device, channel))
    }

    /// `<request>/result`: where the answer to a command or scan request goes.
    pub fn result(request: &str) -> String {
        format!("{request}/result")
    }

    /// `<request>/progress`: where a scan reports each module as it is found.
    pub fn scan_progress(request: &str) -> String {
        format!("{request}/progress")
    }

    /// The filters that take commands and scan requests: `<root>/+/+/cmd`, `<root>/+/cmd`,
    /// `<root>/bus/+/scan`.
    pub fn command_filters(&self) -> [String; 3] {
        [
            format!("{}/+/+/cmd", self.root),
            format!("{}/+/cmd", self.root),
            format!("{}/bus/+/scan", self.root),
        ]
    }

    /// `<root>/config/set`: a config pushed from the broker (`[remote] config = true`).
    pub fn config_set(&self) -> String {
        format!("{}/config/set", self.root)
    }

    /// `<root>/config/result`: what became of a pushed config.
    pub fn config_result(&self) -> String {
        format!("{}/config/result", self.root)
    }

    /// Reads a command topic: `<root>/<device>/<channel>/cmd` or `<root>/<device>/cmd`. The
    /// one reader of command topics (the router asks it).
    pub fn parse_command<'a>(&self, topic: &'a str) -> Option<(&'a str, Option<&'a str>)> {
        parse_command(&self.root, topic)
    }

    /// Reads a scan request topic `<root>/bus/<bus>/scan`: the bus.
    pub fn parse_scan<'a>(&self, topic: &'a str) -> Option<&'a str> {
        parse_scan(&self.root, topic)
    }
}

/// Where a command's MQTT v5 response topic may not point, written once: the gateway
/// publishes a result there under its own credentials, so a sender allowed only command topics
/// must not reach, through it, what it may not publish itself.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ResponseRule {
    root: String,
    /// Namespaces the gateway's outputs publish in, and why a result may not go there.
    reserved: Vec<(String, &'static str)>,
}

impl ResponseRule {
    /// The rule of a gateway publishing under `root`, beside the namespaces of its formats
    /// (Home Assistant's discovery prefix, whether discovery is on or not: Home Assistant
    /// listens there either way; the Sparkplug B namespace), each with the reason it is
    /// refused.
    pub fn new(root: &str, reserved: Vec<(String, &'static str)>) -> ResponseRule {
        ResponseRule {
            root: root.to_string(),
            reserved,
        }
    }

    /// Why a result may not go to `topic`, or `Ok` (its shape, length and wildcards are
    /// checked apart, in `command::check_response_topic`):
    /// - under the gateway's root only its result topics (`…/cmd/result`, `…/scan/result`):
    ///   never its status, boot marker, readings, bus stats or command topics;
    /// - nothing under the Home Assistant discovery prefix (configs, its status), nor in the
    ///   Sparkplug B namespace (a forged DDATA or NDEATH for any node);
    /// - nowhere a request is taken (a last level `cmd` or `scan`, of any gateway): a result
    ///   must not become a command.
    ///
    /// Everything else is confined by the broker's ACL (the example in docs/security.md lets
    /// the gateway write its root and `replies/#` only).
    pub fn check(&self, topic: &str) -> Result<(), &'static str> {
        let under = |prefix: &str| {
            topic == prefix
                || topic
                    .strip_prefix(prefix)
                    .is_some_and(|rest| rest.starts_with('/'))
        };
        if under(&self.root) {
            let request = topic.strip_suffix("/result").unwrap_or_default();
            let is_result = parse_command(&self.root, request).is_some()
                || parse_scan(&self.root, request).is_some();
            return if is_result {
                Ok(())
            } else {
                Err("it is under the gateway's own topics (only their /result topics may be used)")
            };
        }
        if let Some((_, why)) = self.reserved.iter().find(|(prefix, _)| under(prefix)) {
            return Err(why);
        }
        if matches!(topic.rsplit('/').next(), Some("cmd" | "scan")) {
            return Err("it is a command or scan topic");
        }
        Ok(())
    }
}

/// Splits a command topic `<root>/<device>/<channel>/cmd` or `<root>/<device>/cmd`.
fn parse_command<'a>(root: &str, topic: &'a str) -> Option<(&'a str, Option<&'a str>)> {
    let rest = topic.strip_prefix(root)?.strip_prefix('/')?;
    let rest = rest.strip_suffix("/cmd")?;
    match rest.split('/').collect::<Vec<_>>()[..] {
        [device] if !device.is_empty() => Some((device, None)),
        [device, channel] if !device.is_empty() && !channel.is_empty() => {
            Some((device, Some(channel)))
        }
        _ => None,
    }
}

/// The bus of a scan request topic `<root>/bus/<bus>/scan`.
fn parse_scan<'a>(root: &str, topic: &'a str) -> Option<&'a str> {
    let rest = topic.strip_prefix(root)?.strip_prefix("/bus/")?;
    let bus = rest.strip_suffix("/scan")?;
    (!bus.is_empty() && !bus.contains('/')).then_some(bus)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn command_topics_name_device_and_channel() {
        assert_eq!(
            parse_command("pg/e1", "pg/e1/press/enc0/cmd"),
            Some(("press", Some("enc0")))
        );
        assert_eq!(
            parse_command("pg/e1", "pg/e1/press/cmd"),
            Some(("press", None))
        );
        assert_eq!(parse_command("pg/e1", "pg/e1/press/enc0/cmd/result"), None);
        assert_eq!(parse_command("pg/e1", "pg/e1/a/b/c/cmd"), None);
        assert_eq!(parse_command("pg/e1", "other/press/cmd"), None);
    }

    #[test]
    fn the_scan_topic_names_one_bus_under_the_root() {
        assert_eq!(parse_scan("pg/gw", "pg/gw/bus/line1/scan"), Some("line1"));
        assert_eq!(parse_scan("pg/gw", "pg/gw/bus/line1/scan/result"), None);
        assert_eq!(parse_scan("pg/gw", "pg/gw/bus//scan"), None);
        assert_eq!(parse_scan("pg/gw", "pg/other/bus/line1/scan"), None);
    }

    #[test]
    fn topics_sit_under_the_root() {
        let t = Topics::new("pulsegate/edge-01");
        assert_eq!(t.gateway_status(), "pulsegate/edge-01/status");
        assert_eq!(t.device_status("press1"), "pulsegate/edge-01/press1/status");
        assert_eq!(t.reading("press1", "enc0"), "pulsegate/edge-01/press1/enc0");
        assert_eq!(t.bus_stats("line1"), "pulsegate/edge-01/bus/line1/stats");
        assert_eq!(t.device("press1"), "pulsegate/edge-01/press1");
    }

    #[test]
    fn a_response_topic_may_not_reach_the_gateways_own_topics_or_home_assistants() {
        let t = Topics::new("pg/e1");
        let rule = ResponseRule::new(
            "pg/e1",
            vec![
                ("homeassistant".into(), "Home Assistant's"),
                ("spBv1.0".into(), "Sparkplug's"),
            ],
        );
        for refused in [
            t.gateway_status(),
            t.gateway_marker(),
            t.device_status("press"),
            t.reading("press", "enc0"),
            t.device("press"),
            t.bus_stats("line1"),
            t.channel_command("press", "enc0"),
            t.device_command("press"),
            "pg/e1".into(),
            "pg/e1/bus/line1/scan".into(),
            "pg/e1/press/enc0/result".into(),
            "pg/e1/x/y/z/cmd/result".into(),
            "homeassistant/status".into(),
            "spBv1.0/plant/NDEATH/e1".into(),
            "spBv1.0/STATE/scada".into(),
            "homeassistant/sensor/e1/press_enc0/config".into(),
            "pg/e2/press/enc0/cmd".into(),
            "pg/e2/bus/line1/scan".into(),
        ] {
            assert!(rule.check(&refused).is_err(), "{refused}");
        }
        for allowed in [
            Topics::result(&t.channel_command("press", "enc0")),
            Topics::result(&t.device_command("press")),
            "pg/e1/bus/line1/scan/result".into(),
            "replies/mes/42".into(),
            "pg/e10/status".into(),
            "homeassistantx/reply".into(),
        ] {
            assert_eq!(rule.check(&allowed), Ok(()), "{allowed}");
        }
    }

    #[test]
    fn every_topic_the_gateway_subscribes_to_is_read_back_by_its_parser() {
        let t = Topics::new("pg/e1");
        let cmd = t.channel_command("press", "enc0");
        assert_eq!(t.parse_command(&cmd), Some(("press", Some("enc0"))));
        assert_eq!(
            t.parse_command(&t.device_command("press")),
            Some(("press", None))
        );
        assert_eq!(t.parse_scan("pg/e1/bus/line1/scan"), Some("line1"));
        assert_eq!(
            t.parse_command(&Topics::result(&cmd)),
            None,
            "results are not commands"
        );
        let [channel, device, scan] = t.command_filters();
        let matches = |filter: &str, topic: &str| rumqttc::matches(topic, filter);
        assert!(matches(&channel, &cmd));
        assert!(matches(&device, &t.device_command("press")));
        assert!(matches(&scan, "pg/e1/bus/line1/scan"));
    }
}
