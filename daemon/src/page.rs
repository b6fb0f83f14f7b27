//! `report.html`: one self-contained page per inspected scan (the labelled deviation map
//! embedded), with the verdict and its reasons, statistics, datum and region tables, the
//! registration's quality (iterations, trusted fraction, alignment, stability, per-direction
//! conditioning), per-sensor point counts and stage timings, and links to the scan's files.
//! Built from the files the scan wrote (`report.json`, `scan.json`, `deviation.png`), so it
//! can be regenerated from a stored scan.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use base64::Engine as _;
use serde_json::Value;

/// Write `report.html` into the scan (or `ris inspect` output) directory `dir`, atomically.
pub fn write_report_page(dir: &Path) -> Result<PathBuf> {
    let read_json = |name: &str| -> Result<Option<Value>> {
        let path = dir.join(name);
        if !path.is_file() {
            return Ok(None);
        }
        let text = std::fs::read_to_string(&path)
            .with_context(|| format!("reading {}", path.display()))?;
        Ok(Some(serde_json::from_str(&text).with_context(|| {
            format!("{} is not valid JSON", path.display())
        })?))
    };
    let report = read_json("report.json")?;
    let scan = read_json("scan.json")?;
    let map = dir.join("deviation.png");
    let map = if map.is_file() {
        Some(std::fs::read(&map).with_context(|| format!("reading {}", map.display()))?)
    } else {
        None
    };
    let mut files: Vec<String> = std::fs::read_dir(dir)
        .with_context(|| format!("listing {}", dir.display()))?
        .flatten()
        .filter(|e| e.path().is_file())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n != "report.html")
        .collect();
    files.sort();
    let html = render(report.as_ref(), scan.as_ref(), map.as_deref(), &files);
    let path = dir.join("report.html");
    ris_core::io::write_atomic(&path, html.as_bytes())
        .with_context(|| format!("writing {}", path.display()))?;
    Ok(path)
}

/// HTML-escaped text (`&`, `<`, `>`, `"`, `'`): safe in element content and quoted attributes.
pub fn esc(s: &str) -> String {
    let mut o = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => o.push_str("&amp;"),
            '<' => o.push_str("&lt;"),
            '>' => o.push_str("&gt;"),
            '"' => o.push_str("&quot;"),
            '\'' => o.push_str("&#39;"),
            _ => o.push(c),
        }
    }
    o
}

/// A number with `d` decimals, or "–" when absent.
fn num(v: &Value, d: usize) -> String {
    v.as_f64()
        .map_or_else(|| "–".to_string(), |x| format!("{x:.d$}"))
}

fn text(v: &Value) -> String {
    match v {
        Value::String(s) => esc(s),
        Value::Null => "–".into(),
        other => esc(&other.to_string()),
    }
}

/// One table: header cells and rows of already-escaped cells.
fn table(out: &mut String, id: &str, head: &[&str], rows: &[Vec<String>]) {
    let _ = write!(out, "<table id=\"{id}\"><thead><tr>");
    for h in head {
        let _ = write!(out, "<th>{}</th>", esc(h));
    }
    out.push_str("</tr></thead><tbody>");
    for r in rows {
        out.push_str("<tr>");
        for c in r {
            let _ = write!(out, "<td>{c}</td>");
        }
        out.push_str("</tr>");
    }
    out.push_str("</tbody></table>");
}

const STYLE: &str = "body{font-family:system-ui,sans-serif;margin:24px;color:#111;max-width:1300px}\
h1{margin:0 0 4px 0}h2{margin-top:28px;border-bottom:1px solid #ccc}\
.verdict{display:inline-block;padding:6px 18px;font-size:28px;font-weight:bold;color:#fff;border-radius:4px}\
.pass{background:#008c3c}.fail{background:#c81e1e}.not_measured,.none{background:#c87800}\
table{border-collapse:collapse;margin:8px 0}td,th{border:1px solid #ccc;padding:3px 8px;text-align:right}\
th{background:#f2f2f2}td:first-child,th:first-child{text-align:left}\
img{max-width:100%;border:1px solid #ddd}.muted{color:#666}ul.reasons li{margin:2px 0}";

