// camera.h — the perspective camera of a UsdGeomCamera.
//
// Contract: built from CameraDesc and an image size; generateRay() maps a film
// position in pixels (x right, y down, (0,0) the top-left corner) to a world ray
// whose tmin/tmax are the clipping range measured along the view axis. The aperture
// is fitted inside the image (USD's default conform policy): the image shows at least
// the whole aperture, extended along the axis where the aspects differ.
#pragma once

#include "math.h"
#include "scene_desc.h"

namespace granular {

class Camera {
 public:
  Camera() = default;
  Camera(const CameraDesc& desc, int width, int height);
  Ray generateRay(float px, float py) const;
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
};

}  // namespace granular
