//! The connections a pool serves, oldest first, each with the token that closes it. A pool is
//! never refused: when every slot is taken, the oldest connection is closed for the new one, so
//! a client that holds connections open on purpose cannot keep a probe of `/healthz` (or a
//! technician's page) out.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex, MutexGuard};

use tokio_util::sync::CancellationToken;

/// A pool shared by the connections' tasks.
pub type Pool = Arc<Mutex<Slots>>;

/// What `m` guards, whatever a task that panicked while holding it left behind (a pool's
/// entries and a lease are only ever whole).
pub fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// A connection's slot in a pool, given back when dropped (with the answer or the connection
/// that holds it).
pub struct Lease {
    pool: Pool,
    id: u64,
}

impl Lease {
    /// Takes a slot of `pool` for the connection `token` closes.
    pub fn take(pool: &Pool, token: CancellationToken) -> Lease {
        let id = lock(pool).admit(token);
        Lease {
            pool: pool.clone(),
            id,
        }
    }
}

impl Drop for Lease {
    fn drop(&mut self) {
        lock(&self.pool).done(self.id);
    }
}

/// One pool: at most `capacity` connections.
pub struct Slots {
    capacity: usize,
    next: u64,
    open: BTreeMap<u64, CancellationToken>,
}

impl Slots {
    /// An empty pool of `capacity` (at least 1) slots.
    pub fn new(capacity: usize) -> Slots {
        Slots {
            capacity: capacity.max(1),
            next: 0,
            open: BTreeMap::new(),
        }
    }

    /// A connection closed by `token` takes a slot: its id. When every slot is taken, the
    /// oldest connection's token is cancelled (it closes) and its slot is the new one's.
    pub fn admit(&mut self, token: CancellationToken) -> u64 {
        while self.open.len() >= self.capacity {
            if let Some((_, oldest)) = self.open.pop_first() {
                oldest.cancel();
            }
        }
        let id = self.next;
        self.next += 1;
        self.open.insert(id, token);
        id
    }

    /// A connection left the pool (answered, timed out, closed, or moved to another pool).
    pub fn done(&mut self, id: u64) {
        self.open.remove(&id);
    }

    /// Connections in the pool now.
    #[cfg(test)]
    pub fn occupied(&self) -> usize {
        self.open.len()
    }

    /// Closes every connection of the pool (the endpoint is shutting down).
    pub fn close_all(&mut self) {
        for (_, token) in std::mem::take(&mut self.open) {
            token.cancel();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_connection_beyond_the_slots_closes_the_oldest_and_only_it() {
        let mut slots = Slots::new(8);
        let first: Vec<(u64, CancellationToken)> = (0..8)
            .map(|_| {
                let t = CancellationToken::new();
                (slots.admit(t.clone()), t)
            })
            .collect();
        assert!(first.iter().all(|(_, t)| !t.is_cancelled()));
        let newest = CancellationToken::new();
        slots.admit(newest.clone());
        assert!(first[0].1.is_cancelled(), "the oldest is closed");
        assert!(first[1..].iter().all(|(_, t)| !t.is_cancelled()));
        assert!(!newest.is_cancelled());
        slots.done(first[0].0);
        slots.done(first[1].0);
        let another = CancellationToken::new();
        slots.admit(another.clone());
        assert!(
            !first[2].1.is_cancelled() && !another.is_cancelled(),
            "a slot freed by a finished connection is taken without closing anyone"
        );
        assert_eq!(slots.open.len(), 8);
    }

    #[test]
    fn a_lease_gives_its_slot_back_when_dropped() {
        let pool: Pool = Arc::new(Mutex::new(Slots::new(1)));
        let first = CancellationToken::new();
        let lease = Lease::take(&pool, first.clone());
        assert_eq!(lock(&pool).open.len(), 1);
        drop(lease);
        assert_eq!(lock(&pool).open.len(), 0);
        let _second = Lease::take(&pool, CancellationToken::new());
        assert!(!first.is_cancelled(), "a freed slot closes no one");
    }

    #[test]
    fn closing_all_cancels_every_connection_and_empties_the_pool() {
        let mut slots = Slots::new(2);
        let (a, b) = (CancellationToken::new(), CancellationToken::new());
        slots.admit(a.clone());
        slots.admit(b.clone());
        slots.close_all();
        assert!(a.is_cancelled() && b.is_cancelled());
        assert_eq!(slots.open.len(), 0);
    }
}
