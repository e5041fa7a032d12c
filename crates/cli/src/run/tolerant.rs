//! The frame source of `jointloc run`: tolerant by default, so that a flight does not stop for
//! one bad sample (`docs/architecture.md` §"Bad input in flight"). The dataset is read with
//! [`Sequence::open_tolerant`] (bad lines skipped, bad readings dropped, gaps flagged), and a
//! frame that cannot be decoded or has another size than the camera's is skipped; each fault is
//! one warning naming the file and line or frame, and is counted by kind into `summary.json`'s
//! `input_faults`. `--strict` reads and loads as before, failing on the first fault.

use std::collections::BTreeMap;
use std::path::Path;

use image::GrayImage;
use jointloc_formats::{InputFault, InputFaultKind, Sequence};
use jointloc_system::Outputs;

/// The faults met so far, by kind.
#[derive(Debug)]
pub(super) struct FrameSource {
    strict: bool,
    counts: BTreeMap<InputFaultKind, usize>,
}

impl FrameSource {
    /// Opens the sequence of `dataset`, strictly or tolerantly.
    pub(super) fn open(dataset: &Path, strict: bool) -> anyhow::Result<(Sequence, Self)> {
        let mut source = Self {
            strict,
            counts: BTreeMap::new(),
        };
        if strict {
            return Ok((Sequence::open(dataset)?, source));
        }
        let (sequence, faults) = Sequence::open_tolerant(dataset)?;
        for InputFault { kind, message } in faults {
            source.record(kind, &message);
        }
        Ok((sequence, source))
    }

    fn record(&mut self, kind: InputFaultKind, message: &str) {
        tracing::warn!(kind = kind.name(), "bad input: {message}");
        *self.counts.entry(kind).or_default() += 1;
    }

    /// Frame `i` of `sequence`: strictly, decoded or the error; tolerantly, `None` (counted
    /// and warned) when it cannot be decoded or is not `width × height` pixels.
    pub(super) fn load(
        &mut self,
        sequence: &Sequence,
        i: usize,
        (width, height): (u32, u32),
    ) -> anyhow::Result<Option<GrayImage>> {
        if self.strict {
            return Ok(Some(sequence.load_image(i)?));
        }
        let image = match sequence.load_image(i) {
            Ok(image) => image,
            Err(e) => {
                let message = format!("frame {i}: {e}: skipped");
                self.record(InputFaultKind::FramesUnreadable, &message);
                return Ok(None);
            }
        };
        if image.dimensions() != (width, height) {
            let message = format!(
                "frame {i}: {}: image is {}x{} px but the camera is {width}x{height} px: skipped",
                sequence.frames[i].path.display(),
                image.width(),
                image.height()
            );
            self.record(InputFaultKind::FramesWrongSize, &message);
            return Ok(None);
        }
        Ok(Some(image))
    }

    /// Adds the frame source's counts to the library's (the altimeter gate's) in the summary,
    /// and prints them on one line when there are any.
    pub(super) fn report(&self, outputs: &mut Outputs) {
        let faults = &mut outputs.summary.input_faults;
        for (kind, n) in &self.counts {
            *faults.entry(kind.name().to_string()).or_default() += n;
        }
        if !faults.is_empty() {
            let list: Vec<String> = faults.iter().map(|(k, n)| format!("{k} {n}")).collect();
            println!(
                "bad input skipped or dropped (flight continued): {}",
                list.join(", ")
            );
        }
    }
}
