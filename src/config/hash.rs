//! The hash of the config in force: the same config gives the same hash at every start, any
//! change that matters gives another (a bus, a device, a channel setting, a profile file, an
//! output, a password: secrets are hashed, never shown). For the fleet view: `<root>/gateway`,
//! the Prometheus info metric, the Sparkplug NBIRTH.

use super::model::Config;

impl Config {
    /// 16 hex digits of SHA-256 over the checked config as the gateway uses it (not the file:
    /// comments, key order and defaults written out change nothing).
    pub fn hash(&self) -> String {
        let mut ctx = ring::digest::Context::new(&ring::digest::SHA256);
        let mut canonical = self.clone();
        // Where it was read from is no part of what it says (nor where profiles are looked up
        // relative to it: the profiles in force are in the devices, with their fingerprints).
        canonical.source = std::path::PathBuf::new();
        canonical.gateway.profile_dir = std::path::PathBuf::new();
        ctx.update(format!("{canonical:?}").as_bytes());
        // `Debug` hides secrets: their bytes go in apart.
        for mqtt in std::iter::once(&self.mqtt).chain(self.outputs.list.iter().map(|o| &o.mqtt)) {
            if let Some(p) = &mqtt.password {
                ctx.update(&[0xff]);
                ctx.update(p.0.as_bytes());
            }
        }
        let digest = ctx.finish();
        digest.as_ref()[..8]
            .iter()
            .map(|b| format!("{b:02x}"))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use super::*;

    fn config(text: &str, file: &str) -> Config {
        let base = "[gateway]\nid = \"e1\"\n[buses.l]\nhost = \"127.0.0.1\"\nport = 502\n[buses.l.devices.d]\nunit = 1\nmodel = \"yl67\"\n";
        let env = Some(std::collections::HashMap::new());
        Config::from_toml(&format!("{base}{text}"), Path::new(file), env).unwrap()
    }

    #[test]
    fn the_same_config_has_the_same_hash_wherever_it_was_read_from() {
        let a = config("", "/etc/pulsegate/pulsegate.toml");
        let b = config("\n# a comment\n", "/tmp/other.toml");
        assert_eq!(a.hash(), b.hash());
        assert_eq!(a.hash().len(), 16);
    }

    #[test]
    fn any_change_that_matters_moves_the_hash() {
        let base = config("", "x.toml").hash();
        for change in [
            "[buses.l.devices.d.channels.a0]\nscale = 0.001\nunit = \"kWh\"\n",
            "[mqtt]\nhost = \"10.0.0.2\"\n",
            "[mqtt]\npassword = \"secret\"\n",
            "[outputs.scada]\nkind = \"sparkplug\"\n[sparkplug]\ngroup_id = \"g\"\n",
        ] {
            assert_ne!(config(change, "x.toml").hash(), base, "{change}");
        }
        assert_ne!(
            config("[mqtt]\npassword = \"one\"\n", "x.toml").hash(),
            config("[mqtt]\npassword = \"two\"\n", "x.toml").hash(),
            "a new password is a new config, though it is never shown"
        );
    }
}
