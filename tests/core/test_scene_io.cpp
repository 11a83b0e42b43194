// test_scene_io.cpp — the JSON scene format: a full scene, and every kind of bad input
// reported as an InputError naming the object and the key.
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <functional>
#include <unistd.h>
#include <nlohmann/json.hpp>

#include "core/error.h"
#include "core/image_io.h"
#include "core/light.h"
#include "core/scene_io.h"
#include "core/shapes.h"

using namespace granular;
using nlohmann::json;

namespace {

const char* kScene = R"({
  // comments are allowed
  "render": {"width": 320, "height": 240, "spp": 4, "seed": 9, "max_depth": 512, "rr_depth": 5, "threads": 2},
  "camera": {"look_at": {"eye": [0, 1, 5], "target": [0, 1, 0], "up": [0, 1, 0]},
             "focal_length": 35, "horizontal_aperture": 36, "vertical_aperture": 27,
             "clipping_range": [0.01, 1000]},
  "materials": {
    "sand": {"type": "dielectric", "ior": 1.5, "absorption": [0.1, 0.2, 0.4]},
    "floor": {"type": "lambert", "albedo": 0.5},
    "lamp": {"albedo": [0, 0, 0], "emission": [2, 2, 1]}
  },
  "meshes": [
    {"name": "floor", "shape": {"box": {"lo": [-5, -0.1, -5], "hi": [5, 0, 5]}}, "material": "floor"},
    {"shape": {"mesh": {"points": [[0,0,0],[1,0,0],[1,1,0],[0,1,0]],
                        "face_vertex_counts": [4], "face_vertex_indices": [0,1,2,3]}},
     "transform": {"translate": [0, 2, 0], "rotate": [90, 0, 1, 0], "scale": 2}, "visible": false}
  ],
  "lights": [
    {"name": "sun", "type": "distant", "direction": [0, -1, -1], "angle": 0.53, "color": [1, 0.9, 0.8],
     "intensity": 3, "exposure": 1},
    {"type": "sphere", "position": [1, 2, 3], "radius": 0.25},
    {"type": "rect", "transform": [1,0,0,0, 0,1,0,4, 0,0,1,0, 0,0,0,1], "width": 2, "height": 0.5, "normalize": true},
    {"type": "dome", "intensity": 0.5}
  ],
  "aggregates": [
    {"name": "castle",
     "boundary": {"lathe": {"profile": [[1, 0], [0.8, 1], [0, 1.5]], "segments": 32}},
     "transform": {"translate": [0, 0, 0]},
     "grain_radius": 0.01, "packing_rate": 0.6, "seed": 1, "tile_spheres": 256,
     "prototypes": [
       {"name": "rock", "shape": {"rock": {"subdivisions": 2, "roughness": 0.2, "seed": 3}}, "material": "sand"},
       {"shape": {"ellipsoid": {"radii": [1, 0.6, 0.4], "subdivisions": 1}}}
     ],
     "weights": [3, 1]}
  ]
})";

json base() { return json::parse(kScene, nullptr, true, /*ignore_comments=*/true); }

// The InputError message a scene produces, or a marker saying what went wrong instead.
std::string errorOf(const std::string& text) {
  try {
    parseSceneJson(text, "scenes/test.json");
  } catch (const InputError& e) {
    return e.what();
  } catch (const std::exception& e) {
    return std::string("WRONG EXCEPTION TYPE: ") + e.what();
  }
  return "NO ERROR";
}
std::string errorOf(const json& j) { return errorOf(j.dump()); }

// The InputError message of loading the scene file at path, or "NO ERROR".
std::string errorLoading(const std::filesystem::path& path) {
  try {
    loadSceneJson(path.string());
  } catch (const InputError& e) {
    return e.what();
  }
  return "NO ERROR";
}

std::string errorAfter(const std::function<void(json&)>& edit) {
  json j = base();
  edit(j);
  return errorOf(j);
}

#define EXPECT_CONTAINS(hay, needle) EXPECT_NE((hay).find(needle), std::string::npos) << "message: " << (hay)

void expectNear(const Vec3& a, const Vec3& b, float eps = 1e-5f) {
  EXPECT_NEAR(a.x, b.x, eps);
  EXPECT_NEAR(a.y, b.y, eps);
  EXPECT_NEAR(a.z, b.z, eps);
}

}  // namespace

