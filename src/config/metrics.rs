//! `[metrics]`: the Prometheus endpoint. Absent: no endpoint. Present: `listen` defaults to
//! loopback, because the endpoint is for a local scraper, not the open network.

use std::net::SocketAddr;

use super::walk::{Errors, Table, join};

/// Where `/metrics` and `/healthz` are served.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Metrics {
    pub listen: SocketAddr,
}

/// The default address: loopback, the port Prometheus's list of exporters reserves for us.
pub const DEFAULT_LISTEN: &str = "127.0.0.1:9464";

pub(super) fn check(table: Option<Table<'_>>, errs: &mut Errors) -> Option<Metrics> {
    let mut t = table?;
    let mut m = Metrics {
        listen: DEFAULT_LISTEN.parse().expect("valid default"),
    };
    if let Some(v) = t.opt::<String>("listen", errs) {
        match v.parse::<SocketAddr>() {
            Ok(a) => m.listen = a,
            Err(_) => errs.push(
                &join(&t.path, "listen"),
                t.origin(),
                format!("{v:?} is not an IP address and port, e.g. {DEFAULT_LISTEN:?}"),
            ),
        }
    }
    t.finish(errs);
    Some(m)
}
