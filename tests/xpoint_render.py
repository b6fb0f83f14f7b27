#!/usr/bin/env python3
"""An independent renderer of single-shot scenes (not RIS code).

It draws, with numpy, a table top carrying a step (a box turned about the vertical), a
spherical cap and a half-buried horizontal cylinder, seen by a camera with lens distortion and
lit by a projector that shows xpoint.png (SPEC §10) as it is, pixel by pixel. Camera and
projector poses, the objects, their texture and the noise come from the seed. Each camera pixel
is the mean of 2 x 2 rays across its area, the projector's pixels are blurred by its lens (a
one-pixel tent), then a Gaussian lens blur and Gaussian read noise
with shot noise are added. The table ends inside the view, so the pattern falls off it into
nothing; objects shadow the projector's light and hide each other from the camera.

It also renders the sensor's reference recording (SPEC §4, §6): the bare plane z = 0 under the
Gray codes of SPEC §3 (2 x 2 rays per pixel), and writes the sensor file as SPEC §6 states it,
so the decoder reads nothing but the pattern and what this script wrote.

usage: xpoint_render.py XPOINT_DIR SEED NOISE TEXTURE OUT_DIR
NOISE: read noise, grey levels (shot noise of 0.05 per level comes on top); TEXTURE: the
standard deviation of the surfaces' albedo texture relative to their albedo (sinusoids of
periods about 2-25 mm; 0 for plain surfaces).
writes OUT_DIR/sensor.toml, OUT_DIR/reference/ (capture set), OUT_DIR/image.png (8-bit grey),
and the truth at each pixel's centre: xyz.npy (H x W x 3 float32, sensor frame mm, NaN where no
surface) and projector.npy (H x W x 3 float32: projector column and row of that surface point,
NaN outside the projector's image, and 1 where the projector lights it, 0 in its shadow).
"""

import json
import os
import sys
import tomllib
import zlib

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from omni_room_render import write_png  # noqa: E402

CAMERA = (1024, 768)


def read_png(path):
    """8-bit greyscale, non-interlaced PNG (what SPEC §10 says xpoint.png is)."""
    with open(path, "rb") as f:
        data = f.read()
    assert data[:8] == b"\x89PNG\r\n\x1a\n", path
    pos, idat = 8, b""
    while pos < len(data):
        n = int.from_bytes(data[pos : pos + 4], "big")
        kind, body = data[pos + 4 : pos + 8], data[pos + 8 : pos + 8 + n]
        if kind == b"IHDR":
            w, h = int.from_bytes(body[0:4], "big"), int.from_bytes(body[4:8], "big")
            depth, colour, interlace = body[8], body[9], body[12]
            assert (depth, colour, interlace) == (8, 0, 0), "8-bit grey, not interlaced"
        elif kind == b"IDAT":
            idat += body
        pos += 12 + n
    raw = zlib.decompress(idat)
    out = np.zeros((h, w), dtype=np.int32)
    prev = np.zeros(w, dtype=np.int32)
    for y in range(h):
        f = raw[y * (w + 1)]
        line = np.frombuffer(raw, dtype=np.uint8, count=w, offset=y * (w + 1) + 1).astype(np.int32)
        if f == 0:
            cur = line
        elif f == 1:
            cur = np.cumsum(line) % 256
        elif f == 2:
            cur = (line + prev) % 256
        else:
            cur = np.zeros(w, dtype=np.int32)
            left = 0
            for x in range(w):
                up, ul = int(prev[x]), int(prev[x - 1]) if x > 0 else 0
                if f == 3:
                    pred = (left + up) // 2
                else:
                    p = left + up - ul
                    pa, pb, pc = abs(p - left), abs(p - up), abs(p - ul)
                    pred = left if pa <= pb and pa <= pc else (up if pb <= pc else ul)
                left = (int(line[x]) + pred) % 256
                cur[x] = left
        out[y] = cur
        prev = cur
    return out.astype(np.float64)


def look_at(eye, target, down=(0.0, -1.0, 0.0)):
    """World -> device rotation: rows are the device's x (image right), y (image down) and z
    (forward) axes."""
    z = np.asarray(target, float) - eye
    z /= np.linalg.norm(z)
    x = np.cross(down, z)
    x /= np.linalg.norm(x)
    return np.array([x, np.cross(z, x), z])


