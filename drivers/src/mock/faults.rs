//! Faults the mock pair can be told to commit, so that tests see the sequencer handle them.

use std::sync::Arc;

use super::Shared;

/// A fault applied to one exposure (counted from 0 over the pair's lifetime).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Fault {
    /// The frame is exposed (its id is used) but never delivered.
    DropFrame,
    /// The trigger is ignored: no exposure, no frame.
    MissedTrigger,
    /// The frame is delivered twice.
    DuplicateFrame,
    /// The frame is delivered only after the next trigger.
    LateFrame,
    /// The projector shows the next slide instead of the requested one for this exposure.
    WrongPattern,
    /// The camera disconnects at this trigger; `reconnect` brings it back unless disabled.
    Disconnect,
    /// The stream stops at this trigger while the control channel still answers: this and
    /// every later trigger is acknowledged but no frame comes, until `reconnect` reopens the
    /// camera (a stream channel lost under a camera that kept its controller).
    StreamStall,
}

/// Plans faults on a mock pair.
#[derive(Clone)]
pub struct FaultInjector {
    pub(super) shared: Arc<Shared>,
}

impl FaultInjector {
    /// Commit `fault` at exposure number `at` (0 = the pair's first trigger).
    pub fn at(&self, at: u64, fault: Fault) {
        self.shared.lock().faults.push((at, fault));
    }

    /// Commit `fault` at the next exposure.
    pub fn next(&self, fault: Fault) {
        let mut st = self.shared.lock();
        let at = st.triggers;
        st.faults.push((at, fault));
    }

    /// Exposures made so far.
    pub fn exposures(&self) -> u64 {
        self.shared.lock().triggers
    }

    /// A projector that puts each slide on screen `latency` after it was asked to (default 0):
    /// an exposure before then sees the previous slide.
    pub fn set_latency(&self, latency: std::time::Duration) {
        self.shared.lock().latency = latency;
    }

    /// Whether `reconnect` succeeds after a disconnect (default true).
    pub fn set_reconnectable(&self, yes: bool) {
        self.shared.lock().reconnectable = yes;
    }

    /// A new scan of the cell begins: a wearing scene (`wear` of a panel) is rendered with the
    /// dent one scan deeper from now on.
    pub fn next_scan(&self) {
        self.shared.lock().scans += 1;
    }
}