TEST(SceneIo, FullSceneParses) {
  SceneDesc d = parseSceneJson(kScene, "scenes/test.json");
  EXPECT_EQ(d.settings.width, 320);
  EXPECT_EQ(d.settings.height, 240);
  EXPECT_EQ(d.settings.spp, 4);
  EXPECT_EQ(d.settings.seed, 9u);
  EXPECT_EQ(d.settings.maxDepth, 512);
  EXPECT_EQ(d.settings.rrDepth, 5);
  EXPECT_EQ(d.settings.threads, 2);

  expectNear(d.camera.cameraToWorld.point({0, 0, 0}), {0, 1, 5});
  expectNear(d.camera.cameraToWorld.vector({0, 0, -1}), {0, 0, -1});
  expectNear(d.camera.cameraToWorld.vector({0, 1, 0}), {0, 1, 0});
  EXPECT_FLOAT_EQ(d.camera.focalLength, 35);
  EXPECT_FLOAT_EQ(d.camera.verticalAperture, 27);
  EXPECT_FLOAT_EQ(d.camera.clipNear, 0.01f);
  EXPECT_FLOAT_EQ(d.camera.clipFar, 1000);

  ASSERT_EQ(d.materials.size(), 3u);
  auto mat = [&](const std::string& n) -> const MaterialDesc& {
    for (auto& m : d.materials)
      if (m.name == n) return m;
    throw std::runtime_error("no material " + n);
  };
  EXPECT_EQ(mat("sand").type, MaterialType::Dielectric);
  EXPECT_FLOAT_EQ(mat("sand").ior, 1.5f);
  EXPECT_EQ(mat("sand").absorption, Vec3(0.1f, 0.2f, 0.4f));
  EXPECT_EQ(mat("floor").type, MaterialType::Lambert);
  EXPECT_EQ(mat("floor").albedo, Vec3(0.5f));
  EXPECT_EQ(mat("lamp").emission, Vec3(2, 2, 1));

  ASSERT_EQ(d.meshes.size(), 2u);
  EXPECT_EQ(d.meshes[0].name, "floor");
  EXPECT_EQ(d.materials[d.meshes[0].material].name, "floor");
  EXPECT_NEAR(d.meshes[0].mesh.signedVolume(), 10.0, 1e-5);
  EXPECT_EQ(d.meshes[1].name, "meshes[1]");
  EXPECT_EQ(d.meshes[1].material, -1);
  EXPECT_FALSE(d.meshes[1].visible);
  EXPECT_EQ(d.meshes[1].mesh.numTriangles(), 2u);
  // T * R * S: x -> (rotate 90 about y) -> -z, scaled by 2, moved up 2.
  expectNear(d.meshes[1].xf.point({1, 0, 0}), {0, 2, -2});

  ASSERT_EQ(d.lights.size(), 4u);
  const LightDesc& sun = d.lights[0];
  EXPECT_EQ(sun.name, "sun");
  EXPECT_EQ(sun.type, LightType::Distant);
  expectNear(sun.xf.vector({0, 0, -1}), normalize(Vec3(0, -1, -1)));
  EXPECT_FLOAT_EQ(sun.angle, 0.53f);
  EXPECT_FLOAT_EQ(sun.intensity, 3);
  EXPECT_FLOAT_EQ(sun.exposure, 1);
  EXPECT_EQ(sun.color, Vec3(1, 0.9f, 0.8f));
  EXPECT_EQ(d.lights[1].type, LightType::Sphere);
  EXPECT_EQ(d.lights[1].name, "lights[1]");
  expectNear(d.lights[1].xf.point({0, 0, 0}), {1, 2, 3});
  EXPECT_FLOAT_EQ(d.lights[1].radius, 0.25f);
  EXPECT_EQ(d.lights[2].type, LightType::Rect);
  expectNear(d.lights[2].xf.point({0, 0, 0}), {0, 4, 0});
  EXPECT_FLOAT_EQ(d.lights[2].width, 2);
  EXPECT_FLOAT_EQ(d.lights[2].height, 0.5f);
  EXPECT_TRUE(d.lights[2].normalize);
  EXPECT_EQ(d.lights[3].type, LightType::Dome);
  EXPECT_TRUE(d.lights[3].textureFile.empty());

  ASSERT_EQ(d.aggregates.size(), 1u);
  const AggregateDesc& a = d.aggregates[0];
  EXPECT_EQ(a.name, "castle");
  EXPECT_GT(validateClosed(a.boundary, "b"), 0);
  EXPECT_FLOAT_EQ(a.grainRadius, 0.01f);
  EXPECT_FLOAT_EQ(a.packingRate, 0.6f);
  EXPECT_EQ(a.seed, 1u);
  EXPECT_EQ(a.tileSpheres, 256);
  ASSERT_EQ(a.prototypes.size(), 2u);
  EXPECT_EQ(a.prototypes[0].name, "castle/rock");
  EXPECT_EQ(d.materials[a.prototypes[0].material].name, "sand");
  EXPECT_EQ(a.prototypes[0].mesh.points, makeRock(2, 0.2f, 3).points);
  EXPECT_EQ(a.prototypes[1].name, "castle.prototypes[1]");
  EXPECT_EQ(a.prototypes[1].material, -1);
  EXPECT_EQ(a.weights, (std::vector<float>{3, 1}));
}

TEST(SceneIo, MinimalSceneUsesDefaults) {
  SceneDesc d = parseSceneJson("{}", "empty.json");
  EXPECT_EQ(d.settings.width, 640);
  EXPECT_TRUE(d.meshes.empty());
  json j = base();
  j["aggregates"][0].erase("weights");
  d = parseSceneJson(j.dump(), "x.json");
  EXPECT_EQ(d.aggregates[0].weights, (std::vector<float>{1, 1}));
}

TEST(SceneIo, PackingRateOutOfRange) {
  std::string e = errorAfter([](json& j) { j["aggregates"][0]["packing_rate"] = 0.9; });
  EXPECT_CONTAINS(e, "castle.packing_rate: 0.9 is outside (0, 0.64]");
  e = errorAfter([](json& j) { j["aggregates"][0]["packing_rate"] = 0; });
  EXPECT_CONTAINS(e, "castle.packing_rate: 0 is outside (0, 0.64]");
  EXPECT_EQ(errorAfter([](json& j) { j["aggregates"][0]["packing_rate"] = 0.64; }), "NO ERROR");
}

TEST(SceneIo, WeightErrors) {
  std::string e = errorAfter([](json& j) { j["aggregates"][0]["weights"] = {0, 0}; });
  EXPECT_CONTAINS(e, "castle.weights");
  EXPECT_CONTAINS(e, "all zero");
  e = errorAfter([](json& j) { j["aggregates"][0]["weights"] = {-1, 1}; });
  EXPECT_CONTAINS(e, "castle.weights");
  EXPECT_CONTAINS(e, "weight 0 = -1");
  e = errorAfter([](json& j) { j["aggregates"][0]["weights"] = {1, 1, 1}; });
  EXPECT_CONTAINS(e, "castle.weights: has 3 entries but there are 2 prototypes");
  e = errorAfter([](json& j) { j["aggregates"][0]["prototypes"] = json::array(); j["aggregates"][0].erase("weights"); });
  EXPECT_CONTAINS(e, "castle.prototypes");
}

TEST(SceneIo, NanPointThroughTheCppApi) {
  SceneDesc d = parseSceneJson(kScene, "x.json");
  EXPECT_NO_THROW(validateSceneDesc(d));
  d.aggregates[0].prototypes[0].mesh.points[3].y = std::nanf("");
  try {
    validateSceneDesc(d);
    FAIL() << "no error";
  } catch (const InputError& e) {
    EXPECT_EQ(e.object(), "castle/rock");
    EXPECT_EQ(e.attribute(), "points");
    EXPECT_CONTAINS(std::string(e.what()), "point 3 is not finite");
  }
  d = parseSceneJson(kScene, "x.json");
  d.materials[0].albedo.x = std::nanf("");
  try {
    validateSceneDesc(d);
    FAIL() << "no error";
  } catch (const InputError& e) {
    EXPECT_EQ(e.attribute(), "albedo");
  }
}

