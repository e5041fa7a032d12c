//! How the report names files: relative to the report's own folder (`OUT`), so a committed
//! report, its logs and the commands it records hold no path of the machine it ran on.
//!
//! - A path under `OUT` is written relative to it: `runs/crater-easy-s201-vo.tum`,
//!   `datasets/crater-easy-s201-60m` (the commands reproduce a row when run from `OUT`).
//! - A path under the datasets folder given with `--datasets`, when that folder is outside
//!   `OUT`, is written `<datasets>/crater-easy-s201-60m`: a `../../..` chain to a scratch
//!   folder says less to a reader than the name of the option that set it.
//! - Any other path is left as it is (the benchmark passes no other path to its runs).
//!
//! The children still run with the real paths; only what the report, the logs and the
//! failure reasons show is rewritten. The resume journal (`OUT/runs/journal.jsonl`, not part
//! of the report) keys runs by the real command line.

use std::path::{Component, Path, PathBuf};

/// Placeholder for the `--datasets` folder when it is outside the report's folder.
pub const DATASETS: &str = "<datasets>";

/// `path` relative to `base`, lexically (no file needs to exist, symbolic links are not
/// followed): `runs/x.tum` under `base`, `.` for `base` itself, `../other/x` beside it.
/// Relative inputs are taken from the current directory. Separators are `/`.
pub fn relative_to(base: &Path, path: &Path) -> String {
    let base = absolute(base);
    let path = absolute(path);
    let b: Vec<Component> = base.components().collect();
    let p: Vec<Component> = path.components().collect();
    let common = b.iter().zip(&p).take_while(|(x, y)| x == y).count();
    let mut parts: Vec<String> = vec!["..".to_string(); b.len() - common];
    parts.extend(
        p[common..]
            .iter()
            .map(|c| c.as_os_str().to_string_lossy().into_owned()),
    );
    if parts.is_empty() {
        ".".to_string()
    } else {
        parts.join("/")
    }
}

/// `path` made absolute against the current directory, `.` and `..` resolved lexically.
pub fn absolute(path: &Path) -> PathBuf {
    let joined = if path.is_absolute() {
        path.to_path_buf()
    } else {
        std::env::current_dir()
            .unwrap_or_else(|_| PathBuf::from("/"))
            .join(path)
    };
    let mut out = PathBuf::new();
    for c in joined.components() {
        match c {
            Component::CurDir => {}
            Component::ParentDir => {
                out.pop();
            }
            other => out.push(other),
        }
    }
    out
}

/// The report's folder and the datasets folder, and how paths under them are shown.
#[derive(Debug, Clone)]
pub struct PathNames {
    report: PathBuf,
    /// The datasets folder when it is outside the report's folder.
    datasets: Option<PathBuf>,
    /// Text forms of the two folders to rewrite in free text (logs, error messages), with
    /// what replaces them; longest first.
    forms: Vec<(String, String)>,
}

impl PathNames {
    pub fn new(report: &Path, datasets: &Path) -> Self {
        let report_abs = absolute(report);
        let datasets_abs = absolute(datasets);
        let outside = !datasets_abs.starts_with(&report_abs);
        let mut forms = Vec::new();
        let mut add = |p: &Path, name: &str| {
            // Absolute forms only: a relative name such as `runs` may be a word of the text.
            let mut texts = vec![absolute(p).display().to_string()];
            if let Ok(c) = p.canonicalize() {
                texts.push(c.display().to_string());
            }
            for t in texts {
                let t = t.trim_end_matches('/').to_string();
                if !t.is_empty() && t != "." && !forms.iter().any(|(f, _)| *f == t) {
                    forms.push((t, name.to_string()));
                }
            }
        };
        if outside {
            add(datasets, DATASETS);
        }
        add(report, ".");
        forms.sort_by_key(|(f, _)| std::cmp::Reverse(f.len()));
        Self {
            report: report_abs,
            datasets: outside.then_some(datasets_abs),
            forms,
        }
    }

    /// How the report shows `path`.
    pub fn name(&self, path: &Path) -> String {
        let abs = absolute(path);
        if abs.starts_with(&self.report) {
            return relative_to(&self.report, &abs);
        }
        if let Some(d) = &self.datasets
            && abs.starts_with(d)
        {
            let rest = relative_to(d, &abs);
            return if rest == "." {
                DATASETS.to_string()
            } else {
                format!("{DATASETS}/{rest}")
            };
        }
        path.display().to_string()
    }

    /// A command-line argument as the report shows it: rewritten when it is a path (it has a
    /// separator) under one of the two folders, else unchanged.
    pub fn arg(&self, arg: &str) -> String {
        if !arg.contains('/') {
            return arg.to_string();
        }
        let abs = absolute(Path::new(arg));
        let under_datasets = self.datasets.as_ref().is_some_and(|d| abs.starts_with(d));
        if abs.starts_with(&self.report) || under_datasets {
            self.name(Path::new(arg))
        } else {
            arg.to_string()
        }
    }

