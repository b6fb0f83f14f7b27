#!/usr/bin/env python3
"""Seeded STEP parts and their truth, written by an independent OpenCASCADE (the cadquery-ocp
wheel, OCCT 7.8+, not Debian's 7.6 that RIS links): the test reads each part with RIS and compares.

usage: step_parts.py OUT_DIR SEED COUNT [DX DY DR]

For part k it writes OUT_DIR/part_k.step (AP214) and OUT_DIR/part_k.json:
  {"faces": [{"entity": n, "kind": "plane"|"cylinder"|"cone"|"sphere"|"torus"|"other",
              "origin": [..], "axis": [..], "radius": r, "radius2": r2,
              "area": exact area (mm²), "mesh_area": area of this OCCT's own tessellation}],
   "bounds": [[lo], [hi]], "holes": [{"centre": [..], "axis": [..], "radius": r}]}
With DX DY DR, each block is also written as built with its first hole moved by (DX, DY) mm
across its axis and its radius grown by DR mm: OUT_DIR/part_k_actual.step, and the truth gains
"planted": {"hole": 0, "shift": [..] (CAD frame), "radius": r}.
Entities are the STEP entity numbers (#n) of the ADVANCED_FACEs, read back from the file by this
OCCT. Families: a block with filleted edges (planes, cylinders, sphere corners), through holes
(cylinders), a countersink (cone) and a turned groove on a shaft (torus), at random sizes and in a
random pose.
"""

import json
import math
import re
import random
import sys

from OCP.BRep import BRep_Tool
from OCP.BRepAdaptor import BRepAdaptor_Surface
from OCP.BRepBndLib import BRepBndLib
from OCP.Bnd import Bnd_Box
from OCP.BRepAlgoAPI import BRepAlgoAPI_Cut, BRepAlgoAPI_Fuse
from OCP.BRepBuilderAPI import BRepBuilderAPI_Transform
from OCP.BRepFilletAPI import BRepFilletAPI_MakeFillet
from OCP.BRepGProp import BRepGProp
from OCP.BRepMesh import BRepMesh_IncrementalMesh
from OCP.BRepPrimAPI import (BRepPrimAPI_MakeBox, BRepPrimAPI_MakeCone,
                             BRepPrimAPI_MakeCylinder, BRepPrimAPI_MakeTorus)
from OCP.GeomAbs import (GeomAbs_Cone, GeomAbs_Cylinder, GeomAbs_Plane, GeomAbs_Sphere,
                         GeomAbs_Torus)
from OCP.GProp import GProp_GProps
from OCP.IFSelect import IFSelect_RetDone
from OCP.Interface import Interface_Static
from OCP.STEPControl import STEPControl_AsIs, STEPControl_Reader, STEPControl_Writer
from OCP.TopAbs import TopAbs_FACE, TopAbs_REVERSED, TopAbs_EDGE
from OCP.TopExp import TopExp_Explorer
from OCP.TopLoc import TopLoc_Location
from OCP.TopoDS import TopoDS
from OCP.gp import gp_Ax1, gp_Ax2, gp_Dir, gp_Pnt, gp_Trsf, gp_Vec


def xyz(v):
    return [v.X(), v.Y(), v.Z()]


def block(rng, plant=None):
    """A filleted block with through holes and one countersink; `plant` (dx, dy, dr) moves and
    grows the first hole."""
    lx, ly, lz = rng.uniform(60, 200), rng.uniform(40, 150), rng.uniform(10, 40)
    shape = BRepPrimAPI_MakeBox(gp_Pnt(-lx / 2, -ly / 2, 0), lx, ly, lz).Shape()
    fillet = BRepFilletAPI_MakeFillet(shape)
    r = rng.uniform(1.0, min(5.0, lz / 4))
    ex = TopExp_Explorer(shape, TopAbs_EDGE)
    while ex.More():
        fillet.Add(r, TopoDS.Edge(ex.Current()))
        ex.Next()
    shape = fillet.Shape()
    holes = []
    for _ in range(rng.randint(1, 4)):
        for _attempt in range(50):
            hr = rng.uniform(2.0, 10.0)
            cx = rng.uniform(-lx / 2 + hr + 8, lx / 2 - hr - 8)
            cy = rng.uniform(-ly / 2 + hr + 8, ly / 2 - hr - 8)
            if all(math.hypot(cx - h[0], cy - h[1]) > hr + h[2] + 8 for h in holes):
                holes.append((cx, cy, hr))
                break
    for i, (cx, cy, hr) in enumerate(holes):
        if i == 0 and plant is not None:
            cx, cy, hr = cx + plant[0], cy + plant[1], hr + plant[2]
        tool = BRepPrimAPI_MakeCylinder(gp_Ax2(gp_Pnt(cx, cy, -1), gp_Dir(0, 0, 1)), hr,
                                        lz + 2).Shape()
        shape = BRepAlgoAPI_Cut(shape, tool).Shape()
        if i == 0 and lz > 12:
            # a 90° countersink from the top face
            depth = min(hr, lz / 3)
            cone = BRepPrimAPI_MakeCone(gp_Ax2(gp_Pnt(cx, cy, lz - depth), gp_Dir(0, 0, 1)),
                                        hr, hr + depth + 1, depth + 1).Shape()
            shape = BRepAlgoAPI_Cut(shape, cone).Shape()
    return shape, [{"centre": [cx, cy, lz / 2], "axis": [0, 0, 1], "radius": hr}
                   for cx, cy, hr in holes]


