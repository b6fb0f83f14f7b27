#!/usr/bin/env python3
"""An independent renderer of rooms seen by an omnidirectional sensor (not RIS code).

It reads the sensor file and the ring pattern as SPEC §13 states them and renders, with numpy,
the camera's view of a box room lit by the projector's rings through both hyperbolic mirrors:
each camera pixel is the mean of 2 x 2 rays across its area, the rings are evaluated from the
formula in rings.toml (not from rings.png), Gaussian read noise is added. It writes image.png
(8-bit grey) and truth: xyz.npy (H x W x 3 float32, sensor frame mm, NaN where no room point) and
projector.npy (H x W x 2 float32, the projector pixel lighting the pixel's centre, NaN unlit).

usage: omni_room_render.py SENSOR.toml RINGS.toml ROOM.json OUT_DIR
ROOM.json: {"half": [hx, hy], "center": [cx, cy], "floor": f, "ceiling": c,
            "albedo": [walls, floor, ceiling], "boxes": [{"center": [..], "half": [..],
            "albedo": a}], "gain": 230, "ambient": 0.03, "noise": 1.0, "seed": 7}
"""

import json
import struct
import sys
import tomllib
import zlib

import numpy as np


def unit(section):
    k = np.array(section["k"], dtype=float)
    m = section["mirror"]
    a, b = float(m["a"]), float(m["b"])
    return {
        "w": int(section["width"]),
        "h": int(section["height"]),
        "k": k,
        "a": a,
        "b": b,
        "e": np.sqrt(a * a + b * b),
        "rim": float(m["rim"]),
        "r": np.array(m["r"], dtype=float),
        "t": np.array(m["t"], dtype=float),
    }


def hit_sheet(u, o, d):
    """First hit (s > 0) of rays o + s d (mirror frame, N x 3) with the sheet z > 0 inside the rim."""
    a2, b2 = u["a"] ** 2, u["b"] ** 2
    qa = d[:, 2] ** 2 / a2 - (d[:, 0] ** 2 + d[:, 1] ** 2) / b2
    qb = 2 * (o[:, 2] * d[:, 2] / a2 - (o[:, 0] * d[:, 0] + o[:, 1] * d[:, 1]) / b2)
    qc = o[:, 2] ** 2 / a2 - (o[:, 0] ** 2 + o[:, 1] ** 2) / b2 - 1
    disc = qb * qb - 4 * qa * qc
    ok = disc >= 0
    sq = np.sqrt(np.where(ok, disc, 0))
    with np.errstate(divide="ignore", invalid="ignore"):
        s1 = (-qb - sq) / (2 * qa)
        s2 = (-qb + sq) / (2 * qa)
    best = np.full(len(o), np.nan)
    for s in (np.minimum(s1, s2), np.maximum(s1, s2)):
        p = o + d * s[:, None]
        good = ok & (s > 1e-9) & (p[:, 2] > 0) & (np.hypot(p[:, 0], p[:, 1]) <= u["rim"]) & np.isnan(best)
        best = np.where(good, s, best)
    return o + d * best[:, None]


def normal(u, p):
    n = np.stack([-p[:, 0] / u["b"] ** 2, -p[:, 1] / u["b"] ** 2, p[:, 2] / u["a"] ** 2], axis=1)
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def camera_rays(u, px, py):
    """Sensor-frame rays of pixels (px, py): origin on the mirror, reflected direction."""
    kinv = np.linalg.inv(u["k"])
    pts = np.stack([px, py, np.ones_like(px)], axis=1) @ kinv.T
    d = pts / np.linalg.norm(pts, axis=1, keepdims=True)
    o = np.tile([0.0, 0.0, -u["e"]], (len(px), 1))
    p = hit_sheet(u, o, d)
    n = normal(u, p)
    refl = d - 2 * np.sum(d * n, axis=1, keepdims=True) * n
    return p @ u["r"].T + u["t"], refl @ u["r"].T


