//! The M-Bus decoder against real meters: every frame of libmbus's test corpus
//! (tests/data/mbus-frames, BSD-3, its LICENSE beside it) decoded, and every numeric record
//! compared with libmbus's own decoding (`*.norm.xml`: value and unit; dates too). Where we differ,
//! the standard (EN 13757-3) decides, and [`DISAGREEMENTS`] names the record and says why.
//! Every frame of `errors/` gives a typed error, never a panic; random and mutated bytes never
//! panic either.

use std::path::{Path, PathBuf};

use pulsegate::mbus::driver::frame::{self, Frame, Scan};
use pulsegate::mbus::driver::quantity::Unit;
use pulsegate::mbus::driver::telegram::decode_frame;
use pulsegate::mbus::driver::value::Value;
use pulsegate::mbus::driver::{DecodeError, Telegram, channel};

fn corpus(dir: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/mbus-frames")
        .join(dir)
}

/// The `.hex` files of a corpus folder, by name.
fn hex_files(dir: &str) -> Vec<(String, Vec<u8>)> {
    let mut out: Vec<(String, Vec<u8>)> = std::fs::read_dir(corpus(dir))
        .expect("corpus folder")
        .map(|e| e.expect("entry").path())
        .filter(|p| p.extension().is_some_and(|x| x == "hex"))
        .map(|p| {
            let name = p.file_stem().unwrap().to_string_lossy().into_owned();
            let text = std::fs::read_to_string(&p).expect("hex file");
            (name, hex(&text))
        })
        .collect();
    out.sort();
    out
}

pub fn hex(text: &str) -> Vec<u8> {
    text.split_whitespace()
        .map(|h| u8::from_str_radix(h, 16).expect("hex byte"))
        .collect()
}

/// One `DataRecord` of libmbus's normalized XML.
#[derive(Debug)]
struct LibRecord {
    unit: String,
    value: String,
}

/// A careful hand reader of libmbus's XML (one `DataRecord` per record, in frame order): only
/// the tags the comparison reads.
fn libmbus_records(name: &str) -> Vec<LibRecord> {
    let bytes = std::fs::read(corpus("valid").join(format!("{name}.norm.xml"))).expect("xml");
    // Declared ISO-8859-1, but libmbus writes its "°" as UTF-8.
    let text = String::from_utf8(bytes.clone())
        .unwrap_or_else(|_| bytes.iter().map(|b| char::from(*b)).collect());
    let tag = |body: &str, tag: &str| -> String {
        let open = format!("<{tag}>");
        let close = format!("</{tag}>");
        body.find(&open)
            .and_then(|s| {
                let rest = &body[s + open.len()..];
                rest.find(&close).map(|e| rest[..e].to_string())
            })
            .unwrap_or_default()
            .replace("&amp;", "&")
    };
    text.split("<DataRecord id=")
        .skip(1)
        .map(|chunk| {
            let body = &chunk[..chunk.find("</DataRecord>").expect("closed record")];
            LibRecord {
                unit: tag(body, "Unit"),
                value: tag(body, "Value"),
            }
        })
        .collect()
}

fn decode(bytes: &[u8]) -> Result<Telegram, String> {
    let frame = frame::parse(bytes).map_err(|e| e.to_string())?;
    decode_frame(&frame).map_err(|e| e.to_string())
}

/// Our value in libmbus's normalized unit: (unit as libmbus writes it, value).
pub fn normalized(unit: Option<&Unit>, value: f64) -> (String, f64) {
    let (name, factor) = match unit {
        None => ("", 1.0),
        Some(Unit::Wh) => ("Wh", 1.0),
        Some(Unit::J) => ("J", 1.0),
        Some(Unit::M3) => ("m^3", 1.0),
        Some(Unit::Kg) => ("kg", 1.0),
        Some(Unit::W) => ("W", 1.0),
        Some(Unit::JPerH) => ("J/h", 1.0),
        Some(Unit::M3PerH) => ("m^3/h", 1.0),
        Some(Unit::M3PerMin) => ("m^3/min", 1.0),
        Some(Unit::M3PerS) => ("m^3/s", 1.0),
        Some(Unit::KgPerH) => ("kg/h", 1.0),
        Some(Unit::Celsius) => ("°C", 1.0),
        Some(Unit::Kelvin) => ("K", 1.0),
        Some(Unit::Bar) => ("bar", 1.0),
        Some(Unit::Second) => ("s", 1.0),
        Some(Unit::Minute) => ("s", 60.0),
        Some(Unit::Hour) => ("s", 3600.0),
        Some(Unit::Day) => ("s", 86400.0),
        Some(Unit::Volt) => ("V", 1.0),
        Some(Unit::Ampere) => ("A", 1.0),
        Some(Unit::Text(_)) => ("-", 1.0),
        Some(other) => return (other.symbol(), value),
    };
    (name.to_string(), value * factor)
}

