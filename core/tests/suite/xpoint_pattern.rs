//! The X-point pattern: for seeded projectors, steps and seeds, any two distinct 3×3 windows
//! differ in ≥ 3 symbols (Eq. 4.1), windows repeat only at the stated period, and every window
//! of a period block is unique; the rendered image puts each primitive's saddle and long axis
//! where `xpoint.toml` says, and nothing else is lit; dense regions refine the grid where they
//! are asked and nowhere else; bad requests and files are refused by name.

use std::collections::HashMap;

use ris_core::single_shot::code::{hamming, window, DISTANCE, PERIOD};
use ris_core::single_shot::{DenseRegion, XPointPattern};

use crate::common;
use common::Rng;

#[test]
fn windows_keep_their_distance_and_repeat_only_at_the_period() {
    for (k, (w, h, step)) in [
        (1024u32, 768u32, [14u32, 14u32]),
        (1920, 1080, [12, 12]),
        (1920, 1080, [16, 14]),
        (800, 600, [12, 16]),
        (1280, 800, [13, 15]),
    ]
    .into_iter()
    .enumerate()
    {
        let seed = 11 * k as u64 + 3;
        let p = XPointPattern::generate(w, h, step, 3, seed).expect("pattern");
        let [cols, rows] = p.grid();
        assert_eq!(p.primitives.u.len(), cols * rows);
        let mut seen: HashMap<[u8; 9], (usize, usize)> = HashMap::new();
        for j in 0..rows - 2 {
            for i in 0..cols - 2 {
                let win = window(&p.primitives.value, cols, i, j);
                if let Some(&(i0, j0)) = seen.get(&win) {
                    assert!(
                        (i - i0) % PERIOD[0] == 0 && (j - j0) % PERIOD[1] == 0,
                        "{w}x{h}: windows at ({i0},{j0}) and ({i},{j}) are equal"
                    );
                } else {
                    seen.insert(win, (i, j));
                }
            }
        }
        let distinct: Vec<[u8; 9]> = seen.keys().copied().collect();
        let expect = (cols - 2).min(PERIOD[0]) * (rows - 2).min(PERIOD[1]);
        assert_eq!(distinct.len(), expect, "{w}x{h}: distinct windows");
        let mut worst = 9;
        for a in 0..distinct.len() {
            for b in a + 1..distinct.len() {
                worst = worst.min(hamming(&distinct[a], &distinct[b]));
            }
        }
        assert!(worst >= DISTANCE, "{w}x{h} seed {seed}: distance {worst}");
        // Every symbol is used about equally.
        let mut hist = [0usize; 4];
        for &v in &p.primitives.value {
            hist[v as usize] += 1;
        }
        let n = p.primitives.value.len() as f64;
        assert!(
            hist.iter().all(|&c| (c as f64 / n - 0.25).abs() < 0.06),
            "{hist:?}"
        );
    }
    // Seeds give different arrays.
    let a = XPointPattern::generate(1024, 768, [14, 14], 3, 1).expect("a");
    let b = XPointPattern::generate(1024, 768, [14, 14], 3, 2).expect("b");
    assert_ne!(a.primitives.value, b.primitives.value);
    assert_eq!(
        a,
        XPointPattern::generate(1024, 768, [14, 14], 3, 1).expect("again")
    );
}