def scene_of(seed, projector, amplitude):
    rng = np.random.default_rng(seed)
    pw, ph = projector
    cam_c = np.array([rng.uniform(-40, 40), rng.uniform(-40, 40), rng.uniform(1560, 1640)])
    cam_r = look_at(cam_c, [rng.uniform(-30, 30), rng.uniform(-30, 30), 0.0])
    f = rng.uniform(1750, 1850)
    cam_k = np.array(
        [[f, 0, CAMERA[0] / 2 - 0.5 + rng.uniform(-8, 8)], [0, f * rng.uniform(0.998, 1.002), CAMERA[1] / 2 - 0.5 + rng.uniform(-8, 8)], [0, 0, 1]]
    )
    dist = np.array([rng.uniform(-0.08, 0.08), rng.uniform(-0.05, 0.05), rng.uniform(-5e-4, 5e-4), rng.uniform(-5e-4, 5e-4), 0.0])
    side = rng.choice([-1.0, 1.0])
    proj_c = cam_c + np.array([side * rng.uniform(380, 520), rng.uniform(-60, 60), rng.uniform(-40, 80)])
    proj_r = look_at(proj_c, [rng.uniform(-40, 40), rng.uniform(-40, 40), 0.0])
    fp = rng.uniform(1750, 2000) * pw / 1024
    proj_k = np.array([[fp, 0, pw / 2 - 0.5], [0, fp, ph / 2 - 0.5 + rng.uniform(-20, 20)], [0, 0, 1]])
    table = {"center": [rng.uniform(-30, 30), rng.uniform(-30, 30)], "half": [rng.uniform(320, 380), rng.uniform(230, 280)]}

    # The objects in three bands across the table so that they do not overlap.
    xs = rng.permutation([-200.0, 0.0, 200.0]) + rng.uniform(-20, 20, 3) + table["center"][0]
    ys = rng.uniform(-80, 80, 3) + table["center"][1]
    box_h = rng.uniform(25, 50)
    objects = {
        "box": {"center": [xs[0], ys[0], box_h / 2], "half": [rng.uniform(55, 80), rng.uniform(55, 90), box_h / 2], "yaw": rng.uniform(0, np.pi)},
        "cap": {"center": [xs[1], ys[1], 0.0], "radius": rng.uniform(80, 120)},
        "cylinder": {"center": [xs[2], ys[2], 0.0], "radius": rng.uniform(35, 55), "half_length": rng.uniform(70, 110), "yaw": rng.uniform(0, np.pi)},
    }
    objects["cap"]["center"][2] = -rng.uniform(0.35, 0.7) * objects["cap"]["radius"]
    objects["cylinder"]["center"][2] = -rng.uniform(0.0, 0.4) * objects["cylinder"]["radius"]
    texture = [
        (rng.normal(0, 1, 3) * 2 * np.pi / rng.uniform(4, 25), rng.uniform(0, 2 * np.pi)) for _ in range(6)
    ]
    return {
        "camera": {"center": cam_c.tolist(), "r": cam_r.tolist(), "k": cam_k.tolist(), "dist": dist.tolist()},
        "projector": {"center": proj_c.tolist(), "r": proj_r.tolist(), "k": proj_k.tolist(), "width": pw, "height": ph},
        "table": table,
        "objects": objects,
        "texture": [(list(k), p) for k, p in texture],
        "albedo": {"table": rng.uniform(0.4, 0.6), "part": rng.uniform(0.5, 0.7), "reference": 0.6},
        "texture_amplitude": amplitude,
        "ambient": rng.uniform(0.02, 0.05),
    }


def camera_rays(s, px, py):
    """Origin and unit directions (world) of camera pixels (px, py), through the distortion."""
    c = s["camera"]
    k, (k1, k2, p1, p2, k3) = np.array(c["k"]), c["dist"]
    xd, yd = (px - k[0, 2]) / k[0, 0], (py - k[1, 2]) / k[1, 1]
    x, y = xd.copy(), yd.copy()
    for _ in range(8):
        r2 = x * x + y * y
        radial = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2**3
        x = (xd - (2 * p1 * x * y + p2 * (r2 + 2 * x * x))) / radial
        y = (yd - (p1 * (r2 + 2 * y * y) + 2 * p2 * x * y)) / radial
    d = np.stack([x, y, np.ones_like(x)], axis=1) @ np.array(c["r"])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return np.array(c["center"]), d


def hit_box(b, o, d):
    cy, sy = np.cos(b["yaw"]), np.sin(b["yaw"])
    rot = np.array([[cy, sy, 0], [-sy, cy, 0], [0, 0, 1]])  # world -> box
    lo = (o - np.array(b["center"])) @ rot.T
    ld = d @ rot.T
    half = np.array(b["half"])
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (-half - lo) / ld
        t2 = (half - lo) / ld
    tn, tf = np.minimum(t1, t2), np.maximum(t1, t2)
    tn = np.where(np.isnan(tn), -np.inf, tn)
    tf = np.where(np.isnan(tf), np.inf, tf)
    near, far = tn.max(axis=1), tf.min(axis=1)
    axis = tn.argmax(axis=1)
    ok = (near <= far) & (near > 1e-6)
    n_local = np.zeros_like(d)
    n_local[np.arange(len(d)), axis] = -np.sign(ld[np.arange(len(d)), axis])
    return np.where(ok, near, np.inf), n_local @ rot