    /// `text` with every mention of the two folders rewritten: `<report>/runs/x` → `runs/x`,
    /// `<datasets folder>/y` → `<datasets>/y`, the report folder alone → `.`. A mention counts
    /// where it starts a word (after a space, quote, bracket, `=` or `:`) and ends at a
    /// separator or the end of the path.
    pub fn scrub(&self, text: &str) -> String {
        let mut out = String::with_capacity(text.len());
        let mut i = 0;
        'outer: while i < text.len() {
            let at_word_start = i == 0
                || text[..i]
                    .chars()
                    .next_back()
                    .is_some_and(|c| c.is_whitespace() || "'\"`([{=:,".contains(c));
            if at_word_start {
                for (form, name) in &self.forms {
                    let Some(rest) = text[i..].strip_prefix(form.as_str()) else {
                        continue;
                    };
                    match rest.chars().next() {
                        Some('/') => {
                            // `<report>/x` → `x`; `<datasets>/x` stays `<datasets>/x`.
                            let after = rest[1..].chars().next();
                            let ends =
                                after.is_none_or(|c| c.is_whitespace() || "'\"`)]},;:".contains(c));
                            if name == "." && !ends {
                                i += form.len() + 1;
                            } else if name == "." {
                                out.push('.');
                                i += form.len() + 1;
                            } else {
                                out.push_str(name);
                                i += form.len();
                            }
                            continue 'outer;
                        }
                        None => {
                            out.push_str(name);
                            i += form.len();
                            continue 'outer;
                        }
                        Some(c) if c.is_whitespace() || "'\"`)]},;:".contains(c) => {
                            out.push_str(name);
                            i += form.len();
                            continue 'outer;
                        }
                        Some(_) => {}
                    }
                }
            }
            let c = text[i..].chars().next().expect("in bounds");
            out.push(c);
            i += c.len_utf8();
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn relative_to_under_beside_and_itself() {
        let base = Path::new("/scratch/bench/out");
        assert_eq!(
            relative_to(base, Path::new("/scratch/bench/out/runs/a.tum")),
            "runs/a.tum"
        );
        assert_eq!(relative_to(base, Path::new("/scratch/bench/out")), ".");
        assert_eq!(relative_to(base, Path::new("/scratch/bench/out/")), ".");
        assert_eq!(
            relative_to(base, Path::new("/scratch/data/crater")),
            "../../data/crater"
        );
        assert_eq!(
            relative_to(base, Path::new("/scratch/bench/out/runs/../logs/./1.log")),
            "logs/1.log"
        );
        // Relative inputs are taken from the same current directory.
        assert_eq!(
            relative_to(Path::new("bench"), Path::new("bench/runs/x")),
            "runs/x"
        );
        assert_eq!(
            relative_to(Path::new("bench"), Path::new("data/y")),
            "../data/y"
        );
    }

    #[test]
    fn names_args_and_free_text() {
        let n = PathNames::new(Path::new("/scratch/b/out"), Path::new("/scratch/ds"));
        assert_eq!(
            n.name(Path::new("/scratch/b/out/runs/x-vo.tum")),
            "runs/x-vo.tum"
        );
        assert_eq!(
            n.name(Path::new("/scratch/ds/crater-easy-s201-60m")),
            "<datasets>/crater-easy-s201-60m"
        );
        assert_eq!(n.arg("/scratch/ds/crater"), "<datasets>/crater");
        assert_eq!(n.arg("/scratch/b/out/runs/r"), "runs/r");
        for unchanged in [
            "--force",
            "xfeat-lighterglue",
            "fixed:0.2",
            "36.5,-41",
            "/etc/x",
        ] {
            assert_eq!(n.arg(unchanged), unchanged);
        }
        let log = "wrote /scratch/b/out/runs/r\nno pose in /scratch/b/out/runs/r/trajectory.tum: \
                   dataset '/scratch/ds/c' (see /scratch/b/out)\n/scratch/b/outer/x /scratch/dsx \
                   /scratch/b/out/";
        assert_eq!(
            n.scrub(log),
            "wrote runs/r\nno pose in runs/r/trajectory.tum: dataset '<datasets>/c' (see .)\n\
             /scratch/b/outer/x /scratch/dsx ."
        );
    }

    #[test]
    fn datasets_inside_the_report_folder_are_relative() {
        let n = PathNames::new(Path::new("/s/out"), Path::new("/s/out/datasets"));
        assert_eq!(n.arg("/s/out/datasets/c"), "datasets/c");
        assert_eq!(
            n.scrub("$ x --dataset /s/out/datasets/c"),
            "$ x --dataset datasets/c"
        );
    }

    #[test]
    fn relative_folders_are_resolved_from_the_current_directory() {
        let n = PathNames::new(Path::new("bench"), Path::new("data"));
        assert_eq!(n.arg("bench/runs/a"), "runs/a");
        assert_eq!(n.arg("data/c"), "<datasets>/c");
        let cwd = std::env::current_dir().unwrap();
        let text = format!("reading {}/bench/runs/a.tum, not runs/b", cwd.display());
        assert_eq!(n.scrub(&text), "reading runs/a.tum, not runs/b");
    }
}
