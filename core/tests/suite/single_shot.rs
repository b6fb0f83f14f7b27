//! Single-shot decoding against the simulator's truth: the X-point pattern projected on seeded
//! variations of the demo scene (boxes with steps, a sphere, a dome, a cylinder; shadows,
//! occlusions and the pattern falling off the objects; sensor noise), at steps of 12–16
//! projector pixels and, with the detector set for the spacing, 9–12. Every decoded X-point must be the primitive that truly lights that camera
//! point, and nearly every primitive the camera sees whole must be decoded.

use std::path::Path;

use ris_core::geometry::Vec3;
use ris_core::pattern::{Pattern, ProjectionMask};
use ris_core::sensor::Reconstructor;
use ris_core::sim::{Scene, SceneFile, Simulator};
use ris_core::single_shot::{
    camera_spacing, decode_frame, reconstruct, DenseRegion, DetectParams, Detector, Lattice,
    ReferencePrediction, XPointPattern,
};

use crate::common;
use common::{seeds, Rng};

fn demo_file() -> SceneFile {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/scenes/demo.toml");
    toml::from_str(&std::fs::read_to_string(path).expect("read")).expect("parse")
}

/// What one seeded case measured.
struct Outcome {
    visible: usize,
    decoded_visible: usize,
    decoded: usize,
    wrong: usize,
    at_edges: usize,
    points: usize,
    mean_mm: f64,
    far: usize,
    /// Of those, points flagged as beside a missing neighbour (halved confidence).
    far_flagged: usize,
    measured: usize,
    mean_px: f64,
    /// Per primitive: seen whole by the camera, and decoded.
    seen: Vec<bool>,
    found: Vec<bool>,
}

impl Outcome {
    /// One line of what was decoded and measured, the same for both families.
    fn summary(&self) -> String {
        format!(
            "{} of {} visible primitives decoded ({:.1} %), {} decoded in all, {} wrong, {} at depth edges, mean {:.3} px; {} points, mean |3D error| {:.3} mm over {}, {} beyond 2 mm ({} flagged)",
            self.decoded_visible,
            self.visible,
            100.0 * self.rate(),
            self.decoded,
            self.wrong,
            self.at_edges,
            self.mean_px,
            self.points,
            self.mean_mm,
            self.measured,
            self.far,
            self.far_flagged
        )
    }

    /// The share of the primitives the camera sees that were decoded.
    fn rate(&self) -> f64 {
        self.decoded_visible as f64 / self.visible.max(1) as f64
    }

    /// What every family asserts of decoding: enough primitives in view, at least `rate` of
    /// them decoded, ≤ 0.1 % placed wrong, and at most `far_share` of the points beyond 2 mm.
    fn assert_decoding(&self, label: &str, rate: f64, far_share: f64) {
        assert!(self.visible > 1000, "{label}: {} visible", self.visible);
        assert!(
            self.rate() >= rate,
            "{label}: {:.1} % decoded",
            100.0 * self.rate()
        );
        assert!(
            (self.wrong as f64) <= 0.001 * self.decoded as f64,
            "{label}: {} of {} wrong",
            self.wrong,
            self.decoded
        );
        assert!(
            (self.far as f64) <= far_share * self.measured as f64,
            "{label}: {} of {} beyond 2 mm",
            self.far,
            self.measured
        );
    }
}

fn run(file: SceneFile, step: [u32; 2], seed: u64) -> Outcome {
    run_dense(file, step, &[], seed)
}

/// As [`run`], the pattern finer over `dense`.
fn run_dense(file: SceneFile, step: [u32; 2], dense: &[DenseRegion], seed: u64) -> Outcome {
    let scene = Scene::from_file(file, Path::new("."), "single-shot").expect("scene");
    let sim = Simulator::new(scene.clone());
    let (pw, ph) = (scene.projector.width, scene.projector.height);
    let pattern = XPointPattern::with_dense(pw, ph, step, dense, 3, seed).expect("pattern");
    let mask = ProjectionMask {
        width: pw,
        height: ph,
        values: pattern
            .render()
            .into_iter()
            .map(|v| f32::from(v) / 255.0)
            .collect(),
    };
    let img = sim.frame_with(&sim.layout(), Pattern::White, Some(&mask), 1.0, seed);
    let (w, h) = (img.width as usize, img.height as usize);
    // The Gray-code reference (the bare plane, decoded) predicts each camera point's projector
    // position and gives the parallax model, as a sensor file's [reference] does; the detector
    // is set for the X-points' spacing in the camera, as risd sets it.
    let layout = sim.layout();
    let dec_ref = ris_core::decode::decode(
        &Simulator::new(scene.reference()).capture(&layout, 1000 + seed, &|_, _| {}),
        &ris_core::decode::DecodeParams::default(),
    )
    .expect("reference");
    let spacing = camera_spacing(&dec_ref, pattern.finest_step()).expect("spacing");
    let params = DetectParams::for_spacing(spacing);
    eprintln!(
        "spacing {spacing:.1?} px: radius {:.2} sigma {:.2}",
        params.radius, params.sigma
    );
    let reference = ReferencePrediction::new(&dec_ref).expect("row codes");
    let predict = |x: f64, y: f64| reference.at(x, y);
    let (found, matches, stats) =
        decode_frame(&mut Detector::new(params), &img, &pattern, Some(&predict));
    let rec = Reconstructor::parallax(&scene.camera, scene.projector.center(), &dec_ref)
        .expect("parallax model");
    let cloud = reconstruct(&matches, &rec);
    let t = &sim.cache.truth;
    let truth = Truth {
        width: w,
        height: h,
        xyz: t.xyz.clone(),
        projector: t
            .xyz
            .iter()
            .map(|p| {
                if !p[0].is_finite() {
                    return None;
                }
                scene.projector.project(&Vec3::new(
                    f64::from(p[0]),
                    f64::from(p[1]),
                    f64::from(p[2]),
                ))
            })
            .collect(),
        lit: t.lit.iter().map(|&l| l >= 0.999).collect(),
    };
    evaluate(
        &truth,
        &pattern,
        &found,
        &matches,
        &stats,
        &rec,
        cloud.len(),
    )
}

