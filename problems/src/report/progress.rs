//! Progress bars for long runs: indicatif bars on standard error when it is a
//! terminal, nothing at all otherwise (pipes, CI logs, tests).

use indicatif::{MultiProgress, ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::io::IsTerminal;

/// A set of progress bars, or none.
#[derive(Clone, Debug)]
pub struct Progress {
    multi: Option<MultiProgress>,
}

impl Progress {
    /// Bars on standard error if it is a terminal, otherwise hidden.
    pub fn on_terminal() -> Self {
        if std::io::stderr().is_terminal() {
            Progress { multi: Some(MultiProgress::with_draw_target(ProgressDrawTarget::stderr())) }
        } else {
            Progress::hidden()
        }
    }

    /// Never draws.
    pub fn hidden() -> Self {
        Progress { multi: None }
    }

    /// A bar counting `total` steps, labelled `label` (hidden when this
    /// `Progress` is).
    pub fn bar(&self, label: &str, total: u64) -> ProgressBar {
        match &self.multi {
            Some(multi) => {
                let bar = multi.add(ProgressBar::new(total));
                let style = ProgressStyle::with_template(
                    "{prefix:>34} [{bar:30}] {percent:>3}% {human_pos}/{human_len} steps, {elapsed} (eta {eta})",
                )
                .unwrap_or_else(|_| ProgressStyle::default_bar())
                .progress_chars("=> ");
                bar.set_style(style);
                bar.set_prefix(label.to_string());
                bar
            }
            None => ProgressBar::hidden(),
        }
    }

    /// A counter of steps whose number is not known in advance (a
    /// tolerance-driven run), labelled `label` (hidden when this `Progress`
    /// is).
    pub fn counter(&self, label: &str) -> ProgressBar {
        match &self.multi {
            Some(multi) => {
                let bar = multi.add(ProgressBar::no_length());
                let style = ProgressStyle::with_template("{prefix:>34} {spinner} {human_pos} steps, {elapsed}")
                    .unwrap_or_else(|_| ProgressStyle::default_spinner());
                bar.set_style(style);
                bar.set_prefix(label.to_string());
                bar
            }
            None => ProgressBar::hidden(),
        }
    }
}
