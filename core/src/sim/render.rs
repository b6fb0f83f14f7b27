//! The render cache: the scene is ray-cast once per camera sub-sample (hit, shadow, projector
//! coordinate, irradiance), so each frame is only a weighted look-up of the projected light plus
//! noise.

use rand::rngs::SmallRng;
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;

use std::sync::{Arc, Mutex, PoisonError};

use super::light::{Grid, Light, MaskTap, Tap};
use super::scene::Scene;
use crate::geometry::Vec3;
use crate::io::bytes::{ByteReader, ByteWriter};

/// One directly lit camera sub-sample: where it sits in the projector, and its weight
/// ((albedo × cos + Blinn-Phong lobe) × irradiance falloff / sub-samples per pixel).
#[derive(Clone, Copy, Debug)]
struct LitSample {
    u: f32,
    v: f32,
    weight: f32,
}

/// Light a sub-sample receives from its lit neighbours (inter-reflection): the projector light
/// around (u, v) blurred over the material's inter-reflection radius, times `weight` (the
/// material's inter-reflection fraction times the sample's reflectance towards the camera).
#[derive(Clone, Copy, Debug)]
struct BounceSample {
    u: f32,
    v: f32,
    weight: f32,
    channel: u8,
}

/// Ground truth per camera pixel, from the ray through the pixel centre.
#[derive(Clone, Debug)]
pub struct Truth {
    /// Width.
    pub width: u32,
    /// Height.
    pub height: u32,
    /// Surface point (sensor world frame), NaN where the ray hits nothing.
    pub xyz: Vec<[f32; 3]>,
    /// Material index, 255 where nothing was hit.
    pub material: Vec<u8>,
    /// Fraction of the pixel's sub-samples lit by the projector (not shadowed).
    pub lit: Vec<f32>,
}

/// A sample's place on a light's grid and its weight (0 where the light does not reach it).
#[derive(Clone, Copy, Debug, Default)]
struct Located {
    tap: Tap,
    weight: f32,
}

/// Every sample located on the grids of one frame's lights: the direct light's for the lit
/// samples, each bounce channel's for the inter-reflection samples.
#[derive(Debug)]
struct FrameTaps {
    light: Grid,
    bounce: Vec<Grid>,
    lit: Vec<Located>,
    bounced: Vec<Located>,
}

/// Every sample located on the pixels of a projection mask of one size (the blurs of one mask,
/// and the masks of a scan, share it).
#[derive(Debug)]
struct MaskTaps {
    size: (usize, usize),
    lit: Vec<MaskTap>,
    bounced: Vec<MaskTap>,
}

/// Precomputed light transport of a scene.
#[derive(Debug)]
pub struct RenderCache {
    width: u32,
    height: u32,
    offsets: Vec<u32>,
    samples: Vec<LitSample>,
    bounce_offsets: Vec<u32>,
    bounces: Vec<BounceSample>,
    /// Inter-reflection blur (projector pixels) of each bounce channel.
    pub bounce_sigmas: Vec<f32>,
    ambient: Vec<f32>,
    /// Ground truth.
    pub truth: Truth,
    /// The samples located on the grids of the last frame's lights: the patterns of a scan
    /// share their grids, so each frame after the first only reads its profiles.
    taps: Mutex<Option<Arc<FrameTaps>>>,
    /// The samples located on the last mask's pixels.
    mask_taps: Mutex<Option<Arc<MaskTaps>>>,
}

impl Clone for RenderCache {
    fn clone(&self) -> RenderCache {
        RenderCache {
            width: self.width,
            height: self.height,
            offsets: self.offsets.clone(),
            samples: self.samples.clone(),
            bounce_offsets: self.bounce_offsets.clone(),
            bounces: self.bounces.clone(),
            bounce_sigmas: self.bounce_sigmas.clone(),
            ambient: self.ambient.clone(),
            truth: self.truth.clone(),
            taps: Mutex::new(None),
            mask_taps: Mutex::new(None),
        }
    }
}

