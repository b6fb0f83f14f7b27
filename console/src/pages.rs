//! The console's pages, rendered on the server (every value HTML-escaped; the scripts only
//! refresh fragments, draw the 3D view and read events).

use std::fmt::Write as _;

use ris_daemon::page::esc;
use ris_daemon::protocol::ScanState;
use serde_json::Value;

use crate::auth::{Role, Session};
use crate::characteristic::Characteristic;
use crate::fabric::Fabric;
use crate::history::{Filter, ScanRecord};
use crate::spc;

/// The style sheet (screen and print).
pub const CSS: &str = include_str!("../assets/console.css");
/// The live page's script (server-sent events, fragment refresh).
pub const JS: &str = include_str!("../assets/console.js");
/// The 3D deviation view.
pub const VIEWER: &str = include_str!("../assets/viewer.js");

/// Scans of a part a trend draws (the newest).
pub const TREND_SCANS: usize = 1000;

/// `s` as one URL path segment.
pub fn url(s: &str) -> String {
    let mut o = String::with_capacity(s.len());
    for b in s.bytes() {
        if b.is_ascii_alphanumeric() || matches!(b, b'-' | b'_' | b'.' | b'~') {
            o.push(b as char);
        } else {
            let _ = write!(o, "%{b:02X}");
        }
    }
    o
}

/// `s` as a safe file name.
pub fn file_name(s: &str) -> String {
    s.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.') {
                c
            } else {
                '_'
            }
        })
        .collect()
}

