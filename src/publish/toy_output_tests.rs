//! A toy output kind, everything of it in this file: its part of the config (its name, its own
//! `[toy]` table and the reader of it, the prefix it reserves), its encoder (each reading's total
//! as text on `<prefix>/<device>/<channel>`) and its one registry line
//! (`Registry::standard().with(…)`). It goes through the real config check and the real
//! builder, and publishes a reading; nothing else in `src/` knows it.

use std::sync::Arc;

use crate::config::outputs::kind::{Context, Kind, OwnTable, Settings};
use crate::config::walk::{Errors, Table};
use crate::config::{Config, ConfigErrors, OutputConfig};
use crate::outbox::Message;
use crate::publish::format::Format;
use crate::publish::formats::{Entry, Registry, STANDARD};
use crate::publish::lifecycle::{Stage, plain};
use crate::reading::{Output, Reading};

/// `[toy]`, checked.
#[derive(Debug, Clone, PartialEq)]
struct ToySettings {
    prefix: String,
}

/// The toy kind's part of the config: `[toy]` is needed exactly when an output is of kind
/// `toy`; its prefix is no place for a command's response.
static TOY: Kind = Kind {
    name: "toy",
    gateway_topics: false,
    table: Some(OwnTable {
        name: "toy",
        read: read_toy,
        needed: Some("with its prefix"),
    }),
    reserved: |settings| {
        let toy = settings?.as_any().downcast_ref::<ToySettings>()?;
        Some((toy.prefix.clone(), "it is the toy's"))
    },
};

fn read_toy(
    table: Option<Table<'_>>,
    _: &Context<'_>,
    errs: &mut Errors,
) -> Option<Arc<dyn Settings>> {
    let mut t = table?;
    let prefix = t.req::<String>("prefix", errs);
    t.finish(errs);
    Some(Arc::new(ToySettings { prefix: prefix? }))
}

/// The toy encoder.
struct Toy {
    prefix: String,
}

impl Toy {
    fn new(config: &Config, _: &OutputConfig) -> Toy {
        let settings = config.outputs.settings::<ToySettings>();
        Toy {
            prefix: settings.map_or_else(String::new, |s| s.prefix.clone()),
        }
    }
}

impl Format for Toy {
    fn messages(&mut self, event: &Output) -> Vec<Message> {
        let Output::DeviceReadings { readings, .. } = event else {
            return Vec::new();
        };
        let total = |r: &Reading| {
            let topic = format!("{}/{}/{}", self.prefix, r.device, r.channel);
            Message::new(topic, r.update.total.to_string(), 1, false)
        };
        readings.iter().map(total).collect()
    }
}

/// The gateway's kinds and the toy: its one line.
fn registry() -> Registry {
    Registry::standard().with(Entry {
        kind: &TOY,
        build: |c, o| vec![plain(Toy::new(c, o))],
    })
}

const BUS: &str = "[buses.l]\nhost = \"127.0.0.1\"\nport = 502\n[buses.l.devices.d]\nunit = 1\nmodel = \"yl67\"\n";

fn check(registry: &Registry, outputs: &str) -> Result<Config, ConfigErrors> {
    let text = format!("[gateway]\nid = \"e1\"\n{outputs}\n{BUS}");
    let path = std::path::Path::new("toy.toml");
    let known = crate::config::Known {
        kinds: registry.kinds(),
        protocols: crate::protocols::Registry::standard().protocols(),
    };
    Config::from_toml_with(&text, path, Some(Default::default()), &known)
}

/// A counter reading of `d/a0` whose running total is `total` (the shared test reading, so
/// the toy's test owns no copy of the struct).
fn reading(total: i64) -> Reading {
    let mut r = Reading::sample("d", "a0", 1);
    r.update.total = total;
    r.count = total;
    r.kind = crate::profile::ChannelKind::Counter;
    r
}

const TOY_OUTPUT: &str = "[outputs.plc]\nkind = \"toy\"\n[toy]\nprefix = \"plant\"\n";

#[test]
fn a_toy_kind_registered_with_one_line_is_checked_built_and_publishes_a_reading() {
    let registry = registry();
    let config = check(&registry, TOY_OUTPUT).expect("the toy's config");
    let output = &config.outputs.list[0];
    assert_eq!((output.name.as_str(), output.kind.name()), ("plc", "toy"));
    let mut stage = Stage::new(registry.build(&config, output));
    let out = stage.render(&Output::single(reading(42)));
    assert_eq!(out.len(), 1, "{out:?}");
    assert_eq!(out[0].topic, "plant/d/a0");
    assert_eq!(&out[0].payload[..], b"42");
    assert!(
        stage.will().is_none(),
        "no gateway topics, so no voice: its will is none"
    );
}

#[test]
fn the_toy_reads_its_own_table_and_reserves_its_prefix() {
    let registry = registry();
    let config = check(&registry, TOY_OUTPUT).unwrap();
    let reserved = config.outputs.reserved_prefixes();
    assert!(reserved.iter().any(|(p, _)| p == "plant"), "{reserved:?}");
    let broken = "[outputs.plc]\nkind = \"toy\"\n[toy]\nnope = 1\n";
    let err = check(&registry, broken).unwrap_err().to_string();
    assert!(
        err.contains("toy.prefix") && err.contains("toy.nope"),
        "{err}"
    );
    let err = check(&registry, "[outputs.plc]\nkind = \"toy\"\n").unwrap_err();
    let err = err.to_string();
    assert!(err.contains("needs [toy] with its prefix"), "{err}");
    let err = check(&registry, "[toy]\nprefix = \"p\"\n").unwrap_err();
    let err = err.to_string();
    assert!(err.contains("[toy] is set but no output"), "{err}");
}

#[test]
fn a_kind_left_out_of_the_registry_cannot_be_parsed_and_the_error_lists_the_registry() {
    let err = check(&Registry::standard(), TOY_OUTPUT).unwrap_err();
    let err = err.to_string();
    assert!(err.contains("unknown output format \"toy\""), "{err}");
    assert!(
        err.contains("\"json\", \"sparkplug\", \"homeassistant\""),
        "{err}"
    );
    let err = check(&registry(), "[outputs.x]\nkind = \"xml\"\n").unwrap_err();
    let err = err.to_string();
    assert!(err.contains("\"homeassistant\", \"toy\""), "{err}");
}

#[test]
fn every_kind_has_a_name_of_its_own() {
    let names: Vec<&str> = STANDARD.iter().map(|e| e.kind.name).collect();
    let mut unique = names.clone();
    unique.sort();
    unique.dedup();
    assert_eq!(unique.len(), names.len(), "{names:?}");
    let twice = std::panic::catch_unwind(|| registry().with(STANDARD[0]));
    assert!(twice.is_err(), "a kind registered twice is refused");
}
