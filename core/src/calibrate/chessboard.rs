//! Chessboard inner-corner detection (SPEC §7): saddle points of the smoothed image, normalised
//! by the local contrast so that shadowed corners count; a grid grown from a seed by prediction,
//! every member checked to be an X-junction (four alternating sectors); sub-pixel refinement by
//! the gradient-orthogonality condition. Corners that cannot be seen are reported as missing, never
//! guessed; a grid that cannot be placed on the board unambiguously is an error.

use std::collections::{HashMap, VecDeque};

use serde::{Deserialize, Serialize};

use crate::image::gaussian_blur;
use crate::{Error, Result};

/// Inner corners of a chessboard along its two grid directions.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct BoardSize {
    /// Inner corners along the board's x direction.
    pub cols: usize,
    /// Inner corners along the board's y direction.
    pub rows: usize,
}

impl BoardSize {
    /// Parse `"9x6"`.
    pub fn parse(text: &str) -> Option<BoardSize> {
        let (a, b) = text.split_once(['x', 'X'])?;
        let (cols, rows) = (a.trim().parse().ok()?, b.trim().parse().ok()?);
        (cols >= 2 && rows >= 2).then_some(BoardSize { cols, rows })
    }

    /// Number of inner corners.
    pub fn len(&self) -> usize {
        self.cols * self.rows
    }

    /// Whether the board has no corners (never for a parsed size).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Detected inner corners, row-major (`j * cols + i`), pixel coordinates (SPEC §2). The index `i`
/// runs along the board's x direction and increases with image u; `(i, j)` appear in the image
/// with the handedness of `(u, v)`.
#[derive(Clone, Debug)]
pub struct Corners {
    /// The board the corners belong to.
    pub board: BoardSize,
    /// Position of each corner, `None` where it was not found.
    pub points: Vec<Option<[f64; 2]>>,
}

impl Corners {
    /// Number of corners found.
    pub fn found(&self) -> usize {
        self.points.iter().flatten().count()
    }

    /// Grid indices `(i, j)` of the corners that were not found.
    pub fn missing(&self) -> Vec<(usize, usize)> {
        self.points
            .iter()
            .enumerate()
            .filter(|(_, p)| p.is_none())
            .map(|(k, _)| (k % self.board.cols, k / self.board.cols))
            .collect()
    }

    /// Found corners with their grid indices.
    pub fn iter_found(&self) -> impl Iterator<Item = ((usize, usize), [f64; 2])> + '_ {
        let cols = self.board.cols;
        self.points
            .iter()
            .enumerate()
            .filter_map(move |(k, p)| p.map(|p| ((k % cols, k / cols), p)))
    }
}

/// Detector settings; the defaults suit boards whose squares are 12 px or larger.
#[derive(Clone, Debug)]
pub struct DetectParams {
    /// Smoothing before the saddle measure, pixels (squares should be 8 px or larger).
    pub sigma: f32,
    /// Smallest light–dark difference (8-bit levels) of a corner.
    pub min_contrast: f32,
    /// Threshold on the contrast-normalised saddle measure.
    pub min_response: f32,
    /// Half window of the sub-pixel refinement; `None` picks 40 % of the local square size,
    /// at most 11.
    pub refine_half_window: Option<usize>,
    /// Most seeds tried before giving up.
    pub max_seeds: usize,
}

impl Default for DetectParams {
    fn default() -> Self {
        DetectParams {
            sigma: 1.5,
            min_contrast: 12.0,
            min_response: 0.25,
            refine_half_window: None,
            max_seeds: 200,
        }
    }
}

#[derive(Clone, Copy, Debug)]
struct Candidate {
    x: f64,
    y: f64,
    response: f32,
}

/// Find the inner corners of `board` in an image of 8-bit levels (`width × height`, row-major).
/// Errors say why no board could be placed: no grid, or a grid of the wrong extent (a board cut by
/// the image border or by a shadow, or clutter continuing the grid).
pub fn detect(
    levels: &[f32],
    width: usize,
    height: usize,
    board: BoardSize,
    params: &DetectParams,
) -> Result<Corners> {
    if levels.len() != width * height || width < 16 || height < 16 {
        return Err(Error::Insufficient(format!(
            "chessboard: image of {width}x{height} with {} samples is too small or inconsistent",
            levels.len()
        )));
    }
    // Corners are refined on the full-resolution image in any case.
    let img = Image {
        data: gaussian_blur(levels, width, height, 0.7),
        width,
        height,
    };
    // A large image is searched at half resolution first (a quarter of the work; its squares
    // are large enough there), and at full resolution if that does not find the whole board.
    if width.min(height) >= HALF_RESOLUTION_FROM {
        let (half, hw, hh) = half_resolution(levels, width, height);
        if let Ok((mut corners, spacing)) = coarse(&half, hw, hh, board, params) {
            if corners.found() == board.len() {
                for p in corners.points.iter_mut().flatten() {
                    *p = [2.0 * p[0] + 0.5, 2.0 * p[1] + 0.5];
                }
                return Ok(refine_all(&img, corners, 2.0 * spacing, params));
            }
        }
    }
    let (corners, spacing) = coarse(levels, width, height, board, params)?;
    Ok(refine_all(&img, corners, spacing, params))
}

