//! Resolution and depth error of an omnidirectional sensor (Sec. 6.3): how much wall one
//! camera or projector pixel covers, and how far a point moves when either unit is off by one
//! pixel, as a function of the point's height and range. The mirror's curvature makes both
//! vary across the image, so the figures are given per point, not as one number.

use super::{MirrorUnit, OmniSensor, Ray};
use crate::geometry::Vec3;
use crate::{Error, Result};

/// The error figures at one wall point.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct ErrorPoint {
    /// Horizontal range of the point from the sensor's axis, mm.
    pub range_mm: f64,
    /// Height of the point in the sensor frame, mm.
    pub height_mm: f64,
    /// Elevation of the point seen from the camera's viewpoint, degrees (negative: below it).
    pub elevation_deg: f64,
    /// Distance of the point's camera pixel from the image of the mirror's axis, pixels.
    pub camera_radius_px: f64,
    /// Wall one camera pixel covers there (radially in the image: vertically on the wall), mm.
    pub camera_mm_per_px: f64,
    /// Wall one projector pixel covers there, mm.
    pub projector_mm_per_px: f64,
    /// How far the reconstructed point moves for a one-pixel camera error, mm.
    pub depth_error_camera_mm: f64,
    /// The same for a one-pixel projector error, mm.
    pub depth_error_projector_mm: f64,
    /// Both errors added (the bound Sec. 6.3 quotes), mm.
    pub depth_error_mm: f64,
}

/// The figures of `sensor` for wall points at each of `ranges` (mm, along the sensor's +x)
/// and each of `heights` (mm, sensor frame). A point that either unit cannot see, or whose
/// rays do not cross, is left out; an error says so when none is left.
pub fn analyse(sensor: &OmniSensor, ranges: &[f64], heights: &[f64]) -> Result<Vec<ErrorPoint>> {
    let mut out = Vec::new();
    for &range in ranges {
        for &z in heights {
            if let Some(p) = at(sensor, range, z) {
                out.push(p);
            }
        }
    }
    if out.is_empty() {
        return Err(Error::Insufficient(
            "no analysed point is seen by both the camera and the projector: check the ranges and heights against the mirrors' fields of view".into(),
        ));
    }
    Ok(out)
}

/// The pixel of `unit` that sees `p`, and the ray of the pixel one step further from the
/// image of the mirror's axis.
fn shifted(unit: &MirrorUnit, p: &Vec3) -> Option<((f64, f64), Ray, Ray)> {
    let ((u, v), _) = unit.project(p)?;
    let k = &unit.lens.k;
    let (cx, cy) = (k[(0, 2)], k[(1, 2)]);
    let r = (u - cx).hypot(v - cy);
    if r < 1e-6 {
        return None;
    }
    let (du, dv) = ((u - cx) / r, (v - cy) / r);
    let here = unit.back_project(u, v)?;
    let next = unit.back_project(u + du, v + dv)?;
    Some(((u - cx, v - cy), here, next))
}

fn at(sensor: &OmniSensor, range: f64, z: f64) -> Option<ErrorPoint> {
    let p = Vec3::new(range, 0.0, z);
    let (cr, cam, cam_next) = shifted(&sensor.camera, &p)?;
    let (_, proj, proj_next) = shifted(&sensor.projector, &p)?;
    // Wall footprints: where the shifted rays meet the wall plane x = range.
    let wall = |ray: &Ray| -> Option<Vec3> {
        (ray.direction.x.abs() > 1e-12).then(|| {
            let s = (range - ray.origin.x) / ray.direction.x;
            ray.origin + ray.direction * s
        })
    };
    let camera_mm_per_px = (wall(&cam_next)? - p).norm();
    let projector_mm_per_px = (wall(&proj_next)? - p).norm();
    let depth_error_camera_mm = (crossing(&cam_next, &proj)? - p).norm();
    let depth_error_projector_mm = (crossing(&cam, &proj_next)? - p).norm();
    let f1 = sensor.camera.viewpoint();
    let d = p - f1;
    Some(ErrorPoint {
        range_mm: range,
        height_mm: z,
        elevation_deg: d.z.atan2(d.x.hypot(d.y)).to_degrees(),
        camera_radius_px: cr.0.hypot(cr.1),
        camera_mm_per_px,
        projector_mm_per_px,
        depth_error_camera_mm,
        depth_error_projector_mm,
        depth_error_mm: depth_error_camera_mm + depth_error_projector_mm,
    })
}

