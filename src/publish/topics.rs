//! Topic names under the gateway's root. Pure.

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

    pub fn root(&self) -> &str {
        &self.root
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

    /// `<root>/bus/<bus>/stats`: bus health.
    pub fn bus_stats(&self, bus: &str) -> String {
        format!("{}/bus/{bus}/stats", self.root)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn topics_sit_under_the_root() {
        let t = Topics::new("pulsegate/edge-01");
        assert_eq!(t.gateway_status(), "pulsegate/edge-01/status");
        assert_eq!(t.device_status("press1"), "pulsegate/edge-01/press1/status");
        assert_eq!(t.reading("press1", "enc0"), "pulsegate/edge-01/press1/enc0");
        assert_eq!(t.bus_stats("line1"), "pulsegate/edge-01/bus/line1/stats");
        assert_eq!(t.device("press1"), "pulsegate/edge-01/press1");
    }
}