/// Images whose smaller side has at least this many pixels are searched at half resolution
/// first.
const HALF_RESOLUTION_FROM: usize = 960;

/// 2 × 2 box average: pixel (x, y) covers full-resolution pixels 2x…2x+1, 2y…2y+1, so its
/// centre is at full-resolution 2x + 0.5.
fn half_resolution(levels: &[f32], width: usize, height: usize) -> (Vec<f32>, usize, usize) {
    use rayon::prelude::*;
    let (hw, hh) = (width / 2, height / 2);
    let mut out = vec![0.0f32; hw * hh];
    out.par_chunks_mut(hw).enumerate().for_each(|(y, row)| {
        let (a, b) = (&levels[2 * y * width..], &levels[(2 * y + 1) * width..]);
        for (x, o) in row.iter_mut().enumerate() {
            *o = 0.25 * (a[2 * x] + a[2 * x + 1] + b[2 * x] + b[2 * x + 1]);
        }
    });
    (out, hw, hh)
}

/// The board's corners at pixel precision (saddle points grown into a grid and placed on the
/// board), and the grid's square size in pixels.
fn coarse(
    levels: &[f32],
    width: usize,
    height: usize,
    board: BoardSize,
    params: &DetectParams,
) -> Result<(Corners, f64)> {
    let smooth = Image {
        data: gaussian_blur(levels, width, height, params.sigma),
        width,
        height,
    };
    let candidates = saddles(&smooth, params);
    if candidates.len() < 4 {
        return Err(Error::Insufficient(format!(
            "chessboard: {} saddle points in the image, no board",
            candidates.len()
        )));
    }
    let buckets = Buckets::new(&candidates, width, height);
    let mut order: Vec<usize> = (0..candidates.len()).collect();
    order.sort_by(|&a, &b| candidates[b].response.total_cmp(&candidates[a].response));

    // Seeds in order of response; a grid that fits the board ends the search (unless another
    // finds more of its corners), one that does not is remembered for the error message.
    let mut best: Option<(Corners, Grid)> = None;
    let mut failure: Option<(usize, Error)> = None;
    let mut taken = vec![false; candidates.len()];
    let mut tried = 0;
    for &seed in &order {
        if taken[seed] {
            continue;
        }
        if tried == params.max_seeds {
            break;
        }
        tried += 1;
        taken[seed] = true;
        let Some(grid) = grow(&smooth, &candidates, &buckets, seed, params) else {
            continue;
        };
        for &c in grid.nodes.values() {
            taken[c] = true;
        }
        match place(&grid, &candidates, board) {
            Ok(corners) => {
                let found = corners.found();
                if best.as_ref().is_none_or(|(b, _)| found > b.found()) {
                    best = Some((corners, grid));
                }
                if found == board.len() {
                    break;
                }
            }
            Err(e) => {
                if failure.as_ref().is_none_or(|(n, _)| grid.nodes.len() > *n) {
                    failure = Some((grid.nodes.len(), e));
                }
            }
        }
    }
    match (best, failure) {
        (Some((corners, grid)), _) => Ok((corners, grid.spacing)),
        (None, Some((_, e))) => Err(e),
        (None, None) => Err(Error::Insufficient(
            "chessboard: no grid of X-junctions found".to_string(),
        )),
    }
}

/// Every corner refined to sub-pixel precision on `img`, with a window that follows the local
/// square size (under perspective a board-wide size would reach the neighbouring corners where
/// the squares are small); `spacing` is the grid's square size, pixels.
fn refine_all(img: &Image, mut corners: Corners, spacing: f64, params: &DetectParams) -> Corners {
    let board = corners.board;
    let (cols, rows) = (board.cols as i64, board.rows as i64);
    let coarse = corners.points.clone();
    for (k, slot) in corners.points.iter_mut().enumerate() {
        let Some(p) = *slot else { continue };
        let (i, j) = ((k % board.cols) as i64, (k / board.cols) as i64);
        let local = [(1, 0), (-1, 0), (0, 1), (0, -1)]
            .iter()
            .filter_map(|&(di, dj)| {
                let (ni, nj) = (i + di, j + dj);
                if ni < 0 || nj < 0 || ni >= cols || nj >= rows {
                    return None;
                }
                let q = coarse[(nj * cols + ni) as usize]?;
                Some(((q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2)).sqrt())
            })
            .fold(spacing, f64::min);
        let half = params
            .refine_half_window
            .unwrap_or_else(|| ((0.4 * local).round() as usize).clamp(2, 11));
        // A corner whose refinement leaves its window (or the image) is reported missing
        // rather than kept at its coarse position.
        *slot = refine(img, p[0], p[1], half);
        if slot.is_none() {
            tracing::debug!(
                i,
                j,
                "chessboard corner dropped: sub-pixel refinement failed"
            );
        }
    }
    corners
}

