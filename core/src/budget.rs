//! What a long computation may spend: a deadline and a stop flag, checked inside its loops.
//!
//! A caller that must stay responsive (risd under systemd, a CLI interrupted by the user)
//! installs a [`Budget`] around a stage with [`within`]; the stage's loops ask [`check`] (or
//! [`spent`] where they cannot return an error) once per iteration, so a stage whose parameters
//! ask for more work than its deadline allows, or that is cancelled, ends at its next
//! iteration with [`Error::Interrupted`] naming the stage. Without a budget the checks cost a
//! thread-local read and pass. The budget belongs to the thread that installed it: work a stage
//! hands to rayon's pool is bounded by the iterations of the loop that hands it out.

use std::cell::RefCell;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use crate::{Error, Result};

/// Why a stage was stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Interruption {
    /// Its stop flag was raised (risd stopping, the user interrupting).
    Cancelled,
    /// It ran past its deadline.
    Overdue {
        /// The deadline it was given.
        limit: Duration,
    },
}

impl std::fmt::Display for Interruption {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Interruption::Cancelled => write!(f, "cancelled"),
            Interruption::Overdue { limit } if *limit < Duration::from_secs(1) => {
                write!(f, "past its deadline of {} ms", limit.as_millis().max(1))
            }
            Interruption::Overdue { limit } => {
                write!(f, "past its deadline of {:.1} s", limit.as_secs_f64())
            }
        }
    }
}

/// A stage's name, deadline and stop flag.
#[derive(Clone, Debug)]
pub struct Budget {
    stage: String,
    start: Instant,
    limit: Option<Duration>,
    stop: Option<Arc<AtomicBool>>,
}

impl Budget {
    /// A budget for `stage` (named in the error), starting now.
    pub fn new(stage: impl Into<String>) -> Budget {
        Budget {
            stage: stage.into(),
            start: Instant::now(),
            limit: None,
            stop: None,
        }
    }

    /// End the stage once `limit` has passed since the budget was made.
    pub fn deadline(mut self, limit: Duration) -> Budget {
        self.limit = Some(limit);
        self
    }

    /// End the stage once `stop` is raised.
    pub fn stop_flag(mut self, stop: Arc<AtomicBool>) -> Budget {
        self.stop = Some(stop);
        self
    }

    /// The stage's name.
    pub fn stage(&self) -> &str {
        &self.stage
    }

    /// Why the stage must end now, if it must.
    pub fn interruption(&self) -> Option<Interruption> {
        if self
            .stop
            .as_ref()
            .is_some_and(|s| s.load(Ordering::Relaxed))
        {
            return Some(Interruption::Cancelled);
        }
        match self.limit {
            Some(limit) if self.start.elapsed() > limit => Some(Interruption::Overdue { limit }),
            _ => None,
        }
    }
}

thread_local! {
    static CURRENT: RefCell<Option<Budget>> = const { RefCell::new(None) };
}

/// Run `work` on this thread under `budget` (the previous budget, if any, is restored after).
pub fn within<T>(budget: Budget, work: impl FnOnce() -> T) -> T {
    struct Restore(Option<Budget>);
    impl Drop for Restore {
        fn drop(&mut self) {
            let previous = self.0.take();
            CURRENT.with(|c| *c.borrow_mut() = previous);
        }
    }
    let _restore = Restore(CURRENT.with(|c| c.borrow_mut().replace(budget)));
    work()
}

/// `Err(Error::Interrupted)` when this thread's stage is cancelled or past its deadline.
pub fn check() -> Result<()> {
    CURRENT.with(|c| match c.borrow().as_ref() {
        Some(b) => match b.interruption() {
            Some(why) => Err(Error::Interrupted {
                stage: b.stage.clone(),
                why,
            }),
            None => Ok(()),
        },
        None => Ok(()),
    })
}

/// Whether this thread's stage must end now (for loops that cannot return an error: they stop,
/// and their caller's [`check`] says why).
pub fn spent() -> bool {
    CURRENT.with(|c| {
        c.borrow()
            .as_ref()
            .is_some_and(|b| b.interruption().is_some())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_stage_ends_at_its_deadline_or_when_stopped_and_not_before() {
        assert!(check().is_ok(), "no budget: no limit");
        let stop = Arc::new(AtomicBool::new(false));
        let b = Budget::new("the test stage")
            .deadline(Duration::from_millis(200))
            .stop_flag(stop.clone());
        let (mut n, start) = (0u64, Instant::now());
        let e = within(b, || loop {
            if let Err(e) = check() {
                return e;
            }
            n += 1;
            std::thread::sleep(Duration::from_millis(1));
        });
        let took = start.elapsed();
        assert!(n > 5, "{n} iterations before the deadline");
        assert!(took >= Duration::from_millis(200), "{took:?}");
        assert!(e.to_string().contains("the test stage"), "{e}");
        assert!(e.to_string().contains("deadline of 200 ms"), "{e}");
        assert!(check().is_ok(), "the budget ends with its stage");
        let b = Budget::new("stopped").stop_flag(stop.clone());
        within(b, || {
            assert!(check().is_ok());
            stop.store(true, Ordering::SeqCst);
            assert!(spent());
            let e = check().expect_err("stopped");
            assert_eq!(e.to_string(), "stopped: cancelled");
            // An inner stage's budget ends with it; the outer one is back.
            within(Budget::new("inner"), || assert!(check().is_ok()));
            assert!(check().is_err());
        });
    }
}
