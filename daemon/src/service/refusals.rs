//! Refused requests, counted and logged at a rate: a flood of bad requests is one WARN line
//! per window with how many were refused since, not one line each.

use std::sync::Mutex;
use std::time::{Duration, Instant};

/// How often a refusal is logged at most.
const WINDOW: Duration = Duration::from_secs(10);

/// The refusals of one service.
#[derive(Default)]
pub(super) struct Refusals {
    state: Mutex<Window>,
}

#[derive(Default)]
struct Window {
    logged_at: Option<Instant>,
    suppressed: u64,
    total: u64,
}

impl Refusals {
    /// Count a refusal of a request on `key` and log it unless one was logged within the
    /// window.
    pub(super) fn note(&self, key: &str, reason: &str) {
        match self.note_at(Instant::now()) {
            Some(0) => tracing::warn!(%key, reason, "request refused"),
            Some(n) => tracing::warn!(
                %key,
                reason,
                not_logged = n,
                "request refused ({n} more since the last line, not logged one by one)"
            ),
            None => {}
        }
    }

    /// Count a refusal at `now`: `Some(n)` when it is to be logged (`n` refused since the last
    /// line went unlogged), `None` when it is only counted.
    fn note_at(&self, now: Instant) -> Option<u64> {
        let Ok(mut w) = self.state.lock() else {
            return Some(0);
        };
        w.total += 1;
        if w.logged_at.is_some_and(|t| now.duration_since(t) < WINDOW) {
            w.suppressed += 1;
            return None;
        }
        w.logged_at = Some(now);
        Some(std::mem::take(&mut w.suppressed))
    }

    /// Requests refused since the service started.
    pub(super) fn total(&self) -> u64 {
        self.state.lock().map_or(0, |w| w.total)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_flood_is_one_line_per_window_and_every_refusal_counts() {
        let r = Refusals::default();
        let t0 = Instant::now();
        assert_eq!(r.note_at(t0), Some(0));
        let logged = (1..=8_100)
            .filter(|k| r.note_at(t0 + Duration::from_micros(*k)).is_some())
            .count();
        assert_eq!(logged, 0, "within the window nothing more is logged");
        assert_eq!(
            r.note_at(t0 + WINDOW),
            Some(8_100),
            "the next line says how many"
        );
        assert_eq!(r.note_at(t0 + 2 * WINDOW + Duration::from_secs(1)), Some(0));
        assert_eq!(r.total(), 8_103);
    }
}
