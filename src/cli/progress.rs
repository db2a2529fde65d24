//! Progress on the terminal: an indicatif bar per phase when stderr is a terminal, and a
//! log line per phase and about every 10 s when it is not (CI, logs, `nohup`).

use std::io::IsTerminal;
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressStyle};
use splat4d::fit::loss::psnr;
use splat4d::fit::train::StepRecord;
use splat4d::model::Progress;
use splat4d::tasks::fit::FitProgress;

/// How often a piped run logs a line.
const LOG_EVERY: Duration = Duration::from_secs(10);

/// Progress of the current phase.
pub struct Bars {
    bar: Option<ProgressBar>,
    /// Piped output: `(phase, done, total, last line)`.
    log: Option<(String, usize, usize, Instant)>,
    terminal: bool,
}

impl Bars {
    /// Bars on a terminal, log lines otherwise.
    pub fn new() -> Self {
        Bars {
            bar: None,
            log: None,
            terminal: std::io::stderr().is_terminal(),
        }
    }

    /// Ends the current phase.
    pub fn finish(&mut self) {
        if let Some(bar) = self.bar.take() {
            bar.finish_and_clear();
        }
        if let Some((phase, done, total, _)) = self.log.take() {
            eprintln!("{phase}: {done}/{total} done");
        }
    }

    fn message(&mut self, text: String) {
        if let Some(bar) = &self.bar {
            bar.set_message(text);
        } else if let Some((phase, done, total, last)) = &mut self.log
            && last.elapsed() >= LOG_EVERY
        {
            eprintln!("{phase}: {done}/{total}, {text}");
            *last = Instant::now();
        }
    }
}

impl Drop for Bars {
    fn drop(&mut self) {
        if let Some(bar) = self.bar.take() {
            bar.finish_and_clear();
        }
    }
}

impl Progress for Bars {
    fn start(&mut self, phase: &str, total: usize) {
        self.finish();
        if self.terminal {
            let bar = ProgressBar::new(total as u64);
            bar.set_style(
                ProgressStyle::with_template(
                    "{prefix} [{elapsed_precise}] {bar:30} {pos}/{len} ({per_sec}) {msg}",
                )
                .expect("a valid template"),
            );
            bar.set_prefix(format!("{phase:>8}"));
            self.bar = Some(bar);
        } else {
            eprintln!("{phase}: {total} to do");
            self.log = Some((phase.to_owned(), 0, total, Instant::now()));
        }
    }

    fn note(&mut self, text: &str) {
        match &self.bar {
            Some(bar) => bar.println(format!("note: {text}")),
            None => eprintln!("note: {text}"),
        }
    }

    fn tick(&mut self) {
        if let Some(bar) = &self.bar {
            bar.inc(1);
        } else if let Some((phase, done, total, last)) = &mut self.log {
            *done += 1;
            if last.elapsed() >= LOG_EVERY {
                eprintln!("{phase}: {done}/{total}");
                *last = Instant::now();
            }
        }
    }
}

impl FitProgress for Bars {
    fn start(&mut self, steps: usize) {
        Progress::start(self, "fit", steps);
    }

    fn note(&mut self, text: &str) {
        Progress::note(self, text);
    }

    fn step(&mut self, record: &StepRecord, heldout_psnr: Option<f64>) {
        let heldout = heldout_psnr.map_or(String::new(), |p| format!(", held-out {p:.2} dB"));
        self.tick();
        self.message(format!(
            "{} kernels, loss {:.3e}, PSNR {:.2} dB{heldout}",
            record.kernels,
            record.train_loss,
            psnr(record.train_loss)
        ));
    }
}
