//! How a message is delivered, decided in one place from what it carries, for every output:
//! owed (stored, spooled, in order, never evicted by anything else) or chatter (memory only,
//! bounded, dropped first and counted), and whether it is kept at all while the broker is away.
//! Formats only say what a message carries ([`Content`]); the output stage applies this to
//! everything they make.

use crate::outbox::{Class, Content, Message};

/// Sets `message`'s class and transience: what a consumer counts on is owed whatever the
/// format, and what the gateway can make again is chatter.
pub fn classify(message: &mut Message) {
    let (class, transient) = match message.content {
        Content::Data => (Class::Owed, false),
        Content::Config | Content::Answer => (Class::Chatter, false),
        Content::Health => (Class::Chatter, true),
    };
    message.class = class;
    message.transient = transient;
}

/// [`classify`] over a list.
pub fn classified(mut messages: Vec<Message>) -> Vec<Message> {
    for m in &mut messages {
        classify(m);
    }
    messages
}

#[cfg(test)]
mod tests {
    use super::*;

    fn class_of(content: Content) -> (Class, bool) {
        let mut m = Message::new("t".into(), "x", 1, false).carrying(content);
        classify(&mut m);
        (m.class, m.transient)
    }

    #[test]
    fn readings_are_owed_and_what_the_gateway_can_make_again_is_chatter() {
        assert_eq!(class_of(Content::Data), (Class::Owed, false));
        assert_eq!(class_of(Content::Config), (Class::Chatter, false));
        assert_eq!(class_of(Content::Answer), (Class::Chatter, false));
        assert_eq!(class_of(Content::Health), (Class::Chatter, true));
    }

    #[test]
    fn a_format_cannot_make_its_own_message_owed_or_chatter() {
        let mut m = Message::chatter("t".into(), "x", 1, false);
        classify(&mut m);
        assert_eq!(
            m.class,
            Class::Owed,
            "data is owed whatever the format said"
        );
    }
}
