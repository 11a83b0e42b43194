// test_math.cpp — Transform::lookAt and Transform::inverse.
#include <gtest/gtest.h>

#include "core/math.h"

using namespace granular;

namespace {

void expectNear(const Vec3& a, const Vec3& b, float eps = 1e-5f) {
  EXPECT_NEAR(a.x, b.x, eps);
  EXPECT_NEAR(a.y, b.y, eps);
  EXPECT_NEAR(a.z, b.z, eps);
}

void expectOrthonormal(const Transform& t) {
  Vec3 x = t.vector({1, 0, 0}), y = t.vector({0, 1, 0}), z = t.vector({0, 0, 1});
  EXPECT_NEAR(length(x), 1, 1e-6);
  EXPECT_NEAR(length(y), 1, 1e-6);
  EXPECT_NEAR(length(z), 1, 1e-6);
  EXPECT_NEAR(dot(x, y), 0, 1e-6);
  EXPECT_NEAR(dot(y, z), 0, 1e-6);
  EXPECT_NEAR(dot(x, z), 0, 1e-6);
  EXPECT_NEAR(t.determinant3(), 1, 1e-6);  // right-handed
}

}  // namespace

TEST(Math, LookAtMapsMinusZToViewDirection) {
  Vec3 eye(1, 2, 3), target(4, 0, -1);
  Transform t = Transform::lookAt(eye, target, {0, 1, 0});
  expectOrthonormal(t);
  expectNear(t.point({0, 0, 0}), eye);
  expectNear(t.vector({0, 0, -1}), normalize(target - eye));
  // Local +Y leans towards world up; local +X is horizontal.
  EXPECT_GT(t.vector({0, 1, 0}).y, 0);
  EXPECT_NEAR(t.vector({1, 0, 0}).y, 0, 1e-6);
}

TEST(Math, LookAtUpParallelToViewStillOrthonormal) {
  Transform t = Transform::lookAt({0, 5, 0}, {0, 0, 0}, {0, 1, 0});
  expectOrthonormal(t);
  expectNear(t.vector({0, 0, -1}), {0, -1, 0});
}

TEST(Math, InverseOfAffineTransform) {
  Transform a = Transform::translate({1, -2, 3}) * Transform::scale({2, 0.5f, -3});
  a.m[0][1] = 0.3;  // some shear
  a.m[2][0] = -0.7;
  Transform inv;
  ASSERT_TRUE(a.inverse(inv));
  Transform p = a * inv;
  for (int i = 0; i < 4; ++i)
    for (int j = 0; j < 4; ++j) EXPECT_NEAR(p.m[i][j], i == j ? 1.0 : 0.0, 1e-12);
  Vec3 q(0.2f, 0.4f, -5);
  expectNear(inv.point(a.point(q)), q);
}

TEST(Math, InverseNeedsPivoting) {
  // Zero on the diagonal: Gauss-Jordan without row swaps would divide by zero.
  Transform a;
  a.m[0][0] = 0; a.m[0][1] = 1;
  a.m[1][0] = 1; a.m[1][1] = 0;
  Transform inv;
  ASSERT_TRUE(a.inverse(inv));
  EXPECT_DOUBLE_EQ(inv.m[0][1], 1);
  EXPECT_DOUBLE_EQ(inv.m[1][0], 1);
}

// A placement far from the origin says nothing about whether a matrix inverts: the
// translation takes no part in the tolerance (10^14 units away was once "singular").
TEST(Math, InverseOfATransformFarFromTheOrigin) {
  for (double far : {1e6, 1e14}) {
    const Transform a = Transform::translate(far, -far, far) * Transform::scale({2, 2, 2});
    Transform inv;
    ASSERT_TRUE(a.inverse(inv)) << far;
    const Transform id = a * inv;
    for (int i = 0; i < 4; ++i)
      for (int j = 0; j < 4; ++j) EXPECT_NEAR(id.m[i][j], i == j ? 1.0 : 0.0, 1e-9 * (j == 3 ? far : 1)) << far;
  }
}

// Vectors whose squares leave float (a cross product of edges 10^9 long, or of edges
// 10^-12 long) still normalise to their direction, not to zero or (0, 0, 1).
TEST(Math, NormalizeOutsideTheRangeOfSquares) {
  for (float s : {1e25f, 1e-25f, 1.0f}) {
    const Vec3 n = normalize(Vec3(3, 0, -4) * s);
    EXPECT_NEAR(n.x, 0.6f, 1e-6f) << s;
    EXPECT_NEAR(n.y, 0.0f, 1e-6f) << s;
    EXPECT_NEAR(n.z, -0.8f, 1e-6f) << s;
  }
  EXPECT_EQ(normalize(Vec3(0.0f)), Vec3(0, 0, 1));
  EXPECT_EQ(normalize(Vec3(kInf, 0, 0)), Vec3(0, 0, 1));
}

TEST(Math, InverseRejectsSingularAndNonFinite) {
  Transform inv;
  EXPECT_FALSE(Transform::scale({1, 0, 1}).inverse(inv));
  Transform r3;
  r3.m[0][0] = 1; r3.m[0][1] = 2; r3.m[0][2] = 3;
  r3.m[1][0] = 4; r3.m[1][1] = 5; r3.m[1][2] = 6;
  r3.m[2][0] = 7; r3.m[2][1] = 8; r3.m[2][2] = 9;  // classic singular matrix
  EXPECT_FALSE(r3.inverse(inv));
  Transform nan;
  nan.m[1][2] = std::nan("");
  EXPECT_FALSE(nan.inverse(inv));
}