#[test]
fn the_image_shows_each_primitive_where_the_file_says() {
    for (seed, step) in [(1u64, [14u32, 14u32]), (2, [12, 16]), (3, [16, 12])] {
        let p = XPointPattern::generate(640, 480, step, 3, seed).expect("pattern");
        let img = p.render();
        let (w, r) = (640usize, p.pattern.radius);
        let q = &p.primitives;
        let mut lit = vec![false; img.len()];
        for k in 0..q.u.len() {
            // Moments of the primitive's patch (Eq. 4.2–4.5): centroid at the corner, long axis
            // at value · 45°.
            let (mut m00, mut m10, mut m01) = (0f64, 0f64, 0f64);
            let mut pix = Vec::new();
            let (x0, x1) = ((q.u[k] - r - 1.0) as usize, (q.u[k] + r + 1.0) as usize);
            let (y0, y1) = ((q.v[k] - r - 1.0) as usize, (q.v[k] + r + 1.0) as usize);
            for y in y0..=y1 {
                for x in x0..=x1 {
                    lit[y * w + x] = true;
                    let f = f64::from(img[y * w + x]);
                    m00 += f;
                    m10 += f * x as f64;
                    m01 += f * y as f64;
                    pix.push((x as f64, y as f64, f));
                }
            }
            let (xm, ym) = (m10 / m00, m01 / m00);
            assert!(
                (xm - q.u[k]).abs() < 0.02 && (ym - q.v[k]).abs() < 0.02,
                "seed {seed} primitive {k}: centroid ({xm:.3}, {ym:.3}) vs corner ({}, {})",
                q.u[k],
                q.v[k]
            );
            let (mut c20, mut c02, mut c11) = (0f64, 0f64, 0f64);
            for (x, y, f) in pix {
                c20 += f * (x - xm) * (x - xm);
                c02 += f * (y - ym) * (y - ym);
                c11 += f * (x - xm) * (y - ym);
            }
            let alpha = 0.5 * (2.0 * c11).atan2(c20 - c02);
            let want = f64::from(q.value[k]) * std::f64::consts::FRAC_PI_4;
            let mut diff = (alpha - want).rem_euclid(std::f64::consts::PI);
            if diff > std::f64::consts::FRAC_PI_2 {
                diff = std::f64::consts::PI - diff;
            }
            assert!(
                diff.to_degrees() < 1.0,
                "seed {seed} primitive {k}: axis {:.2}° for value {}",
                alpha.to_degrees(),
                q.value[k]
            );
            // The corner is a saddle: the bright quadrants sit on the long axis.
            let at = |d: f64, a: f64| {
                let (x, y) = (q.u[k] + d * a.cos(), q.v[k] + d * a.sin());
                img[(y.round() as usize) * w + x.round() as usize]
            };
            assert!(
                at(0.6 * r, want) > 200 && at(0.6 * r, want + std::f64::consts::FRAC_PI_2) < 40
            );
        }
        assert!(
            img.iter().zip(&lit).all(|(&v, &l)| l || v == 0),
            "light outside the primitives"
        );
    }
}

#[test]
fn impossible_requests_and_bad_files_are_refused_by_name() {
    let err = XPointPattern::generate(1024, 768, [14, 14], 4, 1)
        .expect_err("distance 4")
        .to_string();
    assert!(
        err.contains("min_distance") && err.contains("at most 3"),
        "{err}"
    );
    let err = XPointPattern::generate(1024, 768, [6, 14], 3, 1)
        .expect_err("step")
        .to_string();
    assert!(err.contains("step"), "{err}");
    let err = XPointPattern::generate(60, 40, [14, 14], 3, 1)
        .expect_err("tiny")
        .to_string();
    assert!(err.contains("3x3"), "{err}");

    let dir = tempfile::tempdir().expect("tmp");
    let p = XPointPattern::generate(320, 240, [14, 14], 3, 5).expect("pattern");
    let path = dir.path().join("xpoint.toml");
    ris_core::io::write_toml(&path, &p).expect("write");
    assert_eq!(XPointPattern::load(&path).expect("load"), p);
    let text = std::fs::read_to_string(&path).expect("read");
    let bad = dir.path().join("bad.toml");
    std::fs::write(&bad, text.replacen("value = [", "value = [7, ", 1)).expect("w");
    let err = XPointPattern::load(&bad).expect_err("bad").to_string();
    assert!(
        err.contains("bad.toml") && err.contains("primitives.value"),
        "{err}"
    );
}

