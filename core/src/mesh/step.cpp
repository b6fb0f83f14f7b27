// STEP (ISO 10303-21, AP203/AP214/AP242) B-rep models read by OpenCASCADE and tessellated to a
// chordal tolerance, face by face, so that each triangle keeps the B-rep face it came from.
// The C interface below is the only way in; every OpenCASCADE exception is caught here and turned
// into a message, and a deadline stops the transfer and the meshing through OpenCASCADE's own
// user-break hook.

#include <BRepAdaptor_Surface.hxx>
#include <BRepBndLib.hxx>
#include <BRepMesh_IncrementalMesh.hxx>
#include <BRep_Tool.hxx>
#include <Bnd_Box.hxx>
#include <IFSelect_ReturnStatus.hxx>
#include <IMeshTools_Parameters.hxx>
#include <Interface_InterfaceModel.hxx>
#include <Interface_Static.hxx>
#include <Message.hxx>
#include <Message_Messenger.hxx>
#include <Message_PrinterOStream.hxx>
#include <Message_ProgressIndicator.hxx>
#include <Message_ProgressRange.hxx>
#include <Message_ProgressScope.hxx>
#include <Poly_Triangulation.hxx>
#include <STEPControl_Reader.hxx>
#include <Standard_Failure.hxx>
#include <StepRepr_RepresentationItem.hxx>
#include <TCollection_HAsciiString.hxx>
#include <TopAbs.hxx>
#include <TopExp.hxx>
#include <TopLoc_Location.hxx>
#include <TopTools_IndexedMapOfShape.hxx>
#include <TopoDS.hxx>
#include <TopoDS_Face.hxx>
#include <TopoDS_Shape.hxx>
#include <XSControl_TransferReader.hxx>
#include <XSControl_WorkSession.hxx>
#include <gp_Cone.hxx>
#include <gp_Cylinder.hxx>
#include <gp_Pln.hxx>
#include <gp_Sphere.hxx>
#include <gp_Torus.hxx>

#include <chrono>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

namespace {

// Stops OpenCASCADE's long operations (transfer, meshing) once the deadline has passed.
class Deadline : public Message_ProgressIndicator {
public:
    explicit Deadline(double seconds)
        : end_(std::chrono::steady_clock::now()
               + std::chrono::microseconds(static_cast<long long>(seconds * 1e6))) {}
    Standard_Boolean UserBreak() override {
        return std::chrono::steady_clock::now() > end_;
    }
    void Show(const Message_ProgressScope&, const Standard_Boolean) override {}
    bool passed() const { return std::chrono::steady_clock::now() > end_; }

private:
    std::chrono::steady_clock::time_point end_;
};

char* copy_string(const std::string& s) {
    char* out = static_cast<char*>(std::malloc(s.size() + 1));
    if (out != nullptr) {
        std::memcpy(out, s.c_str(), s.size() + 1);
    }
    return out;
}

template <typename T> T* copy_vector(const std::vector<T>& v) {
    if (v.empty()) {
        return nullptr;
    }
    T* out = static_cast<T*>(std::malloc(v.size() * sizeof(T)));
    if (out != nullptr) {
        std::memcpy(out, v.data(), v.size() * sizeof(T));
    }
    return out;
}

}  // namespace

