//! `config.toml`: the settings a run used, defaults, `--config` file and flags merged, so that
//! `jointloc run --config <out>/config.toml` repeats the run and two runs' settings diff line
//! by line.

use std::path::Path;

use serde::Serialize;

use super::write_text;
use crate::error::{FormatError, Result};

/// Writes `settings` as TOML after a `# `-comment `header` (one comment line per line).
pub fn write_settings_toml<T: Serialize>(path: &Path, header: &str, settings: &T) -> Result<()> {
    let body = settings_toml(settings).map_err(|message| FormatError::Invalid {
        path: path.to_path_buf(),
        message,
    })?;
    let comments: String = header.lines().map(|l| format!("# {l}\n")).collect();
    write_text(path, &format!("{comments}\n{body}"))
}

/// `settings` as TOML text (tables after the plain values, as TOML wants them).
pub fn settings_toml<T: Serialize>(settings: &T) -> std::result::Result<String, String> {
    toml::to_string(settings).map_err(|e| format!("settings not representable in TOML: {e}"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde::Deserialize;

    #[derive(Debug, PartialEq, Serialize, Deserialize)]
    struct Inner {
        gain: f64,
        window_s: f64,
    }

    #[derive(Debug, PartialEq, Serialize, Deserialize)]
    struct Settings {
        matcher: String,
        start: Option<[f64; 2]>,
        inner: Inner,
        every: usize,
    }

    #[test]
    fn settings_read_back_as_written_header_and_all() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("config.toml");
        let s = Settings {
            matcher: "xfeat-lighterglue".into(),
            start: None,
            inner: Inner {
                gain: 0.163,
                window_s: 10.0,
            },
            every: 5,
        };
        write_settings_toml(&path, "line one\nline two", &s).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(text.starts_with("# line one\n# line two\n\n"), "{text}");
        assert!(!text.contains("start"), "None is left out: {text}");
        let back: Settings = toml::from_str(&text).unwrap();
        assert_eq!(back, s);
    }

    #[test]
    fn an_unwritable_folder_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("missing").join("config.toml");
        let inner = Inner {
            gain: 0.1,
            window_s: 1.0,
        };
        let err = write_settings_toml(&path, "h", &inner).unwrap_err();
        assert!(err.to_string().contains("missing"), "{err}");
    }
}
