//! The plant's M-Bus segments: meters built from `sim.toml` (`[mbus.NAME]`), each segment
//! served on TCP (an M-Bus-to-Ethernet converter) or on a pseudo-terminal at its baud rate
//! 8E1 (a level converter).

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};
use std::time::Instant;

use tokio_util::sync::CancellationToken;

use super::config::{SimMeterConfig, SimSegmentConfig};
use super::meter::{Behaviour, Gauge, Quantity, Register, SimMeter, Width};
use super::segment::Segment;
use super::shell::{self, SharedSegment};
use crate::sim::endpoint::{Endpoint, relink};
use crate::sim::{Part, Plant, SimError};

/// A simulated M-Bus segment.
pub struct PlantSegment {
    pub name: String,
    pub endpoint: Endpoint,
    /// The serial segment's baud rate (`None` on TCP).
    pub baud: Option<u32>,
    pub segment: SharedSegment,
    /// Meter names, in the segment's order of meters.
    pub meters: Vec<String>,
    /// The pseudo-terminal's serial end, kept open.
    _keep: Option<serialport::TTYPort>,
}

impl PlantSegment {
    /// Runs `f` on the meter called `name`.
    pub fn with_meter<R>(&self, name: &str, f: impl FnOnce(&mut SimMeter) -> R) -> Option<R> {
        let i = self.meters.iter().position(|m| m == name)?;
        let mut seg = self.segment.lock().unwrap_or_else(|e| e.into_inner());
        seg.meters.get_mut(i).map(f)
    }

    /// The primary address the gateway reads `name` at, or `None` when another meter of the
    /// segment shares its address (then only its secondary address tells it apart).
    pub fn primary_of(&self, name: &str) -> Option<u8> {
        let seg = self.segment.lock().unwrap_or_else(|e| e.into_inner());
        let i = self.meters.iter().position(|m| m == name)?;
        let a = seg.meters[i].address;
        (seg.meters.iter().filter(|m| m.address == a).count() == 1).then_some(a)
    }

    /// The id of meter `name`.
    pub fn id_of(&self, name: &str) -> Option<u32> {
        self.with_meter(name, |m| m.id)
    }
}

/// A meter of `sim.toml`.
pub fn build_meter(name: &str, c: &SimMeterConfig) -> Result<SimMeter, String> {
    let letters = c.manufacturer.as_bytes();
    if letters.len() != 3 || !letters.iter().all(u8::is_ascii_uppercase) {
        return Err(format!(
            "meter {name}: manufacturer must be three letters A-Z"
        ));
    }
    if c.id > 99_999_999 {
        return Err(format!("meter {name}: an id has at most 8 digits"));
    }
    let mut m = SimMeter::new(c.id, &c.manufacturer, c.version, c.medium, c.address);
    for r in &c.registers {
        let quantity = match r.quantity.as_str() {
            "energy_wh" => Quantity::EnergyWh,
            "energy_kwh" => Quantity::EnergyKwh,
            "volume_litre" => Quantity::VolumeLitre,
            other => return Err(format!("meter {name}: unknown register quantity {other:?}")),
        };
        let width = match r.width.as_str() {
            "bcd8" => Width::Bcd8,
            "int32" => Width::Int32,
            other => return Err(format!("meter {name}: unknown register width {other:?}")),
        };
        m = m.with_register(Register::new(quantity, width, r.start, r.rate));
    }
    for (kind, v) in &c.gauges {
        let small = || i16::try_from(*v).map_err(|_| format!("meter {name}: {kind} {v} too large"));
        let gauge = match kind.as_str() {
            "power_w" => Gauge::PowerW(*v),
            "flow_litre_per_hour" => Gauge::FlowLitrePerHour(small()?),
            "flow_temperature_centi" => Gauge::FlowTemperatureCenti(small()?),
            "return_temperature_centi" => Gauge::ReturnTemperatureCenti(small()?),
            other => return Err(format!("meter {name}: unknown gauge {other:?}")),
        };
        m = m.with_gauge(gauge);
    }
    m.records_per_telegram = c.records_per_telegram;
    m.behaviour = match (c.silent, c.garbage) {
        (true, _) => Behaviour::Silent,
        (false, true) => Behaviour::Garbage,
        _ => Behaviour::Normal,
    };
    Ok(m)
}

/// Builds and serves one segment; `start` is the plant's time 0.
pub async fn serve(
    name: &str,
    c: &SimSegmentConfig,
    start: Instant,
    cancel: &CancellationToken,
) -> Result<PlantSegment, String> {
    let mut meters = Vec::new();
    let mut names = Vec::new();
    for (mname, mc) in &c.meters {
        meters.push(build_meter(mname, mc)?);
        names.push(mname.clone());
    }
    let segment: SharedSegment = Arc::new(Mutex::new(Segment::new(meters)));
    let (endpoint, baud, keep) = match (&c.listen, &c.link) {
        (Some(addr), None) => {
            let bound = shell::serve_tcp(*addr, segment.clone(), start, cancel.child_token())
                .await
                .map_err(|e| format!("cannot listen on {addr}: {e}"))?;
            (Endpoint::Tcp(bound), None, None)
        }
        (None, link) => {
            let baud = c.baud.unwrap_or(2400);
            let (path, keep) = shell::serve_pty(segment.clone(), baud, start, cancel.child_token())
                .map_err(|e| format!("cannot create a pseudo-terminal: {e}"))?;
            let path = match link {
                Some(link) => {
                    relink(&path, link)
                        .map_err(|e| format!("cannot link {}: {e}", link.display()))?;
                    link.clone()
                }
                None => path,
            };
            (Endpoint::Serial(path), Some(baud), Some(keep))
        }
        (Some(_), Some(_)) => {
            return Err("give either `link` (serial) or `listen` (TCP), not both".into());
        }
    };
    Ok(PlantSegment {
        name: name.to_string(),
        endpoint,
        baud,
        segment,
        meters: names,
        _keep: keep,
    })
}

/// sim.toml's M-Bus segments (`[mbus.NAME]`), the plant's config part.
pub type SegmentTables = BTreeMap<String, SimSegmentConfig>;

/// The plant's M-Bus segments, one of its parts.
pub struct Segments(pub Vec<PlantSegment>);

impl Part for Segments {
    fn endpoints(&self) -> Vec<String> {
        self.0
            .iter()
            .map(|seg| format!("M-Bus segment {}: {:?}", seg.name, seg.endpoint))
            .collect()
    }
}

/// Builds and serves sim.toml's M-Bus segments, on the plant's clock (`start`) until `cancel`.
pub async fn start(
    tables: &SegmentTables,
    start: Instant,
    cancel: &CancellationToken,
) -> Result<Segments, SimError> {
    let mut segments = Vec::new();
    for (name, c) in tables {
        let segment = serve(name, c, start, cancel)
            .await
            .map_err(|message| SimError::Bus {
                bus: name.clone(),
                message,
            })?;
        segments.push(segment);
    }
    Ok(Segments(segments))
}

impl Plant {
    /// An M-Bus segment by name.
    pub fn segment(&self, name: &str) -> Option<&PlantSegment> {
        self.segments().iter().find(|s| s.name == name)
    }

    /// Every M-Bus segment.
    pub fn segments(&self) -> &[PlantSegment] {
        self.part::<Segments>().map_or(&[], |s| &s.0)
    }
}
