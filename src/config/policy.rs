//! Publish policy: which polled readings are published. Pure: readings and their times in,
//! decisions out.
//!
//! Polling fast keeps commands quick and counters safe from wrap; publishing every poll floods
//! the broker and Home Assistant's recorder when nothing moves. A [`Gate`] per channel skips
//! readings by the policy and carries what they booked into the next published one: its
//! `delta` covers everything since the last published reading, so a consumer summing deltas
//! never misses a pulse. Readings with an event (reset, clear, preset, gap, wrap) are always
//! published: they explain a jump.

use std::time::Duration;

use crate::counter::Update;

/// `publish = "poll" | "change"`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum PublishMode {
    /// Every poll (at most once per `min_interval` when set).
    #[default]
    Poll,
    /// When the channel moved (at most once per `min_interval`), and once per `heartbeat`
    /// when it did not.
    Change,
}

/// `payload = "channel" | "device"`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum PayloadMode {
    /// One message per channel on `<root>/<device>/<channel>`.
    #[default]
    Channel,
    /// One message per poll on `<root>/<device>`, keyed by channel name.
    Device,
}

/// Heartbeat of `publish = "change"` when none is configured.
pub const DEFAULT_HEARTBEAT: Duration = Duration::from_secs(300);

/// Policy keys as written at one level (gateway, device or channel); unset keys inherit.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct PolicyOverride {
    pub publish: Option<PublishMode>,
    pub heartbeat: Option<Duration>,
    pub min_interval: Option<Duration>,
}

impl PolicyOverride {
    /// `self` with the keys of `more` (a narrower level) on top.
    pub fn then(&self, more: &PolicyOverride) -> PolicyOverride {
        PolicyOverride {
            publish: more.publish.or(self.publish),
            heartbeat: more.heartbeat.or(self.heartbeat),
            min_interval: more.min_interval.or(self.min_interval),
        }
    }

    /// The policy these keys describe. A zero `min_interval` or `heartbeat` (written `"0s"`)
    /// means none: it overrides a wider level's value instead of inheriting it.
    pub fn policy(&self) -> Policy {
        let mode = self.publish.unwrap_or_default();
        let set = |d: Option<Duration>| d.filter(|d| !d.is_zero());
        Policy {
            mode,
            heartbeat: match mode {
                PublishMode::Poll => None,
                PublishMode::Change => match self.heartbeat {
                    None => Some(DEFAULT_HEARTBEAT),
                    zero_or_set => set(zero_or_set),
                },
            },
            min_interval: set(self.min_interval),
        }
    }
}

/// The resolved policy of one channel.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Policy {
    pub mode: PublishMode,
    pub heartbeat: Option<Duration>,
    pub min_interval: Option<Duration>,
}

/// What a channel's gate remembers between polls.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Gate {
    /// When the last reading was published (ms since the epoch); `None` before the first.
    last_at: Option<u64>,
    /// The module's count in the last published reading.
    last_count: Option<i64>,
    /// Deltas of readings skipped since the last published one.
    carried: i64,
}

impl Gate {
    /// Whether `policy` publishes a reading of `count` with `update`, read at `at_ms`.
    pub fn wants(&self, policy: &Policy, at_ms: u64, count: i64, update: &Update) -> bool {
        let Some(last) = self.last_at else {
            return true;
        };
        if update.event.is_some() {
            return true;
        }
        let since = Duration::from_millis(at_ms.saturating_sub(last));
        let paced = policy.min_interval.is_none_or(|m| since >= m);
        match policy.mode {
            PublishMode::Poll => paced,
            PublishMode::Change => {
                let moved = self.carried + update.delta != 0 || self.last_count != Some(count);
                if moved {
                    paced
                } else {
                    policy.heartbeat.is_some_and(|h| since >= h)
                }
            }
        }
    }

    /// The reading is published: returns its update with the carried deltas added.
    pub fn publish(&mut self, at_ms: u64, count: i64, update: &Update) -> Update {
        let mut out = *update;
        out.delta += std::mem::take(&mut self.carried);
        self.last_at = Some(at_ms);
        self.last_count = Some(count);
        out
    }

    /// The reading is skipped: its delta waits for the next published one.
    pub fn skip(&mut self, update: &Update) {
        self.carried += update.delta;
    }

