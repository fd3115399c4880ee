//! Progress on stderr for the long steps of a host command: a spinner for a step of
//! unknown length ([`with_spinner`]) and a bar for a replay ([`Progress`]), each shown
//! only once the step has taken [`PROGRESS_DELAY`] and only when stderr is a terminal.

use std::sync::mpsc::{self, RecvTimeoutError};
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

/// How long a step runs before its progress is shown.
pub const PROGRESS_DELAY: Duration = Duration::from_secs(1);

/// Runs `work`, showing a spinner with `message` on stderr if it takes longer than
/// [`PROGRESS_DELAY`] (only when stderr is a terminal).
pub fn with_spinner<T>(message: String, work: impl FnOnce() -> T) -> T {
    // The spinner thread waits on a channel that is closed when `work` returns (or
    // panics): the sender is dropped then.
    let (done, finished) = mpsc::channel::<()>();
    std::thread::scope(|scope| {
        scope.spawn(move || {
            if finished.recv_timeout(PROGRESS_DELAY) != Err(RecvTimeoutError::Timeout) {
                return;
            }
            let spinner = ProgressBar::with_draw_target(None, ProgressDrawTarget::stderr());
            let style = ProgressStyle::with_template("{spinner} {msg} ({elapsed})")
                .unwrap_or_else(|_| ProgressStyle::default_spinner());
            spinner.set_style(style);
            spinner.set_message(message);
            while finished.recv_timeout(Duration::from_millis(100)) == Err(RecvTimeoutError::Timeout) {
                spinner.tick();
            }
            spinner.finish_and_clear();
        });
        let _done = done;
        work()
    })
}

/// A progress bar on stderr that appears only once a run has taken a second (and only
/// when stderr is a terminal).
pub struct Progress {
    total: usize,
    start: Instant,
    bar: Option<ProgressBar>,
}

impl Progress {
    /// A bar for `total` rows, not shown yet.
    pub fn new(total: usize) -> Self {
        Progress { total, start: Instant::now(), bar: None }
    }

    /// `done` rows of the total are done.
    pub fn update(&mut self, done: usize) {
        if self.bar.is_none() && self.start.elapsed() >= PROGRESS_DELAY {
            let bar = ProgressBar::with_draw_target(Some(self.total as u64), ProgressDrawTarget::stderr());
            let style = ProgressStyle::with_template("replay [{bar:40}] {pos}/{len} rows, {eta} left")
                .unwrap_or_else(|_| ProgressStyle::default_bar())
                .progress_chars("=> ");
            bar.set_style(style);
            self.bar = Some(bar);
        }
        if let Some(bar) = &self.bar {
            bar.set_position(done as u64);
        }
    }

    /// Removes the bar, if it was shown.
    pub fn finish(&mut self) {
        if let Some(bar) = self.bar.take() {
            bar.finish_and_clear();
        }
    }
}
