// IES LM-63 profiles (core/ies.h): what a file says, by its symmetry, and what is refused.
#include <gtest/gtest.h>

#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>

#include "core/error.h"
#include "core/ies.h"
#include "core/math.h"

using namespace granular;

namespace {

constexpr float kDeg = kPi / 180.0f;

// An LM-63-2002 file of photometric type C: candela multiplier `mult`, the angles and the
// rows of candela (one per horizontal angle) as the text after the counts gives them.
std::string iesText(const std::string& vertical, const std::string& horizontal, const std::string& candela, int nv,
                    int nh, double mult = 1.0, const std::string& tilt = "NONE") {
  std::ostringstream s;
  s << "IESNA:LM-63-2002\n[TEST] written for this test\n[MANUFAC] none\nTILT=" << tilt << "\n"
    << "1 -1 " << mult << " " << nv << " " << nh << " 1 2 0.1 0.2 0.05\n1.0 1.0 20\n"
    << vertical << "\n" << horizontal << "\n" << candela << "\n";
  return s.str();
}

std::string errorOf(const std::string& text) {
  try {
    parseIes(text);
  } catch (const InputError& e) {
    return e.detail();
  }
  return "";
}

}  // namespace

TEST(IesProfile, AnAxialProfileInterpolatesOverTheVerticalAngleAndIsDarkPastItsRange) {
  const IesProfile p = parseIes(iesText("0 45 90", "0", "100 50 0", 3, 1, 2.0));
  EXPECT_EQ(p.verticalCount(), 3);
  EXPECT_EQ(p.horizontalCount(), 1);
  for (float phi : {0.0f, 1.0f, -2.0f, 7.0f}) {
    EXPECT_FLOAT_EQ(p.intensity(0, phi), 200.0f);  // times the candela multiplier
    EXPECT_FLOAT_EQ(p.intensity(22.5f * kDeg, phi), 150.0f);
    EXPECT_FLOAT_EQ(p.intensity(67.5f * kDeg, phi), 50.0f);
  }
  EXPECT_FLOAT_EQ(p.intensity(90 * kDeg, 0), 0.0f);
  EXPECT_EQ(p.intensity(120 * kDeg, 0), 0.0f);  // a downlight: nothing upward
  EXPECT_FLOAT_EQ(p.maxIntensity(), 200.0f);
  // Ballast and ballast-lamp factors multiply too; numbers split by commas and CRLF lines.
  std::string text = "IESNA91\r\nTILT=NONE\r\n1,-1,1,2,1,1,2,0,0,0\r\n0.5,3,0\r\n0,180\r\n0\r\n10,20\r\n";
  const IesProfile q = parseIes(text);
  EXPECT_FLOAT_EQ(q.intensity(0, 0), 15.0f);
  EXPECT_FLOAT_EQ(q.intensity(90 * kDeg, 0), 22.5f);
  EXPECT_FLOAT_EQ(q.intensity(kPi, 0), 30.0f);
}

