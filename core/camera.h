// camera.h — the perspective camera of a UsdGeomCamera.
//
// Contract: built from CameraDesc and an image size; generateRay() maps a film
// position in pixels (x right, y down, (0,0) the top-left corner) to a world ray
// whose tmin/tmax are the clipping range measured along the view axis. The aperture
// is fitted inside the image (USD's default conform policy): the image shows at least
// the whole aperture, extended along the axis where the aspects differ. With a lens
// (CameraDesc::lensRadius > 0) it is a thin lens: the ray leaves a point of the lens disk
// (uniform, pdf 1/(π r²)) towards the point the pinhole ray meets on the plane in focus,
// so points on that plane stay sharp; every lens point weighs the same.
#pragma once

#include "math.h"
#include "rng.h"
#include "scene_desc.h"

namespace granular {

class Camera {
 public:
  Camera() = default;
  Camera(const CameraDesc& desc, int width, int height);
  // (lensU, lensV): the lens sample, ignored by a pinhole.
  Ray generateRay(float px, float py, float lensU = 0.5f, float lensV = 0.5f) const;
  // A sample's camera ray through pixel (x, y): the film position from rng (y's jitter,
  // then x's), then (with a lens only, so that pinhole images keep their random numbers)
  // the lens position, then (with an open shutter only, likewise) the ray's time, uniform
  // over the shutter (pdf 1 / (close − open)).
  Ray sampleRay(int x, int y, Rng& rng) const;
  bool hasLens() const { return lensRadius_ > 0; }
  // A camera ray cone (ept.h: footprint = width + spread·t): width at the lens and spread.
  // With a lens the footprint narrows to the pixel's at the plane in focus and widens
  // beyond it (|width + spread·t| is the footprint).
  float coneWidth() const { return 2.0f * lensRadius_; }
  float coneSpread() const { return pixelSpreadAngle() - (hasLens() ? 2.0f * lensRadius_ / focusDistance_ : 0.0f); }
  // Distance along the view axis (-Z in camera space) of a world point: the depth AOV.
  float viewDepth(const Vec3& worldPoint) const;
  Vec3 position() const { return position_; }
  // Angle a pixel subtends (at the image centre): the spread of a camera ray cone.
  float pixelSpreadAngle() const { return 2.0f * halfH_ / float(height_); }

 private:
  Transform toWorld_, toCamera_;
  Vec3 position_;
  float halfW_ = 1, halfH_ = 1, offX_ = 0, offY_ = 0;  // film window at unit distance
  int width_ = 1, height_ = 1;
  float clipNear_ = 0, clipFar_ = kInf;
  float lensRadius_ = 0, focusDistance_ = 1;
  float shutterOpen_ = 0, shutterClose_ = 0;
};

}  // namespace granular
