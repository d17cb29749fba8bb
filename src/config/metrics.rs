//! `[metrics]`: the HTTP endpoint (`/metrics`, `/healthz`, the status page and its API).
//! Absent: no endpoint. Present: `listen` defaults to loopback, because the endpoint is for a
//! local scraper and a technician on the machine, not the open network; an address anyone else
//! can reach needs `token`, or the config is refused.

use std::net::SocketAddr;

use super::connection::Secret;
use super::walk::{Errors, Table, join};

/// Where the HTTP endpoint listens, and the token its page and API ask for.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Metrics {
    pub listen: SocketAddr,
    /// `token`: the bearer token (or login) the status page and `/api/v1/status` ask for;
    /// required when `listen` is not loopback. `/metrics` and `/healthz` never ask.
    pub token: Option<Secret>,
}

/// The default address: loopback, the port Prometheus's list of exporters reserves for us.
pub const DEFAULT_LISTEN: &str = "127.0.0.1:9464";

/// A token shorter than this is too easy to guess over the network.
pub const MIN_TOKEN_CHARS: usize = 16;

pub(crate) fn check(table: Option<Table<'_>>, errs: &mut Errors) -> Option<Metrics> {
    let mut t = table?;
    let mut m = Metrics {
        listen: DEFAULT_LISTEN.parse().expect("valid default"),
        token: None,
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
    if let Some(token) = t.opt::<String>("token", errs) {
        let fits = |c: char| c.is_ascii_alphanumeric() || "-._~+/=".contains(c);
        if token.chars().count() < MIN_TOKEN_CHARS || !token.chars().all(fits) {
            errs.push(
                &join(&t.path, "token"),
                t.origin(),
                format!(
                    "must be at least {MIN_TOKEN_CHARS} characters of A-Z, a-z, 0-9 and -._~+/= (e.g. the output of `openssl rand -hex 16`)"
                ),
            );
        }
        m.token = Some(Secret(token));
    }
    if !m.listen.ip().is_loopback() && m.token.is_none() {
        errs.push(
            &join(&t.path, "token"),
            t.origin(),
            format!(
                "listen = \"{}\" is reachable from other machines: set metrics.token (the status page and its API ask for it), or listen on loopback ({DEFAULT_LISTEN:?})",
                m.listen
            ),
        );
    }
    t.finish(errs);
    Some(m)
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use crate::config::Config;

    const BASE: &str = "[mqtt]\nhost = \"b\"\n[buses.l]\nport = \"/dev/ttyUSB0\"\n[buses.l.devices.m]\nunit = 1\nmodel = \"yl67\"\n";

    fn check(metrics: &str) -> Result<Config, String> {
        let text = format!("{BASE}[metrics]\n{metrics}");
        Config::from_toml(&text, Path::new("t.toml"), Some(Default::default()))
            .map_err(|e| e.to_string())
    }

    #[test]
    fn a_listener_other_machines_can_reach_without_a_token_is_refused_naming_the_key() {
        let err = check("listen = \"0.0.0.0:9464\"\n").unwrap_err();
        assert!(err.contains("metrics.token"), "{err}");
        assert!(err.contains("0.0.0.0:9464"), "{err}");
        let ok = check("listen = \"0.0.0.0:9464\"\ntoken = \"0123456789abcdef\"\n").unwrap();
        let token = ok.metrics.unwrap().token.unwrap();
        assert_eq!(token.0, "0123456789abcdef");
    }

    #[test]
    fn loopback_needs_no_token_and_a_short_token_is_refused() {
        assert!(check("listen = \"127.0.0.1:9464\"\n").is_ok());
        assert!(check("listen = \"[::1]:9464\"\n").is_ok());
        let err = check("token = \"short\"\n").unwrap_err();
        assert!(err.contains("metrics.token") && err.contains("16"), "{err}");
    }
}
