//! What a verification shows a person: a residual map per measured artefact (PNG) and the
//! one-page certificate (`verify.html`).

use std::fmt::Write as _;
use std::path::Path;

use super::{Certificate, Figure, Status};
use crate::image::save_rgb_png;
use crate::inspect::canvas::Canvas;
use crate::inspect::{deviation_colour, verdict_colour};
use crate::Result;

/// The residuals of one fitted artefact in a flat view: a sphere seen along the mean
/// direction of its measured cap (coordinates from its centre), a flat in its own plane.
#[derive(Clone, Debug)]
pub struct ResidualMap {
    /// File name of the PNG (inside the output directory).
    pub file: String,
    /// The map's title.
    pub title: String,
    /// Position of each point in the view, mm.
    pub uv: Vec<[f64; 2]>,
    /// Signed residual of each point, mm.
    pub residual: Vec<f64>,
    /// Residual shown at the first colour limit (half the figure's MPE), mm.
    pub scale: f64,
    /// The sphere's radius, drawn as its outline; `None` for a flat.
    pub disc_radius: Option<f64>,
}

const WHITE: [u8; 3] = [255, 255, 255];
const INK: [u8; 3] = [20, 20, 20];
const GREY: [u8; 3] = [150, 150, 150];

/// Draw `map` into `dir/map.file`.
pub fn write_residual_map(dir: &Path, map: &ResidualMap) -> Result<()> {
    let (w, plot_h) = (480usize, 400usize);
    let h = plot_h + 110;
    let mut c = Canvas::new(w, h, WHITE);
    c.text(12.0, 8.0, 15.0, &map.title, INK);
    let (x0, y0, pw) = (40.0, 34.0, (w - 80) as f64);
    // Extent of the view: the disc, or the flat's points.
    let (umin, umax, vmin, vmax) = match map.disc_radius {
        Some(r) => (-r, r, -r, r),
        None => map.uv.iter().fold(
            (
                f64::INFINITY,
                f64::NEG_INFINITY,
                f64::INFINITY,
                f64::NEG_INFINITY,
            ),
            |(a, b, cc, d), p| (a.min(p[0]), b.max(p[0]), cc.min(p[1]), d.max(p[1])),
        ),
    };
    let span = (umax - umin).max(vmax - vmin).max(1e-9);
    let scale = pw.min(plot_h as f64 - 10.0) / span;
    let cx = x0 + 0.5 * pw - 0.5 * (umax + umin) * scale;
    let cy = y0 + 0.5 * (plot_h as f64 - 10.0) + 0.5 * (vmax + vmin) * scale;
    if let Some(r) = map.disc_radius {
        c.circle((cx, cy), r * scale, GREY, 1);
    }
    let dot = if map.uv.len() > 20_000 { 1 } else { 2 };
    for (p, &d) in map.uv.iter().zip(&map.residual) {
        let x = (cx + p[0] * scale).round() as i64;
        let y = (cy - p[1] * scale).round() as i64;
        c.fill(x, y, dot, dot, deviation_colour(d, map.scale));
    }
    // Colour bar: −2 … +2 × scale.
    let (bx, by, bw) = (40.0, (y0 as usize + plot_h + 8) as f64, (w - 80) as f64);
    for i in 0..bw as i64 {
        let t = (i as f64 / bw - 0.5) * 4.0 * map.scale;
        c.fill(
            bx as i64 + i,
            by as i64,
            1,
            14,
            deviation_colour(t, map.scale),
        );
    }
    for k in -2..=2 {
        let x = bx + (f64::from(k) + 2.0) / 4.0 * bw;
        c.text_centred(
            x,
            by + 18.0,
            12.0,
            &format!("{:+.3}", f64::from(k) * map.scale),
            INK,
        );
    }
    c.text(
        12.0,
        by + 40.0,
        12.0,
        "residual, mm (green: within half the MPE)",
        INK,
    );
    save_rgb_png(&dir.join(&map.file), w as u32, h as u32, &c.rgb)
}

fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