TEST(SceneIo, OpenBoundaryMesh) {
  std::string e = errorAfter([](json& j) {
    // A box missing its last triangle.
    j["aggregates"][0]["boundary"] = {
        {"mesh",
         {{"points", {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {1, 1, 0}, {0, 0, 1}, {1, 0, 1}, {0, 1, 1}, {1, 1, 1}}},
          {"face_vertex_indices", {0, 4, 6, 0, 6, 2, 1, 3, 7, 1, 7, 5, 0, 1, 5, 0, 5, 4,
                                   2, 6, 7, 2, 7, 3, 0, 2, 3, 0, 3, 1, 4, 5, 7}}}}};
  });
  EXPECT_CONTAINS(e, "castle.boundary");
  EXPECT_CONTAINS(e, "open boundary: edge (");
}

TEST(SceneIo, UnknownKeyIsReported) {
  std::string e = errorAfter([](json& j) { j["aggregates"][0]["packing_rat"] = 0.5; });
  EXPECT_CONTAINS(e, "castle.packing_rat: unknown key");
  EXPECT_CONTAINS(e, "packing_rate");  // the allowed keys are listed
  e = errorAfter([](json& j) { j["rendr"] = json::object(); });
  EXPECT_CONTAINS(e, "scene.rendr: unknown key");
  e = errorAfter([](json& j) { j["materials"]["sand"]["albedo"] = 0.5; });  // not a dielectric key
  EXPECT_CONTAINS(e, "sand.albedo: unknown key");
  e = errorAfter([](json& j) { j["aggregates"][0]["boundary"]["lathe"]["segmnts"] = 8; });
  EXPECT_CONTAINS(e, "castle.boundary.lathe.segmnts: unknown key");
}

TEST(SceneIo, WrongTypeIsReported) {
  std::string e = errorAfter([](json& j) { j["aggregates"][0]["grain_radius"] = "big"; });
  EXPECT_CONTAINS(e, "castle.grain_radius: expected a number, got string \"big\"");
  // A long value is shortened with its non-ASCII characters escaped, never cut inside one.
  std::string accented;
  for (int i = 0; i < 30; ++i) accented += "\xc3\xa9";  // "é" 30 times
  e = errorAfter([&](json& j) { j["aggregates"][0]["grain_radius"] = accented; });
  EXPECT_CONTAINS(e, "castle.grain_radius: expected a number, got string \"\\u00e9\\u00e9");
  EXPECT_EQ(e.find('\xc3'), std::string::npos) << e;
  e = errorAfter([](json& j) { j["render"]["spp"] = 1.5; });
  EXPECT_CONTAINS(e, "render.spp: expected an integer");
  e = errorAfter([](json& j) { j["camera"]["look_at"]["eye"] = {1, 2}; });
  EXPECT_CONTAINS(e, "camera.look_at.eye: expected an array of 3 numbers");
  e = errorAfter([](json& j) { j["meshes"] = json::object(); });
  EXPECT_CONTAINS(e, "scene.meshes: expected an array");
  e = errorAfter([](json& j) { j["meshes"][0]["visible"] = 1; });
  EXPECT_CONTAINS(e, "floor.visible: expected true or false");
  e = errorAfter([](json& j) { j["aggregates"][0]["seed"] = -1; });
  EXPECT_CONTAINS(e, "castle.seed: -1 must be >= 0");
  e = errorOf(std::string("[1, 2]"));
  EXPECT_CONTAINS(e, "scenes/test.json: expected an object");
}

TEST(SceneIo, SyntaxError) {
  std::string e = errorOf(std::string("{\n  \"render\": {\"width\": 10,}\n}"));
  EXPECT_CONTAINS(e, "scenes/test.json: JSON parse error at byte ");
  EXPECT_CONTAINS(e, "line 2");
  e = errorOf(std::string("{\"render\": {\"spp\": 1, \"spp\": 2}}"));
  EXPECT_CONTAINS(e, "duplicate key \"spp\" in render");
}

