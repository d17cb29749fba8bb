//! The protocol of a bus that names none, and the serving outputs' register map and its
//! guard, as the config check and the remote side see them (each protocol's checks of
//! `[buses.NAME]` and its words are its own [`BusProtocol`](super::bus::BusProtocol), in its
//! folder).

use super::bus::Protocol;

impl Protocol {
    /// The protocol of a bus that names none.
    pub const DEFAULT: Protocol = crate::modbus::config::protocol::PROTOCOL;
}

/// A server output's register map: a contract, so unit ids and blocks that collide are errors.
pub(crate) use crate::modbus::config::server::map::RegisterMap;

/// What of the server outputs an unsigned pushed config may not change, in words.
pub use crate::modbus::config::server::guard::changes as server_changes;
