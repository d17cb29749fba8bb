//! OBIS names (IEC 62056-61) of a metered channel's registers: `A-B:C.D.E`, each group a
//! number 0..=255 (`1-0:1.8.0`: electricity, channel 0, active energy import, integral, total).
//! A tariff register is the channel's name with its tariff's number as the last group
//! (`1-0:1.8.1`), the demand is the maximum of the same quantity (`1-0:1.6.0`). Pure.

use std::fmt;
use std::str::FromStr;

/// An OBIS name `A-B:C.D.E`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Obis([u8; 5]);

/// The value group D of a maximum demand register.
const MAXIMUM: u8 = 6;

impl Obis {
    /// The register of the tariff numbered `tariff` (1, 2, … in the calendar's order).
    pub fn tariff(self, tariff: usize) -> Obis {
        let mut g = self.0;
        g[4] = u8::try_from(tariff).unwrap_or(u8::MAX);
        Obis(g)
    }

    /// The maximum demand of the same quantity, over all tariffs (`1-0:1.6.0`).
    pub fn demand(self) -> Obis {
        let mut g = self.0;
        g[3] = MAXIMUM;
        g[4] = 0;
        Obis(g)
    }
}

impl fmt::Display for Obis {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let [a, b, c, d, e] = self.0;
        write!(f, "{a}-{b}:{c}.{d}.{e}")
    }
}

impl FromStr for Obis {
    type Err = String;

    fn from_str(s: &str) -> Result<Obis, String> {
        let bad = || {
            format!("{s:?} is not an OBIS name: write A-B:C.D.E, each a number 0..255 (1-0:1.8.0)")
        };
        let (a, rest) = s.split_once('-').ok_or_else(bad)?;
        let (b, rest) = rest.split_once(':').ok_or_else(bad)?;
        let mut groups = vec![a, b];
        groups.extend(rest.split('.'));
        if groups.len() != 5 {
            return Err(bad());
        }
        let mut g = [0u8; 5];
        for (slot, text) in g.iter_mut().zip(groups) {
            let digits = !text.is_empty() && text.bytes().all(|c| c.is_ascii_digit());
            *slot = text.parse().ok().filter(|_| digits).ok_or_else(bad)?;
        }
        Ok(Obis(g))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_name_reads_and_prints_as_written() {
        let o: Obis = "1-0:1.8.0".parse().unwrap();
        assert_eq!(o.to_string(), "1-0:1.8.0");
        assert_eq!(
            "8-0:1.0.0".parse::<Obis>().unwrap().to_string(),
            "8-0:1.0.0"
        );
    }

    #[test]
    fn a_tariff_register_takes_the_tariffs_number_and_the_demand_is_d_6() {
        let o: Obis = "1-0:1.8.0".parse().unwrap();
        assert_eq!(o.tariff(1).to_string(), "1-0:1.8.1");
        assert_eq!(o.tariff(2).to_string(), "1-0:1.8.2");
        assert_eq!(o.demand().to_string(), "1-0:1.6.0");
        let export: Obis = "1-0:2.8.0".parse().unwrap();
        assert_eq!(export.demand().to_string(), "1-0:2.6.0");
    }

    #[test]
    fn what_is_not_five_groups_of_0_to_255_is_refused() {
        for bad in [
            "1.8.0",
            "1-0:1.8",
            "1-0:1.8.0.0",
            "1-0:1.8.256",
            "1-0:1.8.x",
            "1-0:1..0",
            "1-0:+1.8.0",
            "1:0-1.8.0",
        ] {
            let e = bad.parse::<Obis>().unwrap_err();
            assert!(e.contains("A-B:C.D.E"), "{bad}: {e}");
        }
    }
}