TEST(SceneIo, ReferenceAndRangeErrors) {
  std::string e = errorAfter([](json& j) { j["meshes"][0]["material"] = "flor"; });
  EXPECT_CONTAINS(e, "floor.material: unknown material \"flor\"");
  e = errorAfter([](json& j) { j["aggregates"][0]["prototypes"][0]["material"] = "glass"; });
  EXPECT_CONTAINS(e, "castle/rock.material: unknown material");
  e = errorAfter([](json& j) { j["materials"]["sand"]["ior"] = 5; });
  EXPECT_CONTAINS(e, "sand.ior: 5 is outside [1, 4]");
  EXPECT_EQ(errorAfter([](json& j) { j["materials"]["sand"]["ior"] = 1; }), "NO ERROR");
  e = errorAfter([](json& j) { j["materials"]["sand"]["roughness"] = 1.2; });
  EXPECT_CONTAINS(e, "sand.roughness: 1.2 is outside [0, 1]");
  e = errorAfter([](json& j) { j["materials"]["sand"]["roughness"] = -0.5; });
  EXPECT_CONTAINS(e, "sand.roughness: -0.5 is outside [0, 1]");
  e = errorAfter([](json& j) { j["materials"]["floor"]["roughness"] = 0.5; });  // Lambert has none
  EXPECT_CONTAINS(e, "roughness");
  {
    json j = base();
    j["materials"]["sand"]["roughness"] = 0.4;
    int rough = 0;
    for (const MaterialDesc& m : parseSceneJson(j.dump(), "scenes/test.json").materials)
      if (m.name == "sand") rough += m.roughness == 0.4f;
    EXPECT_EQ(rough, 1);
  }
  e = errorAfter([](json& j) { j["materials"]["floor"]["albedo"] = {0.5, 1.5, 0}; });
  EXPECT_CONTAINS(e, "floor.albedo");
  e = errorAfter([](json& j) { j["render"]["width"] = 0; });
  EXPECT_CONTAINS(e, "render.width: 0 is outside [1, 32768]");
  e = errorAfter([](json& j) { j["render"]["max_depth"] = 0; });
  EXPECT_CONTAINS(e, "render.max_depth");
  e = errorAfter([](json& j) { j["render"]["da_depth_factor"] = 0; });
  EXPECT_CONTAINS(e, "render.da_depth_factor: 0 must be a positive number");
  e = errorAfter([](json& j) { j["render"]["da_min_order"] = -1; });
  EXPECT_CONTAINS(e, "render.da_min_order: -1 must be >= 0");
  EXPECT_EQ(errorAfter([](json& j) { j["render"]["da_depth_factor"] = 2.5; j["render"]["da_min_order"] = 0; }),
            "NO ERROR");
  e = errorAfter([](json& j) { j["camera"]["clipping_range"] = {1, 0.5}; });
  EXPECT_CONTAINS(e, "camera.clipping_range");
  e = errorAfter([](json& j) { j["camera"]["focal_length"] = 0; });
  EXPECT_CONTAINS(e, "camera.focal_length");
  e = errorAfter([](json& j) { j["lights"][1]["radius"] = 0; });
  EXPECT_CONTAINS(e, "lights[1].radius");
  e = errorAfter([](json& j) { j["lights"][0]["angle"] = 180; });
  EXPECT_CONTAINS(e, "sun.angle: 180 is outside [0, 180)");
  e = errorAfter([](json& j) { j["lights"][0]["type"] = "spot"; });
  EXPECT_CONTAINS(e, "sun.type: unknown light type \"spot\"");
  e = errorAfter([](json& j) { j["aggregates"][0]["tile_spheres"] = 4; });
  EXPECT_CONTAINS(e, "castle.tile_spheres: 4 is outside [8, 100000]");
  e = errorAfter([](json& j) { j["aggregates"][0]["grain_radius"] = -0.1; });
  EXPECT_CONTAINS(e, "castle.grain_radius");
  e = errorAfter([](json& j) { j["aggregates"][0]["prototypes"][0]["shape"]["rock"]["roughness"] = 0.7; });
  EXPECT_CONTAINS(e, "castle/rock.shape.rock.roughness: 0.7 is outside [0, 0.5)");
  e = errorAfter([](json& j) { j["aggregates"][0]["boundary"] = {{"sphere", json::object()}}; });
  EXPECT_CONTAINS(e, "castle.boundary: unknown shape \"sphere\"");
  e = errorAfter([](json& j) { j["meshes"][0]["transform"] = {1,0,0,0, 0,1,0,0, 0,0,1,0, 5,0,0,1}; });
  EXPECT_CONTAINS(e, "floor.transform: bottom row");
  e = errorAfter([](json& j) { j["meshes"][0]["transform"] = {{"scale", {1, 0, 1}}}; });
  EXPECT_CONTAINS(e, "floor.transform: is singular");
  e = errorAfter([](json& j) { j["meshes"][1]["name"] = "floor"; });
  EXPECT_CONTAINS(e, "meshes[1].name: \"floor\" is used by another entry");
  e = errorAfter([](json& j) { j["lights"][3]["texture_file"] = "missing_sky.exr"; });
  EXPECT_CONTAINS(e, "lights[3].texture_file");
  EXPECT_CONTAINS(e, "does not exist");
}

TEST(SceneIo, ObjShapesAndFiles) {
  namespace fs = std::filesystem;
  fs::path dir = fs::temp_directory_path() / ("granular_scene_io_" + std::to_string(::getpid()));
  fs::create_directories(dir / "models");
  {
    // Unit cube as quads, with slash forms and negative (relative) indices.
    std::ofstream obj(dir / "models" / "cube.obj");
    obj << "# cube\no cube\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nv 0 0 1\nv 1 0 1\nv 0 1 1\nv 1 1 1\n"
           "vn 0 0 1\nf 1/1/1 5/2/1 7//1 3\nf 2 4 8 6\nf 1 2 6 5\nf 3 7 8 4\nf -8 -6 -5 -7\nf 5 6 8 7\n";
    std::ofstream bad(dir / "models" / "bad.obj");
    bad << "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n";
  }
  json j = base();
  j["aggregates"][0]["boundary"] = {{"obj", "models/cube.obj"}};
  std::ofstream(dir / "scene.json") << j.dump(2);
  SceneDesc d = loadSceneJson((dir / "scene.json").string());
  EXPECT_EQ(d.aggregates[0].boundary.numTriangles(), 12u);
  EXPECT_DOUBLE_EQ(d.aggregates[0].boundary.signedVolume(), 1.0);

  // The error of the scene whose castle's boundary is that OBJ file.
  auto errorWithBoundary = [&](const std::string& obj) {
    j["aggregates"][0]["boundary"] = {{"obj", obj}};
    std::ofstream(dir / "scene.json") << j.dump(2);
    return errorLoading(dir / "scene.json");
  };
  const std::string bad = errorWithBoundary("models/bad.obj");
  EXPECT_CONTAINS(bad, "castle.boundary.obj");
  EXPECT_CONTAINS(bad, "bad.obj:4: vertex index 4 is out of range");
  // A token that is not a number is quoted with its bytes that are not printable ASCII as
  // '?': the Python bindings decode the message as UTF-8, which 0xff is not.
  std::ofstream(dir / "models" / "binary.obj") << "v 0 0 0\nv 1 \xff\xc3\xa9 0\n";
  EXPECT_CONTAINS(errorWithBoundary("models/binary.obj"), "binary.obj:2: \"???\" is not a finite number");
  EXPECT_CONTAINS(errorAfter([](json& jj) { jj["meshes"][0]["shape"] = {{"obj", "nope.obj"}}; }), "cannot open");
  try {
    loadSceneJson((dir / "no_such.json").string());
    ADD_FAILURE() << "no error";
  } catch (const InputError& e) {
    EXPECT_CONTAINS(std::string(e.what()), "cannot open");
  }
  fs::remove_all(dir);
}

TEST(SceneIo, ValuesThatWouldRenderNonFiniteAreInputErrors) {
  // Found by fuzz/fuzz_usd_attributes and checked here through both front ends' gate:
  // each value is finite and in its own range, yet the render would not be.
  EXPECT_NE(errorAfter([](json& j) { j["camera"]["focal_length"] = 1e-37; }).find("camera.focal_length"),
            std::string::npos);
  EXPECT_NE(errorAfter([](json& j) {
              j["lights"][0]["intensity"] = 1e38;
              j["lights"][0]["exposure"] = 100;
            }).find("sun.intensity"),
            std::string::npos);
  // A projective matrix cannot come from JSON (the reader checks the bottom row), but the
  // USD front end hands core any 4x4: validateSceneDesc refuses it.
  SceneDesc d = parseSceneJson(kScene, "scenes/test.json");
  d.camera.cameraToWorld.m[3][3] = 0.5;
  try {
    validateSceneDesc(d);
    ADD_FAILURE() << "a projective camera matrix was accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("camera.transform: is not affine"), std::string::npos) << e.what();
  }
  d = parseSceneJson(kScene, "scenes/test.json");
  d.aggregates[0].xf.m[3][1] = 1e-3;
  EXPECT_THROW(validateSceneDesc(d), InputError);
}