/// A row-major f32 image with bilinear sampling.
struct Image {
    data: Vec<f32>,
    width: usize,
    height: usize,
}

impl Image {
    #[inline]
    fn at(&self, x: usize, y: usize) -> f32 {
        self.data[y * self.width + x]
    }

    /// Bilinear sample; `None` outside the image.
    #[inline]
    fn sample(&self, x: f64, y: f64) -> Option<f32> {
        if x < 0.0 || y < 0.0 {
            return None;
        }
        let (x0, y0) = (x as usize, y as usize);
        if x0 + 1 >= self.width || y0 + 1 >= self.height {
            return None;
        }
        let (fx, fy) = ((x - x0 as f64) as f32, (y - y0 as f64) as f32);
        let top = self.at(x0, y0) * (1.0 - fx) + self.at(x0 + 1, y0) * fx;
        let bottom = self.at(x0, y0 + 1) * (1.0 - fx) + self.at(x0 + 1, y0 + 1) * fx;
        Some(top * (1.0 - fy) + bottom * fy)
    }
}

/// Local maxima of the saddle measure `−det(Hessian) σ² / (gradient energy + floor)`.
fn saddles(img: &Image, params: &DetectParams) -> Vec<Candidate> {
    use rayon::prelude::*;
    let (w, h) = (img.width, img.height);
    let mut det = vec![0.0f32; w * h];
    let mut energy = vec![0.0f32; w * h];
    det.par_chunks_mut(w)
        .zip(energy.par_chunks_mut(w))
        .enumerate()
        .for_each(|(y, (drow, erow))| {
            if y == 0 || y + 1 >= h {
                return;
            }
            for x in 1..w - 1 {
                let c = img.at(x, y);
                let ixx = img.at(x + 1, y) - 2.0 * c + img.at(x - 1, y);
                let iyy = img.at(x, y + 1) - 2.0 * c + img.at(x, y - 1);
                let ixy = 0.25
                    * (img.at(x + 1, y + 1) - img.at(x - 1, y + 1) - img.at(x + 1, y - 1)
                        + img.at(x - 1, y - 1));
                drow[x] = (ixy * ixy - ixx * iyy).max(0.0);
                let gx = 0.5 * (img.at(x + 1, y) - img.at(x - 1, y));
                let gy = 0.5 * (img.at(x, y + 1) - img.at(x, y - 1));
                erow[x] = gx * gx + gy * gy;
            }
        });
    let energy = gaussian_blur(&energy, w, h, 2.0 * params.sigma);
    let s2 = params.sigma * params.sigma;
    // A step of height C blurred by σ has a peak gradient of C / (σ √(2π)).
    let floor = (params.min_contrast / (params.sigma * 2.5)).powi(2);
    let response: Vec<f32> = det
        .par_iter()
        .zip(energy.par_iter())
        .map(|(&d, &e)| d * s2 / (e + floor))
        .collect();
    let radius = (1.5 * params.sigma).ceil().max(2.0) as usize;
    let threshold = params.min_response;
    let rows: Vec<Vec<Candidate>> = (radius..h.saturating_sub(radius))
        .into_par_iter()
        .map(|y| {
            let mut out = Vec::new();
            for x in radius..w - radius {
                let r = response[y * w + x];
                if r < threshold {
                    continue;
                }
                let mut is_max = true;
                'win: for yy in y - radius..=y + radius {
                    for xx in x - radius..=x + radius {
                        let o = response[yy * w + xx];
                        if o > r || (o == r && (yy, xx) < (y, x)) {
                            is_max = false;
                            break 'win;
                        }
                    }
                }
                if !is_max {
                    continue;
                }
                let peak = |a: f32, b: f32, c: f32| {
                    let den = a - 2.0 * b + c;
                    if den < 0.0 {
                        f64::from((0.5 * (a - c) / den).clamp(-0.5, 0.5))
                    } else {
                        0.0
                    }
                };
                let dx = peak(response[y * w + x - 1], r, response[y * w + x + 1]);
                let dy = peak(response[(y - 1) * w + x], r, response[(y + 1) * w + x]);
                out.push(Candidate {
                    x: x as f64 + dx,
                    y: y as f64 + dy,
                    response: r,
                });
            }
            out
        })
        .collect();
    rows.into_iter().flatten().collect()
}