def hit_sphere(c, radius, o, d):
    oc = o - np.array(c)
    b = np.sum(oc * d, axis=1)
    disc = b * b - (np.sum(oc * oc, axis=1) - radius * radius)
    sq = np.sqrt(np.maximum(disc, 0))
    best = np.full(len(d), np.inf)
    for t in (-b + sq, -b - sq):
        z = o[:, 2] + t * d[:, 2]
        good = (disc >= 0) & (t > 1e-6) & (z >= 0) & (t < best)
        best = np.where(good, t, best)
    p = o + d * np.where(np.isfinite(best), best, 0)[:, None]
    return best, (p - np.array(c)) / radius


def hit_cylinder(cyl, o, d):
    cy, sy = np.cos(cyl["yaw"]), np.sin(cyl["yaw"])
    rot = np.array([[cy, sy, 0], [-sy, cy, 0], [0, 0, 1]])  # world -> cylinder (axis = x)
    lo = (o - np.array(cyl["center"])) @ rot.T
    ld = d @ rot.T
    r, hl = cyl["radius"], cyl["half_length"]
    zc = cyl["center"][2]
    a = ld[:, 1] ** 2 + ld[:, 2] ** 2
    b = lo[:, 1] * ld[:, 1] + lo[:, 2] * ld[:, 2]
    c = lo[:, 1] ** 2 + lo[:, 2] ** 2 - r * r
    disc = b * b - a * c
    sq = np.sqrt(np.maximum(disc, 0))
    best = np.full(len(d), np.inf)
    normal = np.zeros_like(d)
    with np.errstate(divide="ignore", invalid="ignore"):
        for t in ((-b - sq) / a, (-b + sq) / a):
            p = lo + ld * t[:, None]
            good = (disc >= 0) & (t > 1e-6) & (np.abs(p[:, 0]) <= hl) & (p[:, 2] + zc >= 0) & (t < best)
            best = np.where(good, t, best)
            n = np.stack([np.zeros_like(t), p[:, 1], p[:, 2]], axis=1) / r
            normal = np.where(good[:, None], n, normal)
        for end in (-hl, hl):
            t = (end - lo[:, 0]) / ld[:, 0]
            p = lo + ld * t[:, None]
            good = (t > 1e-6) & (p[:, 1] ** 2 + p[:, 2] ** 2 <= r * r) & (p[:, 2] + zc >= 0) & (t < best)
            best = np.where(good, t, best)
            normal = np.where(good[:, None], np.array([np.sign(end), 0.0, 0.0]), normal)
    return best, normal @ rot


def hit_table(s, o, d):
    tb = s["table"]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -o[:, 2] / d[:, 2]
    p = o + d * np.where(np.isfinite(t), t, 0)[:, None]
    good = (t > 1e-6) & (np.abs(p[:, 0] - tb["center"][0]) <= tb["half"][0]) & (np.abs(p[:, 1] - tb["center"][1]) <= tb["half"][1])
    return np.where(good, t, np.inf), np.tile([0.0, 0.0, 1.0], (len(d), 1))


def first_hit(s, o, d, table=True, parts=True):
    """Distance, normal (towards the ray's origin) and albedo class (0 table, 1 part)."""
    o = np.broadcast_to(o, d.shape)
    hits = [hit_table(s, o, d)] if table else []
    if parts:
        ob = s["objects"]
        hits += [hit_box(ob["box"], o, d), hit_sphere(ob["cap"]["center"], ob["cap"]["radius"], o, d), hit_cylinder(ob["cylinder"], o, d)]
    ts = np.stack([h[0] for h in hits])
    which = ts.argmin(axis=0)
    t = ts[which, np.arange(len(d))]
    n = np.stack([h[1] for h in hits])[which, np.arange(len(d))]
    n = np.where((np.sum(n * d, axis=1) > 0)[:, None], -n, n)
    return t, n, np.minimum(which, 1) if table else np.ones(len(d), dtype=int)