impl RenderCache {
    /// The cache as bytes (every array bit-exact), read back by [`RenderCache::from_bytes`].
    pub fn to_bytes(&self) -> Vec<u8> {
        let n = self.offsets.len();
        let mut w = ByteWriter::with_capacity(64 + 40 * n + 16 * self.samples.len());
        w.u32(self.width);
        w.u32(self.height);
        w.u32s(&self.offsets);
        let (mut u, mut v, mut weight) = (Vec::new(), Vec::new(), Vec::new());
        for s in &self.samples {
            u.push(s.u);
            v.push(s.v);
            weight.push(s.weight);
        }
        for a in [&u, &v, &weight] {
            w.f32s(a);
        }
        w.u32s(&self.bounce_offsets);
        let (mut u, mut v, mut weight, mut channel) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for b in &self.bounces {
            u.push(b.u);
            v.push(b.v);
            weight.push(b.weight);
            channel.push(b.channel);
        }
        for a in [&u, &v, &weight] {
            w.f32s(a);
        }
        w.bytes(&channel);
        w.f32s(&self.bounce_sigmas);
        w.f32s(&self.ambient);
        let t = &self.truth;
        w.u32(t.width);
        w.u32(t.height);
        let xyz: Vec<f32> = t.xyz.iter().flatten().copied().collect();
        w.f32s(&xyz);
        w.bytes(&t.material);
        w.f32s(&t.lit);
        w.bytes
    }

    /// A cache written by [`RenderCache::to_bytes`]; `None` when the bytes are damaged or
    /// inconsistent (lengths, offsets).
    pub fn from_bytes(bytes: &[u8]) -> Option<RenderCache> {
        let mut r = ByteReader::new(bytes);
        let (width, height) = (r.u32()?, r.u32()?);
        let pixels = (width as usize).checked_mul(height as usize)?;
        let offsets = r.u32s()?;
        let (u, v, weight) = (r.f32s()?, r.f32s()?, r.f32s()?);
        let bounce_offsets = r.u32s()?;
        let (bu, bv, bweight) = (r.f32s()?, r.f32s()?, r.f32s()?);
        let channel = r.bytes()?;
        let bounce_sigmas = r.f32s()?;
        let ambient = r.f32s()?;
        let (tw, th) = (r.u32()?, r.u32()?);
        let xyz = r.f32s()?;
        let material = r.bytes()?.to_vec();
        let lit = r.f32s()?;
        let consistent = r.remaining() == 0
            && offsets.len() == pixels + 1
            && bounce_offsets.len() == pixels + 1
            && offsets.last().map(|&o| o as usize) == Some(u.len())
            && bounce_offsets.last().map(|&o| o as usize) == Some(bu.len())
            && offsets.windows(2).all(|w| w[0] <= w[1])
            && bounce_offsets.windows(2).all(|w| w[0] <= w[1])
            && v.len() == u.len()
            && weight.len() == u.len()
            && bv.len() == bu.len()
            && bweight.len() == bu.len()
            && channel.len() == bu.len()
            && channel.iter().all(|&c| (c as usize) < bounce_sigmas.len())
            && ambient.len() == pixels
            && (tw, th) == (width, height)
            && xyz.len() == 3 * pixels
            && material.len() == pixels
            && lit.len() == pixels;
        if !consistent {
            return None;
        }
        Some(RenderCache {
            width,
            height,
            offsets,
            samples: (0..u.len())
                .map(|i| LitSample {
                    u: u[i],
                    v: v[i],
                    weight: weight[i],
                })
                .collect(),
            bounce_offsets,
            bounces: (0..bu.len())
                .map(|i| BounceSample {
                    u: bu[i],
                    v: bv[i],
                    weight: bweight[i],
                    channel: channel[i],
                })
                .collect(),
            bounce_sigmas,
            ambient,
            truth: Truth {
                width,
                height,
                xyz: xyz.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
                material,
                lit,
            },
            taps: Mutex::new(None),
            mask_taps: Mutex::new(None),
        })
    }