/// Per camera pixel, what a renderer knows of the scene.
struct Truth {
    width: usize,
    height: usize,
    /// The surface point the pixel's centre sees (sensor frame, mm); NaN where none.
    xyz: Vec<[f32; 3]>,
    /// Where that point lies in the projector, lit or not; `None` outside its image.
    projector: Vec<Option<(f64, f64)>>,
    /// Whether the projector lights the point wholly (not in a shadow).
    lit: Vec<bool>,
}

/// Decoded X-points and their points against the truth.
fn evaluate(
    truth: &Truth,
    pattern: &XPointPattern,
    found: &[ris_core::single_shot::Detection],
    matches: &[ris_core::single_shot::Correspondence],
    stats: &ris_core::single_shot::DecodeStats,
    rec: &Reconstructor,
    points: usize,
) -> Outcome {
    let (w, h) = (truth.width, truth.height);
    // Truth: the projector position of each camera pixel's lit surface point.
    let tp: Vec<Option<(f64, f64)>> = truth
        .projector
        .iter()
        .zip(&truth.lit)
        .map(|(p, &lit)| if lit { *p } else { None })
        .collect();
    let [cols, rows] = pattern.grid();
    let lattice = pattern.lattice();
    let r = pattern.pattern.radius;
    let mut centre_seen = vec![false; cols * rows];
    let mut where_seen = vec![(0.0f64, 0.0f64); cols * rows];
    let mut broken = vec![false; cols * rows];
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            let edge = x < 8 || y < 8 || x + 8 >= w || y + 8 >= h;
            let Some(pos) = tp[i] else {
                // A shadowed pixel breaks the primitive whose light it should have had.
                if let Some(p) = truth.projector[i] {
                    mark(&mut broken, p, &lattice, r + 1.5);
                }
                continue;
            };
            // The image's edge, or the end of the surface beside it (nothing there to light),
            // cuts the primitives about it.
            let void = |j: usize| truth.xyz.get(j).is_some_and(|q| q[0].is_nan());
            if edge || void(i - 1) || void(i + 1) || void(i - w) || void(i + w) {
                mark(&mut broken, pos, &lattice, r + 1.5);
                continue;
            }
            // Seen at a usable size: no camera pixel spans more than 2 projector pixels here
            // (a primitive on a wall seen edge-on is a sliver no decoder can read).
            let grad = |j: usize| {
                tp.get(j)
                    .copied()
                    .flatten()
                    .map(|q| (q.0 - pos.0, q.1 - pos.1))
            };
            let (Some(ju), Some(jv)) = (grad(i + 1), grad(i + w)) else {
                continue;
            };
            let (a, b, c, d) = (ju.0, jv.0, ju.1, jv.1);
            let t = a * a + b * b + c * c + d * d;
            let det = a * d - b * c;
            let smax = (0.5 * (t + (t * t - 4.0 * det * det).max(0.0).sqrt())).sqrt();
            if smax > 2.0 {
                mark(&mut broken, pos, &lattice, 0.75);
                continue;
            }
            mark(&mut centre_seen, pos, &lattice, 0.75);
            let (gi, gj) = lattice.place(pos.0, pos.1);
            let (gi, gj) = (gi.round(), gj.round());
            if gi >= 0.0
                && gj >= 0.0
                && (gi as usize) < cols
                && (gj as usize) < rows
                && (pos.0 - lattice.columns[gi as usize]).hypot(pos.1 - lattice.rows[gj as usize])
                    < 0.75
            {
                where_seen[gj as usize * cols + gi as usize] = (x as f64, y as f64);
            }
        }
    }
    // A primitive is seen whole when its corner is seen, nothing of it is shadowed or cut by
    // the image's edge or the end of the surface, and no depth edge (a jump in the truth
    // between neighbouring pixels) runs through it.
    for y in 1..h {
        for x in 1..w {
            let (a, b, c) = (tp[y * w + x], tp[y * w + x - 1], tp[(y - 1) * w + x]);
            if let (Some(a), Some(b), Some(c)) = (a, b, c) {
                let jump = |p: (f64, f64), q: (f64, f64)| (p.0 - q.0).hypot(p.1 - q.1) > 3.0;
                if jump(a, b) || jump(a, c) {
                    mark(&mut broken, a, &lattice, r + 2.0);
                    mark(
                        &mut broken,
                        if jump(a, b) { b } else { c },
                        &lattice,
                        r + 2.0,
                    );
                }
            }
        }
    }
    let visible: Vec<bool> = centre_seen
        .iter()
        .zip(&broken)
        .map(|(s, b)| *s && !b)
        .collect();

    // 3D: each reconstructed X-point against the surface point its camera ray truly meets.
    let mut mm = Vec::new();
    let mut far_flagged = 0;
    let mut asyms: Vec<f64> = Vec::new();
    for m in matches {
        let (fx, fy) = (m.x.floor() as usize, m.y.floor() as usize);
        let (ax, ay) = (m.x - fx as f64, m.y - fy as f64);
        let mut acc = [0f64; 3];
        let mut wsum = 0.0;
        let mut spread = 0f64;
        let first = truth.xyz[fy * w + fx];
        for (i, wt) in [
            (fy * w + fx, (1.0 - ax) * (1.0 - ay)),
            (fy * w + fx + 1, ax * (1.0 - ay)),
            ((fy + 1) * w + fx, (1.0 - ax) * ay),
            ((fy + 1) * w + fx + 1, ax * ay),
        ] {
            let q = truth.xyz[i];
            if q[0].is_finite() {
                for k in 0..3 {
                    acc[k] += wt * f64::from(q[k]);
                }
                wsum += wt;
                spread = spread.max(f64::from((q[2] - first[2]).abs()));
            }
        }
        // Depth edges: the truth there is no single surface.
        if wsum < 0.999 || spread > 2.0 {
            continue;
        }
        let Some(p) = rec.point_at(m.x, m.y, m.u, m.v) else {
            continue;
        };
        let t = Vec3::new(acc[0] / wsum, acc[1] / wsum, acc[2] / wsum);
        let e = (p - t).norm();
        if e > 2.0 && std::env::var("RIS_DEBUG").is_ok() {
            eprintln!("far: cam ({:.1},{:.1}) proj ({:.1},{:.1}) point {:?} truth {:?} err {e:.2} codeword {} asym {:.3}", m.x, m.y, m.u, m.v, p, t, m.from_codeword, m.asymmetry);
        }
        mm.push(e);
        asyms.push(m.asymmetry);
        if e > 2.0 && m.sides != 0b1111 {
            far_flagged += 1;
        }
    }
    if std::env::var("RIS_DEBUG").is_ok() {
        asyms.sort_by(f64::total_cmp);
        let q = |f: f64| asyms[((asyms.len() - 1) as f64 * f) as usize];
        eprintln!(
            "asymmetry quantiles 50/90/99 %: {:.3} {:.3} {:.3}",
            q(0.5),
            q(0.9),
            q(0.99)
        );
    }
    let mut decoded_visible = 0;
    let mut wrong = 0;
    let mut sum = 0.0;
    let mut bias = (0.0, 0.0);
    let mut at_edges = 0;
    let mut seen_prims = vec![false; cols * rows];
    for m in matches {
        seen_prims[m.primitive] = true;
        // Bilinear truth at the sub-pixel corner.
        let (fx, fy) = (m.x.floor() as usize, m.y.floor() as usize);
        let (ax, ay) = (m.x - fx as f64, m.y - fy as f64);
        let corners = [
            (tp[fy * w + fx], (1.0 - ax) * (1.0 - ay)),
            (tp[fy * w + fx + 1], ax * (1.0 - ay)),
            (tp[(fy + 1) * w + fx], (1.0 - ax) * ay),
            (tp[(fy + 1) * w + fx + 1], ax * ay),
        ];
        let known: Vec<((f64, f64), f64)> = corners
            .iter()
            .filter_map(|(p, wt)| p.map(|p| (p, *wt)))
            .collect();
        let total: f64 = known.iter().map(|(_, wt)| wt).sum();
        if known.is_empty() || total <= 0.0 {
            continue;
        }
        let u = known.iter().map(|(p, wt)| p.0 * wt).sum::<f64>() / total;
        let v = known.iter().map(|(p, wt)| p.1 * wt).sum::<f64>() / total;
        let err = (u - m.u).hypot(v - m.v);
        // At a depth edge the four pixels about the corner see different surfaces and the
        // truth there is no single point: such matches are counted apart.
        let spread = known
            .iter()
            .map(|(p, _)| (p.0 - u).hypot(p.1 - v))
            .fold(0.0, f64::max);
        if err > 3.0 && (known.len() < 4 || spread > 3.0) {
            at_edges += 1;
        } else if err > 3.0 {
            if std::env::var("RIS_DEBUG").is_ok() {
                eprintln!("wrong: cam ({:.1},{:.1}) claimed ({:.1},{:.1}) true ({u:.1},{v:.1}) codeword {}", m.x, m.y, m.u, m.v, m.from_codeword);
            }
            wrong += 1;
        } else {
            sum += err;
            bias.0 += u - m.u;
            bias.1 += v - m.v;
        }
    }
    let mut undetected = 0;
    for (k, v) in visible.iter().enumerate() {
        if *v && seen_prims[k] {
            decoded_visible += 1;
        } else if *v {
            let (x, y) = where_seen[k];
            if !found.iter().any(|d| (d.x - x).hypot(d.y - y) < 2.0) {
                undetected += 1;
                if std::env::var("RIS_DEBUG").is_ok() {
                    eprintln!("undetected: primitive {k} near camera ({x}, {y})");
                }
            }
        }
    }
    eprintln!("visible but not detected: {undetected}");
    let good = (matches.len() - wrong - at_edges).max(1) as f64;
    let seen = visible.clone();
    eprintln!(
        "step {:?}: {} detections, {stats:?}, bias ({:.3}, {:.3}) px",
        pattern.pattern.step,
        found.len(),
        bias.0 / good,
        bias.1 / good
    );
    Outcome {
        visible: visible.iter().filter(|v| **v).count(),
        decoded_visible,
        decoded: matches.len(),
        wrong,
        at_edges,
        mean_px: sum / (matches.len() - wrong - at_edges).max(1) as f64,
        points,
        mean_mm: mm.iter().sum::<f64>() / mm.len().max(1) as f64,
        far: mm.iter().filter(|e| **e > 2.0).count(),
        far_flagged,
        measured: mm.len(),
        seen,
        found: seen_prims,
    }
}

