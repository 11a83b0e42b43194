// test_mesh.cpp — mesh validity checks, volumes, transforms and procedural shapes.
#include <gtest/gtest.h>

#include "core/error.h"
#include "core/mesh.h"
#include "core/shapes.h"
#include "test_helpers.h"

using namespace granular;

namespace {

// The message of the InputError `f` throws ("" if it throws nothing).
template <typename F>
std::string errorOf(F&& f) {
  try {
    f();
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

void expectClosed(const TriangleMesh& m, const char* what) {
  SCOPED_TRACE(what);
  double v = 0;
  EXPECT_NO_THROW(v = validateClosed(m, what));
  EXPECT_GT(v, 0) << "outward winding gives positive volume";
}

TriangleMesh unitCubeQuads() {
  std::vector<Vec3> pts;
  for (int i = 0; i < 8; ++i) pts.push_back({float(i & 1), float((i >> 1) & 1), float((i >> 2) & 1)});
  std::vector<int> counts(6, 4);
  std::vector<int> idx = {0, 4, 6, 2, 1, 3, 7, 5, 0, 1, 5, 4, 2, 6, 7, 3, 0, 2, 3, 1, 4, 5, 7, 6};
  return triangulate(pts, counts, idx, "cube");
}

}  // namespace

TEST(Mesh, ProceduralShapesAreClosedAndOutward) {
  for (int s = 0; s <= 3; ++s) expectClosed(makeIcosphere(s), "icosphere");
  expectClosed(makeBox({-1, -2, -3}, {1, 2, 3}), "box");
  expectClosed(makeUVSphere(3, 2), "uvsphere 3x2");
  expectClosed(makeUVSphere(24, 12), "uvsphere");
  expectClosed(makeLathe({{1, 0}, {1, 1}}, 16), "cylinder (two caps)");
  expectClosed(makeLathe({{0, 0}, {1, 0.5f}, {0, 1}}, 8), "double cone (two poles)");
  expectClosed(makeLathe({{1, 0}, {0.8f, 1}, {0, 1.5f}}, 64), "tower (cap + pole)");
  expectClosed(makeLathe({{0, 1}, {1, 0}}, 8), "profile running downwards");
  expectClosed(makeLathe({{0.5f, 0}, {1, 0.3f}, {0.3f, 0.6f}, {1, 1}, {0.4f, 1.2f}}, 32), "vase");
  expectClosed(makeRock(3, 0.3f, 7), "rock");
  expectClosed(makeEllipsoid({1, 0.5f, 0.25f}, 2), "ellipsoid");
  expectClosed(unitCubeQuads(), "quad cube");
}

TEST(Mesh, ShapesHaveSharedVertices) {
  EXPECT_EQ(makeBox({0, 0, 0}, {1, 1, 1}).points.size(), 8u);
  EXPECT_EQ(makeBox({0, 0, 0}, {1, 1, 1}).numTriangles(), 12u);
  TriangleMesh ico = makeIcosphere(2);
  EXPECT_EQ(ico.numTriangles(), 20u * 16u);
  EXPECT_EQ(ico.points.size(), 162u);  // V = 10 * 4^n + 2
  for (const Vec3& p : ico.points) EXPECT_NEAR(length(p), 1.0f, 1e-6f);
  TriangleMesh uv = makeUVSphere(16, 8);
  EXPECT_EQ(uv.points.size(), 16u * 7u + 2u);
  for (const Vec3& p : uv.points) EXPECT_NEAR(length(p), 1.0f, 1e-6f);
}

TEST(Mesh, SignedVolumes) {
  double sphere = 4.0 / 3.0 * 3.14159265358979323846;
  EXPECT_NEAR(makeIcosphere(4).signedVolume(), sphere, 0.01 * sphere);
  EXPECT_DOUBLE_EQ(makeBox({-1, 0, 2}, {1, 3, 6}).signedVolume(), 2.0 * 3.0 * 4.0);
  EXPECT_DOUBLE_EQ(unitCubeQuads().signedVolume(), 1.0);
  // Far from the origin the volume must not drown in cancellation.
  EXPECT_NEAR(makeBox({1000, 1000, 1000}, {1001, 1002, 1003}).signedVolume(), 6.0, 1e-9);
  EXPECT_NEAR(makeEllipsoid({1, 2, 3}, 4).signedVolume(), 6 * sphere, 0.01 * 6 * sphere);
  // Cylinder r=1, h=2 with 256 segments: the inscribed polygon's area times height.
  double cyl = 2 * 0.5 * 256 * std::sin(2 * 3.14159265358979323846 / 256);
  EXPECT_NEAR(makeLathe({{1, 0}, {1, 2}}, 256).signedVolume(), cyl, 1e-5);
  TriangleMesh flipped = makeBox({0, 0, 0}, {1, 1, 1});
  flipped.flip();
  EXPECT_DOUBLE_EQ(flipped.signedVolume(), -1.0);
}

TEST(Mesh, Areas) {
  EXPECT_DOUBLE_EQ(makeBox({-1, 0, 2}, {1, 3, 6}).area(), 2.0 * (2.0 * 3.0 + 3.0 * 4.0 + 2.0 * 4.0));
  EXPECT_DOUBLE_EQ(unitCubeQuads().area(), 6.0);
  // A fine icosphere approaches the sphere's 4π from below (its triangles are inscribed).
  const double sphere = 4.0 * 3.14159265358979323846, ico = makeIcosphere(5).area();
  EXPECT_LT(ico, sphere);
  EXPECT_GT(ico, 0.995 * sphere);
  EXPECT_EQ(TriangleMesh().area(), 0.0);
}

TEST(Mesh, TransformedKeepsOutwardWinding) {
  TriangleMesh box = makeBox({0, 0, 0}, {1, 2, 3});
  TriangleMesh mirrored = box.transformed(Transform::scale({-2, 1, 1}));
  EXPECT_NEAR(mirrored.signedVolume(), 12.0, 1e-9);
  EXPECT_NO_THROW(validateClosed(mirrored, "mirrored"));
  TriangleMesh moved = box.transformed(Transform::translate({5, 0, 0}) * Transform::scale(Vec3(0.5f)));
  EXPECT_NEAR(moved.signedVolume(), 6.0 / 8.0, 1e-9);
  EXPECT_EQ(moved.bounds().lo, Vec3(5, 0, 0));
  EXPECT_EQ(moved.bounds().hi, Vec3(5.5f, 1, 1.5f));
}

TEST(Mesh, Bounds) {
  Bounds3 b = makeBox({-1, -2, -3}, {4, 5, 6}).bounds();
  EXPECT_EQ(b.lo, Vec3(-1, -2, -3));
  EXPECT_EQ(b.hi, Vec3(4, 5, 6));
  EXPECT_TRUE(TriangleMesh().bounds().empty());
}

TEST(Mesh, RemovedTriangleIsOpenBoundary) {
  TriangleMesh m = makeIcosphere(1);
  m.indices.erase(m.indices.begin() + 9, m.indices.begin() + 12);
  std::string e = errorOf([&] { validateClosed(m, "/World/Sand.boundary"); });
  EXPECT_NE(e.find("/World/Sand.boundary"), std::string::npos) << e;
  EXPECT_NE(e.find("open boundary: edge ("), std::string::npos) << e;
  EXPECT_NE(e.find("is used by 1 triangle(s)"), std::string::npos) << e;
}

TEST(Mesh, NonFinitePointIsReported) {
  TriangleMesh m = makeBox({0, 0, 0}, {1, 1, 1});
  m.points[5].x = std::nanf("");
  std::string e = errorOf([&] { validateClosed(m, "grainMesh"); });
  EXPECT_NE(e.find("grainMesh.points"), std::string::npos) << e;
  EXPECT_NE(e.find("point 5 is not finite (nan, 0, 1)"), std::string::npos) << e;
  m.points[5].x = kInf;
  EXPECT_NE(errorOf([&] { validateMesh(m, "m"); }).find("not finite"), std::string::npos);
}

TEST(Mesh, FlippedTriangleIsWindingError) {
  TriangleMesh m = makeIcosphere(1);
  std::swap(m.indices[31], m.indices[32]);
  std::string e = errorOf([&] { validateClosed(m, "rock"); });
  EXPECT_NE(e.find("rock."), std::string::npos) << e;
  EXPECT_NE(e.find("inconsistent winding at edge"), std::string::npos) << e;
}

TEST(Mesh, DuplicatedTriangleIsNonManifold) {
  TriangleMesh m = makeBox({0, 0, 0}, {1, 1, 1});
  m.indices.insert(m.indices.end(), {0, 4, 6});
  std::string e = errorOf([&] { validateClosed(m, "box"); });
  EXPECT_NE(e.find("non-manifold edge"), std::string::npos) << e;
}

TEST(Mesh, IndexAndEmptinessErrors) {
  TriangleMesh m = makeBox({0, 0, 0}, {1, 1, 1});
  m.indices[7] = 99;
  std::string e = errorOf([&] { validateMesh(m, "obj"); });
  EXPECT_NE(e.find("obj.faceVertexIndices: index 7 = 99 is out of range [0, 8)"), std::string::npos) << e;
  EXPECT_NE(errorOf([&] { validateMesh(TriangleMesh(), "empty"); }).find("has no triangles"), std::string::npos);
  TriangleMesh ragged = makeBox({0, 0, 0}, {1, 1, 1});
  ragged.indices.pop_back();
  EXPECT_NE(errorOf([&] { validateMesh(ragged, "r"); }).find("not a multiple of 3"), std::string::npos);
}

TEST(Mesh, DegenerateMeshesAreRejected) {
  // Two triangles back to back: closed, consistently wound, but enclosing nothing.
  TriangleMesh pillow;
  pillow.points = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
  pillow.indices = {0, 1, 2, 0, 2, 1};
  EXPECT_NE(errorOf([&] { validateClosed(pillow, "p"); }).find("degenerate: encloses no volume"), std::string::npos);
  // All triangles collinear.
  TriangleMesh line;
  line.points = {{0, 0, 0}, {1, 0, 0}, {2, 0, 0}};
  line.indices = {0, 1, 2, 0, 2, 1};
  EXPECT_NE(errorOf([&] { validateClosed(line, "l"); }).find("degenerate"), std::string::npos);
}

TEST(Mesh, IndividualDegenerateTrianglesAreAllowed) {
  // Tetrahedron whose edge AB carries a midpoint M: the zero-area triangle ABM
  // closes the surface.
  TriangleMesh m;
  m.points = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}, {0.5f, 0, 0}};  // A B C D M
  const uint32_t A = 0, B = 1, C = 2, D = 3, M = 4;
  m.indices = {A, C, M, M, C, B,  // was A C B, split at M
               B, D, A,           // shares edge AB
               B, A, M,           // degenerate (collinear)
               A, D, C, B, C, D};
  ASSERT_GT(m.signedVolume(), 0);
  EXPECT_NEAR(validateClosed(m, "tet"), 1.0 / 6.0, 1e-7);
  // A triangle repeating an index adds nothing and is ignored.
  TriangleMesh box = makeBox({0, 0, 0}, {1, 1, 1});
  box.indices.insert(box.indices.end(), {3, 3, 5});
  EXPECT_NO_THROW(validateClosed(box, "box"));
}