def project(u, x):
    """Projector pixel lighting sensor-frame points x (central unit), and the mirror point."""
    xm = (x - u["t"]) @ u["r"]  # r^T (x - t)
    f1 = np.array([0.0, 0.0, u["e"]])
    d = f1 - xm
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    m = hit_sheet(u, xm, d)
    # only the outer face reflects
    back = np.sum((xm - m) * normal(u, m), axis=1) > 0
    cam = m - np.array([0.0, 0.0, -u["e"]])
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = np.stack([cam[:, 0] / cam[:, 2], cam[:, 1] / cam[:, 2], np.ones(len(cam))], axis=1) @ u["k"].T
    pu, pv = uv[:, 0], uv[:, 1]
    inside = (pu >= -0.5) & (pv >= -0.5) & (pu <= u["w"] - 0.5) & (pv <= u["h"] - 0.5) & ~back
    pu = np.where(inside, pu, np.nan)
    pv = np.where(inside, pv, np.nan)
    return pu, pv, m @ u["r"].T + u["t"]


def rings_value(rings, pu, pv):
    pat = rings["pattern"]
    cx, cy = pat["center"]
    rho = np.hypot(pu - cx, pv - cy)
    theta = np.arctan2(pv - cy, pu - cx)
    out = np.zeros_like(pu)
    for r in rings["ring"]:
        x = (rho - r["radius"]) / r["width"]
        if pat["profile"] == "gaussian":
            g = np.where(np.abs(x) < 6, np.exp(-0.5 * x * x), 0)
        else:
            g = (np.abs(x) <= 0.5).astype(float)
        out += r["intensity"] * g * 0.5 * (1 + np.cos(r["frequency"] * theta + r["phase"]))
    return np.clip(np.nan_to_num(out), 0, 1)


def room_hit(room, o, d):
    """Nearest room surface along o + t d: t, normal (facing the ray), albedo."""
    n_rays = len(o)
    best_t = np.full(n_rays, np.inf)
    best_n = np.zeros((n_rays, 3))
    best_a = np.zeros(n_rays)
    (hx, hy), (cx, cy) = room["half"], room["center"]
    walls, floor_a, ceil_a = room["albedo"]
    planes = [
        (0, cx - hx, cx + hx, walls, walls),
        (1, cy - hy, cy + hy, walls, walls),
        (2, room["floor"], room["ceiling"], floor_a, ceil_a),
    ]
    with np.errstate(divide="ignore", invalid="ignore"):
        for axis, lo, hi, a_lo, a_hi in planes:
            da = d[:, axis]
            t = np.where(da > 0, (hi - o[:, axis]) / da, (lo - o[:, axis]) / da)
            alb = np.where(da > 0, a_hi, a_lo)
            nrm = np.zeros((n_rays, 3))
            nrm[:, axis] = -np.sign(da)
            take = (t > 1e-6) & (t < best_t)
            best_t = np.where(take, t, best_t)
            best_n = np.where(take[:, None], nrm, best_n)
            best_a = np.where(take, alb, best_a)
        for box in room.get("boxes", []):
            c, h = np.array(box["center"]), np.array(box["half"])
            t0 = (c - h - o) / d
            t1 = (c + h - o) / d
            tmin = np.minimum(t0, t1)
            tmax = np.maximum(t0, t1)
            tn = np.nanmax(tmin, axis=1)
            tf = np.nanmin(tmax, axis=1)
            take = (tn <= tf) & (tn > 1e-6) & (tn < best_t)
            face = np.argmax(tmin, axis=1)
            nrm = np.zeros((n_rays, 3))
            nrm[np.arange(n_rays), face] = -np.sign(d[np.arange(n_rays), face])
            best_t = np.where(take, tn, best_t)
            best_n = np.where(take[:, None], nrm, best_n)
            best_a = np.where(take, box["albedo"], best_a)
    return best_t, best_n, best_a


