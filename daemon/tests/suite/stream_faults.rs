//! A stream meets a flaky and then a lost camera (the mock pair's fault injection): a frame that
//! does not come is skipped and counted, a lost camera ends the stream with its reason in the
//! status, and once the camera is back a new stream runs.

use std::path::Path;
use std::time::{Duration, Instant};

use ris_daemon::cell::Cell;
use ris_daemon::config::CellConfig;
use ris_daemon::protocol::StreamSpec;
use ris_daemon::stream::{self, Publish, StreamControl, StreamEnd};
use ris_drivers::mock::Fault;
use zenoh::Wait;

#[test]
fn a_missed_frame_is_skipped_and_a_lost_camera_ends_the_stream_with_its_reason() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/mock-cell.toml");
    let mut config = CellConfig::load(&path).expect("mock cell");
    config.sensors.truncate(1);
    config.parts.clear();
    config.sensors[0].frame_timeout = Duration::from_millis(300);
    let mut cell = Cell::prepare(&config, 5, &|_, _, _| {}).expect("cell");
    let faults = cell.pairs[0].faults.clone().expect("mock faults");
    let at = faults.exposures() + 3;
    faults.at(at, Fault::DropFrame);
    faults.at(at + 4, Fault::MissedTrigger);
    faults.at(at + 9, Fault::Disconnect);
    let session =
        zenoh::open(ris_daemon::service::zenoh_config("peer", &[], &[]).expect("zenoh config"))
            .wait()
            .expect("session");
    let out = Publish {
        session: &session,
        cell: "faults",
        stopping: &|| false,
        beat: &|| {},
    };
    let control = StreamControl::default();
    let spec = StreamSpec {
        sensors: vec!["s1".into()],
        rate_hz: 50.0,
    };
    let (_jobs_tx, jobs) = std::sync::mpsc::sync_channel::<()>(1);
    control.start(spec.clone());
    let (s, generation) = control.wanted().expect("wanted");
    let t = Instant::now();
    let end = stream::run(&mut cell, &s, generation, &control, &out, &jobs);
    assert!(matches!(end, StreamEnd::Stopped));
    assert!(t.elapsed() < Duration::from_secs(60));
    let status = control.status();
    let s1 = &status.sensors["s1"];
    assert_eq!(status.state, "failed", "{status:?}");
    let why = status.error.clone().unwrap_or_default();
    assert!(why.contains("sensor s1"), "{why}");
    // Two frames did not come and were skipped; the third failure was the lost camera.
    assert_eq!(s1.missed, 3, "{status:?}");
    assert!(s1.frames >= 6, "{status:?}");
    assert!(
        control.wanted().is_none(),
        "a failed stream is not retried by itself"
    );
    assert!(
        cell.status()[0].driver != ris_daemon::protocol::DriverState::Connected,
        "the pair is marked as reconnecting"
    );

    // The camera comes back; a new stream runs until it is stopped.
    assert!(cell.reconnect(), "the mock camera reconnects");
    control.start(spec);
    let (s, generation) = control.wanted().expect("wanted");
    std::thread::scope(|scope| {
        let watcher = scope.spawn(|| {
            let t = Instant::now();
            while control.status().sensors["s1"].published < 3 {
                assert!(
                    t.elapsed() < Duration::from_secs(60),
                    "no frames after the reconnect"
                );
                std::thread::sleep(Duration::from_millis(20));
            }
            control.stop();
        });
        let end = stream::run(&mut cell, &s, generation, &control, &out, &jobs);
        assert!(matches!(end, StreamEnd::Stopped));
        watcher.join().expect("watcher");
    });
    let status = control.status();
    assert_eq!(status.state, "stopped", "{status:?}");
    assert!(status.sensors["s1"].published >= 3, "{status:?}");
    assert!(control.latest("s1").is_some_and(|l| l.cloud.len() > 1000));
}
