//! The series of the Modbus server output (`[outputs.<name>] kind = "modbus"`): their names and
//! help texts, handed (through `crate::protocols`) to `metrics/families.rs`, which registers them with
//! the others.

const REQUESTS: (&str, &str) = (
    "pulsegate_modbus_server_requests_total",
    "Requests a Modbus server output answered, by function code and result (ok, or the exception's name).",
);
const CONNECTIONS: (&str, &str) = (
    "pulsegate_modbus_server_connections",
    "Client connections a Modbus server output holds open.",
);
const CLOSED: (&str, &str) = (
    "pulsegate_modbus_server_connections_closed_total",
    "Client connections a Modbus server output closed itself, by reason (not_allowed: at accept; evicted: oldest idle for a new one; idle: silent too long or a half frame; bad_frame: not Modbus TCP).",
);

/// The server output's families, in the order `Families::register` takes them: requests,
/// connections, connections closed.
pub const SERVER: [(&str, &str); 3] = [REQUESTS, CONNECTIONS, CLOSED];