def blocked(room, p, q):
    d = q - p
    length = np.linalg.norm(d, axis=1)
    d = d / length[:, None]
    out = np.zeros(len(p), dtype=bool)
    with np.errstate(divide="ignore", invalid="ignore"):
        for box in room.get("boxes", []):
            c, h = np.array(box["center"]), np.array(box["half"])
            t0 = (c - h - p) / d
            t1 = (c + h - p) / d
            tn = np.nanmax(np.minimum(t0, t1), axis=1)
            tf = np.nanmin(np.maximum(t0, t1), axis=1)
            out |= (tn <= tf) & (tf > 1e-3) & (tn < length - 1e-3)
    return out


def shade(cam, proj, rings, room, px, py):
    o, d = camera_rays(cam, px, py)
    valid = np.all(np.isfinite(o), axis=1)
    o = np.where(valid[:, None], o, 0)
    d = np.where(valid[:, None], d, [0, 0, 1])
    t, n, alb = room_hit(room, o, d)
    valid &= np.isfinite(t)
    p = o + d * np.where(valid, t, 0)[:, None]
    pu, pv, m = project(proj, p)
    lit = valid & np.isfinite(pu)
    lit &= ~blocked(room, p, np.where(lit[:, None], m, p + 1))
    to = m - p
    to /= np.linalg.norm(to, axis=1, keepdims=True)
    cosine = np.clip(np.sum(n * to, axis=1), 0, None)
    light = room.get("ambient", 0.03) + np.where(lit, rings_value(rings, np.nan_to_num(pu), np.nan_to_num(pv)) * cosine, 0)
    level = np.where(valid, room.get("gain", 230.0) * alb * light, 0)
    return level, np.where(valid[:, None], p, np.nan), np.where(lit, pu, np.nan), np.where(lit, pv, np.nan)


def write_png(path, w, h, pixels):
    raw = b"".join(b"\x00" + pixels[y].tobytes() for y in range(h))

    def chunk(kind, data):
        c = kind + data
        return struct.pack(">I", len(data)) + c + struct.pack(">I", zlib.crc32(c) & 0xFFFFFFFF)

    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0))
    png += chunk(b"IDAT", zlib.compress(raw, 1)) + chunk(b"IEND", b"")
    with open(path, "wb") as f:
        f.write(png)


def main():
    sensor_path, rings_path, room_path, out = sys.argv[1:5]
    with open(sensor_path, "rb") as f:
        sensor = tomllib.load(f)
    with open(rings_path, "rb") as f:
        rings = tomllib.load(f)
    with open(room_path) as f:
        room = json.load(f)
    cam, proj = unit(sensor["camera"]), unit(sensor["projector"])
    w, h = cam["w"], cam["h"]
    ys, xs = np.mgrid[0:h, 0:w]
    xs, ys = xs.ravel().astype(float), ys.ravel().astype(float)
    total = np.zeros(w * h)
    for dx, dy in [(-0.25, -0.25), (0.25, -0.25), (-0.25, 0.25), (0.25, 0.25)]:
        level, _, _, _ = shade(cam, proj, rings, room, xs + dx, ys + dy)
        total += level / 4
    _, xyz, pu, pv = shade(cam, proj, rings, room, xs, ys)
    rng = np.random.default_rng(room.get("seed", 7))
    total += rng.normal(0, room.get("noise", 1.0), w * h) * (total > 0)
    image = np.clip(np.round(total), 0, 255).astype(np.uint8).reshape(h, w)
    write_png(f"{out}/image.png", w, h, image)
    np.save(f"{out}/xyz.npy", xyz.reshape(h, w, 3).astype(np.float32))
    np.save(f"{out}/projector.npy", np.stack([pu, pv], axis=1).reshape(h, w, 2).astype(np.float32))
    print(f"rendered {w}x{h}: {int(np.isfinite(pu).sum())} lit pixels")


if __name__ == "__main__":
    main()
