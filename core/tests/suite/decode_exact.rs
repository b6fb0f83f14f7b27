//! Decoding exactness on noise-free simulated captures, and the parallax model against Eq. 2.37.

use ris_core::capture::CaptureSet;
use ris_core::decode::{decode, Binarization, DecodeParams};
use ris_core::geometry::{look_at, Mat3, Vec3};
use ris_core::image::{GrayImage, Pixels};
use ris_core::pattern::{CodeAxis, Pattern};
use ris_core::sensor::{parallel_height, Reconstructor};
use ris_core::sim::{
    MaterialSection, ObjectSection, RenderSection, Scene, SceneFile, SimCamera, SimProjector,
    Simulator,
};

fn rows(m: &Mat3) -> [[f64; 3]; 3] {
    [
        [m[(0, 0)], m[(0, 1)], m[(0, 2)]],
        [m[(1, 0)], m[(1, 1)], m[(1, 2)]],
        [m[(2, 0)], m[(2, 1)], m[(2, 2)]],
    ]
}

/// A flat-plane scene: camera straight down at `cam_z`, projector at `proj` looking at `target`.
fn plane_scene(
    proj: Vec3,
    target: Vec3,
    noise: f64,
    blur: f64,
    objects: Vec<ObjectSection>,
) -> Scene {
    let (rc, tc) = look_at(Vec3::new(0.0, 0.0, 1600.0), Vec3::zeros(), Vec3::y());
    let (rp, tp) = look_at(proj, target, Vec3::y());
    let mut material = std::collections::BTreeMap::new();
    material.insert(
        "matte".to_string(),
        MaterialSection {
            albedo: 0.7,
            specular: 0.0,
            shininess: 0.0,
            interreflection: 0.0,
            interreflection_radius: 0.0,
            texture: None,
            texture_amplitude: 0.0,
            texture_period: 20.0,
        },
    );
    let mut object = vec![ObjectSection {
        shape: "plane".into(),
        material: "matte".into(),
        ..Default::default()
    }];
    object.extend(objects);
    let file = SceneFile {
        camera: SimCamera {
            width: 320,
            height: 240,
            k: [[700.0, 0.0, 159.5], [0.0, 700.0, 119.5], [0.0, 0.0, 1.0]],
            dist: [0.0; 5],
            r: rows(&rc),
            t: [tc.x, tc.y, tc.z],
            exposure: 1.0,
            noise,
            shot_noise: 0.0,
        },
        projector: SimProjector {
            width: 256,
            height: 192,
            k: [[560.0, 0.0, 127.5], [0.0, 560.0, 95.5], [0.0, 0.0, 1.0]],
            dist: [0.0; 5],
            r: rows(&rp),
            t: [tp.x, tp.y, tp.z],
            ambient: 0.02,
            blur,
        },
        material,
        object,
        render: RenderSection {
            supersample: 4,
            seed: 7,
            rows: true,
        },
        calibration: None,
    };
    Scene::from_file(file, std::path::Path::new("."), "test scene").expect("scene")
}