TEST(SceneIo, WorldCoordinatesStayWithin1e15) {
  // A transform that scales a boundary by 1e38 is finite and invertible, but its world
  // points overflow float (the aggregate's grid became NaN: found by the USD fuzzer).
  EXPECT_NE(errorAfter([](json& j) { j["aggregates"][0]["transform"] = {{"scale", 1e38}}; }).find("transform"),
            std::string::npos);
  EXPECT_NE(errorAfter([](json& j) { j["meshes"][0]["transform"] = {{"translate", {0, 2e15, 0}}}; })
                .find("floor.transform"),
            std::string::npos);
  EXPECT_NE(errorAfter([](json& j) { j["lights"][1]["radius"] = 1e20; }).find("radius"), std::string::npos);
  EXPECT_NE(errorAfter([](json& j) { j["camera"]["look_at"]["eye"] = {0, 1, 1e16}; }).find("camera.transform"),
            std::string::npos);
  // 1e6-unit scenes (bench/stress.py) are well inside.
  EXPECT_EQ(errorAfter([](json& j) { j["aggregates"][0]["transform"] = {{"scale", 1e6}}; }), "NO ERROR");
}

TEST(SceneIo, NumberBeyondDoubleIsAnInputError) {
  // nlohmann reports 1e400 as out_of_range while reading the value, not as a parse error;
  // it escaped as a nlohmann exception (exit 1) until the JSON fuzzer found it.
  std::string e = errorOf(std::string(R"({"render": {"width": 1e400}})"));
  EXPECT_NE(e.find("render.width: number overflow"), std::string::npos) << e;
  e = errorOf(std::string(R"({"aggregates": [{"grain_radius": -1e999}]})"));
  EXPECT_NE(e.find("aggregates.grain_radius"), std::string::npos) << e;
  e = errorOf(std::string("[1e999]"));
  EXPECT_NE(e.find("scene: number overflow"), std::string::npos) << e;
}

TEST(SceneIo, NormalisedLightsMustKeepAFiniteRadiance) {
  // normalize divides by the area: a sphere of radius 6e-39 has an area that underflows
  // to 0, and the radiance became +inf (NaN samples; found by the USD fuzzer).
  std::string e = errorAfter([](json& j) {
    j["lights"][1]["radius"] = 6e-39;
    j["lights"][1]["normalize"] = true;
  });
  EXPECT_NE(e.find("intensity"), std::string::npos) << e;
  EXPECT_NE(e.find("/ area"), std::string::npos) << e;
  // The same light without normalize is fine (it just adds almost nothing).
  EXPECT_EQ(errorAfter([](json& j) { j["lights"][1]["radius"] = 6e-39; }), "NO ERROR");
  // A radius <= 0 is still reported as such, not as an infinite radiance.
  e = errorAfter([](json& j) {
    j["lights"][1]["radius"] = 0;
    j["lights"][1]["normalize"] = true;
  });
  EXPECT_NE(e.find("radius"), std::string::npos) << e;
}

TEST(SceneIo, TexturesAndTextureCoordinates) {
  namespace fs = std::filesystem;
  fs::path dir = fs::temp_directory_path() / ("granular_scene_io_tex_" + std::to_string(::getpid()));
  fs::create_directories(dir / "maps");
  Image img(2, 1, {"R", "G", "B"});
  writeExr((dir / "maps" / "albedo.exr").string(), img);
  json j = base();
  j["materials"]["floor"] = json::parse(R"({"type": "lambert", "opacity": 0.5, "opacity_threshold": 0.25,
      "albedo_texture": {"file": "maps/albedo.exr", "wrap_s": "repeat", "wrap_t": "clamp",
                         "scale": [2, 2, 2, 1], "bias": [0, 0.1, 0, 0], "color_space": "raw"},
      "opacity_texture": {"file": "maps/albedo.exr", "channel": "a"}})");
  // A quad with per-face-vertex st: the fan (0 1 2), (0 2 3) takes the corners' values.
  j["meshes"][1]["shape"]["mesh"]["st"] = json::parse("[[0, 0], [1, 0], [1, 1], [0, 1]]");
  j["meshes"][1]["shape"]["mesh"]["st_interpolation"] = "faceVarying";
  j["meshes"][1]["material"] = "floor";
  std::ofstream(dir / "scene.json") << j.dump(2);
  SceneDesc d = loadSceneJson((dir / "scene.json").string());
  const MaterialDesc& m = *std::find_if(d.materials.begin(), d.materials.end(),
                                        [](const MaterialDesc& x) { return x.name == "floor"; });
  EXPECT_EQ(m.albedoTexture.file, (dir / "maps" / "albedo.exr").string());
  EXPECT_EQ(m.albedoTexture.source, "floor.albedo_texture");
  EXPECT_EQ(m.albedoTexture.wrapS, TextureWrap::Repeat);
  EXPECT_EQ(m.albedoTexture.wrapT, TextureWrap::Clamp);
  EXPECT_EQ(m.albedoTexture.colorSpace, TextureColorSpace::Raw);
  EXPECT_EQ(m.albedoTexture.channel, -1);
  EXPECT_FLOAT_EQ(m.albedoTexture.scale[0], 2.0f);
  EXPECT_FLOAT_EQ(m.albedoTexture.bias[1], 0.1f);
  EXPECT_EQ(m.opacityTexture.channel, 3);
  EXPECT_FLOAT_EQ(m.opacity, 0.5f);
  EXPECT_FLOAT_EQ(m.opacityThreshold, 0.25f);
  const std::vector<float> expected = {0, 0, 1, 0, 1, 1, 0, 0, 1, 1, 0, 1};
  EXPECT_EQ(d.meshes[1].mesh.uvs, expected);

  auto errorIn = [&](const std::function<void(json&)>& edit) {
    json k = j;
    edit(k);
    std::ofstream(dir / "scene.json") << k.dump(2);
    return errorLoading(dir / "scene.json");
  };
  EXPECT_CONTAINS(errorIn([](json& k) { k["materials"]["floor"]["albedo_texture"]["file"] = "maps/nope.png"; }),
                  "floor.albedo_texture.file");
  EXPECT_CONTAINS(errorIn([](json& k) { k["materials"]["floor"]["albedo_texture"]["wrap_s"] = "tile"; }),
                  "floor.albedo_texture.wrap_s: \"tile\" is not black, clamp, repeat, mirror or useMetadata");
  EXPECT_CONTAINS(errorIn([](json& k) { k["materials"]["floor"]["opacity_texture"]["channel"] = "rgb"; }),
                  "floor.opacity_texture.channel: a float input takes r, g, b or a, not rgb");
  EXPECT_CONTAINS(errorIn([](json& k) { k["meshes"][1]["shape"]["mesh"]["st"] = json::parse("[[0, 0]]"); }),
                  "1 values for 4 face vertices");
  EXPECT_CONTAINS(errorIn([](json& k) { k["materials"]["floor"]["opacity"] = 2; }), "floor.opacity: 2 is outside [0, 1]");
  fs::remove_all(dir);
}

