//! An output kind as the config sees it: its name, whether it carries the gateway's topics, its
//! settings (its own table, read by its own file) and the topic prefixes it reserves. The kinds
//! are not listed here: the output registry (`publish/formats.rs`, where each is built) hands
//! them to the check as [`Kinds`], so a kind left out of it cannot be parsed, built or named in
//! an error.

use std::any::Any;
use std::fmt;
use std::sync::Arc;

use crate::config::walk::{Errors, Table};

/// An output kind's part of the config. Each kind's file has one, as a `static`.
pub struct Kind {
    /// The name the config writes (`kind = "…"`, `mqtt.format`).
    pub name: &'static str,
    /// Whether it publishes the gateway's JSON topics under its topic root (and so says the
    /// gateway's status there, with that status as its will).
    pub gateway_topics: bool,
    /// Its settings, when it has a table of its own.
    pub table: Option<OwnTable>,
    /// The topic prefix no command may point a response topic into, and why, given its
    /// settings (`None` when its table is absent or broken).
    pub reserved: fn(Option<&dyn Settings>) -> Reserved,
}

/// A topic prefix a kind reserves, and why.
pub type Reserved = Option<(String, &'static str)>;

/// The reader of a kind's own table.
pub(crate) type Read =
    fn(Option<Table<'_>>, &Context<'_>, &mut Errors) -> Option<Arc<dyn Settings>>;

/// A kind's own top-level table (`[sparkplug]`, `[homeassistant]`) and the file that reads it.
pub struct OwnTable {
    /// The table's name.
    pub name: &'static str,
    /// Reads it (absent: `None`); `None` back when absent or broken (the problems in `errs`).
    pub(crate) read: Read,
    /// `Some(what)`: an output of this kind needs the table (`"with its group_id"`), and the
    /// table without such an output is an error too.
    pub needed: Option<&'static str>,
}

/// What a kind's reader may know of the rest of the config.
pub struct Context<'a> {
    /// `[gateway] id`.
    pub gateway_id: &'a str,
}

/// A kind's checked settings, kept in [`super::Outputs`] and found again by their type.
pub trait Settings: Any + fmt::Debug + Send + Sync {
    fn as_any(&self) -> &dyn Any;
    fn same(&self, other: &dyn Settings) -> bool;
}

impl<T: Any + fmt::Debug + PartialEq + Send + Sync> Settings for T {
    fn as_any(&self) -> &dyn Any {
        self
    }
    fn same(&self, other: &dyn Settings) -> bool {
        other.as_any().downcast_ref::<T>() == Some(self)
    }
}

impl PartialEq for dyn Settings {
    fn eq(&self, other: &dyn Settings) -> bool {
        self.same(other)
    }
}

/// A kind that reserves no topic prefix.
pub fn reserves_nothing(_: Option<&dyn Settings>) -> Reserved {
    None
}

/// What an output publishes: one of the registry's kinds, had from [`Kinds::find`] (outside the
/// config). Compared by name.
#[derive(Clone, Copy)]
pub struct OutputKind(&'static Kind);

impl OutputKind {
    pub(crate) fn of(kind: &'static Kind) -> OutputKind {
        OutputKind(kind)
    }

    /// The name the config writes.
    pub fn name(self) -> &'static str {
        self.0.name
    }

    /// Whether it publishes the gateway's JSON topics under its topic root.
    pub fn carries_gateway_topics(self) -> bool {
        self.0.gateway_topics
    }

    /// Whether it is `kind`.
    pub fn is(self, kind: &Kind) -> bool {
        self.0.name == kind.name
    }
}

impl PartialEq for OutputKind {
    fn eq(&self, other: &OutputKind) -> bool {
        self.0.name == other.0.name
    }
}

impl Eq for OutputKind {}

impl fmt::Debug for OutputKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "OutputKind({:?})", self.0.name)
    }
}

impl fmt::Display for OutputKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// The kinds a config may name, in the order the registry lists them (and an error does).
#[derive(Clone)]
pub struct Kinds(pub Vec<&'static Kind>);

impl Kinds {
    /// The kind named `name`.
    pub fn find(&self, name: &str) -> Option<OutputKind> {
        self.0
            .iter()
            .find(|k| k.name == name)
            .map(|k| OutputKind(k))
    }

    /// The kinds as an error lists them.
    pub fn list(&self) -> String {
        let names: Vec<String> = self.0.iter().map(|k| format!("{:?}", k.name)).collect();
        names.join(", ")
    }

    /// Every kind.
    pub fn all(&self) -> impl Iterator<Item = OutputKind> + '_ {
        self.0.iter().map(|k| OutputKind(k))
    }
}