#[test]
fn noise_free_capture_decodes_to_the_true_projector_column() {
    for blur in [0.0, 0.6] {
        let scene = plane_scene(
            Vec3::new(400.0, 0.0, 1600.0),
            Vec3::zeros(),
            0.0,
            blur,
            vec![],
        );
        let sim = Simulator::new(scene.clone());
        let capture = sim.capture(&sim.layout(), 0, &|_, _| {});
        let dec = decode(&capture, &DecodeParams::default()).expect("decode");
        let (w, h) = (scene.camera.width as usize, scene.camera.height as usize);
        let project = |u: f64, v: f64| -> f64 {
            let d = scene.camera.ray(u, v);
            let oc = scene.camera.center();
            let p = oc + d * (-oc.z / d.z);
            scene.projector.project(&p).expect("projects").0
        };
        let (mut n, mut inside_cell, mut wrong, mut sum_abs) = (0usize, 0usize, 0usize, 0.0f64);
        for v in 0..h {
            for u in 0..w {
                let c = dec.col[v * w + u];
                if !c.is_finite() {
                    continue;
                }
                let (uf, vf) = (u as f64, v as f64);
                let centre = project(uf, vf);
                // Projector columns covered by the pixel footprint (its four corners).
                let corners = [
                    project(uf - 0.5, vf - 0.5),
                    project(uf + 0.5, vf - 0.5),
                    project(uf - 0.5, vf + 0.5),
                    project(uf + 0.5, vf + 0.5),
                ];
                let (lo, hi) = corners
                    .iter()
                    .fold((f64::MAX, f64::MIN), |a, &x| (a.0.min(x), a.1.max(x)));
                if (lo + 0.5).floor() == (hi + 0.5).floor() {
                    // The whole footprint lies in one projector pixel: the code cell is exact.
                    inside_cell += 1;
                    let cell = (centre + 0.5).floor();
                    wrong += usize::from((f64::from(c) - cell).abs() > 0.5 + 1e-3);
                }
                n += 1;
                sum_abs += (f64::from(c) - centre).abs();
            }
        }
        let mean = sum_abs / n as f64;
        eprintln!("blur {blur}: {n} valid of {}, {inside_cell} footprints inside one cell, {wrong} outside it; mean |Δcol| {mean:.4} px", w * h);
        assert!(n as f64 >= 0.95 * (w * h) as f64, "only {n} valid pixels");
        assert!(inside_cell > 1000);
        assert_eq!(wrong, 0, "pixels decoded outside their code cell");
        // Linear crossing of box-integrated sharp edges is biased by up to ~0.07 px; blur smooths it.
        assert!(
            mean < if blur > 0.0 { 0.02 } else { 0.05 },
            "noise-free sub-pixel error {mean} px"
        );
    }
}

#[test]
fn sixteen_bit_and_threshold_mode_decode_the_same_codes() {
    let scene = plane_scene(
        Vec3::new(400.0, 0.0, 1600.0),
        Vec3::zeros(),
        0.5,
        0.5,
        vec![],
    );
    let sim = Simulator::new(scene);
    let capture = sim.capture(&sim.layout(), 0, &|_, _| {});
    let base = decode(&capture, &DecodeParams::default()).expect("decode");
    // 16 bit: the same frames scaled by 257 must give identical maps.
    let mut wide = capture.clone();
    for img in wide.frames.values_mut() {
        *img = GrayImage::from_u16(img.width, img.height, img.to_u16());
    }
    let dec16 = decode(&wide, &DecodeParams::default()).expect("decode 16");
    assert!(matches!(
        wide.frames[&Pattern::White].pixels,
        Pixels::U16(_)
    ));
    let same = base
        .col
        .iter()
        .zip(&dec16.col)
        .all(|(a, b)| (a.is_nan() && b.is_nan()) || (a - b).abs() < 1e-4);
    assert!(same, "16-bit decode differs");
    // Without inverses: threshold mode, still close to the dual result.
    let mut no_inv: CaptureSet = capture.clone();
    no_inv
        .frames
        .retain(|p, _| !matches!(p, Pattern::Gray { inverse: true, .. }));
    assert!(!no_inv.has_inverses(CodeAxis::Column));
    let thr = decode(&no_inv, &DecodeParams::default()).expect("threshold decode");
    assert_eq!(thr.binarization, Binarization::Threshold);
    let diffs: Vec<f32> = base
        .col
        .iter()
        .zip(&thr.col)
        .filter(|(a, b)| a.is_finite() && b.is_finite())
        .map(|(a, b)| (a - b).abs())
        .collect();
    let mean = diffs.iter().sum::<f32>() / diffs.len() as f32;
    eprintln!(
        "threshold mode: {} common pixels, mean |Δ| {mean:.4}",
        diffs.len()
    );
    assert!(diffs.len() as f64 > 0.9 * base.valid_count() as f64);
    assert!(
        mean < 0.05,
        "threshold decode deviates by {mean} px on average"
    );
    // Confidence says the threshold decode is of lower quality.
    let conf = |d: &ris_core::decode::Decoded| {
        d.confidence.iter().filter(|c| **c > 0.0).sum::<f32>() / d.valid_count() as f32
    };
    assert!(conf(&thr) < 0.75 * conf(&base));
}

