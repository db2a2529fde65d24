//! Progress on the terminal: an indicatif bar per phase when stderr is a terminal (its
//! message cut to the terminal's width, so it draws at any width), and when it is not (CI,
//! logs, `nohup`) a log line per phase and about every 5 s with the phase, the fraction done
//! and the estimated time left.

use std::io::IsTerminal;
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressStyle};
use splat4d::fit::loss::psnr;
use splat4d::fit::train::StepRecord;
use splat4d::model::Progress;
use splat4d::tasks::fit::FitProgress;

/// How often a piped run logs a line.
const LOG_EVERY: Duration = Duration::from_secs(5);

/// A piped phase: its name, steps done and to do, when it started and when it last logged.
struct PhaseLog {
    phase: String,
    done: usize,
    total: usize,
    started: Instant,
    last: Instant,
    /// The phase's own estimate of its time left (else a straight line through the time so
    /// far).
    left: Option<f64>,
}

impl PhaseLog {
    /// `phase: done/total (p %), about N s left`.
    fn line(&self) -> String {
        let fraction = self.done as f64 / self.total.max(1) as f64;
        let elapsed = self.started.elapsed().as_secs_f64();
        let straight = (self.done > 0)
            .then(|| elapsed * (self.total.saturating_sub(self.done)) as f64 / self.done as f64);
        let left = self
            .left
            .or(straight)
            .map_or(String::new(), |s| format!(", about {s:.0} s left"));
        format!(
            "{}: {}/{} ({:.0} %){left}",
            self.phase,
            self.done,
            self.total,
            100.0 * fraction
        )
    }
}

/// Progress of the current phase.
pub struct Bars {
    bar: Option<ProgressBar>,
    /// Piped output: the current phase.
    log: Option<PhaseLog>,
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
        if let Some(log) = self.log.take() {
            eprintln!(
                "{}: {}/{} done in {:.1} s",
                log.phase,
                log.done,
                log.total,
                log.started.elapsed().as_secs_f64()
            );
        }
    }

    fn message(&mut self, text: String) {
        if let Some(bar) = &self.bar {
            bar.set_message(text);
        } else if let Some(log) = &mut self.log
            && log.last.elapsed() >= LOG_EVERY
        {
            eprintln!("{}, {text}", log.line());
            log.last = Instant::now();
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
                    "{prefix} {bar:20} {pos}/{len} {elapsed}<{eta} {wide_msg}",
                )
                .expect("a valid template"),
            );
            bar.set_prefix(format!("{phase:>8}"));
            self.bar = Some(bar);
        } else {
            eprintln!("{phase}: {total} to do");
            self.log = Some(PhaseLog {
                phase: phase.to_owned(),
                done: 0,
                total,
                started: Instant::now(),
                last: Instant::now(),
                left: None,
            });
        }
    }

    fn note(&mut self, text: &str) {
        let text = crate::cli::flags::name_advice(text);
        match &self.bar {
            Some(bar) => bar.println(format!("note: {text}")),
            None => eprintln!("note: {text}"),
        }
    }

    fn tick(&mut self) {
        if let Some(bar) = &self.bar {
            bar.inc(1);
        } else if let Some(log) = &mut self.log {
            log.done += 1;
            if log.last.elapsed() >= LOG_EVERY {
                eprintln!("{}", log.line());
                log.last = Instant::now();
            }
        }
    }
}

impl FitProgress for Bars {
    fn start(&mut self, steps: usize) {
        Progress::start(self, "fit", steps);
        // The fit's own estimate of the time left replaces the bar's straight line.
        if let Some(bar) = &self.bar {
            bar.set_style(
                ProgressStyle::with_template("{prefix} {bar:20} {pos}/{len} {elapsed} {wide_msg}")
                    .expect("a valid template"),
            );
        }
    }

    fn note(&mut self, text: &str) {
        Progress::note(self, text);
    }

    fn step(&mut self, record: &StepRecord, heldout_psnr: Option<f64>, seconds_left: Option<f64>) {
        let heldout = heldout_psnr.map_or(String::new(), |p| format!(", held-out {p:.2} dB"));
        if let Some(log) = &mut self.log {
            log.left = seconds_left;
        }
        let left = match (&self.bar, seconds_left) {
            (Some(_), Some(s)) => format!("about {s:.0} s left, "),
            _ => String::new(),
        };
        self.tick();
        self.message(format!(
            "{left}{} kernels, loss {:.3e}, PSNR {:.2} dB{heldout}",
            record.kernels,
            record.train_loss,
            psnr(record.train_loss)
        ));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_piped_line_names_the_phase_the_fraction_and_the_time_left() {
        let ten_seconds_ago = Instant::now() - Duration::from_secs(10);
        let mut log = PhaseLog {
            phase: "fit".into(),
            done: 0,
            total: 400,
            started: ten_seconds_ago,
            last: ten_seconds_ago,
            left: None,
        };
        assert_eq!(log.line(), "fit: 0/400 (0 %)");
        log.done = 100;
        // 100 in 10 s: 300 more take about 30 s.
        assert_eq!(log.line(), "fit: 100/400 (25 %), about 30 s left");
        // A phase's own estimate replaces the straight line.
        log.left = Some(52.4);
        assert_eq!(log.line(), "fit: 100/400 (25 %), about 52 s left");
    }
}