extern "C" {

// One B-rep face: its surface kind and, for analytic surfaces, their parameters (mm, unit
// vectors). kind: 0 other, 1 plane, 2 cylinder, 3 cone, 4 sphere, 5 torus, 6 B-spline/Bezier,
// 7 surface of revolution or extrusion, 8 offset.
// plane: origin, normal (outward, the face's orientation applied);
// cylinder: axis point, axis direction, radius; cone: apex-side point on the axis, direction,
// reference radius, semi-angle (rad); sphere: centre, radius; torus: centre, axis, major, minor.
struct RisStepFace {
    int32_t kind;
    int32_t reversed;
    double origin[3];
    double axis[3];
    double radius;
    double radius2;
    int32_t entity;  // the face's STEP entity number (#n in the file), 0 if not known
    int32_t triangles;
};

struct RisStepMesh {
    double* vertices;     // 3 per vertex
    size_t n_vertices;
    uint32_t* triangles;  // 3 per triangle, counter-clockwise seen from outside the solid
    uint32_t* face_of;    // per triangle: the index of its face in `faces`
    size_t n_triangles;
    RisStepFace* faces;
    size_t n_faces;
    char* names;          // face names (the STEP entity's name), '\n'-separated, one per face
    size_t untriangulated;  // faces without a triangulation (degenerate or failed)
    double lo[3];
    double hi[3];
    char* error;          // set when the call failed; everything else is then empty
};

void ris_step_free(RisStepMesh* m) {
    if (m == nullptr) {
        return;
    }
    std::free(m->vertices);
    std::free(m->triangles);
    std::free(m->face_of);
    std::free(m->faces);
    std::free(m->names);
    std::free(m->error);
    std::memset(m, 0, sizeof(*m));
}

// Read `path`, tessellate every face to `chordal` mm (and `angular` rad) and fill `out`.
// Returns 0 on success; otherwise `out->error` says why. `max_triangles` bounds the result
// and `seconds` the time of the transfer and the meshing.
int ris_step_read(const char* path, double chordal, double angular, size_t max_triangles,
                  double seconds, RisStepMesh* out) {
    std::memset(out, 0, sizeof(*out));
    std::string failure;
    try {
        // OpenCASCADE's messages (transfer statistics, warnings) go nowhere: the caller reports.
        Handle(Message_Messenger) messenger = Message::DefaultMessenger();
        messenger->RemovePrinters(STANDARD_TYPE(Message_PrinterOStream));
        Interface_Static::SetCVal("xstep.cascade.unit", "MM");
        Interface_Static::SetIVal("read.step.ideas", 0);

        STEPControl_Reader reader;
        const IFSelect_ReturnStatus status = reader.ReadFile(path);
        if (status != IFSelect_RetDone) {
            out->error = copy_string("not a readable STEP (ISO 10303-21) file: the parser "
                                     "refused its syntax or its schema");
            return 1;
        }
        Handle(Deadline) deadline = new Deadline(seconds);
        Message_ProgressRange range = deadline->Start();
        Message_ProgressScope scope(range, "STEP", 2);
        if (reader.NbRootsForTransfer() == 0) {
            out->error = copy_string("the file holds no shape (no product or representation "
                                     "to transfer)");
            return 1;
        }
        reader.TransferRoots(scope.Next());
        if (deadline->passed()) {
            out->error = copy_string("reading the B-rep took longer than the time allowed");
            return 1;
        }
        TopoDS_Shape shape = reader.OneShape();
        if (shape.IsNull()) {
            out->error = copy_string("the file's shapes could not be transferred to a B-rep");
            return 1;
        }
        TopTools_IndexedMapOfShape faces;
        TopExp::MapShapes(shape, TopAbs_FACE, faces);
        if (faces.Extent() == 0) {
            out->error = copy_string("the shape has no faces (wireframe or points only)");
            return 1;
        }
        Bnd_Box box;
        BRepBndLib::Add(shape, box);
        double x0, y0, z0, x1, y1, z1;
        box.Get(x0, y0, z0, x1, y1, z1);
        out->lo[0] = x0; out->lo[1] = y0; out->lo[2] = z0;
        out->hi[0] = x1; out->hi[1] = y1; out->hi[2] = z1;

        IMeshTools_Parameters parameters;
        parameters.Deflection = chordal;
        parameters.DeflectionInterior = chordal;
        parameters.Angle = angular;
        parameters.AngleInterior = angular;
        parameters.InParallel = Standard_True;
        parameters.Relative = Standard_False;
        BRepMesh_IncrementalMesh mesher(shape, parameters, scope.Next());
        if (deadline->passed()) {
            out->error = copy_string("tessellating the faces took longer than the time allowed");
            return 1;
        }

        Handle(XSControl_TransferReader) transfer = reader.WS()->TransferReader();
        Handle(Interface_InterfaceModel) model = reader.WS()->Model();
        std::vector<double> vertices;
        std::vector<uint32_t> triangles;
        std::vector<uint32_t> face_of;
        std::vector<RisStepFace> infos;
        std::string names;
        for (int f = 1; f <= faces.Extent(); ++f) {
            const TopoDS_Face& face = TopoDS::Face(faces(f));
            RisStepFace info;
            std::memset(&info, 0, sizeof(info));
            const bool reversed = face.Orientation() == TopAbs_REVERSED;
            info.reversed = reversed ? 1 : 0;
            std::string name;
            if (!transfer.IsNull() && !model.IsNull()) {
                Handle(Standard_Transient) entity = transfer->EntityFromShapeResult(face, 1);
                if (entity.IsNull()) {
                    entity = transfer->EntityFromShapeResult(face, -1);
                }
                if (!entity.IsNull()) {
                    info.entity = model->Number(entity) > 0
                        ? std::atoi(model->StringLabel(entity)->ToCString() + 1) : 0;
                    Handle(StepRepr_RepresentationItem) item =
                        Handle(StepRepr_RepresentationItem)::DownCast(entity);
                    if (!item.IsNull() && !item->Name().IsNull()) {
                        name = item->Name()->ToCString();
                    }
                }
            }
            for (char& c : name) {
                if (c == '\n' || c == '\r') {
                    c = ' ';
                }
            }
            names += name;
            names += '\n';
            BRepAdaptor_Surface surface(face, Standard_False);
            const double sign = reversed ? -1.0 : 1.0;
            auto put = [](double* dst, const gp_XYZ& v) {
                dst[0] = v.X(); dst[1] = v.Y(); dst[2] = v.Z();
            };
            switch (surface.GetType()) {
            case GeomAbs_Plane: {
                const gp_Pln p = surface.Plane();
                info.kind = 1;
                put(info.origin, p.Location().XYZ());
                gp_XYZ n = p.Axis().Direction().XYZ();
                if (!p.Direct()) {
                    n.Reverse();
                }
                put(info.axis, n * sign);
                break;
            }
            case GeomAbs_Cylinder: {
                const gp_Cylinder c = surface.Cylinder();
                info.kind = 2;
                put(info.origin, c.Location().XYZ());
                put(info.axis, c.Axis().Direction().XYZ());
                info.radius = c.Radius();
                break;
            }
            case GeomAbs_Cone: {
                const gp_Cone c = surface.Cone();
                info.kind = 3;
                put(info.origin, c.Location().XYZ());
                put(info.axis, c.Axis().Direction().XYZ());
                info.radius = c.RefRadius();
                info.radius2 = c.SemiAngle();
                break;
            }
            case GeomAbs_Sphere: {
                const gp_Sphere s = surface.Sphere();
                info.kind = 4;
                put(info.origin, s.Location().XYZ());
                put(info.axis, s.Position().Direction().XYZ());
                info.radius = s.Radius();
                break;
            }
            case GeomAbs_Torus: {
                const gp_Torus t = surface.Torus();
                info.kind = 5;
                put(info.origin, t.Location().XYZ());
                put(info.axis, t.Axis().Direction().XYZ());
                info.radius = t.MajorRadius();
                info.radius2 = t.MinorRadius();
                break;
            }
            case GeomAbs_BSplineSurface:
            case GeomAbs_BezierSurface:
                info.kind = 6;
                break;
            case GeomAbs_SurfaceOfRevolution:
            case GeomAbs_SurfaceOfExtrusion:
                info.kind = 7;
                break;
            case GeomAbs_OffsetSurface:
                info.kind = 8;
                break;
            default:
                info.kind = 0;
                break;
            }

            TopLoc_Location location;
            Handle(Poly_Triangulation) tri = BRep_Tool::Triangulation(face, location);
            if (tri.IsNull() || tri->NbTriangles() == 0) {
                out->untriangulated += 1;
                infos.push_back(info);
                continue;
            }
            if (triangles.size() / 3 + static_cast<size_t>(tri->NbTriangles()) > max_triangles) {
                out->error = copy_string(
                    "the tessellation would exceed " + std::to_string(max_triangles)
                    + " triangles: raise the chordal tolerance");
                return 1;
            }
            const gp_Trsf& trsf = location.Transformation();
            const uint32_t base = static_cast<uint32_t>(vertices.size() / 3);
            for (int i = 1; i <= tri->NbNodes(); ++i) {
                const gp_Pnt p = tri->Node(i).Transformed(trsf);
                vertices.push_back(p.X());
                vertices.push_back(p.Y());
                vertices.push_back(p.Z());
            }
            for (int i = 1; i <= tri->NbTriangles(); ++i) {
                int a, b, c;
                tri->Triangle(i).Get(a, b, c);
                if (reversed) {
                    std::swap(b, c);
                }
                triangles.push_back(base + static_cast<uint32_t>(a - 1));
                triangles.push_back(base + static_cast<uint32_t>(b - 1));
                triangles.push_back(base + static_cast<uint32_t>(c - 1));
                face_of.push_back(static_cast<uint32_t>(f - 1));
            }
            info.triangles = tri->NbTriangles();
            infos.push_back(info);
        }
        out->vertices = copy_vector(vertices);
        out->n_vertices = vertices.size() / 3;
        out->triangles = copy_vector(triangles);
        out->face_of = copy_vector(face_of);
        out->n_triangles = face_of.size();
        out->faces = copy_vector(infos);
        out->n_faces = infos.size();
        out->names = copy_string(names);
        return 0;
    } catch (const Standard_Failure& e) {
        failure = std::string("OpenCASCADE failed: ") + e.GetMessageString();
    } catch (const std::bad_alloc&) {
        failure = "out of memory while reading the model";
    } catch (...) {
        failure = "OpenCASCADE failed with an unknown exception";
    }
    ris_step_free(out);
    out->error = copy_string(failure);
    return 1;
}

}  // extern "C"