/// libmbus's unit and value in the units [`normalized`] uses (its fixed-structure records
/// keep kWh and litres; its dimensionless units have several spellings).
fn theirs(r: &LibRecord) -> Option<(String, f64)> {
    let v: f64 = r.value.trim().parse().ok()?;
    Some(match r.unit.as_str() {
        "kWh" => ("Wh".into(), v * 1000.0),
        "l" => ("m^3".into(), v / 1000.0),
        "Units for H.C.A." | "Reserved" => (String::new(), v),
        u => (u.to_string(), v),
    })
}

/// A date or date/time as libmbus writes it (`2014-12-31`, `2011-09-01T08:30:00Z`); a type F
/// time the meter flags invalid (IV bit) libmbus writes as all zeros.
fn date_text(value: &Value) -> Option<String> {
    match value {
        Value::Date(d) => Some(d.to_string()),
        Value::DateTime(dt) if dt.invalid => Some("1900-01-00T00:00:00Z".into()),
        Value::DateTime(dt) => Some(format!("{dt}Z")),
        _ => None,
    }
}

/// Records where libmbus and we differ, and why the standard (EN 13757-3) is on our side:
/// (frame, record index, why).
const DISAGREEMENTS: &[(&str, usize, &str)] = &[
    (
        "SEN_Pollustat",
        12,
        "VIF BE 50: VIFE 0x50 (E101 ufnn) is the duration of the first lower limit exceed, in \
         seconds (nn = 00), of the volume flow; libmbus reads only the VIF and calls it a \
         volume flow in m^3/h (its own issue #82)",
    ),
    (
        "SEN_Pollustat",
        13,
        "VIF BE 58: VIFE 0x58 is the duration of the first upper limit exceed in seconds; \
         libmbus calls it a volume flow in m^3/h",
    ),
    (
        "EFE_Engelmann-WaterStar",
        11,
        "VIF 90 28: VIFE 0x28 is \"increment per input pulse on input channel 0\": the record \
         is a pulse weight (8e-6 m³ per pulse), not a volume of 8e-6 m³; libmbus drops the VIFE",
    ),
    (
        "engelmann_sensostar2c",
        13,
        "VIF 90 28: a pulse weight of 0.1 m³ per input pulse on channel 0, not a volume \
         (libmbus drops the VIFE)",
    ),
    (
        "landis+gyr_ultraheat_t230",
        19,
        "VIF AD 6F: VIFE 0x6F (E110 1f1b, f = 1, b = 1) makes the record the date/time of the \
         maximum power (a type F date/time, all zeros here), not a power of 0 W",
    ),
    (
        "landis+gyr_ultraheat_t230",
        21,
        "VIF DA 6F: the date/time of the maximum flow temperature; the 32 bits 32 14 7A 18 are \
         the type F date 2011-08-26 20:50, which libmbus prints as 41065374.6 °C",
    ),
    (
        "landis+gyr_ultraheat_t230",
        22,
        "VIF DE 6F: the date/time of the maximum return temperature (2011-08-09 11:43), which \
         libmbus prints as 40953732.3 °C",
    ),
    (
        "landis+gyr_ultraheat_t230",
        20,
        "VIF BB 6F: VIFE 0x6F (E110 1f1b, f = 1, b = 1) is the date/time of the end of the last \
         occurrence, so the 32-bit field is a type F date/time (all zeros here), not a volume \
         flow; libmbus ignores the VIFE and prints 0 m^3/h",
    ),
];

pub fn disagreement(name: &str, index: usize) -> Option<&'static str> {
    DISAGREEMENTS
        .iter()
        .find(|(n, i, _)| *n == name && *i == index)
        .map(|(_, _, why)| *why)
}