TEST(SceneIo, GrainSizesAndSpread) {
  json j = base();
  j["aggregates"][0]["sizes"] = json::parse("[1.0, 0.5]");
  j["aggregates"][0]["size_spread"] = 0.2;
  SceneDesc d = parseSceneJson(j.dump(), "scenes/test.json");
  EXPECT_EQ(d.aggregates[0].sizes, (std::vector<float>{1.0f, 0.5f}));
  EXPECT_FLOAT_EQ(d.aggregates[0].sizeSpread, 0.2f);
  EXPECT_CONTAINS(errorAfter([](json& k) { k["aggregates"][0]["sizes"] = json::parse("[1.0]"); }),
                  "castle.sizes: has 1 entries but there are 2 prototypes");
  EXPECT_CONTAINS(errorAfter([](json& k) { k["aggregates"][0]["sizes"] = json::parse("[1.0, 0.0]"); }),
                  "castle.sizes: size 1 = 0 is outside [0.1, 10]");
  EXPECT_CONTAINS(errorAfter([](json& k) { k["aggregates"][0]["sizes"] = json::parse("[8.0, 0.5]"); }),
                  "more than 10 times the smallest");
  EXPECT_CONTAINS(errorAfter([](json& k) { k["aggregates"][0]["size_spread"] = 0.7; }),
                  "castle.size_spread: 0.7 is outside [0, 0.5]");
}

// ---- motion blur and simulated grains ----------------------------------------------------

namespace {

// A scene with the camera's shutter open, a box that moves over it and an instancer's grains
// with every per-grain array: what a simulation hands a pipeline without USD.
json movingScene() {
  json j = base();
  j["camera"]["shutter_open"] = -0.01;
  j["camera"]["shutter_close"] = 0.02;
  j["meshes"][0]["shutter_transforms"] = {{{"translate", {-1, 0, 0}}}, {{"translate", {1, 0.5, 0}}}};
  j["instanced_grains"] = json::parse(R"([
    {"name": "pile", "transform": {"translate": [0, 1, 0]},
     "prototypes": [{"name": "rock", "shape": {"icosphere": {"subdivisions": 1}}, "material": "sand"},
                    {"shape": {"box": {}}}],
     "positions": [[0, 0, 0], [0.5, 0, 0], [0, 0.5, 0]],
     "orientations": [[1, 0, 0, 0], [0, 1, 0, 0], [0.6, 0, 0.8, 0]],
     "scales": [0.1, 0.2, 0.1],
     "proto_indices": [0, 1, 0],
     "velocities": [[1, 0, 0], [0, 2, 0], [0, 0, 3]],
     "angular_velocities": [[0, 90, 0], [0, 0, 0], [360, 0, 0]]}
  ])");
  return j;
}

}  // namespace

TEST(SceneIo, ShutterMovingMeshesAndInstancedGrainsReadAsTheDescription) {
  const SceneDesc d = parseSceneJson(movingScene().dump(), "scenes/test.json");
  EXPECT_FLOAT_EQ(d.camera.shutterOpen, -0.01f);
  EXPECT_FLOAT_EQ(d.camera.shutterClose, 0.02f);
  ASSERT_TRUE(d.meshes[0].shutterXf.has_value());
  EXPECT_TRUE(sameTransform(d.meshes[0].shutterXf->first, Transform::translate(Vec3(-1, 0, 0))));
  EXPECT_TRUE(sameTransform(d.meshes[0].shutterXf->second, Transform::translate(Vec3(1, 0.5f, 0))));
  EXPECT_FALSE(d.meshes[1].shutterXf.has_value());

  // The description a USD front end would fill for the same instancer, field by field.
  InstancedGrainsDesc want;
  want.name = "pile";
  want.xf = Transform::translate(Vec3(0, 1, 0));
  want.prototypes.resize(2);
  want.prototypes[0].name = "pile/rock";
  want.prototypes[0].mesh = makeIcosphere(1);
  want.prototypes[1].name = "pile.prototypes[1]";
  want.prototypes[1].mesh = makeBox(Vec3(-1.0f), Vec3(1.0f));
  want.positions = {{0, 0, 0}, {0.5f, 0, 0}, {0, 0.5f, 0}};
  want.orientations = {{1, 0, 0, 0}, {0, 1, 0, 0}, {0.6f, 0, 0.8f, 0}};
  want.scales = {0.1f, 0.2f, 0.1f};
  want.protoIndices = {0, 1, 0};
  want.velocities = {{1, 0, 0}, {0, 2, 0}, {0, 0, 3}};
  want.angularVelocities = {{0, 90, 0}, {0, 0, 0}, {360, 0, 0}};
  ASSERT_EQ(d.instancedGrains.size(), 1u);
  const InstancedGrainsDesc& g = d.instancedGrains[0];
  want.prototypes[0].material = g.prototypes[0].material;  // by index: checked by name below
  want.prototypes[1].material = -1;                        // clear glass, as an aggregate's
  EXPECT_EQ(d.materials[size_t(g.prototypes[0].material)].name, "sand");
  EXPECT_EQ(g.prototypes[0].name, want.prototypes[0].name);
  EXPECT_EQ(g.prototypes[1].name, want.prototypes[1].name);
  EXPECT_TRUE(sameInstancedGrains(g, want));

  // Optional arrays may be left out (identity, scale 1, still), as in USD.
  json j = movingScene();
  for (const char* k : {"orientations", "scales", "velocities", "angular_velocities"}) j["instanced_grains"][0].erase(k);
  const SceneDesc still = parseSceneJson(j.dump(), "scenes/test.json");
  EXPECT_TRUE(still.instancedGrains[0].orientations.empty() && still.instancedGrains[0].scales.empty() &&
              still.instancedGrains[0].velocities.empty() && still.instancedGrains[0].angularVelocities.empty());
}

