//! The X-point pattern: for seeded projectors, steps and seeds, any two distinct 3×3 windows
//! differ in ≥ 3 symbols (Eq. 4.1), windows repeat only at the stated period, and every window
//! of a period block is unique; the rendered image puts each primitive's saddle and long axis
//! where `xpoint.toml` says, and nothing else is lit; bad requests and files are refused by
//! name.

use std::collections::HashMap;

use ris_core::single_shot::code::{hamming, window, DISTANCE, PERIOD};
use ris_core::single_shot::XPointPattern;

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
