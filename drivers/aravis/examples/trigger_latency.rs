//! Trigger-to-frame latency of an Aravis camera: `cargo run --release -p ris-aravis --features
//! aravis --example trigger_latency -- DEVICE [N] [FRAME_RATE]` (DEVICE: an IP address, an id or
//! `fake`). Prints the median, 10th and 90th percentile over N software triggers.

use std::time::{Duration, Instant};

use ris_aravis::{AravisCamera, DeviceSpec, OpenOptions};
use ris_drivers::{Camera, TriggerMode};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let device = args.get(1).map(String::as_str).unwrap_or("fake");
    let n: usize = args.get(2).and_then(|a| a.parse().ok()).unwrap_or(30);
    let rate: Option<f64> = args.get(3).and_then(|a| a.parse().ok());
    let mut cam = AravisCamera::open(
        DeviceSpec::parse(device),
        OpenOptions {
            frame_rate: rate,
            ..OpenOptions::default()
        },
    )?;
    cam.set_trigger(TriggerMode::Software)?;
    cam.start()?;
    let mut ms = Vec::with_capacity(n);
    for _ in 0..n {
        let t = Instant::now();
        cam.trigger()?;
        cam.next_frame(Duration::from_secs(3))?;
        ms.push(t.elapsed().as_secs_f64() * 1e3);
    }
    cam.stop()?;
    ms.sort_by(f64::total_cmp);
    let at = |q: f64| ms[((ms.len() - 1) as f64 * q) as usize];
    println!(
        "{device}: trigger to frame over {n} triggers: median {:.1} ms (p10 {:.1}, p90 {:.1})",
        at(0.5),
        at(0.1),
        at(0.9)
    );
    Ok(())
}
