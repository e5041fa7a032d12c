//! A progress bar over the frames of a run (hidden when stderr is not a terminal).

use indicatif::{ProgressBar, ProgressStyle};
use jointloc_system::{FixRecord, FusedFrame, Observer};

pub(super) struct Progress {
    bar: ProgressBar,
    fixes: usize,
}

impl Progress {
    pub(super) fn new(frames: usize) -> Self {
        let bar = ProgressBar::new(frames as u64);
        bar.set_style(
            ProgressStyle::with_template("{bar:40} {pos}/{len} frames {msg} {elapsed_precise}")
                .expect("valid template")
                .progress_chars("=> "),
        );
        Self { bar, fixes: 0 }
    }
}

impl Observer for Progress {
    fn frame(&mut self, frame: &FusedFrame) {
        self.bar.set_position(frame.index as u64 + 1);
    }

    fn fix(&mut self, _fix: &FixRecord) {
        self.fixes += 1;
        self.bar.set_message(format!("{} fixes", self.fixes));
    }
}

impl Drop for Progress {
    fn drop(&mut self) {
        self.bar.finish_and_clear();
    }
}