def shaft(rng):
    """A shaft with a chamfer (cone) and a turned groove (torus)."""
    radius, length = rng.uniform(8, 30), rng.uniform(60, 160)
    shape = BRepPrimAPI_MakeCylinder(gp_Ax2(gp_Pnt(0, 0, 0), gp_Dir(0, 0, 1)), radius,
                                     length).Shape()
    chamfer = rng.uniform(1.0, radius / 4)
    cap = BRepPrimAPI_MakeCone(gp_Ax2(gp_Pnt(0, 0, length - chamfer), gp_Dir(0, 0, 1)),
                               radius + 1, radius - chamfer, chamfer).Shape()
    ring = BRepPrimAPI_MakeCylinder(gp_Ax2(gp_Pnt(0, 0, length - chamfer), gp_Dir(0, 0, 1)),
                                    radius + 5, chamfer + 1).Shape()
    shape = BRepAlgoAPI_Cut(shape, BRepAlgoAPI_Cut(ring, cap).Shape()).Shape()
    minor = rng.uniform(1.0, radius / 5)
    groove = BRepPrimAPI_MakeTorus(gp_Ax2(gp_Pnt(0, 0, rng.uniform(0.3, 0.6) * length),
                                          gp_Dir(0, 0, 1)), radius, minor).Shape()
    shape = BRepAlgoAPI_Cut(shape, groove).Shape()
    return shape, []


def random_pose(rng):
    t = gp_Trsf()
    axis = gp_Dir(rng.gauss(0, 1), rng.gauss(0, 1), rng.gauss(0, 1))
    t.SetRotation(gp_Ax1(gp_Pnt(0, 0, 0), axis), rng.uniform(-math.pi, math.pi))
    move = gp_Trsf()
    move.SetTranslation(gp_Vec(rng.uniform(-500, 500), rng.uniform(-500, 500),
                               rng.uniform(-500, 500)))
    return move.Multiplied(t)


def face_record(face, entity):
    s = BRepAdaptor_Surface(face, False)
    kind = s.GetType()
    rec = {"entity": entity, "kind": "other", "origin": [0, 0, 0], "axis": [0, 0, 0],
           "radius": 0.0, "radius2": 0.0}
    reversed_ = face.Orientation() == TopAbs_REVERSED
    if kind == GeomAbs_Plane:
        p = s.Plane()
        n = p.Axis().Direction()
        n = xyz(n)
        if not p.Direct():
            n = [-c for c in n]
        if reversed_:
            n = [-c for c in n]
        rec.update(kind="plane", origin=xyz(p.Location()), axis=n)
    elif kind == GeomAbs_Cylinder:
        c = s.Cylinder()
        rec.update(kind="cylinder", origin=xyz(c.Location()), axis=xyz(c.Axis().Direction()),
                   radius=c.Radius())
    elif kind == GeomAbs_Cone:
        c = s.Cone()
        rec.update(kind="cone", origin=xyz(c.Location()), axis=xyz(c.Axis().Direction()),
                   radius=c.RefRadius(), radius2=c.SemiAngle())
    elif kind == GeomAbs_Sphere:
        c = s.Sphere()
        rec.update(kind="sphere", origin=xyz(c.Location()), radius=c.Radius())
    elif kind == GeomAbs_Torus:
        c = s.Torus()
        rec.update(kind="torus", origin=xyz(c.Location()), axis=xyz(c.Axis().Direction()),
                   radius=c.MajorRadius(), radius2=c.MinorRadius())
    props = GProp_GProps()
    BRepGProp.SurfaceProperties_s(face, props)
    rec["area"] = props.Mass()
    loc = TopLoc_Location()
    tri = BRep_Tool.Triangulation_s(face, loc)
    area = 0.0
    if tri is not None:
        trsf = loc.Transformation()
        for i in range(1, tri.NbTriangles() + 1):
            a, b, c = tri.Triangle(i).Get()
            pa, pb, pc = (tri.Node(k).Transformed(trsf) for k in (a, b, c))
            u = gp_Vec(pa, pb)
            v = gp_Vec(pa, pc)
            area += 0.5 * u.Crossed(v).Magnitude()
    rec["mesh_area"] = area
    return rec