    /// Deltas skipped and not yet published.
    pub fn carried(&self) -> i64 {
        self.carried
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::event::Event;

    fn update(delta: i64, total: i64) -> Update {
        Update {
            delta,
            total,
            seq: 0,
            rate_hz: None,
            event: None,
        }
    }

    fn change(heartbeat_ms: u64, min_ms: Option<u64>) -> Policy {
        PolicyOverride {
            publish: Some(PublishMode::Change),
            heartbeat: Some(Duration::from_millis(heartbeat_ms)),
            min_interval: min_ms.map(Duration::from_millis),
        }
        .policy()
    }

    /// Polls every `poll_ms` for `n` polls with the given delta per poll; returns the times
    /// published and the sum of published deltas.
    fn run(policy: &Policy, poll_ms: u64, n: u64, delta: impl Fn(u64) -> i64) -> (Vec<u64>, i64) {
        let mut gate = Gate::default();
        let (mut total, mut count, mut times, mut sum) = (0, 0, Vec::new(), 0);
        for i in 0..n {
            let at = i * poll_ms;
            let d = delta(i);
            total += d;
            count += d;
            let u = update(d, total);
            if gate.wants(policy, at, count, &u) {
                sum += gate.publish(at, count, &u).delta;
                times.push(at);
            } else {
                gate.skip(&u);
            }
        }
        (times, sum + gate.carried())
    }

    #[test]
    fn poll_mode_publishes_every_poll() {
        let (times, _) = run(&Policy::default(), 100, 10, |_| 0);
        assert_eq!(times.len(), 10);
    }

    #[test]
    fn a_still_channel_publishes_once_per_heartbeat() {
        let (times, _) = run(&change(1000, None), 100, 31, |_| 0);
        assert_eq!(times, vec![0, 1000, 2000, 3000]);
    }

    #[test]
    fn a_moving_channel_publishes_at_most_once_per_minimum_interval() {
        let (times, sum) = run(&change(10_000, Some(500)), 100, 30, |_| 7);
        assert_eq!(times, vec![0, 500, 1000, 1500, 2000, 2500]);
        assert_eq!(
            sum,
            7 * 30,
            "every pulse is in a published delta or still carried"
        );
    }

    #[test]
    fn a_channel_that_stops_publishes_what_it_carried_once_the_interval_passed() {
        let policy = change(10_000, Some(500));
        let mut gate = Gate::default();
        assert!(gate.wants(&policy, 0, 0, &update(0, 0)));
        gate.publish(0, 0, &update(0, 0));
        let u = update(5, 5);
        assert!(!gate.wants(&policy, 100, 5, &u));
        gate.skip(&u);
        let still = update(0, 5);
        assert!(!gate.wants(&policy, 400, 5, &still));
        gate.skip(&still);
        assert!(
            gate.wants(&policy, 600, 5, &still),
            "carried pulses count as movement"
        );
        assert_eq!(gate.publish(600, 5, &still).delta, 5);
        assert!(!gate.wants(&policy, 1200, 5, &still), "then it is still");
    }

    #[test]
    fn an_event_is_published_at_once_with_what_was_carried() {
        let policy = change(10_000, Some(5_000));
        let mut gate = Gate::default();
        gate.publish(0, 0, &update(0, 0));
        let u = update(3, 3);
        gate.skip(&u);
        let cleared = Update {
            event: Some(Event::Cleared),
            ..update(0, 3)
        };
        assert!(gate.wants(&policy, 100, 0, &cleared));
        assert_eq!(gate.publish(100, 0, &cleared).delta, 3);
    }

    #[test]
    fn an_encoder_moving_back_to_where_it_was_still_counts_as_moved() {
        let policy = change(10_000, None);
        let mut gate = Gate::default();
        gate.publish(0, 10, &update(0, 0));
        assert!(gate.wants(&policy, 100, 12, &update(2, 2)));
        gate.publish(100, 12, &update(2, 2));
        assert!(!gate.wants(&policy, 200, 12, &update(0, 2)));
    }

    #[test]
    fn narrower_levels_override_wider_ones_key_by_key() {
        let gateway = PolicyOverride {
            publish: Some(PublishMode::Change),
            heartbeat: Some(Duration::from_secs(60)),
            min_interval: None,
        };
        let channel = PolicyOverride {
            min_interval: Some(Duration::from_secs(5)),
            ..Default::default()
        };
        let p = gateway.then(&channel).policy();
        assert_eq!(p.mode, PublishMode::Change);
        assert_eq!(p.heartbeat, Some(Duration::from_secs(60)));
        assert_eq!(p.min_interval, Some(Duration::from_secs(5)));
        assert_eq!(PolicyOverride::default().policy(), Policy::default());
    }

    #[test]
    fn a_zero_min_interval_or_heartbeat_at_a_narrower_level_means_none() {
        let gateway = PolicyOverride {
            min_interval: Some(Duration::from_secs(1)),
            heartbeat: Some(Duration::from_secs(60)),
            ..Default::default()
        };
        let device = PolicyOverride {
            publish: Some(PublishMode::Poll),
            min_interval: Some(Duration::ZERO),
            ..Default::default()
        };
        let p = gateway.then(&device).policy();
        assert_eq!((p.mode, p.min_interval), (PublishMode::Poll, None));
        let mut gate = Gate::default();
        gate.publish(0, 10, &update(0, 0));
        assert!(gate.wants(&p, 100, 11, &update(1, 1)), "every poll");

        let channel = PolicyOverride {
            publish: Some(PublishMode::Change),
            heartbeat: Some(Duration::ZERO),
            ..Default::default()
        };
        let p = gateway.then(&channel).policy();
        assert_eq!(
            p.heartbeat, None,
            "no heartbeat: a still channel stays quiet"
        );
        assert!(!gate.wants(&p, 10_000_000, 10, &update(0, 0)));
        assert_eq!(
            gateway.policy().min_interval,
            Some(Duration::from_secs(1)),
            "inherited when not written"
        );
    }
}