/// Whether a circle of `radius` around (x, y) crosses four alternating light and dark sectors of
/// at least `min_contrast`, point-symmetric like an inner chessboard corner; returns the
/// orientation of its light sectors (the phase of the ring's second harmonic, radians), which
/// turns by half a revolution from one corner to the next.
fn x_junction(img: &Image, x: f64, y: f64, radius: f64, min_contrast: f32) -> Option<f64> {
    const N: usize = 32;
    let mut ring = [0.0f32; N];
    for (k, v) in ring.iter_mut().enumerate() {
        let a = k as f64 * std::f64::consts::TAU / N as f64;
        *v = img.sample(x + radius * a.cos(), y + radius * a.sin())?;
    }
    // Compare each sample with the one a quarter turn on: light against dark sectors alternate
    // in sign four times around an X-junction, also where a soft shadow dims part of it.
    let mut diff = [0.0f32; N];
    for (k, d) in diff.iter_mut().enumerate() {
        *d = ring[k] - ring[(k + N / 4) % N];
    }
    let peak = diff.iter().fold(0.0f32, |m, d| m.max(d.abs()));
    if peak < min_contrast {
        return None;
    }
    let amplitude: f32 = diff.iter().map(|d| d.abs()).sum::<f32>() / N as f32;
    let asymmetry: f32 = (0..N)
        .map(|k| (ring[k] - ring[(k + N / 2) % N]).abs())
        .sum::<f32>()
        / N as f32;
    if asymmetry > 0.35 * amplitude {
        return None;
    }
    // Signs of the samples clear of the band around zero, counted cyclically.
    let band = 0.2 * peak;
    let mut classes = [0i8; N];
    let mut n = 0;
    for d in diff.iter().filter(|d| d.abs() > band) {
        classes[n] = if *d > 0.0 { 1 } else { -1 };
        n += 1;
    }
    if n < N / 2 {
        return None;
    }
    let changes = (0..n)
        .filter(|&k| classes[k] != classes[(k + 1) % n])
        .count();
    if changes != 4 {
        return None;
    }
    let (mut re, mut im) = (0.0f64, 0.0f64);
    for (k, &v) in ring.iter().enumerate() {
        let a = 2.0 * k as f64 * std::f64::consts::TAU / N as f64;
        re += f64::from(v) * a.cos();
        im += f64::from(v) * a.sin();
    }
    Some(im.atan2(re))
}

/// Candidates binned on a coarse grid for radius queries.
struct Buckets {
    cell: f64,
    nx: usize,
    ny: usize,
    bins: Vec<Vec<usize>>,
}

impl Buckets {
    fn new(c: &[Candidate], width: usize, height: usize) -> Buckets {
        let cell = 16.0;
        let nx = (width as f64 / cell).ceil() as usize + 1;
        let ny = (height as f64 / cell).ceil() as usize + 1;
        let mut bins = vec![Vec::new(); nx * ny];
        for (i, p) in c.iter().enumerate() {
            bins[(p.y / cell) as usize * nx + (p.x / cell) as usize].push(i);
        }
        Buckets { cell, nx, ny, bins }
    }

    /// Indices of candidates within `r` of (x, y), nearest first.
    fn within(&self, c: &[Candidate], x: f64, y: f64, r: f64) -> Vec<(f64, usize)> {
        let span = |v: f64, n: usize| {
            let lo = ((v - r) / self.cell).floor().max(0.0) as usize;
            let hi = (((v + r) / self.cell).floor().max(0.0) as usize).min(n - 1);
            lo..=hi
        };
        let mut out = Vec::new();
        for by in span(y, self.ny) {
            for bx in span(x, self.nx) {
                for &i in &self.bins[by * self.nx + bx] {
                    let d = ((c[i].x - x).powi(2) + (c[i].y - y).powi(2)).sqrt();
                    if d <= r {
                        out.push((d, i));
                    }
                }
            }
        }
        out.sort_by(|a, b| a.0.total_cmp(&b.0));
        out
    }
}

/// A grid of candidates with integer indices, grown from one seed.
struct Grid {
    nodes: HashMap<(i32, i32), usize>,
    /// Median distance between grid neighbours, pixels.
    spacing: f64,
}

/// Smallest square (pixels) the detector resolves.
const MIN_SQUARE: f64 = 8.0;

const DIRS: [(i32, i32); 4] = [(1, 0), (-1, 0), (0, 1), (0, -1)];

