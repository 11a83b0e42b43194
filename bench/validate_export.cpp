// granular-validate — what bench/validate_mitsuba.py needs from our side (a tool, not a test).
//
//   granular-validate export SCENE.json OUTDIR
//     Writes OUTDIR/scene.json and binary PLY meshes describing the scene exactly as our
//     renderer sees it, for an independent renderer to rebuild:
//       * width, height and the maximum number of scattering events of a path;
//       * the camera: camera-to-world matrix (row-major, USD convention: looks down local
//         -Z, +Y up), the horizontal field of view after the aperture is fitted to the
//         image, the clipping range; width and height;
//       * lights: dome (constant only) as radiance, distant with angle 0 (delta) as the
//         direction of travel and the irradiance;
//       * materials by index (the scene's own, then the defaults Scene::build adds);
//       * meshes in world space with their material index;
//       * per aggregate: the boundary in world space, the prototypes as normalised into
//         their unit bounding spheres (GrainPrototype::mesh), every grain as a prototype
//         index and a 4x4 object-to-world matrix (translate(c) * R * rotation), the grain
//         radius (Beer–Lambert absorption is per unit of the prototype's space, so it is
//         absorption / R in world units), and, when the scene's technique uses media, the
//         TT medium our VPT renders: σ_t, α_s and the phase table per channel.
//   granular-validate vpt SCENE.json OUT.exr [--spp N] [--seed S]
//     Our VPT alone of the TT media (technique ept+vpt, no DA): every camera path starts
//     in the media mode (ept.h kVpt) in the medium holding the camera, as
//     tests/core/test_vpt.cpp does, so the image is the equivalent media's radiance with
//     the boundary as an index-matched interface. Pixel sample s of (x, y) is seeded by
//     hash(seed, x, y, s) and jittered in the pixel like Renderer.
#include <tbb/parallel_for.h>

#include <atomic>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "core/ept.h"
#include "core/error.h"
#include "core/microfacet.h"
#include "core/film.h"
#include "core/image_io.h"
#include "core/render.h"
#include "core/scene.h"
#include "core/scene_io.h"
#include "core/vpt.h"

using namespace granular;