fn page(title: &str, session: Option<&Session>, body: &str) -> String {
    let mut nav = String::from(r#"<a href="/">Cells</a> <a href="/scans">Scans</a>"#);
    if let Some(s) = session {
        let _ = write!(
            nav,
            r#" <span class="who">{} ({})</span> <form method="post" action="/logout" class="inline"><input type="hidden" name="csrf" value="{}"><button>Sign out</button></form>"#,
            esc(&s.user),
            match s.role {
                Role::Operator => "operator",
                Role::Reader => "reader",
            },
            esc(&s.csrf)
        );
    }
    format!(
        r#"<!DOCTYPE html><html lang="en"><head><meta charset="utf-8"><title>{} · RIS console</title><meta name="viewport" content="width=device-width, initial-scale=1"><link rel="stylesheet" href="/assets/console.css"></head><body><header><b>RIS console</b> <nav>{nav}</nav></header><div id="alarm" class="alarm" hidden></div><main>{body}</main><script src="/assets/console.js"></script></body></html>"#,
        esc(title)
    )
}

/// The verdict in an operator's words: the word and a sentence.
pub fn verdict_words(verdict: Option<&str>) -> (&'static str, &'static str, &'static str) {
    match verdict {
        Some("pass") => ("PASS", "pass", "The part is within tolerance."),
        Some("fail") => ("FAIL", "fail", "The part is out of tolerance."),
        Some("not_measured") => (
            "NOT MEASURED",
            "unmeasured",
            "Too little of the part was measured to decide.",
        ),
        _ => (
            "NO INSPECTION",
            "none",
            "The scan was not inspected against a part.",
        ),
    }
}

fn verdict_cell(verdict: Option<&str>) -> String {
    let (word, class, _) = verdict_words(verdict);
    format!(r#"<span class="verdict {class}">{word}</span>"#)
}

/// A scan's state in words.
pub fn state_words(s: &ScanState) -> String {
    match s {
        ScanState::Queued => "queued".into(),
        ScanState::Acquiring {
            sensor,
            phase,
            frame,
            frames,
        } => match phase {
            Some(p) => format!("acquiring {sensor}, {p}: frame {frame} of {frames}"),
            None => format!("acquiring {sensor}: frame {frame} of {frames}"),
        },
        ScanState::Reconstructing { sensor } => format!("reconstructing {sensor}"),
        ScanState::Merging => "merging the sensors' clouds".into(),
        ScanState::Inspecting { part } => format!("inspecting against {part}"),
        ScanState::Done => "done".into(),
        ScanState::Failed { reason } => format!("failed: {reason}"),
    }
}

fn scan_link(s: &ScanRecord) -> String {
    format!(
        r#"<a href="/cells/{}/scans/{}">{}</a>"#,
        url(&s.cell),
        url(&s.scan_id),
        esc(&s.scan_id)
    )
}

fn scans_table(rows: &[ScanRecord]) -> String {
    let mut o = String::from(
        "<table class=\"scans\"><thead><tr><th>Scan</th><th>Cell</th><th>Time (UTC)</th><th>Part</th><th>Serial</th><th>Tag</th><th>Verdict</th></tr></thead><tbody>",
    );
    for s in rows {
        let part = s.part.as_deref().map_or_else(String::new, |p| {
            format!(r#"<a href="/parts/{}">{}</a>"#, url(p), esc(p))
        });
        let _ = write!(
            o,
            "<tr><td>{}</td><td>{}</td><td>{}</td><td>{part}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
            scan_link(s),
            esc(&s.cell),
            esc(&s.time),
            esc(s.serial.as_deref().unwrap_or("")),
            esc(s.tag.as_deref().unwrap_or("")),
            verdict_cell(s.verdict.as_deref())
        );
    }
    if rows.is_empty() {
        o.push_str("<tr><td colspan=\"7\">No scan yet.</td></tr>");
    }
    o.push_str("</tbody></table>");
    o
}

/// The cells (the live fragment of the first page): state, queue, scans in progress, the
/// latest result.
pub fn cells_table(fabric: &Fabric) -> anyhow::Result<String> {
    let mut cells = fabric.cells();
    for c in fabric.history.cells()? {
        cells.entry(c).or_default();
    }
    let mut o = String::from("<div id=\"cells\" data-fragment=\"/fragment/cells\">");
    if cells.is_empty() {
        o.push_str("<p>No cell found yet: the console finds every risd on the fabric by its health token.</p>");
    }
    for (cell, view) in &cells {
        let state = match (&view.health, view.alive) {
            (Some(h), true) => h.state.clone(),
            (None, true) => "found".into(),
            (_, false) => "offline".into(),
        };
        let _ = write!(
            o,
            r#"<section class="cell" data-cell="{c}"><h2>{c} <span class="state {s}">{s}</span></h2>"#,
            c = esc(cell),
            s = esc(&state)
        );
        if let Some(h) = &view.health {
            let _ = write!(
                o,
                "<p>Sensors {}; {} waiting.</p>",
                esc(&h.sensors.join(", ")),
                h.queue
            );
        }
        for (id, st) in &view.active {
            let _ = write!(
                o,
                r#"<p class="active">Scan <a href="/cells/{}/scans/{}">{}</a>: <span class="progress">{}</span></p>"#,
                url(cell),
                url(id),
                esc(id),
                esc(&state_words(st))
            );
        }
        let streaming = fabric.streaming(cell);
        if !streaming.is_empty() {
            o.push_str("<div class=\"fused\">");
            for sensor in streaming {
                let _ = write!(
                    o,
                    r#"<figure><img class="fused" data-cell="{c}" data-sensor="{s}" src="/cells/{cu}/stream/{su}.png" alt="{s}'s fusion picture"><figcaption>{s}, live</figcaption></figure>"#,
                    c = esc(cell),
                    s = esc(&sensor),
                    cu = url(cell),
                    su = url(&sensor)
                );
            }
            o.push_str("</div>");
        }
        if let Some(latest) = fabric.history.latest(cell)? {
            let (word, _, _) = verdict_words(latest.verdict.as_deref());
            let _ = write!(
                o,
                r#"<p class="latest">Latest: {} {} <span class="verdict-word">{word}</span> {}</p>"#,
                scan_link(&latest),
                esc(latest.part.as_deref().unwrap_or("")),
                verdict_cell(latest.verdict.as_deref())
            );
        }
        o.push_str("</section>");
    }
    o.push_str("</div>");
    Ok(o)
}

/// The form an operator starts a scan with (outside every refreshed fragment, so what is typed
/// stays while the page updates).
fn start_form(fabric: &Fabric, session: &Session) -> String {
    if session.role != Role::Operator {
        return String::new();
    }
    let mut options = String::new();
    for (cell, view) in fabric.cells() {
        if view.alive {
            let _ = write!(
                options,
                r#"<option value="{c}">{c}</option>"#,
                c = esc(&cell)
            );
        }
    }
    if options.is_empty() {
        return "<p class=\"hint\">No cell to scan with yet (reload when one is found).</p>".into();
    }
    format!(
        r#"<form method="post" action="/scan" class="start"><input type="hidden" name="csrf" value="{}"><label>Cell <select name="cell">{options}</select></label> <label>Mode <select name="mode"><option value="gray">Gray code</option><option value="adaptive">adaptive mask</option><option value="single-shot">single shot</option></select></label> <label>Part <input name="part" size="10"></label> <label>Serial <input name="serial" size="12" maxlength="256"></label> <label>Tag <input name="tag" size="12" maxlength="256"></label> <button>Start scan</button></form>"#,
        esc(&session.csrf)
    )
}

/// The latest scans of every cell, the parts' trends and the latest alarms (the second live
/// fragment of the first page).
pub fn latest(fabric: &Fabric) -> anyhow::Result<String> {
    let mut body =
        String::from("<div id=\"latest\" data-fragment=\"/fragment/latest\"><h2>Latest scans</h2>");
    body.push_str(&scans_table(&fabric.history.search(&Filter {
        limit: Some(20),
        ..Filter::default()
    })?));
    let parts = fabric.history.parts()?;
    if !parts.is_empty() {
        body.push_str("<h2>Trends</h2><ul class=\"parts\">");
        for p in parts {
            let _ = write!(
                body,
                r#"<li><a href="/parts/{}">{}</a></li>"#,
                url(&p),
                esc(&p)
            );
        }
        body.push_str("</ul>");
    }
    let alarms = fabric.history.alarms(None, 10)?;
    if !alarms.is_empty() {
        body.push_str("<h2>Alarms</h2><ul class=\"alarms\">");
        for a in alarms {
            let _ = write!(
                body,
                r#"<li>{} <a href="/parts/{}?c={}">{}</a> at scan <a href="/cells/{}/scans/{}">{}</a>: {}</li>"#,
                esc(&a.time),
                url(&a.part),
                url(&a.characteristic),
                esc(&a.characteristic),
                url(&a.cell),
                url(&a.scan_id),
                esc(&a.scan_id),
                esc(&a.message)
            );
        }
        body.push_str("</ul>");
    }
    body.push_str("</div>");
    Ok(body)
}

/// `/`: the start of a scan (operators), the cells, the latest scans of every cell, the parts'
/// trends and the latest alarms; the cells and the latest scans refresh themselves.
pub fn index(fabric: &Fabric, session: &Session) -> anyhow::Result<String> {
    let mut body = start_form(fabric, session);
    body.push_str(&cells_table(fabric)?);
    body.push_str(&latest(fabric)?);
    Ok(page("Cells", Some(session), &body))
}

/// The sign-in page.
pub fn login(message: Option<&str>) -> String {
    let m = message.map_or_else(String::new, |m| {
        format!("<p class=\"error\">{}</p>", esc(m))
    });
    page(
        "Sign in",
        None,
        &format!(
            r#"<h1>Sign in</h1>{m}<form method="post" action="/login" class="login"><label>User <input name="user" autocomplete="username" required></label><label>Password <input name="password" type="password" autocomplete="current-password" required></label><button>Sign in</button></form>"#
        ),
    )
}

/// `/scans`: the search form and the scans found.
pub fn scans(session: &Session, f: &Filter, rows: &[ScanRecord]) -> String {
    let v = |o: &Option<String>| esc(o.as_deref().unwrap_or(""));
    let selected = |x: &str| {
        if f.verdict.as_deref() == Some(x) {
            " selected"
        } else {
            ""
        }
    };
    let body = format!(
        r#"<h1>Scans</h1><form method="get" action="/scans" class="search"><label>Cell <input name="cell" value="{}"></label> <label>Part <input name="part" value="{}"></label> <label>Serial or tag <input name="text" value="{}"></label> <label>Verdict <select name="verdict"><option value="">any</option><option value="pass"{}>PASS</option><option value="fail"{}>FAIL</option><option value="not_measured"{}>NOT MEASURED</option></select></label> <label>From <input name="from" type="date" value="{}"></label> <label>To <input name="to" type="date" value="{}"></label> <button>Search</button></form><p>{} scans.</p>{}"#,
        v(&f.cell),
        v(&f.part),
        v(&f.text),
        selected("pass"),
        selected("fail"),
        selected("not_measured"),
        v(&f.from),
        v(&f.to),
        rows.len(),
        scans_table(rows)
    );
    page("Scans", Some(session), &body)
}

/// The live progress of a scan the history does not have yet (the fragment the page
/// refreshes).
pub fn progress(fabric: &Fabric, cell: &str, id: &str) -> String {
    let state = fabric
        .cells()
        .get(cell)
        .and_then(|v| v.active.get(id).cloned());
    let text = match state {
        Some(s) => state_words(&s),
        None => {
            "waiting for the cell's next state (finished scans appear here once recorded)".into()
        }
    };
    format!(
        r#"<p id="progress" class="progress" data-fragment="/fragment/scan/{}/{}">{}</p>"#,
        url(cell),
        url(id),
        esc(&text)
    )
}

/// A scan in progress.
pub fn pending(fabric: &Fabric, session: &Session, cell: &str, id: &str) -> String {
    page(
        id,
        Some(session),
        &format!(
            r#"<h1>Scan {} on {}</h1><div data-scan="{}" data-cell="{}">{}</div>"#,
            esc(id),
            esc(cell),
            esc(id),
            esc(cell),
            progress(fabric, cell, id)
        ),
    )
}

fn number(v: &Value) -> String {
    v.as_f64().map_or_else(|| "–".into(), |x| format!("{x:.3}"))
}

/// A scan's result: the verdict first, what and when, the characteristics, the numbered
/// out-of-tolerance regions, the datums, the 3D deviation view and the labelled map.
pub fn result(
    session: &Session,
    s: &ScanRecord,
    report: Option<&Value>,
    values: &[Characteristic],
) -> String {
    let (word, class, sentence) = verdict_words(s.verdict.as_deref());
    let mut b =
        format!(r#"<section class="banner {class}"><h1 id="verdict">{word}</h1><p>{sentence}</p>"#);
    if !s.reasons.is_empty() {
        b.push_str("<ul class=\"reasons\">");
        for r in &s.reasons {
            let _ = write!(b, "<li>{}</li>", esc(r));
        }
        b.push_str("</ul>");
    }
    b.push_str("</section>");
    let row = |k: &str, v: &str| format!("<tr><th>{k}</th><td>{}</td></tr>", esc(v));
    let _ = write!(
        b,
        "<table class=\"meta\">{}{}{}{}{}{}{}{}</table>",
        row("Part", s.part.as_deref().unwrap_or("–")),
        row("Serial", s.serial.as_deref().unwrap_or("–")),
        row("Tag", s.tag.as_deref().unwrap_or("–")),
        row("Operator", s.operator.as_deref().unwrap_or("–")),
        row("Cell", &s.cell),
        row("Time (UTC)", &s.time),
        row("Scan", &s.scan_id),
        row("Mode", &s.mode),
    );
    let base = format!("/cells/{}/scans/{}", url(&s.cell), url(&s.scan_id));
    let _ = write!(
        b,
        r#"<p class="actions"><button onclick="window.print()">Print report</button> <a href="{base}/page">The cell's full report</a> <a href="{base}/report.json">report.json</a></p>"#
    );
    if !values.is_empty() {
        b.push_str("<h2>Characteristics</h2><table class=\"values\"><thead><tr><th>Characteristic</th><th>Value</th><th>Lower limit</th><th>Upper limit</th><th></th></tr></thead><tbody>");
        for c in values {
            let out = c.lower.is_some_and(|l| c.value < l) || c.upper.is_some_and(|u| c.value > u);
            let lim = |l: Option<f64>| l.map_or_else(|| "–".into(), |x| format!("{x:.3}"));
            let _ = write!(
                b,
                r#"<tr class="{}"><td>{}</td><td>{:.4} {}</td><td>{}</td><td>{}</td><td>{}</td></tr>"#,
                if out { "out" } else { "in" },
                esc(&c.name),
                c.value,
                c.unit,
                lim(c.lower),
                lim(c.upper),
                if out { "out of limits" } else { "" }
            );
        }
        b.push_str("</tbody></table>");
    }
    if let Some(r) = report {
        let tol = r["tolerance_mm"].as_f64().unwrap_or(f64::NAN);
        let regions = r["regions_out_of_tolerance"]
            .as_array()
            .cloned()
            .unwrap_or_default();
        b.push_str("<h2>Out-of-tolerance regions</h2>");
        if regions.is_empty() {
            b.push_str("<p>None.</p>");
        } else {
            b.push_str("<table class=\"regions\"><thead><tr><th>#</th><th>Points</th><th>Peak, mm</th><th>Mean, mm</th><th>Centre (CAD), mm</th></tr></thead><tbody>");
            for (i, g) in regions.iter().enumerate() {
                let c = &g["centroid"];
                let _ = write!(
                    b,
                    r##"<tr class="region" data-region="{}" data-x="{}" data-y="{}" data-z="{}"><td><a href="#view">{}</a></td><td>{}</td><td>{}</td><td>{}</td><td>({}, {}, {})</td></tr>"##,
                    i + 1,
                    number(&c[0]),
                    number(&c[1]),
                    number(&c[2]),
                    i + 1,
                    g["points"].as_u64().unwrap_or(0),
                    number(&g["peak_deviation_mm"]),
                    number(&g["mean_deviation_mm"]),
                    number(&c[0]),
                    number(&c[1]),
                    number(&c[2]),
                );
            }
            b.push_str("</tbody></table>");
        }
        if let Some(datums) = r["datums"].as_array().filter(|d| !d.is_empty()) {
            b.push_str("<h2>Datums</h2><table class=\"datums\"><thead><tr><th>Datum</th><th>Points</th><th>Mean, mm</th><th>RMS, mm</th><th>99 % within, mm</th><th></th></tr></thead><tbody>");
            for d in datums {
                let _ =
                    write!(
                    b,
                    "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
                    esc(d["name"].as_str().unwrap_or("")),
                    d["points"].as_u64().unwrap_or(0),
                    number(&d["mean"]),
                    number(&d["rms"]),
                    number(&d["p99_abs"]),
                    if d["in_tolerance"].as_bool() == Some(true) { "in tolerance" } else { "out" }
                );
            }
            b.push_str("</tbody></table>");
        }
        let _ = write!(
            b,
            r#"<h2>Deviation in 3D</h2><p class="hint">Drag to rotate, wheel to zoom, click a point to read it.</p><div class="viewer"><canvas id="view" width="900" height="600" data-src="{base}/deviation.bin" data-tolerance="{tol}"></canvas><div class="legend"><span>−2 tol</span><span class="bar"></span><span>+2 tol</span> (tolerance ±{tol:.3} mm)</div><p id="pick" class="pick">No point picked.</p><p id="view-status" class="hint"></p></div><h2>Deviation map</h2><img class="map" src="{base}/map.png" alt="labelled deviation map"><script src="/assets/viewer.js"></script>"#
        );
    }
    page(&s.scan_id, Some(session), &b)
}

/// An individuals chart as SVG: values, centre line, control limits, specification limits,
/// points that fired a rule in red.
fn chart_svg(
    values: &[f64],
    chart: Option<&spc::Chart>,
    lower: Option<f64>,
    upper: Option<f64>,
) -> String {
    let (w, h, m) = (900.0, 280.0, 40.0);
    let mut lo = values.iter().copied().fold(f64::INFINITY, f64::min);
    let mut hi = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    for x in [chart.map(|c| c.lcl), chart.map(|c| c.ucl), lower, upper]
        .into_iter()
        .flatten()
    {
        lo = lo.min(x);
        hi = hi.max(x);
    }
    if !(lo.is_finite() && hi.is_finite()) {
        return String::new();
    }
    let pad = ((hi - lo) * 0.08).max(1e-6);
    let (lo, hi) = (lo - pad, hi + pad);
    let n = values.len().max(2) as f64;
    let x = |i: usize| m + (w - 2.0 * m) * i as f64 / (n - 1.0);
    let y = |v: f64| h - m - (h - 2.0 * m) * (v - lo) / (hi - lo);
    let mut o =
        format!(r#"<svg class="chart" viewBox="0 0 {w} {h}" width="{w}" height="{h}" role="img">"#);
    let line = |o: &mut String, v: f64, class: &str, label: &str| {
        let _ = write!(
            o,
            r#"<line class="{class}" x1="{m}" x2="{}" y1="{y:.1}" y2="{y:.1}"/><text x="{}" y="{:.1}" class="lab">{label} {v:.4}</text>"#,
            w - m,
            w - m - 120.0,
            y(v) - 3.0,
            y = y(v)
        );
    };
    if let Some(c) = chart {
        line(&mut o, c.centre, "cl", "CL");
        line(&mut o, c.ucl, "ucl", "UCL");
        line(&mut o, c.lcl, "ucl", "LCL");
    }
    if let Some(u) = upper {
        line(&mut o, u, "spec", "USL");
    }
    if let Some(l) = lower {
        line(&mut o, l, "spec", "LSL");
    }
    let mut path = String::new();
    for (i, v) in values.iter().enumerate() {
        let _ = write!(
            path,
            "{}{:.1},{:.1}",
            if i == 0 { "M" } else { "L" },
            x(i),
            y(*v)
        );
    }
    let _ = write!(o, r#"<path class="series" d="{path}"/>"#);
    let fired: std::collections::HashSet<usize> = chart
        .map(|c| c.signals.iter().map(|s| s.index).collect())
        .unwrap_or_default();
    for (i, v) in values.iter().enumerate() {
        let _ = write!(
            o,
            r#"<circle cx="{:.1}" cy="{:.1}" r="{}" class="{}"/>"#,
            x(i),
            y(*v),
            if fired.contains(&i) { 3.5 } else { 2.2 },
            if fired.contains(&i) { "sig" } else { "pt" }
        );
    }
    o.push_str("</svg>");
    o
}

fn histogram_svg(values: &[f64]) -> String {
    let bins = spc::histogram(values, 20);
    let (w, h, m) = (420.0, 180.0, 20.0);
    let top = bins.iter().map(|b| b.2).max().unwrap_or(1).max(1) as f64;
    let bw = (w - 2.0 * m) / bins.len().max(1) as f64;
    let mut o =
        format!(r#"<svg class="hist" viewBox="0 0 {w} {h}" width="{w}" height="{h}" role="img">"#);
    for (i, (_, _, c)) in bins.iter().enumerate() {
        let bh = (h - 2.0 * m) * *c as f64 / top;
        let _ = write!(
            o,
            r#"<rect x="{:.1}" y="{:.1}" width="{:.1}" height="{bh:.1}"/>"#,
            m + i as f64 * bw,
            h - m - bh,
            bw - 1.0
        );
    }
    if let (Some(f), Some(l)) = (bins.first(), bins.last()) {
        let _ = write!(
            o,
            r#"<text x="{m}" y="{}" class="lab">{:.4}</text><text x="{}" y="{}" class="lab">{:.4}</text>"#,
            h - 4.0,
            f.0,
            w - m - 50.0,
            h - 4.0,
            l.1
        );
    }
    o.push_str("</svg>");
    o
}

/// `/parts/<part>`: every characteristic's trend, or one in full with its chart, rules,
/// capability and histogram.
pub fn trend(
    fabric: &Fabric,
    session: &Session,
    part: &str,
    only: Option<&str>,
) -> anyhow::Result<String> {
    let names = fabric.history.characteristics(part)?;
    let mut b = format!(
        r#"<h1>Trends of {}</h1><p class="actions"><a href="/parts/{p}/export.csv">Export CSV</a> <a href="/parts/{p}/export.dfq">Export AQDEF (.dfq)</a> <a href="/scans?part={p}">Scans</a></p>"#,
        esc(part),
        p = url(part)
    );
    if names.is_empty() {
        b.push_str("<p>No characteristic recorded for this part.</p>");
    }
    b.push_str("<nav class=\"chars\">");
    for n in &names {
        let _ = write!(
            b,
            r#"<a href="/parts/{}?c={}"{}>{}</a> "#,
            url(part),
            url(n),
            if Some(n.as_str()) == only {
                " class=\"on\""
            } else {
                ""
            },
            esc(n)
        );
    }
    b.push_str("</nav>");
    let shown: Vec<&String> = match only {
        Some(c) => names.iter().filter(|n| n.as_str() == c).collect(),
        None => names.iter().collect(),
    };
    for name in shown {
        let series = fabric.history.series(part, name, TREND_SCANS)?;
        let values: Vec<f64> = series.iter().map(|p| p.value).collect();
        let (lower, upper) = series.last().map_or((None, None), |p| (p.lower, p.upper));
        let chart = spc::chart(&values, 20);
        let _ = write!(
            b,
            r#"<section class="trend" data-characteristic="{}"><h2><a href="/parts/{}?c={}">{}</a></h2>"#,
            esc(name),
            url(part),
            url(name),
            esc(name)
        );
        b.push_str(&chart_svg(&values, chart.as_ref(), lower, upper));
        match &chart {
            Some(c) => {
                let _ = write!(
                    b,
                    "<p>{} scans; centre {:.4}, limits {:.4} … {:.4} from the first {}.</p>",
                    values.len(),
                    c.centre,
                    c.lcl,
                    c.ucl,
                    c.baseline
                );
            }
            None => {
                let _ = write!(
                    b,
                    "<p>{} scans: control limits need {} scans of a baseline.</p>",
                    values.len(),
                    spc::MIN_BASELINE
                );
            }
        }
        if let Some(cap) = spc::capability(&values, lower, upper) {
            let _ = write!(
                b,
                "<p class=\"capability\">Cp {} · Cpk {:.2} (mean {:.4}, σ {:.4})</p>",
                cap.cp.map_or_else(|| "–".into(), |c| format!("{c:.2}")),
                cap.cpk,
                cap.mean,
                cap.sigma
            );
        }
        if only.is_some() {
            if let Some(c) = &chart {
                if !c.signals.is_empty() {
                    b.push_str("<h3>Rules fired</h3><ul class=\"signals\">");
                    for s in &c.signals {
                        let p = &series[s.index];
                        let _ = write!(
                            b,
                            r#"<li>scan <a href="/cells/{}/scans/{}">{}</a> ({}): {}</li>"#,
                            url(&p.cell),
                            url(&p.scan_id),
                            esc(&p.scan_id),
                            esc(p.serial.as_deref().unwrap_or("")),
                            s.rule.describe()
                        );
                    }
                    b.push_str("</ul>");
                }
            }
            b.push_str("<h3>Histogram</h3>");
            b.push_str(&histogram_svg(&values));
        }
        b.push_str("</section>");
    }
    Ok(page(&format!("Trends of {part}"), Some(session), &b))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn urls_and_file_names_are_safe() {
        assert_eq!(url("a b/<c>"), "a%20b%2F%3Cc%3E");
        assert_eq!(file_name("../x y"), ".._x_y");
    }

    #[test]
    fn a_chart_of_a_thousand_scans_is_drawn() {
        let values: Vec<f64> = (0..1000).map(|i| (i as f64 * 0.37).sin() * 0.01).collect();
        let c = spc::chart(&values, 20);
        let svg = chart_svg(&values, c.as_ref(), Some(-0.5), Some(0.5));
        assert_eq!(svg.matches("<circle").count(), 1000);
    }
}