fn status_word(s: Status) -> &'static str {
    match s {
        Status::Pass => "PASS",
        Status::Fail => "FAIL",
        Status::NotMeasured => "NOT MEASURED",
    }
}

fn status_key(s: Status) -> &'static str {
    match s {
        Status::Pass => "pass",
        Status::Fail => "fail",
        Status::NotMeasured => "not_measured",
    }
}

fn css_colour(s: Status) -> String {
    let [r, g, b] = verdict_colour(status_key(s));
    format!("rgb({r},{g},{b})")
}

fn mm(v: Option<f64>) -> String {
    v.map(|v| format!("{v:.4}")).unwrap_or_else(|| "—".into())
}

fn rows(out: &mut String, title: &str, symbol: &str, figures: &[Figure]) {
    if figures.is_empty() {
        return;
    }
    let _ = write!(
        out,
        "<h2>{title} ({symbol})</h2><table><tr><th>position</th><th>cloud</th><th>where</th>\
         <th>measured</th><th>calibrated</th><th>{symbol}</th><th>MPE</th><th>points</th>\
         <th>left out</th><th>result</th></tr>"
    );
    for f in figures {
        let place = match (&f.position.in_volume, &f.position.along) {
            (Some(u), Some(a)) => format!("({:.2}, {:.2}, {:.2}) along {}", u[0], u[1], u[2], a),
            (Some(u), None) => format!("({:.2}, {:.2}, {:.2})", u[0], u[1], u[2]),
            (None, _) => f
                .position
                .centre
                .map(|c| format!("at ({:.0}, {:.0}, {:.0}) mm", c[0], c[1], c[2]))
                .unwrap_or_else(|| "—".into()),
        };
        let result = match &f.reason {
            Some(r) => format!("NOT MEASURED: {}", escape(r)),
            None => status_word(f.status).to_string(),
        };
        let map = f
            .map
            .as_deref()
            .map(|m| format!(" <a href=\"#{0}\">map</a>", escape(m)))
            .unwrap_or_default();
        let _ = write!(
            out,
            "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{:.4}</td><td>{}</td>\
             <td>{:.4}</td><td>{}</td><td>{}</td><td style=\"color:{}\">{}{}</td></tr>",
            escape(&f.position.label),
            escape(&f.cloud),
            escape(&place),
            mm(f.measured),
            f.calibrated,
            mm(f.error),
            f.mpe,
            f.points,
            f.left_out,
            css_colour(f.status),
            result,
            map
        );
    }
    out.push_str("</table>");
}

/// The one-page certificate: the system, the artefacts and their calibration, every position
/// with its figures against the MPE, the residual maps (files beside the page) and the
/// verdict.
pub fn certificate_html(cert: &Certificate) -> String {
    certificate_page(cert, &|file| file.to_string())
}