def project(s, p):
    pr = s["projector"]
    x = (p - np.array(pr["center"])) @ np.array(pr["r"]).T
    k = np.array(pr["k"])
    with np.errstate(divide="ignore", invalid="ignore"):
        u = k[0, 0] * x[:, 0] / x[:, 2] + k[0, 2]
        v = k[1, 1] * x[:, 1] / x[:, 2] + k[1, 2]
    inside = (x[:, 2] > 0) & (u > -0.5) & (v > -0.5) & (u < pr["width"] - 0.5) & (v < pr["height"] - 0.5)
    return np.where(inside, u, np.nan), np.where(inside, v, np.nan)


def albedo(s, p, cls):
    tex = np.zeros(len(p))
    for k, phase in s["texture"]:
        tex += np.sin(p @ np.array(k) + phase)
    tex /= np.sqrt(len(s["texture"]) / 2)
    base = np.where(cls == 0, s["albedo"]["table"], s["albedo"]["part"])
    return np.clip(base * (1 + s["texture_amplitude"] * tex), 0.02, 1.0)


def surface(s, px, py, parts=True):
    """Per ray: point, normal, albedo class, projector (u, v), the light's cosine and whether
    the projector reaches the point."""
    o, d = camera_rays(s, px, py)
    t, n, cls = first_hit(s, o, d, parts=parts)
    valid = np.isfinite(t)
    p = o + d * np.where(valid, t, 0)[:, None]
    pu, pv = project(s, p)
    to = np.array(s["projector"]["center"]) - p
    dist = np.linalg.norm(to, axis=1)
    to /= dist[:, None]
    cosine = np.clip(np.sum(n * to, axis=1), 0, None)
    lit = valid & np.isfinite(pu) & (cosine > 0)
    if parts:
        # Shadows: only the parts can come between a point and the projector above the table.
        idx = np.flatnonzero(lit)
        ts, _, _ = first_hit(s, p[idx] + n[idx] * 0.01, to[idx], table=False)
        lit[idx] &= ts >= dist[idx] - 0.02
    return valid, p, cls, pu, pv, cosine, lit


def blur(img, sigma):
    r = int(np.ceil(3 * sigma))
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
    k /= k.sum()
    for axis in (0, 1):
        pad = np.pad(img, [(r, r) if a == axis else (0, 0) for a in (0, 1)], mode="edge")
        img = sum(k[i] * np.take(pad, np.arange(i, i + img.shape[axis]), axis=axis) for i in range(2 * r + 1))
    return img


def expose(level, rng, noise):
    level = blur(level, 0.5)
    level = level + rng.normal(0, 1, level.shape) * np.sqrt(noise**2 + 0.05 * level)
    return np.clip(np.round(level), 0, 255).astype(np.uint8)


def subsamples(n):
    return [((i + 0.5) / n - 0.5, (j + 0.5) / n - 0.5) for j in range(n) for i in range(n)]


def shown_at(slide, pu, pv):
    """What the projector shows at (pu, pv): its pixels, blurred by the lens' defocus (bilinear
    between pixel centres, a tent of one pixel)."""
    ph, pw = slide.shape
    u = np.clip(np.nan_to_num(pu), 0, pw - 1.001)
    v = np.clip(np.nan_to_num(pv), 0, ph - 1.001)
    u0, v0 = np.floor(u).astype(int), np.floor(v).astype(int)
    a, b = u - u0, v - v0
    return (
        slide[v0, u0] * (1 - a) * (1 - b)
        + slide[v0, u0 + 1] * a * (1 - b)
        + slide[v0 + 1, u0] * (1 - a) * b
        + slide[v0 + 1, u0 + 1] * a * b
    )


def render_xpoint(s, slide, gain, rng, noise):
    w, h = CAMERA
    level = np.zeros((h, w))
    rows = 48
    for y0 in range(0, h, rows):
        ys, xs = np.mgrid[y0 : min(h, y0 + rows), 0:w]
        xs, ys = xs.ravel().astype(float), ys.ravel().astype(float)
        acc = np.zeros(len(xs))
        subs = subsamples(2)
        for dx, dy in subs:
            valid, p, cls, pu, pv, cosine, lit = surface(s, xs + dx, ys + dy)
            shown = np.where(lit, shown_at(slide, pu, pv) / 255.0, 0.0)
            acc += np.where(valid, gain * albedo(s, p, cls) * (s["ambient"] + shown * cosine), 0.0)
        level[y0 : y0 + rows] = (acc / len(subs)).reshape(-1, w)
    return expose(level, rng, noise)