/// Mark the primitives within `reach` projector pixels of `p`.
fn mark(flags: &mut [bool], p: (f64, f64), lattice: &Lattice, reach: f64) {
    let (cols, rows) = (lattice.columns.len(), lattice.rows.len());
    let (gi, gj) = lattice.place(p.0, p.1);
    let (gi, gj) = (gi.round() as i64, gj.round() as i64);
    for j in (gj - 1)..=(gj + 1) {
        for i in (gi - 1)..=(gi + 1) {
            if i < 0 || j < 0 || i as usize >= cols || j as usize >= rows {
                continue;
            }
            let (u, v) = (lattice.columns[i as usize], lattice.rows[j as usize]);
            if (p.0 - u).hypot(p.1 - v) <= reach {
                flags[j as usize * cols + i as usize] = true;
            }
        }
    }
}

#[test]
fn decoded_x_points_are_the_primitives_that_light_them() {
    let mut rng = Rng(5);
    for case in seeds(2, 3) {
        let mut f = demo_file();
        let step = [rng.range(12.0, 16.99) as u32, rng.range(12.0, 16.99) as u32];
        f.camera.noise = rng.range(1.0, 3.0);
        f.render.seed = case + 1;
        let o = run(f, step, 100 + case);
        eprintln!("case {case} step {step:?}: {}", o.summary());
        assert!(
            (o.at_edges as f64) <= 0.005 * o.decoded as f64,
            "case {case}: {} of {} off at depth edges",
            o.at_edges,
            o.decoded
        );
        assert!(o.mean_px < 0.2, "case {case}: mean {:.3} px", o.mean_px);
        assert!(
            o.points + 10 >= o.decoded,
            "case {case}: {} points of {}",
            o.points,
            o.decoded
        );
        // The bound is 0.1 %; beside shadows and the boxes' edges a few corners land
        // 2–3 mm off: the shadow cuts the outer part of their lobes, and what is left is still
        // point-symmetric (a strip), about a centre up to a pixel from the corner. This asserts
        // what is reached today, and that most of them carry the boundary flag.
        assert!(
            2 * o.far_flagged >= o.far,
            "case {case}: {} of {} beyond 2 mm flagged",
            o.far_flagged,
            o.far
        );
        o.assert_decoding(&format!("case {case}"), 0.95, 0.005);
        assert!(o.mean_mm <= 0.3, "case {case}: mean {:.3} mm", o.mean_mm);
    }
}