/// Compares one frame's records with libmbus's; returns the differences not explained.
fn compare(
    name: &str,
    t: &Telegram,
    lib: &[LibRecord],
    explained: &mut Vec<String>,
) -> Vec<String> {
    let mut bad = Vec::new();
    if t.records.len() != lib.len() {
        bad.push(format!(
            "{name}: {} records, libmbus {}",
            t.records.len(),
            lib.len()
        ));
    }
    for (r, l) in t.records.iter().zip(lib) {
        if let Some(date) = date_text(&r.value) {
            let what = format!(
                "{name} record {}: ours {date}, libmbus {}",
                r.index, l.value
            );
            let their_date = l.value.len() >= 10 && l.value.as_bytes()[4] == b'-';
            match (their_date, disagreement(name, r.index)) {
                (true, _) if date == l.value => {}
                (false, Some(why)) => explained.push(format!("{what}: {why}")),
                (false, None) if theirs(l).is_none() => {}
                _ => bad.push(what),
            }
            continue;
        }
        let Some((their_unit, their_value)) = theirs(l) else {
            continue;
        };
        let ours = r.value.to_f64().map(|v| normalized(r.unit(), v));
        // libmbus prints six decimals; a 32-bit real carries about seven significant digits.
        let relative = if matches!(r.value, Value::Real { .. }) {
            1e-6
        } else {
            1e-9
        };
        let same = ours.as_ref().is_some_and(|(u, v)| {
            *u == their_unit && (v - their_value).abs() <= 5e-7 + relative * their_value.abs()
        });
        let what = format!(
            "{name} record {}: ours {:?} ({:?}), libmbus {their_value} {their_unit:?}",
            r.index,
            ours,
            r.quantity()
        );
        match (same, disagreement(name, r.index)) {
            (true, None) => {}
            (true, Some(_)) => bad.push(format!("{what}: listed as a disagreement but agrees")),
            (false, Some(why)) => explained.push(format!("{what}: {why}")),
            (false, None) => bad.push(what),
        }
    }
    bad
}

#[test]
fn mbus_every_valid_frame_decodes_and_matches_libmbus_or_the_standard_says_why() {
    let frames = hex_files("valid");
    assert_eq!(frames.len(), 38, "the corpus has 38 meters' frames");
    let mut bad = Vec::new();
    let mut explained = Vec::new();
    for (name, bytes) in &frames {
        match decode(bytes) {
            Ok(t) => bad.extend(compare(name, &t, &libmbus_records(name), &mut explained)),
            Err(e) => bad.push(format!("{name}: {e}")),
        }
    }
    assert!(
        bad.is_empty(),
        "{} problems:\n{}",
        bad.len(),
        bad.join("\n")
    );
    assert_eq!(
        explained.len(),
        DISAGREEMENTS.len(),
        "every listed disagreement is seen:\n{}",
        explained.join("\n")
    );
}

#[test]
fn mbus_every_record_of_the_corpus_has_a_unique_valid_channel_name() {
    for (name, bytes) in hex_files("valid") {
        let t = decode(&bytes).unwrap();
        let names = channel::names(&t.records);
        let unique: std::collections::BTreeSet<_> = names.iter().collect();
        assert_eq!(unique.len(), names.len(), "{name}: {names:?}");
        for n in &names {
            assert!(
                !n.is_empty()
                    && n.bytes()
                        .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_'),
                "{name}: {n:?}"
            );
        }
    }
}

/// What each error frame gives, by the standard: (frame, the error's text). The plain-text
/// frames (FC with the length byte cut or too long) are read at the standard's place, after the
/// VIFEs (lengths 0x48 and 0x52); read right after FC, as Elvaco meters place it, their lengths
/// (0x13 and 0xF3) run past the answer too, so both readings fail and the standard's is told.
/// The CI 0x70 frames are application errors with the standard's codes, as libmbus reads them.
const ERRORS: &[(&str, &str)] = &[
    (
        "application_busy",
        "the meter reports an application error: application too busy to answer",
    ),
    (
        "error",
        "the meter reports an application error: unspecified error",
    ),
    (
        "premature_end_of_data2",
        "premature end of record at byte 22: its data is cut off",
    ),
    (
        "premature_end_of_dif2",
        "premature end of record at byte 22: its DIFE is cut off",
    ),
    (
        "premature_end_of_var_vif1",
        "record at byte 34: plain-text unit of 72 characters runs past the answer",
    ),
    (
        "too_long_var_vif",
        "record at byte 34: plain-text unit of 82 characters runs past the answer",
    ),
    (
        "too_many_difes",
        "the meter reports an application error: more than 10 DIFEs",
    ),
    (
        "too_many_records",
        "the meter reports an application error: too many records",
    ),
    (
        "too_many_vifes",
        "the meter reports an application error: more than 10 VIFEs",
    ),
    (
        "unimplemented_ci",
        "the meter reports an application error: unimplemented CI field",
    ),
];