    /// Ray-cast the scene (parallel over camera rows).
    pub fn build(scene: &Scene) -> RenderCache {
        let (w, h) = (scene.camera.width as usize, scene.camera.height as usize);
        let ss = scene.render.supersample as usize;
        let inv_n = 1.0 / (ss * ss) as f64;
        let oc = scene.camera.center();
        let op = scene.projector.center();
        let d0 = op.norm().max(1e-9);
        // One bounce channel per inter-reflecting material: its radius in projector pixels at
        // the cell's standoff.
        let fp = scene.projector.k[(0, 0)];
        let mut channel_of = vec![None; scene.materials.len()];
        let mut bounce_sigmas = Vec::new();
        for (i, m) in scene.materials.iter().enumerate() {
            if m.interreflection > 0.0 && bounce_sigmas.len() < 255 {
                channel_of[i] = Some(bounce_sigmas.len() as u8);
                bounce_sigmas.push((m.interreflection_radius * fp / d0).max(0.5) as f32);
            }
        }
        struct Row {
            counts: Vec<u32>,
            samples: Vec<LitSample>,
            bounce_counts: Vec<u32>,
            bounces: Vec<BounceSample>,
            ambient: Vec<f32>,
            xyz: Vec<[f32; 3]>,
            material: Vec<u8>,
            lit: Vec<f32>,
        }
        let rows: Vec<Row> = (0..h)
            .into_par_iter()
            .map(|v| {
                let mut row = Row {
                    counts: vec![0; w],
                    samples: Vec::new(),
                    bounce_counts: vec![0; w],
                    bounces: Vec::new(),
                    ambient: vec![0.0; w],
                    xyz: vec![[f32::NAN; 3]; w],
                    material: vec![255; w],
                    lit: vec![0.0; w],
                };
                // Each ray's lens solved from the last one's (sub-samples a fraction of a pixel
                // apart): one Newton step instead of two or three.
                let mut near = None;
                for u in 0..w {
                    let mut lit_count = 0usize;
                    for sy in 0..ss {
                        for sx in 0..ss {
                            let uu = u as f64 + (sx as f64 + 0.5) / ss as f64 - 0.5;
                            let vv = v as f64 + (sy as f64 + 0.5) / ss as f64 - 0.5;
                            let d = scene.camera.ray_near(uu, vv, &mut near);
                            let Some((t, mut n, obj)) =
                                scene.intersect(&oc, &d, 1e-6, f64::INFINITY)
                            else {
                                continue;
                            };
                            let p = oc + d * t;
                            if n.dot(&d) > 0.0 {
                                n = -n;
                            }
                            let albedo = scene.albedo(obj, &p);
                            let material = scene.objects[obj].material;
                            let mat = &scene.materials[material];
                            row.ambient[u] += (albedo * scene.ambient * inv_n) as f32;
                            if let Some(hit) = direct_light(scene, &p, &n, &op, d0) {
                                lit_count += 1;
                                let mut reflect = albedo * hit.cos;
                                if mat.specular > 0.0 {
                                    // Blinn-Phong: half vector between light and view.
                                    let h = (hit.to_light - d).normalize();
                                    reflect +=
                                        mat.specular * n.dot(&h).max(0.0).powf(mat.shininess);
                                }
                                row.samples.push(LitSample {
                                    u: hit.u as f32,
                                    v: hit.v as f32,
                                    weight: (reflect * hit.falloff * inv_n) as f32,
                                });
                                row.counts[u] += 1;
                                if let Some(channel) = channel_of[material] {
                                    row.bounces.push(BounceSample {
                                        u: hit.u as f32,
                                        v: hit.v as f32,
                                        // Re-scattered with the point's own reflectance
                                        // towards the camera (lobe included): shiny parts
                                        // pass bright neighbours' light on strongly.
                                        weight: (reflect
                                            * mat.interreflection
                                            * hit.falloff
                                            * inv_n)
                                            as f32,
                                        channel,
                                    });
                                    row.bounce_counts[u] += 1;
                                }
                            }
                        }
                    }
                    row.lit[u] = lit_count as f32 * inv_n as f32;
                    let d = scene.camera.ray_near(u as f64, v as f64, &mut near);
                    if let Some((t, _, obj)) = scene.intersect(&oc, &d, 1e-6, f64::INFINITY) {
                        let p = oc + d * t;
                        row.xyz[u] = [p.x as f32, p.y as f32, p.z as f32];
                        row.material[u] = scene.objects[obj].material.min(254) as u8;
                    }
                }
                row
            })
            .collect();
        let mut cache = RenderCache {
            width: w as u32,
            height: h as u32,
            offsets: Vec::with_capacity(w * h + 1),
            samples: Vec::with_capacity(rows.iter().map(|r| r.samples.len()).sum()),
            bounce_offsets: Vec::with_capacity(w * h + 1),
            bounces: Vec::with_capacity(rows.iter().map(|r| r.bounces.len()).sum()),
            bounce_sigmas,
            ambient: Vec::with_capacity(w * h),
            truth: Truth {
                width: w as u32,
                height: h as u32,
                xyz: Vec::with_capacity(w * h),
                material: Vec::with_capacity(w * h),
                lit: Vec::with_capacity(w * h),
            },
            taps: Mutex::new(None),
            mask_taps: Mutex::new(None),
        };
        cache.offsets.push(0);
        cache.bounce_offsets.push(0);
        for row in rows {
            for c in row.counts {
                let last = *cache.offsets.last().unwrap_or(&0);
                cache.offsets.push(last + c);
            }
            for c in row.bounce_counts {
                let last = *cache.bounce_offsets.last().unwrap_or(&0);
                cache.bounce_offsets.push(last + c);
            }
            cache.samples.extend(row.samples);
            cache.bounces.extend(row.bounces);
            cache.ambient.extend(row.ambient);
            cache.truth.xyz.extend(row.xyz);
            cache.truth.material.extend(row.material);
            cache.truth.lit.extend(row.lit);
        }
        cache
    }