/// Fine patterns: steps of 9–12 projector pixels, the closest X-points 8.7–10.7 camera pixels
/// apart, with the detector set for that spacing (`DetectParams::for_spacing`, as risd and
/// `ris single-shot` set it). With the earlier default disc of 5 px the steps of 9 decode under
/// 2 % (the disc takes in the neighbours' light), and with the spacing's median instead of its
/// 10th percentile, 57–93 %. The bound is 92 % (93–98 % measured), not the 95 % of the coarser
/// steps.
#[test]
fn fine_patterns_decode_with_the_detector_set_for_their_spacing() {
    let mut rng = Rng(23);
    for case in seeds(2, 3) {
        let mut f = demo_file();
        let s = rng.range(9.0, 11.99) as u32;
        let step = [s, s + rng.range(0.0, 1.99) as u32];
        f.camera.noise = rng.range(1.0, 3.0);
        f.render.seed = case + 7;
        let o = run(f, step, 200 + case);
        eprintln!("fine case {case} step {step:?}: {}", o.summary());
        o.assert_decoding(&format!("fine case {case}"), 0.92, 0.005);
        assert!(
            o.mean_mm <= 0.3,
            "fine case {case}: mean {:.3} mm",
            o.mean_mm
        );
    }
}

/// Dense regions (the seed's critical regions, where a part needs more points): seeded
/// patterns at steps of 14–16 with one or two regions, of random place and size, at steps of
/// 9–11 (the detector set for the finest spacing, as risd sets it). No primitive is placed
/// wrong and the points are as accurate as elsewhere; the regions hold more points than the
/// coarse grid would put there. What is lost: where the step changes (a region's border, and
/// where its bands of finer columns or rows cross) the neighbour search, set by the grid about
/// it, misses neighbours, so fewer primitives decode than on a uniform pattern. When this was
/// written: 83.3 / 78.3 / 85.1 % of the primitives seen whole decoded (a uniform pattern 95–96
/// %), 89.0 / 73.8 / 85.3 % inside the regions, 0 wrong, 0 / 0 / 1 beyond 2 mm, mean 0.15 mm;
/// 2.27 / 1.45 / 2.15 times the coarse grid's primitives inside them.
#[test]
fn dense_regions_decode_finer_where_asked() {
    let mut rng = Rng(61);
    for case in seeds(2, 3) {
        let mut f = demo_file();
        let step = [rng.range(14.0, 16.99) as u32, rng.range(14.0, 16.99) as u32];
        let (pw, ph) = (1024.0, 768.0);
        let regions: Vec<DenseRegion> = (0..1 + case % 2)
            .map(|_| {
                let (rw, rh) = (rng.range(0.25, 0.45) * pw, rng.range(0.25, 0.45) * ph);
                let (x0, y0) = (
                    rng.range(0.1 * pw, 0.9 * pw - rw),
                    rng.range(0.1 * ph, 0.9 * ph - rh),
                );
                let s = rng.range(9.0, 11.99) as u32;
                DenseRegion {
                    x: [x0, x0 + rw],
                    y: [y0, y0 + rh],
                    step: [s, s],
                }
            })
            .collect();
        f.camera.noise = rng.range(1.0, 3.0);
        f.render.seed = case + 31;
        let o = run_dense(f, step, &regions, 300 + case);
        eprintln!(
            "dense case {case} step {step:?} regions {regions:?}: {}",
            o.summary()
        );
        // Within the regions: the primitives seen whole there, and those decoded.
        let pattern =
            XPointPattern::with_dense(1024, 768, step, &regions, 3, 300 + case).expect("pattern");
        let q = &pattern.primitives;
        let inside = |k: usize| {
            regions
                .iter()
                .any(|r| (r.x[0]..r.x[1]).contains(&q.u[k]) && (r.y[0]..r.y[1]).contains(&q.v[k]))
        };
        let (mut seen, mut found) = (0, 0);
        for k in (0..q.u.len()).filter(|&k| inside(k)) {
            seen += usize::from(o.seen[k]);
            found += usize::from(o.seen[k] && o.found[k]);
        }
        // Seen and decoded where the columns, the rows, both or neither are fine.
        let mut zones = [[0usize; 2]; 4];
        for k in 0..q.u.len() {
            let fc = regions.iter().any(|r| (r.x[0]..r.x[1]).contains(&q.u[k]));
            let fr = regions.iter().any(|r| (r.y[0]..r.y[1]).contains(&q.v[k]));
            let z = usize::from(fc) + 2 * usize::from(fr);
            zones[z][0] += usize::from(o.seen[k]);
            zones[z][1] += usize::from(o.seen[k] && o.found[k]);
        }
        eprintln!("zones (coarse, fine columns, fine rows, both) seen/decoded: {zones:?}");
        // The coarse grid's primitives in the same regions (overlaps counted once).
        let plain = XPointPattern::generate(1024, 768, step, 3, 300 + case).expect("plain");
        let pq = &plain.primitives;
        let coarse = (0..pq.u.len())
            .filter(|&k| {
                regions.iter().any(|r| {
                    (r.x[0]..r.x[1]).contains(&pq.u[k]) && (r.y[0]..r.y[1]).contains(&pq.v[k])
                })
            })
            .count() as f64;
        eprintln!(
            "dense case {case}: {found} of {seen} seen whole in the regions decoded ({:.1} %), {:.2} times the coarse grid's {coarse} primitives there",
            100.0 * found as f64 / seen.max(1) as f64,
            found as f64 / coarse
        );
        o.assert_decoding(&format!("dense case {case}"), 0.75, 0.005);
        assert!(
            o.mean_mm <= 0.3,
            "dense case {case}: mean {:.3} mm",
            o.mean_mm
        );
        assert!(seen > 300, "dense case {case}: {seen} seen in the regions");
        assert!(
            found as f64 >= 0.7 * seen as f64,
            "dense case {case}: {found} of {seen} decoded in the regions"
        );
        assert!(
            found as f64 >= 1.3 * coarse,
            "dense case {case}: {found} decoded in the regions, where the coarse grid has {coarse:.0}"
        );
    }
}

