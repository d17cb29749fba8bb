//! Our M-Bus frames and decodings against another implementation: pymeterbus (PyPI, BSD-3),
//! driven by tests/mbus_pymeterbus.py (scripts/test installs it). The frames we build
//! (SND_NKE, REQ_UD2 with and without the FCB, select with wildcards) must be its bytes, and
//! a few corpus answers must decode to the same numbers in the same units.

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;

use pulsegate::mbus::driver::address::SecondaryMask;
use pulsegate::mbus::driver::frame::{self, req_ud2, select, snd_nke};
use pulsegate::mbus::driver::telegram::decode_frame;
use serde_json::Value;

use super::mbus_frames::{disagreement, hex, normalized};

fn pymeterbus(args: &[&str]) -> Value {
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/mbus_pymeterbus.py");
    let out = Command::new("python3")
        .arg(script)
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("python3 runs tests/mbus_pymeterbus.py (scripts/test installs pymeterbus)");
    assert!(
        out.status.success(),
        "pymeterbus: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("JSON from tests/mbus_pymeterbus.py")
}

/// A select mask in libmbus's and pymeterbus's text: 8 id digits (F for any), the
/// manufacturer's two bytes in wire order, version, medium (FF/FFFF for any).
fn mask(text: &str) -> SecondaryMask {
    let byte = |at: usize| u8::from_str_radix(&text[at..at + 2], 16).unwrap();
    let manufacturer = u16::from_le_bytes([byte(8), byte(10)]);
    SecondaryMask {
        manufacturer: (manufacturer != 0xFFFF).then_some(manufacturer),
        version: (byte(12) != 0xFF).then_some(byte(12)),
        medium: (byte(14) != 0xFF).then_some(byte(14)),
        ..SecondaryMask::from_id(&text[..8]).unwrap()
    }
}

fn hex_text(bytes: &[u8]) -> String {
    bytes
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect::<Vec<_>>()
        .join(" ")
}

#[test]
fn mbus_the_frames_we_build_are_the_bytes_pymeterbus_builds() {
    let theirs = pymeterbus(&["frames"]);
    let theirs = theirs.as_object().unwrap();
    assert!(theirs.len() >= 20, "{theirs:?}");
    for (what, bytes) in theirs {
        let ours = match what.split(' ').collect::<Vec<_>>()[..] {
            ["snd_nke", a] => snd_nke(a.parse().unwrap()),
            ["req_ud2", a] => req_ud2(a.parse().unwrap(), false),
            ["req_ud2", "fcb", a] => req_ud2(a.parse().unwrap(), true),
            ["select", m] => select(&mask(m)),
            _ => panic!("unknown frame {what}"),
        };
        assert_eq!(hex_text(&ours), bytes.as_str().unwrap(), "{what}");
    }
}

/// Frames whose records we compare with pymeterbus's, record by record.
const FRAMES: &[&str] = &[
    "kamstrup_382_005",
    "svm_f22_telegram1",
    "itron_cf_55",
    "abb_delta",
    "EDC",
    "ELV-Elvaco-CMa10",
    "landis+gyr_ultraheat_t230",
];

/// pymeterbus's unit as libmbus and [`normalized`] write it.
fn their_unit(unit: &str) -> Option<&'static str> {
    Some(match unit {
        "MeasureUnit.WH" => "Wh",
        "MeasureUnit.M3" => "m^3",
        "MeasureUnit.M3_H" => "m^3/h",
        "MeasureUnit.W" => "W",
        "MeasureUnit.C" => "°C",
        "MeasureUnit.K" => "K",
        "MeasureUnit.V" => "V",
        "MeasureUnit.A" => "A",
        "MeasureUnit.SECONDS" => "s",
        _ => return None,
    })
}

#[test]
fn mbus_a_few_answers_decode_to_pymeterbus_numbers_in_the_same_units() {
    let dir = Path::new("tests/data/mbus-frames/valid");
    let paths: Vec<String> = FRAMES
        .iter()
        .map(|f| dir.join(format!("{f}.hex")).display().to_string())
        .collect();
    let args: Vec<&str> = std::iter::once("decode")
        .chain(paths.iter().map(String::as_str))
        .collect();
    let theirs = pymeterbus(&args);
    let mut compared = BTreeMap::new();
    for (name, path) in FRAMES.iter().zip(&paths) {
        let text = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join(path));
        let frame = frame::parse(&hex(&text.unwrap())).unwrap();
        let ours = decode_frame(&frame).unwrap();
        let records = theirs[path.as_str()]["records"].as_array().unwrap();
        assert_eq!(ours.records.len(), records.len(), "{name}");
        for (r, t) in ours.records.iter().zip(records) {
            let Some(unit) = their_unit(t["unit"].as_str().unwrap_or_default()) else {
                continue;
            };
            if disagreement(name, r.index).is_some() {
                continue;
            }
            let value: f64 = match &t["value"] {
                Value::Number(n) => n.as_f64().unwrap(),
                Value::String(s) => s.parse().unwrap(),
                other => panic!("{name} record {}: {other}", r.index),
            };
            let (our_unit, our_value) = normalized(r.unit(), r.value.to_f64().unwrap());
            assert_eq!(our_unit, unit, "{name} record {}", r.index);
            assert!(
                (our_value - value).abs() <= 1e-6 * value.abs().max(1.0),
                "{name} record {}: ours {our_value}, pymeterbus {value}",
                r.index
            );
            *compared.entry(*name).or_insert(0) += 1;
        }
    }
    assert_eq!(compared.len(), FRAMES.len(), "{compared:?}");
}

#[test]
fn mbus_pymeterbus_fails_on_the_fixed_data_frame_that_we_decode() {
    let path = "tests/data/mbus-frames/valid/sen_pollusonic_2.hex";
    let theirs = pymeterbus(&["decode", path]);
    let error = theirs[path]["error"].as_str().unwrap_or_default();
    assert!(error.contains("Not a variable data long frame"), "{theirs}");
    let text = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join(path));
    let ours = decode_frame(&frame::parse(&hex(&text.unwrap())).unwrap()).unwrap();
    assert_eq!(ours.ci, 0x73);
    let values: Vec<String> = ours
        .records
        .iter()
        .map(|r| {
            format!(
                "{} {}",
                r.value.to_decimal_string().unwrap(),
                r.unit().unwrap()
            )
        })
        .collect();
    assert_eq!(values, ["6531000 Wh", "0.069 m³"]);
}