#[test]
fn parallax_model_agrees_with_eq_2_37_in_the_parallel_configuration() {
    // Projector beside the camera at the same standoff, both looking straight down: the baseline
    // (d = 300 mm) is parallel to the reference plane.
    let (s, d) = (1600.0, 300.0);
    let box_obj = ObjectSection {
        shape: "box".into(),
        material: "matte".into(),
        center: Some([0.0, 0.0, 30.0]),
        size: Some([120.0, 90.0, 60.0]),
        ..Default::default()
    };
    let scene = plane_scene(
        Vec3::new(d, 0.0, s),
        Vec3::new(d, 0.0, 0.0),
        0.0,
        0.3,
        vec![box_obj],
    );
    let sim = Simulator::new(scene.clone());
    let layout = sim.layout();
    let dec = decode(
        &sim.capture(&layout, 0, &|_, _| {}),
        &DecodeParams::default(),
    )
    .expect("decode");
    let reference = Simulator::new(scene.reference());
    let dec_ref = decode(
        &reference.capture(&layout, 100, &|_, _| {}),
        &DecodeParams::default(),
    )
    .expect("ref");
    let rec =
        Reconstructor::parallax(&scene.camera, scene.projector.center(), &dec_ref).expect("model");
    let cloud = rec.reconstruct(&dec).expect("reconstruct");
    // For each point on the box top: m = |P_r − Q| recomputed from the reference decode, and
    // h from Eq. 2.37 must equal the general model's z.
    let rays = ris_core::sensor::RayTable::new(&scene.camera);
    let geometry = ris_core::sensor::Parallax::new(&scene.camera, scene.projector.center(), {
        // Same fit as the reconstructor.
        let r = Reconstructor::parallax(&scene.camera, scene.projector.center(), &dec_ref)
            .expect("model");
        drop(r);
        fit_reference(&scene, &rays, &dec_ref)
    });
    let (mut n, mut worst) = (0usize, 0.0f64);
    let mut top_err = Vec::new();
    let mut fast_gap = 0.0f64;
    for (p, &px) in cloud.points.iter().zip(&cloud.pixels) {
        if p[2] < 50.0 {
            continue;
        }
        let pp = geometry
            .point(&rays, px as usize, f64::from(dec.col[px as usize]))
            .expect("point");
        let h = parallel_height(s, d, pp.shift);
        worst = worst.max((h - pp.point.z).abs());
        // The reconstructor's fast path (quadratic table + one Newton step) equals the exact search.
        let fast = Vec3::new(p[0].into(), p[1].into(), p[2].into());
        fast_gap = fast_gap.max((fast - pp.point).norm());
        n += 1;
        top_err.push((f64::from(p[2]) - 60.0).abs());
    }
    let mean_top = top_err.iter().sum::<f64>() / top_err.len() as f64;
    eprintln!("{n} box-top points, mean |z − 60| {mean_top:.3} mm, max {:.3}; worst |Eq. 2.37 − general| = {worst:.2e} mm", top_err.iter().fold(0.0f64, |a, &b| a.max(b)));
    assert!(mean_top < 0.1, "box top mean error {mean_top} mm");
    eprintln!("fast path vs exact search: {fast_gap:.2e} mm (float32 output)");
    assert!(
        fast_gap < 1e-3,
        "fast parallax path deviates by {fast_gap} mm"
    );
    assert!(n > 1000);
    assert!(
        worst < 1e-6,
        "Eq. 2.37 and the general model disagree by {worst} mm"
    );
}

fn fit_reference(
    scene: &Scene,
    rays: &ris_core::sensor::RayTable,
    dec_ref: &ris_core::decode::Decoded,
) -> ris_core::sensor::reference::PlaneCodeMap {
    let mut samples = Vec::new();
    let oc = scene.camera.center();
    let (w, h) = (scene.camera.width as usize, scene.camera.height as usize);
    for v in 0..h {
        for u in 0..w {
            let c = dec_ref.col[v * w + u];
            if c.is_finite() {
                let d = scene.camera.r.transpose() * rays.camera_dir(u as u32, v as u32);
                let lam = -oc.z / d.z;
                samples.push(ris_core::sensor::reference::PlaneSample {
                    x: oc.x + lam * d.x,
                    y: oc.y + lam * d.y,
                    code: f64::from(c),
                });
            }
        }
    }
    ris_core::sensor::reference::PlaneCodeMap::fit(
        &samples,
        ris_core::sensor::reference::DEFAULT_DEGREE,
    )
    .expect("fit")
}