namespace {

// A mesh with uvs is written unwelded (three vertices per triangle) with u, v per vertex:
// PLY, like Mitsuba's meshes, holds texture coordinates per vertex, ours are per corner.
// v is written as 1 − v: Mitsuba's bitmap puts v = 0 on the image's top row (its OBJ loader
// flips v for that), USD's st on the bottom row.
void writePlyWithUvs(const std::string& path, const TriangleMesh& m) {
  std::ofstream out(path, std::ios::binary);
  if (!out) throw std::runtime_error("cannot write " + path);
  out << "ply\nformat binary_little_endian 1.0\nelement vertex " << m.indices.size()
      << "\nproperty float x\nproperty float y\nproperty float z\nproperty float u\nproperty float v\nelement face "
      << m.numTriangles() << "\nproperty list uchar int vertex_indices\nend_header\n";
  for (size_t c = 0; c < m.indices.size(); ++c) {
    const Vec3& p = m.points[m.indices[c]];
    float v[5] = {p.x, p.y, p.z, m.uvs[2 * c], 1.0f - m.uvs[2 * c + 1]};
    out.write(reinterpret_cast<const char*>(v), sizeof v);
  }
  for (size_t t = 0; t < m.numTriangles(); ++t) {
    unsigned char n = 3;
    int idx[3] = {int(3 * t), int(3 * t + 1), int(3 * t + 2)};
    out.write(reinterpret_cast<const char*>(&n), 1);
    out.write(reinterpret_cast<const char*>(idx), sizeof idx);
  }
  if (!out) throw std::runtime_error("cannot write " + path);
}

void writePly(const std::string& path, const TriangleMesh& m) {
  if (m.hasUvs()) return writePlyWithUvs(path, m);
  std::ofstream out(path, std::ios::binary);
  if (!out) throw std::runtime_error("cannot write " + path);
  out << "ply\nformat binary_little_endian 1.0\nelement vertex " << m.points.size()
      << "\nproperty float x\nproperty float y\nproperty float z\nelement face " << m.numTriangles()
      << "\nproperty list uchar int vertex_indices\nend_header\n";
  for (const Vec3& p : m.points) {
    float v[3] = {p.x, p.y, p.z};
    out.write(reinterpret_cast<const char*>(v), sizeof v);
  }
  for (size_t t = 0; t < m.numTriangles(); ++t) {
    unsigned char n = 3;
    int idx[3] = {int(m.indices[3 * t]), int(m.indices[3 * t + 1]), int(m.indices[3 * t + 2])};
    out.write(reinterpret_cast<const char*>(&n), 1);
    out.write(reinterpret_cast<const char*>(idx), sizeof idx);
  }
  if (!out) throw std::runtime_error("cannot write " + path);
}

std::string num(double v) {
  char b[40];
  std::snprintf(b, sizeof b, "%.9g", v);
  return b;
}
std::string vec(const Vec3& v) { return "[" + num(v.x) + ", " + num(v.y) + ", " + num(v.z) + "]"; }
std::string matrix(const Transform& t) {
  std::string s = "[";
  for (int i = 0; i < 16; ++i) s += (i ? ", " : "") + num(t.m[i / 4][i % 4]);
  return s + "]";
}
std::string floats(const std::vector<float>& v) {
  std::string s = "[";
  for (size_t i = 0; i < v.size(); ++i) s += (i ? ", " : "") + num(v[i]);
  return s + "]";
}

// Mirrors Scene::build's material list: the scene's, then the defaults it appends.
std::vector<MaterialDesc> sceneMaterials(const SceneDesc& d) {
  std::vector<MaterialDesc> m = d.materials;
  MaterialDesc grey;
  grey.name = "default_surface";
  m.push_back(grey);
  MaterialDesc glass;
  glass.name = "default_grain";
  glass.type = MaterialType::Dielectric;
  m.push_back(glass);
  return m;
}

int exportScene(const std::string& scenePath, const std::string& dir) {
  SceneDesc desc = loadSceneJson(scenePath);
  if (desc.settings.technique == Technique::Hybrid) desc.settings.technique = Technique::EptVpt;
  auto scene = Scene::build(desc);
  std::filesystem::create_directories(dir);
  const int W = desc.settings.width, H = desc.settings.height;
  const int defaultSurface = int(desc.materials.size()), defaultGrain = defaultSurface + 1;

  // Horizontal field of view of the fitted aperture, read back through the camera itself.
  if (desc.camera.horizontalApertureOffset != 0 || desc.camera.verticalApertureOffset != 0)
    throw InputError("camera", "apertureOffset", "the exporter supports no aperture offset");
  Transform toCam;
  desc.camera.cameraToWorld.inverse(toCam);
  Vec3 edge = toCam.vector(scene->camera().generateRay(float(W), 0.5f * H).d);
  double fovX = 2.0 * std::atan2(double(edge.x), double(-edge.z)) * 180.0 / 3.14159265358979323846;

  std::string j = "{\n";
  j += "  \"width\": " + std::to_string(W) + ", \"height\": " + std::to_string(H) +
       ", \"max_depth\": " + std::to_string(desc.settings.maxDepth) + ",\n";
  j += "  \"camera\": {\"to_world\": " + matrix(desc.camera.cameraToWorld) + ", \"fov_x_deg\": " + num(fovX) +
       ", \"near\": " + num(desc.camera.clipNear) + ", \"far\": " + num(std::min(desc.camera.clipFar, 1e30f)) +
       ", \"lens_radius\": " + num(desc.camera.lensRadius) + ", \"focus_distance\": " + num(desc.camera.focusDistance) +
       "},\n";

  j += "  \"lights\": [";
  for (size_t i = 0; i < desc.lights.size(); ++i) {
    const LightDesc& l = desc.lights[i];
    Vec3 L = l.color * (l.intensity * std::exp2(l.exposure));
    j += i ? ",\n    " : "\n    ";
    if (l.type == LightType::Dome) {
      if (!l.textureFile.empty()) throw InputError(l.name, "textureFile", "the exporter supports constant domes only");
      j += "{\"type\": \"dome\", \"radiance\": " + vec(L) + "}";
    } else if (l.type == LightType::Distant) {
      if (l.angle != 0) throw InputError(l.name, "angle", "the exporter supports delta distant lights (angle 0) only");
      // The light emits along its local -Z; our irradiance is the radiance value.
      j += "{\"type\": \"distant\", \"direction\": " + vec(normalize(l.xf.vector(Vec3(0, 0, -1)))) +
           ", \"irradiance\": " + vec(L) + "}";
    } else {
      throw InputError(l.name, "type", "the exporter supports dome and distant lights only");
    }
  }
  j += "\n  ],\n";

  std::vector<MaterialDesc> mats = sceneMaterials(desc);
  j += "  \"materials\": [";
  for (size_t i = 0; i < mats.size(); ++i) {
    const MaterialDesc& m = mats[i];
    if (!isBlack(m.emission)) throw InputError(m.name, "emission", "the exporter supports no emission");
    if (m.emissionTexture.enabled() || m.opacityTexture.enabled() || m.opacity < 1)
      throw InputError(m.name, "emissionTexture", "the exporter supports albedo textures only");
    j += i ? ",\n    " : "\n    ";
    j += "{\"name\": \"" + m.name + "\", \"type\": \"" +
         std::string(m.type == MaterialType::Lambert ? "lambert" : "dielectric") + "\", \"albedo\": " + vec(m.albedo) +
         ", \"ior\": " + num(m.ior) + ", \"absorption\": " + vec(m.absorption) +
         ", \"ggx_alpha\": " + num(m.type == MaterialType::Dielectric ? alphaFromRoughness(m.roughness) : 0.0f);
    if (m.albedoTexture.enabled()) {
      // Mitsuba's bitmap: bilinear, one wrap mode for both axes, sRGB decoding (raw false)
      // of 8-bit images; no scale or bias.
      const TextureDesc& t = m.albedoTexture;
      for (int c = 0; c < 4; ++c)
        if (t.scale[c] != 1 || t.bias[c] != 0) throw InputError(t.source, "scale", "the exporter supports no scale or bias");
      if (t.wrapS != t.wrapT) throw InputError(t.source, "wrap", "the exporter supports one wrap mode for s and t");
      static const char* wraps[] = {"repeat", "black", "clamp", "repeat", "mirror"};
      j += ", \"albedo_texture\": {\"file\": \"" + t.file + "\", \"wrap\": \"" + wraps[int(t.wrapS)] +
           "\", \"raw\": " + (t.colorSpace == TextureColorSpace::Raw ? "true" : "false") + "}";
    }
    j += "}";
  }
  j += "\n  ],\n";

  j += "  \"meshes\": [";
  int meshCount = 0;
  for (size_t i = 0; i < desc.meshes.size(); ++i) {
    const MeshDesc& m = desc.meshes[i];
    if (!m.visible) continue;
    std::string file = "mesh" + std::to_string(i) + ".ply";
    writePly(dir + "/" + file, m.mesh.transformed(m.xf));
    j += meshCount++ ? ",\n    " : "\n    ";
    j += "{\"ply\": \"" + file + "\", \"material\": " + std::to_string(m.material >= 0 ? m.material : defaultSurface) + "}";
  }
  j += "\n  ],\n";

  j += "  \"aggregates\": [";
  for (size_t a = 0; a < scene->aggregates().size(); ++a) {
    const Aggregate& agg = *scene->aggregates()[a];
    const AggregateDesc& ad = desc.aggregates[a];
    std::string prefix = "agg" + std::to_string(a);
    // The scene holds its aggregates in render space; the export is in world space.
    const Vec3d origin = scene->renderOrigin();
    writePly(dir + "/" + prefix + "_boundary.ply", agg.boundary().transformed(Transform::translate(origin.x, origin.y, origin.z)));
    j += a ? ",\n    " : "\n    ";
    j += "{\"name\": \"" + agg.name() + "\", \"boundary_ply\": \"" + prefix + "_boundary.ply\", \"grain_radius\": " +
         num(agg.grainRadius()) + ",\n     \"prototypes\": [";
    for (size_t p = 0; p < agg.prototypes().size(); ++p) {
      std::string file = prefix + "_proto" + std::to_string(p) + ".ply";
      writePly(dir + "/" + file, agg.prototypes()[p].mesh);
      int mat = ad.prototypes[p].material >= 0 ? ad.prototypes[p].material : defaultGrain;
      j += (p ? ", " : "") + std::string("{\"ply\": \"") + file + "\", \"material\": " + std::to_string(mat) + "}";
    }
    j += "],\n     \"grains\": [";
    long count = 0;
    agg.forEachGrain(agg.bounds(), [&](const GrainInstance& g) {
      Transform xf;
      for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 3; ++c) xf.m[r][c] = double(g.radius) * g.rotation.m[r][c];
        xf.m[r][3] = double(g.center[r]) + origin[r];
      }
      j += (count++ ? ",\n       " : "\n       ") + std::string("{\"prototype\": ") + std::to_string(g.prototype) +
           ", \"matrix\": " + matrix(xf) + "}";
    });
    j += "]";
    if (scene->hasMedia()) {
      const MediumParams& mp = scene->mediumParams(int(a));
      j += ",\n     \"medium\": {\"sigma_t\": " + vec(mp.sigmaT) + ", \"albedo\": " + vec(mp.albedo) + ", \"g\": " +
           vec(mp.g) + ", \"phase\": [" + floats(mp.phase[0].density) + ", " + floats(mp.phase[1].density) + ", " +
           floats(mp.phase[2].density) + "]}";
    }
    j += "}";
    std::fprintf(stderr, "aggregate %s: %ld grains\n", agg.name().c_str(), count);
  }
  j += "\n  ]\n}\n";
  std::ofstream out(dir + "/scene.json");
  out << j;
  if (!out) throw std::runtime_error("cannot write " + dir + "/scene.json");
  return 0;
}

