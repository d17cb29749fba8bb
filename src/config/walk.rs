//! A walker over the merged configuration tree that records every problem it meets, with the
//! key path and the file (or "the environment") it came from, instead of stopping at the first.

use std::collections::BTreeSet;
use std::time::Duration;

use config::{Map, Value, ValueKind};
use serde::de::DeserializeOwned;

use super::error::ConfigError;

/// The longest duration any key takes (a week): far beyond any sensible poll or flush interval,
/// and far from overflowing a deadline.
pub(crate) const MAX_DURATION: Duration = Duration::from_secs(7 * 24 * 3600);

/// Collected errors of one configuration check.
#[derive(Debug, Default)]
pub(crate) struct Errors {
    pub list: Vec<ConfigError>,
    pub default_origin: String,
}

impl Errors {
    pub fn push(&mut self, path: &str, origin: Option<&str>, message: impl Into<String>) {
        self.list.push(ConfigError {
            path: path.to_string(),
            origin: origin.unwrap_or(&self.default_origin).to_string(),
            message: message.into(),
        });
    }
}

/// One table of the tree: hands out its keys and reports the ones nobody asked for.
pub(crate) struct Table<'a> {
    pub path: String,
    origin: Option<String>,
    map: &'a Map<String, Value>,
    used: BTreeSet<String>,
}

/// Joins a table path and a key.
pub(crate) fn join(path: &str, key: &str) -> String {
    if path.is_empty() {
        key.to_string()
    } else {
        format!("{path}.{key}")
    }
}

impl<'a> Table<'a> {
    /// A view of `value` as a table, or an error at `path` when it is something else.
    pub fn of(value: &'a Value, path: &str, errs: &mut Errors) -> Option<Table<'a>> {
        match &value.kind {
            ValueKind::Table(map) => Some(Table {
                path: path.to_string(),
                origin: value.origin().map(str::to_string),
                map,
                used: BTreeSet::new(),
            }),
            _ => {
                errs.push(path, value.origin(), "expected a table");
                None
            }
        }
    }

    pub fn origin(&self) -> Option<&str> {
        self.origin.as_deref()
    }

    fn take(&mut self, key: &str) -> Option<&'a Value> {
        self.used.insert(key.to_string());
        self.map.get(key)
    }

    /// An optional value of any deserializable type.
    pub fn opt<T: DeserializeOwned>(&mut self, key: &str, errs: &mut Errors) -> Option<T> {
        let value = self.take(key)?;
        match value.clone().try_deserialize::<T>() {
            Ok(v) => Some(v),
            Err(e) => {
                errs.push(
                    &join(&self.path, key),
                    value.origin(),
                    clean(&e.to_string()),
                );
                None
            }
        }
    }