SURFACE_KIND = {"PLANE": "plane", "CYLINDRICAL_SURFACE": "cylinder",
                "CONICAL_SURFACE": "cone", "SPHERICAL_SURFACE": "sphere",
                "TOROIDAL_SURFACE": "torus"}


def shell_faces(path):
    """The ADVANCED_FACE labels of the file's one closed shell, in the shell's order, each with
    the type of its surface entity: read from the file's text, not through OCCT."""
    entities = {}
    text = open(path).read()
    for m in re.finditer(r"#(\d+)\s*=\s*([A-Z_0-9]+)\s*\((.*?)\)\s*;", text, re.S):
        entities[int(m.group(1))] = (m.group(2), m.group(3))
    shells = [args for kind, args in entities.values() if kind == "CLOSED_SHELL"]
    if len(shells) != 1:
        raise SystemExit(f"{path}: {len(shells)} closed shells, expected one")
    out = []
    for ref in re.findall(r"#(\d+)", shells[0]):
        kind, args = entities[int(ref)]
        if kind != "ADVANCED_FACE":
            raise SystemExit(f"{path}: shell member #{ref} is {kind}")
        surface_ref = re.findall(r"#(\d+)", args)[-1]
        out.append((int(ref), entities[int(surface_ref)][0]))
    return out


def main():
    out, seed, count = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    plant = [float(v) for v in sys.argv[4:7]] if len(sys.argv) >= 7 else None
    rng = random.Random(seed)
    Interface_Static.SetCVal_s("write.step.schema", "AP214IS")
    Interface_Static.SetCVal_s("write.step.unit", "MM")
    for k in range(count):
        state = rng.getstate()
        shape, holes = (block if k % 3 != 2 else shaft)(rng)
        actual = None
        if plant is not None and k % 3 != 2:
            again = random.Random()
            again.setstate(state)
            actual, _ = block(again, plant)
        pose = random_pose(rng)
        shape = BRepBuilderAPI_Transform(shape, pose, True).Shape()
        planted = None
        if actual is not None:
            actual = BRepBuilderAPI_Transform(actual, pose, True).Shape()
            writer = STEPControl_Writer()
            writer.Transfer(actual, STEPControl_AsIs)
            if writer.Write(f"{out}/part_{k}_actual.step") != IFSelect_RetDone:
                raise SystemExit(f"cannot write {out}/part_{k}_actual.step")
            shift = gp_Vec(plant[0], plant[1], 0).Transformed(pose)
            planted = {"hole": 0, "shift": [shift.X(), shift.Y(), shift.Z()],
                       "radius": holes[0]["radius"] + plant[2]}
        for h in holes:
            p = gp_Pnt(*h["centre"]).Transformed(pose)
            d = gp_Dir(*h["axis"]).Transformed(pose)
            h["centre"], h["axis"] = xyz(p), xyz(d)
        path = f"{out}/part_{k}.step"
        writer = STEPControl_Writer()
        writer.Transfer(shape, STEPControl_AsIs)
        if writer.Write(path) != IFSelect_RetDone:
            raise SystemExit(f"cannot write {path}")
        # Read the file back so that each face is keyed by its entity number in the file.
        reader = STEPControl_Reader()
        if reader.ReadFile(path) != IFSelect_RetDone:
            raise SystemExit(f"cannot read back {path}")
        reader.TransferRoots()
        back = reader.OneShape()
        BRepMesh_IncrementalMesh(back, 0.01, False, 0.35, True)
        labels = shell_faces(path)
        faces = []
        ex = TopExp_Explorer(back, TopAbs_FACE)
        while ex.More():
            faces.append(TopoDS.Face(ex.Current()))
            ex.Next()
        if len(faces) != len(labels):
            raise SystemExit(f"{path}: {len(faces)} faces read back, {len(labels)} in the shell")
        records = []
        for face, (label, surface) in zip(faces, labels):
            rec = face_record(face, label)
            if SURFACE_KIND.get(surface, "other") != rec["kind"]:
                raise SystemExit(f"{path}: face #{label} is a {surface} in the file but "
                                 f"{rec['kind']} read back: the face order differs")
            records.append(rec)
        faces = records
        box = Bnd_Box()
        BRepBndLib.AddOptimal_s(back, box, False, False)
        solid = GProp_GProps()
        BRepGProp.VolumeProperties_s(back, solid)
        with open(f"{out}/part_{k}.json", "w") as f:
            json.dump({"faces": faces, "volume": solid.Mass(), "bounds": [xyz(box.CornerMin()), xyz(box.CornerMax())],
                       "holes": holes, "planted": planted}, f)


if __name__ == "__main__":
    main()