/// The page.
fn render(
    report: Option<&Value>,
    scan: Option<&Value>,
    map: Option<&[u8]>,
    files: &[String],
) -> String {
    let null = Value::Null;
    let r = report.unwrap_or(&null);
    let s = scan.unwrap_or(&null);
    let verdict = r["verdict"].as_str().unwrap_or("none");
    let shown = match verdict {
        "pass" => "PASS",
        "fail" => "FAIL",
        "not_measured" => "NOT MEASURED",
        _ => "NOT INSPECTED",
    };
    let part = s["inspection"]["part"].as_str().unwrap_or("");
    let id = s["scan_id"].as_str().unwrap_or("");
    let mut o = String::new();
    let _ = write!(
        o,
        "<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>{} {}: {shown}</title><style>{STYLE}</style></head><body>",
        esc(part),
        esc(id)
    );
    let _ = write!(
        o,
        "<header><h1>{}</h1><div id=\"verdict\" class=\"verdict {}\">{shown}</div>",
        if part.is_empty() {
            "Inspection".to_string()
        } else {
            esc(part)
        },
        esc(verdict)
    );
    let _ = write!(
        o,
        "<p class=\"muted\">scan {} · cell {} · mode {} · tolerance ± {} mm</p></header>",
        text(&s["scan_id"]),
        text(&s["cell"]),
        text(&s["mode"]),
        num(&r["tolerance_mm"], 3)
    );
    let list = |o: &mut String, title: &str, v: &Value| {
        if let Some(items) = v.as_array().filter(|a| !a.is_empty()) {
            let _ = write!(o, "<h2>{}</h2><ul class=\"reasons\">", esc(title));
            for i in items {
                let _ = write!(o, "<li>{}</li>", text(i));
            }
            o.push_str("</ul>");
        }
    };
    list(&mut o, "Why", &r["reasons"]);
    list(&mut o, "Warnings", &r["warnings"]);
    if let Some(png) = map {
        let b64 = base64::engine::general_purpose::STANDARD.encode(png);
        let _ = write!(
            o,
            "<h2>Deviation map</h2><img id=\"map\" alt=\"deviation map\" src=\"data:image/png;base64,{b64}\">"
        );
    }
    if report.is_some() {
        let st = &r["statistics"];
        o.push_str("<h2>Statistics</h2>");
        let rows: Vec<Vec<String>> = [
            ("points", num(&st["points"], 0)),
            ("mean, mm", num(&st["mean"], 4)),
            ("RMS, mm", num(&st["rms"], 4)),
            ("std, mm", num(&st["std"], 4)),
            ("min, mm", num(&st["min"], 4)),
            ("max, mm", num(&st["max"], 4)),
            (
                "robust min / max (0.01 % / 99.99 %), mm",
                format!(
                    "{} / {}",
                    num(&st["robust_min"], 4),
                    num(&st["robust_max"], 4)
                ),
            ),
            (
                "5th / 50th / 95th percentile, mm",
                format!(
                    "{} / {} / {}",
                    num(&st["p05"], 4),
                    num(&st["p50"], 4),
                    num(&st["p95"], 4)
                ),
            ),
            (
                "within tolerance",
                st["within_tolerance"]
                    .as_f64()
                    .map_or("–".into(), |w| format!("{:.2} %", 100.0 * w)),
            ),
            ("beyond the CAD", num(&st["beyond_cad"], 0)),
            (
                "outside the inspected surface",
                num(&st["outside_inspected"], 0),
            ),
            (
                "coverage",
                r["coverage"]["fraction"].as_f64().map_or("–".into(), |w| {
                    format!(
                        "{:.1} % of {}",
                        100.0 * w,
                        esc(r["coverage"]["surface"]
                            .as_str()
                            .unwrap_or("the whole CAD surface"))
                    )
                }),
            ),
        ]
        .into_iter()
        .map(|(k, v)| vec![esc(k), v])
        .collect();
        table(&mut o, "statistics", &["", "value"], &rows);

        if let Some(list) = r["characteristics"].as_array().filter(|a| !a.is_empty()) {
            o.push_str("<h2>Characteristics</h2>");
            let rows: Vec<Vec<String>> = list
                .iter()
                .map(|c| {
                    vec![
                        format!("{} {}", text(&c["symbol"]), text(&c["characteristic"])),
                        text(&c["name"]),
                        c["faces"].as_array().map_or("–".into(), |f| {
                            f.iter()
                                .map(|n| format!("#{}", num(n, 0)))
                                .collect::<Vec<_>>()
                                .join(", ")
                        }),
                        num(&c["measured"], 3),
                        format!(
                            "{} … {}",
                            num(&c["lower_limit"], 3),
                            num(&c["upper_limit"], 3)
                        ),
                        match c["in_tolerance"].as_bool() {
                            Some(true) => "yes".into(),
                            Some(false) => "no".into(),
                            None => format!("not measured: {}", text(&c["not_measured"])),
                        },
                        format!("{:.0} %", 100.0 * c["coverage"].as_f64().unwrap_or(0.0)),
                        text(&c["method"]),
                    ]
                })
                .collect();
            table(
                &mut o,
                "characteristics",
                &[
                    "characteristic",
                    "feature",
                    "faces",
                    "measured, mm",
                    "limits, mm",
                    "in tolerance",
                    "measured share",
                    "how",
                ],
                &rows,
            );
        }

        o.push_str("<h2>Datums</h2>");
        let rows: Vec<Vec<String>> = r["datums"]
            .as_array()
            .map(|a| {
                a.iter()
                    .map(|d| {
                        let f = &d["frame"];
                        vec![
                            text(&d["name"]),
                            num(&d["points"], 0),
                            num(&d["mean"], 4),
                            num(&d["rms"], 4),
                            num(&d["p99_abs"], 4),
                            if d["in_tolerance"].as_bool() == Some(true) {
                                "yes".into()
                            } else {
                                "no".into()
                            },
                            match f["measured"].as_array() {
                                Some(p) => {
                                    p.iter().map(|c| num(c, 3)).collect::<Vec<_>>().join(", ")
                                }
                                None => text(&f["error"]),
                            },
                            f["offset_mm"].as_array().map_or("–".into(), |p| {
                                p.iter().map(|c| num(c, 4)).collect::<Vec<_>>().join(", ")
                            }),
                        ]
                    })
                    .collect()
            })
            .unwrap_or_default();
        if rows.is_empty() {
            o.push_str("<p class=\"muted\">none: trusted-region registration</p>");
        } else {
            table(
                &mut o,
                "datums",
                &[
                    "datum",
                    "points",
                    "mean, mm",
                    "RMS, mm",
                    "99 % |dev|, mm",
                    "in tolerance",
                    "measured at",
                    "offsets, mm",
                ],
                &rows,
            );
        }

        o.push_str("<h2>Regions out of tolerance</h2>");
        let rows: Vec<Vec<String>> = r["regions_out_of_tolerance"]
            .as_array()
            .map(|a| {
                a.iter()
                    .enumerate()
                    .map(|(i, g)| {
                        vec![
                            (i + 1).to_string(),
                            num(&g["peak_deviation_mm"], 3),
                            num(&g["mean_deviation_mm"], 3),
                            num(&g["points"], 0),
                            g["centroid"].as_array().map_or("–".into(), |p| {
                                p.iter().map(|c| num(c, 1)).collect::<Vec<_>>().join(", ")
                            }),
                        ]
                    })
                    .collect()
            })
            .unwrap_or_default();
        if rows.is_empty() {
            o.push_str("<p class=\"muted\">none</p>");
        } else {
            table(
                &mut o,
                "regions",
                &[
                    "region",
                    "peak, mm",
                    "mean, mm",
                    "points",
                    "centroid (CAD), mm",
                ],
                &rows,
            );
        }

        o.push_str("<h2>Registration</h2>");
        let g = &r["registration"];
        let a = &g["alignment"];
        let rows: Vec<Vec<String>> = [
            ("mode", text(&g["mode"])),
            ("iterations", num(&g["iterations"], 0)),
            (
                "trusted fraction",
                g["trusted_fraction"]
                    .as_f64()
                    .map_or("–".into(), |w| format!("{:.1} %", 100.0 * w)),
            ),
            (
                "coarse alignment score (runner-up)",
                if a.is_null() {
                    "initial pose given".into()
                } else {
                    format!(
                        "{} ({})",
                        num(&a["best_score"], 3),
                        num(&a["runner_up_score"], 3)
                    )
                },
            ),
            (
                "stability: largest shift leaving out one region, mm",
                num(&g["stability"]["shift_mm"], 3),
            ),
        ]
        .into_iter()
        .map(|(k, v)| vec![esc(k), v])
        .collect();
        table(&mut o, "registration", &["", "value"], &rows);
        let rows: Vec<Vec<String>> = r["conditioning"]["directions"]
            .as_array()
            .map(|a| {
                a.iter()
                    .map(|d| {
                        vec![
                            text(&d["kind"]),
                            d["axis"].as_array().map_or("–".into(), |p| {
                                p.iter().map(|c| num(c, 2)).collect::<Vec<_>>().join(", ")
                            }),
                            d["strength"]
                                .as_f64()
                                .map_or("–".into(), |x| format!("{x:.2e}")),
                            num(&d["slide_mm"], 2),
                        ]
                    })
                    .collect()
            })
            .unwrap_or_default();
        table(
            &mut o,
            "conditioning",
            &[
                "direction",
                "axis (CAD)",
                "strength",
                "slide per tolerance, mm",
            ],
            &rows,
        );
    }
    if let Some(sensors) = s["sensors"].as_array() {
        o.push_str("<h2>Sensors</h2>");
        let rows: Vec<Vec<String>> = sensors
            .iter()
            .map(|t| {
                let st = &t["stages"];
                vec![
                    text(&t["sensor"]),
                    num(&t["points"], 0),
                    num(&t["outside_volume"], 0),
                    num(&t["frames"], 0),
                    format!(
                        "{} – {}",
                        num(&t["acquire"][0], 2),
                        num(&t["acquire"][1], 2)
                    ),
                    num(&st["decode"], 3),
                    num(&st["reconstruct"], 3),
                    num(&st["merge"], 3),
                ]
            })
            .collect();
        table(
            &mut o,
            "sensors",
            &[
                "sensor",
                "points",
                "outside calibrated volume",
                "frames",
                "acquired, s",
                "decode, s",
                "reconstruct, s",
                "merge, s",
            ],
            &rows,
        );
        let _ = write!(
            o,
            "<p>{} merged points; {} s of computation after the last frame; {} s in all.</p>",
            num(&s["merged_points"], 0),
            num(&s["compute_after_last_frame"], 2),
            num(&s["total"], 2)
        );
    }
    o.push_str("<h2>Files</h2><ul id=\"files\">");
    for f in files {
        let _ = write!(o, "<li><a href=\"{0}\">{0}</a></li>", esc(f));
    }
    o.push_str("</ul>");
    // The page states whether it rendered whole (its map decoded), for people and for tests.
    o.push_str(
        "<script>window.addEventListener('load',function(){var m=document.getElementById('map');\
document.body.dataset.rendered=(!m||(m.complete&&m.naturalWidth>0))?'ok':'broken';});</script>",
    );
    o.push_str("</body></html>\n");
    o
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn text_from_the_files_is_escaped() {
        let report =
            serde_json::json!({"verdict": "fail", "reasons": ["<script>alert(1)</script> & more"]});
        let html = render(Some(&report), None, None, &["a<b>.ply".into()]);
        assert!(!html.contains("<script>alert"));
        assert!(html.contains("&lt;script&gt;alert(1)&lt;/script&gt; &amp; more"));
        assert!(html.contains("href=\"a&lt;b&gt;.ply\""));
        assert!(html.contains("class=\"verdict fail\">FAIL<"));
    }
}
