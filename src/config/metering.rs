//! Metering keys: `intervals` (gateway, device, channel levels; the most specific one wins) and
//! `gateway.timezone`.

use super::walk::{Errors, Table, join};
use crate::metering::{Clock, Period};

/// Reads `intervals = ["15min", "1h", …]` of one table. `Some(vec![])` turns intervals off below
/// a level that has them.
pub(crate) fn intervals(t: &mut Table<'_>, errs: &mut Errors) -> Option<Vec<Period>> {
    let texts = t.opt::<Vec<String>>("intervals", errs)?;
    let path = join(&t.path, "intervals");
    let mut periods: Vec<Period> = Vec::with_capacity(texts.len());
    for text in texts {
        match Period::parse(&text) {
            Ok(p) => match periods.iter().find(|q| q.ms() == p.ms()) {
                Some(q) => errs.push(
                    &path,
                    t.origin(),
                    format!(
                        "{text:?} is the same period as {:?}: list each once",
                        q.text()
                    ),
                ),
                None => periods.push(p),
            },
            Err(e) => errs.push(&path, t.origin(), e.to_string()),
        }
    }
    Some(periods)
}

/// Reads `timezone` (IANA name, default UTC).
pub(crate) fn timezone(t: &mut Table<'_>, errs: &mut Errors) -> Clock {
    let Some(name) = t.opt::<String>("timezone", errs) else {
        return Clock::default();
    };
    Clock::named(&name).unwrap_or_else(|e| {
        errs.push(&join(&t.path, "timezone"), t.origin(), e.to_string());
        Clock::default()
    })
}