/// One scene of the independent renderer (`tests/xpoint_render.py`, numpy: its own camera with
/// distortion, projector, objects, shadows, texture and noise; it shows `xpoint.png` as it is
/// and writes the sensor file and its Gray-code reference recording as SPEC §4 and §6 state
/// them), decoded as `ris single-shot` does: the sensor file's model and reference.
/// Starts the renderer on `pattern` (written to `dir/slide`); the scene goes to `dir/scene`.
fn render_independent(
    pattern: &XPointPattern,
    seed: u64,
    noise: f64,
    texture: f64,
    dir: &Path,
) -> std::process::Child {
    use ris_core::image::GrayImage;
    let slide = dir.join("slide");
    std::fs::create_dir_all(&slide).expect("mkdir");
    let (w, h) = (pattern.pattern.width, pattern.pattern.height);
    GrayImage::from_u8(w, h, pattern.render())
        .save_png(&slide.join("xpoint.png"))
        .expect("xpoint.png");
    ris_core::io::write_toml(&slide.join("xpoint.toml"), &pattern).expect("xpoint.toml");
    let renderer = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/xpoint_render.py");
    std::process::Command::new("python3")
        .arg(&renderer)
        .arg(&slide)
        .arg(seed.to_string())
        .arg(noise.to_string())
        .arg(texture.to_string())
        .arg(dir.join("scene"))
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("python3 (with numpy) runs the independent renderer")
}