TEST(SceneIo, MotionBlurOffRendersTheInstant) {
  json j = movingScene();
  j["render"]["motion_blur"] = false;
  const SceneDesc d = parseSceneJson(j.dump(), "scenes/test.json");
  EXPECT_EQ(d.camera.shutterOpen, 0.0f);
  EXPECT_EQ(d.camera.shutterClose, 0.0f);
  EXPECT_EQ(motionSpan(d.camera), 0.0f);
  for (const MeshDesc& m : d.meshes) EXPECT_FALSE(m.shutterXf.has_value()) << m.name;
  // The grains keep their velocities: with the shutter closed they are placed at the frame.
  EXPECT_EQ(d.instancedGrains[0].velocities.size(), 3u);
}

TEST(SceneIo, BadMotionBlurAndInstancedGrainsNameTheObjectAndKey) {
  auto errorIn = [](const std::function<void(json&)>& edit) {
    json j = movingScene();
    edit(j);
    return errorOf(j);
  };
  auto grains = [](json& j) -> json& { return j["instanced_grains"][0]; };
  EXPECT_CONTAINS(errorIn([](json& j) { j["camera"]["shutter_close"] = -0.5; }),
                  "camera.shutter_close: -0.5 is before shutter_open -0.01");
  EXPECT_CONTAINS(errorIn([](json& j) { j["camera"]["shutter_close"] = 7200; }), "camera.shutter_open: [-0.01, 7200] s is beyond an hour");
  EXPECT_CONTAINS(errorIn([](json& j) { j["camera"]["shutter_open"] = "now"; }),
                  "camera.shutter_open: expected a number");
  EXPECT_CONTAINS(errorIn([](json& j) { j["render"]["motion_blur"] = 0; }), "render.motion_blur: expected true or false");
  EXPECT_CONTAINS(errorIn([](json& j) { j["meshes"][0]["shutter_transforms"] = {{{"translate", {1, 0, 0}}}}; }),
                  "floor.shutter_transforms: expected [transform at open, transform at close]");
  EXPECT_CONTAINS(errorIn([](json& j) { j["meshes"][0]["shutter_transforms"][1] = {{"scale", 0}}; }),
                  "floor.shutter_transforms: is singular");
  EXPECT_CONTAINS(errorIn([](json& j) { j["meshes"][0]["shutter_transforms"][0] = {{"translate", {1e30, 0, 0}}}; }),
                  "floor.shutter_transforms: ");
  EXPECT_CONTAINS(errorIn([&](json& j) { grains(j)["proto_indices"] = {0, 2, 0}; }),
                  "pile.proto_indices: instance 1 has 2, not the index of one of its 2 prototypes");
  EXPECT_CONTAINS(errorIn([&](json& j) { grains(j)["positions"].erase(2); }),
                  "pile.positions: has 2 values but protoIndices has 3");
  EXPECT_CONTAINS(errorIn([&](json& j) { grains(j)["orientations"][2] = {1, 1, 0, 0}; }),
                  "pile.orientations: instance 2 has (1, 1, 0, 0), not a unit quaternion");
  EXPECT_CONTAINS(errorIn([&](json& j) { grains(j)["orientations"][0] = {1, 0, 0}; }),
                  "pile.orientations: expected [w, x, y, z] quaternions");
  EXPECT_CONTAINS(errorIn([&](json& j) { grains(j)["scales"][1] = -1; }), "pile.scales: instance 1 has scale -1");
  EXPECT_CONTAINS(errorIn([&](json& j) { grains(j)["velocities"] = {{1, 0, 0}}; }),
                  "pile.velocities: has 1 values but protoIndices has 3");
  EXPECT_CONTAINS(errorIn([&](json& j) { grains(j)["angular_velocities"][0] = {0, 1e39, 0}; }),
                  "pile.angular_velocities: 1e+39 does not fit in a float");
  EXPECT_CONTAINS(errorIn([&](json& j) { grains(j)["proto_indices"][0] = 0.5; }),
                  "pile.proto_indices: expected an integer");
  EXPECT_CONTAINS(errorIn([&](json& j) { grains(j).erase("positions"); }), "pile.positions: is required");
  EXPECT_CONTAINS(errorIn([&](json& j) { grains(j)["prototypes"] = json::array(); }), "pile.prototypes: is empty");
  EXPECT_CONTAINS(errorIn([&](json& j) { grains(j)["prototypes"][0]["material"] = "snow"; }),
                  "pile/rock.material: unknown material \"snow\"");
  EXPECT_CONTAINS(errorIn([&](json& j) { grains(j)["velocity"] = json::array(); }), "pile.velocity: unknown key");
  EXPECT_CONTAINS(errorIn([&](json& j) { grains(j)["transform"] = {{"scale", 0}}; }), "pile.transform: is singular");
  EXPECT_CONTAINS(errorIn([&](json& j) { j["instanced_grains"].push_back(grains(j)); }),
                  "instanced_grains[1].name: \"pile\" is used by another entry of instanced_grains");
}

