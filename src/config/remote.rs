//! `[remote]`: config pushed from the broker (off by default). `config = true` takes a new
//! config on `<root>/config/set`, checks it as `pulsegate check` does, applies it and watches it
//! for `grace`; `security = true` lets a pushed config change what holds secrets or trust
//! (`[mqtt]`'s and the outputs' credentials and TLS, and `[remote]` itself).

use std::time::Duration;

use super::walk::{Errors, Table};

/// `[remote]`, checked.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Remote {
    pub config: bool,
    /// How long a pushed config is watched before it is kept (or rolled back).
    pub grace: Duration,
    pub security: bool,
}

/// The default grace period of a pushed config.
pub const DEFAULT_GRACE: Duration = Duration::from_secs(60);

impl Default for Remote {
    fn default() -> Remote {
        Remote {
            config: false,
            grace: DEFAULT_GRACE,
            security: false,
        }
    }
}

/// Reads `[remote]`.
pub(crate) fn read(table: Option<Table<'_>>, errs: &mut Errors) -> Remote {
    let mut r = Remote::default();
    let Some(mut t) = table else { return r };
    if let Some(v) = t.opt("config", errs) {
        r.config = v;
    }
    if let Some(v) = t.duration_within(
        "grace",
        Duration::from_secs(5),
        Duration::from_secs(3600),
        errs,
    ) {
        r.grace = v;
    }
    if let Some(v) = t.opt("security", errs) {
        r.security = v;
    }
    t.finish(errs);
    r
}
