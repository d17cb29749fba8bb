//! The seed models' profiles, compiled into the binary.

/// The compiled-in profile files, by file name.
pub const BUILTIN: &[(&str, &str)] = &[
    ("yl67.toml", include_str!("../../profiles/yl67.toml")),
    ("wj157.toml", include_str!("../../profiles/wj157.toml")),
    (
        "zh-yx1600.toml",
        include_str!("../../profiles/zh-yx1600.toml"),
    ),
];