TEST(SceneIo, AnIesProfileIsNamedRelativeToTheSceneFile) {
  namespace fs = std::filesystem;
  const fs::path dir = fs::temp_directory_path() / ("granular_json_ies_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  std::ofstream(dir / "spot.ies") << "IESNA:LM-63-2002\nTILT=NONE\n1 -1 1 2 1 1 2 0 0 0\n1 1 10\n0 90\n0\n10 0\n";
  std::ofstream(dir / "photo.ies") << "a photograph\n";
  const std::string source = (dir / "scene.json").string();
  SceneDesc d = parseSceneJson(R"({"lights": [{"name": "spot", "type": "sphere", "shaping_ies_file": "spot.ies",
      "shaping_ies_angle_scale": -0.5, "shaping_ies_normalize": true}]})",
                               source);
  ASSERT_EQ(d.lights.size(), 1u);
  EXPECT_TRUE(d.lights[0].shaping.enabled);
  EXPECT_EQ(fs::path(d.lights[0].shaping.iesFile), dir / "spot.ies");
  EXPECT_FLOAT_EQ(d.lights[0].shaping.iesAngleScale, -0.5f);
  EXPECT_TRUE(d.lights[0].shaping.iesNormalize);
  auto error = [&](const std::string& text) {
    try {
      parseSceneJson(text, source);
    } catch (const InputError& e) {
      return std::string(e.what());
    }
    return std::string("NO ERROR");
  };
  EXPECT_EQ(error(R"({"lights": [{"name": "s", "type": "disk", "shaping_ies_file": "none.ies"}]})"),
            "s.shaping_ies_file: \"" + (dir / "none.ies").string() + "\" does not exist");
  EXPECT_EQ(error(R"({"lights": [{"name": "s", "type": "disk", "shaping_ies_file": "photo.ies"}]})"),
            "s.shaping_ies_file: \"" + (dir / "photo.ies").string() +
                "\" has no TILT= line: it is not an IES LM-63 photometric file");
  EXPECT_CONTAINS(error(R"({"lights": [{"name": "s", "type": "disk", "shaping_ies_angle_scale": "wide"}]})"),
                  "s.shaping_ies_angle_scale");
  EXPECT_CONTAINS(error(R"({"lights": [{"name": "s", "type": "distant", "shaping_ies_file": "spot.ies"}]})"),
                  "s.shaping_ies_file");
  fs::remove_all(dir);
}

TEST(SceneIo, DiskAndCylinderLightsAndShapingParse) {
  SceneDesc d = parseSceneJson(R"({"lights": [
      {"name": "disk", "type": "disk", "radius": 0.3, "shaping_cone_angle": 30, "shaping_cone_softness": 0.2},
      {"name": "tube", "type": "cylinder", "position": [0, 2, 0], "radius": 0.05, "length": 2,
       "shaping_focus": 3, "shaping_focus_tint": [0.1, 0.2, 0.3]},
      {"name": "plain", "type": "disk"}]})",
                               "x.json");
  ASSERT_EQ(d.lights.size(), 3u);
  EXPECT_EQ(d.lights[0].type, LightType::Disk);
  EXPECT_FLOAT_EQ(d.lights[0].radius, 0.3f);
  EXPECT_TRUE(d.lights[0].shaping.enabled);
  EXPECT_FLOAT_EQ(d.lights[0].shaping.coneAngle, 30);
  EXPECT_FLOAT_EQ(d.lights[0].shaping.coneSoftness, 0.2f);
  EXPECT_FLOAT_EQ(d.lights[0].shaping.focus, 0);  // UsdLux's fallback
  EXPECT_EQ(d.lights[1].type, LightType::Cylinder);
  expectNear(d.lights[1].xf.point({0, 0, 0}), {0, 2, 0});
  EXPECT_FLOAT_EQ(d.lights[1].length, 2);
  EXPECT_FLOAT_EQ(d.lights[1].shaping.coneAngle, 90);
  EXPECT_FLOAT_EQ(d.lights[1].shaping.focus, 3);
  EXPECT_EQ(d.lights[1].shaping.focusTint, Vec3(0.1f, 0.2f, 0.3f));
  EXPECT_FALSE(d.lights[2].shaping.enabled);
  // Errors name the light and the key.
  EXPECT_CONTAINS(errorOf(std::string(R"({"lights": [{"name": "t", "type": "cylinder", "length": 0}]})")), "t.length");
  EXPECT_CONTAINS(errorOf(std::string(R"({"lights": [{"name": "t", "type": "disk", "shaping_focus_tint": [-1, 0, 0]}]})")),
                  "t.shaping_focus_tint");
  EXPECT_CONTAINS(errorOf(std::string(R"({"lights": [{"name": "s", "type": "distant", "shaping_focus": 1}]})")), "s.shaping_focus");
}

TEST(SceneIo, MeshLightsParseTheirShape) {
  SceneDesc d = parseSceneJson(R"({"lights": [
      {"name": "panel", "type": "mesh", "transform": {"translate": [0, 2, 0]}, "double_sided": true,
       "shape": {"mesh": {"points": [[0, 0, 0], [1, 0, 0], [1, 0, 1], [0, 0, 1]],
                          "face_vertex_counts": [4], "face_vertex_indices": [0, 1, 2, 3]}}},
      {"name": "ball", "type": "mesh", "intensity": 2, "normalize": true, "shape": {"icosphere": {"radius": 0.5}}}]})",
                               "x.json");
  ASSERT_EQ(d.lights.size(), 2u);
  EXPECT_EQ(d.lights[0].type, LightType::Mesh);
  EXPECT_EQ(d.lights[0].mesh.numTriangles(), 2u);
  EXPECT_TRUE(d.lights[0].doubleSided);
  expectNear(d.lights[0].xf.point({0, 0, 0}), {0, 2, 0});
  EXPECT_EQ(d.lights[1].type, LightType::Mesh);
  EXPECT_GT(d.lights[1].mesh.numTriangles(), 20u);
  EXPECT_FALSE(d.lights[1].doubleSided);
  EXPECT_NEAR(normalizationArea(d.lights[1]), d.lights[1].mesh.area(), 1e-6);
  EXPECT_CONTAINS(errorOf(std::string(R"({"lights": [{"name": "m", "type": "mesh"}]})")), "m.shape");
  EXPECT_CONTAINS(errorOf(std::string(R"({"lights": [{"name": "m", "type": "mesh", "shaping_cone_angle": 30,
                                        "shape": {"icosphere": {"radius": 1}}}]})")),
                  "m.shaping_cone_angle");
  EXPECT_CONTAINS(errorOf(std::string(R"({"lights": [{"name": "m", "type": "mesh", "shape": {"mesh": {"points": [[0, 0, 0], [1, 0, 0], [2, 0, 0]],
                                        "face_vertex_counts": [3], "face_vertex_indices": [0, 1, 2]}}}]})")),
                  "m.points: the mesh has no area");
}
