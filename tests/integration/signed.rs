//! Signed records end to end: the simulator, a real Mosquitto, the gateway with a key that
//! `openssl genpkey` wrote and its clock set by libfaketime just before a local midnight, so that
//! a daily billing record closes too. Every interval and billing record is checked with openssl
//! alone against the key the gateway's marker publishes, and `pulsegate verify` reads the
//! capture as `mosquitto_sub -v` prints it.

use std::path::Path;
use std::process::Command;
use std::time::Duration;

use base64::Engine as _;
use base64::engine::general_purpose::STANDARD;
use serde_json::Value;

use crate::billing::{Faked, record_from, setup};
use crate::support::Message;

fn openssl(args: &[&str]) -> std::process::Output {
    Command::new("openssl")
        .args(args)
        .output()
        .expect("openssl")
}

/// Whether openssl alone verifies `text` against `sig` (base64) with the public key in `pem`.
fn openssl_verifies(dir: &Path, pem: &Path, text: &[u8], sig: &str) -> bool {
    let (t, s) = (dir.join("text"), dir.join("sig"));
    std::fs::write(&t, text).unwrap();
    std::fs::write(&s, STANDARD.decode(sig).unwrap()).unwrap();
    let out = openssl(&[
        "pkeyutl",
        "-verify",
        "-rawin",
        "-pubin",
        "-inkey",
        pem.to_str().unwrap(),
        "-in",
        t.to_str().unwrap(),
        "-sigfile",
        s.to_str().unwrap(),
    ]);
    out.status.success()
}

/// The raw 32-byte public key of a PEM public key: the last 32 bytes of its DER.
fn raw_public(pem: &Path) -> Vec<u8> {
    let out = openssl(&[
        "pkey",
        "-pubin",
        "-in",
        pem.to_str().unwrap(),
        "-outform",
        "DER",
    ]);
    assert!(out.status.success());
    out.stdout[out.stdout.len() - 32..].to_vec()
}

fn verify(file: &Path) -> (bool, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_pulsegate"))
        .args(["verify", file.to_str().unwrap()])
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
    )
}

fn line(m: &Message) -> String {
    format!("{} {}", m.topic, m.payload)
}

/// Run from `burn_in` (it starts with the other long runs).
pub(crate) async fn every_record_verifies_with_openssl_against_the_published_key_and_verify_finds_tampering()
 {
    // Five-second records, the fake clock started 19 s before midnight: four records, the
    // billing record and one more in about 25 s of wall clock.
    let r = setup("signed", 25.0, "intervals = [\"5s\"]\n", "").await;
    let key = r.dir.join("signing.pem");
    let public = r.dir.join("public.pem");
    let k = key.to_str().unwrap();
    assert!(
        openssl(&["genpkey", "-algorithm", "ed25519", "-out", k])
            .status
            .success()
    );
    assert!(
        openssl(&[
            "pkey",
            "-in",
            k,
            "-pubout",
            "-out",
            public.to_str().unwrap()
        ])
        .status
        .success()
    );
    let billing = format!(
        "[tariffs]\ndefault = \"offpeak\"\n[[tariffs.rule]]\ntariff = \"peak\"\n\
         days = [\"fri\"]\nfrom = \"23:59\"\nto = \"00:00\"\n\
         [billing]\nperiod = \"daily\"\ndemand = \"5s\"\nsigning_key = \"{k}\"\n"
    );
    let text = std::fs::read_to_string(&r.config).unwrap() + &billing;
    std::fs::write(&r.config, text).unwrap();
    // Friday 4 December 2026, 23:59:41 CET; local midnight is 23:00Z.
    let fake = Faked::at(&r.dir, "2026-12-04T22:59:41Z");
    let gw = fake.start(&r.config);
    let base = "pulsegate/test/m1/a0";
    let bill_topic = format!("{base}/billing");
    r.sub
        .wait_for(&bill_topic, Duration::from_secs(60), |_| true)
        .await
        .expect("a billing record at midnight");
    let rec_topic = format!("{base}/interval/5s");
    record_from(&r.sub, &rec_topic, "2026-12-04T23:00:00Z", 20).await;
    drop(gw);

    let marker = r.sub.on("pulsegate/test/gateway");
    let marker = marker.last().expect("the boot marker").json();
    let published = STANDARD
        .decode(marker["signing_key"].as_str().unwrap())
        .unwrap();
    assert_eq!(
        published,
        raw_public(&public),
        "the marker says the key's public half"
    );

    let mut records = r.sub.on(&rec_topic);
    assert!(records.len() >= 4, "{records:?}");
    records.extend(r.sub.on(&bill_topic));
    for m in &records {
        let json: Value = m.json();
        let text = STANDARD.decode(json["signed"].as_str().unwrap()).unwrap();
        let sig = json["sig"].as_str().unwrap();
        let shown = String::from_utf8_lossy(&text).into_owned();
        assert!(
            openssl_verifies(&r.dir, &public, &text, sig),
            "{}: {shown}",
            m.topic
        );
        for k in [
            "gateway",
            "device",
            "channel",
            "period",
            "start",
            "end",
            "seq",
            "total_start",
        ] {
            assert!(shown.contains(&format!("\n{k}=")), "{k} in {shown}");
        }
        assert!(
            shown.contains(&format!("\ndelta={}\n", json["delta"])),
            "{shown}"
        );
        let mut changed = text.clone();
        let at = changed.len() / 2;
        changed[at] ^= 1;
        assert!(
            !openssl_verifies(&r.dir, &public, &changed, sig),
            "a changed byte"
        );
    }

    // The capture as `mosquitto_sub -v` prints it: all valid.
    let mut lines = vec![format!("pulsegate/test/gateway {marker}")];
    lines.extend(r.sub.on(&rec_topic).iter().map(line));
    lines.extend(r.sub.on(&bill_topic).iter().map(line));
    let whole = r.dir.join("capture.txt");
    std::fs::write(&whole, lines.join("\n")).unwrap();
    let (ok, out) = verify(&whole);
    assert!(ok, "{out}");
    assert!(
        !out.contains("tampered") && !out.contains("missing"),
        "{out}"
    );

    // The second record's delta changed, and the third left out.
    let changed = lines[2].replacen("\"delta\":", "\"delta\":1", 1);
    let mut bad = vec![lines[0].clone(), lines[1].clone(), changed];
    bad.extend(lines[4..].iter().cloned());
    let file = r.dir.join("bad.txt");
    std::fs::write(&file, bad.join("\n")).unwrap();
    let (ok, out) = verify(&file);
    assert!(!ok, "{out}");
    assert!(out.contains("tampered  m1/a0 interval 5s"), "{out}");
    assert!(out.contains("missing   m1/a0 interval 5s"), "{out}");
    let _ = &r.broker;
}
