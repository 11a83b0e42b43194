// bindings.cpp — the granular_core Python module: core/ for the usd-core front end.
//
// Contract: exposes the plain scene description (SceneDesc and its parts) for a front
// end to fill, the granular schema's meaning on prims (MeshPrim -> SceneDesc), validation, scene building and progressive rendering on a worker thread
// with the GIL released (a progress callback runs under the GIL every fraction of a
// second; if it raises, or Ctrl-C arrives, the render is cancelled and the exception
// propagates), image output, and the coarse
// density export / VDB read-back, and the teleportation-transport media of a built
// scene (Scene.media). Vec3 values are 3-sequences (returned as tuples);
// transforms are 4x4 nested sequences in core's convention (row-major, acting on
// column vectors: a USD GfMatrix4d is its transpose). Point and index arrays are numpy
// arrays. core's InputError surfaces as granular_core.InputError (a ValueError) with
// .object, .attribute and .detail; nothing a caller passes can crash the process.
#include <pybind11/functional.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <exception>
#include <memory>
#include <mutex>
#include <optional>
#include <thread>

#include "core/denoise.h"
#include "core/density_export.h"
#include "core/error.h"
#include "core/grain_density.h"
#include "core/granular_prims.h"
#include "core/heterogeneous_medium.h"
#include "core/ies.h"
#include "core/image_io.h"
#include "core/instanced_grains.h"
#include "core/medium.h"
#include "core/mesh.h"
#include "core/render.h"
#include "core/scene.h"
#include "core/scene_desc.h"
#include "core/scene_io.h"
#include "core/shapes.h"
#include "core/switching.h"
#include "core/tt.h"
#include "core/usd_camera.h"
#include "core/usd_implicit.h"
#include "core/usd_lights.h"
#include "core/usd_mesh.h"
#include "core/render_products.h"
#include "core/usd_render.h"
#include "core/usd_shading.h"

namespace py = pybind11;
using namespace granular;

// ---- Vec3 and Transform as plain Python sequences ------------------------------------
namespace pybind11::detail {

template <>
struct type_caster<Vec3> {
  PYBIND11_TYPE_CASTER(Vec3, const_name("tuple[float, float, float]"));
  bool load(handle src, bool convert) {
    if (!src || !PySequence_Check(src.ptr()) || PyUnicode_Check(src.ptr()) || PyBytes_Check(src.ptr())) return false;
    sequence seq = reinterpret_borrow<sequence>(src);
    if (seq.size() != 3) return false;
    for (size_t i = 0; i < 3; ++i) {
      make_caster<float> c;
      if (!c.load(seq[i], convert)) return false;
      value[int(i)] = cast_op<float>(c);
    }
    return true;
  }
  static handle cast(const Vec3& v, return_value_policy, handle) { return make_tuple(v.x, v.y, v.z).release(); }
};

template <>
struct type_caster<Transform> {
  PYBIND11_TYPE_CASTER(Transform, const_name("list[list[float]]"));
  bool load(handle src, bool convert) {
    if (!src || !PySequence_Check(src.ptr()) || PyUnicode_Check(src.ptr())) return false;
    sequence rows = reinterpret_borrow<sequence>(src);
    if (rows.size() != 4) return false;
    for (size_t i = 0; i < 4; ++i) {
      object row = rows[i];
      if (!PySequence_Check(row.ptr()) || PyUnicode_Check(row.ptr())) return false;
      sequence r = reinterpret_borrow<sequence>(row);
      if (r.size() != 4) return false;
      for (size_t j = 0; j < 4; ++j) {
        make_caster<double> c;
        if (!c.load(r[j], convert)) return false;
        value.m[i][j] = cast_op<double>(c);
      }
    }
    return true;
  }
  static handle cast(const Transform& t, return_value_policy, handle) {
    list rows;
    for (int i = 0; i < 4; ++i) rows.append(make_tuple(t.m[i][0], t.m[i][1], t.m[i][2], t.m[i][3]));
    return rows.release();
  }
};

}  // namespace pybind11::detail

namespace {

using FloatArray = py::array_t<float, py::array::c_style | py::array::forcecast>;
using IntArray = py::array_t<int64_t, py::array::c_style | py::array::forcecast>;

std::vector<Vec3> toPoints(const FloatArray& a, const std::string& what) {
  if (a.ndim() != 2 || a.shape(1) != 3) throw py::value_error(what + " must be an array of shape (N, 3)");
  std::vector<Vec3> pts(size_t(a.shape(0)));
  auto r = a.unchecked<2>();
  for (py::ssize_t i = 0; i < a.shape(0); ++i) pts[size_t(i)] = Vec3(r(i, 0), r(i, 1), r(i, 2));
  return pts;
}

std::vector<int64_t> toInts(const IntArray& a, const std::string& what) {
  if (a.ndim() != 1) throw py::value_error(what + " must be a 1-D array");
  auto r = a.unchecked<1>();
  std::vector<int64_t> v(size_t(a.shape(0)));
  for (py::ssize_t i = 0; i < a.shape(0); ++i) v[size_t(i)] = r(i);
  return v;
}

// Narrowing to int: values outside int's range become -1, which every consumer rejects
// as out of range (an index) or as too few vertices (a count).
std::vector<int> toInt32(const std::vector<int64_t>& v) {
  std::vector<int> r(v.size());
  for (size_t i = 0; i < v.size(); ++i) r[i] = (v[i] < INT32_MIN || v[i] > INT32_MAX) ? -1 : int(v[i]);
  return r;
}

// A numpy array's numbers as core reads them in place (granular_prims.h: NumberView): float
// (16, 32, 64 bits) or, with integers, int32/int64 arrays in C order as they are; any other
// array converted (to float32, or to int64 with integers), the copy held with the view.
struct HeldNumbers {
  py::array array;
  NumberView view;
};
HeldNumbers numbersOf(const py::object& obj, bool integers) {
  HeldNumbers h;
  py::array a = py::array::ensure(obj);
  if (!a) throw py::value_error("expected an array of numbers");
  const char kind = a.dtype().kind();
  const auto size = a.dtype().itemsize();
  // Taken in place only when C-ordered and in the machine's byte order; else converted.
  const bool inOrder = (a.flags() & py::array::c_style) != 0 && a.dtype().byteorder() != '>';
  using T = NumberView::Type;
  if (inOrder && kind == 'f' && !integers && (size == 2 || size == 4 || size == 8))
    h.view.type = size == 2 ? T::Half : size == 4 ? T::Float : T::Double;
  else if (inOrder && kind == 'i' && integers && (size == 4 || size == 8))
    h.view.type = size == 4 ? T::Int32 : T::Int64;
  else if (integers) {
    a = py::array_t<int64_t, py::array::c_style | py::array::forcecast>::ensure(obj);
    h.view.type = T::Int64;
  } else {
    a = py::array_t<float, py::array::c_style | py::array::forcecast>::ensure(obj);
    h.view.type = T::Float;
  }
  if (!a) throw py::value_error("expected an array of numbers");
  h.view.data = a.data();
  h.view.count = size_t(a.size());
  h.array = std::move(a);
  return h;
}

py::array_t<float> pointsToArray(const std::vector<Vec3>& pts) {
  py::array_t<float> a({py::ssize_t(pts.size()), py::ssize_t(3)});
  auto w = a.mutable_unchecked<2>();
  for (size_t i = 0; i < pts.size(); ++i)
    for (int k = 0; k < 3; ++k) w(py::ssize_t(i), k) = pts[i][k];
  return a;
}

// A pixel window as Python sees one: (x0, x1, y0, y1).
std::tuple<int, int, int, int> windowTuple(const PixelWindow& w) { return {w.x0, w.x1, w.y0, w.y1}; }

// A UsdGeomMesh's topology as core reads it (usd_mesh.h); numPoints stands for the points,
// which only count when a primvar is expanded.
UsdMeshRecord meshTopology(const std::string& path, size_t numPoints, const IntArray& counts, const IntArray& indices,
                           const IntArray& holes, const std::string& orientation) {
  UsdMeshRecord r;
  r.path = path;
  r.points.resize(numPoints);
  r.faceVertexCounts = toInt32(toInts(counts, "faceVertexCounts"));
  r.faceVertexIndices = toInt32(toInts(indices, "faceVertexIndices"));
  r.holeIndices = toInt32(toInts(holes, "holeIndices"));
  r.orientation = orientation;
  return r;
}

TriangleMesh makeMesh(const FloatArray& points, const IntArray& indices) {
  TriangleMesh m;
  m.points = toPoints(points, "points");
  std::vector<int64_t> idx = toInts(indices, "indices");
  m.indices.resize(idx.size());
  for (size_t i = 0; i < idx.size(); ++i)
    // Out-of-range values map to an index no mesh has, which validation reports.
    m.indices[i] = (idx[i] < 0 || idx[i] > int64_t(UINT32_MAX)) ? UINT32_MAX : uint32_t(idx[i]);
  return m;
}

py::dict boundsDict(const Bounds3& b) {
  py::dict d;
  d["lo"] = b.lo;
  d["hi"] = b.hi;
  return d;
}

// The Python exception type; a plain handle holding a reference that is never dropped,
// so that nothing touches it after the interpreter has shut down.
py::handle gInputError;

py::dict aggregateInfo(const Aggregate& a, int tileSpheres, const Vec3d& renderOrigin) {
  const AggregateStats& s = a.stats();
  py::dict d;
  d["name"] = a.name();
  d["approx_grains"] = s.approxGrains;
  d["cells"] = s.cells;
  d["inside_cells"] = s.insideCells;
  d["partial_cells"] = s.partialCells;
  d["memory_bytes"] = s.memoryBytes;
  d["setup_seconds"] = s.setupSeconds;
  d["tile_seconds"] = s.tileSeconds;
  d["sdf_seconds"] = s.sdfSeconds;
  d["field_voxel"] = s.fieldVoxel;
  d["grain_radius"] = a.grainRadius();
  d["max_grain_radius"] = a.maxGrainRadius();
  d["cell_size"] = a.cellSize();
  d["packing_rate"] = a.packingRate();
  d["tile_spheres"] = tileSpheres;
  d["tile_packing_rate"] = a.tile().packingRate;
  // In world space: the scene holds it in render space.
  Bounds3 world = a.bounds();
  for (int i = 0; i < 3; ++i) {
    world.lo[i] = float(double(world.lo[i]) + renderOrigin[i]);
    world.hi[i] = float(double(world.hi[i]) + renderOrigin[i]);
  }
  d["bounds"] = boundsDict(world);
  d["max_interior_depth"] = s.maxInteriorDepth;
  return d;
}

// Python-owned scene: the desc it was built from and the built scene.
struct PyScene {
  SceneDesc desc;
  std::unique_ptr<Scene> scene;
};

// A switching measurement's fields (switching.h) into d.
void addSwitchMeasure(const SwitchMeasure& m, py::dict& d) {
  d["candidates"] = std::vector<int>(std::begin(kSwitchVisits), std::end(kSwitchVisits));
  d["bias"] = m.bias;
  d["bias_se"] = m.biasSE;
  d["exit_bias"] = m.exitBias;
  d["exit_bias_se"] = m.exitBiasSE;
  d["exit_reference"] = m.exitReference;
  d["albedo"] = m.albedo;
  d["albedo_se"] = m.albedoSE;
  d["chosen"] = m.visits;
  d["seconds"] = m.seconds;
  d["paths"] = m.paths;
  d["candidate_paths"] = m.candidatePaths;
  d["events"] = m.events;
  d["from_cache"] = m.fromCache;
}

// The scene of aggregate a, which measured its switching (so its proxy tables and medium
// exist); IndexError or ValueError naming `what` otherwise.
const Scene& measuredAggregate(const PyScene& s, int a, const char* what) {
  const Scene& sc = *s.scene;
  if (a < 0 || a >= int(sc.aggregates().size())) throw py::index_error("aggregate out of range");
  if (!sc.switchMeasure(a))
    throw std::invalid_argument(str(what, ": the scene did not measure this aggregate's switching "
                                    "(technique ept, or explicit_bounces set)"));
  return sc;
}

// A measurement run anew with these paths, early stop and seed, the GIL released while
// the walks run on TBB's threads; the fields of `switching`.
template <typename Measure>
py::dict measuredAnew(SwitchOptions o, int64_t paths, bool stopEarly, uint64_t seed, const Measure& measure) {
  o.paths = paths;
  o.stopEarly = stopEarly;
  o.seed = seed;
  const SwitchMeasure m = [&] {
    py::gil_scoped_release release;
    return measure(o);
  }();
  py::dict d;
  addSwitchMeasure(m, d);
  return d;
}

struct PyRenderer {
  std::shared_ptr<PyScene> scene;
  std::unique_ptr<Renderer> renderer;
  std::string stoppedBy = "samples";
};

py::dict mediumDict(const MediumParams& m) {
  py::dict d;
  d["grain_radius"] = m.grainRadius;
  d["packing_rate"] = m.packingRate;
  d["sigma_b"] = m.sigmaB;
  d["beta"] = m.combined.beta;
  d["beta_se"] = m.combined.betaSE;
  d["lambda_delta"] = m.combined.lambdaDelta;
  d["lambda_s"] = py::make_tuple(m.combined.lambdaS[0], m.combined.lambdaS[1], m.combined.lambdaS[2]);
  d["lambda_beta"] = m.lambdaBeta;
  d["lambda_t"] = m.lambdaT;
  d["sigma_t"] = m.sigmaT;
  d["albedo"] = m.albedo;
  d["g"] = m.g;
  d["sigma_s_reduced"] = m.sigmaSReduced;
  d["sigma_t_reduced"] = m.sigmaTReduced;
  d["albedo_reduced"] = m.albedoReduced;
  d["sigma_a"] = m.sigmaA;
  d["sigma_tr"] = m.sigmaTr;
  d["mean_free_path"] = m.meanFreePath();
  d["rays"] = m.combined.rays;
  d["truncated"] = m.combined.truncated;
  return d;
}

}  // namespace