def render_reference(s, out, gain, rng, noise):
    w, h = CAMERA
    pw, ph = s["projector"]["width"], s["projector"]["height"]
    nc, nr = int(np.ceil(np.log2(pw))), int(np.ceil(np.log2(ph)))
    ys, xs = np.mgrid[0:h, 0:w]
    xs, ys = xs.ravel().astype(float), ys.ravel().astype(float)
    subs = subsamples(2)
    # Per ray: its projector column and row codes and the light it returns per unit of
    # projector level; the ambient part is the same in every frame.
    codes_c, codes_r, light = [], [], []
    base = np.zeros(w * h)
    for dx, dy in subs:
        valid, p, _, pu, pv, cosine, lit = surface(s, xs + dx, ys + dy, parts=False)
        # The reference plane is the whole plane z = 0, not the table.
        g = gain * np.clip(s["albedo"]["reference"] * (1 + 0.1 * np.sin(p @ np.array([0.05, 0.03, 0.0]))), 0, 1)
        base += g * s["ambient"]
        c = np.round(np.nan_to_num(pu)).astype(np.int64)
        r = np.round(np.nan_to_num(pv)).astype(np.int64)
        codes_c.append(c ^ (c >> 1))
        codes_r.append(r ^ (r >> 1))
        light.append(np.where(lit, g * cosine, 0.0) / len(subs))
    base /= len(subs)
    full = sum(light)

    def shot(level):
        return expose((base + level).reshape(h, w), rng, noise)

    frames = {"white": shot(full), "black": shot(0 * full)}
    for name, codes, bits in (("col", codes_c, nc), ("row", codes_r, nr)):
        for k in range(bits):
            on = sum(l * ((g >> (bits - 1 - k)) & 1) for l, g in zip(light, codes))
            frames[f"gray_{name}_{k:02}"] = shot(on)
            frames[f"gray_{name}_{k:02}_inv"] = shot(full - on)
    os.makedirs(f"{out}/reference", exist_ok=True)
    for name, img in frames.items():
        write_png(f"{out}/reference/{name}.png", w, h, img)
    with open(f"{out}/reference/capture.toml", "w") as f:
        f.write(f"[projector]\nwidth = {pw}\nheight = {ph}\ncolumn_step = 1\nrow_step = 1\n[camera]\nwidth = {w}\nheight = {h}\n")


def toml_matrix(m):
    return "[" + ", ".join("[" + ", ".join(repr(float(x)) for x in row) + "]" for row in m) + "]"


def main():
    xpoint_dir, seed, noise, texture, out = sys.argv[1], int(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4]), sys.argv[5]
    with open(f"{xpoint_dir}/xpoint.toml", "rb") as f:
        pattern = tomllib.load(f)["pattern"]
    slide = read_png(f"{xpoint_dir}/xpoint.png")
    assert slide.shape == (pattern["height"], pattern["width"]), "xpoint.png is not the pattern's size"
    s = scene_of(seed, (pattern["width"], pattern["height"]), texture)
    os.makedirs(out, exist_ok=True)
    rng = np.random.default_rng(seed + 1000)
    gain = 200.0 / max(s["albedo"]["table"], s["albedo"]["part"])
    render_reference(s, out, gain, rng, noise)
    write_png(f"{out}/image.png", CAMERA[0], CAMERA[1], render_xpoint(s, slide, gain, rng, noise))
    w, h = CAMERA
    ys, xs = np.mgrid[0:h, 0:w]
    valid, p, _, pu, pv, _, lit = surface(s, xs.ravel().astype(float), ys.ravel().astype(float))
    np.save(f"{out}/xyz.npy", np.where(valid[:, None], p, np.nan).reshape(h, w, 3).astype(np.float32))
    np.save(f"{out}/projector.npy", np.stack([pu, pv, lit.astype(float)], axis=1).reshape(h, w, 3).astype(np.float32))
    cam = s["camera"]
    r = np.array(cam["r"])
    t = -r @ np.array(cam["center"])
    with open(f"{out}/sensor.toml", "w") as f:
        f.write(
            f"[camera]\nwidth = {w}\nheight = {h}\nk = {toml_matrix(cam['k'])}\ndist = [{', '.join(repr(float(x)) for x in cam['dist'])}]\n"
            f"r = {toml_matrix(r)}\nt = [{', '.join(repr(float(x)) for x in t)}]\n"
            f"[projector]\nwidth = {pattern['width']}\nheight = {pattern['height']}\n"
            f"center = [{', '.join(repr(float(x)) for x in s['projector']['center'])}]\n"
            '[reference]\ncapture = "reference"\n'
        )
    with open(f"{out}/scene.json", "w") as f:
        json.dump(s, f, indent=1)
    print(f"rendered {w}x{h}: {int(valid.sum())} surface pixels, {int(lit.sum())} lit")


if __name__ == "__main__":
    main()
