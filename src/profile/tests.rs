use super::*;

fn profile(model: &str) -> Arc<Profile> {
    Profiles::builtin().get(model).expect(model)
}

fn names(channels: &[ChannelSpec]) -> Vec<&str> {
    channels.iter().map(|c| c.name.as_str()).collect()
}

use std::sync::Arc;

#[test]
fn every_built_in_profile_loads() {
    let p = Profiles::builtin();
    for model in ["yl67", "ibf67", "wj157", "zh-yx1600"] {
        assert!(p.get(model).is_some(), "{model}");
    }
}

#[test]
fn ibf67_shares_the_yl67_profile() {
    assert_eq!(profile("ibf67").model, "yl67");
}

#[test]
fn yl67_encoders_in_quadrature_mode_are_enc0_to_enc3() {
    let ch = profile("yl67").channels(&[0, 0, 0, 0]).unwrap();
    assert_eq!(names(&ch), ["enc0", "enc1", "enc2", "enc3"]);
    assert!(
        ch.iter()
            .all(|c| c.kind == ChannelKind::Encoder && c.count.ty == ValueType::I32)
    );
}

#[test]
fn yl67_encoder_in_counter_mode_becomes_two_unsigned_inputs() {
    let ch = profile("yl67").channels(&[0, 1, 0, 1]).unwrap();
    assert_eq!(names(&ch), ["enc0", "a1", "b1", "enc2", "a3", "b3"]);
    let a1 = &ch[1];
    assert_eq!((a1.count.address, a1.count.ty), (36, ValueType::U32));
    assert_eq!(ch[2].count.address, 38);
}

#[test]
fn the_datasheet_read_of_encoder_0_is_at_offset_16() {
    // Request 01 03 00 10 00 02: two registers at 0x0010.
    let ch = profile("yl67").channels(&[0, 0, 0, 0]).unwrap();
    assert_eq!((ch[0].count.address, ch[0].count.len()), (0x10, 2));
}

#[test]
fn the_datasheet_clear_of_encoder_0_writes_10_to_register_67() {
    // 01 06 00 43 00 0A: write 10 to 0x0043.
    let ch = profile("yl67").channels(&[0, 0, 0, 0]).unwrap();
    assert_eq!((ch[0].clear.register, ch[0].clear.code), (0x43, 10));
    assert_eq!(ch[3].clear.code, 13);
    assert_eq!(
        ch[0].clear_all,
        Some(CodeWrite {
            register: 67,
            code: 18
        })
    );
}

#[test]
fn yl67_di_clear_codes_run_20_to_27() {
    let ch = profile("yl67").channels(&[1, 1, 1, 1]).unwrap();
    let codes: Vec<u16> = ch.iter().map(|c| c.clear.code).collect();
    assert_eq!(codes, [20, 21, 22, 23, 24, 25, 26, 27]);
    assert_eq!(
        ch[0].clear_all,
        Some(CodeWrite {
            register: 67,
            code: 36
        })
    );
}

#[test]
fn wj157_mode_decides_encoder_or_two_counters() {
    let p = profile("wj157");
    assert_eq!(names(&p.channels(&[0]).unwrap()), ["enc0"]);
    let di = p.channels(&[1]).unwrap();
    assert_eq!(names(&di), ["a0", "b0"]);
    assert_eq!(di[0].freq.unwrap().ty, ValueType::F32);
    assert_eq!(di[1].clear.code, 21);
}

#[test]
fn zh_yx1600_has_16_inputs_read_high_word_first() {
    let p = profile("zh-yx1600");
    let ch = p.channels(&[0; 8]).unwrap();
    assert_eq!(ch.len(), 16);
    assert_eq!(ch[0].name, "di1");
    assert_eq!(ch[15].name, "di16");
    assert_eq!(ch[15].count.address, 0x1160 + 2 * 15);
    assert_eq!(ch[15].freq.unwrap().address, 0x1180 + 2 * 15);
    assert_eq!(ch[15].clear.register, 0x1100 + 15);
    assert_eq!(p.word_order, WordOrder::HighFirst);
}

#[test]
fn zh_yx1600_quadrature_pair_keeps_the_odd_counter_only() {
    let p = profile("zh-yx1600");
    // Bit 1 of the mode word of counter 1 (and other bits that do not matter).
    let ch = p.channels(&[0x0102, 0, 0, 0, 0, 0, 0, 0x0002]).unwrap();
    let n = names(&ch);
    assert_eq!(&n[..3], ["di1", "di3", "di4"]);
    assert_eq!(n.last(), Some(&"di15"));
    assert_eq!(ch.len(), 14);
    assert_eq!(ch[0].kind, ChannelKind::Encoder);
}

#[test]
fn an_unknown_work_mode_is_an_error_naming_it() {
    let err = profile("yl67").channels(&[0, 7, 0, 0]).unwrap_err();
    assert_eq!(err.value, 7);
    assert!(err.to_string().contains("encoder 1: work mode 7"), "{err}");
}

