//! The seed models' profiles, compiled into the binary.

use super::Profile;

const BUILTIN: &[(&str, &str)] = &[
    ("yl67.toml", include_str!("../../profiles/yl67.toml")),
    ("wj157.toml", include_str!("../../profiles/wj157.toml")),
    (
        "zh-yx1600.toml",
        include_str!("../../profiles/zh-yx1600.toml"),
    ),
];

/// The built-in profiles; they are checked by the test suite, so a failure here is a build bug.
pub fn builtin_profiles() -> Vec<Profile> {
    BUILTIN
        .iter()
        .map(|(name, text)| {
            Profile::from_toml(text, &format!("(built-in) {name}"))
                .unwrap_or_else(|e| panic!("built-in profile is broken: {e}"))
        })
        .collect()
}