fn grow(
    img: &Image,
    c: &[Candidate],
    buckets: &Buckets,
    seed: usize,
    params: &DetectParams,
) -> Option<Grid> {
    let s = c[seed];
    let near = buckets.within(c, s.x, s.y, 200.0);
    // Axis `a`: nearest neighbour with an opposite partner; axis `b`: the nearest roughly
    // perpendicular one with an opposite partner.
    let vec_to = |i: usize| [c[i].x - s.x, c[i].y - s.y];
    let partner = |v: [f64; 2]| -> Option<usize> {
        let n = (v[0] * v[0] + v[1] * v[1]).sqrt();
        buckets
            .within(c, s.x - v[0], s.y - v[1], 0.25 * n)
            .first()
            .map(|&(_, i)| i)
    };
    let check = |i: usize, r: f64| x_junction(img, c[i].x, c[i].y, r, params.min_contrast);
    // Neighbours along the grid have opposite polarity.
    let opposite = |p: f64, q: f64| (p - q).cos() < -0.3;
    let neighbour = |i: usize, d: f64| -> bool {
        check(seed, 0.3 * d).is_some_and(|p0| check(i, 0.3 * d).is_some_and(|p| opposite(p, p0)))
    };
    let mut axes: Vec<([f64; 2], usize, usize)> = Vec::new();
    for &(d, i) in near.iter().skip(1).take(16) {
        if d < MIN_SQUARE || !neighbour(i, d) {
            continue;
        }
        let v = vec_to(i);
        let Some(j) = partner(v) else { continue };
        if !neighbour(j, d) {
            continue;
        }
        match axes.first() {
            None => axes.push((v, i, j)),
            Some((a, _, _)) => {
                let na = (a[0] * a[0] + a[1] * a[1]).sqrt();
                let cos = (a[0] * v[0] + a[1] * v[1]) / (na * d);
                if cos.abs() < 0.5 && (0.5..2.0).contains(&(d / na)) {
                    axes.push((v, i, j));
                    break;
                }
            }
        }
    }
    if axes.len() < 2 {
        return None;
    }
    let (a, ia, ja) = axes[0];
    let (b, ib, jb) = axes[1];
    let norm = |v: [f64; 2]| (v[0] * v[0] + v[1] * v[1]).sqrt();
    let radius = 0.3 * norm(a).min(norm(b));
    let mut nodes: HashMap<(i32, i32), usize> = HashMap::new();
    let mut used: HashMap<usize, (i32, i32)> = HashMap::new();
    let mut phase: HashMap<(i32, i32), f64> = HashMap::new();
    for (cell, i) in [
        ((0, 0), seed),
        ((1, 0), ia),
        ((-1, 0), ja),
        ((0, 1), ib),
        ((0, -1), jb),
    ] {
        if used.insert(i, cell).is_some() {
            return None;
        }
        nodes.insert(cell, i);
        phase.insert(cell, check(i, radius).unwrap_or(0.0));
    }
    let pos = |i: usize| [c[i].x, c[i].y];
    let mut queue: VecDeque<(i32, i32)> = nodes.keys().copied().collect();
    while let Some(cell) = queue.pop_front() {
        let p = pos(nodes[&cell]);
        for d in DIRS {
            let target = (cell.0 + d.0, cell.1 + d.1);
            if nodes.contains_key(&target) {
                continue;
            }
            let step = predict_step(&nodes, c, cell, d).unwrap_or(match d {
                (1, 0) => a,
                (-1, 0) => [-a[0], -a[1]],
                (0, 1) => b,
                _ => [-b[0], -b[1]],
            });
            let len = norm(step);
            let (px, py) = (p[0] + step[0], p[1] + step[1]);
            let from = phase[&cell];
            let hit = buckets
                .within(c, px, py, 0.3 * len)
                .into_iter()
                .filter(|&(_, i)| !used.contains_key(&i))
                .find_map(|(_, i)| {
                    let p = check(i, 0.3 * len)?;
                    opposite(p, from).then_some((i, p))
                });
            if let Some((i, p)) = hit {
                used.insert(i, target);
                nodes.insert(target, i);
                phase.insert(target, p);
                queue.push_back(target);
            }
        }
    }
    let graph = &nodes;
    let mut gaps: Vec<f64> = graph
        .iter()
        .flat_map(|(&(i, j), &n)| {
            [(1, 0), (0, 1)]
                .into_iter()
                .filter_map(move |d| Some((n, *graph.get(&(i + d.0, j + d.1))?)))
        })
        .map(|(m, n)| norm([c[m].x - c[n].x, c[m].y - c[n].y]))
        .collect();
    gaps.sort_by(f64::total_cmp);
    let spacing = gaps.get(gaps.len() / 2).copied().unwrap_or(norm(a));
    Some(Grid { nodes, spacing })
}

