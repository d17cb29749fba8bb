//! The send window: what the MQTT client holds, in the order it was handed over, with the
//! counts [`crate::outbox::Outbox::next`] asks for at every message kept as it changes, not
//! counted again. At a thousand devices the outbox hands out thousands of messages a second;
//! walking the whole window for each of them cost a tenth of the gateway's CPU.

use std::collections::VecDeque;

use super::message::Message;

/// A message handed to the client, waiting for its acknowledgement.
#[derive(Debug, Clone, PartialEq, Eq)]
struct Slot {
    held: Held,
    /// Packet id, once the client has sent it (0 for QoS 0).
    pkid: Option<u16>,
    acked: bool,
}

/// What a slot of the window holds.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Held {
    /// The store's message with this sequence number.
    Owed(u64),
    /// A chatter message, kept to be queued again if the connection goes before its
    /// acknowledgement.
    Chatter(Box<Message>),
}

impl Slot {
    fn owed(&self) -> bool {
        matches!(self.held, Held::Owed(_))
    }

    fn acked_chatter(&self) -> bool {
        self.acked && !self.owed()
    }
}

/// The client's messages: the store's oldest owed messages, in order, with chatter between.
#[derive(Debug, Default)]
pub struct Window {
    slots: VecDeque<Slot>,
    /// Owed slots among `slots`.
    owed: usize,
    /// Acknowledged chatter slots among `slots`, waiting to be forgotten.
    acked_chatter: usize,
}

impl Window {
    /// Messages the client holds.
    pub fn len(&self) -> usize {
        self.slots.len()
    }

    pub fn is_empty(&self) -> bool {
        self.slots.is_empty()
    }

    /// Owed messages the client holds.
    pub fn owed(&self) -> usize {
        self.owed
    }

    /// Chatter messages the client holds.
    pub fn chatter(&self) -> usize {
        self.slots.len() - self.owed
    }

    /// Something handed to the client and not acknowledged yet.
    pub fn waiting(&self) -> bool {
        self.slots.iter().any(|s| !s.acked)
    }

    /// Hands `held` to the client; `acked` for a message that needs no acknowledgement (an
    /// unsendable owed message, dropped).
    pub fn push(&mut self, held: Held, acked: bool) {
        let slot = Slot {
            held,
            pkid: acked.then_some(0),
            acked,
        };
        self.owed += usize::from(slot.owed());
        self.acked_chatter += usize::from(slot.acked_chatter());
        self.slots.push_back(slot);
    }

    /// The client could not take the last message handed to it: it comes back, if the client
    /// has not sent it.
    pub fn take_back_unsent(&mut self) -> Option<Held> {
        if self.slots.back().is_none_or(|s| s.pkid.is_some()) {
            return None;
        }
        let slot = self.slots.pop_back()?;
        self.owed -= usize::from(slot.owed());
        Some(slot.held)
    }

    /// The client sent the oldest message it had not sent yet, with `pkid`.
    pub fn sent(&mut self, pkid: u16) {
        if let Some(slot) = self.slots.iter_mut().find(|s| s.pkid.is_none()) {
            slot.pkid = Some(pkid);
            slot.acked = pkid == 0;
            self.acked_chatter += usize::from(slot.acked_chatter());
        }
    }

    /// The broker acknowledged `pkid`.
    pub fn acked(&mut self, pkid: u16) {
        if let Some(slot) = self
            .slots
            .iter_mut()
            .find(|s| s.pkid == Some(pkid) && !s.acked)
        {
            slot.acked = true;
            self.acked_chatter += usize::from(slot.acked_chatter());
        }
    }

    /// Forgets acknowledged chatter and the acknowledged owed messages that are next in order
    /// (an acknowledgement that overtook an older one waits for it; chatter in flight does not
    /// hold owed messages back). Returns how many owed messages left: the store's front.
    pub fn release(&mut self) -> usize {
        let mut released = 0;
        // The usual case, acknowledgements in order: a walk of the acknowledged front only.
        while self.slots.front().is_some_and(|s| s.owed() && s.acked) {
            self.slots.pop_front();
            released += 1;
        }
        if self.acked_chatter > 0 || self.first_owed_acked() {
            released += self.release_between_chatter();
        }
        self.owed -= released;
        released
    }

