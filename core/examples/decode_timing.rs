//! Time decoding of a simulated 2048x2048 capture (set RIS_TIMING=1 for the stage breakdown).
#[path = "../benches/common.rs"]
mod common;
fn main() {
    if std::env::var("RIS_LOG").is_ok() {
        tracing_subscriber_init();
    }
    let (_, capture, _) = common::captures_2k();
    for _ in 0..std::env::var("N")
        .ok()
        .and_then(|n| n.parse().ok())
        .unwrap_or(5)
    {
        let t = std::time::Instant::now();
        let d = ris_core::decode::decode(&capture, &ris_core::decode::DecodeParams::default())
            .expect("decode");
        println!("decode {:?} ({} valid)", t.elapsed(), d.valid_count());
    }
}

fn tracing_subscriber_init() {
    // Minimal stderr logger for the example: print debug events' fields.
    struct Printer;
    impl tracing::Subscriber for Printer {
        fn enabled(&self, m: &tracing::Metadata<'_>) -> bool {
            m.target().starts_with("ris_core")
        }
        fn new_span(&self, _: &tracing::span::Attributes<'_>) -> tracing::span::Id {
            tracing::span::Id::from_u64(1)
        }
        fn record(&self, _: &tracing::span::Id, _: &tracing::span::Record<'_>) {}
        fn record_follows_from(&self, _: &tracing::span::Id, _: &tracing::span::Id) {}
        fn event(&self, e: &tracing::Event<'_>) {
            struct V(String);
            impl tracing::field::Visit for V {
                fn record_debug(&mut self, f: &tracing::field::Field, v: &dyn std::fmt::Debug) {
                    self.0.push_str(&format!("{}={:?} ", f.name(), v));
                }
            }
            let mut v = V(String::new());
            e.record(&mut v);
            eprintln!("{}", v.0);
        }
        fn enter(&self, _: &tracing::span::Id) {}
        fn exit(&self, _: &tracing::span::Id) {}
    }
    let _ = tracing::subscriber::set_global_default(Printer);
}