/// The midpoint of the shortest segment between two rays; `None` when they are parallel.
pub fn crossing(a: &Ray, b: &Ray) -> Option<Vec3> {
    let w = a.origin - b.origin;
    let (da, db) = (a.direction, b.direction);
    let (aa, ab, bb) = (da.dot(&da), da.dot(&db), db.dot(&db));
    let (aw, bw) = (da.dot(&w), db.dot(&w));
    let den = aa * bb - ab * ab;
    if den.abs() < 1e-12 {
        return None;
    }
    let s = (ab * bw - bb * aw) / den;
    let t = (aa * bw - ab * aw) / den;
    Some((a.origin + da * s + b.origin + db * t) * 0.5)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::omni::OmniFile;

    /// The seed's stacked layout (SPEC §13): its prototype mirrors, the camera unit above
    /// (F1 at z = +150 mm, facing down), the projector unit below (F1 at −150 mm), both of
    /// `side` pixels across the mirror's image (the rim fills the image's height).
    fn sensor(width: u32, height: u32) -> OmniSensor {
        // The rim (30 mm) is seen 106.7 mm from F2: it fills the height at f = r·106.7/30.
        let f = 0.5 * f64::from(height) * 106.7 / 30.0;
        let (cx, cy) = (0.5 * f64::from(width) - 0.5, 0.5 * f64::from(height) - 0.5);
        let unit = |r: &str, t: f64| {
            format!(
                "width = {width}\nheight = {height}\nk = [[{f}, 0.0, {cx}], [0.0, {f}, {cy}], [0.0, 0.0, 1.0]]\n[{{}}.mirror]\na = {a}\nb = {b}\nrim = 30.0\nr = {r}\nt = [0.0, 0.0, {t}]\n",
                a = 1248.2060f64.sqrt(),
                b = 351.7940f64.sqrt(),
            )
        };
        let down = "[[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]";
        let up = "[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]";
        let text = format!(
            "kind = \"omni\"\n[camera]\n{}[projector]\n{}",
            unit(down, 190.0).replace("{}", "camera"),
            unit(up, -190.0).replace("{}", "projector")
        );
        let file: OmniFile = toml::from_str(&text).expect("toml");
        OmniSensor::from_file(&file, std::path::Path::new("."), "test").expect("sensor")
    }

    fn level(points: &[ErrorPoint], range: f64) -> ErrorPoint {
        *points
            .iter()
            .filter(|p| p.range_mm == range)
            .min_by(|a, b| a.height_mm.abs().total_cmp(&b.height_mm.abs()))
            .expect("a point at that range")
    }

    #[test]
    fn errors_have_the_seeds_size_and_scale_with_pixels_and_range() {
        let heights: Vec<f64> = (-15..=3).map(|k| f64::from(k) * 100.0).collect();
        let small = analyse(&sensor(640, 480), &[2500.0, 4000.0], &heights).expect("640x480");
        let large = analyse(&sensor(2048, 2048), &[2500.0, 4000.0], &heights).expect("2k");
        let (s25, s40) = (level(&small, 2500.0), level(&small, 4000.0));
        let (l25, l40) = (level(&large, 2500.0), level(&large, 4000.0));
        // The seed: a one-pixel error moves a point 160 mm at 2.5 m with 640x480, 39 mm with
        // 2k x 2k (170 and 42 mm here, for either unit at the level between them).
        assert!(
            (120.0..220.0).contains(&s25.depth_error_camera_mm),
            "{s25:?}"
        );
        assert!((28.0..55.0).contains(&l25.depth_error_camera_mm), "{l25:?}");
        assert!(
            (s25.depth_error_mm - s25.depth_error_camera_mm - s25.depth_error_projector_mm).abs()
                < 1e-9
        );
        // Error scales with the pixels across the mirror's image (480 → 2048) …
        let ratio = s25.depth_error_mm / l25.depth_error_mm;
        assert!((3.0..6.0).contains(&ratio), "640x480 / 2k: {ratio:.2}");
        // … and grows with the square of range, as triangulation over a fixed baseline does
        // (the seed's 4 m figures, 256 and 62 mm, grow about linearly instead).
        for (near, far) in [(s25, s40), (l25, l40)] {
            let g = far.depth_error_mm / near.depth_error_mm;
            assert!((2.2..2.9).contains(&g), "4 m / 2.5 m: {g:.2}");
        }
        // One camera pixel covers some millimetres of wall at 2.5 m (the seed: 7 to 25).
        assert!(
            (3.0..40.0).contains(&s25.camera_mm_per_px),
            "{:.1} mm/px",
            s25.camera_mm_per_px
        );
    }

    #[test]
    fn a_one_pixel_error_moves_the_point_as_much_as_a_closed_form_says() {
        // Rays from two viewpoints B apart vertically meet at range D; an angular error δθ of
        // one ray moves the crossing by about D² δθ / (B cos²θ) along the other ray's
        // direction, up to the angle between them.
        let s = sensor(640, 480);
        let p = analyse(&s, &[2500.0], &[0.0]).expect("analysed")[0];
        let q = Vec3::new(2500.0, 0.0, 0.0);
        let ((u, v), _) = s.camera.project(&q).expect("seen");
        let k = &s.camera.lens.k;
        let (cx, cy) = (k[(0, 2)], k[(1, 2)]);
        let r = (u - cx).hypot(v - cy);
        let a = s.camera.back_project(u, v).expect("ray").direction;
        let b = s
            .camera
            .back_project(u + (u - cx) / r, v + (v - cy) / r)
            .expect("ray")
            .direction;
        let dtheta = a.angle(&b);
        let f_c = s.camera.viewpoint();
        let f_p = s.projector.viewpoint();
        let baseline = (f_c - f_p).norm();
        let (dc, dp) = (q - f_c, q - f_p);
        let gamma = dc.angle(&dp);
        // The crossing moves along the projector's ray: range error × (distance / range).
        let expected = dc.norm() * dtheta / gamma.sin();
        let rel = p.depth_error_camera_mm / expected;
        assert!(
            (0.9..1.1).contains(&rel),
            "{:.1} mm against {expected:.1} mm (baseline {baseline:.0} mm)",
            p.depth_error_camera_mm
        );
    }
}