/// Step from `cell` towards `cell + d` predicted from known neighbours: the step into `cell`
/// along `d`, else the parallel step of a neighbouring row or column.
fn predict_step(
    nodes: &HashMap<(i32, i32), usize>,
    c: &[Candidate],
    cell: (i32, i32),
    d: (i32, i32),
) -> Option<[f64; 2]> {
    let at = |k: (i32, i32)| nodes.get(&k).map(|&i| [c[i].x, c[i].y]);
    let p = at(cell)?;
    if let Some(q) = at((cell.0 - d.0, cell.1 - d.1)) {
        return Some([p[0] - q[0], p[1] - q[1]]);
    }
    for e in [(d.1, d.0), (-d.1, -d.0)] {
        let side = (cell.0 + e.0, cell.1 + e.1);
        if let (Some(q0), Some(q1)) = (at(side), at((side.0 + d.0, side.1 + d.1))) {
            return Some([q1[0] - q0[0], q1[1] - q0[1]]);
        }
    }
    None
}

/// Map a grown grid onto the board's indices: orientation, extent, missing corners.
fn place(grid: &Grid, c: &[Candidate], board: BoardSize) -> Result<Corners> {
    let (mut i0, mut i1, mut j0, mut j1) = (i32::MAX, i32::MIN, i32::MAX, i32::MIN);
    for &(i, j) in grid.nodes.keys() {
        i0 = i0.min(i);
        i1 = i1.max(i);
        j0 = j0.min(j);
        j1 = j1.max(j);
    }
    let (nx, ny) = ((i1 - i0 + 1) as usize, (j1 - j0 + 1) as usize);
    let transpose = if (nx, ny) == (board.cols, board.rows) {
        false
    } else if (ny, nx) == (board.cols, board.rows) {
        true
    } else {
        let fits = (nx <= board.cols && ny <= board.rows) || (ny <= board.cols && nx <= board.rows);
        return Err(Error::Insufficient(format!(
            "chessboard: found a {nx}x{ny} grid of {} corners where the board has {}x{}{}",
            grid.nodes.len(),
            board.cols,
            board.rows,
            if fits {
                "; part of the board is outside the image or in shadow, so the corners cannot be \
                 numbered"
            } else {
                "; the grid continues beyond the board (clutter or a larger board)"
            }
        )));
    };
    // (bi, bj) on the board for a grid cell, before orientation fixes.
    let to_board = |(i, j): (i32, i32)| {
        let (gi, gj) = ((i - i0) as usize, (j - j0) as usize);
        if transpose {
            (gj, gi)
        } else {
            (gi, gj)
        }
    };
    let mut points: Vec<Option<[f64; 2]>> = vec![None; board.len()];
    for (&cell, &n) in &grid.nodes {
        let (bi, bj) = to_board(cell);
        points[bj * board.cols + bi] = Some([c[n].x, c[n].y]);
    }
    // Orientation: i increases with u; (i, j) has the handedness of (u, v).
    let mean_step = |di: bool| {
        let mut s = [0.0f64; 2];
        for j in 0..board.rows {
            for i in 0..board.cols {
                let (ni, nj) = if di { (i + 1, j) } else { (i, j + 1) };
                if ni >= board.cols || nj >= board.rows {
                    continue;
                }
                if let (Some(p), Some(q)) =
                    (points[j * board.cols + i], points[nj * board.cols + ni])
                {
                    s[0] += q[0] - p[0];
                    s[1] += q[1] - p[1];
                }
            }
        }
        s
    };
    let (si, sj) = (mean_step(true), mean_step(false));
    let flip_i = si[0] < 0.0;
    let cross = si[0] * sj[1] - si[1] * sj[0];
    let flip_j = (cross < 0.0) != flip_i;
    let mut out = vec![None; board.len()];
    for j in 0..board.rows {
        for i in 0..board.cols {
            let ti = if flip_i { board.cols - 1 - i } else { i };
            let tj = if flip_j { board.rows - 1 - j } else { j };
            out[tj * board.cols + ti] = points[j * board.cols + i];
        }
    }
    Ok(Corners { board, points: out })
}