    /// An optional value as the tree holds it (for values of more than one type).
    pub fn raw(&mut self, key: &str) -> Option<&'a Value> {
        self.take(key)
    }

    /// A value that must be present.
    pub fn req<T: DeserializeOwned>(&mut self, key: &str, errs: &mut Errors) -> Option<T> {
        if !self.map.contains_key(key) {
            errs.push(&join(&self.path, key), self.origin(), "missing");
            self.used.insert(key.to_string());
            return None;
        }
        self.opt(key, errs)
    }

    /// An optional integer. Strings of digits are taken (environment overrides are strings);
    /// a decimal number is refused rather than rounded (1.5 must not become unit 1).
    pub fn int<T: TryFrom<i64>>(&mut self, key: &str, errs: &mut Errors) -> Option<T> {
        let value = self.take(key)?;
        let path = join(&self.path, key);
        let n: Option<i64> = match &value.kind {
            ValueKind::I64(n) => Some(*n),
            ValueKind::U64(n) => i64::try_from(*n).ok(),
            ValueKind::I128(n) => i64::try_from(*n).ok(),
            ValueKind::U128(n) => i64::try_from(*n).ok(),
            ValueKind::String(s) => s.trim().parse().ok(),
            _ => None,
        };
        let Some(n) = n else {
            let what = match &value.kind {
                ValueKind::Float(_) => "expected a whole number, not a decimal one",
                _ => "expected a whole number",
            };
            errs.push(&path, value.origin(), what);
            return None;
        };
        match T::try_from(n) {
            Ok(v) => Some(v),
            Err(_) => {
                errs.push(&path, value.origin(), format!("{n} is out of range"));
                None
            }
        }
    }

    /// An optional humantime duration ("300ms", "1m 30s"), greater than zero and at most
    /// [`MAX_DURATION`].
    pub fn duration(&mut self, key: &str, errs: &mut Errors) -> Option<Duration> {
        self.duration_within(key, Duration::from_millis(1), MAX_DURATION, errs)
    }

    /// An optional humantime duration within `min..=max` (a zero `min` allows zero): every
    /// duration is bounded, so no deadline computed from one can overflow.
    pub fn duration_within(
        &mut self,
        key: &str,
        min: Duration,
        max: Duration,
        errs: &mut Errors,
    ) -> Option<Duration> {
        let value = self.take(key)?;
        let path = join(&self.path, key);
        let text = match &value.kind {
            ValueKind::String(s) => s.clone(),
            _ => {
                errs.push(
                    &path,
                    value.origin(),
                    "expected a duration such as \"500ms\" or \"2s\"",
                );
                return None;
            }
        };
        match humantime::parse_duration(&text) {
            Ok(d) if d.is_zero() && !min.is_zero() => {
                errs.push(&path, value.origin(), "must be greater than zero");
                None
            }
            Ok(d) if d < min => {
                errs.push(
                    &path,
                    value.origin(),
                    format!("must be at least {}", humantime::format_duration(min)),
                );
                None
            }
            Ok(d) if d > max => {
                errs.push(
                    &path,
                    value.origin(),
                    format!("must be at most {}", humantime::format_duration(max)),
                );
                None
            }
            Ok(d) => Some(d),
            Err(e) => {
                errs.push(&path, value.origin(), format!("bad duration {text:?}: {e}"));
                None
            }
        }
    }

    /// A sub-table, when present.
    pub fn table(&mut self, key: &str, errs: &mut Errors) -> Option<Table<'a>> {
        let value = self.take(key)?;
        Table::of(value, &join(&self.path, key), errs)
    }

    /// The entries of a sub-table whose keys are names (buses, devices), sorted by name.
    pub fn entries(&mut self, key: &str, errs: &mut Errors) -> Vec<(String, &'a Value)> {
        let Some(value) = self.take(key) else {
            return Vec::new();
        };
        match &value.kind {
            ValueKind::Table(map) => {
                let mut v: Vec<_> = map.iter().map(|(k, v)| (k.clone(), v)).collect();
                v.sort_by(|a, b| a.0.cmp(&b.0));
                v
            }
            _ => {
                errs.push(
                    &join(&self.path, key),
                    value.origin(),
                    "expected a table of named entries",
                );
                Vec::new()
            }
        }
    }

    /// Whether a key is present (and marks it used).
    pub fn has(&mut self, key: &str) -> bool {
        self.map.contains_key(key)
    }

    /// Reports every key nobody asked for as unknown.
    pub fn finish(self, errs: &mut Errors) {
        let mut unknown: Vec<_> = self
            .map
            .iter()
            .filter(|(k, _)| !self.used.contains(*k))
            .collect();
        unknown.sort_by(|a, b| a.0.cmp(b.0));
        for (key, value) in unknown {
            errs.push(&join(&self.path, key), value.origin(), "unknown key");
        }
    }
}

/// The config crate's messages end with their own origin; ours carries it separately.
fn clean(msg: &str) -> String {
    match msg.find(" for key") {
        Some(i) => msg[..i].to_string(),
        None => msg.to_string(),
    }
}
