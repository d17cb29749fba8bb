//! Wrong tokens, limited per client: an address that gives [`MAX_FAILURES`] wrong tokens within
//! [`WINDOW`] has every token it gives refused unchecked for [`LOCKOUT`], the right one too (so
//! guessing costs a minute per handful of tries). What is remembered is bounded: at most
//! [`MAX_CLIENTS`] clients, the one heard from least recently forgotten for a new one. Pure:
//! the time is an argument.

use std::collections::{BTreeMap, HashMap, VecDeque};
use std::fmt;
use std::net::IpAddr;
use std::time::Duration;

use tokio::time::Instant;

/// Wrong tokens a client may give within [`WINDOW`]; the one that makes them this many locks
/// it out.
pub const MAX_FAILURES: usize = 5;
/// The window wrong tokens are counted in (sliding: any 60 s).
pub const WINDOW: Duration = Duration::from_secs(60);
/// How long a locked-out client's tokens are refused unchecked.
pub const LOCKOUT: Duration = Duration::from_secs(60);
/// Clients remembered at most (about 200 bytes each).
pub const MAX_CLIENTS: usize = 1024;

/// Who gives a token, as the lockout counts: an IPv4 address, or the /64 an IPv6 address is in
/// (one host usually has a whole /64 to pick its addresses from).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Client {
    V4([u8; 4]),
    V6Net([u8; 8]),
}

impl Client {
    /// The client a connection from `ip` counts as (an IPv4 address mapped into IPv6 is that
    /// IPv4 address).
    pub fn of(ip: IpAddr) -> Client {
        match ip {
            IpAddr::V4(v4) => Client::V4(v4.octets()),
            IpAddr::V6(v6) => match v6.to_ipv4_mapped() {
                Some(v4) => Client::V4(v4.octets()),
                None => {
                    let o = v6.octets();
                    Client::V6Net([o[0], o[1], o[2], o[3], o[4], o[5], o[6], o[7]])
                }
            },
        }
    }
}

impl fmt::Display for Client {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Client::V4(o) => write!(f, "{}", std::net::Ipv4Addr::from(*o)),
            Client::V6Net(o) => {
                let mut full = [0u8; 16];
                full[..8].copy_from_slice(o);
                write!(f, "{}/64", std::net::Ipv6Addr::from(full))
            }
        }
    }
}

/// What a client's wrong token did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Wrong {
    /// Counted; the client may try again.
    Counted,
    /// It was one too many: the client is locked out for [`LOCKOUT`].
    LockedOut,
}

/// One client's recent wrong tokens and lockout.
#[derive(Debug)]
struct Entry {
    /// When its last wrong tokens came, oldest first; at most [`MAX_FAILURES`], none older
    /// than [`WINDOW`] once looked at.
    failures: VecDeque<Instant>,
    locked_until: Option<Instant>,
    /// Its place in [`Lockout::by_use`].
    used: u64,
}

/// Every remembered client's wrong tokens and lockout.
#[derive(Debug)]
pub struct Lockout {
    clients: HashMap<Client, Entry>,
    /// Clients by when they were last heard from (a counter, not a time), oldest first.
    by_use: BTreeMap<u64, Client>,
    next_use: u64,
    capacity: usize,
}

impl Default for Lockout {
    fn default() -> Lockout {
        Lockout::new(MAX_CLIENTS)
    }
}

impl Lockout {
    /// No client remembered; at most `capacity` (at least 1) will be.
    pub fn new(capacity: usize) -> Lockout {
        Lockout {
            clients: HashMap::new(),
            by_use: BTreeMap::new(),
            next_use: 0,
            capacity: capacity.max(1),
        }
    }

    /// Whether `client`'s token may be checked at `now`: `Err` with the time left while it is
    /// locked out.
    pub fn admit(&mut self, client: Client, now: Instant) -> Result<(), Duration> {
        let Some(entry) = self.clients.get(&client) else {
            return Ok(());
        };
        match entry.locked_until {
            Some(until) if until > now => {
                self.touch(client);
                Err(until - now)
            }
            Some(_) => {
                // The lockout is over: the client starts again with a clean slate.
                self.forget(client);
                Ok(())
            }
            None => Ok(()),
        }
    }

    /// `client` gave a wrong token at `now`.
    pub fn wrong(&mut self, client: Client, now: Instant) -> Wrong {
        if !self.clients.contains_key(&client) {
            self.make_room();
            self.clients.insert(
                client,
                Entry {
                    failures: VecDeque::with_capacity(MAX_FAILURES),
                    locked_until: None,
                    used: 0,
                },
            );
        }
        self.touch(client);
        let Some(entry) = self.clients.get_mut(&client) else {
            return Wrong::Counted;
        };
        entry.failures.push_back(now);
        while entry.failures.len() > MAX_FAILURES
            || entry
                .failures
                .front()
                .is_some_and(|t| now.saturating_duration_since(*t) >= WINDOW)
        {
            entry.failures.pop_front();
        }
        if entry.failures.len() < MAX_FAILURES {
            return Wrong::Counted;
        }
        entry.failures.clear();
        entry.locked_until = Some(now + LOCKOUT);
        Wrong::LockedOut
    }

    /// `client` gave the right token: its wrong ones are forgotten (whoever knows the token
    /// has nothing to guess).
    pub fn right(&mut self, client: Client) {
        self.forget(client);
    }

    /// Clients remembered now.
    #[cfg(test)]
    pub fn remembered(&self) -> usize {
        self.clients.len()
    }

    /// `client` was heard from: it becomes the last one to be forgotten.
    fn touch(&mut self, client: Client) {
        let Some(entry) = self.clients.get_mut(&client) else {
            return;
        };
        self.by_use.remove(&entry.used);
        entry.used = self.next_use;
        self.next_use += 1;
        self.by_use.insert(entry.used, client);
    }