    /// Render one 8-bit frame of the projector showing `light` (and `bounce`, the same light
    /// blurred by each of [`RenderCache::bounce_sigmas`]): signal = 255 × exposure × radiance,
    /// plus read and shot noise, rounded and clipped (saturation at 255).
    pub fn render(
        &self,
        light: &Light,
        bounce: &[Light],
        exposure: f64,
        noise: f64,
        shot_noise: f64,
        seed: u64,
    ) -> Vec<u8> {
        let w = self.width as usize;
        let mut out = vec![0u8; w * self.height as usize];
        let gain = (255.0 * exposure) as f32;
        let taps = self.taps(light, bounce);
        // Every light of a frame shows the same mask (blurred by its own σ), or none.
        let mask_taps = light.mask().map(|m| self.mask_taps(m.size()));
        out.par_chunks_mut(w).enumerate().for_each(|(v, row)| {
            let mut rng =
                SmallRng::seed_from_u64(seed ^ (v as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
            for (u, px) in row.iter_mut().enumerate() {
                let i = v * w + u;
                let mut radiance = self.ambient[i];
                let lit = self.offsets[i] as usize..self.offsets[i + 1] as usize;
                let bounced = self.bounce_offsets[i] as usize..self.bounce_offsets[i + 1] as usize;
                match (light.mask(), &mask_taps) {
                    (Some(m), Some(mt)) => {
                        for (t, mt) in taps.lit[lit.clone()].iter().zip(&mt.lit[lit]) {
                            radiance += t.weight * (light.stripes_at(&t.tap) * m.at(mt));
                        }
                    }
                    _ => {
                        for t in &taps.lit[lit] {
                            radiance += t.weight * light.stripes_at(&t.tap);
                        }
                    }
                }
                for (k, (t, s)) in taps.bounced[bounced.clone()]
                    .iter()
                    .zip(&self.bounces[bounced.clone()])
                    .enumerate()
                {
                    let l = &bounce[s.channel as usize];
                    let stripes = l.stripes_at(&t.tap);
                    radiance += t.weight
                        * match (l.mask(), &mask_taps) {
                            (None, _) => stripes,
                            // a bounce light's mask located with the direct light's
                            (Some(m), Some(mt)) if mt.size == m.size() => {
                                stripes * m.at(&mt.bounced[bounced.start + k])
                            }
                            (Some(m), _) => stripes * m.sample(s.u, s.v),
                        };
                }
                let signal = f64::from(gain * radiance);
                let sigma = (noise * noise + shot_noise * signal).sqrt();
                let z: f64 = if sigma > 0.0 {
                    StandardNormal.sample(&mut rng)
                } else {
                    0.0
                };
                // rounded half up (as `round` for the non-negative values that survive
                // the clamp, without its library call)
                *px = (signal + sigma * z + 0.5).clamp(0.0, 255.0) as u8;
            }
        });
        out
    }

    /// The samples located on the grids of `light` and `bounce`: the last frame's when the
    /// grids are the same, else found again (in parallel) and kept for the next frame.
    fn taps(&self, light: &Light, bounce: &[Light]) -> Arc<FrameTaps> {
        let grid = light.grid();
        let grids: Vec<Grid> = bounce.iter().map(Light::grid).collect();
        let locate = |l: &Light, u: f32, v: f32, weight: f32| match l.locate(u, v) {
            Some(tap) => Located { tap, weight },
            None => Located::default(),
        };
        kept_or(
            &self.taps,
            |t| t.light == grid && t.bounce == grids,
            || FrameTaps {
                light: grid,
                bounce: grids.clone(),
                lit: self
                    .samples
                    .par_iter()
                    .map(|s| locate(light, s.u, s.v, s.weight))
                    .collect(),
                bounced: self
                    .bounces
                    .par_iter()
                    .map(|s| locate(&bounce[s.channel as usize], s.u, s.v, s.weight))
                    .collect(),
            },
        )
    }

    /// The samples located on the pixels of a mask of `size`: the last mask's when it had
    /// this size, else found again (in parallel, outside the lock) and kept.
    fn mask_taps(&self, size: (usize, usize)) -> Arc<MaskTaps> {
        kept_or(
            &self.mask_taps,
            |t| t.size == size,
            || MaskTaps {
                size,
                lit: self
                    .samples
                    .par_iter()
                    .map(|s| MaskTap::locate(size, s.u, s.v))
                    .collect(),
                bounced: self
                    .bounces
                    .par_iter()
                    .map(|s| MaskTap::locate(size, s.u, s.v))
                    .collect(),
            },
        )
    }
}

/// The value kept in `slot` when it `fits`, else `make`'s, kept for the next call. `make` runs
/// outside the lock: a thread outside the rayon pool waiting under it on workers that wait on
/// the lock would never finish (two calls may then make the same value at once).
fn kept_or<T>(
    slot: &Mutex<Option<Arc<T>>>,
    fits: impl Fn(&T) -> bool,
    make: impl FnOnce() -> T,
) -> Arc<T> {
    let kept = slot.lock().unwrap_or_else(PoisonError::into_inner).clone();
    if let Some(t) = kept.filter(|t| fits(t)) {
        return t;
    }
    let made = Arc::new(make());
    *slot.lock().unwrap_or_else(PoisonError::into_inner) = Some(Arc::clone(&made));
    made
}

/// How the projector lights a surface point.
struct DirectHit {
    /// Projector coordinates.
    u: f64,
    v: f64,
    /// Cosine of the incidence angle.
    cos: f64,
    /// Inverse-square falloff relative to the standoff.
    falloff: f64,
    /// Unit vector towards the projector.
    to_light: Vec3,
}

/// Projector coordinate and irradiance at surface point `p` (normal `n`), or `None` when the
/// projector does not reach it (behind, outside its image, self-shadowed or occluded).
fn direct_light(scene: &Scene, p: &Vec3, n: &Vec3, op: &Vec3, d0: f64) -> Option<DirectHit> {
    let to_p = op - p;
    let dist = to_p.norm();
    let l = to_p / dist;
    let cos = n.dot(&l);
    if cos <= 0.0 {
        return None;
    }
    let (pu, pv) = scene.projector.project(p)?;
    let (pw, ph) = (
        f64::from(scene.projector.width),
        f64::from(scene.projector.height),
    );
    if pu < -2.0 || pv < -2.0 || pu > pw + 1.0 || pv > ph + 1.0 {
        return None;
    }
    let origin = p + n * 1e-3;
    if scene.intersect(&origin, &l, 0.0, dist - 2e-3).is_some() {
        return None;
    }
    Some(DirectHit {
        u: pu,
        v: pv,
        cos,
        falloff: (d0 / dist).powi(2),
        to_light: l,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pattern::{CodeLayout, Pattern, ProjectionMask};
    use crate::sim::Simulator;

    /// Each frame, its samples located once for a scan, is the sum the lights give at every
    /// sample, bit for bit: plain and masked (bounce lights under the same mask or a mask of
    /// another size), direct and inter-reflected light, and again after a blur that moves the
    /// profiles' grids (the direct light's and the bounce lights', or the bounce lights' alone).
    #[test]
    fn frames_read_every_sample_as_the_lights_give_it() {
        let sim = Simulator::new(crate::sim::tests::small_scene());
        let c = &sim.cache;
        assert!(!c.bounces.is_empty(), "the scene inter-reflects");
        let layout = CodeLayout::new(128, 96);
        let mask = ProjectionMask {
            width: 128,
            height: 96,
            values: (0..128 * 96).map(|i| 0.2 + (i % 7) as f32 / 10.0).collect(),
        };
        let direct = |light: &Light, bounce: &[Light]| -> Vec<u8> {
            (0..c.ambient.len())
                .map(|i| {
                    let mut radiance = c.ambient[i];
                    for s in &c.samples[c.offsets[i] as usize..c.offsets[i + 1] as usize] {
                        radiance += s.weight * light.sample(s.u, s.v);
                    }
                    for s in
                        &c.bounces[c.bounce_offsets[i] as usize..c.bounce_offsets[i + 1] as usize]
                    {
                        radiance += s.weight * bounce[s.channel as usize].sample(s.u, s.v);
                    }
                    (f64::from(255.0f32 * radiance) + 0.5).clamp(0.0, 255.0) as u8
                })
                .collect()
        };
        let column = Pattern::Gray {
            axis: crate::pattern::CodeAxis::Column,
            bit: 3,
            inverse: false,
        };
        // A bounce light may show a mask of another size than the direct light's.
        let small = ProjectionMask {
            width: 64,
            height: 48,
            values: (0..64 * 48).map(|i| 0.1 + (i % 5) as f32 / 6.0).collect(),
        };
        for blur in [0.6f32, 2.5] {
            for (masked, bounce_mask) in [
                (None, None),
                (Some(&mask), Some(&mask)),
                (Some(&mask), Some(&small)),
            ] {
                for pattern in [Pattern::White, column] {
                    let lights = |sigma: f32, m: Option<&ProjectionMask>| {
                        let l = sim.light_blurred(&layout, pattern, sigma);
                        match m {
                            Some(m) => l.masked(m, sigma),
                            None => l,
                        }
                    };
                    let light = lights(blur, masked);
                    let bounce: Vec<Light> = c
                        .bounce_sigmas
                        .iter()
                        .map(|s| lights((blur * blur + s * s).sqrt(), bounce_mask))
                        .collect();
                    let frame = c.render(&light, &bounce, 1.0, 0.0, 0.0, 0);
                    assert!(
                        frame == direct(&light, &bounce),
                        "blur {blur}, masks {:?} {:?}, {pattern:?}",
                        masked.map(|m| m.width),
                        bounce_mask.map(|m| m.width)
                    );
                }
            }
        }
        // Bounce lights blurred anew under the same direct light.
        let light = sim.light_blurred(&layout, column, 2.5);
        let bounce: Vec<Light> = c
            .bounce_sigmas
            .iter()
            .map(|s| sim.light_blurred(&layout, column, 3.0 * s))
            .collect();
        assert!(c.render(&light, &bounce, 1.0, 0.0, 0.0, 0) == direct(&light, &bounce));
    }
}
