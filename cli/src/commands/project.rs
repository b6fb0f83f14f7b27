//! `ris project`: a pattern full-screen on a projector with exact pixels, or the present
//! latency of the window projector over a scan's sequence.

use std::time::{Duration, Instant};

use anyhow::{bail, Result};
use ris_core::pattern::{CodeLayout, Pattern};
use ris_drivers::{Projector, Slide};

/// What `ris project` does with the window.
pub enum Run {
    /// Show the pattern for this many seconds.
    Hold(f64),
    /// Show every slide of a scan this many times; print the median and 95th-percentile time
    /// of `show`.
    Latency(usize),
    /// Run the driver conformance suite.
    Conformance,
}

/// Open the projector window on `monitor` and do `what`.
pub fn run(pattern: &str, width: u32, height: u32, monitor: usize, what: Run) -> Result<()> {
    let pattern = Pattern::parse(pattern)?;
    if let Run::Hold(hold) = what {
        if !(hold.is_finite() && hold >= 0.0) {
            bail!("--hold {hold}: must be a non-negative number of seconds");
        }
    }
    let mut projector = open(width, height, monitor)?;
    match what {
        Run::Conformance => {
            ris_drivers::conformance::projector(&mut projector)
                .map_err(|e| anyhow::anyhow!("conformance: {e}"))?;
            println!("conformance: ok ({})", projector.info().id);
        }
        Run::Hold(hold) => {
            projector.load(&[Slide::plain(pattern)])?;
            let shown = projector.show(0)?;
            tracing::info!(pattern = %pattern.name(), sequence = shown.sequence, "shown");
            println!(
                "{} on monitor {monitor} ({width}x{height}) for {hold} s",
                pattern.name()
            );
            std::thread::sleep(Duration::from_secs_f64(hold));
        }
        Run::Latency(n) => {
            let slides: Vec<Slide> = CodeLayout::new(width, height)
                .sequence(true)
                .into_iter()
                .map(Slide::plain)
                .collect();
            let t = Instant::now();
            projector.load(&slides)?;
            let upload = t.elapsed().as_secs_f64();
            let mut ms = Vec::with_capacity(n * slides.len());
            for _ in 0..n.max(1) {
                for slot in 0..slides.len() {
                    let t = Instant::now();
                    projector.show(slot)?;
                    ms.push(t.elapsed().as_secs_f64() * 1e3);
                }
            }
            ms.sort_by(f64::total_cmp);
            let q = |p: f64| ms[((ms.len() - 1) as f64 * p).round() as usize];
            println!(
                "{} slides uploaded in {:.0} ms; present latency over {} shows: median {:.2} ms, p95 {:.2} ms, max {:.2} ms",
                slides.len(),
                upload * 1e3,
                ms.len(),
                q(0.5),
                q(0.95),
                q(1.0)
            );
        }
    }
    Ok(())
}

#[cfg(feature = "projector")]
fn open(width: u32, height: u32, monitor: usize) -> Result<impl Projector> {
    use anyhow::Context;
    ris_projector::WindowProjector::open(&ris_projector::WindowOptions {
        width,
        height,
        monitor,
    })
    .context("opening the projector window")
}

#[cfg(not(feature = "projector"))]
fn open(_: u32, _: u32, _: usize) -> Result<ris_drivers::mock::MockProjector> {
    bail!("this build has no projector window: rebuild with `--features projector` (winit + wgpu)")
}