int renderVpt(const std::string& scenePath, const std::string& outPath, int spp, long seed) {
  SceneDesc desc = loadSceneJson(scenePath);
  desc.settings.technique = Technique::EptVpt;  // media, no DA
  if (spp > 0) desc.settings.spp = spp;
  if (seed >= 0) desc.settings.seed = uint64_t(seed);
  auto scene = Scene::build(desc);
  if (!scene->hasMedia()) throw InputError(scenePath, "aggregates", "no aggregate is thick enough to get a medium");
  const RenderSettings& rs = scene->settings();
  const Camera& cam = scene->camera();
  const int startMedium = scene->mediumAt(cam.position());
  Film film(rs.width, rs.height);
  std::atomic<long> nonFinite{0};
  tbb::parallel_for(0, rs.height, [&](int y) {
    for (int x = 0; x < rs.width; ++x)
      for (int s = 0; s < rs.spp; ++s) {
        Rng rng(hashInts(rs.seed, uint64_t(x), uint64_t(y), uint64_t(s)), 0);
        Ray ray = cam.generateRay(float(x) + rng.next1D(), float(y) + rng.next1D());
        PathState p = startPath(ray, 0);
        p.rng = rng;
        p.mode = p.credit = kVpt;
        p.medium = startMedium;
        while (p.alive) vptStep(*scene, p);
        PixelSample ps;
        if (!toPixelSample(p, ps)) ++nonFinite;
        film.add(x, y, ps);
      }
  });
  // A validation image must not hide a numerical failure as a slightly darker pixel.
  if (nonFinite > 0) throw std::runtime_error(str(nonFinite.load(), " VPT samples were not finite"));
  writeImage(outPath, film.toImage());
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 4) {
    std::fprintf(stderr,
                 "usage: granular-validate export SCENE.json OUTDIR\n"
                 "       granular-validate vpt SCENE.json OUT.exr [--spp N] [--seed S]\n");
    return 2;
  }
  std::string mode = argv[1];
  int spp = -1;
  long seed = -1;
  for (int i = 4; i + 1 < argc; i += 2) {
    std::string a = argv[i];
    if (a == "--spp") spp = std::atoi(argv[i + 1]);
    else if (a == "--seed") seed = std::atol(argv[i + 1]);
  }
  const int status = runTool([&] {
    if (mode == "export") return exportScene(argv[2], argv[3]);
    if (mode == "vpt") return renderVpt(argv[2], argv[3], spp, seed);
    return -1;  // no command matched
  });
  if (status >= 0) return status;
  return 2;
}