/// Decodes the scene `render_independent` wrote in `dir`, as `ris single-shot` would.
fn decode_independent(pattern: &XPointPattern, dir: &Path) -> Outcome {
    use ris_core::capture::CaptureSet;
    use ris_core::decode::{decode as decode_gray, DecodeParams};
    use ris_core::image::GrayImage;
    use ris_core::io::npy;
    use ris_core::sensor::{ModelChoice, Sensor};

    let out = dir.join("scene");
    let sensor = Sensor::load(&out.join("sensor.toml")).expect("sensor file");
    let params = DecodeParams::default();
    let rec = Reconstructor::new(&sensor, ModelChoice::Auto, &params).expect("model");
    let reference = decode_gray(
        &CaptureSet::load(sensor.reference.as_ref().expect("reference")).expect("capture"),
        &params,
    )
    .expect("reference decodes");
    let predict = ReferencePrediction::new(&reference).expect("row codes");
    let at = |x: f64, y: f64| predict.at(x, y);
    let image = GrayImage::load(&out.join("image.png")).expect("image");
    let (w, h) = (image.width as usize, image.height as usize);
    let params = camera_spacing(&reference, pattern.finest_step())
        .map_or_else(DetectParams::default, DetectParams::for_spacing);
    let (found, matches, stats) =
        decode_frame(&mut Detector::new(params), &image, pattern, Some(&at));
    let cloud = reconstruct(&matches, &rec);

    let (shape, xyz) = npy::read::<f32>(&out.join("xyz.npy")).expect("xyz.npy");
    assert_eq!(shape, vec![h, w, 3]);
    let (_, proj) = npy::read::<f32>(&out.join("projector.npy")).expect("projector.npy");
    let truth = Truth {
        width: w,
        height: h,
        xyz: xyz.chunks(3).map(|p| [p[0], p[1], p[2]]).collect(),
        projector: proj
            .chunks(3)
            .map(|p| p[0].is_finite().then(|| (f64::from(p[0]), f64::from(p[1]))))
            .collect(),
        lit: proj.chunks(3).map(|p| p[2] > 0.5).collect(),
    };
    evaluate(&truth, pattern, &found, &matches, &stats, &rec, cloud.len())
}