TEST(IesProfile, HorizontalAnglesExtendByTheSymmetryTheyState) {
  // Rows of constant candela (equal at every vertical angle): h(φ) read at θ = 30°.
  auto rowsOf = [](std::initializer_list<int> values, int nv) {
    std::string s;
    for (int v : values)
      for (int i = 0; i < nv; ++i) s += std::to_string(v) + " ";
    return s;
  };
  auto at = [](const IesProfile& p, float phiDeg) { return p.intensity(30 * kDeg, phiDeg * kDeg); };
  // 0–90°: the four quadrants mirror the first.
  const IesProfile quadrant = parseIes(iesText("0 90", "0 45 90", rowsOf({10, 20, 40}, 2), 2, 3));
  EXPECT_FLOAT_EQ(at(quadrant, 0), 10);
  EXPECT_FLOAT_EQ(at(quadrant, 22.5f), 15);
  EXPECT_FLOAT_EQ(at(quadrant, 135), 20);
  EXPECT_FLOAT_EQ(at(quadrant, 157.5f), 15);
  EXPECT_FLOAT_EQ(at(quadrant, 180), 10);
  EXPECT_FLOAT_EQ(at(quadrant, 270), 40);
  EXPECT_FLOAT_EQ(at(quadrant, 315), 20);
  EXPECT_FLOAT_EQ(at(quadrant, -45), 20);
  // 0–180°: mirrored in the plane of 0° and 180°.
  const IesProfile half = parseIes(iesText("0 90", "0 90 180", rowsOf({10, 20, 40}, 2), 2, 3));
  EXPECT_FLOAT_EQ(at(half, 135), 30);
  EXPECT_FLOAT_EQ(at(half, 225), 30);
  EXPECT_FLOAT_EQ(at(half, 270), 20);
  EXPECT_FLOAT_EQ(at(half, 315), 15);
  // 90–270°: mirrored in the plane of 90° and 270°.
  const IesProfile side = parseIes(iesText("0 90", "90 180 270", rowsOf({10, 20, 40}, 2), 2, 3));
  EXPECT_FLOAT_EQ(at(side, 0), 20);
  EXPECT_FLOAT_EQ(at(side, 45), 15);
  EXPECT_FLOAT_EQ(at(side, 135), 15);
  EXPECT_FLOAT_EQ(at(side, 315), 30);
  EXPECT_FLOAT_EQ(at(side, 270), 40);
  // The whole circle, its 360° row left out: closed back to the 0° row.
  const IesProfile open = parseIes(iesText("0 90", "0 90 180 270", rowsOf({10, 20, 40, 80}, 2), 2, 4));
  EXPECT_FLOAT_EQ(at(open, 225), 60);
  EXPECT_FLOAT_EQ(at(open, 315), 45);
  const IesProfile full = parseIes(iesText("0 90", "0 120 240 360", rowsOf({10, 40, 70, 10}, 2), 2, 4));
  EXPECT_FLOAT_EQ(at(full, 60), 25);
  EXPECT_FLOAT_EQ(at(full, 300), 40);
}

TEST(IesProfile, TheMeanIsThePowerOverTheSphereOrHemisphereItCovers) {
  // A constant over the whole sphere, and over the lower hemisphere alone.
  // The midpoint rule on 0.1° cells errs by ~1e-7 of the mean: 1e-5 bounds it and the
  // float sums.
  EXPECT_NEAR(parseIes(iesText("0 180", "0", "7 7", 2, 1)).meanIntensity(), 7.0, 7e-5);
  EXPECT_NEAR(parseIes(iesText("0 90", "0", "7 7", 2, 1)).meanIntensity(), 7.0, 7e-5);
  // I = cos θ at 1° steps over the lower hemisphere: ∫ cos θ dω / 2π = 1/2, less the
  // linear interpolation's own error: it lies below cos θ by h² cos θ / 12 on average over
  // a step h = 1°, so the mean is short by h² / 24 (1.27e-5).
  std::string v, c;
  for (int i = 0; i <= 90; ++i) {
    v += std::to_string(i) + " ";
    c += std::to_string(std::cos(i * kPiD / 180)) + " ";
  }
  EXPECT_NEAR(parseIes(iesText(v, "0", c, 91, 1)).meanIntensity(), 0.5 - std::pow(kPiD / 180, 2) / 24, 2e-6);
  // Varying over φ as well: a quadrant file of rows 0 and 2 at 0° and 90° (linear between)
  // has the mean 1 over its whole circle.
  EXPECT_NEAR(parseIes(iesText("0 90", "0 90", "0 0 2 2", 2, 2)).meanIntensity(), 1.0, 1e-5);
  // A profile over the whole sphere, bright below: ∫ over the lower half alone / 4π.
  EXPECT_NEAR(parseIes(iesText("0 90 90.001 180", "0", "4 4 0 0", 4, 1)).meanIntensity(), 2.0, 2e-5);
}

TEST(IesProfile, TiltTablesAreSkippedAndTheLuminaireTakenAsPhotometered) {
  const IesProfile p = parseIes(iesText("0 90", "0", "5 1", 2, 1, 1.0, "INCLUDE\n1\n3\n0 45 90\n1.0 0.9 0.5"));
  EXPECT_FLOAT_EQ(p.intensity(0, 0), 5.0f);
  EXPECT_FLOAT_EQ(p.intensity(45 * kDeg, 0), 3.0f);
  const IesProfile q = parseIes(iesText("0 90", "0", "5 1", 2, 1, 1.0, "lamp.tlt"));
  EXPECT_FLOAT_EQ(q.intensity(0, 0), 5.0f);
}