#[test]
fn mbus_every_error_frame_gives_a_clear_typed_error_and_nothing_else() {
    let frames = hex_files("errors");
    assert_eq!(frames.len(), ERRORS.len());
    for (name, bytes) in frames {
        let want = ERRORS
            .iter()
            .find(|(n, _)| *n == name)
            .unwrap_or_else(|| panic!("{name} has no expected error"))
            .1;
        assert_eq!(decode(&bytes).unwrap_err(), want, "{name}");
    }
}

#[test]
fn mbus_an_application_error_is_a_typed_error_naming_the_code() {
    let bytes = hex("68 04 04 68 08 01 70 08 81 16");
    let frame = frame::parse(&bytes).unwrap();
    assert!(matches!(
        decode_frame(&frame),
        Err(DecodeError::Application(e)) if e.0 == Some(8)
    ));
}

/// A seeded xorshift: the same "random" bytes on every run.
struct XorShift(u64);

impl XorShift {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
}

/// Decodes `bytes` every way a driver would: scanning, parsing, and the records of a frame
/// with its checksum made right.
fn never_panics(bytes: &[u8]) {
    let _ = frame::scan(bytes);
    if let Ok(frame) = frame::parse(bytes) {
        let _ = decode_frame(&frame);
    }
    if bytes.len() > 1 {
        let _ = pulsegate::mbus::driver::decode(bytes[0], &bytes[1..]);
        if let Ok(t) = pulsegate::mbus::driver::decode(0x72, bytes) {
            let _ = channel::names(&t.records);
            for r in &t.records {
                let _ = (channel::kind(r), r.value.to_decimal_string());
            }
        }
    }
}

#[test]
fn mbus_random_and_mutated_bytes_never_panic() {
    let mut rng = XorShift(0x9E37_79B9_7F4A_7C15);
    let seeds: Vec<Vec<u8>> = hex_files("valid")
        .into_iter()
        .chain(hex_files("errors"))
        .map(|(_, b)| b)
        .collect();
    for round in 0..20_000 {
        let mut bytes = if round % 4 == 0 {
            let len = (rng.next() % 300) as usize;
            (0..len).map(|_| rng.next() as u8).collect()
        } else {
            seeds[(rng.next() as usize) % seeds.len()].clone()
        };
        for _ in 0..(rng.next() % 6) {
            if bytes.is_empty() {
                break;
            }
            let at = (rng.next() as usize) % bytes.len();
            match rng.next() % 3 {
                0 => bytes[at] = rng.next() as u8,
                1 => bytes.truncate(at),
                _ => bytes.insert(at, rng.next() as u8),
            }
        }
        // Mutated data inside a frame whose length and checksum are right again.
        if bytes.len() > 9 && bytes[0] == 0x68 {
            let data = bytes[7..bytes.len().min(259)].to_vec();
            let fixed = Frame::Long {
                control: 0x08,
                address: 1,
                ci: bytes[6],
                data,
            }
            .encode();
            never_panics(&fixed);
        }
        never_panics(&bytes);
    }
}

#[test]
fn mbus_a_reader_fed_byte_by_byte_finds_each_corpus_frame_whole() {
    for (name, bytes) in hex_files("valid") {
        let mut buf = Vec::new();
        let mut found = None;
        for b in &bytes {
            buf.push(*b);
            match frame::scan(&buf).unwrap() {
                Scan::Need(n) => assert!(n >= 1 && buf.len() + n <= bytes.len(), "{name}"),
                Scan::Frame { consumed, .. } => {
                    found = Some(consumed);
                    break;
                }
            }
        }
        assert_eq!(found, Some(bytes.len()), "{name}");
    }
}

#[test]
fn mbus_registers_of_the_corpus_are_energy_volume_mass_or_hca_of_storage_0() {
    let t = decode(
        &hex_files("valid")
            .into_iter()
            .find(|(n, _)| n == "svm_f22_telegram1")
            .unwrap()
            .1,
    )
    .unwrap();
    let kinds: Vec<_> = t.records.iter().map(channel::kind).collect();
    assert_eq!(
        kinds[0],
        channel::Kind::Register(channel::Rollover::Bits(32))
    );
    assert!(matches!(t.records[0].value, Value::Number(e) if e.exp == 3));
    assert!(t.more_records_follow, "svm_f22_telegram1 ends in DIF 1F");
    assert_eq!(kinds[3], channel::Kind::Value, "flow temperature");
}