/// The acceptance on scenes this repository's simulator did not make: seeded scenes of
/// the independent renderer (a step, a cap and a cylinder on a table the pattern falls off,
/// shadows, occlusion, lens distortion, noise) at steps of 12–16 projector pixels and 1.6 m.
/// The first two have a mild albedo texture (5–15 %), the third a strong one (20–30 %, at
/// periods down to 2 mm): texture multiplies the pattern and moves each corner's centre of symmetry,
/// and it is what the mean error grows with (without texture it is under 0.1 mm).
#[test]
fn independent_renders_decode_to_the_surface() {
    // Strong texture lowers the decoded share: the cut tests compare a boundary corner's
    // asymmetry with its neighbours', and texture raises both.
    let kinds = [
        ((0.05, 0.15), 0.3, 0.95),
        ((0.05, 0.15), 0.3, 0.95),
        ((0.2, 0.3), 0.45, 0.94),
    ];
    let textures = kinds.map(|k| k.0);
    for ((case, o), (_, mean_bound, rate)) in
        independent_family(&textures, 0).into_iter().zip(kinds)
    {
        assert!(
            o.mean_mm <= mean_bound,
            "scene {case}: mean {:.3} mm",
            o.mean_mm
        );
        // Corners cut by the end of a surface (the table's edge, a shadow) keep a centre of
        // symmetry off their corner. Those cut along their axis are dropped as cut (their light
        // is narrower than their neighbours'), as are those cut across a lobe when they are
        // clearly more asymmetric than their neighbours, and those only one neighbour confirms;
        // those the symmetric fit placed inside the line of their neighbours are moved to where
        // the whole half of a neighbour's light matches; the rest carry the boundary flag
        // (halved confidence). Points at full confidence beyond 2 mm stay within the issue's
        // 0.1 %; all of them within 0.4 % (1.0–1.1 % before the cut tests, where a table edge
        // runs along a column of primitives; 0.10 and 0.09 % on scenes 1 and 2 when this was
        // written).
        let unflagged = o.far - o.far_flagged;
        assert!(
            unflagged as f64 <= 0.001 * o.measured as f64 + 1.0,
            "scene {case}: {unflagged} of {} unflagged beyond 2 mm",
            o.measured
        );
        o.assert_decoding(&format!("scene {case}"), rate, 0.004);
    }
}

/// Independent scenes, one per albedo texture range of `textures`, drawn in turn from one
/// seeded sequence (steps of 12–16, read noise of 1–3 grey levels), rendered at once (the
/// renderer is single-threaded) and decoded in turn.
fn independent_family(textures: &[(f64, f64)], family: u64) -> Vec<(usize, Outcome)> {
    let dir = tempfile::tempdir().expect("tmp");
    let mut rng = Rng(17 + family);
    let cases: Vec<_> = textures
        .iter()
        .enumerate()
        .map(|(case, &texture)| {
            let step = [rng.range(12.0, 16.99) as u32, rng.range(12.0, 16.99) as u32];
            let noise = rng.range(1.0, 3.0);
            let texture = rng.range(texture.0, texture.1);
            let seed = case as u64 + 1 + 100 * family;
            let pattern = XPointPattern::generate(1024, 768, step, 3, seed).expect("pattern");
            let at = dir.path().join(format!("case{case}"));
            let child = render_independent(&pattern, seed, noise, texture, &at);
            (case, step, noise, texture, pattern, at, child)
        })
        .collect();
    cases
        .into_iter()
        .map(|(case, step, noise, texture, pattern, at, child)| {
            let py = child.wait_with_output().expect("renderer");
            assert!(
                py.status.success(),
                "{}",
                String::from_utf8_lossy(&py.stderr)
            );
            let o = decode_independent(&pattern, &at);
            eprintln!(
                "independent family {family} scene {case} step {step:?} noise {noise:.1} texture {texture:.2}: {}",
                o.summary()
            );
            (case, o)
        })
        .collect()
}

/// The acceptance pooled over twelve independent scenes (the three above and nine more with
/// mild texture): every mild one decodes ≥ 95 % of the primitives in view with a mean error
/// ≤ 0.3 mm; of all their points at most 0.1 % lie beyond 2 mm (when this was written: 6 of
/// 25 816, 0.02 %; 14 before the symmetric fit took the albedo's slope, 18 before the undecided
/// and kinked corners were dropped, 33 before corners only one neighbour confirms and disturbed
/// inner corners were, 42 before cut corners were moved back), and at most 0.1 % are placed at
/// a wrong primitive (1 of 25 871). The thresholds of the cut and drop tests were chosen on
/// these scenes: see [`held_out_renders_pooled_over_twenty_four_scenes`] for 24 that were not
/// looked at first. About two minutes on two cores:
/// `cargo test --profile ci -p ris-core --test core_suite single_shot::pooled_over_twelve -- --ignored --nocapture`
#[test]
#[ignore = "a survey of twelve scenes, about two minutes on two cores"]
fn independent_renders_pooled_over_twelve_scenes() {
    pooled(&[0], 0.95, 0.3, 0.001);
}