TEST(Mesh, TriangulateFansAndChecks) {
  TriangleMesh cube = unitCubeQuads();
  EXPECT_EQ(cube.numTriangles(), 12u);
  std::vector<Vec3> pts = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0.5f, 1.5f, 0}, {0, 1, 0}};
  TriangleMesh pent = triangulate(pts, {5}, {0, 1, 2, 3, 4}, "pent");
  EXPECT_EQ(pent.indices, (std::vector<uint32_t>{0, 1, 2, 0, 2, 3, 0, 3, 4}));

  std::string e = errorOf([&] { triangulate(pts, {3, 2}, {0, 1, 2, 3, 4}, "/World/M"); });
  EXPECT_NE(e.find("/World/M.faceVertexCounts: face 1 has 2 vertices"), std::string::npos) << e;
  e = errorOf([&] { triangulate(pts, {3}, {0, 1, 7}, "/World/M"); });
  EXPECT_NE(e.find("/World/M.faceVertexIndices: index 2 = 7 is out of range [0, 5)"), std::string::npos) << e;
  e = errorOf([&] { triangulate(pts, {3}, {0, -1, 2}, "/World/M"); });
  EXPECT_NE(e.find("faceVertexIndices: index 1 = -1"), std::string::npos) << e;
  e = errorOf([&] { triangulate(pts, {3, 3}, {0, 1, 2, 3}, "/World/M"); });
  EXPECT_NE(e.find("faceVertexCounts: counts sum to 6"), std::string::npos) << e;
}

