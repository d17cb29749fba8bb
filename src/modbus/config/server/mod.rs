//! `[outputs.NAME] kind = "modbus"`: a Modbus TCP server for PLCs, HMIs and SCADA that poll
//! (the register map is `modbus::server::map`). Not an MQTT connection: its table takes its
//! own keys only. What it listens on and who may connect move trust: `check` refuses a listener
//! off loopback without `allow`, and only a signed push may change them.

use std::net::{IpAddr, SocketAddr};

use crate::config::walk::{Errors, Table, join};

pub mod guard;
pub mod map;

/// The kind's name in `[outputs.NAME] kind = …`.
pub const KIND: &str = "modbus";

/// The default listener: loopback, the unprivileged port Modbus gateways commonly use.
pub const DEFAULT_LISTEN: &str = "127.0.0.1:1502";

/// The default and the largest `max_connections`.
pub const DEFAULT_CONNECTIONS: usize = 16;
pub const MAX_CONNECTIONS: usize = 256;

/// One Modbus server output, checked.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ModbusServer {
    pub name: String,
    pub listen: SocketAddr,
    /// Client addresses served; empty: any client that can reach `listen` (loopback only).
    pub allow: Vec<Cidr>,
    /// Beyond it the oldest idle connection is closed for a new one.
    pub max_connections: usize,
    /// Writes to the command registers are taken (clear, preset); otherwise every write is
    /// answered with an exception.
    pub commands: bool,
}

impl ModbusServer {
    /// Whether a client at `ip` is served.
    pub fn allows(&self, ip: IpAddr) -> bool {
        self.allow.is_empty() || self.allow.iter().any(|c| c.contains(ip))
    }
}

/// An address block: `10.20.0.0/16`, `::1/128`, or one address.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Cidr {
    pub addr: IpAddr,
    pub prefix: u8,
}

impl Cidr {
    pub fn contains(&self, ip: IpAddr) -> bool {
        let ip = match (self.addr, ip) {
            (IpAddr::V4(_), IpAddr::V6(v6)) => v6.to_ipv4_mapped().map_or(ip, IpAddr::V4),
            _ => ip,
        };
        match (self.addr, ip) {
            (IpAddr::V4(net), IpAddr::V4(ip)) => {
                masked(u32::from(net).into(), self.prefix, 32)
                    == masked(u32::from(ip).into(), self.prefix, 32)
            }
            (IpAddr::V6(net), IpAddr::V6(ip)) => {
                masked(u128::from(net), self.prefix, 128)
                    == masked(u128::from(ip), self.prefix, 128)
            }
            _ => false,
        }
    }
}

fn masked(bits: u128, prefix: u8, width: u8) -> u128 {
    if prefix == 0 {
        return 0;
    }
    let keep = u32::from(width - prefix.min(width));
    (bits >> keep) << keep
}

impl std::str::FromStr for Cidr {
    type Err = String;
    fn from_str(s: &str) -> Result<Cidr, String> {
        let (addr, prefix) = match s.split_once('/') {
            Some((a, p)) => (a, Some(p)),
            None => (s, None),
        };
        let addr: IpAddr = addr
            .parse()
            .map_err(|_| format!("{s:?} is not an address or a block (10.20.0.0/16)"))?;
        let width = if addr.is_ipv4() { 32 } else { 128 };
        let prefix = match prefix {
            None => width,
            Some(p) => p
                .parse::<u8>()
                .ok()
                .filter(|p| *p <= width)
                .ok_or_else(|| format!("{s:?}: the prefix must be 0..{width}"))?,
        };
        Ok(Cidr { addr, prefix })
    }
}

/// Reads one `[outputs.NAME]` table of kind `modbus` (its `kind` already read).
pub(crate) fn read(name: &str, mut t: Table<'_>, errs: &mut Errors) -> Option<ModbusServer> {
    let path = t.path.clone();
    let listen = match t.opt::<String>("listen", errs) {
        None => DEFAULT_LISTEN.parse().ok()?,
        Some(text) => match text.parse::<SocketAddr>() {
            Ok(a) => a,
            Err(_) => {
                let why = format!("{text:?} is not an address and port (127.0.0.1:1502)");
                errs.push(&join(&path, "listen"), t.origin(), why);
                return None;
            }
        },
    };
    let allow = allow(&mut t, errs);
    if !listen.ip().is_loopback() && allow.is_empty() {
        let why = format!(
            "listens on {listen}, off loopback: name the clients it serves with allow = [\"10.20.0.0/16\"] (a PLC network), or listen on 127.0.0.1"
        );
        errs.push(&join(&path, "allow"), t.origin(), why);
    }
    let max_connections = t
        .int::<usize>("max_connections", errs)
        .unwrap_or(DEFAULT_CONNECTIONS);
    if !(1..=MAX_CONNECTIONS).contains(&max_connections) {
        let why = format!("must be 1..{MAX_CONNECTIONS}");
        errs.push(&join(&path, "max_connections"), t.origin(), why);
    }
    let commands = t.opt::<bool>("commands", errs).unwrap_or(false);
    t.finish(errs);
    Some(ModbusServer {
        name: name.to_string(),
        listen,
        allow,
        max_connections,
        commands,
    })
}

fn allow(t: &mut Table<'_>, errs: &mut Errors) -> Vec<Cidr> {
    let Some(list) = t.opt::<Vec<String>>("allow", errs) else {
        return Vec::new();
    };
    let path = join(&t.path, "allow");
    let mut out = Vec::new();
    for (i, text) in list.iter().enumerate() {
        match text.parse::<Cidr>() {
            Ok(c) => out.push(c),
            Err(why) => errs.push(&format!("{path}[{i}]"), t.origin(), why),
        }
    }
    if list.is_empty() {
        errs.push(
            &path,
            t.origin(),
            "an empty list serves no one: name at least one client block",
        );
    }
    out
}

/// `server_unit = N` of a device: the unit id it answers as on a Modbus server output.
pub(crate) fn server_unit(t: &mut Table<'_>, path: &str, errs: &mut Errors) -> Option<u8> {
    let unit = t.int::<u16>("server_unit", errs)?;
    if (1..=247).contains(&unit) {
        Some(unit as u8)
    } else {
        let why = format!("unit {unit} is outside 1..247 (0 is broadcast, 248..255 reserved)");
        errs.push(&join(path, "server_unit"), t.origin(), why);
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_block_holds_its_addresses_and_no_others() {
        let c: Cidr = "10.20.0.0/16".parse().unwrap();
        assert!(c.contains("10.20.3.4".parse().unwrap()));
        assert!(!c.contains("10.21.0.1".parse().unwrap()));
        assert!(c.contains("::ffff:10.20.0.9".parse().unwrap()), "v4-mapped");
        let one: Cidr = "127.0.0.1".parse().unwrap();
        assert!(one.contains("127.0.0.1".parse().unwrap()));
        assert!(!one.contains("127.0.0.2".parse().unwrap()));
        let all: Cidr = "0.0.0.0/0".parse().unwrap();
        assert!(all.contains("192.0.2.1".parse().unwrap()));
        let v6: Cidr = "fd00::/8".parse().unwrap();
        assert!(v6.contains("fd12::1".parse().unwrap()));
        assert!(!v6.contains("10.0.0.1".parse().unwrap()));
        assert!("10.0.0.0/33".parse::<Cidr>().is_err());
        assert!("plc".parse::<Cidr>().is_err());
    }
}
