//! Sparkplug B topic names, written and read in one place. Pure.
//!
//! `spBv1.0/<group>/<NBIRTH|NDEATH|NDATA|NCMD>/<node>`,
//! `spBv1.0/<group>/<DBIRTH|DDEATH|DDATA|DCMD>/<node>/<device>`, `spBv1.0/STATE/<host>`.

use crate::config::outputs::sparkplug::NAMESPACE;

/// A message type of the node.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    NBirth,
    NDeath,
    NData,
    NCmd,
    DBirth,
    DDeath,
    DData,
    DCmd,
}

impl Kind {
    fn word(self) -> &'static str {
        match self {
            Kind::NBirth => "NBIRTH",
            Kind::NDeath => "NDEATH",
            Kind::NData => "NDATA",
            Kind::NCmd => "NCMD",
            Kind::DBirth => "DBIRTH",
            Kind::DDeath => "DDEATH",
            Kind::DData => "DDATA",
            Kind::DCmd => "DCMD",
        }
    }

    fn of(word: &str) -> Option<Kind> {
        [
            Kind::NBirth,
            Kind::NDeath,
            Kind::NData,
            Kind::NCmd,
            Kind::DBirth,
            Kind::DDeath,
            Kind::DData,
            Kind::DCmd,
        ]
        .into_iter()
        .find(|k| k.word() == word)
    }

    /// Carries a `seq` (everything the node publishes but its death; commands are the host's).
    pub fn numbered(self) -> bool {
        !matches!(self, Kind::NDeath | Kind::NCmd | Kind::DCmd)
    }
}

/// The topics of one edge node.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Topics {
    group: String,
    node: String,
}

impl Topics {
    pub fn new(group: &str, node: &str) -> Topics {
        Topics {
            group: group.to_string(),
            node: node.to_string(),
        }
    }

    /// A node-level topic (`NBIRTH`, `NDEATH`, `NDATA`, `NCMD`).
    pub fn node(&self, kind: Kind) -> String {
        format!("{NAMESPACE}/{}/{}/{}", self.group, kind.word(), self.node)
    }

    /// A device-level topic (`DBIRTH`, `DDEATH`, `DDATA`, `DCMD`).
    pub fn device(&self, kind: Kind, device: &str) -> String {
        format!("{}/{device}", self.node(kind))
    }

    /// The host's state topic.
    pub fn state(host: &str) -> String {
        format!("{NAMESPACE}/STATE/{host}")
    }

    /// What a topic of this node is: its kind and, for a device topic, the device. `None` for
    /// any other topic (another node's, another group's, not Sparkplug).
    pub fn parse<'a>(&self, topic: &'a str) -> Option<(Kind, Option<&'a str>)> {
        let mut levels = topic.split('/');
        if levels.next()? != NAMESPACE || levels.next()? != self.group {
            return None;
        }
        let kind = Kind::of(levels.next()?)?;
        if levels.next()? != self.node {
            return None;
        }
        let device = levels.next();
        if levels.next().is_some() {
            return None;
        }
        let device_kind = matches!(kind, Kind::DBirth | Kind::DDeath | Kind::DData | Kind::DCmd);
        (device_kind == device.is_some()).then_some((kind, device))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn topics_are_written_and_read_back() {
        let t = Topics::new("plant", "edge1");
        assert_eq!(t.node(Kind::NBirth), "spBv1.0/plant/NBIRTH/edge1");
        assert_eq!(
            t.device(Kind::DCmd, "press"),
            "spBv1.0/plant/DCMD/edge1/press"
        );
        assert_eq!(Topics::state("scada"), "spBv1.0/STATE/scada");
        assert_eq!(
            t.parse("spBv1.0/plant/DCMD/edge1/press"),
            Some((Kind::DCmd, Some("press")))
        );
        assert_eq!(
            t.parse("spBv1.0/plant/NCMD/edge1"),
            Some((Kind::NCmd, None))
        );
    }

    #[test]
    fn other_nodes_groups_and_shapes_are_not_ours() {
        let t = Topics::new("plant", "edge1");
        for topic in [
            "spBv1.0/plant/NCMD/edge2",
            "spBv1.0/other/NCMD/edge1",
            "spBv1.0/plant/DCMD/edge1",
            "spBv1.0/plant/NCMD/edge1/press",
            "spBv1.0/plant/DCMD/edge1/press/x",
            "spBv1.0/plant/XCMD/edge1",
            "pulsegate/edge1/press/cmd",
        ] {
            assert_eq!(t.parse(topic), None, "{topic}");
        }
    }
}
