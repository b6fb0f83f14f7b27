//! Inspection outputs: `deviation.ply` (points in the CAD frame with a `deviation` property)
//! and `deviation.png`, a deviation map a quality engineer reads without the JSON: title with
//! part, scan, time and the verdict in colour; statistics; the map seen along the part's
//! thinnest principal axis with a millimetre scale, each datum circled with its residual and
//! each out-of-tolerance region flagged with its peak and a leader line; a colour bar ticked in
//! mm with the tolerance band marked; a logarithmic histogram with labelled axes and the
//! tolerance lines.

use std::path::Path;

use crate::decode::hue_to_rgb;
use crate::image::save_rgb_png;
use crate::io::write_atomic;
use crate::Result;

use super::canvas::{BoxStyle, Canvas, Label};
use super::{Datum, Report};

/// Binary little-endian PLY: x y z deviation (float32), atomically.
pub fn write_deviation_ply(path: &Path, points: &[[f64; 3]], deviations: &[f64]) -> Result<()> {
    let header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment RIS inspection: points in the CAD frame, signed deviation in mm\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nproperty float deviation\nend_header\n",
        points.len()
    );
    let mut buf = Vec::with_capacity(header.len() + points.len() * 16);
    buf.extend_from_slice(header.as_bytes());
    for (p, d) in points.iter().zip(deviations) {
        for v in [p[0] as f32, p[1] as f32, p[2] as f32, *d as f32] {
            buf.extend_from_slice(&v.to_le_bytes());
        }
    }
    write_atomic(path, &buf)
}

/// Colour of deviation `d` for tolerance `tol`: within tolerance green at the nominal turning
/// olive towards +tol and teal towards −tol; cyan → blue below (missing material), yellow → red
/// above (excess), saturating at ±2 tolerances (SPEC §2).
pub fn deviation_colour(d: f64, tol: f64) -> [u8; 3] {
    if !d.is_finite() {
        return [40, 40, 40];
    }
    let t = (d / tol).clamp(-2.0, 2.0);
    if t.abs() <= 1.0 {
        // Within tolerance, a scale of its own, so variation inside the band shows: bright
        // green at the nominal, turning olive towards +tol and teal towards −tol (the colours
        // past the limits, yellow and cyan, are brighter and set the limit apart).
        let (up, down) = (t.max(0.0), (-t).max(0.0));
        return [
            (60.0 + 130.0 * up) as u8,
            (230.0 - 40.0 * t.abs()) as u8,
            (60.0 + 130.0 * down) as u8,
        ];
    }
    // Out of tolerance: hue from yellow (t = 1) to red (t = 2), or cyan (−1) to blue (−2).
    let s = (t.abs() - 1.0) as f32;
    if t > 0.0 {
        [255, (220.0 * (1.0 - s)) as u8, 0]
    } else {
        let c = hue_to_rgb(0.25 * (1.0 - s), 1.0);
        [c[0], c[1], c[2].max(200)]
    }
}

/// What the map's title names.
#[derive(Clone, Debug, Default)]
pub struct MapTitle {
    /// Part (id or CAD file).
    pub part: String,
    /// Scan id (or the cloud's file).
    pub scan: String,
    /// When, as people read it (UTC).
    pub time: String,
}

/// A rendered deviation map: RGB pixels and every label drawn on it.
pub struct DeviationMap {
    /// Width, px.
    pub width: usize,
    /// Height, px.
    pub height: usize,
    /// RGB, row-major.
    pub rgb: Vec<u8>,
    /// The texts drawn and their boxes.
    pub labels: Vec<Label>,
}

impl DeviationMap {
    /// Whether `label`'s box shows exactly its text as rendered alone on `background` (nothing
    /// drawn over it, nothing missing).
    pub fn shows(&self, label: &Label, background: [u8; 3]) -> bool {
        let alone = Canvas::render_alone(label, background);
        let mut ink = 0;
        for y in 0..alone.height as i64 {
            for x in 0..alone.width as i64 {
                let (px, py) = (label.x + x, label.y + y);
                if px < 0 || py < 0 || px as usize >= self.width || py as usize >= self.height {
                    return false;
                }
                let i = (py as usize * self.width + px as usize) * 3;
                let want = alone.get(x, y).unwrap_or(background);
                if want != background {
                    ink += 1;
                }
                if (0..3).any(|k| self.rgb[i + k].abs_diff(want[k]) > 1) {
                    return false;
                }
            }
        }
        ink > 0
    }
}

