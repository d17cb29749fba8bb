//! Broken configs as golden cases.