/// Seeded projectors, steps and regions: the columns whose gap starts inside a region's columns
/// are its `dx` apart (or less where another region begins) and the rest the pattern's (but the
/// one gap that enters a region, which is shorter), likewise rows; each primitive's radius is
/// 0.38 of the least gap to its grid neighbours and it lies whole inside the image; the code
/// keeps its distance; the file states the regions and loads back; and the lattice maps each
/// primitive's projector position to its own grid place and step.
#[test]
fn dense_regions_refine_the_grid_where_asked() {
    let mut rng = Rng(41);
    for case in 0..8u64 {
        let (w, h) = if case % 2 == 0 {
            (1024u32, 768u32)
        } else {
            (1920, 1080)
        };
        let step = [rng.range(13.0, 18.99) as u32, rng.range(13.0, 18.99) as u32];
        let mut regions = Vec::new();
        for _ in 0..1 + case as usize % 2 {
            let (rw, rh) = (
                rng.range(0.15, 0.4) * f64::from(w),
                rng.range(0.15, 0.4) * f64::from(h),
            );
            let (x0, y0) = (
                rng.range(0.0, f64::from(w) - rw),
                rng.range(0.0, f64::from(h) - rh),
            );
            regions.push(DenseRegion {
                x: [x0, x0 + rw],
                y: [y0, y0 + rh],
                step: [
                    rng.range(8.0, f64::from(step[0]) - 2.0) as u32,
                    rng.range(8.0, f64::from(step[1]) - 2.0) as u32,
                ],
            });
        }
        let p = XPointPattern::with_dense(w, h, step, &regions, 3, case + 1).expect("pattern");
        let finest = p.finest_step();
        let r = p.pattern.radius;
        assert!(
            (r - 0.38 * f64::from(finest[0].min(finest[1]))).abs() < 1e-9,
            "case {case}: radius {r}"
        );
        let lattice = p.lattice();
        let plain = XPointPattern::generate(w, h, step, 3, case + 1).expect("plain");
        for (axis, at, size) in [(0, &lattice.columns, w), (1, &lattice.rows, h)] {
            // Inside the image, whole.
            assert!(
                at[0] - r >= 0.0 && at[at.len() - 1] + r <= f64::from(size) - 1.0,
                "case {case} axis {axis}"
            );
            let span = |g: &DenseRegion| if axis == 0 { g.x } else { g.y };
            let mut fine_gaps = 0;
            for pair in at.windows(2) {
                let (a, b) = (pair[0], pair[1]);
                let gap = b - a;
                let fine = regions
                    .iter()
                    .filter(|g| a >= span(g)[0] && a < span(g)[1])
                    .map(|g| f64::from(g.step[axis]))
                    .reduce(f64::min);
                let entering = regions.iter().any(|g| a < span(g)[0] && b >= span(g)[0]);
                if let Some(fine) = fine {
                    assert!(
                        gap <= fine + 1e-9 && gap >= f64::from(finest[axis]) - 1e-9,
                        "case {case} axis {axis}: gap {gap} at {a} inside a region of step {fine}"
                    );
                    fine_gaps += 1;
                } else if entering {
                    assert!(
                        gap >= f64::from(finest[axis]) - 1e-9
                            && gap <= f64::from(step[axis]) + 1e-9,
                        "case {case} axis {axis}: gap {gap} entering a region"
                    );
                } else {
                    assert!(
                        (gap - f64::from(step[axis])).abs() < 1e-9,
                        "case {case} axis {axis}: gap {gap} at {a} outside every region"
                    );
                }
            }
            // Every region is at least 15 % of the image wide: fine gaps, and more positions.
            assert!(fine_gaps > 0, "case {case} axis {axis}: no fine gap");
            let plain_n = if axis == 0 {
                plain.grid()[0]
            } else {
                plain.grid()[1]
            };
            assert!(
                at.len() > plain_n,
                "case {case} axis {axis}: {} positions, {plain_n} without regions",
                at.len()
            );
        }
        // Every primitive whole inside the image, sized by its least gap to a grid neighbour.
        let radii = p.radii();
        let cols = lattice.columns.len();
        let least = |axis: &[f64], i: usize| {
            let before = if i > 0 {
                axis[i] - axis[i - 1]
            } else {
                f64::INFINITY
            };
            let after = axis.get(i + 1).map_or(f64::INFINITY, |a| a - axis[i]);
            before.min(after)
        };
        for (k, &rk) in radii.iter().enumerate() {
            let (u, v) = (p.primitives.u[k], p.primitives.v[k]);
            let gap = least(&lattice.columns, k % cols).min(least(&lattice.rows, k / cols));
            assert!(
                (rk - 0.38 * gap).abs() < 1e-9
                    && rk >= r - 1e-9
                    && rk <= 0.38 * f64::from(step[0].min(step[1])) + 1e-9,
                "case {case}: radius {rk} where the least gap is {gap}"
            );
            assert!(
                u - rk >= 0.0
                    && v - rk >= 0.0
                    && u + rk <= f64::from(w) - 1.0
                    && v + rk <= f64::from(h) - 1.0,
                "case {case}: primitive {k} cut by the image's edge"
            );
        }
        // The code keeps its distance over the whole (larger) grid.
        let [cols, rows] = p.grid();
        let q = &p.primitives;
        for j in (0..rows - 2).step_by(3) {
            for i in (0..cols - 2).step_by(2) {
                let a = window(&q.value, cols, i, j);
                for (jj, ii) in [(j, i + 1), (j + 1, i), (j + 1, i + 1)] {
                    if ii + 2 < cols && jj + 2 < rows {
                        assert!(hamming(&a, &window(&q.value, cols, ii, jj)) >= DISTANCE);
                    }
                }
            }
        }
        // The lattice finds every primitive at its own place, with the steps about it.
        for k in (0..q.u.len()).step_by(7) {
            let (gi, gj) = lattice.place(q.u[k], q.v[k]);
            assert!((gi - f64::from(q.i[k])).abs() < 1e-9 && (gj - f64::from(q.j[k])).abs() < 1e-9);
            let s = lattice.step_at(q.u[k] + 0.5, q.v[k] + 0.5);
            assert!(s[0] >= f64::from(finest[0]) - 1e-9 && s[0] <= f64::from(step[0]) + 1e-9);
            assert!(s[1] >= f64::from(finest[1]) - 1e-9 && s[1] <= f64::from(step[1]) + 1e-9);
        }
        // The file states the regions and loads back as it was.
        let dir = tempfile::tempdir().expect("tmp");
        let path = dir.path().join("xpoint.toml");
        ris_core::io::write_toml(&path, &p).expect("write");
        let text = std::fs::read_to_string(&path).expect("read");
        assert!(
            text.contains("[[pattern.dense]]"),
            "case {case}: no dense table in the file"
        );
        assert_eq!(XPointPattern::load(&path).expect("load"), p);
        eprintln!("case {case}: {w}x{h} step {step:?} regions {regions:?}: {cols}x{rows} grid (plain {:?})", plain.grid());
    }
}