#[test]
fn presets_must_fit_the_count_register() {
    let enc = &profile("yl67").channels(&[0, 1, 0, 0]).unwrap()[0];
    assert!(enc.accepts_preset(-5) && !enc.accepts_preset(1 << 31));
    let di = &profile("yl67").channels(&[0, 1, 0, 0]).unwrap()[1];
    assert!(di.accepts_preset(4_294_967_295) && !di.accepts_preset(-1));
}

#[test]
fn encoder_presets_follow_the_datasheets_range_of_plus_minus_2147483647() {
    // YL67 and WJ157 datasheets: encoder counts -2147483647..+2147483647.
    for (model, modes) in [("yl67", &[0u16, 0, 0, 0][..]), ("wj157", &[0][..])] {
        let enc = &profile(model).channels(modes).unwrap()[0];
        assert!(enc.accepts_preset(-2_147_483_647), "{model}");
        assert!(enc.accepts_preset(2_147_483_647), "{model}");
        assert!(!enc.accepts_preset(-2_147_483_648), "{model}");
    }
    // The ZH-YX1600 counter takes the whole i32 range (0x8000_0000..0x7FFF_FFFF).
    let zh = &profile("zh-yx1600").channels(&[0]).unwrap()[0];
    assert!(zh.accepts_preset(-2_147_483_648));
}

#[test]
fn a_broken_user_profile_is_an_error_naming_the_file() {
    let err = Profile::from_toml(
        "model = \"x\"\nword_order = \"sideways\"",
        "/etc/pulsegate/profiles/x.toml",
    )
    .unwrap_err();
    assert!(
        err.to_string().contains("/etc/pulsegate/profiles/x.toml"),
        "{err}"
    );
}

#[test]
fn user_profiles_are_loaded_from_a_directory() {
    let dir = std::env::temp_dir().join(format!("pulsegate-profiles-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let text = include_str!("../../profiles/wj157.toml")
        .replace("model = \"wj157\"", "model = \"my-counter\"");
    std::fs::write(dir.join("mine.toml"), text).unwrap();
    let p = Profiles::with_dir(&dir).unwrap();
    assert!(p.get("my-counter").is_some() && p.get("yl67").is_some());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn zh_yx1600_frequency_is_pulses_per_window_set_at_0x1140_in_units_of_10ms() {
    let p = profile("zh-yx1600");
    let chans = p.channels(&[0]).unwrap();
    let w1 = chans[0].freq_window.unwrap();
    let w2 = chans[1].freq_window.unwrap();
    assert_eq!((w1.register.address, w2.register.address), (0x1140, 0x1142));
    assert_eq!(w1.seconds(0), Some(1.0), "0 means one second");
    assert_eq!(
        w1.seconds(6000),
        Some(60.0),
        "the datasheet's one-minute example"
    );
    // A factory live lower limit (0x8000_0000) read from the overlapping address is no window.
    assert_eq!(w1.seconds(0x8000_0000), None);
    assert!(
        profile("yl67")
            .all_channels()
            .iter()
            .all(|c| c.freq_window.is_none())
    );
}

#[test]
fn zh_yx1600_power_on_state_is_the_pauto_bits_9_8_of_each_counters_mode_word() {
    let p = profile("zh-yx1600");
    let chans = p.channels(&[0]).unwrap();
    let (di1, di2) = (chans[0].power_on.unwrap(), chans[1].power_on.unwrap());
    assert_eq!((di1.address, di2.address), (0x0700, 0x0701));
    // Section 8.5: pAuto = 1 counts up, 2 counts down; the other bits are kept.
    assert_eq!(di1.apply(0x0000, false), 0x0100);
    assert_eq!(di1.apply(0x0002, true), 0x0202);
    assert_eq!(di1.apply(0x0302, false), 0x0102);
}

/// A user profile with absurd values is an error naming the cause, never a panic.
#[test]
fn a_profile_with_a_zero_rate_or_registers_beyond_u16_is_refused() {
    let base = include_str!("../../profiles/wj157.toml");
    let cases = [
        ("max_rate_hz = 50000", "max_rate_hz = 0", "max_rate_hz"),
        ("max_rate_hz = 50000", "max_rate_hz = -3", "max_rate_hz"),
        (
            "count = { address = 16, stride = 2, type = \"i32\" }",
            "count = { address = 65535, stride = 2, type = \"i32\" }",
            "beyond 65535",
        ),
        ("instances = 1", "instances = 40000", "beyond 65535"),
        ("instances = 1", "instances = 0", "no instances"),
        (
            "answer_timeout = \"100ms\"",
            "answer_timeout = \"500000000000years\"",
            "answer_timeout",
        ),
    ];
    for (from, to, expect) in cases {
        assert!(base.contains(from), "{from}");
        let text = base.replacen(from, to, 1);
        let result = std::panic::catch_unwind(|| Profile::from_toml(&text, "user.toml"));
        let err = result
            .unwrap_or_else(|_| panic!("{to}: panicked"))
            .expect_err(to)
            .to_string();
        assert!(err.contains(expect), "{to}: {err}");
    }
}