/// [`certificate_html`] with each residual map's image source given by `src` (its file
/// name → a path or a `data:` URI, for a page that travels alone).
pub fn certificate_page(cert: &Certificate, src: &dyn Fn(&str) -> String) -> String {
    let mut o = String::new();
    let name = if cert.system.name.is_empty() {
        "optical 3D measuring system".to_string()
    } else {
        cert.system.name.clone()
    };
    let _ = write!(
        o,
        "<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\">\
         <title>Verification of {n}</title><style>\
         body{{font-family:sans-serif;margin:1.5em;color:#111}}\
         table{{border-collapse:collapse;margin:.5em 0 1em}}\
         td,th{{border:1px solid #bbb;padding:2px 6px;font-size:12px;text-align:left}}\
         .verdict{{font-size:28px;font-weight:bold;color:#fff;padding:8px 14px;display:inline-block}}\
         img{{width:240px;margin:4px;border:1px solid #ddd}}\
         @media print{{img{{width:180px}}}}</style></head><body>\
         <h1>Verification of {n}</h1>\
         <p>VDI/VDE 2634 Part 2 (ISO 10360-13): probing error form PF and size PS, \
         sphere-spacing error SD, flatness measurement error F. Evaluated {t}. \
         At most 0.3 % of each artefact's points left out.</p>\
         <div class=\"verdict\" id=\"verdict\" style=\"background:{vc}\">{v}</div>\
         <p><b>{kind}</b>{cov}</p>",
        n = escape(&name),
        t = escape(&cert.time),
        vc = css_colour(cert.verdict),
        v = status_word(cert.verdict),
        kind = escape(&cert.coverage.kind),
        cov = if cert.coverage.missing.is_empty() {
            ": the positions cover the calibrated volume as the guideline recommends.".to_string()
        } else {
            format!(
                ": {}",
                cert.coverage
                    .missing
                    .iter()
                    .map(|m| escape(m))
                    .collect::<Vec<_>>()
                    .join("; ")
            )
        }
    );
    o.push_str("<h2>Artefacts and limits</h2><table><tr><th>artefact</th><th>calibrated</th></tr>");
    let a = &cert.artefacts;
    if let Some(b) = &a.ball_bar {
        let _ = write!(
            o,
            "<tr><td>ball bar</td><td>spheres Ø {} mm and Ø {} mm, centres {} mm apart</td></tr>",
            b.diameter_a, b.diameter_b, b.spacing
        );
    }
    if let Some(s) = &a.sphere {
        let _ = write!(
            o,
            "<tr><td>sphere</td><td>Ø {} mm, form {} mm</td></tr>",
            s.diameter, s.form
        );
    }
    if let Some(p) = &a.plane {
        let _ = write!(
            o,
            "<tr><td>flat</td><td>{} x {} mm, flatness {} mm</td></tr>",
            p.length, p.width, p.flatness
        );
    }
    if !cert.system.calibration.is_empty() {
        let _ = write!(
            o,
            "<tr><td>calibration</td><td>{}</td></tr>",
            escape(&cert.system.calibration)
        );
    }
    let m = &a.mpe;
    let sd = match m.sphere_spacing {
        super::SpacingMpe::Constant(v) => format!("{v} mm"),
        super::SpacingMpe::LengthDependent { a, b } => format!("{a} mm + L / {b}"),
    };
    let _ = write!(
        o,
        "<tr><td>MPE</td><td>PF {} mm, PS ±{} mm, SD ±{}, F {} mm</td></tr>",
        m.probing_form,
        m.probing_size,
        escape(&sd),
        m.flatness
    );
    if let Some(v) = &a.volume {
        let _ = write!(
            o,
            "<tr><td>calibrated volume</td><td>({:.0}, {:.0}, {:.0}) … ({:.0}, {:.0}, {:.0}) mm, \
             diagonal L0 {:.0} mm; positions below are given in it from 0 to 1 per axis</td></tr>",
            v.min[0],
            v.min[1],
            v.min[2],
            v.max[0],
            v.max[1],
            v.max[2],
            v.diagonal()
        );
    }
    o.push_str("</table>");
    rows(&mut o, "Sphere-spacing error", "SD", &cert.sphere_spacing);
    rows(&mut o, "Flatness measurement error", "F", &cert.flatness);
    rows(&mut o, "Probing error form", "PF", &cert.probing_form);
    rows(&mut o, "Probing error size", "PS", &cert.probing_size);
    let mut maps: Vec<&str> = cert.figures().filter_map(|f| f.map.as_deref()).collect();
    maps.dedup();
    if !maps.is_empty() {
        o.push_str("<h2>Residual maps</h2><div>");
        for m in maps {
            let mut files = vec![m.to_string()];
            if let Some(b) = m.strip_suffix("-a.png") {
                files.push(format!("{b}-b.png"));
            }
            for (k, file) in files.iter().enumerate() {
                // The figure's link lands on its first map.
                let id = if k == 0 { m } else { file.as_str() };
                let _ = write!(
                    o,
                    "<img id=\"{}\" src=\"{}\" alt=\"{}\">",
                    escape(id),
                    escape(&src(file)),
                    escape(file)
                );
            }
        }
        o.push_str("</div>");
    }
    o.push_str("</body></html>\n");
    o
}