/// Regions that cannot refine the pattern, and files whose primitives do not lie on one grid of
/// columns and rows, are refused by name.
#[test]
fn bad_dense_regions_and_off_grid_files_are_refused_by_name() {
    let region = |x: [f64; 2], y: [f64; 2], step: [u32; 2]| DenseRegion { x, y, step };
    for (r, want) in [
        (
            region([300.0, 200.0], [100.0, 300.0], [10, 10]),
            "lower to a higher",
        ),
        (
            region([100.0, 2000.0], [100.0, 300.0], [10, 10]),
            "inside the 1024x768",
        ),
        (
            region([100.0, 300.0], [f64::NAN, 300.0], [10, 10]),
            "lower to a higher",
        ),
        (
            region([100.0, 300.0], [100.0, 300.0], [6, 10]),
            "dense region's steps",
        ),
        (
            region([100.0, 300.0], [100.0, 300.0], [10, 20]),
            "dense region's steps",
        ),
    ] {
        let err = XPointPattern::with_dense(1024, 768, [14, 14], &[r], 3, 1)
            .expect_err("bad region")
            .to_string();
        assert!(err.contains("dense[0]") && err.contains(want), "{err}");
    }
    let p = XPointPattern::with_dense(
        640,
        480,
        [16, 16],
        &[region([200.0, 400.0], [150.0, 300.0], [10, 10])],
        3,
        2,
    )
    .expect("pattern");
    let dir = tempfile::tempdir().expect("tmp");
    let path = dir.path().join("xpoint.toml");
    let mut moved = p.clone();
    let k = moved.grid()[0] + 3;
    moved.primitives.u[k] += 2.0;
    ris_core::io::write_toml(&path, &moved).expect("write");
    let err = XPointPattern::load(&path)
        .expect_err("off grid")
        .to_string();
    assert!(
        err.contains("primitives") && err.contains(&format!("entry {k}")),
        "{err}"
    );
    let mut bad = p.clone();
    bad.pattern.dense[0].step = [30, 10];
    ris_core::io::write_toml(&path, &bad).expect("write");
    let err = XPointPattern::load(&path)
        .expect_err("bad region")
        .to_string();
    assert!(err.contains("pattern.dense[0]"), "{err}");
}