    /// The oldest owed message in the window is acknowledged (behind chatter in flight).
    fn first_owed_acked(&self) -> bool {
        self.slots
            .iter()
            .find(|s| s.owed())
            .is_some_and(|s| s.acked)
    }

    fn release_between_chatter(&mut self) -> usize {
        let mut released = 0;
        let mut in_order = true;
        self.slots.retain(|s| {
            if !s.owed() {
                return !s.acked;
            }
            in_order &= s.acked;
            released += usize::from(in_order);
            !in_order
        });
        self.acked_chatter = 0;
        released
    }

    /// The connection is gone and the client with it: the chatter it had not got acknowledged,
    /// to be queued again. The owed messages are still in the store.
    pub fn lost(&mut self) -> Vec<Message> {
        self.owed = 0;
        self.acked_chatter = 0;
        self.slots
            .drain(..)
            .filter_map(|s| match s.held {
                Held::Chatter(m) if !s.acked => Some(*m),
                _ => None,
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn owed(w: &mut Window, seq: u64) {
        w.push(Held::Owed(seq), false);
    }

    fn chatter(w: &mut Window) {
        w.push(
            Held::Chatter(Box::new(Message::chatter("t".into(), "x", 1, false))),
            false,
        );
    }

    /// The counts kept as the window changes are the ones a walk would find.
    fn assert_counts(w: &Window) {
        assert_eq!(w.owed, w.slots.iter().filter(|s| s.owed()).count());
        let acked = w.slots.iter().filter(|s| s.acked_chatter()).count();
        assert_eq!(w.acked_chatter, acked);
    }

    #[test]
    fn in_order_acknowledgements_release_the_front() {
        let mut w = Window::default();
        for seq in 0..3 {
            owed(&mut w, seq);
            w.sent(seq as u16 + 1);
        }
        w.acked(2);
        assert_eq!(w.release(), 0, "the first is not acknowledged yet");
        w.acked(1);
        assert_eq!(w.release(), 2);
        assert_eq!((w.len(), w.owed()), (1, 1));
        assert_counts(&w);
    }

    #[test]
    fn chatter_in_flight_holds_no_owed_message_back_and_leaves_when_acknowledged() {
        let mut w = Window::default();
        chatter(&mut w);
        owed(&mut w, 0);
        chatter(&mut w);
        owed(&mut w, 1);
        for pkid in 1..=4 {
            w.sent(pkid);
        }
        w.acked(2);
        assert_eq!(
            w.release(),
            1,
            "the owed message behind unacknowledged chatter"
        );
        assert_eq!((w.len(), w.owed(), w.chatter()), (3, 1, 2));
        w.acked(3);
        assert_eq!(w.release(), 0);
        assert_eq!(
            (w.len(), w.chatter()),
            (2, 1),
            "acknowledged chatter forgotten"
        );
        assert_counts(&w);
        w.acked(4);
        w.acked(1);
        assert_eq!(w.release(), 1);
        assert!(w.is_empty());
        assert_counts(&w);
    }

    #[test]
    fn a_refused_message_comes_back_and_a_lost_connection_returns_unacknowledged_chatter() {
        let mut w = Window::default();
        owed(&mut w, 0);
        chatter(&mut w);
        w.sent(1);
        assert!(matches!(w.take_back_unsent(), Some(Held::Chatter(_))));
        assert_eq!(w.take_back_unsent(), None, "the owed message was sent");
        owed(&mut w, 1);
        assert_eq!(w.take_back_unsent(), Some(Held::Owed(1)));
        assert_eq!(w.owed(), 1);
        chatter(&mut w);
        chatter(&mut w);
        w.sent(2);
        w.sent(0);
        assert_counts(&w);
        assert_eq!(
            w.lost().len(),
            1,
            "the QoS 0 chatter needed no acknowledgement"
        );
        assert_eq!((w.len(), w.owed(), w.acked_chatter), (0, 0, 0));
    }
}
