//! What the node trusts of its host: the primary host's STATE (Sparkplug 3.0: a message older
//! than the last one accepted, or one that is not `{"online": bool, "timestamp": ms}`, is
//! ignored), and how often it does what the host asks (a rebirth at most once every
//! [`REBIRTH_GAP`], a burst of requests coalesced into one). Pure: payloads and times in,
//! verdicts out.

/// The least time between two rebirths the host asks for; requests within it are coalesced
/// into one rebirth at its end.
pub const REBIRTH_GAP_MS: u64 = 5_000;

/// What a STATE message of the primary host is to the node.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum State {
    /// Taken: the host is online or not, as of `timestamp`.
    Accepted { online: bool },
    /// Older than the last one taken: ignored (Sparkplug 3.0; a replayed or forged message).
    Stale { timestamp: u64, last: u64 },
    /// Not a STATE the spec knows: ignored.
    Malformed(&'static str),
}

/// The primary host as the node last heard of it.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct HostWatch {
    /// The timestamp of the last STATE taken (3.0), if any.
    last: Option<u64>,
    /// STATE messages ignored, since start.
    pub ignored: u64,
}

/// The largest STATE payload read (3.0's is a few dozen bytes).
const MAX_STATE: usize = 1024;

impl HostWatch {
    /// Reads a STATE payload: 3.0's retained JSON `{"online": bool, "timestamp": ms}`, or
    /// 2.2's `ONLINE` / `OFFLINE` (no timestamp: taken only while no 3.0 message was).
    pub fn state(&mut self, payload: &[u8]) -> State {
        let verdict = self.read(payload);
        if !matches!(verdict, State::Accepted { .. }) {
            self.ignored += 1;
        }
        verdict
    }

    fn read(&mut self, payload: &[u8]) -> State {
        match payload {
            b"ONLINE" | b"OFFLINE" if self.last.is_some() => {
                return State::Malformed("a 2.2 STATE after a 3.0 one");
            }
            b"ONLINE" => return State::Accepted { online: true },
            b"OFFLINE" => return State::Accepted { online: false },
            _ => {}
        }
        if payload.len() > MAX_STATE {
            return State::Malformed("larger than a STATE");
        }
        let Ok(serde_json::Value::Object(v)) = serde_json::from_slice(payload) else {
            return State::Malformed("not a JSON object");
        };
        let Some(online) = v.get("online").and_then(serde_json::Value::as_bool) else {
            return State::Malformed("\"online\" is not true or false");
        };
        let Some(timestamp) = v.get("timestamp").and_then(serde_json::Value::as_u64) else {
            return State::Malformed("\"timestamp\" is not a time in milliseconds");
        };
        if let Some(last) = self.last
            && timestamp < last
        {
            return State::Stale { timestamp, last };
        }
        self.last = Some(timestamp);
        State::Accepted { online }
    }
}

/// The host's rebirth requests: each one counted, at most one rebirth every
/// [`REBIRTH_GAP_MS`], the requests in between coalesced into one at its end.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Rebirths {
    /// When the last rebirth went out (the node's clock, ms).
    last: Option<u64>,
    /// A request came within the gap: one rebirth is owed at its end.
    pending: bool,
    /// Requests since start, and the rebirths they caused.
    pub requested: u64,
    pub done: u64,
}

impl Rebirths {
    /// The host asks for a rebirth at `now_ms`: `true` when it is to be done now.
    pub fn request(&mut self, now_ms: u64) -> bool {
        self.requested += 1;
        self.pending = true;
        self.due(now_ms)
    }

    /// Whether an owed rebirth is due at `now_ms` (then it counts as done).
    pub fn due(&mut self, now_ms: u64) -> bool {
        // A clock stepped back counts as the gap elapsed: a rebirth is never blocked for long.
        let recent = self
            .last
            .is_some_and(|t| now_ms >= t && now_ms - t < REBIRTH_GAP_MS);
        if !self.pending || recent {
            return false;
        }
        self.pending = false;
        self.last = Some(now_ms);
        self.done += 1;
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn state(ts: &str, online: bool) -> Vec<u8> {
        format!("{{\"online\":{online},\"timestamp\":{ts}}}").into_bytes()
    }

    #[test]
    fn a_state_older_than_the_last_one_taken_is_ignored() {
        let mut h = HostWatch::default();
        assert_eq!(
            h.state(&state("20000", true)),
            State::Accepted { online: true }
        );
        assert_eq!(
            h.state(&state("10000", false)),
            State::Stale {
                timestamp: 10000,
                last: 20000
            }
        );
        assert_eq!(
            h.state(&state("5000", true)),
            State::Stale {
                timestamp: 5000,
                last: 20000
            }
        );
        assert_eq!(
            h.state(&state("20000", false)),
            State::Accepted { online: false }
        );
        assert_eq!(h.ignored, 2);
    }

    #[test]
    fn a_state_without_a_time_or_a_flag_is_malformed() {
        let mut h = HostWatch::default();
        for bad in [
            &br#"{"online":false,"timestamp":"x"}"#[..],
            br#"{"online":false}"#,
            br#"{"online":"no","timestamp":1}"#,
            br#"{"online":true,"timestamp":-5}"#,
            b"[]",
            b"\xff\xfe",
        ] {
            assert!(matches!(h.state(bad), State::Malformed(_)), "{bad:?}");
        }
        assert_eq!(h.ignored, 6);
    }

    #[test]
    fn the_older_text_state_is_taken_only_before_any_json_one() {
        let mut h = HostWatch::default();
        assert_eq!(h.state(b"ONLINE"), State::Accepted { online: true });
        assert_eq!(h.state(&state("1", true)), State::Accepted { online: true });
        assert!(matches!(h.state(b"OFFLINE"), State::Malformed(_)));
    }

    #[test]
    fn three_hundred_requests_in_a_burst_are_one_rebirth_now_and_one_at_the_end_of_the_gap() {
        let mut r = Rebirths::default();
        let now = 60_000;
        let at_once = (0..300).filter(|i| r.request(now + i)).count();
        assert_eq!(at_once, 1, "the first is done at once");
        assert!(!r.due(now + 1000), "within the gap");
        assert!(r.due(now + REBIRTH_GAP_MS), "the rest coalesced into one");
        assert!(!r.due(now + 2 * REBIRTH_GAP_MS), "nothing more owed");
        assert_eq!((r.requested, r.done), (300, 2));
    }

    #[test]
    fn a_clock_stepped_back_does_not_block_a_rebirth() {
        let mut r = Rebirths::default();
        assert!(r.request(1_000_000));
        assert!(
            r.request(10),
            "the clock went back: the gap counts as elapsed"
        );
    }
}
