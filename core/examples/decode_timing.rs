//! Time decoding of a simulated 2048x2048 capture (set RIS_TIMING=1 for the stage breakdown).
#[path = "../benches/common.rs"]
mod common;
fn main() {
    let (_, capture, _) = common::captures_2k();
    for _ in 0..std::env::var("N").ok().and_then(|n| n.parse().ok()).unwrap_or(5) {
        let t = std::time::Instant::now();
        let d = ris_core::decode::decode(&capture, &ris_core::decode::DecodeParams::default()).expect("decode");
        println!("decode {:?} ({} valid)", t.elapsed(), d.valid_count());
    }
}
