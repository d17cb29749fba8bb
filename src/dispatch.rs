//! Routes command messages from MQTT to the bus of their device, after every check that needs no
//! module, and publishes each result. Retained command messages are ignored: a stale retained
//! clear must not fire at every start.
//!
//! The router is a plain value: [`Router::handle`] takes an [`Event`] (a message, a bus's answer,
//! a reloaded config) and the time, and returns what to do ([`Action`]s); it holds no channel
//! and no lock. `dispatch/run.rs` is its shell: it owns the channels, carries the actions out,
//! and brings each answer from a bus back as an event into the same loop.

mod router;
mod run;

pub use router::{
    Action, EXPIRY, Event, INCOMING_QUEUE, Incoming, Pending, Router, ScanRefusal, Target,
    targets_of,
};
pub use run::{Wiring, run};