PYBIND11_MODULE(granular_core, m) {
  m.doc() = "hdGranular core renderer (Meng et al. 2015) for the usd-core front end";

  // ---- errors ----------------------------------------------------------------------
  gInputError = PyErr_NewException("granular_core.InputError", PyExc_ValueError, nullptr);
  if (!gInputError) throw py::error_already_set();
  m.attr("InputError") = gInputError;
  py::register_exception_translator([](std::exception_ptr p) {
    try {
      if (p) std::rethrow_exception(p);
    } catch (const InputError& e) {
      py::object inst = gInputError(py::str(e.what()));
      inst.attr("object") = e.object();
      inst.attr("attribute") = e.attribute();
      inst.attr("detail") = e.detail();
      PyErr_SetObject(gInputError.ptr(), inst.ptr());
    }
  });

  // ---- meshes ----------------------------------------------------------------------
  py::class_<TriangleMesh>(m, "TriangleMesh")
      .def(py::init<>())
      .def(py::init(&makeMesh), py::arg("points"), py::arg("indices"),
           "points: (N, 3) floats; indices: 3 per triangle")
      .def_property(
          "points", [](const TriangleMesh& t) { return pointsToArray(t.points); },
          [](TriangleMesh& t, const FloatArray& a) { t.points = toPoints(a, "points"); })
      .def_property(
          "indices",
          [](const TriangleMesh& t) {
            py::array_t<uint32_t> a(py::ssize_t(t.indices.size()));
            std::copy(t.indices.begin(), t.indices.end(), a.mutable_data());
            return a;
          },
          [](TriangleMesh& t, const IntArray& a) { t = makeMesh(pointsToArray(t.points), a); })
      .def_property_readonly("num_triangles", &TriangleMesh::numTriangles)
      .def("bounds", [](const TriangleMesh& t) { return boundsDict(t.bounds()); })
      .def("signed_volume", &TriangleMesh::signedVolume)
      .def_property(
          "uvs",
          [](const TriangleMesh& t) {
            py::array_t<float> a({py::ssize_t(t.uvs.size() / 2), py::ssize_t(2)});
            std::copy(t.uvs.begin(), t.uvs.end(), a.mutable_data());
            return a;
          },
          [](TriangleMesh& t, const FloatArray& a) {
            if (a.size() % 2 != 0) throw InputError("mesh", "uvs", "expected (corners, 2) values");
            t.uvs.assign(a.data(), a.data() + a.size());
          },
          "texture coordinates, one (u, v) per triangle corner (3 per triangle), or empty")
      .def("transformed", &TriangleMesh::transformed, py::arg("xf"))
      .def("flip", &TriangleMesh::flip);

  m.def(
      "triangulated_corners",
      [](const IntArray& counts) {
        std::vector<uint32_t> c = triangulatedCorners(toInt32(toInts(counts, "faceVertexCounts")));
        py::array_t<uint32_t> a(py::ssize_t(c.size()));
        std::copy(c.begin(), c.end(), a.mutable_data());
        return a;
      },
      py::arg("face_vertex_counts"),
      "The face-vertex index of each corner of triangulate()'s triangles (expands primvars).");

  m.def(
      "triangulate",
      [](const FloatArray& points, const IntArray& counts, const IntArray& indices, const std::string& object) {
        return triangulate(toPoints(points, "points"), toInt32(toInts(counts, "faceVertexCounts")),
                           toInt32(toInts(indices, "faceVertexIndices")), object);
      },
      py::arg("points"), py::arg("face_vertex_counts"), py::arg("face_vertex_indices"), py::arg("object"),
      "Polygons (USD faceVertexCounts/Indices) to triangles by fans; InputError naming object.");
  m.def(
      "switch_exit_bins",
      [] {
        py::list out;
        for (int j = 0; j < kSwitchExitBins; ++j) {
          const SwitchExitBinRange r = switchExitBinRange(j);
          out.append(py::make_tuple(r.lo, r.hi, r.back ? "back" : "forward"));
        }
        return out;
      },
      "the switching measurement's exit bins (switching.h): (lowest cosine from the entry's normal, highest, side)");
  m.def("validate_mesh", &validateMesh, py::arg("mesh"), py::arg("object"), py::arg("attribute") = "points");
  m.def("validate_closed", &validateClosed, py::arg("mesh"), py::arg("object"),
        "Closed, 2-manifold, consistently wound, non-zero volume; returns the signed volume.");
  m.def("make_icosphere", &makeIcosphere, py::arg("subdivisions"));
  m.def("make_box", &makeBox, py::arg("lo"), py::arg("hi"));
  m.def("make_rock", &makeRock, py::arg("subdivisions"), py::arg("roughness"), py::arg("seed"));
  m.def("make_ellipsoid", &makeEllipsoid, py::arg("radii"), py::arg("subdivisions"));
  m.def("make_uv_sphere", &makeUVSphere, py::arg("segments"), py::arg("rings"));
  m.def("make_lathe", &makeLathe, py::arg("profile"), py::arg("segments"));

  // ---- scene description -------------------------------------------------------------
  py::class_<CameraDesc>(m, "CameraDesc")
      .def(py::init<>())
      .def_readwrite("camera_to_world", &CameraDesc::cameraToWorld)
      .def_readwrite("focal_length", &CameraDesc::focalLength)
      .def_readwrite("horizontal_aperture", &CameraDesc::horizontalAperture)
      .def_readwrite("vertical_aperture", &CameraDesc::verticalAperture)
      .def_readwrite("horizontal_aperture_offset", &CameraDesc::horizontalApertureOffset)
      .def_readwrite("vertical_aperture_offset", &CameraDesc::verticalApertureOffset)
      .def_readwrite("clip_near", &CameraDesc::clipNear)
      .def_readwrite("clip_far", &CameraDesc::clipFar)
      .def_readwrite("lens_radius", &CameraDesc::lensRadius)
      .def_readwrite("focus_distance", &CameraDesc::focusDistance)
      .def_readwrite("shutter_open", &CameraDesc::shutterOpen)
      .def_readwrite("shutter_close", &CameraDesc::shutterClose);

  py::enum_<MaterialType>(m, "MaterialType")
      .value("Lambert", MaterialType::Lambert)
      .value("Dielectric", MaterialType::Dielectric);
  py::enum_<TextureWrap>(m, "TextureWrap")
      .value("UseMetadata", TextureWrap::UseMetadata)
      .value("Black", TextureWrap::Black)
      .value("Clamp", TextureWrap::Clamp)
      .value("Repeat", TextureWrap::Repeat)
      .value("Mirror", TextureWrap::Mirror);
  py::enum_<TextureColorSpace>(m, "TextureColorSpace")
      .value("Auto", TextureColorSpace::Auto)
      .value("Raw", TextureColorSpace::Raw)
      .value("SRGB", TextureColorSpace::SRGB);
  auto float4 = [](const float* v) { return py::make_tuple(v[0], v[1], v[2], v[3]); };
  auto setFloat4 = [](float* v, const std::vector<float>& x, const char* name) {
    if (x.size() != 4) throw InputError("texture", name, "expected 4 numbers");
    std::copy(x.begin(), x.end(), v);
  };
  py::class_<TextureDesc>(m, "TextureDesc")
      .def(py::init<>())
      .def_readwrite("file", &TextureDesc::file)
      .def_readwrite("source", &TextureDesc::source)
      .def_readwrite("wrap_s", &TextureDesc::wrapS)
      .def_readwrite("wrap_t", &TextureDesc::wrapT)
      .def_property(
          "scale", [float4](const TextureDesc& t) { return float4(t.scale); },
          [setFloat4](TextureDesc& t, const std::vector<float>& x) { setFloat4(t.scale, x, "scale"); })
      .def_property(
          "bias", [float4](const TextureDesc& t) { return float4(t.bias); },
          [setFloat4](TextureDesc& t, const std::vector<float>& x) { setFloat4(t.bias, x, "bias"); })
      .def_readwrite("color_space", &TextureDesc::colorSpace)
      .def_readwrite("channel", &TextureDesc::channel)
      .def_property_readonly("enabled", &TextureDesc::enabled);

  py::class_<MaterialDesc>(m, "MaterialDesc")
      .def(py::init<>())
      .def_readwrite("albedo_texture", &MaterialDesc::albedoTexture)
      .def_readwrite("emission_texture", &MaterialDesc::emissionTexture)
      .def_readwrite("opacity_texture", &MaterialDesc::opacityTexture)
      .def_readwrite("opacity", &MaterialDesc::opacity)
      .def_readwrite("opacity_threshold", &MaterialDesc::opacityThreshold)
      .def_readwrite("name", &MaterialDesc::name)
      .def_readwrite("type", &MaterialDesc::type)
      .def_readwrite("albedo", &MaterialDesc::albedo)
      .def_readwrite("ior", &MaterialDesc::ior)
      .def_readwrite("absorption", &MaterialDesc::absorption)
      .def_readwrite("emission", &MaterialDesc::emission)
      .def_readwrite("roughness", &MaterialDesc::roughness)
      .def_readwrite("energy_compensation", &MaterialDesc::energyCompensation);

  py::enum_<LightType>(m, "LightType")
      .value("Distant", LightType::Distant)
      .value("Sphere", LightType::Sphere)
      .value("Rect", LightType::Rect)
      .value("Dome", LightType::Dome)
      .value("Disk", LightType::Disk)
      .value("Cylinder", LightType::Cylinder)
      .value("Mesh", LightType::Mesh);
  py::class_<LightShaping>(m, "LightShaping")
      .def(py::init<>())
      .def_readwrite("enabled", &LightShaping::enabled)
      .def_readwrite("cone_angle", &LightShaping::coneAngle)
      .def_readwrite("cone_softness", &LightShaping::coneSoftness)
      .def_readwrite("focus", &LightShaping::focus)
      .def_readwrite("focus_tint", &LightShaping::focusTint)
      .def_readwrite("ies_file", &LightShaping::iesFile)
      .def_readwrite("ies_angle_scale", &LightShaping::iesAngleScale)
      .def_readwrite("ies_normalize", &LightShaping::iesNormalize);
  py::class_<IesProfile, std::shared_ptr<IesProfile>>(m, "IesProfile",
                                                      "An IES LM-63 profile as core reads it (core/ies.h).")
      .def("intensity", &IesProfile::intensity, py::arg("theta"), py::arg("phi"),
           "candela toward (theta, phi), radians: theta off the light's -Z, phi from +X toward +Y")
      .def_property_readonly("mean_intensity", &IesProfile::meanIntensity, "what inputs:shaping:ies:normalize divides by")
      .def_property_readonly("max_intensity", &IesProfile::maxIntensity)
      .def_property_readonly("vertical_count", &IesProfile::verticalCount)
      .def_property_readonly("horizontal_count", &IesProfile::horizontalCount);
  m.def("read_ies_file", [](const std::string& path) { return std::const_pointer_cast<IesProfile>(readIesFile(path)); },
        py::arg("path"), "The profile of an .ies file (read once while the file is unchanged); InputError when it is not one.");
  py::class_<LightDesc>(m, "LightDesc")
      .def(py::init<>())
      .def_readwrite("name", &LightDesc::name)
      .def_readwrite("type", &LightDesc::type)
      .def_readwrite("xf", &LightDesc::xf)
      .def_readwrite("color", &LightDesc::color)
      .def_readwrite("intensity", &LightDesc::intensity)
      .def_readwrite("exposure", &LightDesc::exposure)
      .def_readwrite("normalize", &LightDesc::normalize)
      .def_readwrite("angle", &LightDesc::angle)
      .def_readwrite("radius", &LightDesc::radius)
      .def_readwrite("width", &LightDesc::width)
      .def_readwrite("height", &LightDesc::height)
      .def_readwrite("length", &LightDesc::length)
      .def_readwrite("shaping", &LightDesc::shaping)
      .def_readwrite("texture_file", &LightDesc::textureFile)
      .def_readwrite("mesh", &LightDesc::mesh, "a mesh light's triangles (a copy: assign a whole TriangleMesh)")
      .def_readwrite("double_sided", &LightDesc::doubleSided)
      .def_readwrite("tint_by_material", &LightDesc::tintByMaterial)
      .def_readwrite("light_link", &LightDesc::lightLink)
      .def_readwrite("shadow_link", &LightDesc::shadowLink)
      .def_readwrite("shadows", &LightDesc::shadows);

  py::class_<MeshDesc>(m, "MeshDesc")
      .def(py::init<>())
      .def_readwrite("name", &MeshDesc::name)
      .def_readwrite("mesh", &MeshDesc::mesh)
      .def_readwrite("xf", &MeshDesc::xf)
      .def_readwrite("material", &MeshDesc::material)
      .def_readwrite("visible", &MeshDesc::visible)
      .def_readwrite("id", &MeshDesc::id)
      .def_readwrite("instance_id", &MeshDesc::instanceId)
      .def_readwrite("link_categories", &MeshDesc::linkCategories)
      .def_readwrite("shutter_xf", &MeshDesc::shutterXf,
                     "(transform at the shutter's open, at its close) for motion blur, or None: still");

  py::class_<GrainPrototypeDesc>(m, "GrainPrototypeDesc")
      .def(py::init<>())
      .def_readwrite("name", &GrainPrototypeDesc::name)
      .def_readwrite("mesh", &GrainPrototypeDesc::mesh)
      .def_readwrite("material", &GrainPrototypeDesc::material);

  py::class_<AggregateDesc>(m, "AggregateDesc")
      .def(py::init<>())
      .def_readwrite("name", &AggregateDesc::name)
      .def_readwrite("boundary", &AggregateDesc::boundary)
      .def_readwrite("xf", &AggregateDesc::xf)
      .def_readwrite("prototypes", &AggregateDesc::prototypes, "a copy: assign a whole list")
      .def_readwrite("weights", &AggregateDesc::weights)
      .def_readwrite("grain_radius", &AggregateDesc::grainRadius)
      .def_readwrite("packing_rate", &AggregateDesc::packingRate)
      .def_readwrite("seed", &AggregateDesc::seed)
      .def_readwrite("tile_spheres", &AggregateDesc::tileSpheres)
      .def_readwrite("sizes", &AggregateDesc::sizes)
      .def_readwrite("size_spread", &AggregateDesc::sizeSpread)
      .def_readwrite("id", &AggregateDesc::id)
      .def_readwrite("instance_id", &AggregateDesc::instanceId)
      .def_readwrite("link_categories", &AggregateDesc::linkCategories)
      .def_readwrite("shutter_xf", &AggregateDesc::shutterXf,
                     "(transform at the shutter's open, at its close) for motion blur, or None: still");

  py::enum_<ProxyUse>(m, "ProxyUse")
      .value("Off", ProxyUse::Off)
      .value("Auto", ProxyUse::Auto)
      .value("On", ProxyUse::On);
  py::enum_<MediumModel>(m, "MediumModel")
      .value("Tt", MediumModel::Tt)
      .value("Exits", MediumModel::Exits);
  py::enum_<Technique>(m, "Technique")
      .value("Ept", Technique::Ept)
      .value("EptVpt", Technique::EptVpt)
      .value("Hybrid", Technique::Hybrid);
  m.def("lens_radius_from_f_stop", &checkedLensRadius, py::arg("focal_length"), py::arg("f_stop"),
        py::arg("object") = "camera", py::arg("attribute") = "fStop",
        "Thin-lens radius in scene units from UsdGeomCamera's focalLength (tenths of a unit) and fStop; "
        "InputError on object.attribute for an fStop that is negative, not finite or below 0.5.");
  m.def("technique_from_name", &techniqueFromName, py::arg("name"), py::arg("object"),
        "\"ept\", \"ept+vpt\" or \"hybrid\"; else InputError on object.technique");
  m.def("technique_name", &techniqueName, py::arg("technique"));
  m.def("proxy_use_from_name", &proxyUseFromName, py::arg("name"), py::arg("object"),
        "\"off\", \"auto\" or \"on\"; else InputError on object.proxies");
  m.def("proxy_use_name", &proxyUseName, py::arg("proxies"));
  m.def("medium_model_from_name", &mediumModelFromName, py::arg("name"), py::arg("object"),
        "\"tt\" or \"exits\"; else InputError on object.medium_model");
  m.def("medium_model_name", &mediumModelName, py::arg("medium_model"));

  py::class_<RenderSettings>(m, "RenderSettings")
      .def(py::init<>())
      .def_readwrite("width", &RenderSettings::width)
      .def_readwrite("height", &RenderSettings::height)
      .def_readwrite("spp", &RenderSettings::spp)
      .def_readwrite("seed", &RenderSettings::seed)
      .def_readwrite("max_depth", &RenderSettings::maxDepth)
      .def_readwrite("rr_depth", &RenderSettings::rrDepth)
      .def_readwrite("threads", &RenderSettings::threads)
      .def_readwrite("technique", &RenderSettings::technique)
      .def_readwrite("bundle_size", &RenderSettings::bundleSize)
      .def_readwrite("tau", &RenderSettings::tau)
      .def_readwrite("explicit_bounces", &RenderSettings::explicitBounces)
      .def_readwrite("da_depth_factor", &RenderSettings::daDepthFactor)
      .def_readwrite("da_min_order", &RenderSettings::daMinOrder)
      .def_readwrite("da_instanced", &RenderSettings::daInstanced)
      .def_readwrite("roulette", &RenderSettings::roulette)
      .def_readwrite("lod", &RenderSettings::lod)
      .def_readwrite("proxies", &RenderSettings::proxies)
      .def_readwrite("medium_model", &RenderSettings::mediumModel)
      .def_readwrite("default_light", &RenderSettings::defaultLight)
      .def_readwrite("physical_sun", &RenderSettings::physicalSun)
      .def_readwrite("sun_regularization", &RenderSettings::sunRegularization)
      .def_readwrite("switch_for_view", &RenderSettings::switchForView)
      .def_readonly_static("MAX_SUN_REGULARIZATION", &RenderSettings::kMaxSunRegularization)
      .def_readwrite("dome_camera_visible", &RenderSettings::domeCameraVisible)
      .def_readwrite("cryptomatte", &RenderSettings::cryptomatte)
      .def_property(
          "crop",
          [](const RenderSettings& s) { return windowTuple({s.cropX0, s.cropX1, s.cropY0, s.cropY1}); },
          [](RenderSettings& s, const std::tuple<int, int, int, int>& c) {
            std::tie(s.cropX0, s.cropX1, s.cropY0, s.cropY1) = c;
          },
          "pixels (x0, x1, y0, y1) rendered: [x0, x1) x [y0, y1); (0, 0, 0, 0): every pixel");

  py::class_<SceneDesc>(m, "SceneDesc")
      .def(py::init<>())
      .def_readwrite("camera", &SceneDesc::camera)
      .def_readwrite("settings", &SceneDesc::settings)
      // Lists are copies (assign a whole list, or use add_*, which return the index).
      .def_readwrite("materials", &SceneDesc::materials)
      .def_readwrite("meshes", &SceneDesc::meshes)
      .def_readwrite("lights", &SceneDesc::lights)
      .def_readwrite("aggregates", &SceneDesc::aggregates)
      .def("add_material", [](SceneDesc& d, const MaterialDesc& x) { d.materials.push_back(x); return int(d.materials.size()) - 1; })
      .def("add_mesh", [](SceneDesc& d, const MeshDesc& x) { d.meshes.push_back(x); return int(d.meshes.size()) - 1; })
      .def("add_light", [](SceneDesc& d, const LightDesc& x) { d.lights.push_back(x); return int(d.lights.size()) - 1; })
      .def("add_aggregate", [](SceneDesc& d, const AggregateDesc& x) { d.aggregates.push_back(x); return int(d.aggregates.size()) - 1; })
      .def_property_readonly("num_instanced_grains", [](const SceneDesc& d) { return d.instancedGrains.size(); })
      .def_property_readonly("instanced_grains", [](const SceneDesc& d) { return d.instancedGrains; },
                             "a copy (the per-grain arrays are shared, not copied)")
      .def("add_instanced_grains", [](SceneDesc& d, const InstancedGrainsDesc& x) {
        d.instancedGrains.push_back(x);
        return int(d.instancedGrains.size()) - 1;
      });

  m.def("validate_scene_desc", &validateSceneDesc, py::arg("desc"));
  m.def("still_frame", &stillFrame, py::arg("desc"),
        "no motion blur: the camera's shutter closed at the frame, every mesh still (in place)");

  // ---- change detection (scene_desc.h: compareScenes) ---------------------------------
  // Unchanged, not None: None is a Python keyword.
  py::enum_<SceneChange>(m, "SceneChange")
      .value("Unchanged", SceneChange::Unchanged)
      .value("View", SceneChange::View)
      .value("Lights", SceneChange::Lights)
      .value("Aggregates", SceneChange::Aggregates)
      .value("Everything", SceneChange::Everything);
  py::class_<SceneChanges>(m, "SceneChanges")
      .def_property_readonly("level", &SceneChanges::level,
                             "the most work needed: Unchanged, View (Scene.set_view), else Scene.build with the "
                             "previous scene (Lights, Aggregates, Everything)")
      .def_readonly("camera", &SceneChanges::camera)
      .def_readonly("settings", &SceneChanges::settings, "render settings that Scene.set_view applies")
      .def_readonly("lights", &SceneChanges::lights)
      .def_readonly("aggregates", &SceneChanges::aggregates,
                    "indices of the new description's aggregates that a build makes anew")
      .def_readonly("aggregate_list", &SceneChanges::aggregateList)
      .def_readonly("aggregate_motion", &SceneChanges::aggregateMotion,
                    "an aggregate's motion over the shutter (lent by its build, moved anew)")
      .def_readonly("meshes", &SceneChanges::meshes)
      .def_readonly("materials", &SceneChanges::materials)
      .def_readonly("media", &SceneChanges::media)
      .def_readonly("render_space", &SceneChanges::renderSpace)
      .def_property_readonly("description", &describeChanges,
                             "for logs: 'unchanged', 'new camera', 'lights and 2 aggregates changed', ...")
      .def("__repr__", [](const SceneChanges& c) { return "<SceneChanges: " + describeChanges(c) + ">"; });
  m.def("compare_scenes", &compareScenes, py::arg("before"), py::arg("after"),
        "What a scene built from `before` needs to render `after` (every field compared)",
        py::call_guard<py::gil_scoped_release>());
  m.def(
      "render_window",
      [](const RenderSettings& s) { return windowTuple(renderWindow(s)); },
      py::arg("settings"), "The pixels (x0, x1, y0, y1) a render covers: the crop, or the whole image");
  m.def(
      "pixel_window_from_ndc",
      [](double xmin, double ymin, double xmax, double ymax, int width, int height) {
        return windowTuple(pixelWindowFromNdc(xmin, ymin, xmax, ymax, width, height));
      },
      py::arg("xmin"), py::arg("ymin"), py::arg("xmax"), py::arg("ymax"), py::arg("width"), py::arg("height"),
      "UsdRenderSettings dataWindowNDC -> pixels (x0, x1, y0, y1), rows from the top; (0, 0, 0, 0) when empty");

  // ---- the granular schema's meaning (granular_prims.h) ------------------------------------
  py::class_<UsdValue>(m, "UsdValue", "An attribute's, primvar's or shader input's value as a front end found it")
      .def(py::init<>())
      .def_readwrite("type_name", &UsdValue::typeName)
      .def_readwrite("numbers", &UsdValue::numbers)
      .def_readwrite("strings", &UsdValue::strings)
      .def_readwrite("is_array", &UsdValue::isArray)
      .def_readwrite("is_string", &UsdValue::isString)
      .def_readwrite("interpolation", &UsdValue::interpolation)
      .def_readwrite("source", &UsdValue::source)
      .def_readwrite("resolved_path", &UsdValue::resolvedPath);
  m.attr("PrimvarValue") = m.attr("UsdValue");

  py::class_<MeshPrim>(m, "MeshPrim")
      .def(py::init<>())
      .def_readwrite("path", &MeshPrim::path)
      .def_readwrite("type_name", &MeshPrim::typeName)
      .def_readwrite("active", &MeshPrim::active)
      .def_readwrite("mesh", &MeshPrim::mesh)
      .def_readwrite("instances", &MeshPrim::instances)
      .def_readwrite("instance_ids", &MeshPrim::instanceIds)
      .def_readwrite("visible", &MeshPrim::visible)
      .def_readwrite("material", &MeshPrim::material)
      .def_readwrite("display_color", &MeshPrim::displayColor)
      .def_readwrite("granular", &MeshPrim::granular, "a copy: assign a whole dict {name: PrimvarValue}")
      .def_readwrite("api_schemas", &MeshPrim::apiSchemas)
      .def_readwrite("id", &MeshPrim::id)
      .def_readwrite("link_categories", &MeshPrim::linkCategories)
      .def_readwrite("light", &MeshPrim::light, "MeshLightAPI: its LightDesc (light_from_usd), or None")
      .def_readwrite("double_sided", &MeshPrim::doubleSided);

  py::class_<AggregateValues>(m, "AggregateValues")
      .def_readonly("grain_radius", &AggregateValues::grainRadius)
      .def_readonly("packing_rate", &AggregateValues::packingRate)
      .def_readonly("prototypes", &AggregateValues::prototypes)
      .def_readonly("weights", &AggregateValues::weights)
      .def_readonly("seed", &AggregateValues::seed)
      .def_readonly("tile_spheres", &AggregateValues::tileSpheres)
      .def_readonly("sizes", &AggregateValues::sizes)
      .def_readonly("size_spread", &AggregateValues::sizeSpread);
  py::class_<GrainValues>(m, "GrainValues")
      .def_readonly("ior", &GrainValues::ior)
      .def_readonly("absorption", &GrainValues::absorption)
      .def_readonly("roughness", &GrainValues::roughness);

  m.def("resolve_prototype_path", &resolvePrototypePath, py::arg("aggregate_path"), py::arg("text"),
        "A prototypes entry made absolute against the aggregate; InputError when it is no prim path.");
  m.def("read_aggregate_values", &readAggregateValues, py::arg("prim"),
        "GranularAggregateAPI values of a MeshPrim: type-checked, fallbacks where absent.");
  m.def("read_grain_values", &readGrainValues, py::arg("prim"));
  m.def(
      "assemble_granular_scene",
      [](const std::vector<MeshPrim>& prims, SceneDesc& desc, const std::optional<py::function>& lookup) {
        PrimLookup find;
        if (lookup)
          find = [&lookup](const std::string& path, MeshPrim& out) {
            py::object r = (*lookup)(path);
            if (r.is_none()) return false;
            out = r.cast<MeshPrim>();
            return true;
          };
        assembleGranularScene(prims, desc, find);
      },
      py::arg("prims"), py::arg("desc"), py::arg("lookup") = py::none(),
      "Appends the prims' meshes, aggregates and grain materials to desc; lookup(path) returns the "
      "MeshPrim of a prototype that is not listed, or None when there is no such prim.");
  // ---- explicit grains from a PointInstancer (instanced_grains.h) -------------------------
  py::class_<InstancedGrainsDesc>(m, "InstancedGrainsDesc")
      .def_readonly("name", &InstancedGrainsDesc::name)
      .def_readonly("xf", &InstancedGrainsDesc::xf)
      .def_readonly("prototypes", &InstancedGrainsDesc::prototypes)
      .def_readonly("link_categories", &InstancedGrainsDesc::linkCategories)
      .def_property_readonly("num_grains", [](const InstancedGrainsDesc& d) { return d.size(); })
      .def_property_readonly("positions", [](const InstancedGrainsDesc& d) { return pointsToArray(d.positions); })
      .def_property_readonly("scales", [](const InstancedGrainsDesc& d) {
        py::array_t<float> a(py::ssize_t(d.scales.size()));
        std::copy(d.scales.begin(), d.scales.end(), a.mutable_data());
        return a;
      })
      .def_property_readonly("has_motion", [](const InstancedGrainsDesc& d) {
        return !d.velocities.empty() || !d.angularVelocities.empty();
      });
  m.def(
      "instanced_grains_from_usd",
      [](const std::string& path, const std::string& typeName, const Transform& xf,
         const std::vector<std::string>& prototypes, const std::vector<Transform>& prototypeXforms,
         const py::object& positions, const py::object& orientations, const py::object& scales,
         const py::object& protoIndices, const py::object& velocities, const py::object& angularVelocities,
         SceneDesc& desc, const py::function& lookup, int id, bool orientationsRealLast, const py::object& mask,
         const std::vector<std::string>& linkCategories) {
        InstancerPrim p;
        p.linkCategories = linkCategories;
        p.path = path;
        p.typeName = typeName;
        p.xf = xf;
        p.prototypes = prototypes;
        p.prototypeXforms = prototypeXforms;
        p.id = id;
        // Read in place (no copy of a float or int array in C order), each when core asks for
        // it and let go of at the next: 10^8 instances are gigabytes an array.
        HeldNumbers current;  // destroyed after the GIL is taken back
        InstancerArrays a;
        a.read = [&](const char* attr) {
          py::gil_scoped_acquire acquire;
          current = HeldNumbers();
          const std::string name = attr;
          const py::object& source = name == "positions"           ? positions
                                     : name == "orientations"      ? orientations
                                     : name == "scales"            ? scales
                                     : name == "protoIndices"      ? protoIndices
                                     : name == "velocities"        ? velocities
                                                                   : angularVelocities;
          current = numbersOf(PyCallable_Check(source.ptr()) ? source() : source, name == "protoIndices");
          return current.view;
        };
        a.orientationsRealLast = orientationsRealLast;
        std::vector<uint8_t> keep;
        if (!mask.is_none()) {
          auto m = py::array_t<uint8_t, py::array::c_style | py::array::forcecast>::ensure(mask);
          if (!m) throw py::value_error("mask must be an array of booleans");
          keep.assign(m.data(), m.data() + m.size());
        }
        PrimLookup find = [&lookup](const std::string& target, MeshPrim& out) {
          py::gil_scoped_acquire acquire;
          py::object r = lookup(target);
          if (r.is_none()) return false;
          out = r.cast<MeshPrim>();
          return true;
        };
        InstancedGrainsDesc g;
        {
          py::gil_scoped_release release;
          g = instancedGrainsFromUsd(p, a, desc, find);
        }
        current = HeldNumbers();
        if (!keep.empty()) {
          if (keep.size() != g.size())
            throw py::value_error(str("mask has ", keep.size(), " values for ", g.size(), " instances"));
          py::gil_scoped_release release;
          keepInstances(g, keep);
        }
        return g;
      },
      py::arg("path"), py::arg("type_name"), py::arg("xf"), py::arg("prototypes"), py::arg("prototype_xforms"),
      py::arg("positions"), py::arg("orientations"), py::arg("scales"), py::arg("proto_indices"),
      py::arg("velocities"), py::arg("angular_velocities"), py::arg("desc"), py::arg("lookup"), py::arg("id") = -1,
      py::arg("orientations_real_last") = false, py::arg("mask") = py::none(),
      py::arg("link_categories") = std::vector<std::string>(),
      "A PointInstancer with GranularInstancedAggregateAPI as core's InstancedGrainsDesc (arrays of numbers, "
      "read in order: 3 per instance, orientations 4 as (w, x, y, z), or as USD's (i, j, k, real) with "
      "orientations_real_last; empty when unauthored; float and int arrays in C order are read in place, "
      "others converted; each array may be given as a function returning it, called when core reads it and "
      "let go of before the next); lookup(path) returns a prototype's MeshPrim or None; its grain materials are "
      "appended to desc. mask (one boolean per instance, or None): the instances left out (False) after "
      "every check, so that errors name the authored index. The GIL is released while converting.");
  py::class_<InstancedGrains>(m, "InstancedGrains")
      .def(py::init<>())
      .def(
          "build",
          [](InstancedGrains& g, const InstancedGrainsDesc& d, bool checkOverlaps) {
            InstancedGrainsDesc copy = d;
            py::gil_scoped_release release;
            g.build(std::move(copy), makeEmbreeDevice(), checkOverlaps);
          },
          py::arg("desc"), py::arg("check_overlaps") = true)
      .def("intersect",
           [](const InstancedGrains& g, const Vec3& o, const Vec3& d, float tmin, float tmax) -> py::object {
             InstancedGrainHit h;
             if (!g.intersect(o, d, tmin, tmax, h)) return py::none();
             py::dict r;
             r["t"] = h.t;
             r["grain"] = h.grain;
             r["prototype"] = h.prototype;
             r["normal"] = h.ng;
             return std::move(r);
           },
           py::arg("origin"), py::arg("direction"), py::arg("tmin") = 0.0f, py::arg("tmax") = kInf)
      .def("occluded", &InstancedGrains::occluded, py::arg("origin"), py::arg("direction"), py::arg("tmin") = 0.0f,
           py::arg("tmax") = kInf, py::arg("time") = 0.0f)
      .def_property_readonly("stats", [](const InstancedGrains& g) {
        const InstancedGrainsStats& s = g.stats();
        py::dict r;
        r["grains"] = s.grains;
        r["cells"] = py::make_tuple(s.cells[0], s.cells[1], s.cells[2]);
        r["occupied_blocks"] = s.occupiedBlocks;
        r["entries"] = s.entries;
        r["cell_size"] = s.cellSize;
        r["input_bytes"] = s.inputBytes;
        r["grid_bytes"] = s.gridBytes;
        r["prototype_bytes"] = s.prototypeBytes;
        r["bytes_per_grain"] = s.bytesPerGrain();
        r["build_seconds"] = s.buildSeconds;
        r["overlap_seconds"] = s.overlapSeconds;
        return r;
      });
  // ---- the rest of a stage's meaning on plain records (usd_*.h) ---------------------------
  py::class_<UsdPrimRecord>(m, "UsdPrimRecord")
      .def(py::init<>())
      .def_readwrite("path", &UsdPrimRecord::path)
      .def_readwrite("type_name", &UsdPrimRecord::typeName)
      .def_readwrite("attributes", &UsdPrimRecord::attributes, "a copy: assign a whole dict {name: UsdValue}")
      .def_readwrite("xf", &UsdPrimRecord::xf);
  py::class_<UsdShaderRecord, UsdPrimRecord>(m, "UsdShaderRecord")
      .def(py::init<>())
      .def_readwrite("connections", &UsdShaderRecord::connections,
                     "a copy: assign a whole dict {input: (shader path, output name)}");
  py::class_<UsdMaterialNetwork>(m, "UsdMaterialNetwork")
      .def(py::init<>())
      .def_readwrite("material", &UsdMaterialNetwork::material)
      .def_readwrite("surface", &UsdMaterialNetwork::surface)
      .def_readwrite("shaders", &UsdMaterialNetwork::shaders, "a copy: assign a whole list");
  m.def(
      "mesh_from_usd",
      [](const std::string& path, const FloatArray& points, const IntArray& counts, const IntArray& indices,
         const IntArray& holes, const std::string& orientation) {
        UsdMeshRecord r = meshTopology(path, 0, counts, indices, holes, orientation);
        r.points = toPoints(points, "points");
        return meshFromUsd(r);
      },
      py::arg("path"), py::arg("points"), py::arg("face_vertex_counts"), py::arg("face_vertex_indices"),
      py::arg("hole_indices"), py::arg("orientation"), "A UsdGeomMesh's triangles (usd_mesh.h)");
  m.def(
      "usd_primvar_at_corners",
      [](const std::string& path, size_t numPoints, const IntArray& counts, const IntArray& indices,
         const IntArray& holes, const std::string& orientation, const UsdValue& primvar, int width,
         const std::string& attribute) {
        std::vector<float> v =
            usdPrimvarAtCorners(meshTopology(path, numPoints, counts, indices, holes, orientation), primvar, width,
                                attribute);
        py::array_t<float> a({py::ssize_t(v.size() / size_t(std::max(width, 1))), py::ssize_t(width)});
        std::copy(v.begin(), v.end(), a.mutable_data());
        return a;
      },
      py::arg("path"), py::arg("num_points"), py::arg("face_vertex_counts"), py::arg("face_vertex_indices"),
      py::arg("hole_indices"), py::arg("orientation"), py::arg("primvar"), py::arg("width"), py::arg("attribute"),
      "A primvar at every corner of mesh_from_usd's triangles, by its interpolation: (corners, width)");
  m.def("is_usd_implicit_surface", &isUsdImplicitSurface, py::arg("type_name"));
  m.def("usd_implicit_attribute_names", &usdImplicitAttributeNames);
  m.def("implicit_surface_from_usd", &implicitSurfaceFromUsd, py::arg("record"));
  m.def("usd_light_attribute_names", &usdLightAttributeNames);
  m.attr("USD_LIGHT_LINK") = kUsdLightLink;
  m.attr("USD_SHADOW_LINK") = kUsdShadowLink;
  m.def(
      "order_usd_lights", [](SceneDesc& desc) { orderUsdLights(desc.lights); }, py::arg("desc"),
      "Sorts desc's lights by prim path, as both USD front ends sample them");
  m.def("usd_camera_attribute_names", &usdCameraAttributeNames);
  m.def(
      "light_from_usd",
      [](const UsdPrimRecord& r) -> py::tuple {
        UsdWarnings w;
        std::optional<LightDesc> l = lightFromUsd(r, w);
        return py::make_tuple(l ? py::cast(*l) : py::none(), w);
      },
      py::arg("record"), "(LightDesc or None when the type is not rendered, [warnings])");
  m.def("camera_from_usd", &cameraFromUsd, py::arg("record"), py::arg("time_codes_per_second") = 24.0);
  m.def(
      "material_from_usd",
      [](const UsdMaterialNetwork& n) -> py::tuple {
        UsdWarnings w;
        std::optional<UsdMaterial> mat = materialFromUsd(n, w);
        if (!mat) return py::make_tuple(py::none(), py::none(), w);
        return py::make_tuple(py::cast(mat->desc), mat->st, w);
      },
      py::arg("network"), "(MaterialDesc or None: the default material, st primvar name, [warnings])");
  m.def(
      "display_color_from_usd",
      [](const UsdValue& value, const std::string& prim, size_t numPoints, const IntArray& counts,
         const IntArray& indices, const IntArray& holes, const std::string& orientation) -> py::tuple {
        const UsdMeshRecord topology = meshTopology(prim, numPoints, counts, indices, holes, orientation);
        UsdWarnings w;
        std::optional<Vec3> c = displayColorFromUsd(value, numPoints ? &topology : nullptr, prim, w);
        return py::make_tuple(c ? py::cast(*c) : py::none(), w);
      },
      py::arg("value"), py::arg("prim"), py::arg("num_points") = 0, py::arg("face_vertex_counts") = IntArray(),
      py::arg("face_vertex_indices") = IntArray(), py::arg("hole_indices") = IntArray(),
      py::arg("orientation") = "rightHanded",
      "(averaged colour or None, [warnings]); with a mesh's topology (read_mesh's), a count that does not "
      "fit the interpolation is ignored with a warning");
  m.def(
      "resolution_from_usd",
      [](const UsdPrimRecord& r) -> py::object {
        auto res = resolutionFromUsd(r);
        if (!res) return py::none();
        return py::make_tuple(res->first, res->second);
      },
      py::arg("settings"));
  m.def(
      "data_window_from_usd",
      [](const UsdPrimRecord* settings, const UsdPrimRecord* product, int width, int height) {
        UsdWarnings w;
        std::optional<PixelWindow> win = dataWindowFromUsd(settings, product, width, height, w);
        py::object window = py::none();
        if (win) window = py::cast(windowTuple(*win));
        return py::make_tuple(window, w);
      },
      py::arg("settings"), py::arg("product"), py::arg("width"), py::arg("height"),
      "((x0, x1, y0, y1) or None for the whole image, [warnings])");

  // ---- UsdRender products and vars (render_products.h) -------------------------------------
  py::class_<RenderVarDesc>(m, "RenderVarDesc")
      .def_readonly("path", &RenderVarDesc::path)
      .def_readonly("source_name", &RenderVarDesc::sourceName)
      .def_readonly("source_type", &RenderVarDesc::sourceType)
      .def_readonly("data_type", &RenderVarDesc::dataType)
      .def_readonly("channels", &RenderVarDesc::channels);
  py::class_<RenderProductDesc>(m, "RenderProductDesc")
      .def_readonly("path", &RenderProductDesc::path)
      .def_readonly("product_name", &RenderProductDesc::productName)
      .def_readonly("width", &RenderProductDesc::width)
      .def_readonly("height", &RenderProductDesc::height)
      .def_readonly("camera", &RenderProductDesc::camera)
      .def_readonly("pixel_aspect_ratio", &RenderProductDesc::pixelAspectRatio)
      .def_readonly("vars", &RenderProductDesc::vars)
      .def_property_readonly("window", [](const RenderProductDesc& p) { return windowTuple(p.window); })
      .def_property_readonly("channels", &RenderProductDesc::channels)
      .def_property_readonly("needs_cryptomatte", &RenderProductDesc::needsCryptomatte);
  m.def("usd_render_product_attribute_names", &usdRenderProductAttributeNames);
  m.def("usd_render_var_attribute_names", &usdRenderVarAttributeNames);
  m.def(
      "render_product_from_usd",
      [](const UsdPrimRecord* settings, const UsdPrimRecord& product, const std::vector<UsdPrimRecord>& vars) {
        UsdWarnings w;
        std::optional<RenderProductDesc> p = renderProductFromUsd(settings, product, vars, w);
        return py::make_tuple(p ? py::cast(*p) : py::none(), w);
      },
      py::arg("settings"), py::arg("product"), py::arg("vars"), "(RenderProductDesc or None, [warnings])");
  m.def("product_file_name", &productFileName, py::arg("product"), py::arg("frame"));
  m.def("check_product_output", &checkProductOutput, py::arg("product"), py::arg("frame"));
  m.def(
      "union_window", [](const std::vector<RenderProductDesc>& ps) { return windowTuple(unionWindow(ps)); },
      py::arg("products"));
  m.def("write_product", &writeProduct, py::arg("product"), py::arg("image"), py::arg("frame"),
        py::call_guard<py::gil_scoped_release>());
  m.def(
      "blackbody_rgb", [](float k) { return blackbodyRgb(k); }, py::arg("kelvin"));

  m.def("load_scene_json", &loadSceneJson, py::arg("path"), py::call_guard<py::gil_scoped_release>());

  // ---- scene building and rendering --------------------------------------------------
  py::class_<PyScene, std::shared_ptr<PyScene>> scene(m, "Scene");
  scene
      .def_static(
          "build",
          [](const SceneDesc& desc, std::shared_ptr<PyScene> previous, py::object log, bool standIns) {
            auto s = std::make_shared<PyScene>();
            s->desc = desc;
            BuildLog say;
            if (!log.is_none())
              say = [&log](const std::string& line) {
                py::gil_scoped_acquire acquire;
                log(line);
              };
            py::gil_scoped_release release;
            s->scene = Scene::build(s->desc, previous ? previous->scene.get() : nullptr,
                                    standIns ? SceneDetail::StandIns : SceneDetail::Full, say);
            return s;
          },
          py::arg("desc"), py::arg("previous") = nullptr, py::arg("log") = py::none(), py::arg("stand_ins") = false,
          "Validates and builds (BVHs, tiles, distance fields); the GIL is released. With the previous "
          "scene of the same stage, its aggregates whose inputs are unchanged are reused (no voxelising, "
          "no TT work). log(line), when given, hears what the build waits for (work the build cache does "
          "not hold). stand_ins: aggregates the previous scene cannot lend are built as stand-ins (their "
          "medium alone, no cells; core/scene.h SceneDetail::StandIns), as a viewport's first image.")
      .def(
          "set_view",
          [](PyScene& s, const CameraDesc& camera, const RenderSettings& settings) {
            s.scene->setView(camera, settings);
            s.desc.camera = camera;
            s.desc.settings = settings;
          },
          py::arg("camera"), py::arg("settings"),
          "A new camera and render settings without rebuilding (geometry, tiles, TT stay); for "
          "renderers made after it. InputError on bad values or a change between ept and the hybrid.")
      .def(
          "changes",
          [](const PyScene& s, const SceneDesc& desc) {
            py::gil_scoped_release release;
            return compareScenes(s.desc, desc);
          },
          py::arg("desc"),
          "compare_scenes(the description this scene was built from, with its latest view, desc): what "
          "it needs to render desc")
      .def_property_readonly("build_seconds", [](const PyScene& s) { return s.scene->buildSeconds(); })
      .def_property_readonly("stand_ins", [](const PyScene& s) { return s.scene->standIns(); },
                             "some aggregate is a stand-in (built with stand_ins=True)")
      .def_property_readonly("aggregates_built", [](const PyScene& s) { return s.scene->aggregatesBuilt(); },
                             "aggregates voxelised by this build")
      .def_property_readonly("aggregates_reused", [](const PyScene& s) { return s.scene->aggregatesReused(); },
                             "aggregates this build took unchanged from the previous scene")
      .def_property_readonly("media_derived", [](const PyScene& s) { return s.scene->mediaDerived(); },
                             "equivalent media this build derived from TT parameters")
      .def_property_readonly("default_light_added", [](const PyScene& s) { return s.scene->defaultLightAdded(); },
                             "the stage had no light and the default white dome (radiance 1) lights it")
      .def_property_readonly("texture_warnings", [](const PyScene& s) { return s.scene->textureWarnings(); },
                             "what the textures could not do as asked (texture.h), one line each")
      .def_property_readonly("widened_suns_warning", [](const PyScene& s) { return s.scene->widenedSunsWarning(); },
                             "the warning about delta suns rendered as the physical sun (\"\" when none)")
      .def_property_readonly("light_picks", [](const PyScene& s) { return s.scene->lightPicksText(); },
                             "each light's chance in light sampling, \"sun 87.6%, sky 12.4%\" (\"\" with one light)")
      .def_property_readonly("ies_profiles", [](const PyScene& s) { return s.scene->iesProfilesText(); },
                             "the lights' IES profiles, for the logs (\"\" when none has one)")
      .def_property_readonly("light_links", [](const PyScene& s) { return s.scene->lightLinksText(); },
                             "each linked light and the objects it lights, \"/World/Rim lights 2 of 14 objects\" "
                             "(\"\" when no light is linked)")
      .def_property_readonly("shadow_links", [](const PyScene& s) { return s.scene->shadowLinksText(); },
                             "each shadow-linked light and the objects that cast shadows from it, "
                             "\"/World/Key: 3 of 14 objects cast shadows\" (\"\" when none is)")
      .def_property_readonly("has_media", [](const PyScene& s) { return s.scene->hasMedia(); },
                             "whether the integrator uses the equivalent media (VPT, DA) in this scene")
      .def_property_readonly("use_proxies", [](const PyScene& s) { return s.scene->useProxies(); },
                             "whether paths go on among proxies after their first grain (RenderSettings.proxies)")
      .def_property_readonly("explicit_bounces", [](const PyScene& s) { return s.scene->explicitBounces(); },
                             "bounces a path not in an aggregate keeps explicit before it may enter a medium (the setting, or "
                             "the largest over the aggregates and instancers)")
      .def_property_readonly(
          "switching",
          [](const PyScene& s) {
            py::list out;
            for (size_t a = 0; a < s.scene->aggregates().size(); ++a) {
              py::dict d;
              const int ai = int(a);
              d["uses_proxies"] = s.scene->useProxies(ai);
              d["proxy_visits"] = s.scene->proxyVisits(ai);
              d["explicit_bounces"] = s.scene->explicitBounces(ai);
              const SwitchMeasure* m = s.scene->switchMeasure(ai);
              d["measured"] = m != nullptr;
              if (m) addSwitchMeasure(*m, d);
              if (const SwitchMeasure* v = s.scene->sunSwitchMeasure(ai)) {
                py::dict sun;
                addSwitchMeasure(*v, sun);
                d["sun"] = sun;
              }
              if (const SwitchMeasure* v = s.scene->viewSwitchMeasure(ai)) {
                py::dict view;
                addSwitchMeasure(*v, view);
                d["view"] = view;
              }
              out.append(d);
            }
            return out;
          },
          "per aggregate: whether paths go on among proxies after their first grain, the proxy visits (or "
          "explicit bounces without proxies) before the medium, and the measurement they come from (switching.h): "
          "candidates (visits tried), bias and bias_se per candidate (relative, RGB), exit_bias and exit_bias_se "
          "per candidate and exit bin (index candidate * len(switch_exit_bins()) + bin), exit_reference per bin, "
          "albedo, chosen, seconds, paths, candidate_paths (per candidate, the paths that forked it: 0 where it "
          "was not measured, its bias 0), events (walk steps), from_cache; under `sun` the same fields of the sun "
          "measurement where it was made (Scene::sunSwitchMeasure: the radiance scattered back toward the distant "
          "lights; from the dome's choice on); with switch_for_view, under `view` those of the view measurement "
          "where it was made (its albedo: the radiance the camera sees there)")
      .def(
          "measure_view_switch",
          [](const PyScene& s, int a, int64_t paths, bool stopEarly, uint64_t seed, bool sun) {
            const Scene& sc = measuredAggregate(s, a, "measure_view_switch");
            const SwitchView view = (sun ? sc.sunSwitchViews() : sc.switchViews())[size_t(a)];
            if (view.entries.size() < size_t(Scene::kMinViewEntries))
              throw std::invalid_argument(str("measure_view_switch: the ", sun ? "distant lights see" : "camera sees",
                                              " aggregate ", a, " in ", view.entries.size(), " of its ",
                                              Scene::kViewGrid * Scene::kViewGrid, " entry rays (",
                                              Scene::kMinViewEntries, " needed), or no distant light or dome lights it"));
            py::dict d = measuredAnew(sun ? sc.sunSwitchOptionsFor(a) : viewSwitchOptions(), paths, stopEarly, seed,
                                      [&](const SwitchOptions& o) {
              return measureViewSwitch(*sc.aggregates()[size_t(a)], sc.proxyTables(a), sc.medium(a), view, o);
            });
            d["entries"] = view.entries.size();
            return d;
          },
          py::arg("aggregate"), py::arg("paths") = viewSwitchOptions().paths, py::arg("stop_early") = true,
          py::arg("seed") = uint64_t(1), py::arg("sun") = false,
          "the view measurement of aggregate a (switching.h: measureViewSwitch; Scene::switchViews) from the scene's camera "
          "and lights, uncached: the fields of `switching` (albedo: the radiance the camera sees there), and entries "
          "(the camera's rays that meet the aggregate); sun=True: the sun measurement's instead (Scene::sunSwitchViews: "
          "the aggregate as each distant light sees it; its candidates from the dome's choice on, as the scene's); "
          "ValueError when the camera (the lights) see too little of it (fewer than 16 entries) or no distant light "
          "or dome lights it")
      .def(
          "measure_switch",
          [](const PyScene& s, int a, int64_t paths, bool stopEarly, uint64_t seed) {
            const Scene& sc = measuredAggregate(s, a, "measure_switch");
            return measuredAnew(SwitchOptions{}, paths, stopEarly, seed, [&](const SwitchOptions& o) {
              return measureSwitch(*sc.aggregates()[size_t(a)], sc.proxyTables(a), sc.medium(a), o);
            });
          },
          py::arg("aggregate"), py::arg("paths") = int64_t(1) << 16, py::arg("stop_early") = true,
          py::arg("seed") = uint64_t(1),
          "the switching measurement of aggregate a (switching.h) run anew, uncached, with `paths` paths; "
          "stop_early=False: every candidate forks in every path and all the paths are traced (reports); the "
          "fields of `switching`")
      .def(
          "low_orders_text", [](const PyScene& s, int a) {
            if (a < 0 || size_t(a) >= s.scene->aggregates().size()) throw py::index_error("no such aggregate");
            return s.scene->lowOrdersText(a);
          },
          py::arg("aggregate"),
          "what carries the aggregate's low orders after its first grain, in the words both front ends print")
      .def_property_readonly("aggregates", [](const PyScene& s) {
        py::list out;
        const auto& aggs = s.scene->aggregates();
        for (size_t i = 0; i < aggs.size(); ++i)
          out.append(aggregateInfo(*aggs[i], s.desc.aggregates[i].tileSpheres, s.scene->renderOrigin()));
        return out;
      })
      .def_property_readonly("instanced_grains", [](const PyScene& s) {
        py::list out;
        const auto& all = s.scene->instancedGrains();
        for (size_t i = 0; i < all.size(); ++i) {
          py::dict d;
          d["name"] = all[i]->desc().name;
          d["grains"] = all[i]->stats().grains;
          d["grid_bytes"] = all[i]->stats().gridBytes;
          d["has_medium"] = s.scene->instancedMedium(int(i)) != nullptr;
          d["proxies"] = s.scene->instancedProxies(int(i));
          d["proxy_visits"] = s.scene->instancedProxyVisits(int(i));
          d["low_orders"] = s.scene->instancedLowOrdersText(int(i));
          d["diffusion"] = s.scene->instancedDiffusionText(int(i));
          const InstancedGrainsStats& st = all[i]->stats();
          d["input_bytes"] = st.inputBytes;
          d["grid_seconds"] = st.buildSeconds;
          d["overlap_seconds"] = st.overlapSeconds;
          const GrainDensityStats* density = s.scene->instancedDensityStats(int(i));
          d["density_seconds"] = density ? density->seconds : 0.0;
          d["density_bytes"] = density ? density->bytes : size_t(0);
          d["medium_seconds"] = s.scene->instancedMediumSeconds(int(i));
          d["tables_seconds"] = s.scene->instancedTablesSeconds(int(i));
          out.append(d);
        }
        return out;
      }, "per instancer of explicit grains: name, grains, grid_bytes, has_medium, proxies, proxy_visits, "
         "low_orders (what carries the paths after their first grain, in words), diffusion (whether DA takes "
         "its medium's deep paths, in words), input_bytes (the per-grain "
         "arrays); this build's seconds: "
         "grid_seconds, overlap_seconds (its grid, 0 when lent), medium_seconds (its medium: the packing-rate "
         "grid, density_seconds of it, and TT), tables_seconds (proxy tables); density_bytes (the "
         "packing-rate grid)");

  py::class_<Image>(m, "Image")
      .def(py::init([](const FloatArray& pixels, const std::vector<std::string>& channels, int x, int y, int fullWidth,
                       int fullHeight) {
             if (pixels.ndim() != 3 || pixels.shape(2) != py::ssize_t(channels.size()))
               throw py::value_error("pixels must be a (height, width, len(channels)) array");
             Image img(int(pixels.shape(1)), int(pixels.shape(0)), channels);
             std::copy(pixels.data(), pixels.data() + img.pixels.size(), img.pixels.begin());
             img.x = x;
             img.y = y;
             img.fullWidth = fullWidth;
             img.fullHeight = fullHeight;
             return img;
           }),
           py::arg("pixels"), py::arg("channels"), py::arg("x") = 0, py::arg("y") = 0, py::arg("full_width") = 0,
           py::arg("full_height") = 0,
           "An image of float32 pixels (height, width, channels), at (x, y) of a full_width x full_height "
           "image (0: this is the full image)")
      .def_readonly("width", &Image::width)
      .def_readonly("height", &Image::height)
      .def_readonly("x", &Image::x)
      .def_readonly("y", &Image::y)
      .def_property_readonly("full_width", &Image::displayWidth)
      .def_property_readonly("full_height", &Image::displayHeight)
      .def_readonly("channels", &Image::channels)
      .def_readwrite("attributes", &Image::attributes, "string header metadata [(name, value)] (EXR)")
      .def_property_readonly(
          "pixels",
          [](const Image& img) {
            py::array_t<float> a({py::ssize_t(img.height), py::ssize_t(img.width), py::ssize_t(img.channels.size())});
            std::copy(img.pixels.begin(), img.pixels.end(), a.mutable_data());
            return a;
          },
          "a (height, width, channels) float32 copy, top row first");

  py::class_<PyRenderer>(m, "Renderer")
      .def(py::init([](std::shared_ptr<PyScene> s) {
             auto r = std::make_unique<PyRenderer>();
             r->scene = std::move(s);
             r->renderer = std::make_unique<Renderer>(*r->scene->scene);
             return r;
           }),
           py::arg("scene"))
      .def(
          "render",
          [](PyRenderer& r, int passSamples, const std::optional<py::function>& progress, double interval,
             float noiseThreshold, double timeLimit) {
            if (passSamples < 1) throw py::value_error("pass_samples must be >= 1");
            if (!(interval > 0)) throw py::value_error("interval must be > 0");
            if (!(noiseThreshold >= 0)) throw py::value_error("noise_threshold must be >= 0");
            if (!(timeLimit >= 0)) throw py::value_error("time_limit must be >= 0");
            // The render runs on a worker thread; this (the calling, usually main) thread
            // waits with the GIL released, and every `interval` seconds takes it to call
            // progress and to let Python handle signals (Ctrl-C), which only the main
            // thread can. Either raising cancels the render; the exception propagates.
            Renderer& renderer = *r.renderer;
            const long target = r.scene->desc.settings.spp;
            std::atomic<bool> cancel{false};
            std::mutex mu;
            std::condition_variable cv;
            bool finished = false, completed = false;
            std::exception_ptr failure;
            const auto t0 = std::chrono::steady_clock::now();
            auto seconds = [&] { return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(); };
            std::optional<py::error_already_set> pending;
            auto poll = [&](double done) {
              try {
                if (PyErr_CheckSignals() != 0) throw py::error_already_set();
                if (progress) (*progress)(done, target, seconds());
              } catch (py::error_already_set& e) {
                if (!pending) pending.emplace(std::move(e));
                cancel = true;
              }
            };
            // Adaptive sampling (render.h): each pixel stops at the noise threshold, and the
            // render once every pixel has. The time limit stops it once the first pass is
            // complete, so that every pixel has samples.
            renderer.setNoiseThreshold(noiseThreshold);
            std::atomic<int> stop{0};  // 2 time limit
            auto stopAt = [&](int why) {
              int none = 0;
              if (stop.compare_exchange_strong(none, why)) cancel = true;
            };
            auto afterPass = [&](const RenderProgress& p) {
              if (timeLimit > 0 && p.samplesDone > 0 && seconds() >= timeLimit) stopAt(2);
            };
            std::thread worker([&] {
              bool ok = false;
              std::exception_ptr err;
              try {
                ok = renderer.render(passSamples, afterPass, &cancel);
              } catch (...) {
                err = std::current_exception();
              }
              std::lock_guard<std::mutex> lock(mu);
              finished = true;
              completed = ok;
              failure = err;
              cv.notify_all();
            });
            for (;;) {
              bool done;
              {
                py::gil_scoped_release release;
                std::unique_lock<std::mutex> lock(mu);
                done = cv.wait_for(lock, std::chrono::duration<double>(interval), [&] { return finished; });
              }
              if (done) break;
              if (!pending) poll(renderer.progressSamples());
              if (timeLimit > 0 && seconds() >= timeLimit && renderer.samplesPerPixel() > 0) stopAt(2);
            }
            {
              py::gil_scoped_release release;
              worker.join();
            }
            if (failure) std::rethrow_exception(failure);
            if (pending) throw std::move(*pending);
            if (stop == 0 && completed && renderer.converged() && renderer.samplesPerPixel() < target) stop = 1;
            r.stoppedBy = stop == 1 ? "noise threshold" : stop == 2 ? "time limit" : "samples";
            completed = completed || stop != 0;
            if (completed) {
              poll(double(renderer.samplesPerPixel()));  // the final 100%
              if (pending) throw std::move(*pending);
            }
            return completed;
          },
          py::arg("pass_samples") = 1, py::arg("progress") = py::none(), py::arg("interval") = 0.25,
          py::arg("noise_threshold") = 0.0f, py::arg("time_limit") = 0.0,
          "Renders settings.spp samples per pixel (passes of pass_samples, rounded up to whole bundles) "
          "on a worker thread, the GIL released; calls progress(samples_done: float, target, seconds) "
          "every `interval` seconds and at the end. With noise_threshold > 0 each pixel stops once "
          "below it (adaptive sampling, core/render.h) and the render once all have; time_limit stops "
          "it after that many seconds (once the first pass is done); stopped_by says which. Returns "
          "False if cancelled.")
      .def_property_readonly(
          "sample_counts",
          [](const PyRenderer& r) {
            const SampleCounts c = r.renderer->sampleCounts();
            py::dict d;
            d["mean"] = c.mean;
            d["min"] = c.min;
            d["max"] = c.max;
            return d;
          },
          "samples per pixel the film holds: mean, min and max (they differ with a noise threshold)")
      .def("sample_count_map",
           [](const PyRenderer& r) {
             const Film& f = r.renderer->film();
             py::array_t<long> a({py::ssize_t(f.height()), py::ssize_t(f.width())});
             auto v = a.mutable_unchecked<2>();
             for (int y = 0; y < f.height(); ++y)
               for (int x = 0; x < f.width(); ++x) v(y, x) = f.samples(x, y);
             return a;
           },
           "each pixel's sample count, (height, width), top row first")
      .def_property_readonly("min_adaptive_samples", [](const PyRenderer& r) { return r.renderer->minAdaptiveSamples(); },
                             "the samples a pixel takes before the noise threshold may stop it")
      .def_property_readonly("stopped_by", [](const PyRenderer& r) { return r.stoppedBy; },
                             "'samples', 'noise threshold' or 'time limit': what ended the last render")
      .def_property_readonly("samples_per_pixel", [](const PyRenderer& r) { return r.renderer->samplesPerPixel(); })
      .def_property_readonly("bundle_size", [](const PyRenderer& r) { return r.renderer->bundleSize(); })
      .def_property_readonly("shortcut_fraction", [](const PyRenderer& r) { return r.renderer->shortcutFraction(); },
                             "fraction of the paths that entered a medium directly by level of detail")
      .def_property_readonly("lost_paths", [](const PyRenderer& r) { return r.renderer->lostPaths(); },
                             "paths ended by a numerical failure (a leak through a medium's boundary): 0 unless "
                             "something is wrong")
      .def_property_readonly("paths", [](const PyRenderer& r) { return r.renderer->paths(); },
                             "camera paths traced so far")
      .def_property_readonly("diffusion_fraction", [](const PyRenderer& r) { return r.renderer->diffusionFraction(); },
                             "fraction of the paths that went on by the diffusion approximation (DA)")
      .def_property_readonly(
          "roulette",
          [](const PyRenderer& r) {
            const RouletteTuning& t = r.renderer->roulette();
            py::dict d;
            d["pa"] = t.pa;
            d["pixels"] = t.pixels;
            d["VL"] = t.VL;
            d["VH"] = t.VH;
            d["tL"] = t.tL;
            d["tH"] = t.tH;
            return d;
          },
          "P_a used (after the first pass) and, when tuned, the pre-render's numbers")
      .def("image", [](const PyRenderer& r) { return r.renderer->image(); });

  m.def("denoiser_available", &denoiserAvailable,
        "whether core was built with Intel Open Image Denoise (and its CPU device works here)");
  m.def("denoiser_unavailable_reason", &denoiserUnavailableReason, "why not, in one line ('' when available)");
  m.def(
      "denoise",
      [](py::array_t<float, py::array::c_style | py::array::forcecast> color,
         py::array_t<float, py::array::c_style | py::array::forcecast> albedo,
         py::array_t<float, py::array::c_style | py::array::forcecast> normal) {
        const std::pair<py::array_t<float, py::array::c_style | py::array::forcecast>*, const char*> in[] = {
            {&color, "color"}, {&albedo, "albedo"}, {&normal, "normal"}};
        for (auto const& [a, name] : in)
          if (a->ndim() != 3 || a->shape(2) != 3 || a->shape(0) != color.shape(0) || a->shape(1) != color.shape(1))
            throw InputError("denoise", name, "expected a (height, width, 3) array of the color's size");
        const int h = int(color.shape(0)), w = int(color.shape(1));
        py::array_t<float> out({py::ssize_t(h), py::ssize_t(w), py::ssize_t(3)});
        float* o = out.mutable_data();
        const float *c = color.data(), *a = albedo.data(), *n = normal.data();
        {
          py::gil_scoped_release release;
          denoise(c, a, n, w, h, o, nullptr);
        }
        return out;
      },
      py::arg("color"), py::arg("albedo"), py::arg("normal"),
      "core/denoise.h: linear HDR color (height, width, 3) denoised by Intel Open Image Denoise, guided by "
      "the albedo and normal AOVs (same shape); RuntimeError when denoiser_available() is False");
  m.def(
      "film_aovs",
      [](bool cryptomatte) {
        py::list out;
        for (const FilmAov& a : filmAovs(cryptomatte))
          out.append(py::make_tuple(a.name, a.channels, a.value == AovValue::Int ? "int" : "float"));
        return out;
      },
      py::arg("cryptomatte") = false, "every AOV of a render's image: [(name, channels, 'float' or 'int')]");
  m.def("write_exr", &writeExr, py::arg("path"), py::arg("image"), py::call_guard<py::gil_scoped_release>());
  m.def("write_png", &writePngSrgb, py::arg("path"), py::arg("image"), py::arg("exposure") = 0.0f,
        py::call_guard<py::gil_scoped_release>());
  m.def("write_image", &writeImage, py::arg("path"), py::arg("image"), py::call_guard<py::gil_scoped_release>());
  m.def("claim_output", &claimOutput, py::arg("path"),
        "Records what the output file is now: a later write_* returns True when another process has written it since");
  m.def("read_tile_exr", &readTileExr, py::arg("path"), py::call_guard<py::gil_scoped_release>(),
        "read_exr for a tile to merge: only an EXR that write_exr wrote, else InputError naming the file");
  m.def("read_exr", &readExr, py::arg("path"), py::call_guard<py::gil_scoped_release>(),
        "An EXR written by write_exr (every channel, its place in the full image)");
  m.def("merge_tiles", &mergeTiles, py::arg("tiles"), py::call_guard<py::gil_scoped_release>(),
        "The rectangle of an image tiled by crops of it (the full image when they cover it), bit for bit; "
        "InputError on gaps, overlaps, mismatches");
  m.def(
      "read_image_rgb", [](const std::string& path) { return readImageRGB(path); }, py::arg("path"),
      py::call_guard<py::gil_scoped_release>());

  // ---- coarse density ------------------------------------------------------------------
  m.def(
      "write_density_vdb",
      [](const std::string& path, const TriangleMesh& worldBoundary, float sigmaT, float voxelSize,
         const std::string& object, const std::map<std::string, float>& floatMeta,
         const std::map<std::string, Vec3>& vec3Meta, const std::map<std::string, std::string>& stringMeta) {
        DensityExportOptions o;
        o.voxelSize = voxelSize;
        o.floatMetadata = floatMeta;
        o.vec3Metadata = vec3Meta;
        o.stringMetadata = stringMeta;
        DensityExportResult r;
        {
          py::gil_scoped_release release;
          r = writeDensityVdb(path, worldBoundary, sigmaT, o, object);
        }
        py::dict d;
        d["voxel_size"] = r.voxelSize;
        d["active_voxels"] = r.activeVoxels;
        d["replaced_other"] = r.replacedOther;
        d["bounds"] = boundsDict(r.worldBounds);
        return d;
      },
      py::arg("path"), py::arg("world_boundary"), py::arg("sigma_t"), py::arg("voxel_size") = 0.0f,
      py::arg("object") = "", py::arg("float_metadata") = std::map<std::string, float>(),
      py::arg("vec3_metadata") = std::map<std::string, Vec3>(),
      py::arg("string_metadata") = std::map<std::string, std::string>(),
      "Float grid 'density': sigma_t at voxel centres inside the closed world-space boundary, 0 outside.");
  m.def("read_vdb_grids", [](const std::string& path) {
    py::list out;
    for (const VdbGridInfo& g : readVdbGrids(path)) {
      py::dict d;
      d["name"] = g.name;
      d["value_type"] = g.valueType;
      d["grid_class"] = g.gridClass;
      d["voxel_size"] = g.voxelSize;
      d["active_voxels"] = g.activeVoxels;
      d["metadata"] = g.metadata;
      out.append(d);
    }
    return out;
  }, py::arg("path"));
  m.def(
      "sample_vdb_grid",
      [](const std::string& path, const std::string& grid, const FloatArray& points) {
        std::vector<float> v = sampleVdbGrid(path, grid, toPoints(points, "points"));
        py::array_t<float> a(py::ssize_t(v.size()));
        std::copy(v.begin(), v.end(), a.mutable_data());
        return a;
      },
      py::arg("path"), py::arg("grid"), py::arg("points"), "World-space values of a float grid (nearest voxel).");

  // ---- teleportation transport -------------------------------------------------------------
  scene.def(
      "media",
      [](const PyScene& s) {
        // The renderer's own media when it built them; else the same derivation
        // (Scene::build's): each normalised prototype with its scene material through
        // estimateGrainTransport (cached on disk), combined by deriveMedium.
        std::vector<MediumParams> media;
        {
          py::gil_scoped_release release;
          const Scene& sc = *s.scene;
          for (size_t i = 0; i < sc.aggregates().size(); ++i) {
            if (sc.hasMedia()) {
              media.push_back(sc.mediumParams(int(i)));
              continue;
            }
            const Aggregate& a = *sc.aggregates()[i];
            std::vector<GrainTransport> gts;
            for (const GrainPrototype& p : a.prototypes()) gts.push_back(estimateGrainTransport(p.mesh, sc.material(p.material)));
            const AggregateDesc& ad = s.desc.aggregates[i];
            media.push_back(deriveMedium(gts, ad.weights, ad.grainRadius, ad.packingRate));
          }
        }
        py::list out;
        for (const MediumParams& mp : media) out.append(mediumDict(mp));
        return out;
      },
      "TT and RTE parameters of every aggregate (world space), as dicts; the GIL is released.");

  // ---- explicit grains' packing rate and the heterogeneous medium ---------------------------
  m.def(
      "instanced_grains_desc",
      [](const std::string& name, const std::vector<TriangleMesh>& prototypes, const FloatArray& positions,
         const FloatArray& scales, const IntArray& protoIndices, const FloatArray& orientations, const Transform& xf) {
        InstancedGrainsDesc d;
        d.name = name;
        d.xf = xf;
        for (size_t k = 0; k < prototypes.size(); ++k) {
          GrainPrototypeDesc p;
          p.name = str(name, "/Prototype", k);
          p.mesh = prototypes[k];
          d.prototypes.push_back(std::move(p));
        }
        d.positions = toPoints(positions, "positions");
        if (scales.ndim() != 1) throw py::value_error("scales must be a 1-D array");
        d.scales.assign(scales.data(), scales.data() + scales.size());
        for (int64_t i : toInts(protoIndices, "proto_indices")) d.protoIndices.push_back(int32_t(i));
        if (orientations.size() > 0) {
          if (orientations.ndim() != 2 || orientations.shape(1) != 4)
            throw py::value_error("orientations must be an array of shape (N, 4) of (w, x, y, z)");
          auto r = orientations.unchecked<2>();
          for (py::ssize_t i = 0; i < orientations.shape(0); ++i) d.orientations.push_back({r(i, 0), r(i, 1), r(i, 2), r(i, 3)});
        }
        validateInstancedGrains(d);
        return d;
      },
      py::arg("name"), py::arg("prototypes"), py::arg("positions"), py::arg("scales"), py::arg("proto_indices"),
      py::arg("orientations") = FloatArray(), py::arg("xf") = Transform(),
      "An InstancedGrainsDesc from arrays (synthetic grains for tests and benchmarks); prototype k is named "
      "<name>/Prototype<k>. InputError as validateInstancedGrains.");
  py::class_<GrainDensity>(m, "GrainDensity")
      .def_readonly("kernel_width", &GrainDensity::kernelWidth)
      .def_property_readonly("voxel_size", [](const GrainDensity& g) { return g.packing.voxelSize; })
      .def_readonly("prototype_names", &GrainDensity::prototypeNames)
      .def("packing_rate",
           [](const GrainDensity& g, const FloatArray& points) {
             std::vector<Vec3> p = toPoints(points, "points");
             py::array_t<float> a(py::ssize_t(p.size()));
             float* out = a.mutable_data();
             for (size_t i = 0; i < p.size(); ++i) out[i] = g.packingRate(p[i]);
             return a;
           },
           py::arg("points"), "f at world points (trilinear)")
      .def("number_fraction",
           [](const GrainDensity& g, int k, const FloatArray& points) {
             std::vector<Vec3> p = toPoints(points, "points");
             py::array_t<float> a(py::ssize_t(p.size()));
             float* out = a.mutable_data();
             for (size_t i = 0; i < p.size(); ++i) out[i] = g.numberFraction(k, p[i]);
             return a;
           },
           py::arg("prototype"), py::arg("points"), "prototype k's number fraction at the nearest voxel")
      .def_property_readonly("stats", [](const GrainDensity& g) {
        const GrainDensityStats& s = g.stats;
        py::dict r;
        r["grains"] = s.grains;
        r["leaves"] = s.leaves;
        r["active_voxels"] = s.activeVoxels;
        r["total_volume"] = s.totalVolume;
        r["mean_radius"] = s.meanRadius;
        r["bytes"] = s.bytes;
        r["build_bytes"] = s.buildBytes;
        r["seconds"] = s.seconds;
        r["kernel_width"] = g.kernelWidth;
        r["voxel_size"] = g.packing.voxelSize;
        return r;
      });
  m.def(
      "build_grain_density",
      [](const InstancedGrainsDesc& desc, float kernelWidth, float kernelRadii, float voxelSize, bool fractions) {
        GrainDensityOptions o;
        o.kernelWidth = kernelWidth;
        o.kernelRadii = kernelRadii;
        o.voxelSize = voxelSize;
        o.fractions = fractions;
        return buildGrainDensity(desc, o);
      },
      py::arg("desc"), py::arg("kernel_width") = 0.0f, py::arg("kernel_radii") = 3.0f, py::arg("voxel_size") = 0.0f,
      py::arg("fractions") = true, py::call_guard<py::gil_scoped_release>(),
      "The grains' packing rate on a sparse voxel grid (core/grain_density.h); the GIL is released.");
  m.def(
      "write_grain_density_vdb",
      [](const std::string& path, const GrainDensity& density, const std::string& object,
         const std::map<std::string, float>& floatMeta, const std::map<std::string, Vec3>& vec3Meta,
         const std::map<std::string, std::string>& stringMeta) {
        DensityExportOptions o;
        o.floatMetadata = floatMeta;
        o.vec3Metadata = vec3Meta;
        o.stringMetadata = stringMeta;
        DensityExportResult r;
        {
          py::gil_scoped_release release;
          r = writeGrainDensityVdb(path, density, o, object);
        }
        py::dict d;
        d["voxel_size"] = r.voxelSize;
        d["active_voxels"] = r.activeVoxels;
        d["replaced_other"] = r.replacedOther;
        d["bounds"] = boundsDict(r.worldBounds);
        return d;
      },
      py::arg("path"), py::arg("density"), py::arg("object") = "",
      py::arg("float_metadata") = std::map<std::string, float>(),
      py::arg("vec3_metadata") = std::map<std::string, Vec3>(),
      py::arg("string_metadata") = std::map<std::string, std::string>(),
      "Float grid 'density' (the packing rate f) and, for mixtures, 'fraction.<k>' (core/density_export.h).");
  py::class_<HeterogeneousMedium>(m, "HeterogeneousMedium")
      .def(py::init([](const GrainDensity& density, const Vec3& sigmaT, const Vec3& albedo, float packingRate) {
             return HeterogeneousMedium(density.packing, packingRate,
                                        HomogeneousMedium(sigmaT, albedo, PhaseTable::isotropic()), "medium");
           }),
           py::arg("density"), py::arg("sigma_t"), py::arg("albedo"), py::arg("packing_rate"),
           "sigma_t(x) = sigma_t * f(x) / packing_rate (isotropic phase here)")
      .def("sigma_t", &HeterogeneousMedium::sigmaT, py::arg("point"))
      .def("majorant", &HeterogeneousMedium::majorant, py::arg("point"))
      .def_property_readonly("bytes", &HeterogeneousMedium::bytes)
      .def_property_readonly("bounds", [](const HeterogeneousMedium& h) { return boundsDict(h.bounds()); })
      .def(
          "estimate_transmittance",
          [](const HeterogeneousMedium& h, const FloatArray& origins, const FloatArray& directions, float tmax,
             int samples, uint64_t seed, const std::string& method) {
            const std::vector<Vec3> o = toPoints(origins, "origins"), d = toPoints(directions, "directions");
            if (o.size() != d.size()) throw py::value_error("origins and directions differ in length");
            if (samples < 2) throw py::value_error("samples must be >= 2");
            if (method != "ratio" && method != "ratio_roulette" && method != "delta")
              throw py::value_error("method must be ratio, ratio_roulette or delta");
            py::array_t<double> mean({py::ssize_t(o.size()), py::ssize_t(3)}), var({py::ssize_t(o.size()), py::ssize_t(3)});
            double* m = mean.mutable_data();
            double* v = var.mutable_data();
            int64_t lookups = 0;
            double seconds = 0;
            {
              py::gil_scoped_release release;
              const auto start = std::chrono::steady_clock::now();
              for (size_t r = 0; r < o.size(); ++r) {
                Ray ray;
                ray.o = o[r];
                ray.d = d[r];
                Rng rng(seed, r);
                double s[3] = {0, 0, 0}, q[3] = {0, 0, 0};
                for (int k = 0; k < samples; ++k) {
                  const Vec3 T = method == "delta" ? h.transmittanceDelta(ray, tmax, rng, &lookups)
                                                   : h.transmittance(ray, tmax, rng, method == "ratio_roulette", &lookups);
                  for (int c = 0; c < 3; ++c) {
                    s[c] += T[c];
                    q[c] += double(T[c]) * T[c];
                  }
                }
                for (int c = 0; c < 3; ++c) {
                  m[3 * r + size_t(c)] = s[c] / samples;
                  v[3 * r + size_t(c)] = std::max(0.0, (q[c] - s[c] * s[c] / samples) / (samples - 1));
                }
              }
              seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
            }
            py::dict out;
            out["mean"] = mean;
            out["variance"] = var;  // of one sample
            out["lookups"] = lookups;
            out["seconds"] = seconds;
            return out;
          },
          py::arg("origins"), py::arg("directions"), py::arg("tmax"), py::arg("samples"), py::arg("seed") = 0,
          py::arg("method") = "ratio",
          "Per ray, `samples` transmittance estimates to tmax (ratio, ratio_roulette or delta tracking): their mean "
          "and one sample's variance (N, 3), the density lookups and the seconds, single-threaded.");
}
