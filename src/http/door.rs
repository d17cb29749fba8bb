//! Who may see the page, its files and its API: every token given (a login form's, a bearer, the
//! cookie) goes through the per-client lockout (`lockout.rs`) before it is compared, and every
//! refused one is counted (`pulsegate_http_login_failures_total`) and said within a log budget
//! (a guessing script must not flood the journal and push real events out of its rate limit).

use std::sync::Mutex;
use std::time::Duration;

use hyper::HeaderMap;
use tokio::time::Instant;

use super::auth;
use super::lockout::{Client, LOCKOUT, Lockout, MAX_FAILURES, WINDOW, Wrong};
use super::slots::lock;
use crate::config::Secret;
use crate::log_budget::LogBudget;
use crate::metrics::{LoginFailure, Metrics};

/// Lines a minute about refused tokens; the rest are counted in the next one.
const LOG_PER_MINUTE: u32 = 10;

/// What the door says to a request.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Pass {
    /// In: no token configured, or it gave the token.
    Open,
    /// 401: it gave no token, or a wrong one.
    Closed,
    /// 429: its client is locked out for this long yet; what it gave was not looked at.
    Limited(Duration),
}

/// The token, the lockout and the log budget of the endpoint.
pub struct Door {
    token: Option<Secret>,
    metrics: Metrics,
    inside: Mutex<Inside>,
}

struct Inside {
    lockout: Lockout,
    log: LogBudget,
}

impl Door {
    /// A door for `token` (none: always open), counting in `metrics`.
    pub fn new(token: Option<Secret>, metrics: Metrics) -> Door {
        Door {
            token,
            metrics,
            inside: Mutex::new(Inside {
                lockout: Lockout::default(),
                log: LogBudget::new(LOG_PER_MINUTE),
            }),
        }
    }

    /// The token, if one is configured.
    pub fn token(&self) -> Option<&Secret> {
        self.token.as_ref()
    }

    /// A request for the page, its files or the API from `client`, by its headers.
    pub fn request(&self, client: Client, headers: &HeaderMap) -> Pass {
        let Some(token) = &self.token else {
            return Pass::Open;
        };
        let given = auth::given(headers);
        if given.is_empty() {
            // Nothing to check, so nothing guessed: the login form (or a bearer challenge).
            return Pass::Closed;
        }
        self.judge(client, || auth::any_is(&given, token))
    }

    /// `POST /login` from `client`, giving `given`.
    pub fn login(&self, client: Client, given: &str) -> Pass {
        let Some(token) = &self.token else {
            return Pass::Open;
        };
        self.judge(client, || auth::same(given, &token.0))
    }

    /// `right` is asked only when `client` is not locked out.
    fn judge(&self, client: Client, right: impl FnOnce() -> bool) -> Pass {
        let now = Instant::now();
        let mut inside = lock(&self.inside);
        if let Err(left) = inside.lockout.admit(client, now) {
            self.metrics.login_failure(LoginFailure::Limited);
            if inside.may_log(now) {
                let s = left.as_secs();
                tracing::info!(%client, "status page: a token refused unchecked (429): its client is locked out for {s} s more");
            }
            return Pass::Limited(left);
        }
        if right() {
            inside.lockout.right(client);
            return Pass::Open;
        }
        self.metrics.login_failure(LoginFailure::WrongToken);
        let wrong = inside.lockout.wrong(client, now);
        let log = inside.may_log(now);
        match wrong {
            Wrong::Counted => {
                if log {
                    tracing::info!(%client, "status page: a wrong token");
                }
                Pass::Closed
            }
            Wrong::LockedOut => {
                if log {
                    let (n, w, l) = (MAX_FAILURES, WINDOW.as_secs(), LOCKOUT.as_secs());
                    tracing::warn!(%client, "status page: {n} wrong tokens within {w} s: the client's tokens are refused (429) for {l} s");
                }
                Pass::Limited(LOCKOUT)
            }
        }
    }
}

impl Inside {
    /// Whether a line may be logged at `now`; says first how many the last minute did not.
    fn may_log(&mut self, now: Instant) -> bool {
        let (log, suppressed) = self.log.allow(now);
        if let Some(n) = suppressed {
            tracing::warn!(
                suppressed = n,
                "status page: {n} more refused tokens (wrong, or from a locked-out client) in the last minute were not logged one by one (pulsegate_http_login_failures_total counts them)"
            );
        }
        log
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use hyper::header::{AUTHORIZATION, HeaderValue};

    fn bearer(token: &str) -> HeaderMap {
        let mut h = HeaderMap::new();
        let v = HeaderValue::from_str(&format!("Bearer {token}")).unwrap();
        h.insert(AUTHORIZATION, v);
        h
    }

    const TOKEN: &str = "0123456789abcdef";

    fn failures(m: &Metrics, result: &str) -> u64 {
        let text = m.encode();
        let series = format!("pulsegate_http_login_failures_total{{result=\"{result}\"}} ");
        let line = text.lines().find(|l| l.starts_with(&series)).unwrap();
        line.rsplit(' ').next().unwrap().parse().unwrap()
    }

    #[test]
    fn a_door_without_a_token_lets_everyone_in_and_counts_nothing() {
        let m = Metrics::new();
        let door = Door::new(None, m.clone());
        let c = Client::of([127, 0, 0, 1].into());
        assert_eq!(door.request(c, &HeaderMap::new()), Pass::Open);
        assert_eq!(door.login(c, "anything"), Pass::Open);
        assert_eq!(failures(&m, "wrong_token") + failures(&m, "limited"), 0);
    }

    #[test]
    fn wrong_bearers_and_logins_share_one_count_and_the_lockout_refuses_the_right_token_too() {
        let m = Metrics::new();
        let door = Door::new(Some(Secret(TOKEN.into())), m.clone());
        let c = Client::of([127, 0, 0, 1].into());
        assert_eq!(door.request(c, &HeaderMap::new()), Pass::Closed);
        assert_eq!(failures(&m, "wrong_token"), 0, "giving nothing is no guess");
        for _ in 0..2 {
            assert_eq!(door.request(c, &bearer("not-the-token-000")), Pass::Closed);
            assert_eq!(door.login(c, "not-the-token-000"), Pass::Closed);
        }
        assert_eq!(door.login(c, "not-the-token-000"), Pass::Limited(LOCKOUT));
        assert!(matches!(door.request(c, &bearer(TOKEN)), Pass::Limited(_)));
        assert!(matches!(door.login(c, TOKEN), Pass::Limited(_)));
        assert_eq!(failures(&m, "wrong_token"), 5);
        assert_eq!(failures(&m, "limited"), 2);
        let other = Client::of([127, 0, 0, 2].into());
        assert_eq!(door.request(other, &bearer(TOKEN)), Pass::Open);
    }
}
