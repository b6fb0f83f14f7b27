#!/usr/bin/env python3
"""Seeded rooms for the omnidirectional sensor's family test (not RIS code).

Prints one room as JSON in the form tests/omni_room_render.py reads: half-sizes 1.8-4 m, the
room off the sensor's axis by up to 30 % of each half-size, floor 1.0-1.4 m below and ceiling
1.1-1.5 m above the sensor, 1-3 boxes standing on the floor at least 0.5 m from the axis,
albedos and read noise 1.5 levels.

usage: omni_room_family.py SEED
"""

import json
import random
import sys


def room(seed):
    r = random.Random(seed)
    hx, hy = r.uniform(1800, 4000), r.uniform(1800, 4000)
    cx, cy = r.uniform(-0.3, 0.3) * hx, r.uniform(-0.3, 0.3) * hy
    floor = -r.uniform(1000, 1400)
    ceiling = r.uniform(1100, 1500)
    boxes = []
    for _ in range(r.randint(1, 3)):
        for _ in range(100):
            bh = [r.uniform(200, 450), r.uniform(200, 450), r.uniform(250, 500)]
            bx = r.uniform(cx - hx + bh[0], cx + hx - bh[0])
            by = r.uniform(cy - hy + bh[1], cy + hy - bh[1])
            if max(abs(bx) - bh[0], abs(by) - bh[1]) > 500:
                break
        boxes.append({"center": [bx, by, floor + bh[2]], "half": bh, "albedo": r.uniform(0.3, 0.7)})
    return {
        "half": [hx, hy],
        "center": [cx, cy],
        "floor": floor,
        "ceiling": ceiling,
        "albedo": [r.uniform(0.4, 0.7), r.uniform(0.25, 0.5), r.uniform(0.5, 0.75)],
        "boxes": boxes,
        "gain": 230.0,
        "ambient": 0.03,
        "noise": 1.5,
        "seed": seed,
    }


if __name__ == "__main__":
    print(json.dumps(room(int(sys.argv[1]))))
