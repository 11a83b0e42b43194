// Coarse density export: the VDB holds sigmaT exactly at voxel centres inside the
// boundary and 0 outside, in world space, and bad input leaves no file behind.
#include <gtest/gtest.h>

#include <filesystem>
#include <random>
#include <unistd.h>

#include "core/density_export.h"
#include "core/error.h"
#include "core/shapes.h"
#include "test_helpers.h"

using namespace granular;
namespace fs = std::filesystem;

namespace {

fs::path tempPath(const std::string& name) {
  fs::path dir = fs::temp_directory_path() / ("granular_density_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  return dir / name;
}

// A sphere of radius 0.5 around (2, 1, -1): an off-origin, world-space boundary.
TriangleMesh worldSphere() {
  return makeIcosphere(3).transformed(Transform::translate(Vec3(2, 1, -1)) * Transform::scale(Vec3(0.5f)));
}

}  // namespace

TEST(DensityExport, VoxelsInsideHoldSigmaTAndOutsideZero) {
  const fs::path path = tempPath("sphere.vdb");
  const TriangleMesh mesh = worldSphere();
  DensityExportOptions opt;
  opt.voxelSize = 0.02f;
  opt.floatMetadata["granular:packingRate"] = 0.6f;
  DensityExportResult r = writeDensityVdb(path.string(), mesh, 37.5f, opt, "/World/Ball");
  ASSERT_TRUE(fs::exists(path));
  EXPECT_FALSE(fs::exists(path.string() + ".tmp"));
  EXPECT_FLOAT_EQ(r.voxelSize, 0.02f);
  // About the sphere's volume in voxels (the icosphere is slightly smaller than the sphere).
  const double sphereVoxels = 4.0 / 3.0 * M_PI * 0.125 / (0.02 * 0.02 * 0.02);
  EXPECT_GT(double(r.activeVoxels), 0.9 * sphereVoxels);
  EXPECT_LT(double(r.activeVoxels), 1.02 * sphereVoxels);

  std::vector<VdbGridInfo> grids = readVdbGrids(path.string());
  ASSERT_EQ(grids.size(), 1u);
  EXPECT_EQ(grids[0].name, "density");
  EXPECT_EQ(grids[0].valueType, "float");
  EXPECT_EQ(grids[0].gridClass, "fog volume");
  EXPECT_FLOAT_EQ(grids[0].voxelSize.x, 0.02f);
  EXPECT_EQ(grids[0].activeVoxels, r.activeVoxels);
  EXPECT_EQ(grids[0].metadata.at("granular:object"), "/World/Ball");
  EXPECT_EQ(grids[0].metadata.at("granular:packingRate"), "0.6");

  // Random world points: away from the surface by more than a voxel, the value is sigmaT
  // inside and 0 outside, as the exact point-in-mesh test says.
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(-0.8f, 0.8f);
  std::vector<Vec3> pts;
  std::vector<bool> inside;
  while (pts.size() < 400) {
    Vec3 p = Vec3(2, 1, -1) + Vec3(u(rng), u(rng), u(rng));
    float d = length(p - Vec3(2, 1, -1));
    if (std::fabs(d - 0.5f) < 0.04f) continue;
    pts.push_back(p);
    inside.push_back(granular::testing::pointInMesh(mesh, p));
  }
  std::vector<float> v = sampleVdbGrid(path.string(), "density", pts);
  ASSERT_EQ(v.size(), pts.size());
  int in = 0;
  for (size_t i = 0; i < pts.size(); ++i) {
    EXPECT_FLOAT_EQ(v[i], inside[i] ? 37.5f : 0.0f) << "at " << pts[i].x << " " << pts[i].y << " " << pts[i].z;
    in += inside[i];
  }
  EXPECT_GT(in, 20);
  EXPECT_GT(int(pts.size()) - in, 20);
  fs::remove(path);
}

TEST(DensityExport, DefaultVoxelSizeSpansTheExtent) {
  const fs::path path = tempPath("auto.vdb");
  DensityExportOptions opt;  // voxelSize 0: extent / 128
  DensityExportResult r = writeDensityVdb(path.string(), worldSphere(), 1.0f, opt, "ball");
  const float extent = maxComponent(worldSphere().bounds().extent());
  EXPECT_NEAR(r.voxelSize, extent / 128.0f, 1e-6f);
  EXPECT_NEAR(r.worldBounds.center().x, 2.0f, 2 * r.voxelSize);
  EXPECT_NEAR(r.worldBounds.center().y, 1.0f, 2 * r.voxelSize);
  EXPECT_NEAR(r.worldBounds.center().z, -1.0f, 2 * r.voxelSize);
  fs::remove(path);
}

TEST(DensityExport, BadInputThrowsAndLeavesNoFile) {
  const fs::path path = tempPath("bad.vdb");
  fs::remove(path);
  DensityExportOptions opt;
  opt.voxelSize = 0.05f;
  auto expectError = [&](const TriangleMesh& m, float sigmaT, const DensityExportOptions& o, const char* attr) {
    try {
      writeDensityVdb(path.string(), m, sigmaT, o, "/World/Ball");
      ADD_FAILURE() << "no error for " << attr;
    } catch (const InputError& e) {
      EXPECT_EQ(e.object(), "/World/Ball");
      EXPECT_EQ(e.attribute(), attr) << e.what();
    }
    EXPECT_FALSE(fs::exists(path));
    EXPECT_FALSE(fs::exists(path.string() + ".tmp"));
  };
  expectError(worldSphere(), std::nanf(""), opt, "sigmaT");
  expectError(worldSphere(), -1.0f, opt, "sigmaT");
  DensityExportOptions tiny = opt;
  tiny.voxelSize = 1e-5f;
  expectError(worldSphere(), 1.0f, tiny, "voxelSize");
  TriangleMesh open = worldSphere();
  open.indices.resize(open.indices.size() - 3);
  expectError(open, 1.0f, opt, "faceVertexIndices");
  // A scene in tiny units: the default voxel (extent / 128) is below what OpenVDB's
  // world-space transform accepts; it was an escaping ArithmeticError (bench/stress.py).
  TriangleMesh micro = worldSphere();
  for (Vec3& p : micro.points) p *= 1e-6f;
  expectError(micro, 1.0f, DensityExportOptions(), "voxelSize");

  // An unwritable destination is an I/O error, not an InputError, and leaves nothing.
  const std::string noDir = (tempPath("missing") / "sub" / "x.vdb").string();
  EXPECT_THROW(writeDensityVdb(noDir, worldSphere(), 1.0f, opt, "ball"), std::runtime_error);
  EXPECT_FALSE(fs::exists(noDir));
}

TEST(DensityExport, ReadingAMissingFileOrGridIsAnInputError) {
  EXPECT_THROW(readVdbGrids(tempPath("nope.vdb").string()), InputError);
  const fs::path path = tempPath("grid.vdb");
  DensityExportOptions opt;
  opt.voxelSize = 0.05f;
  writeDensityVdb(path.string(), worldSphere(), 2.0f, opt, "ball");
  try {
    sampleVdbGrid(path.string(), "temperature", {Vec3(0.0f)});
    ADD_FAILURE() << "no error";
  } catch (const InputError& e) {
    EXPECT_EQ(e.attribute(), "temperature");
    EXPECT_NE(std::string(e.what()).find("density"), std::string::npos) << e.what();
  }
  fs::remove(path);
}