/// Twenty-four independent scenes from two more seeds (families 9 and 10), drawn after every
/// threshold of the detector and the decoder was set and not looked at before: the acceptance
/// on scenes nobody tuned for. When this was written: 33 of 51 824 points beyond 2 mm
/// (0.06 %), 5 of 51 914 placed wrong, every mild scene 95.5–99.5 % decoded with a mean of at
/// most 0.21 mm (the two strongly textured ones 95.7 % each, 0.35 and 0.51 mm); with
/// `ris_core::single_shot::SIDE_VOTES`, 33 of 51 931, 5 of 52 022, mild scenes
/// 95.5–99.6 % (strongly textured 95.7 and 96.0 %); with the default disc of 3.7 px instead of
/// 5, 20 of 52 085, 1 of 52 207, mild scenes 96.9–99.8 % (strongly textured 89.4 and 94.7 %,
/// means 0.43 and 0.34 mm against 0.51 and 0.35). About four minutes on two cores:
/// `cargo test --profile ci -p ris-core --test core_suite single_shot::held_out_renders_pooled_over_twenty_four_scenes -- --exact --ignored --nocapture`
#[test]
#[ignore = "a survey of twenty-four scenes, about four minutes on two cores"]
fn held_out_renders_pooled_over_twenty_four_scenes() {
    pooled(&[9, 10], 0.95, 0.3, 0.001);
}

/// Ninety-six independent scenes (families 1–8) that were held out in turn and then used to
/// set later thresholds (the last: the albedo slope's shrinkage and the half match's least
/// move on families 0–6, the tiles of local grid vectors on 0–8): how the decoder does on all
/// of them. When this was written: 121 of 202 658 points beyond 2 mm (0.06 %; 155 on families
/// 1–6 alone before the symmetric fit took the albedo's slope), 15 of 203 102 placed wrong,
/// every mild scene decoded 95.2–99.6 % (family 1 scene 7, where a tilted surface packs the
/// primitives 8.5 px apart and the grid shears where it folds, 94.3 % before the local grid
/// vectors) with a mean of at most 0.30 mm (0.38 before the slope). About sixteen minutes on
/// two cores. With the default disc of 3.7 px instead of 5 (and every decoder rule since):
/// 99 of 203 692 beyond 2 mm (0.049 %), 10 of 204 234 wrong, every mild scene 96.6–99.9 %:
/// `cargo test --profile ci -p ris-core --test core_suite single_shot::earlier_held_out -- --ignored --nocapture`
#[test]
#[ignore = "a survey of ninety-six scenes, about sixteen minutes on two cores"]
fn earlier_held_out_renders_pooled_over_ninety_six_scenes() {
    pooled(&[1, 2, 3, 4, 5, 6, 7, 8], 0.95, 0.3, 0.001);
}

/// Decode the twelve scenes of each of `families` (the third of each with strong texture),
/// assert every mild one decodes at least `rate` with a mean error of at most `mean` mm, that
/// at most 0.1 % of all are placed wrong and at most `far_share` of all points lie beyond 2 mm.
fn pooled(families: &[u64], rate: f64, mean: f64, far_share: f64) {
    let (mild, strong) = ((0.05, 0.15), (0.2, 0.3));
    let mut textures = vec![mild; 12];
    textures[2] = strong;
    let (mut far, mut measured, mut wrong, mut decoded) = (0, 0, 0, 0);
    let outcomes = families.iter().flat_map(|&f| {
        independent_family(&textures, f)
            .into_iter()
            .zip(&textures)
            .map(move |(o, t)| (f, o, t))
    });
    for (family, (case, o), texture) in outcomes {
        far += o.far;
        measured += o.measured;
        wrong += o.wrong;
        decoded += o.decoded;
        if *texture == mild {
            assert!(
                o.mean_mm <= mean,
                "family {family} scene {case}: mean {:.3} mm",
                o.mean_mm
            );
            assert!(
                o.rate() >= rate,
                "family {family} scene {case}: {:.1} % decoded",
                100.0 * o.rate()
            );
        }
    }
    eprintln!(
        "pooled: {far} of {measured} points beyond 2 mm ({:.2} %), {wrong} of {decoded} placed wrong",
        100.0 * far as f64 / measured as f64
    );
    assert!(
        wrong as f64 <= 0.001 * decoded as f64,
        "{wrong} of {decoded} wrong"
    );
    assert!(
        far as f64 <= far_share * measured as f64,
        "{far} of {measured} beyond 2 mm"
    );
}