const WHITE: [u8; 3] = [255, 255, 255];
const BLACK: [u8; 3] = [0, 0, 0];
const GREY: [u8; 3] = [90, 90, 90];

/// The colour a verdict is shown in.
pub fn verdict_colour(verdict: &str) -> [u8; 3] {
    match verdict {
        "pass" => [0, 140, 60],
        "fail" => [200, 30, 30],
        _ => [200, 120, 0],
    }
}

/// Decimals that tell ±2 tolerances, ±1 and 0 apart.
fn decimals(tol: f64) -> usize {
    (2.0 - tol.log10().floor()).clamp(1.0, 4.0) as usize
}

/// A round length near `target` (1, 2 or 5 × 10ⁿ).
fn round_length(target: f64) -> f64 {
    let e = 10f64.powf(target.max(1e-9).log10().floor());
    [5.0, 2.0, 1.0]
        .iter()
        .map(|m| m * e)
        .find(|l| *l <= target)
        .unwrap_or(e)
}

/// A marker's label on the map: what it says, where it points, its border and font size.
struct Flag {
    anchor: (f64, f64),
    radius: f64,
    text: String,
    border: [u8; 3],
    size: f32,
}

/// Top-left corner for a `size` box labelling `anchor`: the nearest of a ring of positions
/// around it, `gap` away or further, that stays within `bounds` (x0, y0, x1, y1) and overlaps
/// no box in `taken`; the first candidate, clamped, when none is free.
fn place(
    anchor: (f64, f64),
    gap: f64,
    size: (f64, f64),
    bounds: (f64, f64, f64, f64),
    taken: &[(f64, f64, f64, f64)],
) -> (f64, f64) {
    let (w, h) = size;
    let clamp = |x: f64, y: f64| {
        (
            x.clamp(bounds.0 + 2.0, (bounds.2 - w - 2.0).max(bounds.0 + 2.0)),
            y.clamp(bounds.1 + 2.0, (bounds.3 - h - 2.0).max(bounds.1 + 2.0)),
        )
    };
    let free = |x: f64, y: f64| {
        taken.iter().all(|t| {
            x + w + 3.0 < t.0 || t.0 + t.2 + 3.0 < x || y + h + 3.0 < t.1 || t.1 + t.3 + 3.0 < y
        })
    };
    let mut first = None;
    for extra in [0.0, 20.0, 45.0, 80.0, 130.0, 200.0] {
        let d = gap + extra;
        for (sx, sy) in [
            (1.0, -1.0),
            (1.0, 1.0),
            (-1.0, -1.0),
            (-1.0, 1.0),
            (1.0, 0.0),
            (-1.0, 0.0),
        ] {
            let x = if sx > 0.0 {
                anchor.0 + d * 0.7
            } else {
                anchor.0 - d * 0.7 - w
            };
            let y = match sy {
                s if s > 0.0 => anchor.1 + d * 0.7,
                s if s < 0.0 => anchor.1 - d * 0.7 - h,
                _ => anchor.1 - h / 2.0,
            };
            let (x, y) = clamp(x, y);
            first.get_or_insert((x, y));
            if free(x, y) {
                return (x, y);
            }
        }
    }
    first.unwrap_or(anchor)
}