TEST(IesProfile, WhatIsNotAProfileOfTypeCIsRefusedSayingWhichNumber) {
  EXPECT_EQ(errorOf("a picture, not a profile"), "has no TILT= line: it is not an IES LM-63 photometric file");
  EXPECT_EQ(errorOf(iesText("0 90", "0", "5", 2, 1)), "ends before its candela value at horizontal 0°, vertical 90°");
  EXPECT_EQ(errorOf(iesText("0 90", "0", "5 -1", 2, 1)), "candela value at horizontal 0°, vertical 90° is -1, below 0");
  EXPECT_EQ(errorOf(iesText("0 90", "0", "5 nan", 2, 1)),
            "candela value at horizontal 0°, vertical 90° is not a finite number: \"nan\"");
  EXPECT_EQ(errorOf(iesText("0 90", "0", "5 x", 2, 1)), "candela value at horizontal 0°, vertical 90° is not a number: \"x\"");
  // Bytes that are not printable ASCII are shown as '?': a front end decodes the message
  // as UTF-8, which a byte 0xff (or a character cut at 40 bytes) is not.
  EXPECT_EQ(errorOf(iesText("0 90", "0", "5 \xff\xc3\xa9x", 2, 1)),
            "candela value at horizontal 0°, vertical 90° is not a number: \"???x\"");
  EXPECT_EQ(errorOf(iesText("0 90 45", "0", "5 1 1", 3, 1)), "vertical angles are not increasing: 90° then 45°");
  EXPECT_EQ(errorOf(iesText("0 200", "0", "5 1", 2, 1)), "vertical angle 2 is 200°, outside [0, 180]°");
  EXPECT_EQ(errorOf(iesText("0 90", "0 120", "5 1 5 1", 2, 2)),
            "horizontal angles run from 0° to 120°: type C runs them from 0° to 90°, 180° or 360°, or from 90° to 270°");
  EXPECT_EQ(errorOf(iesText("0", "0", "5", 1, 1)), "number of vertical angles is 1, expected a whole number in [2, 100000]");
  EXPECT_EQ(errorOf(iesText("0 90", "0", "5 1", 2, 1, 1e39)),
            "candela multiplier is 1e+39, beyond a 32-bit float");
  // Types A and B measure about other axes.
  std::string typeB = iesText("0 90", "0", "5 1", 2, 1);
  typeB.replace(typeB.find(" 1 2 0.1"), 8, " 2 2 0.1");
  EXPECT_EQ(errorOf(typeB), "photometric type B is not supported (type C is: the luminaire's axis vertical)");
  // Counts that would ask for more memory than any profile needs.
  EXPECT_EQ(errorOf(iesText("0 90", "0", "", 100000, 100000)), "100000 × 100000 angles are more than 4194304 candela values");
}

TEST(IesProfile, AFileIsReadAgainWhenItChanges) {
  namespace fs = std::filesystem;
  const fs::path path = fs::temp_directory_path() / ("granular_ies_" + std::to_string(::getpid()) + ".ies");
  {
    std::ofstream(path) << iesText("0 90", "0", "5 1", 2, 1);
  }
  const auto a = readIesFile(path.string());
  EXPECT_FLOAT_EQ(a->intensity(0, 0), 5.0f);
  EXPECT_EQ(readIesFile(path.string()), a);  // unchanged: the profile read before
  {
    std::ofstream(path) << iesText("0 90", "0", "50 10", 2, 1);
  }
  EXPECT_FLOAT_EQ(readIesFile(path.string())->intensity(0, 0), 50.0f);
  {
    std::ofstream(path) << "IESNA:LM-63-2002\nTILT=NONE\n1 -1 1 2 1 1";
  }
  try {
    readIesFile(path.string());
    ADD_FAILURE() << "a truncated file was read";
  } catch (const InputError& e) {
    EXPECT_EQ(e.object(), path.string());
    EXPECT_EQ(e.detail(), "ends before its units type");
  }
  fs::remove(path);
  try {
    readIesFile(path.string());
    ADD_FAILURE() << "a missing file was read";
  } catch (const InputError& e) {
    EXPECT_EQ(e.detail(), "cannot be found");
  }
}
