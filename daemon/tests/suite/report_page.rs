//! `report.html` in a real browser: risd scans and inspects the mock cell, and headless
//! Chromium (Debian's `chromium`, installed by `.ci/run`) opens the page from the scan
//! directory. It must load with no console message, its embedded map must decode, and a
//! screenshot must show the verdict's colour and the map. A page with a script error is shown
//! to be caught the same way, so the check can fail.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use crate::common;
use common::{output_within, shared_cache};

const CHROMIUM: &str = "/usr/bin/chromium";

/// Chromium, headless, as the probe of this machine kind runs it: no sandbox (root), no GPU,
/// no background networking (the network is closed), a fresh profile.
fn chromium(profile: &Path) -> Command {
    assert!(
        Path::new(CHROMIUM).is_file(),
        "{CHROMIUM} is missing: `.ci/run` installs Debian's chromium package"
    );
    let mut c = Command::new(CHROMIUM);
    c.args([
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--enable-logging=stderr",
        "--v=0",
        "--virtual-time-budget=5000",
    ])
    .arg(format!("--user-data-dir={}", profile.display()));
    c
}

/// The DOM after load and the page's console messages.
fn open(page: &Path, profile: &Path) -> (String, Vec<String>) {
    let o = output_within(
        chromium(profile)
            .arg("--dump-dom")
            .arg(format!("file://{}", page.display())),
        Duration::from_secs(120),
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let console = String::from_utf8_lossy(&o.stderr)
        .lines()
        .filter(|l| l.contains("CONSOLE"))
        .map(str::to_string)
        .collect();
    (String::from_utf8_lossy(&o.stdout).into_owned(), console)
}

fn scan_dir(data: &Path) -> PathBuf {
    let o = output_within(
        Command::new(env!("CARGO_BIN_EXE_risd"))
            .arg("--once")
            .arg("--data-dir")
            .arg(data)
            .arg("--cache-dir")
            .arg(shared_cache())
            .env("RIS_LOG", "warn"),
        Duration::from_secs(300),
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    std::fs::read_dir(data.join("scans"))
        .expect("scans")
        .flatten()
        .map(|e| e.path())
        .find(|p| p.join("report.html").is_file())
        .expect("a scan with report.html")
}

#[test]
fn the_report_page_loads_in_a_headless_browser_and_shows_the_map_and_verdict() {
    let tmp = tempfile::tempdir().expect("tmp");
    let scan = scan_dir(&tmp.path().join("data"));
    let page = scan.join("report.html");
    let html = std::fs::read_to_string(&page).expect("page");
    // Self-contained: the map is embedded, nothing is fetched.
    assert!(html.contains("src=\"data:image/png;base64,"));
    assert!(!html.contains("http://") && !html.contains("https://"));
    for link in [
        "s1.ply",
        "merged.ply",
        "deviation.ply",
        "report.json",
        "scan.json",
    ] {
        assert!(html.contains(&format!("href=\"{link}\"")), "{link}");
    }

    let (dom, console) = open(&page, &tmp.path().join("profile"));
    assert!(console.is_empty(), "console: {console:?}");
    assert!(
        dom.contains("data-rendered=\"ok\""),
        "the map did not decode"
    );
    assert!(dom.contains(">PASS<") && dom.contains("id=\"sensors\""));

    let shot = tmp.path().join("page.png");
    let o = output_within(
        chromium(&tmp.path().join("profile"))
            .arg("--window-size=1300,1400")
            .arg(format!("--screenshot={}", shot.display()))
            .arg(format!("file://{}", page.display())),
        Duration::from_secs(120),
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let img = image::open(&shot).expect("screenshot").to_rgb8();
    // The verdict: a block of the pass colour (#008c3c) near the top.
    let verdict = img
        .enumerate_pixels()
        .filter(|(_, y, p)| *y < 200 && p.0 == [0, 140, 60])
        .count();
    assert!(verdict > 2_000, "{verdict} pixels of the verdict's green");
    // The map: a large area of the in-tolerance greens below it.
    let map = img
        .enumerate_pixels()
        .filter(|(_, y, p)| *y > 300 && p.0[1] > 120 && p.0[0] < 120 && p.0[2] < 100)
        .count();
    assert!(map > 150_000, "{map} map pixels");

    // The same checks catch a broken page: a script error and an image that does not decode.
    let broken = tmp.path().join("broken.html");
    std::fs::write(
        &broken,
        html.replace("data:image/png;base64,", "data:image/png;base64,AAAA")
            .replace("</body>", "<script>undefinedFunction();</script></body>"),
    )
    .expect("broken page");
    let (dom, console) = open(&broken, &tmp.path().join("profile2"));
    assert!(!console.is_empty(), "a script error must reach the console");
    assert!(dom.contains("data-rendered=\"broken\""));
}