/// Sub-pixel corner by the gradient-orthogonality condition: every gradient in the window is
/// orthogonal to the vector from the corner to its pixel. `None` if the iteration leaves the window.
fn refine(img: &Image, x0: f64, y0: f64, half: usize) -> Option<[f64; 2]> {
    let n = 2 * half + 3;
    let mut patch = vec![0.0f32; n * n];
    let hw = half as f64;
    let weights: Vec<f64> = (0..(2 * half + 1) * (2 * half + 1))
        .map(|k| {
            let dx = (k % (2 * half + 1)) as f64 - hw;
            let dy = (k / (2 * half + 1)) as f64 - hw;
            (-(dx * dx + dy * dy) / (hw * hw)).exp()
        })
        .collect();
    let (mut qx, mut qy) = (x0, y0);
    for _ in 0..40 {
        for (k, v) in patch.iter_mut().enumerate() {
            let dx = (k % n) as f64 - hw - 1.0;
            let dy = (k / n) as f64 - hw - 1.0;
            *v = img.sample(qx + dx, qy + dy)?;
        }
        let (mut a11, mut a12, mut a22, mut b1, mut b2) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for yy in 0..2 * half + 1 {
            for xx in 0..2 * half + 1 {
                let (px, py) = (xx + 1, yy + 1);
                let gx = 0.5 * f64::from(patch[py * n + px + 1] - patch[py * n + px - 1]);
                let gy = 0.5 * f64::from(patch[(py + 1) * n + px] - patch[(py - 1) * n + px]);
                let w = weights[yy * (2 * half + 1) + xx];
                let (gxx, gxy, gyy) = (w * gx * gx, w * gx * gy, w * gy * gy);
                let (dx, dy) = (xx as f64 - hw, yy as f64 - hw);
                a11 += gxx;
                a12 += gxy;
                a22 += gyy;
                b1 += gxx * dx + gxy * dy;
                b2 += gxy * dx + gyy * dy;
            }
        }
        let det = a11 * a22 - a12 * a12;
        if det.abs() < 1e-9 {
            return None;
        }
        let sx = (a22 * b1 - a12 * b2) / det;
        let sy = (a11 * b2 - a12 * b1) / det;
        qx += sx;
        qy += sy;
        if (qx - x0).abs() > hw || (qy - y0).abs() > hw {
            return None;
        }
        if sx * sx + sy * sy < 1e-8 {
            break;
        }
    }
    Some([qx, qy])
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A rendered board: `cols × rows` inner corners, squares of `sq` px, affine-skewed, with
    /// light 220 and dark 30, anti-aliased by supersampling.
    fn render(board: BoardSize, sq: f64, w: usize, h: usize) -> (Vec<f32>, Vec<[f64; 2]>) {
        let origin = [w as f64 * 0.5, h as f64 * 0.5];
        // Board → image: a rotation by 10° and a mild shear.
        let (ca, sa) = (10f64.to_radians().cos(), 10f64.to_radians().sin());
        let m = [
            [ca * sq, -sa * sq * 1.05],
            [sa * sq, ca * sq * 1.05 + 0.05 * sq],
        ];
        let det = m[0][0] * m[1][1] - m[0][1] * m[1][0];
        let inv = [
            [m[1][1] / det, -m[0][1] / det],
            [-m[1][0] / det, m[0][0] / det],
        ];
        let cx = (board.cols as f64 - 1.0) / 2.0;
        let cy = (board.rows as f64 - 1.0) / 2.0;
        let mut img = vec![0.0f32; w * h];
        for y in 0..h {
            for x in 0..w {
                let mut acc = 0.0;
                for s in 0..64 {
                    let (ox, oy) = (
                        (s % 8) as f64 * 0.125 - 0.4375,
                        (s / 8) as f64 * 0.125 - 0.4375,
                    );
                    let (dx, dy) = (x as f64 + ox - origin[0], y as f64 + oy - origin[1]);
                    let bx = inv[0][0] * dx + inv[0][1] * dy + cx;
                    let by = inv[1][0] * dx + inv[1][1] * dy + cy;
                    let inside =
                        bx > -1.0 && by > -1.0 && bx < board.cols as f64 && by < board.rows as f64;
                    let dark = inside && (bx.floor() as i64 + by.floor() as i64) % 2 == 0;
                    acc += if dark { 30.0 } else { 220.0 };
                }
                img[y * w + x] = acc / 64.0;
            }
        }
        let truth = (0..board.len())
            .map(|k| {
                let (bx, by) = ((k % board.cols) as f64 - cx, (k / board.cols) as f64 - cy);
                [
                    origin[0] + m[0][0] * bx + m[0][1] * by,
                    origin[1] + m[1][0] * bx + m[1][1] * by,
                ]
            })
            .collect();
        (img, truth)
    }

    fn nearest(truth: &[[f64; 2]], p: [f64; 2]) -> f64 {
        truth
            .iter()
            .map(|t| ((t[0] - p[0]).powi(2) + (t[1] - p[1]).powi(2)).sqrt())
            .fold(f64::MAX, f64::min)
    }

    #[test]
    fn a_large_image_is_searched_at_half_resolution_and_refined_at_full() {
        // 1280 × 1000 (half-resolution search), squares of 70 px: the same precision.
        let board = BoardSize { cols: 9, rows: 6 };
        let (img, truth) = render(board, 70.0, 1280, 1000);
        let corners = detect(&img, 1280, 1000, board, &DetectParams::default()).expect("board");
        assert_eq!(corners.found(), 54);
        let worst = corners
            .iter_found()
            .map(|(_, p)| nearest(&truth, p))
            .fold(0.0, f64::max);
        assert!(worst < 0.05, "worst corner {worst:.3} px from the truth");
    }

    #[test]
    fn finds_every_corner_to_a_twentieth_of_a_pixel() {
        let board = BoardSize { cols: 9, rows: 6 };
        let (img, truth) = render(board, 24.0, 320, 260);
        let corners = detect(&img, 320, 260, board, &DetectParams::default()).expect("board");
        assert_eq!(corners.found(), 54);
        for (_, p) in corners.iter_found() {
            let e = nearest(&truth, p);
            assert!(e < 0.05, "corner {p:?} is {e:.3} px from the truth");
        }
        // i runs with u; (i, j) has the handedness of (u, v).
        let p = |i: usize, j: usize| corners.points[j * 9 + i].expect("corner");
        assert!(p(8, 0)[0] > p(0, 0)[0]);
        let (di, dj) = (
            [p(8, 0)[0] - p(0, 0)[0], p(8, 0)[1] - p(0, 0)[1]],
            [p(0, 5)[0] - p(0, 0)[0], p(0, 5)[1] - p(0, 0)[1]],
        );
        assert!(di[0] * dj[1] - di[1] * dj[0] > 0.0);
    }

    #[test]
    fn a_shadowed_corner_is_missing_not_guessed_and_shadows_keep_low_contrast_corners() {
        let board = BoardSize { cols: 9, rows: 6 };
        let (mut img, truth) = render(board, 24.0, 320, 260);
        // A deep shadow over one inner corner, a soft one (×0.3, 40 px penumbra) over a third of the
        // board.
        let hidden = truth[2 * 9 + 4];
        for y in 0..260 {
            for x in 0..320 {
                let v = &mut img[y * 320 + x];
                if (x as f64 - hidden[0]).hypot(y as f64 - hidden[1]) < 7.0 {
                    *v = 0.0;
                } else {
                    let t = ((x as f32 - 110.0) / 40.0).clamp(0.0, 1.0);
                    *v *= 0.3 + 0.7 * t;
                }
            }
        }
        let corners = detect(&img, 320, 260, board, &DetectParams::default()).expect("board");
        assert_eq!(corners.found(), 53, "missing {:?}", corners.missing());
        let (i, j) = corners.missing()[0];
        let dark_corner = corners
            .iter_found()
            .map(|(_, p)| p)
            .filter(|p| p[0] < 120.0)
            .count();
        assert!(
            dark_corner >= 15,
            "{dark_corner} corners found in the soft shadow"
        );
        // The missing index is the hidden corner (up to the board's 180° symmetry of labels).
        let expect = [(4, 2), (4, 3)];
        assert!(expect.contains(&(i, j)), "missing {:?}", (i, j));
    }

    #[test]
    fn a_board_cut_by_the_border_is_an_error_that_says_so() {
        let board = BoardSize { cols: 9, rows: 6 };
        let (img, _) = render(board, 24.0, 320, 260);
        // Crop: keep columns 70.. so that the leftmost corner column is gone.
        let (w, h) = (240, 260);
        let crop: Vec<f32> = (0..h)
            .flat_map(|y| img[y * 320 + 80..y * 320 + 320].to_vec())
            .collect();
        let err = detect(&crop, w, h, board, &DetectParams::default())
            .expect_err("must not guess")
            .to_string();
        assert!(err.contains("outside the image or in shadow"), "{err}");
    }

    #[test]
    fn no_board_in_noise() {
        let mut rng = crate::testing::Rng(12345);
        let img: Vec<f32> = (0..200 * 150)
            .map(|_| rng.range(100.0, 140.0).floor() as f32)
            .collect();
        let board = BoardSize { cols: 9, rows: 6 };
        assert!(detect(&img, 200, 150, board, &DetectParams::default()).is_err());
    }

    #[test]
    fn board_size_parses() {
        assert_eq!(
            BoardSize::parse("9x6"),
            Some(BoardSize { cols: 9, rows: 6 })
        );
        assert_eq!(BoardSize::parse("13X9").map(|b| b.len()), Some(117));
        assert_eq!(BoardSize::parse("9"), None);
        assert_eq!(BoardSize::parse("1x6"), None);
    }
}