TEST(Mesh, RockIsDeterministicStarShapedAndBounded) {
  TriangleMesh a = makeRock(2, 0.3f, 42), b = makeRock(2, 0.3f, 42), c = makeRock(2, 0.3f, 43);
  EXPECT_EQ(a.points, b.points);
  EXPECT_NE(a.points, c.points);
  float rmin = 10, rmax = 0;
  for (const Vec3& p : a.points) {
    rmin = std::min(rmin, length(p));
    rmax = std::max(rmax, length(p));
  }
  EXPECT_GE(rmin, 0.7f - 1e-5f);
  EXPECT_LE(rmax, 1.3f + 1e-5f);
  EXPECT_GT(rmax - rmin, 0.3f) << "the roughness should actually show";
  EXPECT_TRUE(granular::testing::pointInMesh(a, {0, 0, 0}));
  EXPECT_FALSE(granular::testing::pointInMesh(a, {1.31f, 0, 0}));
  EXPECT_EQ(makeRock(1, 0.0f, 5).points, makeIcosphere(1).points);
}

TEST(Mesh, ShapeParameterErrors) {
  EXPECT_NE(errorOf([] { makeIcosphere(9); }).find("makeIcosphere.subdivisions"), std::string::npos);
  EXPECT_NE(errorOf([] { makeRock(2, 0.5f, 0); }).find("makeRock.roughness"), std::string::npos);
  EXPECT_NE(errorOf([] { makeBox({0, 0, 0}, {1, 0, 1}); }).find("makeBox"), std::string::npos);
  EXPECT_NE(errorOf([] { makeLathe({{1, 0}, {0, 1}, {1, 2}}, 8); }).find("only the first and last"), std::string::npos);
  EXPECT_NE(errorOf([] { makeLathe({{0, 0}, {0, 1}}, 8); }).find("no point off the axis"), std::string::npos);
  EXPECT_NE(errorOf([] { makeLathe({{1, 0}, {1, 1}}, 2); }).find("segments"), std::string::npos);
  EXPECT_NE(errorOf([] { makeEllipsoid({1, 0, 1}, 1); }).find("radii"), std::string::npos);
  // Each factor in range, the product far beyond memory and uint32 indices: refused.
  EXPECT_NE(errorOf([] { makeUVSphere(65536, 65536); }).find("makeUVSphere.rings"), std::string::npos);
  EXPECT_NE(errorOf([] { makeLathe({{1, 0}, {1, 1}, {1, 2}, {1, 3}, {1, 4}, {1, 5}, {1, 6}, {1, 7}, {1, 8}, {1, 9},
                                    {1, 10}, {1, 11}, {1, 12}, {1, 13}, {1, 14}, {1, 15}, {1, 16}, {1, 17}, {1, 18},
                                    {1, 19}, {1, 20}, {1, 21}, {1, 22}, {1, 23}, {1, 24}, {1, 25}, {1, 26}, {1, 27},
                                    {1, 28}, {1, 29}, {1, 30}, {1, 31}, {1, 32}, {1, 33}, {1, 34}, {1, 35}, {1, 36},
                                    {1, 37}, {1, 38}, {1, 39}, {1, 40}, {1, 41}, {1, 42}, {1, 43}, {1, 44}, {1, 45},
                                    {1, 46}, {1, 47}, {1, 48}, {1, 49}, {1, 50}, {1, 51}, {1, 52}, {1, 53}, {1, 54},
                                    {1, 55}, {1, 56}, {1, 57}, {1, 58}, {1, 59}, {1, 60}, {1, 61}, {1, 62}, {1, 63},
                                    {1, 64}},
                                   65536); })
                .find("vertices exceed"),
            std::string::npos);
  EXPECT_EQ(makeUVSphere(2048, 2048).points.size(), size_t(2048) * 2047 + 2);  // the largest sizes still work
}