    fn forget(&mut self, client: Client) {
        if let Some(entry) = self.clients.remove(&client) {
            self.by_use.remove(&entry.used);
        }
    }

    /// Forgets the client heard from least recently while the table is full.
    fn make_room(&mut self) {
        while self.clients.len() >= self.capacity {
            match self.by_use.pop_first() {
                Some((_, oldest)) => {
                    self.clients.remove(&oldest);
                }
                None => break,
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn client(last: u8) -> Client {
        Client::of(IpAddr::from([192, 0, 2, last]))
    }

    const SECOND: Duration = Duration::from_secs(1);

    #[test]
    fn the_fifth_wrong_token_within_a_minute_locks_the_client_out_for_a_minute() {
        let mut l = Lockout::default();
        let t = Instant::now();
        let c = client(1);
        for i in 0..4 {
            assert_eq!(l.admit(c, t + i * SECOND), Ok(()));
            assert_eq!(l.wrong(c, t + i * SECOND), Wrong::Counted, "try {i}");
        }
        assert_eq!(l.wrong(c, t + 4 * SECOND), Wrong::LockedOut);
        assert_eq!(l.admit(c, t + 4 * SECOND), Err(LOCKOUT));
        assert_eq!(l.admit(c, t + 34 * SECOND), Err(30 * SECOND));
        assert_eq!(l.admit(client(2), t + 5 * SECOND), Ok(()), "others may try");
    }

    #[test]
    fn the_right_token_is_refused_during_the_lockout_and_taken_once_it_is_over() {
        let mut l = Lockout::default();
        let t = Instant::now();
        let c = client(1);
        for _ in 0..MAX_FAILURES {
            l.wrong(c, t);
        }
        // The shell asks before it compares: a locked-out client's token is never looked at.
        assert!(l.admit(c, t + LOCKOUT - SECOND).is_err());
        assert_eq!(l.admit(c, t + LOCKOUT), Ok(()));
        l.right(c);
        assert_eq!(l.remembered(), 0, "the right token forgets the client");
    }

    #[test]
    fn after_a_lockout_the_client_starts_again_with_a_clean_slate() {
        let mut l = Lockout::default();
        let t = Instant::now();
        let c = client(1);
        for _ in 0..MAX_FAILURES {
            l.wrong(c, t);
        }
        let after = t + LOCKOUT;
        assert_eq!(l.admit(c, after), Ok(()));
        for _ in 0..MAX_FAILURES - 1 {
            assert_eq!(l.wrong(c, after), Wrong::Counted);
        }
        assert_eq!(l.wrong(c, after), Wrong::LockedOut);
    }

    #[test]
    fn wrong_tokens_spread_over_more_than_a_minute_never_lock_out() {
        let mut l = Lockout::default();
        let t = Instant::now();
        let c = client(1);
        // Four a minute, forever: each minute's first has aged out when the next minute's come.
        for minute in 0..10u32 {
            for i in 0..4u32 {
                let at = t + minute * WINDOW + i * SECOND;
                assert_eq!(l.admit(c, at), Ok(()));
                assert_eq!(l.wrong(c, at), Wrong::Counted, "minute {minute}, try {i}");
            }
        }
    }

    #[test]
    fn the_window_slides_so_a_burst_across_its_edge_still_locks_out() {
        let mut l = Lockout::default();
        let t = Instant::now();
        let c = client(1);
        l.wrong(c, t);
        for _ in 0..3 {
            l.wrong(c, t + 59 * SECOND);
        }
        // 61 s after the first: it has aged out, the three of second 59 have not.
        assert_eq!(l.wrong(c, t + 61 * SECOND), Wrong::Counted);
        assert_eq!(l.wrong(c, t + 61 * SECOND), Wrong::LockedOut);
    }

    #[test]
    fn a_flood_of_distinct_clients_keeps_the_table_at_its_bound_and_forgets_the_least_recent() {
        let mut l = Lockout::new(100);
        let t = Instant::now();
        let locked = client(0);
        for _ in 0..MAX_FAILURES {
            l.wrong(locked, t);
        }
        for i in 0..10_000u32 {
            let c = Client::of(IpAddr::from((0x0a00_0000 + i).to_be_bytes()));
            l.wrong(c, t);
            if i % 50 == 0 {
                // The locked-out client keeps knocking: it stays remembered.
                assert!(l.admit(locked, t + SECOND).is_err());
            }
            assert!(l.remembered() <= 100);
            assert_eq!(l.by_use.len(), l.remembered());
        }
        assert_eq!(l.remembered(), 100);
        assert!(l.admit(locked, t + 2 * SECOND).is_err());
        let first = Client::of(IpAddr::from([10, 0, 0, 1]));
        assert!(!l.clients.contains_key(&first), "the least recent is gone");
    }

    #[test]
    fn an_ipv6_host_counts_as_its_64_and_a_mapped_ipv4_as_the_ipv4_address() {
        let a: IpAddr = "2001:db8:1:2::1".parse().unwrap();
        let b: IpAddr = "2001:db8:1:2:ffff::9".parse().unwrap();
        let other: IpAddr = "2001:db8:1:3::1".parse().unwrap();
        assert_eq!(Client::of(a), Client::of(b));
        assert_ne!(Client::of(a), Client::of(other));
        assert_eq!(Client::of(a).to_string(), "2001:db8:1:2::/64");
        let mapped: IpAddr = "::ffff:192.0.2.7".parse().unwrap();
        assert_eq!(Client::of(mapped), client(7));
        assert_eq!(client(7).to_string(), "192.0.2.7");
    }
}
