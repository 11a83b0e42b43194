// ies.h — a luminaire's photometric profile: the IES LM-63 file that UsdLuxShapingAPI's
// inputs:shaping:ies:file names, read into candela over the light's emission directions.
//
// Angles (photometric type C, the type of architectural and film luminaires): the vertical
// angle θ is 0 along the luminaire's nadir — the light's local −Z, its emission axis — and
// 180° opposite; the horizontal angle φ is 0 along local +X and 90° toward +Y.
//
// Contract: parseIes() reads the text of an LM-63-1986 to -2019 file: keyword lines up to
// TILT=, its tilt table skipped (TILT=INCLUDE; a TILT=<file> is not read either: the
// luminaire is taken as photometered), then the counts, the multipliers (the candela
// multiplier × the ballast factor × the ballast-lamp factor, 1 in newer files), the
// vertical and the horizontal angles, each strictly increasing, and the candela values,
// one row of vertical angles per horizontal angle. Numbers may be split by blanks, commas
// or line breaks. Refused, with an InputError whose detail() says what, for the caller to
// name the light and its attribute:
// not LM-63 text, photometric types A and B (automotive and floodlight photometry, on
// other axes), a count, angle or candela value missing, not finite, negative or out of
// range, angles out of order, horizontal angles that no symmetry of type C explains.
//
// intensity(θ, φ) interpolates bilinearly on the file's grid, extended by the symmetry its
// horizontal angles state: one angle, about the axis; 0–90°, the four quadrants; 0–180°,
// the plane of 0° and 180°; 90–270°, the plane of 90° and 270°; 0 to above 180°, none (a
// file that stops short of 360° is closed to its 0° row). It is 0 at vertical angles the
// file does not cover (a downlight's 0–90° leaves the upper half dark).
#pragma once

#include <memory>
#include <string>
#include <vector>

namespace granular {

class IesProfile {
 public:
  // Candela toward (θ, φ), radians; θ in [0, π], φ any angle (taken modulo 2π).
  float intensity(float theta, float phi) const;
  // UsdLuxShapingAPI's inputs:shaping:ies:normalize divides by this: the profile's power,
  // ∫ I dω over the directions it covers, over 4π — or 2π when its vertical angles span no
  // more than a hemisphere (90°, as Karma and RenderMan normalise): the interpolated
  // profile integrated over 0.5° of φ and 0.1° cells of θ.
  double meanIntensity() const { return mean_; }
  float maxIntensity() const { return max_; }
  int verticalCount() const { return int(vertical_.size()); }
  int horizontalCount() const { return int(horizontal_.size()); }

 private:
  friend IesProfile parseIes(const std::string& text);
  std::vector<float> vertical_;    // radians, increasing
  std::vector<float> horizontal_;  // radians, increasing, as the file lists them (φ is folded onto them)
  std::vector<float> candela_;     // [h * vertical_.size() + v]
  enum class Symmetry { Axial, Quadrant, Bilateral0, Bilateral90, None } symmetry_ = Symmetry::Axial;
  double mean_ = 0;
  float max_ = 0;
  float row(int h, float theta) const;  // the h-th horizontal row at θ (0 off its range)
  // The rows φ falls between after the symmetry's folding, and its place t from j0 to j1.
  void phiRows(float phi, int& j0, int& j1, float& t) const;
};

// The profile in `text` (the contents of a .ies file); InputError("", "", what) on what
// the contract refuses, `what` saying which number is wrong.
IesProfile parseIes(const std::string& text);

// The profile of the file at `path` (read again only when the file's time or size
// changes): InputError(path, "", what) when it cannot be found, read or parsed.
std::shared_ptr<const IesProfile> readIesFile(const std::string& path);

}  // namespace granular