/// Render the labelled deviation map of an inspection.
pub fn render_deviation_map(
    points: &[[f64; 3]],
    deviations: &[f64],
    report: &Report,
    datums: &[Datum],
    title: &MapTitle,
) -> DeviationMap {
    let tol = report.tolerance_mm;
    let dec = decimals(tol);
    // View along the thinnest principal axis of the points.
    let n = points.len().max(1) as f64;
    let mut c = [0.0; 3];
    for p in points {
        for k in 0..3 {
            c[k] += p[k] / n;
        }
    }
    let mut cov = nalgebra::Matrix3::<f64>::zeros();
    for p in points {
        let d = nalgebra::Vector3::new(p[0] - c[0], p[1] - c[1], p[2] - c[2]);
        cov += d * d.transpose();
    }
    let e = cov.symmetric_eigen();
    let mut idx = [0usize, 1, 2];
    idx.sort_by(|&i, &j| e.eigenvalues[j].total_cmp(&e.eigenvalues[i]));
    let (ax, mut ay) = (
        e.eigenvectors.column(idx[0]).into_owned(),
        e.eigenvectors.column(idx[1]).into_owned(),
    );
    // Screen right is `ax`, up is `ay`, so `ax × ay` points at the viewer: seen from the side
    // its largest component is positive (a panel modelled z-up is seen from above), unmirrored.
    let mut view = ax.cross(&ay);
    if view.iamax() < 3 && view[view.iamax()] < 0.0 {
        ay = -ay;
        view = -view;
    }
    let project = |p: &[f64; 3]| {
        let d = nalgebra::Vector3::new(p[0] - c[0], p[1] - c[1], p[2] - c[2]);
        (d.dot(&ax), -d.dot(&ay))
    };
    let uv: Vec<(f64, f64)> = points.iter().map(project).collect();
    let (mut u0, mut u1, mut v0, mut v1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for &(u, v) in &uv {
        u0 = u0.min(u);
        u1 = u1.max(u);
        v0 = v0.min(v);
        v1 = v1.max(v);
    }
    if uv.is_empty() {
        (u0, u1, v0, v1) = (0.0, 1.0, 0.0, 1.0);
    }
    // The map is 560–1100 px wide; points are drawn as squares as large as their spacing.
    let (du, dv) = ((u1 - u0).max(1e-9), (v1 - v0).max(1e-9));
    let spacing = (du * dv / n).sqrt();
    // At most 1400 px tall whatever the part's outline.
    let px = (spacing * 1.3)
        .max(du / 1100.0)
        .min(du / 560.0)
        .max(dv / 1400.0)
        .max(1e-9);
    let dot = ((spacing * 1.3 / px).ceil() as i64).clamp(1, 6);
    let (mw, mh) = ((du / px) as i64 + 1, (dv / px) as i64 + 1);
    let pad = 24i64;
    let header = 96i64;
    let bar_w = 26i64;
    let bar_h = mh.max(260);
    let side = 150i64;
    let hist_w = mw.max(480);
    let hist_h = 170i64;
    let width = (pad + mw.max(hist_w) + 2 * pad + bar_w + side) as usize;
    let map_y = header + 10;
    let scale_y = map_y + bar_h.max(mh) + 14;
    let hist_y = scale_y + 60;
    let height = (hist_y + hist_h + 64) as usize;
    let mut cv = Canvas::new(width, height, WHITE);

    // Title, verdict, statistics.
    let verdict = report.verdict.as_str();
    let shown = match verdict {
        "pass" => "PASS",
        "fail" => "FAIL",
        _ => "NOT MEASURED",
    };
    let vsize = 34.0;
    let vw = Canvas::text_width(shown, vsize);
    let vx = width as f64 - pad as f64 - vw - 18.0;
    cv.boxed_text(
        vx,
        14.0,
        vsize,
        shown,
        BoxStyle {
            ink: WHITE,
            fill: verdict_colour(verdict),
            border: verdict_colour(verdict),
        },
    );
    cv.text(pad as f64, 12.0, 24.0, &title.part, BLACK);
    let sub = format!("scan {}   {}", title.scan, title.time);
    cv.text(pad as f64, 42.0, 15.0, &sub, GREY);
    let s = &report.statistics;
    let stats = format!(
        "mean {:+.dec$}  RMS {:.dec$}  range {:+.dec$} to {:+.dec$} mm   within ±{} mm: {:.1} %   {} points",
        s.mean,
        s.rms,
        s.min,
        s.max,
        tol,
        100.0 * s.within_tolerance,
        s.points
    );
    cv.text(pad as f64, 66.0, 15.0, &stats, BLACK);

    // The map.
    let to_px = |u: f64, v: f64| (pad as f64 + (u - u0) / px, map_y as f64 + (v - v0) / px);
    for (&(u, v), &d) in uv.iter().zip(deviations) {
        let (x, y) = to_px(u, v);
        cv.fill(
            x as i64 - dot / 2,
            y as i64 - dot / 2,
            dot,
            dot,
            deviation_colour(d, tol),
        );
    }
    cv.frame(pad - 1, map_y - 1, mw + 2, mh + 2, [200, 200, 200]);
    // Datums circled at their nominal position and named with their residual; regions out of
    // tolerance marked and flagged with their peak. Markers first, then leader lines, then the
    // labels, each placed inside the map where it covers no other label.
    let mut flags: Vec<Flag> = Vec::new();
    for (i, d) in datums.iter().enumerate() {
        let (u, v) = project(&d.position);
        let (x, y) = to_px(u, v);
        let r = (d.radius / px).max(6.0);
        cv.circle((x, y), r, BLACK, 2);
        let residual = report.datums.get(i).map(|r| match &r.frame {
            Some(m) if m.error.is_some() => "not measured".to_string(),
            Some(m) if !m.offset_mm.is_empty() => format!(
                "{:.dec$} mm",
                m.offset_mm.iter().map(|o| o * o).sum::<f64>().sqrt()
            ),
            _ => format!("RMS {:.dec$} mm", r.rms),
        });
        let text = match residual {
            Some(res) => format!("{} {res}", d.name),
            None => d.name.clone(),
        };
        flags.push(Flag {
            anchor: (x, y),
            radius: r,
            text,
            border: BLACK,
            size: 13.0,
        });
    }
    for (i, g) in report.regions_out_of_tolerance.iter().take(8).enumerate() {
        let (u, v) = project(&g.centroid);
        let (x, y) = to_px(u, v);
        cv.circle((x, y), 6.0, BLACK, 2);
        // numbered as in the report's reasons and the page's table
        let text = format!("{}: {:+.dec$} mm", i + 1, g.peak_deviation_mm);
        flags.push(Flag {
            anchor: (x, y),
            radius: 6.0,
            text,
            border: deviation_colour(g.peak_deviation_mm, tol),
            size: 15.0,
        });
    }
    let bounds = (
        pad as f64,
        map_y as f64,
        (pad + mw) as f64,
        (map_y + mh) as f64,
    );
    let mut taken: Vec<(f64, f64, f64, f64)> = Vec::new();
    let mut placed = Vec::new();
    for f in &flags {
        let padding = (f.size / 4.0).ceil() as f64;
        let (w, h) = (
            Canvas::text_width(&f.text, f.size).ceil() + 2.0 * padding,
            f64::from(f.size.ceil()) + 2.0 * padding,
        );
        let at = place(f.anchor, f.radius + 12.0, (w, h), bounds, &taken);
        taken.push((at.0, at.1, w, h));
        placed.push((at, w, h));
    }
    for (f, (at, w, h)) in flags.iter().zip(&placed) {
        // From the marker's edge to the nearest point of the label's box.
        let (a, r) = (f.anchor, f.radius);
        let near = (a.0.clamp(at.0, at.0 + w), a.1.clamp(at.1, at.1 + h));
        let (dx, dy) = (near.0 - a.0, near.1 - a.1);
        let dist = dx.hypot(dy);
        if dist > r + 2.0 {
            let from = (a.0 + dx / dist * r, a.1 + dy / dist * r);
            cv.line(from, near, BLACK, 2, 0);
        }
    }
    for (f, (at, _, _)) in flags.iter().zip(&placed) {
        let style = BoxStyle {
            ink: BLACK,
            fill: WHITE,
            border: f.border,
        };
        cv.boxed_text(at.0, at.1, f.size, &f.text, style);
    }
    // Scale bar and view direction under the map.
    let len = round_length(0.25 * du);
    let lpx = len / px;
    cv.fill(pad, scale_y, lpx.round() as i64, 4, BLACK);
    cv.fill(pad, scale_y - 4, 2, 12, BLACK);
    cv.fill(pad + lpx.round() as i64 - 2, scale_y - 4, 2, 12, BLACK);
    cv.text(
        pad as f64,
        (scale_y + 10) as f64,
        14.0,
        &format!("{len} mm"),
        BLACK,
    );
    let caption = format!(
        "seen from ({:+.2}, {:+.2}, {:+.2}) in the CAD frame",
        view.x, view.y, view.z
    );
    cv.text(
        (pad as f64 + lpx + 30.0).max(pad as f64 + 120.0),
        (scale_y + 10) as f64,
        14.0,
        &caption,
        GREY,
    );

    // Colour bar, +2 tolerances at the top, with mm ticks and the tolerance band.
    let bx = pad + mw.max(hist_w) + 2 * pad;
    let by = map_y;
    cv.text(
        bx as f64 - 4.0,
        (by - 34) as f64,
        14.0,
        "deviation, mm",
        BLACK,
    );
    for y in 0..bar_h {
        let d = (2.0 - 4.0 * y as f64 / (bar_h - 1).max(1) as f64) * tol;
        cv.fill(bx, by + y, bar_w, 1, deviation_colour(d, tol));
    }
    cv.frame(bx - 1, by - 1, bar_w + 2, bar_h + 2, BLACK);
    let bar_y = |d: f64| by as f64 + (2.0 - d / tol) / 4.0 * (bar_h - 1) as f64;
    for m in [2.0, 1.0, 0.0, -1.0, -2.0] {
        let y = bar_y(m * tol);
        let strong = m.abs() == 1.0;
        cv.fill(
            bx + bar_w,
            y.round() as i64,
            if strong { 14 } else { 8 },
            2,
            BLACK,
        );
        let text = if m == 0.0 {
            "0".to_string()
        } else {
            format!("{:+.dec$}", m * tol)
        };
        cv.text((bx + bar_w + 18) as f64, y - 8.0, 15.0, &text, BLACK);
    }
    // The tolerance band: a bracket left of the bar from −tol to +tol.
    let (t0, t1) = (bar_y(tol), bar_y(-tol));
    cv.fill(
        bx - 10,
        t0.round() as i64,
        2,
        (t1 - t0).round() as i64,
        BLACK,
    );
    cv.fill(bx - 10, t0.round() as i64, 8, 2, BLACK);
    cv.fill(bx - 10, t1.round() as i64, 8, 2, BLACK);
    cv.text(
        (bx + bar_w + 18) as f64,
        (t0 + t1) / 2.0 - 26.0,
        13.0,
        "tolerance",
        GREY,
    );
    cv.text(
        (bx + bar_w + 18) as f64,
        (t0 + t1) / 2.0 + 14.0,
        13.0,
        &format!("± {tol} mm"),
        GREY,
    );

    // Histogram over ±2 tolerances (80 bins), logarithmic so the tails show.
    let bins = 80usize;
    let mut counts = vec![0usize; bins];
    for d in deviations.iter().filter(|d| d.is_finite()) {
        let b = (((d / tol).clamp(-2.0, 2.0) + 2.0) / 4.0 * bins as f64) as usize;
        counts[b.min(bins - 1)] += 1;
    }
    let most = counts.iter().copied().max().unwrap_or(0).max(1);
    let peak = (most as f64).ln_1p();
    let hx = pad + 40;
    let hw = hist_w - 40;
    let bin_w = hw as f64 / bins as f64;
    for (b, &cnt) in counts.iter().enumerate() {
        let bar = ((cnt as f64).ln_1p() / peak * hist_h as f64) as i64;
        let d = (-2.0 + 4.0 * (b as f64 + 0.5) / bins as f64) * tol;
        let x0 = hx + (b as f64 * bin_w) as i64;
        let x1 = hx + ((b + 1) as f64 * bin_w) as i64 - 1;
        cv.fill(
            x0,
            hist_y + hist_h - bar,
            (x1 - x0).max(1),
            bar,
            deviation_colour(d, tol),
        );
    }
    cv.fill(hx, hist_y + hist_h, hw, 2, BLACK);
    cv.fill(hx - 2, hist_y, 2, hist_h + 2, BLACK);
    let hist_x = |d: f64| hx as f64 + (d / tol + 2.0) / 4.0 * hw as f64;
    for m in [-2.0, -1.0, 0.0, 1.0, 2.0] {
        let x = hist_x(m * tol);
        cv.fill(x.round() as i64, hist_y + hist_h, 2, 6, BLACK);
        let text = if m == 0.0 {
            "0".to_string()
        } else {
            format!("{:+.dec$}", m * tol)
        };
        cv.text_centred(x, (hist_y + hist_h + 8) as f64, 14.0, &text, BLACK);
        if m == 1.0 || m == -1.0 {
            cv.line(
                (x, hist_y as f64),
                (x, (hist_y + hist_h) as f64),
                BLACK,
                2,
                6,
            );
        }
    }
    cv.text_centred(
        hx as f64 + hw as f64 / 2.0,
        (hist_y + hist_h + 30) as f64,
        14.0,
        "deviation, mm (tolerance dashed)",
        BLACK,
    );
    cv.text(
        hx as f64 + 6.0,
        (hist_y - 20) as f64,
        14.0,
        &format!("points (log scale, most {most} per bin)"),
        BLACK,
    );
    DeviationMap {
        width,
        height,
        rgb: cv.rgb,
        labels: cv.labels,
    }
}

/// Render the labelled deviation map (see [`render_deviation_map`]) to a PNG, atomically.
pub fn write_deviation_png(
    path: &Path,
    points: &[[f64; 3]],
    deviations: &[f64],
    report: &Report,
    datums: &[Datum],
    title: &MapTitle,
) -> Result<()> {
    let map = render_deviation_map(points, deviations, report, datums, title);
    save_rgb_png(path, map.width as u32, map.height as u32, &map.rgb)
}
